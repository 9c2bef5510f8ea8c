"""The contracts shared by acquisition, calibration and sim: the session format, the capture and
rig description, the camera and operator protocols, the job and control messages.

Nothing here imports the daemon, the sequencer or the simulator, so a calibration worker or the
simulated world may import it alone (the import-linter contracts in pyproject.toml keep it so).
"""
