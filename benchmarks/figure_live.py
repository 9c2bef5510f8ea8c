"""The pictures of docs/live.md: a frame of the live view on the simulated world.

The 72-microphone sphere's camera 0 looks at the demo scene (sim.live_scene.demo_scene: a
speaker playing 4 kHz carried around a loop 1 m away, a 1.6 kHz speaker standing at the
right, broadband noise from the top left 2.5 m away), 1.6 s into it. The live imager maps the
4 kHz third octave on the plane 1 m in front of the camera (101 x 101 points, 0.1 s window),
once by delay-and-sum and once by CLEAN-SC, and draws each over the simulated camera's frame
of that moment, exactly as `micam live video` does. Prints how far each map's peak is from
the speaker's true projection.

    .venv/bin/python benchmarks/figure_live.py [--out docs/figures]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from calibration.figures.style import save_palette_png
from imaging.geometry import geometry_from_dict
from imaging.live import LiveImager, LiveSettings
from imaging.live_frames import MapFrames, caption_of
from sim.arrays import array_layout
from sim.live_light import render_scene_image
from sim.live_scene import demo_scene, world_truth
from sim.world import World

FS = 96_000.0
AT_S = 1.6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures"))
    args = parser.parse_args()
    world = World(layout=array_layout("sphere72"), seed=0)
    geometry = geometry_from_dict(world_truth(world))
    scene = demo_scene(world)
    camera = world.layout.cameras[0]
    rng = np.random.default_rng(0)
    end = round(AT_S * FS)
    volts = scene.mic_volts(0, end) + world.noise.array_noise_v * rng.standard_normal(
        (end, world.layout.n_mics))
    for name, clean in (("live-das.png", False), ("live-clean-sc.png", True)):
        imager = LiveImager(geometry, LiveSettings(clean_sc=clean, image_scale=0.5), FS)
        frames = MapFrames(imager, 1.0 / AT_S, caption_of(imager))
        window = imager.csm.window_samples
        centre = end - window // 2
        frames.add_frame(centre, render_scene_image(camera, scene.positions_at(centre / FS),
                                                    rng))
        drawn = frames.push(0, volts)  # the whole window at once: one frame, at its end
        if not drawn:
            raise RuntimeError("no frame came due")
        frame = drawn[-1]
        truth = camera.project(scene.sources[0].trajectory.at(
            (frame.live_map.end_sample - window / 2) / FS))[0]
        save_palette_png(Image.fromarray(cv2.cvtColor(frame.image, cv2.COLOR_BGR2RGB)),
                         args.out / name)
        print(f"{args.out / name}: peak {np.linalg.norm(frame.live_map.peak_px - truth):.2f} "
              f"px from the speaker's projection, {frame.live_map.n_components} components")


if __name__ == "__main__":
    main()
