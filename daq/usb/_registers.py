"""The DT9836 FPGA register map: 16-bit registers at 16-bit local-bus addresses (public facts).

From `dt9836_hwreg.h` in Data Translation's 2013 Linux driver (see docs/usb-protocol.md). Only
the registers and bits the driver uses are named here. Registers are read and written with the
local-bus commands of `_protocol` (R_/W_*_WORD_LB).
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class Reg(IntEnum):
    """Register addresses."""

    INPUT_CONTROL0 = 0x000
    SAMPLES_PER_TRIG_LO = 0x001
    SAMPLES_PER_TRIG_HI = 0x002
    INPUT_CHAN_MASK_LO = 0x003
    INPUT_CHAN_MASK_HI = 0x004
    OUTPUT_CONTROL = 0x005
    IO_OP_CONTROL = 0x006
    INT_STATUS = 0x007
    INT_MASK = 0x008
    IN_SAMPLE_CLK_PERIOD_LO = 0x009
    IN_SAMPLE_CLK_PERIOD_HI = 0x00A
    OUT_SAMPLE_CLK_PERIOD_LO = 0x00B
    OUT_SAMPLE_CLK_PERIOD_HI = 0x00C
    MISC_CTRLS = 0x010
    VERSION_ID = 0x020
    DIG_IN_CTRL_STAT = 0x103


class InputControl(IntFlag):
    """INPUT_CONTROL0 bits."""

    EXT_TRIGGER = 0x100
    EXT_TRIGGER_POLARITY = 0x80
    EXT_SAMPLE_CLK = 0x40
    ADC_2V_RANGE = 0x10
    ADC_SINGLE_ENDED = 0x1


class OutputControl(IntFlag):
    """OUTPUT_CONTROL bits (DA_CHANNELn_SEL is bit n, n = 0..3)."""

    DAC3_CLEAR_N = 0x8000
    DAC2_CLEAR_N = 0x4000
    DAC1_CLEAR_N = 0x2000
    DAC0_CLEAR_N = 0x1000
    DAC_RESET_ALL_N = 0x800
    EXT_TRIGGER = 0x100
    EXT_TRIGGER_POLARITY = 0x80
    EXT_SAMPLE_CLK = 0x40
    WAVEFORM_GENERATOR = 0x20


DAC_RELEASED = (OutputControl.DAC3_CLEAR_N | OutputControl.DAC2_CLEAR_N
                | OutputControl.DAC1_CLEAR_N | OutputControl.DAC0_CLEAR_N
                | OutputControl.DAC_RESET_ALL_N)
"""OUTPUT_CONTROL with every DAC out of clear and reset (0xF800, the driver's init value)."""


class IoOp(IntFlag):
    """IO_OP_CONTROL bits."""

    OUTPUT_ARM = 0x100
    OUTPUT_SOFT_TRIGGER = 0x80
    INPUT_SCAN_ARM = 0x20
    INPUT_SCAN_STOP = 0x10
    INPUT_SOFT_TRIGGER = 0x8
    CNTR_TMR_RESET = 0x1


class Misc(IntFlag):
    """MISC_CTRLS bits."""

    DAC_TWOS_COMP = 0x2
    ADC_TWOS_COMP = 0x1


BASE_CLOCK_HZ = 36_000_000
"""The DT9836 internal time base (crystal), in hertz."""

INIT_SEQUENCE: tuple[tuple[int, int], ...] = (
    (Reg.OUTPUT_CONTROL, int(DAC_RELEASED)),
    (Reg.INPUT_CONTROL0, 0),
    (Reg.IO_OP_CONTROL, int(IoOp.CNTR_TMR_RESET)),
    (Reg.IO_OP_CONTROL, 0),
    (Reg.INT_STATUS, 0xFFFF),
    (Reg.INT_STATUS, 0),
    (Reg.INT_MASK, 0),
    (Reg.DIG_IN_CTRL_STAT, 0),
)
"""The register writes of Data Translation's driver at probe time, in order (address, value).

Its COUNTER_INT_MASK and DIG_IN_INT_MASK writes are left out: the facts at hand do not give
their addresses, and interrupts stay masked by INT_MASK anyway."""

EEPROM_I2C_ADDRESS = 0x50
"""The 16-byte board EEPROM on the FX2's I2C bus."""
EEPROM_SERIAL = (8, 9, 10, 11)
"""EEPROM registers holding the serial number (read as a little-endian u32)."""
