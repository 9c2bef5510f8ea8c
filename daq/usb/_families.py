"""The board families the USB driver knows: their USB ids, firmware and variant table.

A family is data, not code: the DT9836 and the DT9816 share one driver (`UsbBoard`) and differ
only in these tables (the DT9816 entries are guesses, kept in `_unpublished`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from daq import BOARD_MODELS, BoardModel

from ._ids import DT9816_LOADER_PID, DT9836_LOADER_PID, DT9836_RUNNING_PID
from ._unpublished import DT9816_RUNNING_PID, DT9816_VERSION_IDS

LOADER_IMAGE = "a3load"
"""The second-stage FX2 loader image (answers the 0xA3 external-RAM request)."""


@dataclass(frozen=True)
class Family:
    """One board family.

    Attributes:
        name: "DT9836" or "DT9816".
        loader_pid: product id before the firmware download.
        running_pid: product id of the running firmware.
        firmware: file stem of the family's firmware image (e.g. "dt9836" -> dt9836.hex).
        variants: VERSION_ID register value -> board model name.
    """

    name: str
    loader_pid: int
    running_pid: int
    firmware: str
    variants: Mapping[int, str]

    def model(self, version_id: int) -> BoardModel | None:
        """The board model a version register value names, or None if it is unknown."""
        name = self.variants.get(version_id)
        return None if name is None else BOARD_MODELS[name]


DT9836 = Family(
    name="DT9836",
    loader_pid=DT9836_LOADER_PID,
    running_pid=DT9836_RUNNING_PID,
    firmware="dt9836",
    variants={m.version_id: m.name for m in BOARD_MODELS.values()
              if m.family == "DT9836" and m.version_id is not None},
)
DT9816 = Family(
    name="DT9816",
    loader_pid=DT9816_LOADER_PID,
    running_pid=DT9816_RUNNING_PID,
    firmware="dt9816",
    variants=DT9816_VERSION_IDS,
)
FAMILIES: tuple[Family, ...] = (DT9836, DT9816)


def family_of(product_id: int) -> tuple[Family, bool] | None:
    """(family, firmware running?) for a product id, or None if it is not one of ours."""
    for f in FAMILIES:
        if product_id == f.running_pid:
            return f, True
        if product_id == f.loader_pid:
            return f, False
    return None


def family_named(name: str) -> Family:
    """The family of a board model name ("DT9836-12-2" -> DT9836)."""
    return next(f for f in FAMILIES if f.name == BOARD_MODELS[name].family)
