"""The shared math at the bottom of the layers: rigid transforms, SO(3) Jacobians and Kabsch
(`rigid`), the air's speed of sound and a speaker's piston directivity (`air`), the MLS test
signal (`stimulus`).

Every layer (daq, acquisition and its contracts, calibration, sim, micam) may import it; it
imports none of them (the import-linter layers contract in pyproject.toml), so that using the
math never pulls in the daemon, the driver or the contracts.
"""
