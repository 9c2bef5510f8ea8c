"""Array layouts of the simulated world: microphones, cameras and how they are wired to boards.

Every layout is expressed in the frame of camera 0 (OpenCV convention: x right, y down,
z forward), the frame the calibration reports in. Microphones are assigned to board input
channels in order, as in the paper (3 x DT9836-12 + 6 x DT9816 = 72 inputs); the six rig
speakers hang on the analog outputs of the DT9836s; the reference microphone has an input of
its own on an extra DT9816-A, because the paper's reference microphone records on every pose
(for the speed of sound, section IV-G) while all 72 array inputs are in use.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .errors import SimulationInputError
from .geometry import CameraModel, RigidTransform, pinhole

REFERENCE_BOARD_SERIAL = "16099"
"""Serial of the extra DT9816-A that records the reference microphone. Serials are decimal, as
the boards' own 32-bit serial numbers are."""

ArrayKind = Literal["sphere72", "planar64", "scatter48", "scatter15"]
ARRAY_KINDS: tuple[str, ...] = ("sphere72", "planar64", "scatter48", "scatter15")


@dataclass(frozen=True)
class BoardSpec:
    """One board of the simulated hardware: its variant name and serial number."""

    model: str
    serial: str


@dataclass(frozen=True)
class ChannelRef:
    """A channel of a board: the board's index in `ArrayLayout.boards` and the channel number."""

    board: int
    channel: int


@dataclass(frozen=True)
class SphereBody:
    """A rigid sphere that carries the microphones (for the optional creeping-wave path)."""

    centre_m: np.ndarray
    radius_m: float


@dataclass(frozen=True)
class ArrayLayout:
    """A microphone array with its cameras and its wiring.

    Attributes:
        name: the layout's name ("sphere72", ...).
        mic_positions_m: (M, 3) microphone positions in the camera-0 frame.
        mic_normals: (M, 3) unit vectors the microphones face.
        cameras: the cameras; cameras[0] defines the frame.
        boards: the boards, in sync-group order; boards[0] is the clock and trigger master.
        mic_inputs: the input channel of each microphone.
        speaker_outputs: the output channel that drives each rig speaker.
        reference_input: the input channel of the reference microphone.
        body: the sphere the microphones sit on, if any.
    """

    name: str
    mic_positions_m: np.ndarray
    mic_normals: np.ndarray
    cameras: tuple[CameraModel, ...]
    boards: tuple[BoardSpec, ...]
    mic_inputs: tuple[ChannelRef, ...]
    speaker_outputs: tuple[ChannelRef, ...]
    reference_input: ChannelRef
    body: SphereBody | None = None

    @property
    def n_mics(self) -> int:
        return int(self.mic_positions_m.shape[0])


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (a Fibonacci lattice), none exactly at a pole."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _camera_on_sphere(name: str, centre: np.ndarray, radius: float, azimuth_deg: float
                      ) -> CameraModel:
    """A camera on the sphere's surface at `azimuth_deg` from the front, looking outward."""
    a = np.radians(azimuth_deg)
    normal = np.array([np.sin(a), 0.0, np.cos(a)])
    position = centre + radius * normal
    z_axis = normal
    y_axis = np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(y_axis, z_axis)
    R = np.stack([x_axis, y_axis, z_axis])  # rows: camera axes in the camera-0 frame
    return pinhole(name, cam0_to_cam=RigidTransform(R, -R @ position))


def _wire(n_mics: int, input_boards: list[BoardSpec], models_inputs: dict[str, int],
          n_speakers: int) -> tuple[tuple[BoardSpec, ...], tuple[ChannelRef, ...],
                                    tuple[ChannelRef, ...], ChannelRef]:
    """Assign microphones to input channels in board order, speakers to DT9836 outputs, and
    the reference microphone to channel 0 of an extra DT9816-A appended last."""
    mic_inputs: list[ChannelRef] = []
    for b, spec in enumerate(input_boards):
        for ch in range(models_inputs[spec.model]):
            if len(mic_inputs) < n_mics:
                mic_inputs.append(ChannelRef(b, ch))
    if len(mic_inputs) < n_mics:
        raise SimulationInputError(f"{n_mics} microphones need more inputs than the boards offer")
    outputs = [ChannelRef(b, ch) for b, s in enumerate(input_boards)
               if s.model.startswith("DT9836") for ch in range(2)]
    if len(outputs) < n_speakers:
        raise SimulationInputError(f"{n_speakers} speakers need more outputs than the boards offer")
    boards = (*input_boards, BoardSpec("DT9816-A", REFERENCE_BOARD_SERIAL))
    return boards, tuple(mic_inputs), tuple(outputs[:n_speakers]), ChannelRef(len(boards) - 1, 0)


