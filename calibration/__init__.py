"""Calibration: from a recorded session to microphone coordinates in the camera-0 frame."""
