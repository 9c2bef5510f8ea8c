"""Opening the configured interfaces as boards, in the capture configuration's board order."""

from __future__ import annotations

from collections.abc import Sequence

from ._board import AudioBoard
from ._clock import WordClock
from ._config import AudioConfig
from ._devices import find_device, list_devices
from ._errors import DeviceNotFoundError


def open_audio_boards(config: AudioConfig, labels: Sequence[str]) -> list[AudioBoard]:
    """One board per label (a device of `config`), the first the clock master; several share
    a `WordClock`. DeviceNotFoundError names a label without a device or a device not found."""
    devices = list_devices()
    clock = WordClock() if len(labels) > 1 else None
    boards = []
    for label in labels:
        try:
            entry = config.device(label)
        except KeyError:
            raise DeviceNotFoundError(
                f"board {label!r} of the capture configuration is no device of "
                f"[hardware.audio] (labels: {', '.join(d.label for d in config.devices)})"
            ) from None
        device = find_device(entry.name, entry.host_api, devices)
        boards.append(AudioBoard(device, label, config.block_frames, config.latency, clock))
    return boards
