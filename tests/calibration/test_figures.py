"""The report's and the demo's figures, regenerated from a simulated session and checked for
what they must show: equal axes, every camera labelled once without overlap, the magnified
error vectors against the truth, titled residual panels, grouped notes, small PNGs; and the
study's figure with the bound and the paper's Table II."""

from __future__ import annotations

import json
import os
import re
from itertools import combinations
from pathlib import Path
from typing import cast

import numpy as np
import pytest
from matplotlib.quiver import Quiver

from micam.demo_loop import report as demo_report
from calibration import report
from calibration.figures.geometry import ArrayPicture, geometry_figure, inside_ellipsoids
from calibration.figures.residuals import corner_residual_figure, tof_residual_figure
from calibration.figures import style
from calibration.figures.study import study_figure
from calibration.figures.style import new_figure, save_all
from calibration.pipeline import CalibrationRun, calibrate
from tests.conftest import simulated_session

pytestmark = pytest.mark.slow  # every test here: a calibration run

MAX_PNG_BYTES = 200_000


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four poses of the sphere: cam1 and cam2 see the board in few of them."""
    return simulated_session(tmp_path_factory, "figures", "--poses", "4", "--mls-order", "11",
                             "--seed", "12")


@pytest.fixture(scope="module")
def run(session: Path) -> CalibrationRun:
    return calibrate(session)


@pytest.fixture(scope="module")
def truth(session: Path) -> dict:
    return json.loads((session / "truth.json").read_text())


def _number(pattern: str, text: str) -> float:
    """Group 1 of `pattern`'s first match in `text`, a number."""
    found = re.search(pattern, text)
    assert found is not None, pattern
    return float(found.group(1))


def _views(fig):
    return [ax for ax in fig.axes if (ax.get_gid() or "").startswith("view-")]


def test_geometry_views_are_equal_aspect_and_show_every_camera(run: CalibrationRun,
                                                               truth: dict) -> None:
    picture = report.array_picture(run.result, truth, None, run.solution.covariance_m2,
                            run.measurements.cameras.uncalibrated)
    fig = geometry_figure(picture)
    fig.canvas.draw()
    views = _views(fig)
    assert len(views) == 4
    for ax in views:
        assert ax.get_aspect() == 1.0
        (x0, y0), (x1, y1) = ax.transData.transform([(0.0, 0.0), (1.0, 1.0)])
        assert abs(x1 - x0) == pytest.approx(abs(y1 - y0), rel=1e-6)  # 1 mm is 1 mm both ways
    names = {c["name"] for c in truth["cameras"]}
    renderer = fig.canvas.get_renderer()
    for ax in views[:3]:
        labels = [t for t in ax.texts if t.get_gid() == "camera-label"]
        named = [n.strip().split(" ")[0] for t in labels for n in t.get_text().split(",")]
        assert sorted(named) == sorted(names)  # every camera once, none missing
        boxes = [t.get_window_extent(renderer) for t in labels]
        assert not any(a.overlaps(b) for a, b in combinations(boxes, 2))
    # The error vectors are the errors against the truth, magnified by the stated factor.
    legend = " ".join(t.get_text() for t in fig.legends[0].get_texts())
    factor = _number(r"error \S (\d+)", legend)
    front = views[0]
    quiver = next(c for c in front.collections if isinstance(c, Quiver))
    true_ids = {m["id"]: m["position_m"] for m in truth["microphones"]}
    errors = run.result.positions() - np.array([true_ids[m.id] for m in run.result.microphones])
    # matplotlib types U and V as any array-like; they are masked arrays
    np.testing.assert_allclose(cast(np.ndarray, quiver.U), 1e3 * factor * errors[:, 0],
                               rtol=1e-9)
    np.testing.assert_allclose(cast(np.ndarray, quiver.V), 1e3 * factor * errors[:, 1],
                               rtol=1e-9)
    # The largest magnified (3-D) error spans 5-12 % of the array: visible, not overwhelming.
    extent = np.ptp(run.result.positions(), axis=0).max()
    assert 0.048 <= factor * np.linalg.norm(errors, axis=1).max() / extent <= 0.12


def test_ellipses_much_larger_than_the_errors_get_their_own_factor() -> None:
    rng = np.random.default_rng(0)
    mics = rng.normal(0, 0.1, (40, 3))
    errors = rng.normal(0, 1e-5, (40, 3))
    errors[:4] = [6e-4, 0.0, 0.0]  # four microphones 6 sigma off
    cov = np.broadcast_to(np.diag([1e-4, 1e-4, 4e-4]) ** 2, (40, 3, 3))
    fig = geometry_figure(ArrayPicture(mics + errors, cov, mics, "simulated truth"))
    legend = " ".join(t.get_text() for t in fig.legends[0].get_texts())
    error_factor = _number(r"error \S (\d+)", legend)
    ellipse_factor = _number(r"uncertainty \S (\d+)", legend)
    assert ellipse_factor < error_factor and "smaller" in legend
    assert "36 of 40 errors inside their 95 % uncertainty ellipsoid" in fig._suptitle.get_text()
    assert inside_ellipsoids(errors, None) is None


