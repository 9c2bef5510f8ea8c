"""The daemon's configuration: a TOML file, overridden by MICAM_DAEMON_* environment variables.

Priority, highest first: environment (`MICAM_DAEMON_SESSION_ROOT=...`, nested sections with a
double underscore: `MICAM_DAEMON_SOCKETS__CONTROL=ipc:///run/micam/control`), then the TOML
file, then the defaults below. The file is read once (it may be a pipe: `--config <(...)`)
and parsed once; the settings get the parsed document, never the path to read again. Unknown
keys are refused so a misspelt option is never ignored. With no `[hardware]` section the
daemon runs on a simulated world; its `[simulation]` section is added by the application that
builds that world (`micam.simulated_hardware.MicamDaemonConfig`), so this package never imports
the simulator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Literal, TypeVar

from pydantic import Field, ValidationError, model_validator
from pydantic_settings import (
    BaseSettings,
    InitSettingsSource,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
)

from daq.audio import AudioConfig

from acquisition.contracts.camera import PixelFormat
from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.config_model import ConfigModel, describe_problems
from acquisition.contracts.errors import UserError
from acquisition.contracts.bounded_files import read_toml
from .endpoints import beside, default_control, default_events

ENV_PREFIX = "MICAM_DAEMON_"
DOCS = "docs/protocol.md, section Configuration"

Policy = Literal["retry", "warn", "ignore"]
"""What a failed quality check does: abandon the attempt and capture again, keep it with a
warning to the operator, or not check at all."""


class ConfigError(UserError):
    """The daemon's configuration is missing, unreadable or invalid; the message says where."""


class CurveConfig(ConfigModel):
    """CURVE encryption and client authentication (needed to bind a non-loopback address).

    Make the files with `micam daemon --make-keys DIR`.
    """

    server_secret_key: Path = Field(
        description="ZeroMQ certificate file with the daemon's secret key (…/server.key_secret)")
    authorized_clients: Path = Field(
        description="directory of the public certificates (*.key) of the clients allowed in")


class SocketsConfig(ConfigModel):
    """Where the daemon listens (ZeroMQ endpoints) and who may reach it (docs/security.md).

    By default: ipc sockets in the runtime directory (mode 0750, made by the daemon), socket
    files of mode `ipc_mode`, so the daemon's user and group may connect and nobody else.
    """

    control: str = Field(default_factory=default_control,
                         description="request/reply control socket (default: ipc in the "
                                     "runtime directory, see endpoints.default_runtime_dir)")
    events: str = Field(default_factory=default_events, description="publish socket for events")
    jobs: str | None = Field(
        default=None, description="ROUTER socket calibration workers connect to for jobs "
                                  "(default: beside control, see `beside`)")
    files: str | None = Field(
        default=None, description="ROUTER socket workers fetch session files from, in chunks "
                                  "(default: beside control)")
    curve: CurveConfig | None = None
    max_message_bytes: int = Field(
        default=65_536, ge=1024, le=16 * 2**20,
        description="larger control requests get a 'too_large' error reply; beyond 16 times "
                    "this (1 MiB by default) ZeroMQ drops the connection")
    max_result_bytes: int = Field(
        default=8 * 2**20, ge=65_536, le=256 * 2**20,
        description="the largest frame the jobs socket accepts (a worker's result.json); the "
                    "files socket accepts requests of at most 4 KiB")
    ipc_mode: int = Field(
        default=0o660, ge=0o600, le=0o770,
        description="mode of the ipc socket files (0o660: the daemon's user and group may "
                    "connect; 0o600: its user only)")
    allow_tcp_loopback: bool = Field(
        default=False,
        description="accept tcp://127.0.0.1 without CURVE, although every account on this "
                    "machine can then drive the daemon")

    @property
    def jobs_endpoint(self) -> str:
        return self.jobs or beside(self.control, "jobs")

    @property
    def files_endpoint(self) -> str:
        return self.files or beside(self.control, "files")


class QualityConfig(ConfigModel):
    """Quality checks of every recording and image set, and what a failure does."""

    clip_fraction: float = Field(
        default=0.999, gt=0.5, le=1.0,
        description="a sample at or beyond this fraction of full scale counts as clipped")
    min_level_dbfs: float = Field(
        default=-60.0, le=0.0,
        description="the channel(s) that should hear the speaker: RMS during the burst, dBFS")
    min_snr_db: float = Field(
        default=10.0, description="median SNR of those channels: burst power over pre-burst noise")
    min_channel_snr_db: float = Field(
        default=3.0, description="a microphone channel below this SNR is reported as dead")
    checkerboard_in: Literal["any", "all"] = Field(
        default="any", description="the checkerboard must be found in any / all cameras")
    clipping: Policy = "retry"
    level: Policy = "retry"
    snr: Policy = "retry"
    dead_channels: Policy = "warn"
    checkerboard: Policy = "retry"
    auto_retries: int = Field(
        default=1, ge=0, le=5,
        description="failed attempts re-captured without asking; then the operator captures again")


