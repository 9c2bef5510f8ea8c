"""Run BLAS on one thread where many small or memory-bound calls dominate.

The joint fit's normal equations (a few hundred to about 1,100 unknowns) and CLEAN-SC's
thousands of ~0.1 ms matrix-vector products gain nothing from a second BLAS thread, and on a
loaded 2-core machine an OpenBLAS thread spins waiting for a descheduled partner, which made
a Cholesky factorisation and a zgemv many times slower on 2 threads than on 1
(benchmarks/bench_bundle.py and bench_imaging.py measure the fit and CLEAN-SC).
"""

from __future__ import annotations

import contextlib
import functools

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    """The BLAS libraries of this process, found once (a search of the loaded libraries takes
    about 3 ms, too much to repeat at every call)."""
    import scipy.linalg  # noqa: F401  (loads SciPy's own BLAS, so that it is controlled too)

    return ThreadpoolController()


def single_threaded_blas() -> contextlib.AbstractContextManager:
    """A context in which BLAS uses one thread (restored on exit). Enter it in the calling
    thread before starting worker threads that enter it too: each exit restores the limit
    its entry found."""
    return _controller().limit(limits=1, user_api="blas")
