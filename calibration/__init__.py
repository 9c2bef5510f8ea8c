"""Calibration: from a recorded session to microphone coordinates in the camera-0 frame.

Its stages, each a sub-package whose imports run one way (an import-linter contract):

- `camera/`: what the checkerboard images say: the board and its corners, the images' own
  checks, each camera's fit and board poses, the speakers' positions from those poses;
- `acoustic/`: what the recordings say: delays, times of flight, the camera-scaled speed of
  sound, the microphones' responses (independent of `camera/`);
- `solve/`: the fits that join the two: the camera-frozen microphone solver, its start and
  the paper's baseline, the joint optical-acoustic fit, their robust helpers and bounds;
- `checks/`: the capture's and the fit's mistakes, the plausibility of a result, the
  coverage of a covariance (above the stages they judge).

Around them, at the top: the run (`pipeline`, what the session and options settle beforehand
in `plan`, result.json assembled in `result_assembly`), what the calibration reads and writes
(`session_data` and the recordings' `levels`, a `truth` file, the `result` model, its input
`errors`), the shared pieces (`choices`, `memo`, `_blas`, `_cores`), the report
(`report`, with `figures/`, which the imaging draws with too), the source-count `study`, and
the ZeroMQ `worker/`. `levels` and `result` stay at the top because the stages import them
(and `session_data` imports `levels`); `result_assembly` and `report` because the pipeline
imports the one and the other imports the pipeline, so neither fits in a stage.
"""
