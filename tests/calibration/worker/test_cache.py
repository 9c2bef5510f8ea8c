"""The worker's cache is bounded: least recently used sessions go, never one a job is using,
and sizes are those of the files on disk."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from micam.cli import build_parser
from acquisition.contracts.job_messages import Done, Job, JobFile, JournalPrefix
from calibration.worker import Worker, WorkerSettings
from calibration.errors import CalibrationInputError
from calibration.worker.cache import DEFAULT_MAX_BYTES, JOURNAL, FileCache, parse_size
from calibration.worker.compute import Final

SHA = "0" * 64


def _job(session_id: str, files: dict[str, int] | None = None) -> Job:
    """A job of `session_id` listing `files` (path: bytes) to fetch."""
    return Job(job_id=f"{session_id}-live", attempt=1, kind="live", session_id=session_id,
               poses=1, journal=JournalPrefix(bytes=10, sha256=SHA),
               files=[JobFile(path=p, bytes=n, sha256=SHA) for p, n in (files or {}).items()])


def _fetch(cache: FileCache, job: Job, n_bytes: int) -> None:
    """What a fetch leaves: the journal and a pose's recording, `n_bytes` in all."""
    cache.target(job, JOURNAL).write_bytes(b"j" * 10)
    recording = cache.target(job, "pose/0000/attempt-1/speaker_0.wav")
    recording.parent.mkdir(parents=True, exist_ok=True)
    recording.write_bytes(b"r" * (n_bytes - 10))


def _run(cache: FileCache, session_id: str, n_bytes: int) -> None:
    """One whole job of `session_id` that fetches `n_bytes`."""
    job = _job(session_id)
    with cache.use(job):
        _fetch(cache, job, n_bytes)


def _cached(cache: FileCache) -> list[str]:
    return [s.session_id for s in cache.sessions()]


