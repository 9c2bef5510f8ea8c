"""From the asked-for mistakes to the one `Mistakes` a world makes, and its truth.

Each mistake is resolved here once, for the whole session: its missing arguments drawn from
the session's seed (a generator of its own per kind and occurrence, so that adding one mistake
leaves the others' choices alone), checked against the world (the microphone, speaker, pose or
camera exists; no two mistakes contradict), and written down as a truth record that says
exactly what was done, with micam's 0-based numbers (README, "Numbering"). The kinds are
resolved in an order that lets later ones see earlier ones: the cables first (a capsule's
column is where its cable goes), then the operator (where the rig really is during the
bursts), the speakers, the capsules (a dropout falls while its microphone hears the burst),
the inputs' clipping (on the live microphones nearest the speaker that really plays), the
images.

A record's lists: "microphones" (ids), "columns" (the recording columns, in the order of the
capture configuration's columns, where the mistake shows), "boards" (serials) and "channels"
(board channels) of those columns, "speakers", "poses", "cameras" (indices), "steps" (step
ids); magnitudes in SI units unless their key names another unit (`_mm`, `_deg`, `_px`).
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.step_ids import pose_step, reference_step
from kernel.stimulus import mls_length

from ..arrays import ArrayLayout, ChannelRef
from ..errors import SimulationInputError
from ..geometry import RigidTransform, rotation_from_rotvec
from ..poses import in_view
from ..setups import Key, pose_setup
from ..world import World
from .images import Glare, MotionBlur, Occluder
from .plan import NO_MISTAKES, Echo, ImageEffect, Mistakes, Recording
from .spec import MistakeSpec, parse_mistake

_SEED_STREAM = 8
"""The world's seed streams (sim.world, sim.capture) use 1-7; mistakes draw from this one."""


@dataclass(frozen=True)
class PlanContext:
    """What the planner needs to know of the world: its array and wiring, the capture's
    configuration (columns, burst), the world (physical rig, seed) and the rig's poses."""

    layout: ArrayLayout
    config: CaptureConfig
    world: World
    poses: Sequence[RigidTransform]


def plan_mistakes(texts: Sequence[str], context: PlanContext) -> Mistakes:
    """The world's mistakes for `texts` (`NAME[=ARGS]` each); SimulationInputError for a
    mistake that cannot be made in this world or contradicts another."""
    if not texts:
        return NO_MISTAKES
    specs = [parse_mistake(t) for t in texts]
    planner = _Planner(context)
    seen: Counter[str] = Counter()
    rngs = []
    for spec in specs:
        name = spec.kind.name
        rngs.append(np.random.default_rng([context.world.seed, _SEED_STREAM,
                                           zlib.crc32(name.encode()), seen[name]]))
        seen[name] += 1
    order = sorted(range(len(specs)), key=lambda i: planner.rank(specs[i]))
    records: dict[int, dict] = {}
    for i in order:
        records[i] = {"kind": specs[i].kind.name, **planner.resolve(specs[i], rngs[i])}
    return planner.build(tuple(records[i] for i in range(len(specs))))


