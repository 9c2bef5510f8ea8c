"""Board models and their capabilities.

The figures come from what is public about the Data Translation DT9836 and DT9816 families
(see docs/hardware.md): the DT9836 version register names its variants (12 or 6 simultaneous
16-bit inputs, 0, 2 or 4 16-bit outputs); the DT9836 samples at up to 225 kS/s per channel; the
DT9816 at about 50 kS/s per channel and its "-A" variant at about 150 kS/s, so a 96 kS/s array
needs DT9816-A boards. Figures marked *unverified* in docs/hardware.md come from memory of the
datasheets, not from a document at hand; they live here only, so a lab can correct them in one
place.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ._errors import ConfigurationError

BoardFamily = Literal["DT9836", "DT9816", "audio"]


@dataclass(frozen=True)
class BoardModel:
    """Static capabilities of one board variant.

    Attributes:
        name: the variant as Data Translation names it, e.g. "DT9836-12-2".
        family: "DT9836" or "DT9816" (selects the wire protocol in the USB driver), or "audio"
            for an audio interface of `daq.audio` (its model is built from what PortAudio says).
        n_inputs: simultaneous analog input channels.
        n_outputs: analog output channels (0 for a DT9816).
        input_ranges_v: the bipolar full-scale input ranges the board offers, in volts
            (a range r means codes -32768..32767 span -r..+r).
        output_range_v: the bipolar full-scale output range in volts, or None without outputs.
        max_input_rate_hz: the highest per-channel input sample rate, in samples per second.
        max_output_rate_hz: the highest output update rate, in samples per second.
        resolution_bits: converter resolution; codes are always carried as 16-bit integers.
        input_fifo_samples: depth of the on-board input FIFO, in samples (all channels).
        version_id: the value the board's version register reports for this variant, or None
            where it is not public (the DT9816).
    """

    name: str
    family: BoardFamily
    n_inputs: int
    n_outputs: int
    input_ranges_v: tuple[float, ...]
    output_range_v: float | None
    max_input_rate_hz: float
    max_output_rate_hz: float
    resolution_bits: int = 16
    input_fifo_samples: int = 32768
    version_id: int | None = None

    @property
    def has_outputs(self) -> bool:
        return self.n_outputs > 0


def _dt9836(name: str, n_in: int, n_out: int, version_id: int) -> BoardModel:
    return BoardModel(
        name=name,
        family="DT9836",
        n_inputs=n_in,
        n_outputs=n_out,
        input_ranges_v=(10.0, 2.0),
        output_range_v=10.0 if n_out else None,
        max_input_rate_hz=225_000.0,
        max_output_rate_hz=500_000.0 if n_out else 0.0,
        version_id=version_id,
    )


def _dt9816(name: str, max_rate_hz: float) -> BoardModel:
    return BoardModel(
        name=name,
        family="DT9816",
        n_inputs=6,
        n_outputs=0,
        input_ranges_v=(10.0,),
        output_range_v=None,
        max_input_rate_hz=max_rate_hz,
        max_output_rate_hz=0.0,
        input_fifo_samples=16384,
    )


BOARD_MODELS: dict[str, BoardModel] = {
    m.name: m
    for m in (
        _dt9836("DT9836-12-2", 12, 2, 0x04),
        _dt9836("DT9836-12-0", 12, 0, 0x05),
        _dt9836("DT9836-6-2", 6, 2, 0x06),
        _dt9836("DT9836-6-0", 6, 0, 0x07),
        _dt9836("DT9836-6-4", 6, 4, 0x16),
        _dt9816("DT9816", 50_000.0),
        _dt9816("DT9816-A", 150_000.0),
    )
}


def board_model(name: str) -> BoardModel:
    """Look up a board model by its variant name, with an error that lists the known ones."""
    try:
        return BOARD_MODELS[name]
    except KeyError:
        known = ", ".join(sorted(BOARD_MODELS))
        raise ConfigurationError(
            f"unknown board model {name!r}; known models are: {known}"
        ) from None
