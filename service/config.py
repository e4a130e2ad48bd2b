"""Server configuration: one dataclass filled from ``illum serve`` flags (or by tests)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Optional

__all__ = ["ServiceConfig", "Limits", "default_job_memory", "JOB_MEMORY_FRACTION", "WORKER_BASE_ADDRESS_SPACE"]

JOB_MEMORY_FRACTION = 0.8             # of the machine's memory, shared by the workers
# Address space a warmed-up worker maps before any job (Python, numba, LLVM, Embree, thread
# stacks and malloc arenas: ~1.9 GB with 2 threads), added to the job's cap for RLIMIT_AS.
WORKER_BASE_ADDRESS_SPACE = 4 * 2**30


def default_job_memory(workers: int) -> int | None:
    """JOB_MEMORY_FRACTION of the machine's memory (MemTotal) shared by ``workers`` workers;
    None when it cannot be read."""
    try:
        with open("/proc/meminfo") as fh:
            total = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("MemTotal:"))
    except (OSError, StopIteration, ValueError, IndexError):
        return None
    return int(total * JOB_MEMORY_FRACTION / max(1, workers))


@dataclass(frozen=True)
class Limits:
    """Caps on what one request may ask for. Violations answer 413 (bodies) or 422 (fields),
    naming the field and the limit."""

    max_spp: int = 65_536
    max_time_budget: float = 24 * 3600.0     # seconds of rendering per job, also applied when unset
    max_side: int = 8192                     # pixels per side of the image
    max_pixels: int = 8192 * 8192
    max_upload_bytes: int = 256 * 1024 * 1024
    max_json_bytes: int = 1024 * 1024
    max_preconvolve_size: int = 2048
    max_attempts: int = 16
    max_frames: int = 10_000                 # frames (tasks) of one frame-range job


@dataclass(frozen=True)
class ServiceConfig:
    """Everything the server and its workers need to know.

    data_dir: jobs.db, jobs/<id>/ (log, previews, checkpoint, final image), uploads/, workers/.
    stage_root: the only tree stages may be read from (uploads live in data_dir/uploads).
    workers: worker processes (each renders one job at a time).
    backend: 'local' (render in the worker process) or 'ray' (the worker distributes the job's
    sample passes over a Ray cluster).
    heartbeat_interval / heartbeat_timeout: a running job whose heartbeat is older than the
    timeout is requeued (or failed after max_attempts) by the reaper.
    snapshot_interval: seconds between progressive snapshots (preview EXR+PNG and checkpoint).
    cancel_grace: seconds a worker has to drop a canceled job before it is killed.
    token: when set, every endpoint that reads or changes jobs needs ``Authorization: Bearer <token>``.
    asset_check_timeout: the submission-time asset check (service.assets) gives up after this
    many seconds and leaves the decision to the worker's own check.
    job_memory: bytes one job may use: its render's memory cap (renderer/memory.py; a request's
    settings.max_memory can only lower it) and, with headroom for the interpreter and kernels
    (WORKER_BASE_ADDRESS_SPACE), the worker's hard address-space limit. None: default_job_memory.
    max_time_grace: seconds a job may run beyond ``limits.max_time_budget`` (loading, building,
    compiling, writing) before the supervisor kills its worker and fails it, heartbeats or not.
    """

    data_dir: str
    stage_root: str
    workers: int = 1
    backend: str = "local"
    ray_address: Optional[str] = None
    ray_actors: Optional[int] = None
    max_attempts: int = 3
    heartbeat_interval: float = 0.5
    heartbeat_timeout: float = 15.0
    snapshot_interval: float = 2.0
    cancel_grace: float = 1.2
    threads: Optional[int] = None
    token: Optional[str] = None
    limits: Limits = field(default_factory=Limits)
    asset_check_timeout: float = 60.0   # seconds for the submission-time asset confinement check
    job_memory: Optional[int] = None
    max_time_grace: float = 600.0

    def job_memory_cap(self) -> int | None:
        """job_memory, else default_job_memory for this many workers."""
        return self.job_memory or default_job_memory(max(1, self.workers))

    def __post_init__(self):
        if self.backend not in ("local", "ray"):
            raise ValueError(f"backend must be 'local' or 'ray', got {self.backend!r}")
        if self.workers < 0:
            raise ValueError("workers must be >= 0")
        if not 1 <= self.max_attempts <= self.limits.max_attempts:
            raise ValueError(f"max_attempts must be in [1, {self.limits.max_attempts}]")
        if self.job_memory is not None and self.job_memory < 2**20:
            raise ValueError("the job memory cap must be at least 1 MiB")
        if self.max_time_grace < 0:
            raise ValueError("max_time_grace must be >= 0")
        if self.heartbeat_timeout <= 2 * self.heartbeat_interval:
            raise ValueError("heartbeat_timeout must exceed twice the heartbeat interval")

    @property
    def db_path(self) -> str:
        return os.path.join(self.data_dir, "jobs.db")

    @property
    def jobs_dir(self) -> str:
        return os.path.join(self.data_dir, "jobs")

    @property
    def uploads_dir(self) -> str:
        return os.path.join(self.data_dir, "uploads")

    def job_dir(self, job_id: str) -> str:
        return os.path.join(self.jobs_dir, job_id)

    def worker_threads(self) -> int:
        """Render threads per worker: the cores shared out so N workers do not oversubscribe."""
        if self.threads:
            return int(self.threads)
        return max(1, (os.cpu_count() or 1) // max(1, self.workers))
