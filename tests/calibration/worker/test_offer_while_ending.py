"""A job offered while the last one's thread is still ending waits for it instead of being
refused: the daemon counts a worker idle from its last word on a job, a moment before the job
thread ends, and a refusal was re-offered at once until the job's attempts were spent (a
chaos-test failure: 20 refusals in a row)."""

from __future__ import annotations

import threading
from pathlib import Path

from acquisition.contracts.job_messages import Failed, Job, JournalPrefix
from calibration.worker import Worker, WorkerSettings

WAIT_S = 10.0


def _job(n: int) -> Job:
    return Job(job_id=f"s{n}.final", attempt=1, kind="final", session_id=f"s{n}", poses=1,
               journal=JournalPrefix(bytes=10, sha256="0" * 64), files=[])


def test_an_offer_during_the_last_jobs_end_runs_after_it(tmp_path: Path) -> None:
    worker = Worker(WorkerSettings(jobs=f"ipc://{tmp_path}/jobs", files=f"ipc://{tmp_path}/f",
                                   cache=tmp_path / "cache"))
    sent: list[Failed] = []
    started: list[str] = []
    release = threading.Event()

    def work(job: Job) -> None:  # the job thread: its answer was sent, it is still ending
        started.append(job.job_id)
        release.wait(WAIT_S)
        worker._reports.put(None)

    worker._work = work  # type: ignore[method-assign]
    def send(message: Failed, data: bytes | None = None) -> bool:
        sent.append(message)
        return True

    worker._send = send  # type: ignore[method-assign,assignment]
    try:
        worker._start(_job(1))
        worker._start(_job(2))  # the daemon already counts the worker idle
        assert sent == [] and started == ["s1.final"]
        worker._start(_job(3))  # a second one while one waits: refused, retryable
        assert [(type(m), m.job_id, m.retryable) for m in sent] == [(Failed, "s3.final", True)]

        release.set()
        for _ in range(1000):  # the worker's loop notices the thread's end
            worker._forward_reports()
            if worker.jobs_done == 2:
                break
            threading.Event().wait(0.01)
        assert started == ["s1.final", "s2.final"]
        assert worker.jobs_done == 2 and worker._deferred is None and worker._thread is None
    finally:
        release.set()
        if worker._thread is not None:
            worker._thread.join(WAIT_S)
        worker._context.destroy(linger=0)
