"""The mistakes one simulated world makes, as its layers consult them.

`sim.mistakes.planner` turns the asked-for mistakes into one `Mistakes`, fixed for the whole
session (every choice drawn from the session's seed), and the layers ask it what to do where
the mistake happens: the bench (cables, speakers, capsules, input stages), the operator (the
rig, the reference microphone), the cameras (the scene, the codec). A world without mistakes
holds `NO_MISTAKES`, with which no layer does more than a look-up. Recordings are named by
(set-up key, speaker): the set-up of sim.setups (pose i is (3, i)) and the speaker whose
output the capture drove (the file `speaker_<k>.wav`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..arrays import ChannelRef
from ..geometry import RigidTransform
from ..setups import POSE_SETUP, Key
from .images import mjpeg
from .signals import saturated, with_echo

Recording = tuple[Key, int]
"""(set-up key, speaker driven): one burst's recording."""
ImageEffect = Callable[[np.ndarray], np.ndarray]
"""A change of the ideal float image in front of the lens (sim.light's `scene`)."""


@dataclass(frozen=True)
class Echo:
    """A reflector beside microphone `mic`: a second path `delay_s` after the direct one,
    `gain` times it."""

    mic: int
    delay_s: float
    gain: float


@dataclass(frozen=True)
class Mistakes:
    """Everything the world does wrong, by layer (see the module docstring).

    Attributes:
        records: what truth.json says was done, one dict per mistake.
        mic_inputs: the board input each microphone's cable is on (None: as configured).
        speaker_outputs: the board output each speaker's cable is on (None: as configured).
        mic_factors: (n_mics,) each capsule's wiring: 1, -1 (inverted) or 0 (dead); None: 1.
        echoes: close reflectors.
        saturation: speaker -> drive of its tanh saturation.
        silent: speaker -> the set-ups in which it does not play (None: none of them plays).
        dropouts: recording -> (microphone, sample ranges at idle noise) of every dropout.
        clipping: recording -> the microphones whose input stage is overdriven.
        clip_fraction: where the overdriven inputs reach full scale, as a fraction of the
            burst's peak.
        moved_poses: pose -> the rig's pose during its bursts (its images see the sampled one).
        reference_distances_m: speaker -> the reference microphone's distance in its
            reference recording.
        scenes: (pose, camera) -> the image effects in front of that camera at that pose.
        jpeg_quality: every camera's MJPEG quality (None: raw frames).
    """

    records: tuple[dict, ...] = ()
    mic_inputs: tuple[ChannelRef, ...] | None = None
    speaker_outputs: tuple[ChannelRef, ...] | None = None
    mic_factors: np.ndarray | None = None
    echoes: tuple[Echo, ...] = ()
    saturation: Mapping[int, float] = field(default_factory=dict)
    silent: Mapping[int, frozenset[Key] | None] = field(default_factory=dict)
    dropouts: Mapping[Recording, tuple[tuple[int, tuple[tuple[int, int], ...]], ...]] = field(
        default_factory=dict)
    clipping: Mapping[Recording, tuple[int, ...]] = field(default_factory=dict)
    clip_fraction: float = 1.0
    moved_poses: Mapping[int, RigidTransform] = field(default_factory=dict)
    reference_distances_m: Mapping[int, float] = field(default_factory=dict)
    scenes: Mapping[tuple[int, int], tuple[ImageEffect, ...]] = field(default_factory=dict)
    jpeg_quality: int | None = None

    @property
    def acoustic(self) -> bool:
        """Whether any rendered signal is changed after propagation (factors, echoes,
        dropouts, clipping)."""
        return bool(self.mic_factors is not None or self.echoes or self.dropouts
                    or self.clipping)

    def plays(self, speaker: int, setup: Key) -> bool:
        """Whether speaker `speaker` plays when its output is driven in set-up `setup`."""
        if speaker not in self.silent:
            return True
        setups = self.silent[speaker]
        return setups is not None and setup not in setups

    def radiated(self, speaker: int, spectrum: np.ndarray, n_fft: int) -> np.ndarray:
        """The rFFT of what speaker `speaker` radiates, from its linear output's."""
        drive = self.saturation.get(speaker)
        return spectrum if drive is None else saturated(spectrum, n_fft, drive)

    def after_render(self, recording: Recording, rows: np.ndarray, fs_hz: float) -> None:
        """Change the rendered volts `rows` (n_mics [+ reference], n) of one recording in
        place, the array microphones first in id order: the reflectors' echoes, the capsules'
        wiring, the dropouts."""
        for echo in self.echoes:
            rows[echo.mic] = with_echo(rows[echo.mic], fs_hz, echo.delay_s, echo.gain)
        if self.mic_factors is not None:
            rows[: self.mic_factors.size] *= self.mic_factors[:, None]
        for mic, stretches in self.dropouts.get(recording, ()):
            for start, stop in stretches:
                rows[mic, start:stop] = 0.0

    def scene(self, setup: Key, camera: int) -> ImageEffect | None:
        """What is in front of camera `camera` in set-up `setup` (None: the rig only)."""
        if setup[0] != POSE_SETUP:
            return None
        effects = self.scenes.get((setup[1], camera), ())
        if not effects:
            return None

        def apply(image: np.ndarray) -> np.ndarray:
            for effect in effects:
                image = effect(image)
            return image

        return apply

    def delivered(self, image: np.ndarray) -> np.ndarray:
        """A camera's frame as it reaches the capture (MJPEG-compressed when asked)."""
        return image if self.jpeg_quality is None else mjpeg(image, self.jpeg_quality)


NO_MISTAKES = Mistakes()
