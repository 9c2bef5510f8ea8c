"""Frequency-domain delay-and-sum beamforming over any set of scan points.

For a CSM C (M x M) and steering vectors h(x) (see `steering`), the map is

    B(x) = h(x)^H C h(x)                                   (diagonal kept)
    B(x) = M/(M-1) * (h^H C h - sum_m |h_m|^2 C_mm)        (diagonal removed, the default)

The second form drops the autospectra, which hold each microphone's own noise; the factor
M/(M-1) keeps the level of a coherent source (Acoular's `r_diag=True` with its default
normalisation). Without the diagonal the map can go negative away from sources: `beamform`
clips it at 0 like Acoular's `BeamformerBase`, CLEAN-SC works on the unclipped map.

Cost: h^H C h is evaluated for all G points at once as || L^H h ||^2 with C = L L^H (Cholesky),
one triangular matrix product (BLAS ztrmm, G M^2 / 2 complex multiply-adds), or as a general
product h C^T when C is not positive definite. The diagonal term is a real matrix-vector
product with the frequency-independent |h_m|^2.

Precision (`precision`): "single" (the default) runs the triangular product in complex64 on
vectors whose phases were computed in float64 (see `SteeringModel.vectors_at`), which doubles
the BLAS throughput and halves the memory traffic; the squared norms are summed in float32 and
everything else (Cholesky factor, diagonal term, maps) is float64. Measured on the benchmark
workload (72 mics, 101 x 101 grid, 20 bins at 8 kHz): the maps differ from the float64 ones by
at most 8e-7 of each bin's maximum (about 4e-7 from the steering vectors, see
`SteeringModel.vectors_at`, the rest from the complex64 products), and from Acoular's (which
evaluates its phases in float32) by 2.0e-6, as the float64 maps do; the requirement is 1e-5.
Speed: about 2x the complex128 path. "double" keeps complex128 throughout (about 1e-15).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas

from .csm import CrossSpectra
from .steering import SteeringModel

PRECISIONS = {"single": np.complex64, "double": np.complex128}


def complex_dtype(precision: str) -> type:
    """The complex dtype of a precision name ("single" or "double")."""
    try:
        return PRECISIONS[precision]
    except KeyError:
        raise ValueError(f"precision {precision!r} must be one of {sorted(PRECISIONS)}"
                         ) from None


def diagonal_norm(n_mics: int, remove_diagonal: bool) -> float:
    """M/(M-1) when the diagonal is removed, else 1."""
    if remove_diagonal and n_mics < 2:
        raise ValueError("diagonal removal needs at least 2 microphones")
    return n_mics / (n_mics - 1) if remove_diagonal else 1.0


def quadratic_form(h: np.ndarray, csm: np.ndarray, overwrite: bool = False,
                   precision: str = "single") -> np.ndarray:
    """h[g]^H C h[g] for every row g of h (G, M); C Hermitian (M, M). Real float64 (G,).

    The products run in the complex dtype of `precision` (see the module docstring); the
    Cholesky factor is computed in float64 and cast. With overwrite=True a C-contiguous `h`
    of that dtype is used as work space (its content is lost), which saves a copy;
    otherwise `h` is not modified.
    """
    dtype = complex_dtype(precision)
    real = np.float32 if dtype == np.complex64 else np.float64
    try:
        chol = np.linalg.cholesky(np.asarray(csm, dtype=np.complex128)).astype(dtype)
    except np.linalg.LinAlgError:
        hd = h.astype(dtype, copy=False)
        t = hd @ np.asarray(csm).T.astype(dtype)  # t[g, m] = (C h[g])_m
        return np.einsum("gk,gk->g", hd.conj(), t).real.astype(np.float64)
    trmm = blas.get_blas_funcs("trmm", (chol,))
    if h.flags.f_contiguous and not h.flags.c_contiguous:
        # Column-major h is the G x M matrix h: overwrite it with h conj(L) = h (L^T)^H,
        # a right-side product (the faster one for G >> M).
        reuse = overwrite and h.dtype == dtype
        work = h if reuse else np.array(h, dtype=dtype, order="F", copy=True)
        t = trmm(1.0, np.ascontiguousarray(chol.T), work, side=1, lower=0, trans_a=2,
                 overwrite_b=1)
        tv = t.T.view(real)  # (M, 2G), row-major
        sq = np.einsum("mk,mk->k", tv, tv)
        return (sq[0::2] + sq[1::2]).astype(np.float64)
    # Column-major view of a copy of h is h^T: overwrite it with L^H h^T = (h conj(L))^T.
    reuse = overwrite and h.dtype == dtype and h.flags.c_contiguous
    work = h if reuse else np.array(h, dtype=dtype, order="C", copy=True)
    t = trmm(1.0, chol, work.T, side=0, lower=1, trans_a=2, overwrite_b=1)
    tv = t.T.view(real)
    return np.einsum("gk,gk->g", tv, tv).astype(np.float64)


def beamform_csm(h: np.ndarray, csm: np.ndarray, remove_diagonal: bool = True,
                 h_power: np.ndarray | None = None, overwrite: bool = False,
                 precision: str = "single") -> np.ndarray:
    """Delay-and-sum map (G,) of one CSM (M, M) with steering vectors h (G, M), unclipped.

    Args:
        h_power: |h|^2 (G, M) if already known (it does not depend on frequency); computed
            from h otherwise.
        overwrite: h may be used as work space (see `quadratic_form`).
        precision: "single" or "double" (see the module docstring).
    """
    csm = np.asarray(csm)
    m = csm.shape[-1]
    if csm.shape != (m, m) or h.ndim != 2 or h.shape[1] != m:
        raise ValueError(f"steering vectors {h.shape} and CSM {csm.shape} do not match: "
                         "expected (G, M) and (M, M)")
    power = h_power if h_power is not None or not remove_diagonal else h.real**2 + h.imag**2
    b = quadratic_form(h, csm, overwrite, precision)
    if remove_diagonal:
        b -= power @ np.real(np.diagonal(csm)).astype(power.dtype)
        b *= diagonal_norm(m, True)
    return b


def beamform(spectra: CrossSpectra, steering: SteeringModel, remove_diagonal: bool = True,
             clip_negative: bool = True, precision: str = "single") -> np.ndarray:
    """Delay-and-sum maps (F, G), one per frequency of `spectra`, on the steering's points.

    Sum the rows for a band map over bins (Acoular's `synthetic`), or beamform a band-summed
    CSM (`CrossSpectra.band_sum`, the paper's way) for one map per band. `precision`: see the
    module docstring ("single": complex64 products on float64 phases, maps within about 8e-7
    of each bin's maximum of the float64 ones).
    """
    if spectra.n_channels != steering.n_mics:
        raise ValueError(f"the CSM has {spectra.n_channels} channels but the steering model "
                         f"{steering.n_mics} microphones")
    dtype = complex_dtype(precision)
    maps = np.empty((spectra.freqs_hz.size, steering.n_points))
    # in the steering's layout (column-major, see `steering._distances`)
    work = np.empty_like(steering.path_difference, dtype=dtype)
    for i, h in enumerate(steering.vectors_at(spectra.freqs_hz, dtype, out=work)):
        maps[i] = quadratic_form(h, spectra.csm[i], overwrite=True, precision=precision)
    if remove_diagonal:
        # The diagonal terms of all bins in one product: |h|^2 does not depend on frequency.
        autospectra = np.real(np.diagonal(spectra.csm, axis1=1, axis2=2))  # (F, M)
        maps -= autospectra @ (steering.amplitude**2).T
        maps *= diagonal_norm(steering.n_mics, True)
    if clip_negative:
        np.maximum(maps, 0.0, out=maps)
    return maps
