"""Errors of the audio backend, on top of the driver-layer errors of `daq`.

A fault of a running device is one of `daq`'s own errors (OverrunError for an input overflow,
UnderrunError for an output underflow, DeviceDisconnectedError for a device or server that went
away, ConfigurationError for a rate or channel count the device refuses, SyncError for
interfaces that drift apart), each naming the device and the sample index.
"""

from __future__ import annotations

from daq import ConfigurationError


class AudioUnavailableError(ConfigurationError):
    """PortAudio or its binding (sounddevice) is not installed; the message says how."""


class DeviceNotFoundError(ConfigurationError):
    """No audio device matches the configured name (or it matches several)."""
