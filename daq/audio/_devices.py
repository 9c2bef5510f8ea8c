"""The audio devices PortAudio reaches: their host API, channel counts and default rate.

A device is named as PortAudio names it (under JACK: the client whose ports it stands for,
"system" for the server's own interface); `find_device` accepts the exact name or a part of it
that only one device's name contains, and optionally the host API (ALSA, JACK, Core Audio,
Windows WASAPI, ASIO, ...), since one interface often appears once per host API.
"""

from __future__ import annotations

from dataclasses import dataclass

from ._errors import DeviceNotFoundError
from ._portaudio import refresh


@dataclass(frozen=True)
class AudioDeviceInfo:
    """One device as PortAudio reports it.

    Attributes:
        index: PortAudio's device index (valid until PortAudio is initialised again).
        name: the device's name.
        host_api: the host API's name ("ALSA", "JACK Audio Connection Kit", ...).
        inputs: input channels at most.
        outputs: output channels at most.
        default_rate_hz: the device's default sample rate, samples per second.
    """

    index: int
    name: str
    host_api: str
    inputs: int
    outputs: int
    default_rate_hz: float

    def __str__(self) -> str:
        return f'audio interface "{self.name}" ({self.host_api})'


def list_devices() -> list[AudioDeviceInfo]:
    """Every device PortAudio reaches now (PortAudio initialised again first: `refresh`)."""
    sd = refresh()
    apis = [a["name"] for a in sd.query_hostapis()]
    return [AudioDeviceInfo(index=i, name=str(d["name"]), host_api=apis[d["hostapi"]],
                            inputs=int(d["max_input_channels"]),
                            outputs=int(d["max_output_channels"]),
                            default_rate_hz=float(d["default_samplerate"]))
            for i, d in enumerate(sd.query_devices())]


def _host_matches(device: AudioDeviceInfo, host_api: str | None) -> bool:
    return host_api is None or host_api.lower() in device.host_api.lower()


def find_device(name: str, host_api: str | None = None,
                devices: list[AudioDeviceInfo] | None = None) -> AudioDeviceInfo:
    """The device called `name` (exactly, else the one whose name contains it), on a host API
    whose name contains `host_api` if given; DeviceNotFoundError listing the devices if none
    or several match."""
    devices = list_devices() if devices is None else devices
    candidates = [d for d in devices if _host_matches(d, host_api)]
    exact = [d for d in candidates if d.name == name]
    matches = exact or [d for d in candidates if name.lower() in d.name.lower()]
    where = f"{name!r}" + (f" on host API {host_api!r}" if host_api else "")
    if len(matches) == 1:
        return matches[0]
    known = "; ".join(str(d) for d in devices) or "none"
    if not matches:
        raise DeviceNotFoundError(
            f"no audio device {where}: is it plugged in and powered, and (for JACK) is the "
            f"server running? The devices PortAudio reaches are: {known} "
            "(`micam daq list --backend audio`)")
    raise DeviceNotFoundError(
        f"several audio devices match {where}: {'; '.join(str(d) for d in matches)}; write "
        "the exact name, or add host_api to choose one")