_INPUTS = {"DT9836-12-2": 12, "DT9816-A": 6}


def _paper_boards(n_dt9836: int, n_dt9816: int) -> list[BoardSpec]:
    return [BoardSpec("DT9836-12-2", str(36001 + i)) for i in range(n_dt9836)] + [
        BoardSpec("DT9816-A", str(16001 + i)) for i in range(n_dt9816)
    ]


def sphere72(n_speakers: int = 6, radius_m: float = 0.15) -> ArrayLayout:
    """The paper's kind: 72 microphones on a sphere, a front camera at the front pole (the
    origin) and two side cameras 30 degrees to either side that share part of its view."""
    centre = np.array([0.0, 0.0, -radius_m])
    normals = fibonacci_sphere(72)
    cams = (
        pinhole("cam0"),
        _camera_on_sphere("cam1", centre, radius_m, -30.0),
        _camera_on_sphere("cam2", centre, radius_m, 30.0),
    )
    boards, mics, spk, ref = _wire(72, _paper_boards(3, 6), _INPUTS, n_speakers)
    return ArrayLayout("sphere72", centre + radius_m * normals, normals, cams, boards, mics, spk,
                       ref, SphereBody(centre, radius_m))


def planar64(n_speakers: int = 6, pitch_m: float = 0.04) -> ArrayLayout:
    """An 8 x 8 planar grid in the plane z = 0 with the camera at its centre."""
    g = (np.arange(8) - 3.5) * pitch_m
    xx, yy = np.meshgrid(g, g)
    pos = np.stack([xx.ravel(), yy.ravel(), np.zeros(64)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (64, 1))
    boards, mics, spk, ref = _wire(64, _paper_boards(3, 5), _INPUTS, n_speakers)
    return ArrayLayout("planar64", pos, normals, (pinhole("cam0"),), boards, mics, spk, ref)


def _scatter(n: int, seed: int) -> np.ndarray:
    """n microphone positions scattered in a 0.6 m x 0.6 m x 0.15 m box around the camera, at
    least 3 cm from it."""
    rng = np.random.default_rng(seed)
    pos: list[np.ndarray] = []
    while len(pos) < n:
        p = rng.uniform([-0.3, -0.3, -0.1], [0.3, 0.3, 0.05])
        if np.linalg.norm(p) > 0.03:
            pos.append(p)
    return np.array(pos)


def scatter48(n_speakers: int = 6, seed: int = 7) -> ArrayLayout:
    """An ad-hoc scatter of 48 microphones in a 0.6 m x 0.6 m x 0.15 m box around the camera,
    facing forward; at least 3 cm from the camera."""
    normals = np.tile([0.0, 0.0, 1.0], (48, 1))
    boards, mics, spk, ref = _wire(48, _paper_boards(3, 2), _INPUTS, n_speakers)
    return ArrayLayout("scatter48", _scatter(48, seed), normals, (pinhole("cam0"),), boards,
                       mics, spk, ref)


def scatter15(n_speakers: int = 6, seed: int = 7) -> ArrayLayout:
    """The first 15 microphones of scatter48: with the reference microphone, 16 inputs, what
    one 16-input audio interface records (sim.audio_world). On simulated boards: three
    DT9836-6-2 (6 inputs, 2 outputs each: the six speakers) and the reference DT9816-A."""
    normals = np.tile([0.0, 0.0, 1.0], (15, 1))
    boards, mics, spk, ref = _wire(15, [BoardSpec("DT9836-6-2", str(36001 + i))
                                        for i in range(3)], {"DT9836-6-2": 6}, n_speakers)
    return ArrayLayout("scatter15", _scatter(15, seed), normals, (pinhole("cam0"),), boards,
                       mics, spk, ref)


def array_layout(kind: str, n_speakers: int = 6) -> ArrayLayout:
    """The layout named `kind` (one of ARRAY_KINDS), with a clear error for unknown names."""
    builders = {"sphere72": sphere72, "planar64": planar64, "scatter48": scatter48,
                "scatter15": scatter15}
    if kind not in builders:
        raise SimulationInputError(
            f"unknown array {kind!r}; choose one of {', '.join(ARRAY_KINDS)}")
    return builders[kind](n_speakers=n_speakers)
