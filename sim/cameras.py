"""Simulated cameras: the acquisition `Camera` protocol rendering the simulated world."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from acquisition.contracts.camera import CameraTimeoutError, Frame
from daq import ClosesOnExit

from .geometry import CameraModel
from .light import render_rig_image
from .live_light import render_scene_image
from .mistakes.plan import NO_MISTAKES, Mistakes
from .setups import Setups
from .world import World


class SimulatedCamera(ClosesOnExit):
    """Renders what camera `model` sees of the rig (as built: the world's `physical_rig`) at the
    world's current pose.

    `fail_next_grabs` makes the next grabs time out, as a camera that returns no frame does.
    The sensor noise of a frame is keyed by the set-up and the frame's number in it
    (sim.setups), so a resumed capture renders what an uninterrupted one does.

    `preview` renders the same view at a smaller size, once per set-up (the simulated rig does
    not move between set-ups, so every look at it is the same picture), with noise of its own
    key: previews cost a render per set-up and change nothing a capture records.

    `mistakes` are the camera's (sim.mistakes): what is in front of it at a pose (an arm, a
    highlight, the board's motion) and its codec (MJPEG); they change the grabbed frames, not
    the previews. So do the lab's camera effects (sim.optics) but for the lens's distortion
    (the camera model's) and the plate's bow (the rig's).
    """

    def __init__(self, model: CameraModel, world: World, index: int,
                 setups: Setups | None = None, mistakes: Mistakes = NO_MISTAKES) -> None:
        self.model = model
        self.world = world
        self.index = index
        self.setups = setups or Setups()
        self.mistakes = mistakes
        self.fail_next_grabs = 0
        self._preview: tuple[tuple, np.ndarray] | None = None

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def device_id(self) -> str:
        return f"sim:{self.world.layout.name}:{self.model.name}"

    def grab(self, timeout_s: float = 2.0) -> Frame:
        if self.fail_next_grabs > 0:
            self.fail_next_grabs -= 1
            raise CameraTimeoutError(
                f"camera {self.name} ({self.device_id}) returned no frame within {timeout_s} s"
            )
        key = self.setups.next_frame(self.index)
        rng = np.random.default_rng([self.world.seed, 3, self.index, *key])
        w = self.world
        if w.live_scene is not None:  # live mode: the sources where they are now
            scene = w.live_scene
            image = render_scene_image(self.model, scene.positions_at(scene.now_s), rng,
                                       w.noise.image_noise_grey * w.noise.scale)
            return Frame(image=image, timestamp_s=time.monotonic(), camera=self.name)
        image = render_rig_image(
            self.model, w.physical_rig, w.rig_pose if w.rig_in_view else None, rng,
            noise_grey=w.noise.image_noise_grey * w.noise.scale,
            blur_sigma_px=w.noise.image_blur_px,
            scene=self.mistakes.scene(key[:2], self.index),
            effects=w.lab.camera, camera_key=(w.seed, self.index), noise_scale=w.noise.scale,
        )
        return Frame(image=self.mistakes.delivered(image), timestamp_s=time.monotonic(),
                     camera=self.name)

    def preview(self, max_width: int, timeout_s: float = 2.0) -> Frame:
        if self.fail_next_grabs > 0:
            raise CameraTimeoutError(
                f"camera {self.name} ({self.device_id}) returned no frame within {timeout_s} s")
        w = self.world
        scale = min(1.0, max_width / self.model.width)
        key = (self.setups.current(), w.rig_in_view, scale)
        if self._preview is None or self._preview[0] != key:
            K = self.model.K.copy()
            K[:2] *= scale
            small = replace(self.model, width=round(self.model.width * scale),
                            height=round(self.model.height * scale), K=K)
            rng = np.random.default_rng([w.seed, 5, self.index, *key[0]])
            image = render_rig_image(
                small, w.physical_rig, w.rig_pose if w.rig_in_view else None, rng,
                noise_grey=w.noise.image_noise_grey * w.noise.scale,
                blur_sigma_px=w.noise.image_blur_px * scale)
            self._preview = (key, image)
        return Frame(image=self._preview[1], timestamp_s=time.monotonic(), camera=self.name)

    def close(self) -> None:
        """Nothing to release."""
