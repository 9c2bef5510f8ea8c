"""The emulated boards seen through plain pyusb, and the emulated capture against the world."""

from __future__ import annotations

import numpy as np
import pytest
import usb.core
import usb.util

from daq import InputChannel, OutputChannel, ScanConfig, SyncGroup, volts_to_codes
from daq.usb._ids import EP_CMD_IN, EP_CMD_OUT, EP_MSG_IN, EP_STREAM_IN, EP_STREAM_OUT
from daq.usb._protocol import ReadWord
from sim.arrays import ArrayLayout, scatter48
from sim.analog_bench import AcousticBench
from sim.boards import SimulatedBoard
from sim.usb import EmulatedBus, LoopbackBench, eeprom_serial, emulated_boards
from sim.world import World


def test_running_board_shows_the_dt9836_descriptor_and_endpoints() -> None:
    bus = EmulatedBus(LoopbackBench(), [("DT9836-12-2", "1")])
    dev = usb.core.find(backend=bus.backend, idVendor=0x0867, idProduct=0x3698)
    assert dev is not None and dev.bcdUSB == 0x0200 and dev.port_numbers == (1,)
    intf = dev.get_active_configuration()[(0, 0)]
    eps = {e.bEndpointAddress: e.wMaxPacketSize for e in intf}
    assert eps == {EP_MSG_IN: 512, EP_CMD_OUT: 64, EP_CMD_IN: 64, EP_STREAM_OUT: 512,
                   EP_STREAM_IN: 512, 0x04: 512}
    dev.write(EP_CMD_OUT, ReadWord(0x020).encode())
    assert bytes(dev.read(EP_CMD_IN, 64)) == b"\x00\x04"  # VERSION_ID of a DT9836-12-2
    with pytest.raises(usb.core.USBTimeoutError):
        dev.read(EP_CMD_IN, 64, timeout=10)  # no second reply
    with pytest.raises(usb.core.USBError, match="Pipe"):
        dev.write(EP_CMD_OUT, b"\xff" + bytes(63))  # unknown command: the endpoint stalls
    usb.util.dispose_resources(dev)


def test_fx2_loader_needs_the_loader_for_external_ram_and_re_enumerates() -> None:
    bus = EmulatedBus(LoopbackBench(), [("DT9816-A", "2")], firmware_loaded=False)
    dev = usb.core.find(backend=bus.backend, idVendor=0x0867, idProduct=0x9816)
    assert dev is not None
    with pytest.raises(usb.core.USBError, match="Pipe"):
        dev.ctrl_transfer(0x40, 0xA3, 0x5000, 0, b"\x01\x02")  # no loader running yet
    dev.ctrl_transfer(0x40, 0xA0, 0xE600, 0, b"\x01")
    dev.ctrl_transfer(0x40, 0xA0, 0x0000, 0, b"\x02\x00\x10")  # a "loader"
    dev.ctrl_transfer(0x40, 0xA0, 0xE600, 0, b"\x00")
    descriptor = bytes([18, 1, 0, 2, 0, 0, 0, 64, 0x67, 0x08, 0x98, 0x16, 1, 0, 1, 2, 0, 1])
    dev.ctrl_transfer(0x40, 0xA3, 0x6000, 0, descriptor)
    dev.ctrl_transfer(0x40, 0xA0, 0xE600, 0, b"\x01")
    dev.ctrl_transfer(0x40, 0xA0, 0xE600, 0, b"\x00")  # the firmware starts
    with pytest.raises(usb.core.USBError, match="No such device"):
        dev.ctrl_transfer(0x40, 0xA0, 0xE600, 0, b"\x01")  # the old device is gone
    new = usb.core.find(backend=bus.backend, idVendor=0x0867)
    assert new is not None and new.idProduct == 0x1698 and new.port_numbers == (1,)
    assert new.address != dev.address


def test_named_serials_get_distinct_eeprom_numbers() -> None:
    assert eeprom_serial("1234") == 1234
    assert eeprom_serial("SIM3600") != eeprom_serial("SIM3601")


def _configs(layout: ArrayLayout, n: int) -> list[ScanConfig]:
    configs = []
    for spec in layout.boards:
        n_in = 12 if spec.model.startswith("DT9836") else 6
        outputs = (OutputChannel(channel=0), OutputChannel(channel=1)) if n_in == 12 else ()
        configs.append(ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(n_in)),
                                  outputs=outputs, sample_rate_hz=96_000.0,
                                  samples_per_channel=n))
    return configs


def test_emulated_usb_capture_equals_the_plain_simulated_one() -> None:
    """The acoustic world through the real driver and emulated boards gives the same codes
    as the plain simulated boards for the same seed."""
    volts = np.zeros((1500, 2))
    volts[50:1050, 0] = np.random.default_rng(1).choice([-1.0, 1.0], 1000)
    burst = volts_to_codes(volts, 10.0)
    recordings = []
    for backend in ("simulated", "usb-emulated"):
        world = World(layout=scatter48(), seed=11)
        bench = AcousticBench(world)
        specs = world.layout.boards
        boards = ([SimulatedBoard(s, bench) for s in specs] if backend == "simulated"
                  else emulated_boards(bench, [(s.model, s.serial) for s in specs]))
        group = SyncGroup(boards)
        group.configure(_configs(world.layout, 4000))
        recordings.append(group.acquire({0: burst}, block_samples=1000).codes)
        group.close()
    assert np.array_equal(recordings[0], recordings[1])
    assert recordings[1][:, :48].std() > 10  # the burst was heard
