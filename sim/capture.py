"""A simulated capture set-up: the world, its boards and cameras, its operator, its truth.

`micam simulate` builds one of these and runs the real capture sequencer on it; nothing here
writes a session.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from acquisition.contracts.burst import (
    BurstConfig,
    MlsOrder,
    Periods,
    folding,
    holds_the_room,
    steady_mls_order,
)
from acquisition.contracts.camera import Camera
from acquisition.contracts.capture_config import (
    BoardEntry,
    CameraEntry,
    CaptureConfig,
    ColumnEntry,
    ReferenceMicEntry,
    RigEntry,
    SpeakerEntry,
)
from acquisition.contracts.rig_description import KnownLayout
from daq import Board, InputChannel, OutputChannel, SyncGroup, board_model

from .air_sensor import SimulatedAirSensor
from .arrays import ARRAY_KINDS, ArrayLayout, array_layout
from .analog_bench import AcousticBench
from .boards import SimulatedBoard
from .cameras import SimulatedCamera
from .geometry import Rig, RigidTransform
from .lab import EFFECTS, LabEffects
from .mistakes import parse_mistake
from .mistakes.plan import NO_MISTAKES, Mistakes
from .mistakes.planner import PlanContext, plan_mistakes
from .simulated_operator import SimulatedOperator, reference_stand_position
from .poses import sample_poses
from .setups import Setups
from .world import NoiseModel, World

if TYPE_CHECKING:
    from .jack_world import WorldProcess


class SimulationOptions(BaseModel):
    """The knobs of a simulated capture (all of them, so that a session can be resumed)."""

    model_config = ConfigDict(frozen=True)

    array: str = "sphere72"
    poses: int = Field(default=20, ge=1, le=10_000)
    distance_m: tuple[float, float] = (0.6, 1.0)
    seed: int = 0
    noise: float = Field(default=1.0, ge=0.0, description="scale of every noise; 0 = none")
    temperature_c: float = Field(default=20.0, ge=-40.0, le=60.0)
    mls_order: MlsOrder = 14
    mls_periods: Periods | None = Field(
        default=None,
        description="periods of the sequence per burst (BurstConfig); None: 2 where the "
                    "period is long enough for it (MIN_STEADY_PERIOD_S), 1 for shorter ones")
    body_diffraction: bool = False
    backend: Literal["sim", "usb-emulated", "audio"] = Field(
        default="sim",
        description="plain simulated boards, the real USB driver on emulated USB boards, or "
                    "the audio backend on a real audio server, the world a JACK client "
                    "between its ports (sim.jack_world: needs jackd and JACK-Client)",
    )
    lab: Literal["ideal", "realistic"] = Field(
        default="ideal",
        description="the lab's profile: 'ideal' (point speakers at their stated positions, "
                    "exact print, identical microphones, still air, free field) or "
                    "'realistic' (every effect of sim.lab on)",
    )
    effects: tuple[str, ...] = Field(default=(), description="lab effects added to the profile")
    description_mistake: Literal["none", "turned-pattern", "sample-rate"] = Field(
        default="none",
        description="a mistake in the capture's description, for testing that calibration "
                    "catches it: 'turned-pattern' states the speakers as seen from the "
                    "pattern's opposite corner (a print of the other colour convention), "
                    "'sample-rate' states a sample rate 10 % above the clock's")
    without_effects: tuple[str, ...] = Field(
        default=(), description="lab effects removed from the profile")
    mistakes: tuple[str, ...] = Field(
        default=(), description="mistakes the world makes, each NAME or NAME=ARG,... "
                                "(sim.mistakes; docs/simulation.md, \"Mistakes\")")

    @field_validator("mistakes")
    @classmethod
    def _known_mistakes(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        """Each mistake well formed (SimulationInputError, not a ValueError, so that it
        reaches the user as its own one-line message); whether the world can make it is
        checked when the world is built."""
        for text in v:
            parse_mistake(text)
        return v

    @field_validator("effects", "without_effects")
    @classmethod
    def _known_effects(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = sorted(set(v) - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown lab effect(s) {', '.join(unknown)}; choose from "
                             f"{', '.join(EFFECTS)}")
        return v

    def lab_effects(self) -> LabEffects:
        """The lab's effects: the profile's, plus `effects`, minus `without_effects`."""
        names = set(EFFECTS if self.lab == "realistic" else ())
        names = (names | set(self.effects)) - set(self.without_effects)
        return LabEffects.with_effects(tuple(n for n in EFFECTS if n in names))

    @field_validator("array")
    @classmethod
    def _known_array(cls, v: str) -> str:
        if v not in ARRAY_KINDS:
            raise ValueError(f"unknown array {v!r}; choose one of {', '.join(ARRAY_KINDS)}")
        return v

    @field_validator("distance_m")
    @classmethod
    def _distance_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0.2 <= v[0] <= v[1] <= 5.0:
            raise ValueError(f"distance range {v} must satisfy 0.2 <= min <= max <= 5 m")
        return v

    @model_validator(mode="after")
    def _periods_fit(self) -> SimulationOptions:
        fs = World.sample_rate_hz
        problem = folding(self.mls_order, self.burst(fs).periods, fs)
        if problem is not None:
            raise ValueError(f"{problem}; simulate with --mls-order {steady_mls_order(fs)} or "
                             "more, or --mls-periods 1")
        return self

    def burst(self, sample_rate_hz: float) -> BurstConfig:
        """The bursts of the capture: `mls_periods` periods, or by default two (the
        room-proof steady state) where the sequence is long enough to hold the room, one
        otherwise (the short bursts of quick tests)."""
        periods = self.mls_periods
        if periods is None:
            periods = 2 if holds_the_room(self.mls_order, sample_rate_hz) else 1
        return BurstConfig(mls_order=self.mls_order, periods=periods)


@dataclass
class SimulatedCapture:
    """Everything the capture sequencer needs, plus the world that holds the truth (and, on
    the audio backend, the JACK client that plays it: `close` ends it)."""

    options: SimulationOptions
    world: World
    bench: AcousticBench
    group: SyncGroup
    cameras: list[Camera]
    operator: SimulatedOperator
    config: CaptureConfig
    poses: list[RigidTransform]
    air_sensor: SimulatedAirSensor | None = None
    mistakes: Mistakes = NO_MISTAKES
    world_process: WorldProcess | None = None

    def close(self) -> None:
        """Close the boards and cameras (and end the world's JACK client)."""
        self.group.close()
        for camera in self.cameras:
            camera.close()
        if self.world_process is not None:
            self.world_process.close()


def rig_entry(rig: Rig) -> RigEntry:
    """The capture configuration's description of the simulated rig."""
    return RigEntry(corners_x=rig.corners_x, corners_y=rig.corners_y, square_m=rig.square_m,
                    speakers_m=tuple(tuple(p) for p in rig.speakers_m),
                    reference_mark_m=tuple(rig.reference_mark_m),
                    speaker_diameter_m=rig.speaker_diameter_m, origin_square=rig.origin_square)


def nominal_layout(layout: ArrayLayout) -> KnownLayout:
    """The array's nominal layout as its maker would state it, for the session's description:
    the simulated array is built exactly to its microphone positions (metres, camera-0 frame;
    the calibration places the layout rigidly, so its frame does not matter). A mistake of the
    cables (sim.mistakes) leaves it as it is: it is what the array was built to."""
    return KnownLayout(mic_ids=tuple(range(layout.n_mics)),
                       positions_m=tuple((float(x), float(y), float(z))
                                         for x, y, z in layout.mic_positions_m),
                       source=f"the simulated array {layout.name}")


def capture_config_for(layout: ArrayLayout, rig: Rig, n_poses: int, sample_rate_hz: float,
                       burst: BurstConfig, cameras: list[Camera]) -> CaptureConfig:
    """The capture configuration of a simulated array: every wired input, in board order."""
    wired: dict[int, list[tuple[int, Literal["mic", "reference"], int | None]]] = {}
    for m, ref in enumerate(layout.mic_inputs):
        wired.setdefault(ref.board, []).append((ref.channel, "mic", m))
    ref = layout.reference_input
    wired.setdefault(ref.board, []).append((ref.channel, "reference", None))
    outputs: dict[int, list[int]] = {}
    for out in layout.speaker_outputs:
        outputs.setdefault(out.board, []).append(out.channel)
    boards, columns = [], []
    for b, spec in enumerate(layout.boards):
        model = board_model(spec.model)
        chans = sorted(wired.get(b, []))
        boards.append(BoardEntry(
            model=spec.model, serial=spec.serial,
            inputs=tuple(InputChannel(channel=c, range_v=model.input_ranges_v[0])
                         for c, _, _ in chans),
            outputs=tuple(OutputChannel(channel=c, range_v=model.output_range_v or 10.0)
                          for c in sorted(outputs.get(b, []))),
        ))
        columns += [ColumnEntry(board=spec.serial, channel=c, range_v=model.input_ranges_v[0],
                                role=role, mic_id=mic) for c, role, mic in chans]
    speakers = tuple(
        SpeakerEntry(index=k, board=layout.boards[o.board].serial, output_channel=o.channel,
                     rig_position_m=tuple(rig.speakers_m[k]))
        for k, o in enumerate(layout.speaker_outputs)
    )
    return CaptureConfig(
        sample_rate_hz=sample_rate_hz,
        boards=tuple(boards),
        columns=tuple(columns),
        speakers=speakers,
        reference=ReferenceMicEntry(board=layout.boards[ref.board].serial, channel=ref.channel),
        burst=burst,
        rig=rig_entry(rig),
        cameras=tuple(CameraEntry(name=c.name, device_id=c.device_id) for c in cameras),
        n_poses=n_poses,
        layout=nominal_layout(layout),
    )


def _boards_for(options: SimulationOptions, layout: ArrayLayout,
                bench: AcousticBench) -> list[Board]:
    """The boards of the chosen backend, wired to `bench`."""
    if options.backend == "usb-emulated":
        from .usb import emulated_boards

        return emulated_boards(bench, [(b.model, b.serial) for b in layout.boards])
    return [SimulatedBoard(spec, bench) for spec in layout.boards]


def world_for(options: SimulationOptions) -> tuple[World, list[RigidTransform]]:
    """The world of `options` and its rig poses (the same for the same options, in any
    process: the audio backend's JACK client builds its own)."""
    layout = array_layout(options.array)
    rig = Rig()
    world = World(layout=layout, rig=rig, temperature_c=options.temperature_c,
                  noise=NoiseModel(scale=options.noise), seed=options.seed,
                  body_diffraction=options.body_diffraction, lab=options.lab_effects())
    poses = sample_poses(layout.cameras[0], rig, options.poses, options.distance_m,
                         np.random.default_rng([options.seed, 4]))
    return world, poses


def build_simulated_capture(options: SimulationOptions) -> SimulatedCapture:
    """Build the simulated world for `options` and the hardware to capture it: plain simulated
    boards, or (backend "usb-emulated") the real USB driver talking to emulated boards, both
    wired to the same bench, so that both record the same samples for the same seed. The
    audio backend's capture is `sim.audio_capture` (`sim.backends.build_capture` chooses)."""
    if options.backend == "audio":
        raise ValueError("the audio backend's simulated capture is built by "
                         "sim.backends.build_capture (sim.audio_capture)")
    world, poses = world_for(options)
    layout, rig = world.layout, world.rig
    setups = Setups()  # the noise is keyed by what is captured (sim.setups)
    sim_cameras = [SimulatedCamera(m, world, i, setups) for i, m in enumerate(layout.cameras)]
    cameras: list[Camera] = list(sim_cameras)
    stated_rig = rig.turned() if options.description_mistake == "turned-pattern" else rig
    stated_rate = world.sample_rate_hz * (1.1 if options.description_mistake == "sample-rate"
                                          else 1.0)
    # the periods are chosen at the stated rate: the capture configuration is checked at it
    config = capture_config_for(layout, stated_rig, options.poses, stated_rate,
                                options.burst(stated_rate), cameras)
    mistakes = plan_mistakes(options.mistakes, PlanContext(layout, config, world, poses))
    for camera in sim_cameras:  # the cameras' names are in the configuration the plan reads
        camera.mistakes = mistakes
    bench = AcousticBench(world, setups, mistakes)
    hardware = _boards_for(options, layout, bench)
    operator = SimulatedOperator(world, poses, reference_stand_position(layout.cameras[0]),
                                 setups, mistakes)
    air_sensor = SimulatedAirSensor(world) if world.lab.air_sensor is not None else None
    return SimulatedCapture(options, world, bench, SyncGroup(hardware), cameras,
                            operator, config, poses, air_sensor, mistakes)


def truth_document(sim: SimulatedCapture) -> dict:
    """The ground truth of a simulated capture, in the shape of a calibration result.

    Positions are in the camera-0 frame (OpenCV convention), metres. `speed_of_sound_m_s` is
    the mean over the poses (the air drifts in the realistic lab; every pose's own is in
    `poses`); a pose's `speakers_m` are the speakers' acoustic centres (at the lab model's
    reference frequency), `diaphragms_m` their diaphragms.
    """
    w = sim.world
    layout = w.layout
    progress = w.session_progress
    poses, pose_c = [], []
    for i, p in enumerate(sim.poses):
        w.set_session_progress(i / max(len(sim.poses) - 1, 1))
        pose_c.append(w.speed_of_sound_m_s)
        saved = w.rig_pose
        w.rig_pose = p
        poses.append({"index": i, "rig_to_cam0": p.to_json(),
                      "speakers_m": w.acoustic_centres_m().tolist(),
                      "diaphragms_m": w.speaker_positions().tolist(),
                      "speed_of_sound_m_s": w.speed_of_sound_m_s,
                      "temperature_c": w.air_temperature_c})
        w.rig_pose = saved
    w.set_session_progress(0.0)
    start_c = w.speed_of_sound_m_s
    w.set_session_progress(progress)
    return {
        "microphones": [
            {"id": m, "position_m": layout.mic_positions_m[m].tolist(),
             "board": layout.boards[layout.mic_inputs[m].board].serial,
             "channel": layout.mic_inputs[m].channel}
            for m in range(layout.n_mics)
        ],
        "speed_of_sound_m_s": float(np.mean(pose_c)) if pose_c else start_c,
        "speed_of_sound_at_start_m_s": start_c,
        "temperature_c": w.temperature_c,
        "relative_humidity": w.relative_humidity,
        "pressure_pa": w.pressure_pa,
        "cameras": [c.to_json() for c in layout.cameras],
        "poses": poses,
        "reference_microphone": {
            "stand_position_m": sim.operator.stand_position_m.tolist(),
            "distance_from_speaker_m": w.reference_distance_m,
            "refmic_rig_to_cam0": sim.operator.rig_pose_on_stand().to_json(),
        },
        "board_latencies_s": {b.serial: float(lat)
                              for b, lat in zip(layout.boards, w.board_latencies_s, strict=True)},
        "mic_gains": w.mic_gains.tolist(),
        "rig": w.rig.to_json(),
        "lab": w.lab_truth.to_json(),
        "mistakes": list(sim.mistakes.records),
        "noise": {"scale": w.noise.scale,
                  "array_noise_v": w.noise.array_noise_v,
                  "reference_noise_v": w.noise.reference_noise_v,
                  "image_noise_grey": w.noise.image_noise_grey * w.noise.scale,
                  "image_blur_px": w.noise.image_blur_px},
        "simulation": sim.options.model_dump(mode="json"),
    }
