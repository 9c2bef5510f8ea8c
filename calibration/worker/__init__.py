"""The calibration worker: takes jobs from the acquisition daemon over ZeroMQ and calibrates.

`micam worker --control ENDPOINT` runs `Worker`. Modules: worker (the job loop: ready,
heartbeats, one job at a time, reconnect), fetch (session files in chunks over the daemon's
file endpoint, verified against the journal's checksums, into `cache`), compute (a job's
calibration: the full one for a closed session, a quick one after a pose) and live (the live
update: uncertainties, predicted accuracy, where a new pose would help most). The wire format
is `acquisition.contracts.job_messages`; docs/protocol.md describes the exchange.
"""

from .worker import Worker, WorkerSettings

__all__ = ["Worker", "WorkerSettings"]