class _Planner:
    """Collects what each mistake does to each layer (see `plan_mistakes`)."""

    def __init__(self, context: PlanContext) -> None:
        self.ctx = context
        layout = context.layout
        self.n_mics = layout.n_mics
        self.n_speakers = len(layout.speaker_outputs)
        self.n_poses = len(context.poses)
        self.positions = list(range(self.n_mics))  # where each cable is: the input of that id
        self.speaker_outputs = list(layout.speaker_outputs)
        self.swapped_mics: dict[int, str] = {}  # microphone -> the swap that moved its cable
        self.swapped: dict[int, str] = {}  # speaker -> the swap that moved its cable
        self.capsule: dict[tuple[int, str], str] = {}  # (microphone, kind) -> its mistake
        self.factors = np.ones(self.n_mics)
        self.echoes: list[Echo] = []
        self.saturation: dict[int, float] = {}
        self.silent: dict[int, frozenset[Key] | None] = {}
        self.dropouts: dict[Recording, list[tuple[int, tuple[tuple[int, int], ...]]]] = {}
        self.clipping: dict[Recording, tuple[int, ...]] = {}
        self.clip_fraction = 1.0
        self.moved: dict[int, RigidTransform] = {}
        self.reference_m: dict[int, float] = {}
        self.scenes: dict[tuple[int, int], list[ImageEffect]] = {}
        self.scene_kinds: set[tuple[int, int, str]] = set()
        self.jpeg: int | None = None
        self.once: set[str] = set()
        self._columns = {(c.board, c.channel): j for j, c in enumerate(context.config.columns)}
        # in the order they are resolved in (see the module docstring)
        self._resolvers: dict[str, Callable[[MistakeSpec, np.random.Generator], dict]] = {
            "swap-mics": self._swap_mics, "board-shift": self._board_shift,
            "swap-speakers": self._swap_speakers, "moved-pose": self._moved_pose,
            "refmic-far": self._refmic_far, "silent-speaker": self._silent_speaker,
            "distorted-speaker": self._distorted_speaker, "dead-mic": self._dead_mic,
            "inverted-mic": self._inverted_mic, "intermittent-mic": self._intermittent_mic,
            "close-reflector": self._close_reflector, "clipped-bursts": self._clipped_bursts,
            "hidden-board": self._hidden_board, "motion-blur": self._motion_blur,
            "glare": self._glare, "mjpeg": self._mjpeg,
        }

    def rank(self, spec: MistakeSpec) -> int:
        """Where `spec`'s kind comes in the order of resolution."""
        return list(self._resolvers).index(spec.kind.name)

    def resolve(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        return self._resolvers[spec.kind.name](spec, rng)

    @property
    def mic_inputs(self) -> list[ChannelRef]:
        """The board input each microphone's cable is on now."""
        return [self.ctx.layout.mic_inputs[p] for p in self.positions]

    def build(self, records: tuple[dict, ...]) -> Mistakes:
        """The plan; the cables' records get the columns their microphones are recorded in
        after every cable mistake (a swap and a board shift compose)."""
        for record in records:
            if "recorded_in_columns" in record:
                record["recorded_in_columns"] = self._input_fields(record["microphones"])[
                    "columns"]
        rewired = self.positions != list(range(self.n_mics))
        return Mistakes(
            records=records,
            mic_inputs=tuple(self.mic_inputs) if rewired else None,
            speaker_outputs=tuple(self.speaker_outputs) if self.swapped else None,
            mic_factors=self.factors if np.any(self.factors != 1.0) else None,
            echoes=tuple(self.echoes), saturation=self.saturation, silent=self.silent,
            dropouts={k: tuple(v) for k, v in self.dropouts.items()},
            clipping=self.clipping, clip_fraction=self.clip_fraction,
            moved_poses=self.moved, reference_distances_m=self.reference_m,
            scenes={k: tuple(v) for k, v in self.scenes.items()}, jpeg_quality=self.jpeg)

    # -- numbers, columns and checks ---------------------------------------------------------

    @staticmethod
    def _fail(spec: MistakeSpec, why: str) -> SimulationInputError:
        return SimulationInputError(f"mistake {spec.text!r}: {why}")

    def _index(self, spec: MistakeSpec, position: int, count: int, what: str,
               rng: np.random.Generator, choices: Sequence[int] | None = None) -> int:
        """Argument `position`, a `what` number below `count`, or (not given) one of
        `choices` (default: all) drawn from `rng`."""
        given = spec.arg(position)
        if given is None:
            pool = list(range(count)) if choices is None else list(choices)
            if not pool:
                raise self._fail(spec, f"no {what} is left for it (other mistakes took them)")
            return int(pool[int(rng.integers(len(pool)))])
        if not 0 <= int(given) < count:
            raise self._fail(spec, f"there is no {what} {int(given)} ({_numbers(what, count)})")
        return int(given)

    def _value(self, spec: MistakeSpec, position: int, default: float) -> float:
        given = spec.arg(position)
        return default if given is None else float(given)

    def _only_once(self, spec: MistakeSpec) -> None:
        if spec.kind.name in self.once:
            raise self._fail(spec, f"{spec.kind.name} is asked for twice; ask for it once")
        self.once.add(spec.kind.name)

    def _column(self, ref: ChannelRef) -> int:
        return self._columns[(self.ctx.layout.boards[ref.board].serial, ref.channel)]

    def _input_fields(self, mics: Sequence[int]) -> dict:
        """"columns", "boards", "channels": where the microphones' signals are recorded."""
        inputs = self.mic_inputs
        refs = [inputs[m] for m in mics]
        return {"columns": [self._column(r) for r in refs],
                "boards": [self.ctx.layout.boards[r.board].serial for r in refs],
                "channels": [r.channel for r in refs]}

    def _output_fields(self, speakers: Sequence[int]) -> dict:
        """"boards", "channels": the outputs that really drive the speakers."""
        refs = [self.speaker_outputs[s] for s in speakers]
        return {"boards": [self.ctx.layout.boards[r.board].serial for r in refs],
                "channels": [r.channel for r in refs]}

    def _driven_by(self, speaker: int) -> int:
        """The speaker whose output really drives `speaker`: its bursts are recorded in that
        speaker's files (itself unless the cables are swapped)."""
        return self.ctx.layout.speaker_outputs.index(self.speaker_outputs[speaker])

    def _plays(self, speaker: int) -> int:
        """The speaker that plays when `speaker`'s output is driven."""
        return self.speaker_outputs.index(self.ctx.layout.speaker_outputs[speaker])

    def _never_plays(self, speaker: int) -> bool:
        return speaker in self.silent and self.silent[speaker] is None

    def _capsule(self, spec: MistakeSpec, rng: np.random.Generator) -> int:
        """The microphone of a capsule mistake, checked against the others on it: a dead one
        takes no other, and none is made twice."""
        kind = spec.kind.name
        taken = {mm for mm, _ in self.capsule}
        m = self._index(spec, 0, self.n_mics, "microphone", rng,
                        [k for k in range(self.n_mics) if k not in taken])
        if (m, kind) in self.capsule:
            raise self._fail(spec, f"microphone {m} already has {self.capsule[(m, kind)]!r}")
        others = {k: t for (mm, k), t in self.capsule.items() if mm == m}
        if others and (kind == "dead-mic" or "dead-mic" in others):
            raise self._fail(spec, f"contradicts {next(iter(others.values()))!r}: a dead "
                                   f"microphone {m} has nothing else to get wrong")
        self.capsule[(m, kind)] = spec.text
        return m

    # -- the cables --------------------------------------------------------------------------

    def _mics_on(self, board: int) -> list[int]:
        """The microphones configured on board `board`, by channel."""
        on = [(r.channel, m) for m, r in enumerate(self.ctx.layout.mic_inputs) if r.board == board]
        return [m for _, m in sorted(on)]

    def _swap_mics(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        layout = self.ctx.layout
        if spec.arg(0) is None:  # two free neighbours on one board
            pairs = [(on[k], on[k + 1]) for on in map(self._mics_on, range(len(layout.boards)))
                     for k in range(len(on) - 1)
                     if on[k] not in self.swapped_mics and on[k + 1] not in self.swapped_mics]
            if not pairs:
                raise self._fail(spec, "no two neighbouring microphones are left to swap")
            a, b = pairs[int(rng.integers(len(pairs)))]
        else:
            a = self._index(spec, 0, self.n_mics, "microphone", rng)
            on = self._mics_on(layout.mic_inputs[a].board)
            k = on.index(a)
            neighbours = [on[j] for j in (k + 1, k - 1) if 0 <= j < len(on)]
            free = [m for m in neighbours if m not in self.swapped_mics] or neighbours
            b = self._index(spec, 1, self.n_mics, "microphone", rng, free[:1])
        if a == b:
            raise self._fail(spec, f"swaps microphone {a} with itself; name two microphones")
        for m in (a, b):
            if m in self.swapped_mics:
                raise self._fail(spec, f"contradicts {self.swapped_mics[m]!r}, which swaps the "
                                       f"cable of microphone {m} too")
        self.swapped_mics.update(dict.fromkeys((a, b), spec.text))
        configured = self._input_fields((a, b))
        self.positions[a], self.positions[b] = self.positions[b], self.positions[a]
        return {"microphones": [a, b], **configured, "recorded_in_columns": []}

    def _board_shift(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        self._only_once(spec)
        layout = self.ctx.layout
        boards = int(self._value(spec, 0, 1))
        array_boards = [b for b in range(len(layout.boards)) if self._mics_on(b)]
        shift = boards * len(self._mics_on(array_boards[0]))
        if boards == 0 or shift % self.n_mics == 0:
            raise self._fail(spec, f"a shift of {boards} boards puts every microphone back on "
                                   "its own input; shift by 1 or -1")
        configured = [self._column(r) for r in layout.mic_inputs]
        # the boards' connectors moved: whatever cable was on input position p is on p + shift
        self.positions = [(p + shift) % self.n_mics for p in self.positions]
        return {"boards_shifted": boards, "shift_columns": shift,
                "microphones": list(range(self.n_mics)), "columns": configured,
                "boards": [layout.boards[b].serial for b in array_boards],
                "recorded_in_columns": []}

    def _swap_speakers(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        outputs = self.ctx.layout.speaker_outputs
        if spec.arg(0) is None:  # two free speakers of one board
            pairs = [(a, b) for a in range(self.n_speakers) for b in range(a + 1, self.n_speakers)
                     if outputs[a].board == outputs[b].board
                     and a not in self.swapped and b not in self.swapped]
            if not pairs:
                raise self._fail(spec, "no two speakers of one board are left to swap")
            a, b = pairs[int(rng.integers(len(pairs)))]
        else:
            a = self._index(spec, 0, self.n_speakers, "speaker", rng)
            same = [s for s, o in enumerate(outputs) if o.board == outputs[a].board and s != a]
            b = self._index(spec, 1, self.n_speakers, "speaker", rng,
                            same or [s for s in range(self.n_speakers) if s != a])
        if a == b:
            raise self._fail(spec, f"swaps speaker {a} with itself; name two speakers")
        for s in (a, b):
            if s in self.swapped:
                raise self._fail(spec, f"contradicts {self.swapped[s]!r}, which swaps the "
                                       f"cable of speaker {s} too")
        self.swapped.update(dict.fromkeys((a, b), spec.text))
        self.speaker_outputs[a], self.speaker_outputs[b] = outputs[b], outputs[a]
        return {"speakers": [a, b],
                "boards": [self.ctx.layout.boards[outputs[s].board].serial for s in (a, b)],
                "channels": [outputs[s].channel for s in (a, b)],
                "played_by": [self._plays(a), self._plays(b)]}

    # -- the capsules ------------------------------------------------------------------------

    def _inverted_mic(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        m = self._capsule(spec, rng)
        self.factors[m] = -1.0
        return {"microphones": [m], **self._input_fields([m])}

    def _dead_mic(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        m = self._capsule(spec, rng)
        self.factors[m] = 0.0
        return {"microphones": [m], **self._input_fields([m])}

    def _pose_recordings(self) -> list[tuple[int, int]]:
        """(pose, speaker) of every pose recording, in capture order."""
        return [(p, s) for p in range(self.n_poses) for s in range(self.n_speakers)]

    def _arrival_samples(self, mic: int, pose: int, speaker: int) -> int:
        """When (samples after the burst starts) the burst of `speaker`'s output reaches
        microphone `mic` at pose `pose` (the straight path, to a sample)."""
        w = self.ctx.world
        rig = self.moved.get(pose, self.ctx.poses[pose])
        source = rig.apply(w.physical_rig.speakers_m[self._plays(speaker)])
        distance = float(np.linalg.norm(self.ctx.layout.mic_positions_m[mic] - source))
        return round(distance / w.speed_of_sound_m_s * self.ctx.config.sample_rate_hz)

    def _intermittent_mic(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        m = self._capsule(spec, rng)
        fraction = self._value(spec, 1, 0.3)
        recordings = self._pose_recordings()
        count = max(1, round(fraction * len(recordings)))
        burst = self.ctx.config.burst
        length = burst.periods * mls_length(burst.mls_order)
        chosen = sorted(int(i) for i in rng.choice(len(recordings), count, replace=False))
        listed = []
        for i in chosen:
            pose, speaker = recordings[i]
            # while the microphone hears the burst: from its arrival to its end
            heard = burst.pre_samples + self._arrival_samples(m, pose, speaker)
            stretches = []
            for _ in range(int(rng.integers(1, 4))):
                n = max(1, int(rng.uniform(0.05, 0.25) * length))
                start = heard + int(rng.integers(0, max(1, length - n)))
                stretches.append((start, start + n))
            self.dropouts.setdefault((pose_setup(pose), speaker), []).append(
                (m, tuple(stretches)))
            listed.append({"step": pose_step(pose), "pose": pose, "speaker": speaker,
                           "samples": [list(s) for s in stretches]})
        return {"microphones": [m], **self._input_fields([m]), "fraction": fraction,
                "poses": sorted({r["pose"] for r in listed}), "recordings": listed}

    def _close_reflector(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        m = self._capsule(spec, rng)
        delay_s = 1e-6 * self._value(spec, 1, float(rng.uniform(10.0, 20.0)))
        gain = self._value(spec, 2, float(rng.uniform(0.3, 0.5)))
        self.echoes.append(Echo(m, delay_s, gain))
        return {"microphones": [m], **self._input_fields([m]), "delay_s": delay_s,
                "delay_samples": delay_s * self.ctx.config.sample_rate_hz, "gain": gain}

    # -- the speakers ------------------------------------------------------------------------

    def _silent_speaker(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        poses = [int(p) for p in spec.args[1:]]
        # silent all session, a speaker whose reference microphone was misplaced would hide
        # that mistake: nothing it recorded could show it
        s = self._index(spec, 0, self.n_speakers, "speaker", rng,
                        [k for k in range(self.n_speakers) if k not in self.silent
                         and (poses or k not in self.reference_m)])
        if s in self.silent:
            raise self._fail(spec, f"speaker {s} is silent already; ask for it once")
        if not poses and s in self.reference_m:
            raise self._fail(spec, f"contradicts the reference microphone misplaced at speaker "
                                   f"{s}: silent all session, it never plays to show it")
        for p in poses:
            if not 0 <= p < self.n_poses:
                raise self._fail(spec, f"there is no pose {p} ({_numbers('pose', self.n_poses)})")
        if len(set(poses)) != len(poses):
            raise self._fail(spec, "names a pose twice")
        whole = not poses
        self.silent[s] = None if whole else frozenset(pose_setup(p) for p in poses)
        files = self._driven_by(s)
        steps = ([reference_step(files)] if whole else []) + [
            pose_step(p) for p in (range(self.n_poses) if whole else sorted(poses))]
        return {"speakers": [s], "whole_session": whole,
                "poses": list(range(self.n_poses)) if whole else sorted(poses),
                "steps": steps, "recorded_as_speaker": files, **self._output_fields([s])}

    def _distorted_speaker(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        # a distortion shows in the speaker's reference recording, made at its diaphragm; a
        # swapped speaker's is made at the other speaker, a hand's width away
        s = self._index(spec, 0, self.n_speakers, "speaker", rng,
                        [k for k in range(self.n_speakers) if k not in self.saturation
                         and not self._never_plays(k) and k not in self.swapped])
        if s in self.saturation:
            raise self._fail(spec, f"speaker {s} is distorted already; ask for it once")
        if self._never_plays(s):
            raise self._fail(spec, f"contradicts the silent speaker {s}: it never plays")
        if s in self.swapped:
            raise self._fail(spec, f"contradicts {self.swapped[s]!r}: speaker {s}'s reference "
                                   "recording is made at the other speaker, and a distortion "
                                   "shows only at its own diaphragm")
        drive = self._value(spec, 1, 3.0)
        self.saturation[s] = drive
        return {"speakers": [s], "drive": drive, "recorded_as_speaker": self._driven_by(s),
                **self._output_fields([s])}

    # -- the operator ------------------------------------------------------------------------

    def _moved_pose(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        p = self._index(spec, 0, self.n_poses, "pose", rng,
                        [k for k in range(self.n_poses) if k not in self.moved])
        if p in self.moved:
            raise self._fail(spec, f"pose {p} is moved already; ask for it once")
        mm = self._value(spec, 1, float(rng.uniform(5.0, 20.0)))
        deg = self._value(spec, 2, float(rng.uniform(1.0, 3.0)))
        direction, axis = rng.normal(size=3), rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        axis /= np.linalg.norm(axis)
        images = self.ctx.poses[p]
        # rig frame: x -> R_d (x - c) + c + t, a turn about the pattern's centre c and a shift
        R_d = rotation_from_rotvec(np.radians(deg) * axis)
        centre = self.ctx.world.rig.centre()
        t = 1e-3 * mm * direction
        bursts = images.compose(RigidTransform(R_d, centre - R_d @ centre + t))
        self.moved[p] = bursts
        w = self.ctx.world
        saved = w.rig_pose
        w.rig_pose = bursts
        speakers, diaphragms = w.acoustic_centres_m().tolist(), w.speaker_positions().tolist()
        w.rig_pose = saved
        return {"poses": [p], "steps": [pose_step(p)], "translation_mm": mm,
                "rotation_deg": deg, "translation_cam0_m": (images.R @ t).tolist(),
                "rotation_axis_cam0": (images.R @ axis).tolist(),
                "rig_to_cam0_images": images.to_json(), "rig_to_cam0_bursts": bursts.to_json(),
                "speakers_m_bursts": speakers, "diaphragms_m_bursts": diaphragms}

    def _refmic_far(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        # a swapped speaker's reference recording is of the other speaker, a hand's width
        # away: a few millimetres more in front of its own diaphragm could not show there
        s = self._index(spec, 0, self.n_speakers, "speaker", rng,
                        [k for k in range(self.n_speakers)
                         if k not in self.reference_m and k not in self.swapped])
        if s in self.reference_m:
            raise self._fail(spec, f"the reference microphone's distance from speaker {s} is "
                                   "set already; ask for it once")
        if s in self.swapped:
            raise self._fail(spec, f"contradicts {self.swapped[s]!r}: speaker {s}'s reference "
                                   "recording is of the other speaker, which nothing of a "
                                   "misplaced microphone could show")
        distance = 1e-3 * self._value(spec, 1, 6.0)
        self.reference_m[s] = distance
        return {"speakers": [s], "steps": [reference_step(s)], "distance_m": distance,
                "stated_distance_m": self.ctx.config.reference.distance_from_speaker_m}

    # -- the inputs' clipping ----------------------------------------------------------------

    def _clipped_bursts(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        self._only_once(spec)
        fraction = self._value(spec, 0, 0.35)
        dead = {m for (m, k) in self.capsule if k == "dead-mic"}
        alive = np.array([m for m in range(self.n_mics) if m not in dead])
        count = int(self._value(spec, 1, min(4, alive.size)))
        if count > alive.size:
            raise self._fail(spec, f"COUNT {count} is more than the {alive.size} live "
                                   "microphones")
        self.clip_fraction = fraction
        w = self.ctx.world
        mics_m = self.ctx.layout.mic_positions_m[alive]
        listed = []
        for pose, speaker in self._pose_recordings():
            plays = self._plays(speaker)
            setup = pose_setup(pose)
            if self._never_plays(plays) or setup in (self.silent.get(plays) or ()):
                continue  # a silent speaker's recording has no burst to clip
            rig = self.moved.get(pose, self.ctx.poses[pose])
            source = rig.apply(w.physical_rig.speakers_m[plays])
            nearest = alive[np.argsort(np.linalg.norm(mics_m - source, axis=1))[:count]]
            mics = sorted(int(m) for m in nearest)
            self.clipping[(setup, speaker)] = tuple(mics)
            listed.append({"step": pose_step(pose), "pose": pose, "speaker": speaker,
                           "microphones": mics, **self._input_fields(mics)})
        union = sorted({m for r in listed for m in r["microphones"]})
        return {"fraction": fraction, "count": count, "poses": list(range(self.n_poses)),
                "microphones": union, "columns": self._input_fields(union)["columns"],
                "recordings": listed}

    # -- the images --------------------------------------------------------------------------

    def _board_in(self, camera: int, pose: int) -> np.ndarray | None:
        """The inner corners' pixels (n, 2) in camera `camera` at pose `pose`, or None when
        the whole pattern is not in its view."""
        model = self.ctx.layout.cameras[camera]
        corners = self.ctx.poses[pose].apply(self.ctx.world.physical_rig.corner_points())
        return model.project(corners) if in_view(model, corners, margin_px=10.0) else None

    def _image(self, spec: MistakeSpec, rng: np.random.Generator
               ) -> tuple[int, int, np.ndarray, dict]:
        """The pose and camera of an image mistake, the pattern's corners in that image and
        the record's fields for them."""
        cameras = self.ctx.layout.cameras
        kind = spec.kind.name

        def free(pose: int) -> list[int]:  # the cameras that see the board, not yet taken
            return [c for c in range(len(cameras)) if (pose, c, kind) not in self.scene_kinds
                    and self._board_in(c, pose) is not None]

        # a rig moved after its images shows only against a view the calibration measures,
        # and a view hidden, blurred or in glare is left out
        p = self._index(spec, 0, self.n_poses, "pose", rng,
                        [k for k in range(self.n_poses) if free(k) and k not in self.moved])
        if p in self.moved:
            raise self._fail(spec, f"contradicts the moved pose {p}: a rig moved after its "
                                   "images shows only against a view the calibration "
                                   f"measures, and a view with {kind} is left out")
        seeing = [c for c in range(len(cameras)) if self._board_in(c, p) is not None]
        if not seeing:
            raise self._fail(spec, f"no camera sees the whole board at pose {p}; choose "
                                   "another pose")
        c = self._index(spec, 1, len(cameras), "camera", rng, free(p) or seeing)
        corners = self._board_in(c, p)
        if corners is None:
            raise self._fail(spec, f"camera {c} does not see the whole board at pose {p}; "
                                   f"choose one that does ({', '.join(map(str, seeing))})")
        key = (p, c, kind)
        if key in self.scene_kinds:
            raise self._fail(spec, f"{spec.kind.name} is asked for twice in camera {c}'s image "
                                   f"at pose {p}; ask for it once")
        self.scene_kinds.add(key)
        return p, c, corners, {"poses": [p], "cameras": [c], "camera_names": [cameras[c].name],
                               "steps": [pose_step(p)]}

    def _add_scene(self, pose: int, camera: int, effect: ImageEffect) -> None:
        """Add an effect in front of a camera: the arms and highlights first, the motion blur
        of the whole view last."""
        effects = self.scenes.setdefault((pose, camera), [])
        effects.append(effect)
        effects.sort(key=lambda e: isinstance(e, MotionBlur))

    @staticmethod
    def _short_side_px(corners: np.ndarray, per_row: int) -> float:
        """The pattern's shorter side in the image, pixels (first row and first column)."""
        first_row = np.linalg.norm(corners[per_row - 1] - corners[0])
        first_column = np.linalg.norm(corners[-per_row] - corners[0])
        return float(min(first_row, first_column))

    def _hidden_board(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        p, c, corners, fields = self._image(spec, rng)
        target = self._value(spec, 2, float(rng.uniform(0.3, 0.6)))
        angle = float(rng.uniform(0.0, 2 * np.pi))
        arm = _arm_over(corners, target, angle,
                        0.25 * self._short_side_px(corners, self.ctx.world.rig.corners_x))
        self._add_scene(p, c, arm)
        hidden = np.flatnonzero(arm.covers(corners))
        return {**fields, "fraction": target, "hidden_fraction": hidden.size / len(corners),
                "hidden_corners": hidden.tolist(), "hand_px": list(arm.hand_px),
                "arm_direction": list(arm.direction), "arm_half_width_px": arm.half_width_px,
                "hand_radius_px": arm.hand_radius_px}

    def _motion_blur(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        p, c, _, fields = self._image(spec, rng)
        length = self._value(spec, 2, float(rng.uniform(8.0, 25.0)))
        angle = float(rng.uniform(0.0, 180.0))
        self._add_scene(p, c, MotionBlur(length, angle))
        return {**fields, "length_px": length, "angle_deg": angle}

    def _glare(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        p, c, corners, fields = self._image(spec, rng)
        per_row = self.ctx.world.rig.corners_x
        radius = self._value(spec, 2, float(rng.uniform(0.2, 0.35))
                             * self._short_side_px(corners, per_row))
        a, b = rng.uniform(0.25, 0.75, 2)
        quad = corners[[0, per_row - 1, len(corners) - 1, len(corners) - per_row]]
        centre = ((1 - a) * (1 - b) * quad[0] + a * (1 - b) * quad[1] + a * b * quad[2]
                  + (1 - a) * b * quad[3])
        self._add_scene(p, c, Glare((float(centre[0]), float(centre[1])), radius))
        inside = np.flatnonzero(np.linalg.norm(corners - centre, axis=1) < radius)
        return {**fields, "centre_px": centre.tolist(), "radius_px": radius,
                "corners_in_glare": inside.tolist()}

    def _mjpeg(self, spec: MistakeSpec, rng: np.random.Generator) -> dict:
        self._only_once(spec)
        self.jpeg = int(self._value(spec, 0, float(rng.choice([70, 75, 80, 85, 90]))))
        cameras = self.ctx.layout.cameras
        return {"cameras": list(range(len(cameras))),
                "camera_names": [m.name for m in cameras], "quality": self.jpeg}


def _numbers(what: str, count: int) -> str:
    """What a world has of `what`: "microphones 0-47", "camera 0 only"."""
    return f"{what}s 0-{count - 1}" if count > 1 else f"{what} 0 only"


def _arm_over(corners_px: np.ndarray, fraction: float, angle: float,
              half_width_px: float) -> Occluder:
    """An arm from outside the image along `angle` whose hand reaches just far enough over the
    board to hide `fraction` of its inner corners (`corners_px`): the smallest reach that
    does, by bisection; an arm too narrow to hide that many is widened."""
    centre = corners_px.mean(axis=0)
    direction = np.array([np.cos(angle), np.sin(angle)])
    extent = float(np.max(np.abs((corners_px - centre) @ direction)))
    need = int(np.ceil(fraction * len(corners_px)))
    width = half_width_px
    while True:
        radius = 1.3 * width

        def arm(reach: float, width: float = width, radius: float = radius) -> Occluder:
            hand = centre - reach * direction
            return Occluder((float(hand[0]), float(hand[1])),
                            (float(direction[0]), float(direction[1])), width, radius)

        low, high = -(extent + radius + 1.0), extent + radius + 1.0
        if int(arm(high).covers(corners_px).sum()) >= need:
            break
        width *= 1.3
    for _ in range(40):
        mid = 0.5 * (low + high)
        if int(arm(mid).covers(corners_px).sum()) >= need:
            high = mid
        else:
            low = mid
    return arm(high)
