"""Start the daemon: configuration, hardware, sockets, signals; then serve until SIGTERM.

The first SIGTERM (or SIGINT) ends the current burst, journals the step in progress as
abandoned, leaves the session interrupted (resumable, as after a crash, never closed) and exits
with status 0. A second one exits at once (status 1); the session is then left interrupted too.
Either way the next start offers the session for resuming (or resumes it: `resume_at_start`).
"""

from __future__ import annotations

import logging
import signal
import sys
from pathlib import Path
from types import FrameType

from daq import DaqError

from acquisition.contracts.camera import CameraError
from acquisition.contracts.errors import UserError
from acquisition.daemon.config import DaemonConfig
from acquisition.daemon.hardware import boards_to_bring_up
from acquisition.daemon.security import check_exposure
from acquisition.daemon.service import Daemon
from acquisition.daemon.systemd import configure_logging, sd_notify

from .hardware import load_daemon_config, open_hardware

log = logging.getLogger("micam.daemon")


def check_config(config: DaemonConfig) -> str:
    """Check a loaded configuration without opening anything (`load_daemon_config` has
    validated it; this refuses sockets strangers could reach); a one-line summary of it."""
    check_exposure(config.sockets)
    what = "simulated world" if config.simulated else "real hardware"
    if config.hardware is not None and config.only_boards is not None:
        serials, _ = boards_to_bring_up(config.hardware.capture, config.only_boards)
        what += f" ({'boards ' + ', '.join(serials) if serials else 'the cameras'} alone)"
    return (f"configuration OK: {what}, control {config.sockets.control}, events "
            f"{config.sockets.events}, sessions in {config.session_root}")


def run_daemon(config_path: Path | None, log_level: int = logging.INFO,
               only_boards: tuple[str, ...] | None = None) -> int:
    """Run the daemon in this process until it is told to stop; the process exit status.
    `only_boards` (`--boards`, `--cameras-only`) overrides the configuration's."""
    configure_logging(log_level)
    config = load_daemon_config(config_path)
    if only_boards is not None:
        config = config.model_copy(update={"only_boards": only_boards})
    check_exposure(config.sockets)  # before opening any hardware
    try:
        hardware = open_hardware(config)
    except (DaqError, CameraError) as exc:
        sd_notify(f"STATUS=cannot open the hardware: {exc}")
        raise UserError(f"cannot open the hardware: {exc}") from None
    try:
        daemon = Daemon(config, hardware)
    except BaseException:
        hardware.close()
        raise

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        if daemon.terminating:
            log.warning("second %s: exiting now; the session stays resumable",
                        signal.Signals(signum).name)
            raise SystemExit(1)
        log.info("%s: ending the current burst, then stopping; the session stays resumable",
                 signal.Signals(signum).name)
        daemon.terminate()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    daemon.serve_forever()
    return 0


if __name__ == "__main__":
    sys.exit(run_daemon(Path(sys.argv[1]) if len(sys.argv) > 1 else None))
