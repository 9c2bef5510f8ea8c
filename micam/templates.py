"""Commented, valid starting points for a configuration (`micam config template NAME`).

- `paper`: the daemon on the paper's set-up: 3 x DT9836-12-2 (12 inputs, 2 outputs each, the
  six speakers on their outputs) and 6 x DT9816-A for 72 microphones, the reference microphone
  on a DT9816-A of its own, 3 cameras;
- `generic`: the daemon on a smaller rig: 3 x DT9836-12-2, 35 microphones and the reference
  microphone on the last input of the third board, one camera;
- `audio`: the daemon on an audio interface (any device PortAudio reaches: RME, MOTU,
  Focusrite, Behringer, ...): 15 microphones and the reference microphone on its 16 inputs,
  the six speakers on its outputs, one camera (docs/hardware.md);
- `uma16`: the daemon on a miniDSP UMA-16 USB array (16 MEMS microphones, 4 x 4) with a
  second interface for the reference microphone and the speakers, on one word clock;
- `import`: `micam import` of another recorder's files (docs/import.md).

Each validates as written (tests/acquisition/test_templates.py); the values a person must
change (board serials, camera devices, the rig as built) say so in their comments.
"""

from __future__ import annotations

import json
import textwrap

from acquisition.contracts.errors import UserError
from kernel.stimulus import mls_length
from sim.geometry import PAPER_SPEAKERS_MM

TEMPLATES = ("paper", "generic", "audio", "uma16", "import")

_SPEAKERS_M = [[round(v / 1000.0, 4) for v in p] for p in PAPER_SPEAKERS_MM]

PLACEHOLDER = "CHANGE-ME"
"""What a template writes where only the lab knows the value (a device name); `micam config
check` refuses a file that still holds it."""


def template(name: str) -> str:
    """The template called `name` (one of TEMPLATES), as TOML text."""
    if name == "paper":
        return _daemon(
            "the paper's set-up (Legg & Bradley 2013): 3 x DT9836-12-2 and 6 x DT9816-A for 72 "
            "microphones, the reference microphone on a DT9816-A of its own, 3 cameras",
            [("DT9836-12-2", "36001", 12, 2), ("DT9836-12-2", "36002", 12, 2),
             ("DT9836-12-2", "36003", 12, 2)]
            + [("DT9816-A", f"1600{i}", 6, 0) for i in range(1, 7)]
            + [("DT9816-A", "16099", 1, 0)],
            n_mics=72, reference=("16099", 0), cameras=["cam0", "cam1", "cam2"])
    if name == "generic":
        return _daemon(
            "a smaller rig: 3 x DT9836-12-2, 35 microphones and the reference microphone on "
            "the last input of the third board, one camera",
            [("DT9836-12-2", "36001", 12, 2), ("DT9836-12-2", "36002", 12, 2),
             ("DT9836-12-2", "36003", 12, 2)],
            n_mics=35, reference=("36003", 11), cameras=["cam0"])
    if name == "audio":
        return _daemon(
            "one audio interface with 16 inputs and 6 or more outputs (an RME, MOTU, "
            "Focusrite, Behringer, ...): 15 microphones and the reference microphone on its "
            "inputs, the six speakers on its outputs, one camera",
            [("audio", "interface", 16, 6)], n_mics=15, reference=("interface", 15),
            cameras=["cam0"], audio=([("interface", PLACEHOLDER, None)], False))
    if name == "uma16":
        return _daemon(
            "a miniDSP UMA-16 USB array (16 MEMS microphones) and an audio interface for the "
            "reference microphone and the six speakers, on one word clock, one camera",
            [("audio", "uma16", 16, 0), ("audio", "interface", 1, 6)], n_mics=16,
            reference=("interface", 0), cameras=["cam0"],
            audio=([("uma16", "UMA16", None), ("interface", PLACEHOLDER, None)], True),
            notes=_UMA16, rate_hz=48_000.0)
    if name == "import":
        return _IMPORT
    raise UserError(f"unknown template {name!r}; choose one of {', '.join(TEMPLATES)}")


def _toml(value: object) -> str:
    """A plain value in TOML (JSON's numbers, strings and lists are TOML's)."""
    return json.dumps(value)


AudioDevices = tuple[list[tuple[str, str, str | None]], bool]
"""The audio interfaces of a template: (label, name, host API) each, and the word clock."""


