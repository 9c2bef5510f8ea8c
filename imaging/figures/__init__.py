"""The imaging's figures, in the calibration's figure style (`calibration.figures.style`):
imaging evaluations (`evaluation`) and the maps of one recording on its camera image
(`recording_map`, what `micam image` draws)."""