def test_sizes_are_those_of_the_files_on_disk(tmp_path: Path) -> None:
    cache = FileCache(tmp_path)
    _run(cache, "a", 400)
    extra = tmp_path / "a" / "pose" / "0001" / "speaker_1.wav.partial"  # a fetch cut short
    extra.parent.mkdir(parents=True)
    extra.write_bytes(b"p" * 123)
    (session,) = cache.sessions()
    on_disk = sum(p.stat().st_size for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert session.bytes == on_disk == 523 and cache.total_bytes() == 523


def test_beyond_the_limit_the_least_recently_used_session_goes(tmp_path: Path) -> None:
    cache = FileCache(tmp_path, max_bytes=1000)
    _run(cache, "a", 400)
    _run(cache, "b", 400)
    _run(cache, "a", 400)  # a live job after another pose: `a` is now the more recent
    assert _cached(cache) == ["b", "a"]
    _run(cache, "c", 400)  # 1200 bytes: one must go
    assert _cached(cache) == ["a", "c"]
    assert not (tmp_path / "b").exists() and cache.total_bytes() == 800


def test_the_session_in_use_is_never_evicted(tmp_path: Path) -> None:
    cache = FileCache(tmp_path, max_bytes=1000)
    job = _job("a")
    with cache.use(job):  # `a` is taken first, so it is the least recently used ...
        _fetch(cache, job, 400)
        assert cache.in_use() == {"a"}
        _run(cache, "b", 400)
        _run(cache, "c", 400)  # ... but in use: `b` goes instead
        assert _cached(cache) == ["a", "c"]
        _fetch(cache, job, 1100)  # in use and alone over the limit: kept while in use
        assert sorted(_cached(cache)) == ["a", "c"]
        cache.evict()
        assert _cached(cache) == ["a"]
    assert cache.in_use() == set()
    assert _cached(cache) == []  # once its job ended, it goes: it alone is over the limit


def test_room_is_made_before_fetching(tmp_path: Path) -> None:
    cache = FileCache(tmp_path, max_bytes=1000)
    _run(cache, "a", 400)
    _run(cache, "b", 400)
    job = _job("c", {"pose/0000/attempt-1/speaker_0.wav": 300})  # + the journal: 310 bytes
    with cache.use(job):
        assert _cached(cache) == ["b", "c"]  # `a` went before a byte of `c` arrived


def test_the_order_survives_a_restart_and_other_directories_are_left_alone(
        tmp_path: Path) -> None:
    cache = FileCache(tmp_path, max_bytes=1000)
    _run(cache, "a", 400)
    _run(cache, "b", 400)
    old = (tmp_path / "b").stat().st_mtime_ns - 10**9
    os.utime(tmp_path / "b", ns=(old, old))  # `b` last used a second before `a`
    other = tmp_path / "not-a-session"
    other.mkdir()
    (other / "notes.txt").write_bytes(b"x" * 5000)
    restarted = FileCache(tmp_path, max_bytes=1000)
    assert _cached(restarted) == ["b", "a"] and restarted.total_bytes() == 800
    _run(restarted, "c", 400)
    assert _cached(restarted) == ["a", "c"] and other.is_dir()


def test_the_worker_keeps_its_session_while_calibrating(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Through the worker's job thread: the fetch fills the cache beyond its limit, and the
    calibration still finds every file of its session."""
    import calibration.worker.worker as worker_module

    worker = Worker(WorkerSettings(jobs="inproc://jobs", files="inproc://files",
                                   cache=tmp_path, cache_max_bytes=1000))
    _run(worker.cache, "old", 600)
    job = _job("new", {"pose/0000/attempt-1/speaker_0.wav": 590})
    seen: dict[str, object] = {}

    def fetch(_sock: object, job: Job, cache: FileCache, timeout_s: float) -> int:
        _fetch(cache, job, 600)
        return 600

    def compute(job: Job, session: Path, _joint: bool, _on_stage: object,
                _memo: object = None) -> Final:
        seen["in_use"] = worker.cache.in_use()
        seen["files"] = sorted(p.name for p in session.rglob("*") if p.is_file())
        return Final(b"{}", {"report.md": b"# r"})

    monkeypatch.setattr(worker_module, "fetch_job_files", fetch)
    monkeypatch.setattr(worker_module, "compute", compute)
    worker._work(job)
    assert seen == {"in_use": {"new"}, "files": [JOURNAL, "speaker_0.wav"]}
    assert _cached(worker.cache) == ["new"]  # `old` made room
    reports = [worker._reports.get_nowait() for _ in range(worker._reports.qsize())]
    assert isinstance(reports[-2], tuple) and isinstance(reports[-2][0], Done)
    assert [f.name for f in reports[-2][0].report] == ["report.md"]
    assert reports[-2][1] == [b"{}", b"# r"]  # the result's frame, then the report's
    worker._context.destroy(linger=0)


@pytest.mark.parametrize(
    ("text", "size"),
    [("1048576", 2**20), ("4GiB", 4 * 2**30), ("4G", 4 * 2**30), ("500 MiB", 500 * 2**20),
     ("2GB", 2 * 10**9), ("1.5kib", 1536), ("10b", 10)],
)
def test_sizes_are_read_with_their_units(text: str, size: int) -> None:
    assert parse_size(text) == size


@pytest.mark.parametrize("text", ["", "GiB", "4 XB", "-1", "0", "4GiB extra"])
def test_a_bad_size_says_what_is_accepted(text: str) -> None:
    with pytest.raises(CalibrationInputError, match=r"size|byte"):
        parse_size(text)


def test_the_command_line_sets_the_limit(capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    assert parser.parse_args(["worker"]).cache_max == DEFAULT_MAX_BYTES == 4 * 2**30
    assert parser.parse_args(["worker", "--cache-max", "500MiB"]).cache_max == 500 * 2**20
    with pytest.raises(SystemExit):
        parser.parse_args(["worker", "--cache-max", "lots"])
    assert "--cache-max: 'lots' is not a size" in capsys.readouterr().err


def test_a_limit_must_be_positive(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="positive"):
        FileCache(tmp_path, max_bytes=0)
