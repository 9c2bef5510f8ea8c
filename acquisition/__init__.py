"""The acquisition service: the capture sequencer, cameras, the session store and the CLI."""
