"""The acquisition service: the capture sequencer (`sequencer`), the cameras (`cameras_v4l2`),
the daemon and its ZeroMQ interface (`daemon/`), live mode (`live/`), imports of other
recorders' files (`importer/`), and the formats and messages it shares with the calibration
and the simulated world (`contracts/`: the session store among them). The CLI is `micam/`."""
