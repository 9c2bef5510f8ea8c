"""The Acoular XML exports: microphone k of result.json is "Point k" (one numbering, from 0),
and Acoular, which reads the positions and factors in document order, gets them in id order."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from calibration.result import (
    CalibrationResult,
    MicrophoneResponse,
    MicrophoneResponsesResult,
    MicrophoneResult,
    load_prior_positions,
    write_acoular_calib_xml,
    write_acoular_xml,
)

IDS = [7, 0, 3, 12]  # not contiguous, not in order: a name or an order that is off shows


def _result() -> CalibrationResult:
    """A result holding only what the exports read (its microphones and their responses)."""
    mics = [MicrophoneResult(id=k, position_m=(0.01 * k, -0.02 * k, 1.0 + 0.001 * k),
                             std_m=(1e-4, 1e-4, 1e-4), board="A", residual_rms_s=1e-7,
                             n_measurements=10) for k in IDS]
    responses = MicrophoneResponsesResult(frequencies_hz=[1000.0, 2000.0], n_sources=6,
                                          microphones=[MicrophoneResponse(
                                              id=k, gain=[1.0 + 0.01 * k] * 2,
                                              phase_rad=[0.0] * 2, gain_std=[0.0] * 2,
                                              phase_std_rad=[0.0] * 2) for k in IDS])
    return CalibrationResult.model_construct(microphones=mics, microphone_responses=responses)


def test_the_xml_names_are_the_result_ids_in_id_order(tmp_path: Path) -> None:
    result = _result()
    write_acoular_xml(result, tmp_path / "mics.xml")
    write_acoular_calib_xml(result, tmp_path / "calib.xml")
    for name in ("mics.xml", "calib.xml"):
        names = [p.get("Name") for p in ET.parse(tmp_path / name).getroot().findall("pos")]
        assert names == [f"Point {k}" for k in sorted(IDS)]


def test_acoular_reads_them_in_microphone_id_order(tmp_path: Path) -> None:
    import acoular as ac

    result = _result()
    write_acoular_xml(result, tmp_path / "mics.xml")
    write_acoular_calib_xml(result, tmp_path / "calib.xml")
    by_id = {m.id: m for m in result.microphones}
    np.testing.assert_allclose(ac.MicGeom(file=str(tmp_path / "mics.xml")).pos_total.T,
                               [by_id[k].position_m for k in sorted(IDS)], atol=1e-6)
    np.testing.assert_allclose(ac.Calib(file=str(tmp_path / "calib.xml")).data,
                               [1.0 / (1.0 + 0.01 * k) for k in sorted(IDS)], rtol=1e-5)


def test_a_prior_from_the_xml_is_read_by_name(tmp_path: Path) -> None:
    result = _result()
    write_acoular_xml(result, tmp_path / "mics.xml")
    wanted = np.array([12, 0, 7])
    by_id = {m.id: m.position_m for m in result.microphones}
    np.testing.assert_allclose(load_prior_positions(tmp_path / "mics.xml", wanted),
                               [by_id[k] for k in wanted], atol=1e-6)


def test_an_xml_counting_from_point_1_is_refused_with_the_reason(tmp_path: Path) -> None:
    """Acoular's own export names its first microphone "Point 1": read by name, microphone 0
    is missing, and the message says why instead of shifting every microphone by one."""
    import acoular as ac

    positions = np.array([[0.0, 0.1, 0.2], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    ac.MicGeom(pos_total=positions).export_mpos(str(tmp_path / "theirs.xml"))
    with pytest.raises(CalibrationInputError, match=r'lacks microphones \[0\].*counting from "Point 1"'):
        load_prior_positions(tmp_path / "theirs.xml", np.arange(3))