def _audio_section(audio: AudioDevices) -> list[str]:
    """[hardware]'s backend and [hardware.audio] for the interfaces `audio`."""
    devices, word_clock = audio
    lines = [
        'backend = "audio"        # audio interfaces through PortAudio (docs/hardware.md)',
        "",
        "[hardware.audio]",
        f"word_clock = {'true' if word_clock else 'false'}"
        + ("        # the interfaces share one word clock: the first is its master"
           if word_clock else "       # one interface: its own clock"),
        'latency = "high"         # PortAudio\'s buffer; the latency itself is measured',
        "block_frames = 0         # frames per callback; 0: the host API's choice",
        "",
    ]
    for label, name, host_api in devices:
        lines += [
            "[[hardware.audio.devices]]",
            f'label = "{label}"' + " " * max(1, 15 - len(label))
            + "# the serial of its [[hardware.capture.boards]] entry",
            f'name = "{name}"' + " " * max(1, 16 - len(name))
            + "# its name, or a part of it: `micam daq list --backend audio`",
            (f'host_api = "{host_api}"' if host_api else
             '# host_api = "ALSA"      # where it appears under several: ALSA, JACK, ASIO, ...'),
            "",
        ]
    return lines


def _daemon(title: str, boards: list[tuple[str, str, int, int]], n_mics: int,
            reference: tuple[str, int], cameras: list[str],
            audio: AudioDevices | None = None, notes: tuple[str, ...] = (),
            rate_hz: float = 96_000.0) -> str:
    """A daemon configuration: sockets, quality, the hardware's capture and its cameras (on
    the audio backend with `audio`; `notes` are comment lines after the title).

    TOML puts every key after a table header into that table, so [hardware.capture]'s own
    keys (columns, speakers, cameras) come before its sub-tables (boards, reference, ...)."""
    columns, outputs, board_tables = [], [], []
    mic = 0
    order = 14 if rate_hz > 64_000 else 13  # a period of about 170 ms: room-proof
    post = round(rate_hz * 0.085)  # 85 ms: an interface's latency, then the room's decay
    where = ("the label of a [hardware.audio] device" if audio
             else "this board's serial: `micam daq list`")
    for model, serial, n_inputs, n_outputs in boards:
        board_tables += [
            "[[hardware.capture.boards]]",
            f'model = "{model}"',
            f'serial = "{serial}"' + " " * max(1, 10 + 7 - len(serial)) + f"# {where}",
            "inputs = [",
            *[f"  {{ channel = {c}, range_v = 10.0 }}," for c in range(n_inputs)],
            "]",
            "outputs = [",
            *[f"  {{ channel = {c}, range_v = 10.0 }}," for c in range(n_outputs)],
            "]",
            "",
        ]
        for c in range(n_inputs):
            if (serial, c) == reference:
                columns.append(f'  {{ board = "{serial}", channel = {c}, range_v = 10.0, '
                               'role = "reference" },')
            elif mic < n_mics:
                columns.append(f'  {{ board = "{serial}", channel = {c}, range_v = 10.0, '
                               f'role = "mic", mic_id = {mic} }},')
                mic += 1
        outputs += [(serial, c) for c in range(n_outputs)]
    lines = [
        *textwrap.wrap(f"micam daemon configuration: {title}.", 92, initial_indent="# ",
                       subsequent_indent="# "),
        *notes,
        "# Check it with `micam config check FILE`, run it with `micam daemon --config FILE`.",
        "# Every key is described in docs/protocol.md (Configuration); [hardware.capture] in",
        "# acquisition/contracts/capture_config.py, its rig in acquisition/contracts/rig_description.py.",
        "",
        'session_root = "~/micam-sessions"   # one directory per session under it',
        "",
        "# [sockets]: by default ipc sockets in the runtime directory, which only the daemon's",
        "# user and group can reach (docs/security.md); another host needs [sockets.curve] keys.",
        "",
        "[quality]                # what a failed check does: retry, warn or ignore",
        'clipping = "retry"',
        'snr = "retry"',
        "",
        "[hardware]",
        *(_audio_section(audio) if audio else [
            '# firmware_dir = "/opt/micam/firmware"   # the boards\' firmware images, if they '
            "need it", ""]),
        "[hardware.capture]",
        (f"sample_rate_hz = {rate_hz:.1f}  # a rate every interface offers" if audio
         else "sample_rate_hz = 96000.0  # one external clock for every board"),
        "n_poses = 20             # rig poses per session (micam session start --poses N)",
        "",
        "# Column j of every recording: the boards' inputs (below), board after board, in",
        "# order; each records a microphone (its id) or the reference microphone.",
        "columns = [", *columns, "]",
        "",
        "# The rig's speakers: the output that drives each and its position in the rig frame",
        "# (metres; the paper's Table I). Keep these equal to rig.speakers_m below.",
        "speakers = [",
        *[f'  {{ index = {k}, board = "{outputs[k][0]}", output_channel = {outputs[k][1]}, '
          f"rig_position_m = {_toml(p)} }}," for k, p in enumerate(_SPEAKERS_M)],
        "]",
        "",
        "# The cameras, camera 0 (the calibration's frame) first; device_id labels them in",
        "# each session, [[hardware.cameras]] at the end opens them.",
        "cameras = [",
        *[f'  {{ name = "{c}", device_id = "usb-camera-{c}" }},' for c in cameras],
        "]",
        "",
        *(["# The interfaces, the clock master first; range_v is the voltage that reaches",
           "# digital full scale at the interface's gain setting (its outputs: the voltage its",
           "# full scale drives). Measure it, or leave 10.0: the calibration needs only the",
           "# times, the levels are for the quality checks."] if audio else
          ["# The boards of the sync group, the clock and trigger master first; input ranges in",
           "# volts (the DT9836 also offers 2.0)."]),
        *board_tables,
        "[hardware.capture.reference]   # the reference microphone (paper IV-C)",
        f'board = "{reference[0]}"',
        f"channel = {reference[1]}",
        "distance_from_speaker_m = 0.002   # how far from each speaker in its reference recording",
        "",
        "[hardware.capture.burst]       # what each speaker plays per recording",
        (f"mls_order = {order}          # {mls_length(order)} samples, "
         f"{1e3 * mls_length(order) / rate_hz:.0f} ms at {rate_hz / 1000:.0f} kS/s"),
        "periods = 2             # played back to back; the last is the room-proof one",
        "amplitude_v = 1.0",
        "pre_samples = 512       # recorded silence before the sequence",
        (f"post_samples = {post}    # recorded after it: the interface's latency (the quality "
         "check says if too short), then the room's decay" if audio else
         "post_samples = 2048     # recorded silence after it, while it dies away"),
        "",
        *_RIG,
        "",
    ]
    for camera in cameras:
        lines += [
            "[[hardware.cameras]]",
            f'name = "{camera}"',
            f'device = "/dev/v4l/by-id/usb-{PLACEHOLDER}-{camera}-video-index0"   # ls /dev/v4l/by-id/',
            "width = 1280",
            "height = 960",
            'fourcc = "MJPG"          # or "YUYV" (uncompressed): a mode the camera lists for',
            "                         # this size (v4l2-ctl --list-formats-ext)",
            "# exposure = 150        # V4L2 exposure_absolute; leave out for the camera's own",
            "",
        ]
    return "\n".join(lines)