class V4L2CameraConfig(ConfigModel):
    """One real camera (see acquisition.cameras_v4l2.V4L2Camera)."""

    name: str
    device: str = Field(description="/dev/v4l/by-id/... (stable) or /dev/videoN")
    width: int = Field(gt=0)
    height: int = Field(gt=0)
    fourcc: PixelFormat = Field(
        default="MJPG", examples=["YUYV"],
        description="the pixel format the camera is asked for: MJPG (JPEG frames) or YUYV "
                    "(uncompressed); one of the modes `v4l2-ctl --list-formats-ext` lists "
                    "for this width and height")
    fps: float | None = Field(default=None, gt=0)
    exposure: float | None = Field(
        default=None, description="V4L2 exposure_absolute (driver units, usually 100 us); "
                                  "None leaves the camera's setting")


class HardwareConfig(ConfigModel):
    """Real boards and cameras: the capture configuration plus how to open the devices.

    `backend` chooses the boards: Data Translation boards on USB (`usb`, the boards' serials),
    or audio interfaces through PortAudio (`audio`: `[hardware.audio]` names the devices, each
    capture board has model "audio" and a device's label as its serial; docs/hardware.md)."""

    capture: CaptureConfig = Field(
        description="boards and serials, channel map, speakers, sample rate, burst, rig, cameras")
    cameras: tuple[V4L2CameraConfig, ...]
    firmware_dir: Path | None = None
    backend: Literal["usb", "audio"] = Field(
        default="usb", description="usb: DT9836/DT9816 boards; audio: audio interfaces")
    audio: AudioConfig | None = Field(
        default=None, description="the audio interfaces (backend = \"audio\")")

    @model_validator(mode="after")
    def _backend_configured(self) -> HardwareConfig:
        models = {b.model for b in self.capture.boards}
        if self.backend == "usb":
            if self.audio is not None or "audio" in models:
                raise ValueError("[hardware.audio] and boards of model 'audio' need "
                                 'backend = "audio"')
            return self
        if self.audio is None:
            raise ValueError('backend = "audio" needs a [hardware.audio] section naming the '
                             "interfaces (docs/hardware.md)")
        labels = [d.label for d in self.audio.devices]
        for b in self.capture.boards:
            if b.model != "audio" or b.serial not in labels:
                raise ValueError(f"capture board {b.serial!r}: on the audio backend every board "
                                 f'has model = "audio" and the label of one of [hardware.audio]'
                                 f"'s devices as its serial ({', '.join(labels)})")
        return self

    @model_validator(mode="after")
    def _cameras_match(self) -> HardwareConfig:
        named = [c.name for c in self.capture.cameras]
        given = [c.name for c in self.cameras]
        if named != given:
            raise ValueError(f"hardware.cameras {given} must match capture.cameras {named}, "
                             "in the same order")
        return self


class WorkersConfig(ConfigModel):
    """The calibration hand-off: heartbeats, leases, retries and when live calibration starts."""

    outbox: Path | None = Field(
        default=None,
        description="directory of the job files (default: SESSION_ROOT.outbox beside it)")
    heartbeat_interval_s: float = Field(
        default=1.0, gt=0, le=30,
        description="each side sends a heartbeat this often when idle")
    liveness: int = Field(
        default=3, ge=2, le=20,
        description="a worker silent for this many intervals is dead; its job goes to another")
    job_timeout_s: float = Field(
        default=3600.0, gt=0, description="a lease longer than this is taken back (a hung job)")
    max_attempts: int = Field(
        default=3, ge=1, le=20, description="leases of one job before it is given up as failed")
    retry_delay_s: float = Field(
        default=2.0, ge=0, le=600,
        description="a job that a worker failed with a retryable error (a fetch that broke, a "
                    "worker busy ending its last job) waits this long before it is offered "
                    "again, twice as long after each further attempt (0: at once); a job taken "
                    "back from a lost or silent worker is offered again at once")
    live: bool = Field(default=True, description="calibrate the poses so far after each pose")
    live_min_poses: int = Field(
        default=4, ge=1, description="poses completed before the first live calibration "
        "runs (a count: 4 is after pose 3)")
    keep_finished_days: float = Field(
        default=7.0, gt=0,
        description="records of done and failed final jobs stay in the outbox this long; a "
                    "session completed within this time whose final job is neither in the "
                    "outbox nor stored (the outbox's disk was full) gets one at start-up")


