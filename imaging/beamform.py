"""Frequency-domain delay-and-sum beamforming over any set of scan points.

For a CSM C (M x M) and steering vectors h(x) (see `steering`), the map is

    B(x) = h(x)^H C h(x)                                   (diagonal kept)
    B(x) = M/(M-1) * (h^H C h - sum_m |h_m|^2 C_mm)        (diagonal removed, the default)

The second form drops the autospectra, which hold each microphone's own noise; the factor
M/(M-1) keeps the level of a coherent source (Acoular's `r_diag=True` with its default
normalisation). Without the diagonal the map can go negative away from sources: `beamform`
clips it at 0 like Acoular's `BeamformerBase`, CLEAN-SC works on the unclipped map.

Cost (`HermitianForms`): with C = L L^H (Cholesky), h^H C h = || h conj(L) ||^2, and since L
is lower triangular, column block J = [j0, j1) of h conj(L) needs only h[:, j0:]: three
matrix products doing 2/3 of a full product's work (a triangular product, BLAS trmm, does 1/2
but runs at 3/4 of gemm's speed here and, through scipy, holds the GIL). When C is not
positive definite, the general form Re sum conj(h) (h C^T), one full product. The diagonal
term is a real product with the frequency-independent |h_m|^2. The points are processed in
blocks that stay in cache (steering vectors for every bin, products, norms), on threads
(`parallel`).

Precision (`precision`): "single" (the default) runs the products in complex64 on vectors
whose phases were computed in float64 (see `SteeringModel.vectors_at`), which doubles the BLAS
throughput and halves the memory traffic; the squared norms are summed in float32 and
everything else (Cholesky factor, diagonal term, maps) is float64. Measured on the benchmark
workload (72 mics, 101 x 101 grid, 20 bins at 8 kHz): the maps differ from the float64 ones by
at most 8e-7 of each bin's maximum (about 4e-7 from the steering vectors, the rest from the
complex64 products), and from Acoular's (which evaluates its phases in float32) by 2.0e-6, as
the float64 maps do; the requirement is 1e-5. "double" keeps complex128 throughout (about
1e-15).
"""

from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationInputError

from .csm import CrossSpectra
from .parallel import run_blocks
from .steering import SteeringModel

PRECISIONS = {"single": np.complex64, "double": np.complex128}

TRIANGLE_BLOCKS = 3
"""Column blocks of the Cholesky factor (2/3 of a full product's work; more, smaller
products lose more to BLAS overhead than they save)."""


def complex_dtype(precision: str) -> type:
    """The complex dtype of a precision name ("single" or "double")."""
    try:
        return PRECISIONS[precision]
    except KeyError:
        raise CalibrationInputError(f"precision {precision!r} must be one of {sorted(PRECISIONS)}"
                                    ) from None


def diagonal_norm(n_mics: int, remove_diagonal: bool) -> float:
    """M/(M-1) when the diagonal is removed, else 1."""
    if remove_diagonal and n_mics < 2:
        raise ValueError("diagonal removal needs at least 2 microphones")
    return n_mics / (n_mics - 1) if remove_diagonal else 1.0


class HermitianForms:
    """h^H C_f h for the rows h of a block of steering vectors, for each CSM C_f of a stack.

    Args:
        csm: (F, M, M) Hermitian matrices (any complex dtype; factored in float64).
        precision: "single" (complex64 products, float32 sums) or "double".
    """

    def __init__(self, csm: np.ndarray, precision: str = "single") -> None:
        csm = np.asarray(csm)
        if csm.ndim != 3 or csm.shape[1] != csm.shape[2]:
            raise ValueError(f"CSMs must be a (F, M, M) stack, got shape {csm.shape}")
        self.dtype = complex_dtype(precision)
        self.real = np.float32 if self.dtype == np.complex64 else np.float64
        self.n_mics = csm.shape[1]
        edges = np.linspace(0, self.n_mics, min(TRIANGLE_BLOCKS, self.n_mics) + 1)
        self._edges = [(int(a), int(b)) for a, b in zip(edges[:-1].round(), edges[1:].round(),
                                                         strict=True)]
        self._factors = [self._factor(c) for c in csm]

    def _factor(self, csm: np.ndarray) -> tuple[str, list[np.ndarray]]:
        try:
            lower = np.linalg.cholesky(csm.astype(np.complex128))
        except np.linalg.LinAlgError:
            return "general", [np.ascontiguousarray(csm.T, dtype=self.dtype)]
        conj: np.ndarray = lower.conj().astype(self.dtype)
        return "cholesky", [np.ascontiguousarray(conj[j0:, j0:j1]) for j0, j1 in self._edges]

    def __len__(self) -> int:
        return len(self._factors)

    def work_array(self, n_points: int) -> np.ndarray:
        """Scratch space for `evaluate` on up to n_points rows."""
        return np.empty((n_points, self.n_mics), dtype=self.dtype)

    def evaluate(self, f: int, h: np.ndarray, out: np.ndarray,
                 work: np.ndarray | None = None) -> None:
        """out[g] = h[g]^H C_f h[g] (real) for the rows of h (P, M), of this precision's dtype.

        `work`: scratch from `work_array` (saves an allocation per call).
        """
        kind, factors = self._factors[f]
        p = h.shape[0]
        t = (work if work is not None else self.work_array(p))[:p]
        if kind == "general":
            np.matmul(h, factors[0], out=t)
            np.multiply(t, h.conj(), out=t)
            out[:] = t.real.sum(axis=1)
            return
        for (j0, j1), block in zip(self._edges, factors, strict=True):
            np.matmul(h[:, j0:], block, out=t[:, j0:j1])
        tv: np.ndarray = t.view(self.real)
        out[:] = np.einsum("gk,gk->g", tv, tv)


