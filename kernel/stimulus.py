"""The test signal the speakers play: maximum-length sequences (MLS).

An MLS has a flat spectrum (but at DC), a crest factor of 0 dB and a two-valued periodic
autocorrelation, which makes its cross-correlation with a recording a clean impulse response.
numpy and scipy.signal are imported where a sequence is made: scipy.signal is most of a
daemon's start-up, which needs none until the first burst, and the orders and lengths are read
by `micam`'s command-line parser, which loads no numpy (tests/micam/test_cli.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final

if TYPE_CHECKING:
    import numpy as np

MIN_MLS_ORDER: Final = 4
"""The shortest sequence micam plays: 15 samples."""
MAX_MLS_ORDER: Final = 20
"""The longest sequence micam plays: 1 048 575 samples (10.9 s at 96 kS/s). Every model and
option of an MLS order takes MIN_MLS_ORDER..MAX_MLS_ORDER (acquisition.contracts.burst)."""


def mls_length(order: int) -> int:
    """Samples in one period of the maximum-length sequence of `order`: 2**order - 1."""
    return 2**order - 1


def mls_burst(order: int) -> np.ndarray:
    """One period of a maximum-length sequence of `mls_length(order)` samples, as +-1.0
    floats."""
    if not MIN_MLS_ORDER <= order <= MAX_MLS_ORDER:
        raise ValueError(f"MLS order {order} is outside {MIN_MLS_ORDER}..{MAX_MLS_ORDER} "
                         "(order 14 is 171 ms at 96 kS/s)")
    import numpy as np
    from scipy.signal import max_len_seq

    seq, _ = max_len_seq(order)
    return 2.0 * seq.astype(np.float64) - 1.0
