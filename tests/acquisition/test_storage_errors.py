"""Storage errors: a full disk or a read-only filesystem under `micam simulate`, a full outbox
under the daemon. Each is a clear error; nothing recorded is lost and the work is done once
the disk takes writes again.

A full disk is a real one where possible: a 3 MB tmpfs when the tests may mount (as root);
otherwise a per-file size limit (RLIMIT_FSIZE) gives the writes the same kind of OSError.
"""

from __future__ import annotations

import errno
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import acquisition.daemon.outbox as outbox_module
from micam.cli import main
from acquisition.daemon.config import WorkersConfig
from acquisition.contracts.session import SessionReader
from tests.acquisition.daemon.helpers import (
    REPO,
    ThreadDaemon,
    capture_all,
    small_config,
    wait_state,
)

SIMULATE = [sys.executable, "-m", "micam.cli", "simulate", "--array", "scatter48",
            "--poses", "2", "--mls-order", "9", "--seed", "3", "--quiet"]


def _mount(target: Path, options: str) -> bool:
    target.mkdir()
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)],
                          capture_output=True)
    return done.returncode == 0


@pytest.fixture
def full_disk(tmp_path: Path) -> Iterator[tuple[Path, Callable[[], None] | None]]:
    """A directory on a small disk, and what a child process must run to be limited to it
    (None when the disk is a real 3 MB tmpfs)."""
    disk = tmp_path / "disk"
    if _mount(disk, "size=3m"):
        yield disk, None
        subprocess.run(["umount", str(disk)], check=True)
        return

    def limit_file_size() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))

    yield disk, limit_file_size


@pytest.mark.slow
def test_simulate_on_a_full_disk_says_what_to_do_and_resumes(
        full_disk: tuple[Path, Callable[[], None] | None], tmp_path: Path) -> None:
    disk, limit = full_disk
    out = disk / "s"
    done = subprocess.run([*SIMULATE, "--out", str(out)], cwd=REPO, capture_output=True,
                          text=True, preexec_fn=limit, timeout=300)
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr and "AssertionError" not in done.stderr
    assert done.stderr.startswith("micam: capture interrupted: cannot write ")
    assert f"micam simulate --resume --out {out}" in done.stderr
    reader = SessionReader(out)
    assert reader.status == "interrupted" and reader.verify() == []
    kept = {s: r.files for s, r in reader.steps().items()}

    moved = tmp_path / "s"  # "free space": continue where there is room
    subprocess.run(["cp", "-a", str(out), str(moved)], check=True)
    assert main(["simulate", "--resume", "--out", str(moved), "--quiet"]) == 0
    reader = SessionReader(moved)
    assert reader.status == "complete" and reader.verify() == []
    assert {s: reader.steps()[s].files for s in kept} == kept


def test_simulate_on_a_read_only_filesystem_is_one_clear_line(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    disk = tmp_path / "ro"
    if not _mount(disk, "ro,size=1m"):
        if os.geteuid() == 0:
            pytest.skip("a read-only directory needs mount permission when running as root")
        disk.chmod(0o555)
    try:
        assert main(["simulate", "--out", str(disk / "s"), "--array", "scatter48", "--poses",
                     "2", "--mls-order", "9", "--quiet"]) == 2
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", str(disk)], check=False)
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"micam: error: --out {disk / 's'} cannot be created in {disk}: it "
                          "is not writable") and "\n" not in err, err


class _FullOutbox:
    """Makes the outbox's writes fail with ENOSPC while `full` is set."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.full = True
        write = outbox_module.write_atomic

        def refusing(path: Path, fill, *, replace: bool = False):
            if self.full:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            return write(path, fill, replace=replace)

        monkeypatch.setattr(outbox_module, "write_atomic", refusing)


def _final_jobs(root: Path) -> list[Path]:
    return sorted((root / "sessions.outbox").glob("*.final.json"))


@pytest.mark.slow
def test_a_full_outbox_neither_stops_the_daemon_nor_loses_the_final_job(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    outbox = _FullOutbox(monkeypatch)
    config = small_config(tmp_path, workers=WorkersConfig(live=False))
    running = ThreadDaemon(config)
    try:
        with running.client() as client:
            events = client.subscribe()
            client.request("session.start", poses=1)
            capture_all(client)
            status = wait_state(client, "idle")  # the daemon used to die here
            assert status.calibration.pending == 1 and _final_jobs(tmp_path) == []
            seen = [events.next(1.0) for _ in range(60)]
            assert any(e is not None and e.type == "error" and "outbox" in e.message
                       for e in seen)
            events.close()
            outbox.full = False  # space again: the job is written without any request
            client.wait_until(lambda _: bool(_final_jobs(tmp_path)), 30.0)

            outbox.full = True  # a second session completes, and the daemon stops meanwhile
            second = client.request("session.start", poses=1)["session"]["id"]
            capture_all(client)
            wait_state(client, "idle")
    finally:
        running.stop()
    assert len(_final_jobs(tmp_path)) == 1
    outbox.full = False
    restarted = ThreadDaemon(config)  # finds the complete session without a job: queues it
    try:
        with restarted.client() as client:
            client.wait_until(lambda s: s.calibration.pending == 2, 30.0)
    finally:
        restarted.stop()
    assert f"{second}.final.json" in {p.name for p in _final_jobs(tmp_path)}
