"""Names for what the decoder shows: registers, their bits, board variants, standard requests.

Everything comes from the driver's own tables (`_registers`, `_families`), so the decoded
trace speaks the driver's vocabulary: a register the driver does not name shows as its address.
"""

from __future__ import annotations

from enum import IntFlag

from .._families import FAMILIES
from .._registers import InputControl, IoOp, Misc, OutputControl, Reg

_FLAGS: dict[int, type[IntFlag]] = {Reg.INPUT_CONTROL0: InputControl,
                                    Reg.OUTPUT_CONTROL: OutputControl,
                                    Reg.IO_OP_CONTROL: IoOp, Reg.MISC_CTRLS: Misc}
_DA_SELECT_BITS = 4
"""OUTPUT_CONTROL bits 0..3 select DAC channels 0..3 (DA_CHANNELn_SEL)."""

VARIANTS: dict[int, str] = {v: name for f in FAMILIES for v, name in f.variants.items()}
"""VERSION_ID register value -> board model, over every family (the values do not collide)."""

STANDARD_REQUESTS = {0: "GET_STATUS", 1: "CLEAR_FEATURE", 3: "SET_FEATURE", 5: "SET_ADDRESS",
                     6: "GET_DESCRIPTOR", 7: "SET_DESCRIPTOR", 8: "GET_CONFIGURATION",
                     9: "SET_CONFIGURATION", 10: "GET_INTERFACE", 11: "SET_INTERFACE",
                     12: "SYNCH_FRAME"}
"""USB 2.0 table 9-4."""


def register(address: int) -> str:
    """A register's name, or its address if the driver's map does not name it."""
    try:
        return Reg(address).name
    except ValueError:
        return f"register 0x{address:03x}"


def value(address: int, v: int) -> str:
    """A register value in hex, with the names of its bits where the register has them."""
    flags = _FLAGS.get(address)
    if flags is None:
        return f"0x{v:04x}"
    names = [m.name or "" for m in flags if v & m.value == m.value and m.value]
    rest = v & ~sum(m.value for m in flags if v & m.value == m.value)
    if address == Reg.OUTPUT_CONTROL:
        names += [f"DA{n}_SEL" for n in range(_DA_SELECT_BITS) if rest >> n & 1]
        rest &= ~((1 << _DA_SELECT_BITS) - 1)
    if rest:
        names.append(f"0x{rest:x}")
    return f"0x{v:04x} ({'|'.join(names) or '0'})"
