"""The server's supervisor thread: keeps N worker processes alive and runs the reaper.

* Workers are separate processes (``python -m service.worker``), started with list arguments
  (never through a shell), output to ``DATA/workers/<id>.log``.
* A worker that dies (``kill -9``, a crash) is replaced; its running job is marked stale at once,
  so the reaper requeues it on its next tick (resuming from the job's checkpoint) or fails it
  after ``max_attempts``.
* A worker that has not dropped a canceled job within ``cancel_grace`` seconds (a render pass
  can be long at high resolution) is killed and replaced: cancel always takes effect.
* The reaper requeues running jobs whose heartbeat went stale (this also covers workers on
  other hosts or started by hand), and a collector removes deleted jobs and their directories.
* A job running longer than ``--max-time`` + ``--max-time-grace`` (this attempt) has its
  worker killed and fails for good, even while the worker heartbeats (a blocked read).
* On start-up after a crash of the server, jobs held by workers that no longer exist are made
  stale immediately, so they resume without waiting for the heartbeat timeout.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from .config import ServiceConfig
from .store import JobStore

__all__ = ["Supervisor"]

log = logging.getLogger("illum.supervisor")

TICK = 0.2            # seconds between process checks
REAP_EVERY = 0.5      # seconds between reaper runs
COLLECT_EVERY = 2.0   # seconds between removals of deleted jobs


@dataclass
class _Slot:
    index: int
    proc: subprocess.Popen | None = None
    worker_id: str = ""
    generation: int = 0
    started: float = 0.0
    crashes: list = field(default_factory=list)   # monotonic times of recent early exits
    not_before: float = 0.0                       # respawn back-off
    held: tuple | None = None                     # (job, running frame task or None) the worker holds, as last seen
    job_seen: float = 0.0                         # monotonic time it was first seen holding it


class Supervisor:
    """Owns the worker processes of one server."""

    def __init__(self, config: ServiceConfig, store: JobStore):
        self.config = config
        self.store = store
        n = config.workers
        if config.backend == "ray" and not config.ray_address and n > 1:
            # Each worker is a Ray driver; without a cluster address each would start its own
            # local cluster on the same cores. One driver uses the whole local cluster instead.
            log.warning("--backend ray without --ray-address: using 1 driver worker instead of %d", n)
            n = 1
        self.slots = [_Slot(index=i + 1) for i in range(n)]
        self._stop = threading.Event()
        self._stop_timeout = 10.0
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.started_at = time.time()
        self.workers_log_dir = os.path.join(config.data_dir, "workers")

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        os.makedirs(self.workers_log_dir, exist_ok=True)
        self.recover()
        # Spawning happens on the supervisor thread only: Linux's parent-death signal fires when
        # the *thread* that spawned a worker exits, so that thread must live as long as we do.
        self._thread = threading.Thread(target=self._run, name="illum-supervisor", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop, then ask every worker to checkpoint and requeue (SIGTERM), killing
        those that have not exited after ``timeout`` seconds."""
        self._stop_timeout = timeout
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        else:
            self._stop_workers(timeout)

    def _stop_workers(self, timeout: float) -> None:
        # Runs on the supervisor thread (see start): were that thread to end first, the kernel
        # would SIGKILL the workers before they could checkpoint.
        with self._lock:
            procs = [s.proc for s in self.slots if s.proc is not None]
            for p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + timeout
            for p in procs:
                try:
                    p.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            for s in self.slots:
                s.proc = None

    def alive(self) -> int:
        with self._lock:
            return sum(1 for s in self.slots if s.proc is not None and s.proc.poll() is None)

    def worker_pids(self) -> dict[str, int]:
        """{worker id: pid} of live workers (tests use it to kill one)."""
        with self._lock:
            return {s.worker_id: s.proc.pid for s in self.slots if s.proc is not None and s.proc.poll() is None}

    # ------------------------------------------------------------------ recovery
    def recover(self) -> None:
        """After a server crash: workers recorded on this host whose process is gone (they die
        with the server) lose their jobs now rather than after the heartbeat timeout."""
        host = socket.gethostname()
        for w in self.store.workers():
            if w["host"] == host and not _is_worker_process(w["pid"]):
                jobs = self.store.worker_lost(w["id"], "the server restarted while the job was running")
                if jobs:
                    log.info("recovered jobs %s from vanished worker %s", jobs, w["id"])
        self.store.reap(self.config.heartbeat_timeout)

    # ------------------------------------------------------------------ loop
    def _run(self) -> None:
        try:
            self._loop()
        finally:
            self._stop_workers(self._stop_timeout)

    def _loop(self) -> None:
        last_reap = last_collect = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                with self._lock:
                    for slot in self.slots:
                        self._check(slot, now)
                self._enforce_cancel_deadlines()
                self._enforce_max_time(now)
                if now - last_reap >= REAP_EVERY:
                    last_reap = now
                    for job_id, state in self.store.reap(self.config.heartbeat_timeout):
                        log.info("reaper: job %s -> %s", job_id, state)
                if now - last_collect >= COLLECT_EVERY:
                    last_collect = now
                    for job_id in self.store.collect_deleted():
                        shutil.rmtree(self.config.job_dir(job_id), ignore_errors=True)
            except Exception:  # the supervisor must outlive any single failure (e.g. a locked DB)
                log.exception("supervisor tick failed")
            self._stop.wait(TICK)

    def _check(self, slot: _Slot, now: float) -> None:
        if slot.proc is not None:
            code = slot.proc.poll()
            if code is None:
                return
            reason = (f"worker {slot.worker_id} was killed by {signal.Signals(-code).name}" if code < 0
                      else f"worker {slot.worker_id} exited with code {code}")
            jobs = self.store.worker_lost(slot.worker_id, reason)
            log.warning("%s%s", reason, f" while running {jobs}" if jobs else "")
            if now - slot.started < 10.0:
                slot.crashes = [t for t in slot.crashes if now - t < 60.0] + [now]
                if len(slot.crashes) >= 3:  # crash loop (broken install?): back off
                    slot.not_before = now + 5.0
            slot.proc = None
        if now >= slot.not_before:
            self._spawn(slot, now)

    def _spawn(self, slot: _Slot, now: float) -> None:
        c = self.config
        slot.generation += 1
        slot.worker_id = f"{socket.gethostname().split('.')[0]}-{os.getpid()}-w{slot.index}.{slot.generation}"
        threads = c.worker_threads()
        cmd = [sys.executable, "-m", "service.worker", "--supervised",
               "--data", c.data_dir, "--id", slot.worker_id,
               "--heartbeat-interval", repr(c.heartbeat_interval), "--snapshot-interval", repr(c.snapshot_interval),
               "--threads", str(threads), "--max-time", repr(c.limits.max_time_budget),
               "--max-side", str(c.limits.max_side), "--max-pixels", str(c.limits.max_pixels),
               "--backend", c.backend, "--stage-root", os.path.realpath(c.stage_root)]
        if c.job_memory_cap():
            cmd += ["--max-memory", str(c.job_memory_cap())]
        if c.ray_address:
            cmd += ["--ray-address", c.ray_address]
        if c.ray_actors:
            cmd += ["--ray-actors", str(c.ray_actors)]
        if c.backend == "ray":
            cmd += ["--ray-drivers", str(len(self.slots))]
        env = dict(os.environ)
        # The worker imports this very package, wherever it was imported from here.
        pkg_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env["PYTHONPATH"] = os.pathsep.join(p for p in (pkg_parent, env.get("PYTHONPATH", "")) if p)
        env.setdefault("NUMBA_NUM_THREADS", str(threads))
        env.pop("ILLUM_TOKEN", None)  # workers talk to the DB, never to the API
        log_path = os.path.join(self.workers_log_dir, f"{slot.worker_id}.log")
        with open(log_path, "ab") as out:
            # Its own process group: whatever the worker starts (a local Ray cluster) stays in it,
            # and the worker's group guard (procs.guard_process_group) kills it with the worker.
            slot.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                         env=env, close_fds=True, process_group=0)
        slot.started = now
        log.info("started worker %s (pid %d)", slot.worker_id, slot.proc.pid)

    def _enforce_cancel_deadlines(self) -> None:
        late = {w["id"]: w["job_id"] for w in self.store.workers_past_deadline()}
        if not late:
            return
        with self._lock:
            for slot in self.slots:
                if slot.worker_id in late and slot.proc is not None and slot.proc.poll() is None:
                    job_id = late[slot.worker_id]
                    log.warning("worker %s did not drop canceled job %s in time: killing it", slot.worker_id, job_id)
                    slot.proc.kill()
                    append_job_log(self.config.job_dir(job_id), f"[supervisor] worker {slot.worker_id} was still "
                                    f"busy {self.config.cancel_grace:g} s after the cancel (a long pass): killed")


    def _enforce_max_time(self, now: float) -> None:
        """Kill the worker of a job that has run longer than the server's max time plus
        max_time_grace this attempt, and fail the job for good: a worker blocked in a read (a
        stage that never finishes opening) still heartbeats, so the reaper would never notice.
        An attempt is timed from when this supervisor first sees its worker holding it; for a
        frame-range job, each frame task's attempt is timed on its own (the limit is per frame)."""
        c = self.config
        limit = c.limits.max_time_budget + c.max_time_grace
        frames = self.store.running_tasks()
        holding = {w["id"]: (w["job_id"], frames.get(w["job_id"])) for w in self.store.workers() if w["job_id"]}
        with self._lock:
            for slot in self.slots:
                held = holding.get(slot.worker_id)
                job_id = held[0] if held else None
                if held != slot.held:
                    slot.held, slot.job_seen = held, now
                if job_id is None or now - slot.job_seen <= limit or slot.proc is None or slot.proc.poll() is not None:
                    continue
                msg = (f"the job ran {now - slot.job_seen:.0f} s, beyond this server's limit of "
                       f"{c.limits.max_time_budget:g} s (--max-time) + {c.max_time_grace:g} s (--max-time-grace): "
                       f"its worker was killed")
                log.warning("job %s on worker %s: %s", job_id, slot.worker_id, msg)
                self.store.finish(job_id, slot.worker_id, "failed", error=msg)
                slot.proc.kill()
                append_job_log(c.job_dir(job_id), f"[supervisor] {msg}")


def append_job_log(job_dir: str, message: str) -> None:
    """One line in the job's log, in the worker's format (the job directory may be gone)."""
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime())
    try:
        with open(os.path.join(job_dir, "job.log"), "a", encoding="utf-8") as fh:
            fh.write(f"{stamp} {message}\n")
    except OSError:
        pass


def _is_worker_process(pid: int) -> bool:
    """True if ``pid`` is alive and is an illum worker (pids get reused)."""
    try:
        with open(f"/proc/{int(pid)}/cmdline", "rb") as fh:
            return b"service.worker" in fh.read()
    except OSError:
        if sys.platform.startswith("linux"):
            return False
    try:  # not Linux: fall back to existence only
        os.kill(int(pid), 0)
        return True
    except OSError:
        return False
