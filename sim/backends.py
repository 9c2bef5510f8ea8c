"""The simulated capture of any backend: simulated boards, the USB driver on emulated boards
(sim.capture), or the audio backend on a JACK server with the world as a JACK client
(sim.audio_capture)."""

from __future__ import annotations

from .capture import SimulatedCapture, SimulationOptions, build_simulated_capture
from .errors import SimulationInputError


def build_capture(options: SimulationOptions) -> SimulatedCapture:
    """The world of `options` and the hardware of its backend to capture it."""
    if options.backend == "audio":
        from .audio_capture import build_audio_capture

        if options.mistakes:
            raise SimulationInputError("the simulated world makes its mistakes in its own "
                                       "boards and cameras: simulate them without "
                                       "--backend audio")

        return build_audio_capture(options)
    return build_simulated_capture(options)
