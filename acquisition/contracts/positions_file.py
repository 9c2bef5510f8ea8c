"""Microphone positions from a file: a micam result.json or truth.json, or Acoular's MicGeom XML.

One reader for every place a user gives a known geometry of the array: `micam calibrate
--prior / --layout` (calibration.result.load_prior_positions) and the `[layout] file` of an
import description (acquisition.importer), so that both accept the same files and refuse the
same mistakes in the same words.

Why here: the importer (acquisition) and calibration both read it, and only the contracts are
below both; it needs nothing but the bounded reader of the contracts.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .bounded_files import MAX_DOCUMENT_BYTES, UnreadableFile, read_bounded_text
from .errors import UserError


class PositionsFileError(UserError):
    """A geometry file cannot be read, is not one of the formats, or lacks microphones; the
    message names the file and what is wrong."""


def read_positions(path: Path, what: str) -> dict[int, np.ndarray]:
    """Every microphone's position (3,), metres, by id, of the geometry file `path`.

    Reads a result.json or truth.json (`microphones[].id / position_m`) or Acoular's MicGeom
    XML (`<pos Name="Point k" x y z/>`, Point k being microphone id k, as
    calibration.result.write_acoular_xml writes it), of at most MAX_DOCUMENT_BYTES. `what`
    names the file's role in the messages ("the prior geometry").

    Raises:
        PositionsFileError: unreadable, not one of those formats, or a position that is not
            three finite numbers.
    """
    path = Path(path)
    try:
        text = read_bounded_text(path, MAX_DOCUMENT_BYTES)
        if _is_xml(path):
            points = ET.fromstring(text).findall("pos")
            by_id = {int(p.get("Name", "").split()[-1]):
                     [float(p.get(axis, "")) for axis in "xyz"] for p in points}
        else:
            doc = json.loads(text)
            by_id = {int(m["id"]): m["position_m"] for m in doc["microphones"]}
        positions = {i: np.array(p, dtype=np.float64) for i, p in by_id.items()}
    except UnreadableFile as exc:
        raise PositionsFileError(f"cannot read {what}: {exc}") from None
    except (ValueError, KeyError, TypeError, IndexError, OverflowError, RecursionError,
            ET.ParseError) as exc:
        raise PositionsFileError(f"cannot read {what} {path}: {exc}; give a result.json, a "
                                 "truth.json or an Acoular MicGeom XML") from None
    bad = [i for i, p in positions.items() if p.shape != (3,) or not np.all(np.isfinite(p))]
    if bad:
        raise PositionsFileError(f"{what} {path} gives microphone {bad[0]} the position "
                                 f"{by_id[bad[0]]}; give each microphone three finite "
                                 "coordinates, metres")
    return positions


def positions_of(positions: dict[int, np.ndarray], mic_ids: Iterable[int], path: Path,
                 what: str) -> np.ndarray:
    """(len(mic_ids), 3) the positions (`read_positions` of `path`) of `mic_ids`, in order.

    Raises:
        PositionsFileError: some of `mic_ids` are not in it (with the hint for an XML that
            counts its points from 1).
    """
    ids = [int(i) for i in mic_ids]
    missing = [i for i in ids if i not in positions]
    if missing:
        hint = ('; micam names microphone k "Point k", from 0: an XML counting from '
                '"Point 1" (as Acoular\'s export_mpos and earlier micam versions write it) '
                'needs its names lowered by 1' if _is_xml(Path(path)) else "")
        raise PositionsFileError(f"{what} {path} lacks microphones {missing[:10]}"
                                 f"{' ...' if len(missing) > 10 else ''}{hint}")
    return np.array([positions[i] for i in ids], dtype=np.float64).reshape(len(ids), 3)


def _is_xml(path: Path) -> bool:
    return path.suffix.lower() == ".xml"
