"""Per-microphone complex responses and the CSM correction of paper section VI (Dougherty's
eigenvalue calibration).

A channel m records H_m(f) times what an ideal microphone at its position would record (the
gain and phase of its capsule, preamplifier and converter). With recorded spectra
p_m = H_m p_m^ideal the cross-spectral matrix is C_mn = H_m conj(H_n) C_mn^ideal, so the
correction, at every frequency, is

    C_mn <- C_mn / (H_m conj(H_n))                                        (`correct_csm`)

H has two sources, both `ChannelResponses` and both applied by `correct_csm`:

- the calibration result: result.json's optional "microphone_responses",
  {"frequencies_hz": [...], "microphones": [{"id", "gain": [...], "phase_rad": [...]}]}
  (`responses_from_document`), gains linear relative to the array's median;
- Dougherty's eigenvalue calibration (`eigen_calibration`), from a recording of one dominant
  source at a known position x_s. Its CSM is rank one plus uncorrelated channel noise,
  C = s (H o a)(H o a)^H + N, with a_m = exp(-i k (r_m - r_0 + c tau_m)) / r_m the ideal
  transfer from x_s (the steering model's phase convention, board latencies tau included).
  The principal eigenvector v of C is H o a up to one complex factor, so H_m = v_m / a_m. The
  noise N lies on the diagonal; it is removed by replacing the diagonal with that of the
  rank-one approximation and taking the eigenvector again (a few rounds), so that channels
  with different noise levels do not bias v. The factor is fixed by a gauge: gains relative
  to their root mean square, phases relative to their circular mean (a common factor only
  scales the map; this one keeps the array's total power). H is estimated in every DFT bin
  and averaged over the bins of each band.

Between the frequencies of a `ChannelResponses` the gain and the unwrapped phase are
interpolated linearly; beyond its first and last frequency the end values hold.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibration.errors import CalibrationInputError

from .csm import CrossSpectra, band_edges

MAX_RESPONSE_FREQUENCIES = 100_000
"""Bound on the frequencies of a response read from a file (untrusted input)."""

DIAGONAL_ROUNDS = 8
"""Rounds of diagonal reconstruction in the eigenvalue calibration."""

POWER_STEPS = 4
"""Power-iteration steps per round of diagonal reconstruction."""

MIN_DOMINANCE = 0.95
"""The rank-one part must explain at least this fraction of a band's off-diagonal CSM energy
for the recording to count as one dominant source: a second, uncorrelated source of more than
about a quarter of the first's power (-6 dB) is refused. A simulated single-speaker recording
gives 0.99999."""


@dataclass(frozen=True)
class ChannelResponses:
    """Complex responses H (K, M) of M channels at K increasing frequencies.

    Attributes:
        frequencies_hz: (K,) increasing frequencies, hertz (K = 1: constant over frequency).
        responses: (K, M) complex, H_m(f_k), relative to an ideal microphone.
        source: where they come from, for reports ("result.json", "eigenvalue calibration
            from pose/0000 speaker 4", ...).
    """

    frequencies_hz: np.ndarray
    responses: np.ndarray
    source: str

    def __post_init__(self) -> None:
        f = np.asarray(self.frequencies_hz, dtype=np.float64)
        h = np.asarray(self.responses, dtype=np.complex128)
        if f.ndim != 1 or f.size == 0 or h.shape != (f.size, h.shape[-1]) or h.ndim != 2:
            raise ValueError(f"responses {h.shape} must be (K, M) for K = {f.size} frequencies")
        if np.any(~np.isfinite(f)) or np.any(np.diff(f) <= 0):
            raise ValueError("response frequencies must be finite and strictly increasing")
        if np.any(~np.isfinite(h)) or np.any(h == 0):
            raise ValueError("responses must be finite and non-zero")
        object.__setattr__(self, "frequencies_hz", f)
        object.__setattr__(self, "responses", h)

    @property
    def n_channels(self) -> int:
        return int(self.responses.shape[1])

    def at(self, freqs_hz: np.ndarray) -> np.ndarray:
        """H (F, M) at the frequencies `freqs_hz`: gain and unwrapped phase interpolated
        linearly, held constant beyond the end frequencies."""
        freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=np.float64))
        gain = np.abs(self.responses)
        phase = np.unwrap(np.angle(self.responses), axis=0)
        out = np.empty((freqs.size, self.n_channels), dtype=np.complex128)
        for m in range(self.n_channels):
            g = np.interp(freqs, self.frequencies_hz, gain[:, m])
            p = np.interp(freqs, self.frequencies_hz, phase[:, m])
            out[:, m] = g * np.exp(1j * p)
        return out

    def phase_deg(self) -> np.ndarray:
        """(K, M) phases in degrees, wrapped to (-180, 180]."""
        return np.degrees(np.angle(self.responses))


def _scale_channels(spectra: CrossSpectra, factors: np.ndarray) -> CrossSpectra:
    """The spectra with C_mn multiplied by factors_m conj(factors_n), factors (F, M)."""
    if factors.shape != (spectra.csm.shape[0], spectra.n_channels):
        raise ValueError(f"{factors.shape[1]} channel responses for a CSM of "
                         f"{spectra.n_channels} channels")
    scale = factors[:, :, None] * factors.conj()[:, None, :]
    return replace(spectra, csm=spectra.csm * scale)


def correct_csm(spectra: CrossSpectra, responses: ChannelResponses) -> CrossSpectra:
    """The spectra corrected for the channels' responses: C_mn / (H_m conj(H_n)) at each
    matrix's frequency. Apply it to DFT-bin matrices before summing them into bands."""
    return _scale_channels(spectra, 1.0 / responses.at(spectra.freqs_hz))


def apply_responses(spectra: CrossSpectra, responses: ChannelResponses) -> CrossSpectra:
    """The forward model of `correct_csm`: C_mn H_m conj(H_n), what channels with these
    responses would have recorded (used to simulate microphone errors)."""
    return _scale_channels(spectra, responses.at(spectra.freqs_hz))


def simulated_phase_error(n_channels: int, std_deg: float, seed: int = 0) -> ChannelResponses:
    """A per-channel phase error, normal with standard deviation std_deg degrees, constant
    over frequency, for `apply_responses`: a controlled error of a chosen size, applied in the
    evaluation (the simulated world's own capsule responses, `micam simulate --effect
    mic-responses`, are delays and resonances of fixed spread)."""
    if not 0.0 <= std_deg <= 90.0:
        raise CalibrationInputError(f"a phase error of {std_deg} degrees must lie in 0-90")
    phase = np.radians(std_deg) * np.random.default_rng([seed, 17]).standard_normal(n_channels)
    return ChannelResponses(np.array([1.0]), np.exp(1j * phase)[None, :],
                            f"simulated phase error {std_deg:g} deg (seed {seed})")


def _gauge(h: np.ndarray) -> np.ndarray:
    """Responses (..., M) with gains relative to their root mean square and phases relative to
    their circular mean (the corrected CSM keeps the array's total power, so a map's level
    changes only by the coherence the correction restores)."""
    unit = h / np.abs(h)
    mean = unit.mean(axis=-1, keepdims=True)
    h = h * (mean.conj() / np.abs(mean))
    return h / np.sqrt(np.mean(np.abs(h) ** 2, axis=-1, keepdims=True))


def principal_vectors(csm: np.ndarray, rounds: int = DIAGONAL_ROUNDS,
                      power_steps: int = POWER_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """The principal eigenvector (F, M) of each matrix of csm (F, M, M), its diagonal
    reconstructed from the rank-one approximation (see the module docstring), and the
    fraction (F,) of the off-diagonal energy (squared Frobenius norm) that the rank-one part
    explains (1 for one source; about 1 / (1 + r^2) for a second one r times as strong).

    Power iteration, started from the strongest column: one dominant source puts the second
    eigenvalue orders of magnitude below the first, so a few steps per round converge.
    """
    csm = np.asarray(csm, dtype=np.complex128)
    idx = np.arange(csm.shape[-1])
    off = csm.copy()
    off[..., idx, idx] = 0.0
    work = csm.copy()
    strongest = np.argmax(np.real(np.diagonal(csm, axis1=-2, axis2=-1)), axis=-1)
    v = np.take_along_axis(csm, strongest[:, None, None], axis=2)[..., 0]
    value = np.zeros(csm.shape[0])
    for _ in range(rounds):
        for _ in range(power_steps):
            v = np.einsum("fmn,fn->fm", work, v)
            v /= np.linalg.norm(v, axis=-1, keepdims=True)
        value = np.real(np.einsum("fm,fmn,fn->f", v.conj(), work, v))
        work[..., idx, idx] = value[:, None] * np.abs(v) ** 2
    model = value[:, None, None] * v[:, :, None] * v.conj()[:, None, :]
    model[..., idx, idx] = 0.0
    energy = np.sum(np.abs(off) ** 2, axis=(1, 2))
    explained = 1.0 - np.sum(np.abs(off - model) ** 2, axis=(1, 2)) / np.maximum(energy, 1e-300)
    return v, explained


def eigen_calibration(spectra: CrossSpectra, transfer: np.ndarray, band_centres_hz: np.ndarray,
                      fraction: int, source: str) -> ChannelResponses:
    """Dougherty's eigenvalue calibration (module docstring): responses per band.

    Args:
        spectra: DFT-bin CSMs (F, M, M) of one recording of one dominant source.
        transfer: (F, M) the ideal transfer a_m of that source at each bin (any real scale).
        band_centres_hz: centres of the bands to estimate (each needs a bin of `spectra`).
        fraction: bands are 1/fraction octave wide.
        source: description for `ChannelResponses.source`.

    Raises ValueError when a band has no bin, or when its CSM is not dominated by one source
    (the rank-one part below `MIN_DOMINANCE` of its power): such a recording would calibrate
    the array to a mixture and mislead every map made with it.
    """
    if transfer.shape != spectra.csm.shape[:2]:
        raise ValueError(f"transfer {transfer.shape} does not match spectra "
                         f"{spectra.csm.shape[:2]}")
    vectors, dominance = principal_vectors(spectra.csm)
    per_bin = _gauge(vectors / transfer)
    bands = []
    for centre in np.asarray(band_centres_hz, dtype=np.float64):
        lo, hi = band_edges(centre, fraction)
        inside = (spectra.freqs_hz >= lo) & (spectra.freqs_hz < hi)
        if not np.any(inside):
            raise CalibrationInputError(f"no bin of the calibration recording lies in the band "
                                        f"{lo:.0f}-{hi:.0f} Hz")
        share = float(np.median(dominance[inside]))
        if share < MIN_DOMINANCE:
            raise CalibrationInputError(
                f"{source}: the band at {centre:.0f} Hz is not dominated by one source (one "
                f"source explains {100 * share:.0f} % of its cross-spectra, at least "
                f"{100 * MIN_DOMINANCE:.0f} % needed); calibrate from a recording of a "
                "single speaker with a good signal-to-noise ratio")
        bands.append(per_bin[inside].mean(axis=0))
    return ChannelResponses(np.asarray(band_centres_hz, dtype=np.float64),
                            _gauge(np.array(bands)), source)


def responses_from_document(doc: dict, mic_ids: tuple[int, ...], source: str
                            ) -> ChannelResponses | None:
    """The "microphone_responses" of a result.json document in the order of `mic_ids`, or None
    when it has none. Raises ValueError naming what is wrong (the document is untrusted)."""
    block = doc.get("microphone_responses")
    if block is None:
        return None
    try:
        freqs = np.asarray(block["frequencies_hz"], dtype=np.float64)
        if freqs.ndim != 1 or not 1 <= freqs.size <= MAX_RESPONSE_FREQUENCIES:
            raise ValueError(f"frequencies_hz must list 1-{MAX_RESPONSE_FREQUENCIES} values")
        by_id: dict[int, np.ndarray] = {}
        for mic in block["microphones"]:
            gain = np.asarray(mic["gain"], dtype=np.float64)
            phase = np.asarray(mic["phase_rad"], dtype=np.float64)
            if gain.shape != freqs.shape or phase.shape != freqs.shape:
                raise ValueError(f"microphone {mic['id']}: gain and phase_rad need one value "
                                 f"per frequency ({freqs.size})")
            if np.any(~(gain > 0)) or np.any(~np.isfinite(gain)):
                raise ValueError(f"microphone {mic['id']}: gains must be positive and finite")
            if int(mic["id"]) in by_id:
                raise ValueError(f"microphone {mic['id']} is listed twice")
            by_id[int(mic["id"])] = gain * np.exp(1j * phase)
        missing = [m for m in mic_ids if m not in by_id]
        if missing:
            raise ValueError(f"no response for microphones {missing[:10]}")
        return ChannelResponses(freqs, np.column_stack([by_id[m] for m in mic_ids]),
                                f"microphone_responses of {source}")
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationInputError(f"{source}: its microphone_responses cannot be used: "
                                    f"{exc}; see docs/imaging.md for the format") from None
