"""The audio backend on a real JACK server (jackd, dummy driver) with the simulated world as a
JACK client between its ports: what `micam daq` shows, alignment of a burst and the
microphones on one device clock, the interface's latency measured, and every fault's outcome
(xrun, refused rate or channels, a device that is not there, interfaces without one clock)."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from acquisition.contracts.instructions import Instruction, InstructionKind
from daq import (
    ConfigurationError,
    DeviceDisconnectedError,
    InputChannel,
    OutputChannel,
    OverrunError,
    ScanConfig,
    SyncGroup,
    UnderrunError,
    volts_to_codes,
)
from daq.audio import (
    AudioBoard,
    AudioConfig,
    AudioDeviceConfig,
    AudioDeviceInfo,
    DeviceNotFoundError,
    find_device,
    open_audio_boards,
)
from daq.audio._stream import Fault, refused
from kernel.stimulus import mls_burst
from micam.cli import main
from sim.capture import SimulationOptions
from sim.jack_world import WorldProcess

from .jack_helpers import CAPTURE_PORTS, PERIOD, PLAYBACK_PORTS, RATE_HZ, XRUN_RETRIES, acquire_whole, wait_for

pytestmark = pytest.mark.slow  # every test here: a JACK server and the world as its client

OPTIONS = SimulationOptions(array="scatter15", poses=2, mls_order=10, seed=3, backend="audio")
PRE = 256
N = PERIOD + 4096  # the round trip (one period) and the burst
BURST = mls_burst(10)


@pytest.fixture(scope="module")
def world(jack_server) -> Iterator[WorldProcess]:  # noqa: ANN001
    process = WorldProcess(OPTIONS.model_dump_json(), "micam-test-world")
    process.perform(Instruction(kind=InstructionKind.REFERENCE_AT_SPEAKER, speaker=0,
                                text="reference at speaker 0"))
    yield process
    process.close()


@pytest.fixture(scope="module")
def group(world: WorldProcess) -> Iterator[SyncGroup]:
    group = SyncGroup(open_audio_boards(
        AudioConfig(devices=(AudioDeviceConfig(label="A", name=world.name),)), ["A"]))
    group.configure([scan()])
    yield group
    group.close()


def scan(rate_hz: float = RATE_HZ, inputs: int = 16, n: int = N) -> ScanConfig:
    return ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(inputs)),
                      outputs=(OutputChannel(channel=0),), sample_rate_hz=rate_hz,
                      samples_per_channel=n)


def burst_codes(n: int = N) -> np.ndarray:
    volts = np.zeros((n, 1))
    volts[PRE: PRE + BURST.size, 0] = BURST
    return volts_to_codes(volts, 10.0)


def arrival(recording: np.ndarray, column: int) -> float:
    """The burst's delay in one column, samples from the output's first sample, parabolic."""
    x = recording[:, column].astype(float)
    xc = np.fft.irfft(np.fft.rfft(x, 2 * N) * np.conj(np.fft.rfft(
        burst_codes()[:, 0].astype(float), 2 * N)), 2 * N)[:N]
    k = int(np.argmax(xc))
    a, b, c = xc[k - 1], xc[k], xc[k + 1]
    return k + 0.5 * (a - c) / (a - 2 * b + c)


def test_daq_list_shows_the_dummy_interface(jack_server, capsys) -> None:  # noqa: ANN001
    assert main(["daq", "list", "--backend", "audio"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    system = [r for r in rows if r[-1] == "system"]
    assert len(system) == 1
    assert system[0][:-1] == ["JACK", "Audio", "Connection", "Kit", str(CAPTURE_PORTS),
                              str(PLAYBACK_PORTS), str(RATE_HZ)]


def test_daq_selftest_scans_every_input_at_the_server_rate(jack_server, capsys) -> None:  # noqa: ANN001
    for _ in range(XRUN_RETRIES):  # an xrun of this loaded machine fails a selftest too
        if main(["daq", "selftest", "--backend", "audio", "--device", "system",
                 "--seconds", "0.2"]) == 0:
            break
        assert "input overflow" in capsys.readouterr().out
    out = capsys.readouterr().out
    assert "19200/19200 samples on 16 inputs at 96 kS/s" in out and out.rstrip().endswith("ok")


def test_the_burst_and_the_microphones_share_one_clock(group: SyncGroup) -> None:
    """The reference microphone 2 mm from the speaker hears the burst one JACK period (the
    server's buffer: the interface's latency, measured here, not assumed) plus 2 mm of air and
    the speaker's group delay (a sample or two) after it was played, at the same fraction of a
    sample in every recording."""
    lags = [arrival(acquire_whole(group, {0: burst_codes()}).codes, 15) for _ in range(3)]
    assert all(0.5 < lag - PERIOD < 3.0 for lag in lags), lags
    assert np.ptp(lags) < 1e-3


def test_an_xrun_is_an_overrun_naming_the_device_and_the_sample(group: SyncGroup,
                                                                 world: WorldProcess) -> None:
    """A stalled world client makes the server skip periods: every client's status flags
    say so, and the recording fails at the sample where data was lost; the next one is
    whole again (the stream runs on)."""
    n = 48_000
    group.configure([scan(n=n)])
    try:
        timer = threading.Timer(0.15, world.stall, args=(0.06,))
        timer.start()
        with pytest.raises(OverrunError, match=r'audio interface A \("micam-test-world", JACK '
                           r'Audio Connection Kit\): input overflow and output underflow at '
                           r"sample index (\d+)"):
            group.acquire({0: burst_codes(n)}, block_samples=4096)
        timer.join()
        stream = group.boards[0].stream  # type: ignore[attr-defined]
        wait_for(lambda: stream.frames - stream.faults[-1].frame > 0.3 * RATE_HZ, 10.0,
                 "the server recovered from the stall")
        assert acquire_whole(group, {0: burst_codes(n)}).codes.shape == (n, 16)
    finally:
        group.configure([scan()])


def test_an_output_underflow_alone_is_an_underrun() -> None:
    """JACK flags both on every xrun; a host API that flags only the output's (ALSA's playback
    ran dry) makes an UnderrunError, named the same way (the flags as PortAudio hands them)."""
    board = AudioBoard(AudioDeviceInfo(0, "USB Audio", "ALSA", 2, 2, 48_000.0), "A")
    board._window = 1000  # a recording from stream frame 1000
    with pytest.raises(UnderrunError, match=r'audio interface A \("USB Audio", ALSA\): output '
                                            r"underflow at sample index 24 \(an xrun"):
        board._raise_xrun(Fault(("output underflow",), 1024), playing=True)


def test_a_device_another_program_holds_is_named_as_such() -> None:
    """A JACK port can always be shared, so the server cannot show this: an ALSA device that
    another program opened without dmix answers paDeviceUnavailable (-9985) as PortAudio
    raises it, and the board says what to do instead of a bare PortAudio code."""
    import sounddevice

    device = AudioDeviceInfo(3, "USB Audio", "ALSA", 16, 8, 48_000.0)
    error = refused(device, 48_000.0, 16, 1,
                    sounddevice.PortAudioError("Error opening Stream: Device unavailable", -9985))
    assert isinstance(error, DeviceDisconnectedError)
    assert "another program holds it; close that program" in str(error)
    assert '"USB Audio"' in str(error)
    other = refused(device, 48_000.0, 16, 1,
                    sounddevice.PortAudioError("Unanticipated host error", -9999))
    assert isinstance(other, ConfigurationError)
    assert "cannot open a stream of 16 inputs" in str(other)


def test_a_rate_the_device_refuses_is_a_configuration_error(world: WorldProcess) -> None:
    with open_audio_boards(AudioConfig(devices=(AudioDeviceConfig(label="A", name=world.name),)),
                           ["A"])[0] as board, pytest.raises(
            ConfigurationError, match=r"refuses the sample rate 48000 S/s .*its default is "
                                      r"96000 S/s"):
        board.configure(scan(rate_hz=48_000))


def test_a_channel_the_device_lacks_is_a_configuration_error(world: WorldProcess) -> None:
    with open_audio_boards(AudioConfig(devices=(AudioDeviceConfig(label="A", name=world.name),)),
                           ["A"])[0] as board, pytest.raises(
            ConfigurationError, match=r"input channel 16 does not exist; the device has "
                                      r"inputs 0\.\.15"):
        board.configure(scan(inputs=17))


def test_an_interface_that_is_not_there_is_named(jack_server) -> None:  # noqa: ANN001
    with pytest.raises(DeviceNotFoundError, match=r"no audio device 'Fireface'.*is it plugged "
                                                  r"in.*\"system\" \(JACK"):
        find_device("Fireface")


def test_several_interfaces_need_one_word_clock() -> None:
    with pytest.raises(ValueError, match="2 interfaces need one word clock"):
        AudioConfig(devices=(AudioDeviceConfig(label="A", name="x"),
                             AudioDeviceConfig(label="B", name="y")))


def test_a_jack_device_that_quits_is_a_disconnection_not_silence(group: SyncGroup,
                                                                 world: WorldProcess) -> None:
    """The world's JACK client is the interface here: killed (a program that crashed, a USB
    interface's bridge that quit), PortAudio would go on reading silence; the recording fails
    naming the interface instead. (Last in this module: it ends the module's world.)"""
    acquire_whole(group, {0: burst_codes()})
    os.kill(world.pid, signal.SIGKILL)
    with pytest.raises(DeviceDisconnectedError, match=r'audio interface A \("micam-test-world"'
                       r".*went away at stream frame \d+: its JACK client 'micam-test-world' "
                       r"left the server"):
        for _ in range(50):  # bounded: the server tells the watch within a period or two
            group.acquire({0: burst_codes()})