# The UMA-16's microphones, from Acoular's published geometry file of the array
# (acoular/xml/minidsp_uma-16.xml, positions corrected in Acoular 24.03 after its GitHub issue
# #63): a 4 x 4 grid at 42 mm pitch, metres, in the array's own frame, channel order.
_UMA16_MM = [(21, -63), (63, -63), (21, -21), (63, -21), (21, 21), (63, 21), (21, 63),
             (63, 63), (-63, 63), (-21, 63), (-63, 21), (-21, 21), (-63, -21), (-21, -21),
             (-63, -63), (-21, -63)]
_UMA16 = (
    "#",
    "# The array's published geometry (Acoular's acoular/xml/minidsp_uma-16.xml, corrected",
    "# after Acoular's GitHub issue #63): channel k at (x, y) mm, z = 0; the calibration",
    "# finds the positions as built, compare them with these:",
    *("#   " + ", ".join(f"ch {k}: ({x:+d}, {y:+d})" for k, (x, y) in
                          list(enumerate(_UMA16_MM))[i: i + 4]) for i in range(0, 16, 4)),
    "#",
    "# WHAT MUST HOLD: the UMA-16 and the interface sample on ONE clock. The UMA-16 shows no",
    "# word-clock input, so the interface must follow the array's (or both one clock, e.g. as",
    "# one aggregate device whose clock source is one of them, drift correction off). On two",
    "# free-running clocks the delays grow along every recording (tens of ppm: millimetres);",
    "# micam stops a capture whose interfaces drift apart (daq/audio/_clock.py), but only",
    "# beyond its tolerance: check the calibration's residuals (docs/hardware.md).",
)

