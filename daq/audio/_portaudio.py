"""PortAudio through `sounddevice`, loaded on first use, with an error that says what to install.

`sounddevice` loads the PortAudio library when it is imported, and PortAudio sees the devices
(and, for JACK, the server) that exist at its initialisation. `refresh` initialises it again so
that a device plugged in, or a JACK server started, after the first use is seen; it is only
called while none of this process's streams is open (closing PortAudio closes them).
"""

from __future__ import annotations

import atexit
import threading
from types import ModuleType

from ._errors import AudioUnavailableError

INSTALL = ("install PortAudio and its Python binding: `apt-get install libportaudio2` "
           "(Debian/Ubuntu; jackd2 too for JACK) and `pip install sounddevice`")
"""What a user is told when PortAudio or sounddevice is missing."""

_lock = threading.Lock()
_open_streams = 0
_abandoned = False  # a stream died under PortAudio: it is never terminated in this process


def portaudio() -> ModuleType:
    """The `sounddevice` module, or AudioUnavailableError naming what to install."""
    try:
        import sounddevice
    except ImportError as exc:
        raise AudioUnavailableError(f"the audio backend needs the sounddevice package: {exc}; "
                                    f"{INSTALL}") from None
    except OSError as exc:  # sounddevice is there, the PortAudio library is not
        raise AudioUnavailableError(f"the PortAudio library cannot be loaded ({exc}); "
                                    f"{INSTALL}") from None
    return sounddevice


def refresh() -> ModuleType:
    """PortAudio initialised again (new devices, a restarted JACK server), unless a stream of
    this process is open (then the device list stays what it was)."""
    sd = portaudio()
    with _lock:
        if _open_streams == 0 and not _abandoned:
            sd._terminate()
            sd._initialize()
    return sd


def abandon() -> None:
    """A stream died (its JACK server went away): PortAudio would hang closing it, in
    `refresh` or at the interpreter's exit (sounddevice's exit handler terminates PortAudio),
    so neither happens in this process any more; the process exits without it."""
    global _abandoned
    sd = portaudio()
    with _lock:
        _abandoned = True
        atexit.unregister(sd._exit_handler)


def stream_opened() -> None:
    """Count a stream as open (see `refresh`)."""
    global _open_streams
    with _lock:
        _open_streams += 1


def stream_closed() -> None:
    """Count a stream as closed, or abandoned after its server went away."""
    global _open_streams
    with _lock:
        _open_streams = max(0, _open_streams - 1)
