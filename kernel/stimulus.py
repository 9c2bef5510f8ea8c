"""The test signal the speakers play: maximum-length sequences (MLS).

An MLS has a flat spectrum (but at DC), a crest factor of 0 dB and a two-valued periodic
autocorrelation, which makes its cross-correlation with a recording a clean impulse response.
scipy.signal is imported where a sequence is made: it is most of a daemon's start-up, which
needs none until the first burst.
"""

from __future__ import annotations

import numpy as np


def mls_length(order: int) -> int:
    """Samples in one period of the maximum-length sequence of `order`: 2**order - 1."""
    return 2**order - 1


def mls_burst(order: int) -> np.ndarray:
    """One period of a maximum-length sequence of `mls_length(order)` samples, as +-1.0
    floats."""
    if not 4 <= order <= 20:
        raise ValueError(f"MLS order {order} is outside 4..20 (order 14 is 171 ms at 96 kS/s)")
    from scipy.signal import max_len_seq

    seq, _ = max_len_seq(order)
    return 2.0 * seq.astype(np.float64) - 1.0
