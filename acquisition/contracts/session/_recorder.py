"""What a capture needs of a session store: the steps it writes, as the sequencer calls them.

`SessionWriter` is one; the daemon's quality gate wraps one and checks each file as it comes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np


class StepRecorder(Protocol):
    """Records a capture step by step (see `SessionWriter` for the meaning of each call)."""

    def completed_steps(self) -> dict[str, int]: ...

    def begin_step(self, step: str) -> int: ...

    def write_image(self, step: str, name: str, image: np.ndarray,
                    meta: dict | None = None) -> Path: ...

    def write_recording(self, step: str, name: str, codes: np.ndarray, sample_rate_hz: int,
                        meta: dict | None = None) -> Path: ...

    def write_json(self, step: str, name: str, data: dict) -> Path: ...

    def end_step(self, step: str) -> None: ...

    def abandon_step(self, step: str, reason: str) -> None: ...

    def stop(self, exit_status: str = "success", reason: str = "") -> None: ...

    def close(self) -> None: ...
