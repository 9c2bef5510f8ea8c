"""The composition root: real boards and cameras, or the simulated world, for the daemon.

The acquisition daemon knows only `Hardware` and the real devices; the simulated world lives in
`sim/`, which the daemon must not import (a daemon on the acquisition PC never loads the
simulator). This module joins them, and loads the simulator only when the configuration has no
`[hardware]`: then the configuration is read as `micam.simulated_hardware.MicamDaemonConfig`
(with the `[simulation]` section validated) and `open_hardware` builds that world; otherwise it
is an `OnHardwareConfig` and `open_hardware` opens the real devices.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from pydantic import Field

from acquisition.contracts.bounded_files import read_toml
from acquisition.daemon.config import ConfigError, DaemonConfig, config_of
from acquisition.daemon.hardware import Hardware, keep_boards, open_real_hardware

log = logging.getLogger("micam.daemon")


class OnHardwareConfig(DaemonConfig):
    """The daemon's configuration with `[hardware]`: a `[simulation]` section is accepted and
    left unread (validating it would load the simulator for a world that is not built)."""

    simulation: dict[str, Any] = Field(
        default_factory=dict, description="the simulated world's options, used only without "
                                          "[hardware]")


def daemon_config_of(document: dict[str, Any] | None, where: str) -> DaemonConfig:
    """`micam daemon`'s configuration of a parsed TOML `document` (None: defaults) and the
    environment: an `OnHardwareConfig` when it configures hardware, else the simulated world's
    `MicamDaemonConfig`. Raises ConfigError naming `where`."""
    config = config_of(document, where, OnHardwareConfig)
    if config.hardware is not None:
        return config
    from .simulated_hardware import MicamDaemonConfig

    return config_of(document, where, MicamDaemonConfig)


def load_daemon_config(path: Path | None = None) -> DaemonConfig:
    """Read `micam daemon`'s configuration (None: defaults) with its environment overrides;
    the file is read once, at most 1 MiB (`read_toml`)."""
    if path is None:
        return daemon_config_of(None, "the configuration")
    return daemon_config_of(read_toml(Path(path), "config file", ConfigError),
                            f"config file {path}")


def open_hardware(config: DaemonConfig) -> Hardware:
    """Open the configured hardware, or build the simulated world when none is configured (a
    configuration without `[simulation]`, e.g. a bare `DaemonConfig`: the default world); only
    the boards of `only_boards` when it is set."""
    if config.hardware is not None:
        hardware = open_real_hardware(config.hardware, config.only_boards)
    else:
        from .simulated_hardware import MicamDaemonConfig, SimulationConfig, simulated_hardware

        world = simulated_hardware(config.simulation if isinstance(config, MicamDaemonConfig)
                                   else SimulationConfig())
        try:
            hardware = keep_boards(world, config.only_boards)
        except BaseException:
            world.close()
            raise
    log.info("hardware: %s", hardware.description)
    return hardware