def test_report_figures_are_titled_small_and_notes_grouped(run: CalibrationRun, truth: dict,
                                                           tmp_path: Path) -> None:
    markdown = report.write_report(run, tmp_path / "report", truth)
    for name in ("geometry.png", "residuals.png", "corners.png", "tof_quality.png"):
        size = (markdown.parent / name).stat().st_size
        assert 10_000 < size < MAX_PNG_BYTES, name
    text = markdown.read_text()
    for camera, reason in {(m.camera, m.reason) for m in run.measurements.cameras.missed}:
        lines = [ln for ln in text.splitlines() if ln.startswith(f"- {camera}:") and reason in ln]
        assert len(lines) == 1  # one line per camera and reason, not one per image
        assert re.search(r"in \d+ images? \(pose/", lines[0])
    tof = tof_residual_figure(report.tof_residuals(run))
    assert len(tof.axes) == 6 and all(ax.get_title() for ax in tof.axes)
    corners = corner_residual_figure(report.corner_residuals(run))
    visible = [ax for ax in corners.axes if ax.get_visible()]
    assert len(visible) == 2 * len(run.result.cameras)
    assert all(ax.get_title() for ax in visible)
    scatter = visible[0]
    assert scatter.get_aspect() == 1.0


def test_console_numbers_keep_their_significant_digits(run: CalibrationRun,
                                                       truth: dict) -> None:
    assert report.significant(0.000081, signed=True) == "+0.000081"
    assert report.significant(0.0141) == "0.014" and report.significant(12.3) == "12"
    assert report.significant(0) == "0.0"
    steps = ["pose/0001", "pose/0002", "pose/0003", "pose/0009", "refmic"]
    assert report.step_ranges(steps) == "pose/0001-0003, pose/0009, refmic"
    line = next(ln for ln in report.summary_lines(run, truth) if "c error" in ln)
    printed = _number(r"c error ([-+][\d.]+) m/s", line.split(";")[-1])
    true_error = run.result.speed_of_sound_m_s - truth["speed_of_sound_m_s"]
    assert printed == pytest.approx(true_error, rel=0.06)  # never "+0.000"


def test_demo_figure_shows_the_error_against_the_truth(run: CalibrationRun, session: Path,
                                                       tmp_path: Path) -> None:
    result = tmp_path / "result.json"
    run.result.write(result)
    lines = demo_report(session, result, tmp_path)
    assert any(ln.startswith("mean error") and "mm" in ln for ln in lines)
    size = (tmp_path / "geometry.png").stat().st_size
    assert 10_000 < size < MAX_PNG_BYTES
    assert "magnified" in (tmp_path / "report.md").read_text()


def _row(n: int, mean_mm: float, joint_mm: float | None) -> dict:
    return {"n_sources": n, "trials": 3, "mean_error_m": mean_mm / 1e3, "sem_m": 1e-5,
            "crlb_m": 0.6 * mean_mm / 1e3, "efficiency": 1.6, "latency": "per_board",
            "joint_error_m": None if joint_mm is None else joint_mm / 1e3,
            "joint_sem_m": None if joint_mm is None else 1e-6}


def test_study_figure_is_the_papers_figure_14() -> None:
    results = [{"band_m": band, "rows": [_row(3, 2.0, None), _row(12, 0.8, 0.1),
                                         _row(36, 0.4, 0.05)]}
               for band in ((0.6, 1.0), (1.5, 2.0))]
    fig = study_figure(results)
    panels = [ax for ax in fig.axes if (ax.get_gid() or "").startswith("band-")]
    assert [ax.get_title() for ax in panels] == ["0.6-1.0 m (paper: 0.6-1.0 m)",
                                                  "1.5-2.0 m (paper: 1.4-1.8 m)"]
    for ax in panels:
        assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
        labels = [line.get_label() for line in ax.get_lines()]
        assert "bound (frozen model)" in labels
    paper = next(line for line in panels[0].get_lines()
                 if line.get_label().startswith("paper's Table II"))
    assert list(paper.get_xdata()) == [3, 6, 18, 35]  # Table II at 0.6-1.0 m
    assert list(paper.get_ydata()) == [10.0, 5.5, 5.0, 4.5]
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert {"camera frozen", "joint fit", "bound (frozen model)"} <= set(legend)


def _line_figure(label: str):
    """A small figure; `label` in its title."""
    fig = new_figure(3.0, 2.0)
    fig.add_subplot().plot([0, 1], [1, 0], label=label)
    fig.suptitle(label)
    return fig


def test_save_all_draws_every_figure_once_split_over_two_processes(tmp_path: Path) -> None:
    """Every second figure is drawn by a forked child (its pid differs), the others here."""
    parent = os.getpid()
    drawn_here: list[str] = []

    def make(name: str):
        def draw():
            if os.getpid() == parent:
                drawn_here.append(name)
            return _line_figure(name)
        return draw

    names = ["a", "b", "c", "d"]
    paths = save_all([(make(n), tmp_path / f"{n}.png") for n in names])
    assert paths == [tmp_path / f"{n}.png" for n in names]
    assert all(p.stat().st_size > 1000 for p in paths)
    assert drawn_here == ["b", "d"]


def test_save_all_draws_the_childs_figures_itself_when_the_child_fails(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A figure that cannot be drawn in the child (here: it raises there) is drawn by the
    parent, with a warning; without fork, every figure is drawn here."""
    parent = os.getpid()

    def fails_in_child():
        if os.getpid() != parent:
            raise RuntimeError("no display in the child")
        return _line_figure("x")

    paths = save_all([(fails_in_child, tmp_path / "x.png"),
                      (lambda: _line_figure("y"), tmp_path / "y.png")])
    assert all(p.stat().st_size > 1000 for p in paths)
    assert "drawing x.png here" in caplog.text


def test_save_all_without_fork_draws_everything_here(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(style.multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    parent = os.getpid()
    pids: list[int] = []

    def draw():
        pids.append(os.getpid())
        return _line_figure("z")

    save_all([(draw, tmp_path / "1.png"), (draw, tmp_path / "2.png")])
    assert pids == [parent, parent]
    assert (tmp_path / "1.png").is_file() and (tmp_path / "2.png").is_file()