_RIG = [
    "[hardware.capture.rig]   # the calibration rig as built (acquisition/contracts/rig_description.py)",
    "corners_x = 6           # inner corners along the rig's X axis",
    "corners_y = 9           # ... and along Y (one even, one odd: no half-turn ambiguity)",
    "square_m = 0.030        # printed square, metres (measure the print)",
    'origin_square = "dark"  # colour of the square at +X +Y of the origin corner',
    "speakers_m = [          # each speaker in the rig frame, metres, in speaker order",
    *[f"  {_toml(p)}," for p in _SPEAKERS_M],
    "]",
    "reference_mark_m = [-0.090, -0.060, 0.0]   # rig point touched to the reference mic",
    "speaker_tolerance_m = 0.0003    # how well each speaker sits where stated (std, m)",
    "acoustic_centre_m = 0.0         # expected acoustic-centre offset along the normal (m)",
    "acoustic_centre_std_m = 0.005",
    "print_scale_std = 0.002         # relative uncertainty of the print's scale",
]


_IMPORT = f"""# micam import description: the rig, the array and the recordings of a capture made
# with another recorder (an NI or RME card, a USB audio interface, Acoular's HDF5 files).
# Check it with `micam import FILE --out DIR --check`; see docs/import.md. Every path is
# relative to this file's folder.

sample_rate_hz = 48000            # of every recording
# session_id = "lab-2026-03-02"   # default: the time of the import

[rig]                             # the calibration rig (frame: docs/import.md)
corners_x = 6                     # inner corners along the rig's X axis
corners_y = 9                     # ... and along Y (one even, one odd)
square_m = 0.030                  # printed square, metres (measure the print)
origin_square = "dark"            # colour of the square at +X +Y of the origin corner
# marker_square = [1, 2]          # a square with a dot of the other colour (symmetric boards)
speakers_m = [                    # each speaker in the rig frame, metres, in speaker order
{chr(10).join(f"  {_toml(p)}," for p in _SPEAKERS_M)}
]
speaker_tolerance_m = 0.0003      # build tolerance of each speaker's position (std, m)
print_scale_std = 0.002           # relative uncertainty of the print's scale

# The channel map: each clock/latency group (a board, an interface) and the microphones its
# columns record (columns count from 0). One latency is fitted per group.
[[channels]]
group = "interface"
columns = [1, 2, 3, 4, 5, 6, 7]
mic_ids = [0, 1, 2, 3, 4, 5, 6]

[reference]                       # the reference microphone (paper IV-C)
group = "interface"               # the group whose column records it (the latency gauge)
reference_recordings_column = 0   # its column in the reference recordings
# pose_recordings_column = 0      # its column in the pose recordings, if it records there too
distance_from_speaker_m = 0.002   # in the reference recordings; or one per speaker: [...]

[burst]                           # what each recording holds, in samples
silence_before_samples = 512
mls_order = 14                    # the sequence: 2**14 - 1 samples
periods = 1                       # sequences played back to back (2 or more: room-proof)
silence_after_samples = 2048
extra_recorded_samples = 0        # what the recorder kept after that

[air]                             # measured during the session (leave out if not)
temperature_c = 21.5
temperature_std_c = 0.2

[[cameras]]                       # camera 0 (the calibration's frame) first
name = "cam0"
width = 1280
height = 960
# intrinsics_file = "cam0.yaml"   # a known calibration (OpenCV YAML/JSON, ROS, micam result)
# intrinsics_use = "fixed"        # or "prior" with intrinsics_std = [fx, fy, cx, cy, k1..k3]

# [layout]                        # the array's nominal layout: swapped cables are found by it
# file = "array.xml"              # the maker's Acoular MicGeom XML ("Point k": microphone k)

[recordings]
# one reference recording per speaker, in speaker order
references = ["reference/speaker0.wav", "reference/speaker1.wav", "reference/speaker2.wav",
              "reference/speaker3.wav", "reference/speaker4.wav", "reference/speaker5.wav"]

# one table per rig pose: every speaker's burst, in speaker order (a file, or a place in a
# long take: {{ file = "take.wav", start_sample = 96000 }}), and the cameras' images
[[recordings.poses]]
bursts = ["pose00/speaker0.wav", "pose00/speaker1.wav", "pose00/speaker2.wav",
          "pose00/speaker3.wav", "pose00/speaker4.wav", "pose00/speaker5.wav"]
images = {{ cam0 = "pose00/cam0.png" }}

[[recordings.poses]]
bursts = ["pose01/speaker0.wav", "pose01/speaker1.wav", "pose01/speaker2.wav",
          "pose01/speaker3.wav", "pose01/speaker4.wav", "pose01/speaker5.wav"]
images = {{ cam0 = "pose01/cam0.png" }}
"""
