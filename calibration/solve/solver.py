"""Microphone positions from times of flight: the paper's equation (15), solved properly.

Model, for source s (camera-0 frame position S_s) and microphone m (position X_m):

    tau_ms = |X_m - S_s| / c + delta_b(m) + noise,     noise ~ N(0, sigma_ms^2)

with the speed of sound c, the latency delta_b of the board b(m) recording microphone m (or
one common latency, or none). `solve_microphones` minimises sum ((model - tau) / sigma)^2 as
sparse nonlinear least squares (scipy.optimize.least_squares, 'trf', analytic sparse
Jacobian, robust loss) over the microphone positions, c, the latencies, and optionally

- one small rigid correction per rig pose (6 parameters: the OpenCV rotation vector and
  translation of the board pose) with a prior from the camera's pose covariance: camera pose
  errors move the six speakers of a pose rigidly, and the TOFs of 72 microphones can pull
  them back;
- a prior geometry (CAD, paper section IV-H): X_m = R(Omega) P_m + T (+ small deviations d_m
  with a prior sigma), which regularises the problem at small source counts.

The start is a closed-form multilateration per microphone (calibration.solve.multilateration), with
the camera-side rule for coplanar sources, then a robust fit, outlier rejection and a final
least-squares fit on the inliers whose Jacobian gives the covariance.

The paper's own solver (section IV-I, after Dobler: a derivative-free coordinate search from
zero coordinates) is calibration.solve.paper_method, kept as a baseline; the SO(3) helpers are
kernel.rigid's, the robust scale and normal-matrix inverse calibration.solve.robust's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import OptimizeResult, least_squares
from scipy.spatial.transform import Rotation

from kernel.air import NOMINAL_SPEED_OF_SOUND_M_S
from kernel.rigid import RigidTransform, kabsch, rotated_point_jacobian

from ..choices import DEFAULT_LATENCY, LatencyModel
from ..errors import CalibrationInputError
from .multilateration import multilaterate
from .robust import inverse_normal, robust_sigma

# --------------------------------------------------------------------------------------
# Inputs and outputs
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RigSources:
    """Sources given as rig poses: S = R(rotvec_p) B_k + t_p (paper equation 10).

    Attributes:
        rig_points_m: (n_speakers, 3) speaker positions in the rig frame (paper Table I).
        rotvec: (n_pose, 3) rig-to-camera-0 rotation vectors (OpenCV rvec), radians.
        translation_m: (n_pose, 3) rig-to-camera-0 translations (OpenCV tvec), metres.
        pose_of_source: (n_src,) pose index of each source (row of the TOF matrix).
        speaker_of_source: (n_src,) speaker index of each source.
        pose_covariance: (n_pose, 6, 6) covariance of (rotvec, translation) per pose from the
            camera (solvePnP); required to refine the poses, which it weights.
    """

    rig_points_m: np.ndarray
    rotvec: np.ndarray
    translation_m: np.ndarray
    pose_of_source: np.ndarray
    speaker_of_source: np.ndarray
    pose_covariance: np.ndarray | None = None

    def positions(self, corrections: np.ndarray | None = None) -> np.ndarray:
        """(n_src, 3) source positions, optionally with (n_pose, 6) pose corrections added."""
        rotvec, trans = self.rotvec, self.translation_m
        if corrections is not None:
            rotvec, trans = rotvec + corrections[:, :3], trans + corrections[:, 3:]
        R = Rotation.from_rotvec(rotvec).as_matrix()[self.pose_of_source]
        points = self.rig_points_m[self.speaker_of_source]
        return np.einsum("sij,sj->si", R, points) + trans[self.pose_of_source]


@dataclass(frozen=True)
class PriorGeometry:
    """A known array geometry in its own frame (CAD or an earlier calibration).

    Attributes:
        positions_m: (n_mic, 3) microphone positions in the array's own frame.
        deviation_std_m: prior standard deviation of each microphone's deviation from the
            geometry; None keeps the geometry rigid (6 unknowns for the whole array).
    """

    positions_m: np.ndarray
    deviation_std_m: float | None = None


@dataclass(frozen=True)
class SolverOptions:
    """Options of `solve_microphones`.

    Attributes:
        speed_of_sound_m_s: the start value of c, or its value when not fitted (e.g. from
            `calibration.acoustic.speed_of_sound.fit_speed_of_sound`).
        fit_speed_of_sound: make c an unknown (shared by all microphones, it costs little).
        latency: "per_board" (the default, `calibration.choices.DEFAULT_LATENCY`), "common"
            (one delta for all channels) or "none".
        reference_board: with "per_board", the board whose latency is fixed at 0 (the one
            recording the reference microphone: delays are measured against it). None fits
            every board's latency.
        refine_poses: fit one rigid correction per rig pose (needs RigSources with
            pose_covariance).
        source_std_m: refine every source position too, with this isotropic per-axis prior
            std (scalar or (n_src,)), as the paper's step 5 does. Source errors are shared by
            all microphones; held fixed they leak into c and the latency (about 2x the bound
            with 0.5 mm noise when both are fitted), refined they do not.
        speed_of_sound_prior_std_m_s: prior std of a fitted c around speed_of_sound_m_s (1 m/s
            ~ a thermometer good to 1.5 K); None for none. With one rig pose, c, a latency and
            the array's range are not separable and the priors keep the fit from diverging;
            with many poses the data dominate (sigma_c ~ 0.1 m/s at 96 sources).
        latency_prior_std_s: prior std of every fitted latency around 0; None for none.
        loss: robust loss of scipy.optimize.least_squares for the first fit.
        f_scale: the loss's soft threshold, in units of the robust residual scale at the
            start (so that sigmas that are right only up to a factor still work).
        outlier_threshold: residuals beyond this many robust residual scales after the robust
            fit are outliers: excluded from the final least-squares fit and the covariance.
        camera_center_m: a point on the microphones' side of every rig plane (the camera);
            used by the mirror rule of `multilaterate`.
        planar_tolerance_m: sources whose RMS distance from their best-fit plane is below
            this are treated as coplanar by `multilaterate`.
        max_nfev: evaluation limit of each least-squares stage.
    """

    speed_of_sound_m_s: float = NOMINAL_SPEED_OF_SOUND_M_S
    fit_speed_of_sound: bool = True
    latency: LatencyModel = DEFAULT_LATENCY
    reference_board: int | None = 0
    refine_poses: bool = False
    source_std_m: float | np.ndarray | None = None
    speed_of_sound_prior_std_m_s: float | None = 1.0
    latency_prior_std_s: float | None = 1e-5
    loss: str = "soft_l1"
    f_scale: float = 3.0
    outlier_threshold: float = 5.0
    camera_center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    planar_tolerance_m: float = 0.01
    max_nfev: int = 100


@dataclass(frozen=True)
class MicrophoneSolution:
    """Result of a solver.

    Attributes:
        positions_m: (n_mic, 3) microphone positions in the camera-0 frame (NaN if a
            microphone has too few measurements).
        covariance_m2: (n_mic, 3, 3) position covariance from the final Jacobian, scaled by
            the residual variance (NaN for the paper method).
        speed_of_sound_m_s, speed_of_sound_std_m_s: c and its standard error (0 if fixed).
        latency_s, latency_std_s: (n_board,) latency of each board (all equal for a common
            latency; 0 where fixed).
        pose_corrections: (n_pose, 6) fitted (rotvec, translation) corrections, or None.
        pose_correction_std: (n_pose, 6) their standard errors, or None.
        residuals_s: (n_src, n_mic) measured minus modelled TOF, NaN where missing.
        outliers: (n_src, n_mic) measurements rejected as outliers.
        sigma_scale: factor applied to the given sigmas to match the residual scatter (robust).
        chi2_per_dof: of the final fit, in the rescaled sigmas (about 1 if the model fits).
        nfev: function evaluations in all stages.
    """

    positions_m: np.ndarray
    covariance_m2: np.ndarray
    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    latency_s: np.ndarray
    latency_std_s: np.ndarray
    pose_corrections: np.ndarray | None
    pose_correction_std: np.ndarray | None
    residuals_s: np.ndarray
    outliers: np.ndarray
    sigma_scale: float
    chi2_per_dof: float
    nfev: int = 0

    @property
    def std_m(self) -> np.ndarray:
        """(n_mic, 3) standard deviation of each coordinate."""
        return np.sqrt(np.diagonal(self.covariance_m2, axis1=1, axis2=2))


# --------------------------------------------------------------------------------------
# The least-squares model
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Structure:
    """What is unknown, shared by the model and its row subsets."""

    sources: np.ndarray | RigSources
    n_mic: int
    n_latency: int
    fit_c: bool
    c_fixed: float
    prior: PriorGeometry | None
    refine_poses: bool
    source_std_m: np.ndarray | None  # (n_src,) prior std of per-source refinements, or None
    c_prior_std: float | None  # prior std of c around c_fixed, or None
    latency_prior_std: float | None  # prior std of every latency around 0, or None


_GROUPS = ("mic", "dev", "c", "lat", "pose", "src")


class _Model:
    """Parameter layout, residuals and analytic sparse Jacobian of equation (15).

    Parameter groups, in order: microphones ("mic": 3 per microphone, or the 6 of the prior
    geometry's rigid transform), prior-geometry deviations ("dev", 3 per microphone), c,
    latencies, pose corrections ("pose", 6 per pose) and source refinements ("src", 3 per
    source). Residual rows: one per used measurement, (model - tau) / sigma, then one whitened
    prior row per parameter of the groups that have a prior (dev, pose, src).
    """

    def __init__(
        self, structure: _Structure, tau: np.ndarray, sigma: np.ndarray, src: np.ndarray,
        mic: np.ndarray, latency_col: np.ndarray,
    ) -> None:  # fmt: skip
        self.s = structure
        self.tau, self.sigma, self.src, self.mic, self.latency_col = (
            tau,
            sigma,
            src,
            mic,
            latency_col,
        )
        st = structure
        rig = st.sources if isinstance(st.sources, RigSources) else None
        n_pose = rig.rotvec.shape[0] if st.refine_poses and rig is not None else 0
        n_src_refined = st.source_std_m.size if st.source_std_m is not None else 0
        deviation_std = st.prior.deviation_std_m if st.prior is not None else None
        deviations = deviation_std is not None
        sizes = {
            "mic": 6 if st.prior is not None else 3 * st.n_mic,
            "dev": 3 * st.n_mic if deviations else 0,
            "c": 1 if st.fit_c else 0,
            "lat": st.n_latency,
            "pose": 6 * n_pose,
            "src": 3 * n_src_refined,
        }
        starts = np.cumsum([0, *sizes.values()])[:-1].tolist()
        self.offsets = dict(zip(_GROUPS, starts, strict=True))
        self.n_params = int(sum(sizes.values()))
        self.sizes = sizes
        # Whitening matrices (n_group, k, k) and means of the groups with a prior.
        self.whitening: dict[str, np.ndarray] = {}
        self.prior_mean: dict[str, float] = {"c": st.c_fixed}
        if st.fit_c and st.c_prior_std is not None:
            self.whitening["c"] = np.full((1, 1, 1), 1.0 / st.c_prior_std)
        if st.n_latency and st.latency_prior_std is not None:
            self.whitening["lat"] = np.full((st.n_latency, 1, 1), 1.0 / st.latency_prior_std)
        if deviation_std is not None:
            self.whitening["dev"] = np.broadcast_to(np.eye(3) / deviation_std, (st.n_mic, 3, 3))
        if n_pose:
            if rig is None or rig.pose_covariance is None:
                raise ValueError("refining the poses needs their covariance "
                                 "(RigSources.pose_covariance)")
            self.whitening["pose"] = np.linalg.inv(np.linalg.cholesky(rig.pose_covariance))
        if st.source_std_m is not None and n_src_refined:
            self.whitening["src"] = np.eye(3) / st.source_std_m[:, None, None]

    def part(self, name: str, x: np.ndarray) -> np.ndarray:
        """The slice of x holding parameter group `name`."""
        return x[self.offsets[name] : self.offsets[name] + self.sizes[name]]

    def speed(self, x: np.ndarray) -> float:
        return float(self.part("c", x)[0]) if self.s.fit_c else self.s.c_fixed

    def latencies(self, x: np.ndarray) -> np.ndarray:
        """(n_latency + 1,) with a trailing 0 for rows without a latency column (-1)."""
        return np.append(self.part("lat", x), 0.0)

    def pose_corrections(self, x: np.ndarray) -> np.ndarray | None:
        return self.part("pose", x).reshape(-1, 6) if self.sizes["pose"] else None

    def mic_positions(
        self, x: np.ndarray
    ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """(n_mic, 3) positions and their Jacobian blocks [(cols (n_mic, w), d (n_mic, 3, w))]."""
        n_mic = self.s.n_mic
        eye = np.broadcast_to(np.eye(3), (n_mic, 3, 3))
        own = 3 * np.arange(n_mic)[:, None] + np.arange(3)
        if self.s.prior is None:
            return self.part("mic", x).reshape(-1, 3), [(self.offsets["mic"] + own, eye)]
        omega, trans = self.part("mic", x)[:3], self.part("mic", x)[3:]
        geometry = self.s.prior.positions_m
        positions = RigidTransform.from_rotvec(omega, trans).apply(geometry)
        rot_block = rotated_point_jacobian(np.broadcast_to(omega, geometry.shape), geometry)
        rigid_cols = np.broadcast_to(self.offsets["mic"] + np.arange(6), (n_mic, 6))
        blocks = [(rigid_cols, np.concatenate([rot_block, eye], axis=2))]
        if self.sizes["dev"]:
            positions = positions + self.part("dev", x).reshape(-1, 3)
            blocks.append((self.offsets["dev"] + own, eye))
        return positions, blocks

    def source_positions(
        self, x: np.ndarray
    ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """(n_src, 3) positions and their Jacobian blocks, as `mic_positions`."""
        sources = self.s.sources
        blocks: list[tuple[np.ndarray, np.ndarray]] = []
        if not isinstance(sources, RigSources):
            positions = np.asarray(sources, dtype=float)
        else:
            corr = self.pose_corrections(x)
            positions = sources.positions(corr)
            if corr is not None:
                pose = sources.pose_of_source
                rotvec = (sources.rotvec + corr[:, :3])[pose]
                d_rot = rotated_point_jacobian(
                    rotvec, sources.rig_points_m[sources.speaker_of_source]
                )
                d_src = np.concatenate([d_rot, np.broadcast_to(np.eye(3), d_rot.shape)], axis=2)
                blocks.append((self.offsets["pose"] + 6 * pose[:, None] + np.arange(6), d_src))
        if self.sizes["src"]:
            n_src = positions.shape[0]
            positions = positions + self.part("src", x).reshape(-1, 3)
            cols = self.offsets["src"] + 3 * np.arange(n_src)[:, None] + np.arange(3)
            blocks.append((cols, np.broadcast_to(np.eye(3), (n_src, 3, 3))))
        return positions, blocks

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self._evaluate(x, jacobian=False)[0]

    def jacobian(self, x: np.ndarray) -> sparse.csr_matrix:
        return self._evaluate(x, jacobian=True)[1]

    def _evaluate(
        self, x: np.ndarray, jacobian: bool
    ) -> tuple[np.ndarray, sparse.csr_matrix | None]:
        X, mic_blocks = self.mic_positions(x)
        S, src_blocks = self.source_positions(x)
        c = self.speed(x)
        diff = X[self.mic] - S[self.src]
        dist = np.linalg.norm(diff, axis=1)
        measured = (dist / c + self.latencies(x)[self.latency_col] - self.tau) / self.sigma
        priors = [
            np.einsum("gij,gj->gi", w, self.part(name, x).reshape(w.shape[0], -1)
                      - self.prior_mean.get(name, 0.0)).ravel()
            for name, w in self.whitening.items()
        ]  # fmt: skip
        residual = np.concatenate([measured, *priors])
        if not jacobian:
            return residual, None

        rows_idx = np.arange(self.tau.size)
        grad = diff / (dist * c * self.sigma)[:, None]  # d r / d X_m
        rows, cols, vals = [], [], []
        for index, blocks, sign in ((self.mic, mic_blocks, 1.0), (self.src, src_blocks, -1.0)):
            for block_cols, block_d in blocks:
                rows.append(np.repeat(rows_idx, block_cols.shape[1]))
                cols.append(block_cols[index].ravel())
                vals.append(sign * np.einsum("ri,riw->rw", grad, block_d[index]).ravel())
        if self.s.fit_c:
            rows.append(rows_idx)
            cols.append(np.full(rows_idx.size, self.offsets["c"]))
            vals.append(-dist / (c**2 * self.sigma))
        has_lat = self.latency_col >= 0
        rows.append(rows_idx[has_lat])
        cols.append(self.offsets["lat"] + self.latency_col[has_lat])
        vals.append(1.0 / self.sigma[has_lat])
        start = self.tau.size
        for name, w in self.whitening.items():
            n_group, k = w.shape[:2]
            local = k * np.arange(n_group)[:, None, None]
            rows.append(np.broadcast_to(start + local + np.arange(k)[:, None], w.shape).ravel())
            cols.append(np.broadcast_to(self.offsets[name] + local + np.arange(k), w.shape).ravel())
            vals.append(np.asarray(w).ravel())
            start += n_group * k
        jac = sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(residual.size, self.n_params),
        )
        return residual, jac

    def subset(self, rows: np.ndarray, sigma_factor: float = 1.0) -> _Model:
        """The model restricted to some measurement rows, sigmas multiplied by a factor."""
        return _Model(self.s, self.tau[rows], self.sigma[rows] * sigma_factor, self.src[rows],
                      self.mic[rows], self.latency_col[rows])  # fmt: skip


# --------------------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------------------


def solve_microphones(
    sources: np.ndarray | RigSources,
    tof_s: np.ndarray,
    tof_std_s: float | np.ndarray,
    board_of_mic: np.ndarray | None = None,
    options: SolverOptions | None = None,
    prior_geometry: PriorGeometry | None = None,
) -> MicrophoneSolution:
    """Microphone positions (camera-0 frame), c and latencies from times of flight.

    Args:
        sources: (n_src, 3) source positions in the camera-0 frame (held fixed), or
            RigSources (positions from rig poses; needed to refine the poses).
        tof_s: (n_src, n_mic) times of flight, NaN where missing.
        tof_std_s: scalar or (n_src, n_mic) standard deviations (e.g. TofEstimate.std_s,
            plus any model-error floor). Only their ratios matter unless poses or a prior
            geometry are refined: the overall scale is re-estimated robustly.
        board_of_mic: (n_mic,) board index per microphone for per-board latencies.
        options: SolverOptions.
        prior_geometry: optional PriorGeometry (paper IV-H parametrisation).

    Stages: closed-form start (`multilaterate` with c and no latency), a robust fit with the
    sigmas rescaled to the start's robust residual scale, outlier rejection at
    `outlier_threshold` robust sigmas, and a plain least-squares fit on the inliers whose
    Jacobian gives the covariance, (J^T J)^-1 times the chi^2 per degree of freedom.
    """
    options = options or SolverOptions()
    tof = np.asarray(tof_s, dtype=float)
    n_src, n_mic = tof.shape
    sigma = np.broadcast_to(np.asarray(tof_std_s, dtype=float), tof.shape)
    board = np.zeros(n_mic, dtype=int) if board_of_mic is None else np.asarray(board_of_mic)
    if options.refine_poses and (
        not isinstance(sources, RigSources) or sources.pose_covariance is None
    ):
        raise ValueError("refine_poses needs RigSources with pose_covariance")
    camera_positions = sources.positions() if isinstance(sources, RigSources) else sources

    start = multilaterate(
        camera_positions,
        options.speed_of_sound_m_s * tof,
        camera_center_m=options.camera_center_m,
        planar_tolerance_m=options.planar_tolerance_m,
    )
    if prior_geometry is None:
        solved = np.flatnonzero(np.all(np.isfinite(start), axis=1))
    else:
        solved = np.arange(n_mic)
    valid = np.isfinite(tof) & (sigma > 0)
    valid[:, np.setdiff1d(np.arange(n_mic), solved)] = False
    src_idx, mic_idx = np.nonzero(valid)
    board_col, n_latency = latency_columns(int(board.max()) + 1, options)
    source_std = options.source_std_m
    structure = _Structure(
        sources=sources,
        n_mic=solved.size,
        n_latency=n_latency,
        fit_c=options.fit_speed_of_sound,
        c_fixed=options.speed_of_sound_m_s,
        prior=prior_geometry,
        refine_poses=options.refine_poses,
        source_std_m=None
        if source_std is None
        else np.broadcast_to(source_std, (n_src,)).astype(float),
        c_prior_std=options.speed_of_sound_prior_std_m_s,
        latency_prior_std=options.latency_prior_std_s,
    )
    model = _Model(structure, tof[valid], sigma[valid], src_idx, np.searchsorted(solved, mic_idx),
                   board_col[board[mic_idx]])  # fmt: skip
    x0 = _initial_parameters(model, start[solved], options)

    n_rows = model.tau.size
    start_scale = _robust_scale(model.residuals(x0)[:n_rows])
    robust = _least_squares(model, x0, options.loss, options.f_scale * start_scale, options)
    scale = _robust_scale(robust.fun[:n_rows])
    inliers = np.abs(model.residuals(robust.x)[:n_rows]) <= options.outlier_threshold * scale
    final_model = model.subset(np.flatnonzero(inliers))
    final = _least_squares(final_model, robust.x, "linear", 1.0, options)
    return _solution(final_model, model, final.x, solved, valid, inliers, board_col, scale,
                     robust.nfev + final.nfev)  # fmt: skip


def latency_columns(n_board: int, options: SolverOptions) -> tuple[np.ndarray, int]:
    """Latency column of each board (-1: fixed at 0) and the number of latency unknowns."""
    if options.latency == "none":
        return np.full(n_board, -1), 0
    if options.latency == "common":
        return np.zeros(n_board, dtype=int), 1
    if options.latency != "per_board":
        raise CalibrationInputError(f"unknown latency model {options.latency!r}")
    free = [b for b in range(n_board) if b != options.reference_board]
    column = np.full(n_board, -1)
    column[free] = np.arange(len(free))
    return column, len(free)


def _initial_parameters(model: _Model, start: np.ndarray, options: SolverOptions) -> np.ndarray:
    """Parameter vector at the multilateration start (prior geometry aligned by Kabsch)."""
    x0 = np.zeros(model.n_params)
    if model.s.prior is None:
        x0[: 3 * model.s.n_mic] = start.ravel()
    else:
        ok = np.all(np.isfinite(start), axis=1)
        x0[:6] = kabsch(model.s.prior.positions_m[ok], start[ok]).params
    if model.s.fit_c:
        x0[model.offsets["c"]] = options.speed_of_sound_m_s
    return x0


def _robust_scale(residuals: np.ndarray) -> float:
    """The robust sigma of normalized residuals, floored at 1e-6 to stay > 0."""
    return robust_sigma(residuals, floor=1e-6)


def _least_squares(
    model: _Model, x0: np.ndarray, loss: str, f_scale: float, options: SolverOptions
) -> OptimizeResult:
    """scipy's 'trf' with the analytic sparse Jacobian (LSMR trust-region steps)."""
    return least_squares(
        model.residuals,
        x0,
        jac=model.jacobian,
        method="trf",
        loss=loss,
        f_scale=f_scale,
        x_scale="jac",
        max_nfev=options.max_nfev,
    )


def _solution(
    final_model: _Model,
    model: _Model,
    x: np.ndarray,
    solved: np.ndarray,
    valid: np.ndarray,
    inliers: np.ndarray,
    board_col: np.ndarray,
    scale: float,
    nfev: int,
) -> MicrophoneSolution:
    """Assemble the MicrophoneSolution from the final parameters and Jacobian."""
    jac = final_model.jacobian(x)
    res = final_model.residuals(x)
    chi2 = float(res @ res) / max(res.size - model.n_params, 1)
    cov = inverse_normal((jac.T @ jac).toarray()) * chi2
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))

    n_mic = valid.shape[1]
    X, blocks = model.mic_positions(x)
    positions = np.full((n_mic, 3), np.nan)
    positions[solved] = X
    mic_cov = np.full((n_mic, 3, 3), np.nan)
    mic_cov[solved] = _propagate(cov, blocks)

    residuals = np.full(valid.shape, np.nan)
    residuals[valid] = -model.residuals(x)[: model.tau.size] * model.sigma
    outliers = np.zeros(valid.shape, dtype=bool)
    outliers[valid] = ~inliers
    lat_std = np.append(model.part("lat", std), 0.0)
    pose_std = model.part("pose", std).reshape(-1, 6) if model.sizes["pose"] else None
    return MicrophoneSolution(
        positions_m=positions,
        covariance_m2=mic_cov,
        speed_of_sound_m_s=model.speed(x),
        speed_of_sound_std_m_s=float(std[model.offsets["c"]]) if model.s.fit_c else 0.0,
        latency_s=model.latencies(x)[board_col],
        latency_std_s=lat_std[board_col],
        pose_corrections=model.pose_corrections(x),
        pose_correction_std=pose_std,
        residuals_s=residuals,
        outliers=outliers,
        sigma_scale=scale,
        chi2_per_dof=chi2,
        nfev=nfev,
    )


def _propagate(cov: np.ndarray, blocks: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(n, 3, 3) covariance of points whose Jacobian blocks are `blocks`, from cov."""
    out: np.ndarray | float = 0.0
    for cols_a, d_a in blocks:
        for cols_b, d_b in blocks:
            sub = cov[cols_a[:, :, None], cols_b[:, None, :]]  # (n, wa, wb)
            out = out + np.einsum("niw,nwv,njv->nij", d_a, sub, d_b)
    return np.asarray(out)
