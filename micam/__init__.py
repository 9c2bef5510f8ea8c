"""micam, the application: the `micam` command line, its commands, the demo, and the composition
that chooses real or simulated hardware. It sits above daq/, sim/, acquisition/ and calibration/."""
