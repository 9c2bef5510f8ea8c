"""The audio-interface backend: any device PortAudio reaches, as a `daq.Board` (sounddevice).

ALSA and JACK here, Core Audio, WASAPI and ASIO elsewhere: an RME, MOTU, Focusrite or Behringer
interface, a USB array (miniDSP UMA-16, ReSpeaker). Each interface is one board: its inputs
recorded and its outputs played on one full-duplex stream, one device clock, so a speaker
burst and the microphones stay sample-aligned; the interface's output-to-input latency is
whatever it is, measured by the reference microphone like the boards' (docs/hardware.md).

Modules, each with one job:

- `_portaudio`: loads sounddevice / PortAudio with an install hint, re-initialises PortAudio
  to see new devices;
- `_devices`: the devices (host API, channel counts, default rate), finding one by name;
- `_stream`: one device's continuous stream: the callback, the input ring, the output
  schedule, xruns and a stream that died;
- `_board`: `AudioBoard`, the board protocol on a stream;
- `_clock`: several interfaces on one word clock: trigger, offsets, drift;
- `_config`, `_open`: `[hardware.audio]` and opening its interfaces as boards.

Typical use: `boards = open_audio_boards(config, ["A"])`, then `daq.SyncGroup(boards)`.
"""

from ._board import AudioBoard, AudioIdentity, device_model
from ._clock import WordClock
from ._config import AudioConfig, AudioDeviceConfig
from ._devices import AudioDeviceInfo, find_device, list_devices
from ._errors import AudioUnavailableError, DeviceNotFoundError
from ._open import open_audio_boards
from ._portaudio import INSTALL

__all__ = [
    "INSTALL",
    "AudioBoard",
    "AudioConfig",
    "AudioDeviceConfig",
    "AudioDeviceInfo",
    "AudioIdentity",
    "AudioUnavailableError",
    "DeviceNotFoundError",
    "WordClock",
    "device_model",
    "find_device",
    "list_devices",
    "open_audio_boards",
]