def _check_shapes(n_csm_channels: int, steering_mics: int) -> None:
    if n_csm_channels != steering_mics:
        raise ValueError(f"the CSM has {n_csm_channels} channels but the steering model "
                         f"{steering_mics} microphones")


def beamform_csm(h: np.ndarray, csm: np.ndarray, remove_diagonal: bool = True,
                 h_power: np.ndarray | None = None, precision: str = "single",
                 workers: int | None = None) -> np.ndarray:
    """Delay-and-sum map (G,) of one CSM (M, M) with steering vectors h (G, M), unclipped.

    Args:
        h_power: |h|^2 (G, M) if already known (it does not depend on frequency); computed
            from h otherwise.
        precision: "single" or "double" (see the module docstring).
        workers: threads (None: all cores).
    """
    csm = np.asarray(csm)
    m = csm.shape[-1]
    if csm.shape != (m, m) or h.ndim != 2 or h.shape[1] != m:
        raise ValueError(f"steering vectors {h.shape} and CSM {csm.shape} do not match: "
                         "expected (G, M) and (M, M)")
    forms = HermitianForms(csm[None], precision)
    values = np.empty(h.shape[0])

    def block(start: int, stop: int) -> None:
        rows: np.ndarray = h[start:stop].astype(forms.dtype, order="C", copy=False)
        forms.evaluate(0, rows, values[start:stop])

    run_blocks(block, h.shape[0], workers)
    if remove_diagonal:
        power = h_power if h_power is not None else h.real**2 + h.imag**2
        values -= power @ np.real(np.diagonal(csm)).astype(np.float64)
        values *= diagonal_norm(m, True)
    return values


def beamform(spectra: CrossSpectra, steering: SteeringModel, remove_diagonal: bool = True,
             clip_negative: bool = True, precision: str = "single",
             workers: int | None = None) -> np.ndarray:
    """Delay-and-sum maps (F, G), one per frequency of `spectra`, on the steering's points.

    Sum the rows for a band map over bins (Acoular's `synthetic`), or beamform a band-summed
    CSM (`CrossSpectra.band_sum`, the paper's way) for one map per band. `precision`: see the
    module docstring ("single": complex64 products on float64 phases, maps within about 8e-7
    of each bin's maximum of the float64 ones). `workers`: threads (None: all cores).
    """
    _check_shapes(spectra.n_channels, steering.n_mics)
    forms = HermitianForms(spectra.csm, precision)
    autospectra = np.real(np.diagonal(spectra.csm, axis1=1, axis2=2)).astype(np.float64)
    norm = diagonal_norm(steering.n_mics, remove_diagonal)
    maps = np.empty((len(forms), steering.n_points))

    def block(start: int, stop: int) -> None:
        model = steering.block(start, stop)
        work = forms.work_array(stop - start)
        values = np.empty(stop - start, dtype=forms.real)
        for i, h in enumerate(model.vectors_at(spectra.freqs_hz, forms.dtype, shared=True)):
            forms.evaluate(i, h, values, work)
            maps[i, start:stop] = values
        if remove_diagonal:
            # All bins at once: |h|^2 does not depend on frequency.
            maps[:, start:stop] -= autospectra @ (model.amplitude**2).T
            maps[:, start:stop] *= norm
        if clip_negative:
            np.maximum(maps[:, start:stop], 0.0, out=maps[:, start:stop])

    run_blocks(block, steering.n_points, workers)
    return maps
