"""Run BLAS on one thread where many small or memory-bound calls dominate.

The joint fit's normal equations (a few hundred to about 1,100 unknowns) and CLEAN-SC's
thousands of ~0.1 ms matrix-vector products gain nothing from a second BLAS thread, and on a
loaded 2-core machine an OpenBLAS thread spins waiting for a descheduled partner: a 500 x 500
Cholesky factorisation took 0.44 s on 2 threads against 0.01 s on 1 (load 7.8), a 3534 x 72
zgemv 0.90 ms against 0.07 ms (load 5.8).
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
