"""From a stream of microphone samples and camera frames to drawn video frames.

`MapFrames` feeds the samples to a `LiveImager` and, every `1 / fps` seconds of the stream
(stream time, not wall-clock time: a recording is rendered frame for frame however long it
takes), makes the map of the latest window and draws it over the camera frame taken nearest
the window's centre (the matching frame: the map shows the sound of the window), with the
array's mean spectrum over the same window when asked for (`live_spectrum`). It serves
the live stream (samples from the daemon, `live_feed`) and a recording (`micam live video
--recording`) alike. `VideoFile` writes the frames with OpenCV's VideoWriter: MJPEG in an
.avi, MPEG-4 part 2 in an .mp4.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.errors import CalibrationInputError

from .live import LiveImager, LiveMap, LiveSettings
from .live_draw import draw_live_frame
from .live_spectrum import MeanSpectrum

FRAMES_KEPT = 64
"""Camera frames kept to match maps to (several seconds at video rates)."""
FOURCC = {".avi": "MJPG", ".mp4": "mp4v"}
"""The codec of each video container written."""


@dataclass(frozen=True)
class DrawnFrame:
    """A video frame: the BGR image, its map, the camera frame's stream index (or -1
    when no frame of the camera had arrived), the settings it was drawn with, and the band
    levels of the array's mean spectrum (dB, `MeanSpectrum.centres_hz`; None unless asked
    for)."""

    image: np.ndarray
    live_map: LiveMap
    camera_sample: int
    settings: LiveSettings
    spectrum_db: np.ndarray | None = None


class MapFrames:
    """Drawn frames of a stream (module docstring).

    Args:
        imager: the live imager (its settings name the camera).
        fps: video frames per second of stream time.
        caption: drawn on every frame (band, method, range).
        spectrum: give every frame the array's mean spectrum over the map's window.
    """

    def __init__(self, imager: LiveImager, fps: float, caption: str = "",
                 spectrum: bool = False) -> None:
        if not fps > 0:
            raise CalibrationInputError(f"a video needs a positive frame rate, not {fps}")
        self.imager = imager
        self.hop = max(1, round(imager.sample_rate_hz / fps))
        self.caption = caption
        self.spectrum = MeanSpectrum(imager.n_mics, imager.sample_rate_hz,
                                     imager.csm.window_samples,
                                     imager.settings.block_size) if spectrum else None
        self._frames: deque[tuple[int, np.ndarray]] = deque(maxlen=FRAMES_KEPT)
        self._next = 0  # the stream index at which the next map is due
        self._blank = np.zeros((imager.camera.height, imager.camera.width), dtype=np.uint8)

    def retune(self, imager: LiveImager, caption: str) -> None:
        """Draw with another imager of the same stream (a band, range or plane changed while
        running): the camera frames are kept; a new CSM's window fills from the next samples
        on (one shared with the imager before, `LiveImager.with_range`, goes on)."""
        if imager.sample_rate_hz != self.imager.sample_rate_hz:
            raise CalibrationInputError("a live view is retuned within one stream (one rate)")
        if imager.csm is not self.imager.csm:
            imager.csm.restart(self.imager.csm.samples_in)  # the stream goes on, without a gap
        self.imager, self.caption = imager, caption

    def add_frame(self, sample: int, image: np.ndarray) -> None:
        """A frame of the imager's camera, taken at stream index `sample`."""
        self._frames.append((int(sample), image))

    def push(self, start: int, volts: np.ndarray) -> list[DrawnFrame]:
        """Append microphone samples (n, M) beginning at stream index `start` (after a gap
        the window starts again there); the frames that came due, oldest first."""
        volts = np.asarray(volts)
        if start != self.imager.csm.samples_in:
            self.imager.csm.restart(start)
            self._next = max(self._next, start)
            if self.spectrum is not None:
                self.spectrum.restart()
        out = []
        done = 0
        while done < volts.shape[0]:
            until_due = self._next - self.imager.csm.samples_in
            take = volts.shape[0] - done if until_due <= 0 else min(volts.shape[0] - done,
                                                                    until_due)
            self.imager.push(volts[done: done + take])
            if self.spectrum is not None:
                self.spectrum.push(volts[done: done + take])
            done += take
            if self.imager.ready and self.imager.csm.samples_in >= self._next:
                out.append(self.draw())
                self._next = self.imager.csm.samples_in + self.hop
        return out

    def draw(self) -> DrawnFrame:
        """The map of the latest window over its matching camera frame."""
        live_map = self.imager.map()
        centre = live_map.end_sample - live_map.window_samples // 2
        sample, image = min(self._frames, key=lambda f: abs(f[0] - centre),
                            default=(-1, self._blank))
        settings = self.imager.settings
        drawn = draw_live_frame(image, self.imager.level_image(live_map),
                                settings.dynamic_range_db, live_map.peak_px, self.caption,
                                settings.image_scale)
        levels = self.spectrum.levels_db() if self.spectrum is not None else None
        return DrawnFrame(drawn, live_map, sample, settings, levels)


def caption_of(imager: LiveImager) -> str:
    """What a frame shows: band, method, dynamic range, plane."""
    s = imager.settings
    band = "octave" if s.fraction == 1 else "1/3 octave"
    method = "CLEAN-SC" if s.clean_sc else "delay-and-sum"
    return (f"{s.band_hz:.0f} Hz {band}, {method}, {s.dynamic_range_db:g} dB, "
            f"plane at {s.depth_m:g} m")


class VideoFile:
    """A video file of drawn frames (.avi: MJPEG, .mp4: MPEG-4), opened on the first frame."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() not in FOURCC:
            raise CalibrationInputError(f"{self.path}: write a video as {' or '.join(FOURCC)}")
        if not self.path.parent.is_dir():
            raise CalibrationInputError(f"the directory of {self.path} does not exist")
        self.fps = float(fps)
        self.frames = 0
        self._writer: cv2.VideoWriter | None = None

    def write(self, image: np.ndarray) -> None:
        if self._writer is None:
            fourcc = cv2.VideoWriter.fourcc(*FOURCC[self.path.suffix.lower()])
            self._writer = cv2.VideoWriter(str(self.path), fourcc, self.fps,
                                           (image.shape[1], image.shape[0]))
            if not self._writer.isOpened():
                raise CalibrationInputError(f"OpenCV cannot write {self.path} (no encoder for "
                                            f"{self.path.suffix})")
        self._writer.write(image)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> VideoFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