class HandsFreeConfig(ConfigModel):
    """Capture by itself once the checkerboard has been held still in view (poses only)."""

    enabled: bool = False
    still_s: float = Field(default=1.5, gt=0, le=30, description="how long the board must rest")
    max_motion_px: float = Field(default=2.0, gt=0, description="corner motion counted as still")
    check_interval_s: float = Field(default=0.25, gt=0, le=5)


class PreviewConfig(ConfigModel):
    """Camera previews (`preview` events) while a client asks for them (`micam web`)."""

    fps: float = Field(default=2.0, gt=0, le=10, description="previews per second and camera")
    width: int = Field(default=480, ge=64, le=1280, description="width of a preview, pixels")
    jpeg_quality: int = Field(default=70, ge=10, le=95)


class DaemonConfig(BaseSettings):
    """Everything `micam daemon` needs; see docs/protocol.md and README for an example."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, env_nested_delimiter="__", extra="forbid", frozen=True)

    toml_document: ClassVar[dict[str, Any] | None] = None  # the file's, parsed (load_config)

    session_root: Path = Field(default=Path("~/micam-sessions"),
                               description="sessions are directories under it")
    sockets: SocketsConfig = SocketsConfig()
    hardware: HardwareConfig | None = None
    quality: QualityConfig = QualityConfig()
    hands_free: HandsFreeConfig = HandsFreeConfig()
    workers: WorkersConfig = WorkersConfig()
    previews: PreviewConfig = PreviewConfig()
    poll_interval_s: float = Field(default=0.1, gt=0, le=1.0,
                                   description="longest wait of the service loop")
    resume_at_start: Literal["offer", "auto"] = Field(
        default="offer",
        description="an interrupted session found at start-up (a crash, SIGTERM, a power cut): "
                    "offer it (log, `status.resumable`), or resume it at once (auto)")
    camera_timeout_s: float = Field(default=2.0, gt=0, le=30)
    only_boards: tuple[str, ...] | None = Field(
        default=None,
        description="bring up only these boards of the capture configuration (serials, or the "
                    "audio interfaces' labels), e.g. one board as it arrives; [] for the cameras "
                    "alone (`micam daemon --boards` / `--cameras-only`). The previews and the "
                    "cameras work; a capture and live mode, which need every board, are refused")

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        sources: tuple[PydanticBaseSettingsSource, ...] = (init_settings, env_settings)
        if cls.toml_document is not None:  # below the environment (what TOML's source does)
            sources += (InitSettingsSource(settings_cls, init_kwargs=cls.toml_document),)
        return sources

    @property
    def simulated(self) -> bool:
        """True when no hardware is configured and the daemon runs on the simulated world."""
        return self.hardware is None


Config = TypeVar("Config", bound=DaemonConfig)


def load_config(path: Path | None, config_class: type[Config]) -> Config:
    """Read the configuration from `path` (None: defaults) and the environment.

    `config_class` is DaemonConfig or the application's subclass of it (the one with the
    simulated world's section). The file is read once, at most 1 MiB (`read_toml`).

    Raises ConfigError naming the file, then one line per problem (see `config_of`).
    """
    if path is None:
        return config_of(None, "the configuration", config_class)
    return config_of(read_toml(Path(path), "config file", ConfigError), f"config file {path}",
                     config_class)


def config_of(document: dict[str, Any] | None, where: str, config_class: type[Config]) -> Config:
    """The configuration of a parsed TOML `document` (None: defaults) and the environment.

    Raises ConfigError naming `where` (the file), then one line per problem (the key, its
    section and, for an unknown key, the keys the section accepts), then where the keys are
    documented.
    """
    settings_cls = type(config_class.__name__, (config_class,), {"toml_document": document})
    try:
        return settings_cls()
    except ValidationError as exc:
        problems = describe_problems(exc, config_class)
        raise ConfigError(
            f"{where} (with {ENV_PREFIX}* overrides) is invalid:\n"
            + "".join(f"  {line}\n" for line in problems)
            + f"(the keys and sections are described in {DOCS}; [hardware.capture] is "
              "acquisition/contracts/capture_config.py)") from None
