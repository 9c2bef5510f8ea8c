"""The calibration's named choices: its stages and its latency models.

Light to import (no numpy), so that `micam calibrate` declares its options and its progress
bar from the same names the pipeline and the solver use.
"""

from __future__ import annotations

from typing import Literal, get_args

Stage = Literal["load", "cameras", "speakers", "times of flight", "solver", "dispersion",
                "joint fit", "responses"]
"""A stage of a calibration, as `calibration.pipeline` times it and tells `on_stage`."""
STAGES: tuple[Stage, ...] = get_args(Stage)
"""The stages of a calibration, in the order they run."""

LatencyModel = Literal["per_board", "common", "none"]
"""How the boards' latencies are modelled: one per board (the reference microphone's board
fixed at 0), one common to all channels, or none."""
LATENCY_MODELS: tuple[LatencyModel, ...] = get_args(LatencyModel)
DEFAULT_LATENCY: LatencyModel = "per_board"
"""The latency model of the calibration and of the solver. Delays are measured against the
reference microphone, which records on its own board, so every other board's latency is
relative to that board's: one per board, the reference board's fixed at 0."""
