"""The live view's spectrum: the microphones' mean band power, of the latest window only."""

from __future__ import annotations

import numpy as np

from imaging.live_spectrum import FLOOR_DB, MeanSpectrum

FS = 48_000.0


def _tone(freq_hz: float, amplitudes: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    t = (start + np.arange(n)) / FS
    return np.sin(2 * np.pi * freq_hz * t)[:, None] * amplitudes[None, :]


def test_a_tone_is_the_mean_power_of_the_microphones_in_its_band_and_the_window_slides() -> None:
    amplitudes = np.array([0.5, 1.0, 2.0])  # mean power (0.125 + 0.5 + 2) / 3 = 0.875 V^2
    spectrum = MeanSpectrum(3, FS, 4800, 1024)
    assert np.all(spectrum.levels_db() == FLOOR_DB)  # nothing yet
    spectrum.push(_tone(1000.0, 10 * amplitudes, 7000))  # loud, then gone from the window
    for start in range(7000, 13_000, 1700):  # chunks of any size
        spectrum.push(_tone(4000.0, amplitudes, 1700, start))
    assert spectrum.ready
    levels = spectrum.levels_db()
    at = {round(c): level for c, level in zip(spectrum.centres_hz, levels)}
    assert abs(at[4000] - 10 * np.log10(0.875)) < 0.2  # Hann leakage stays in a third octave
    assert at[1000] < at[4000] - 40 and at[8000] < at[4000] - 40
    assert spectrum.centres_hz[0] >= 100 and spectrum.centres_hz[-1] <= 20_000
