"""Asset confinement of service jobs: a render job may read files only under the stage root
(an uploaded stage: under the stage root and the uploads directory).

The check is ``renderer.usd.confine.find_escapes`` (layers, composition arcs, value clips,
asset-valued attributes; see there). It runs twice:

* **after submission, off the request path**: ``POST /jobs`` queues the job with its check
  pending and answers at once; ``CheckQueue``'s ``MAX_PARALLEL`` long-lived threads run the
  checks, and a refused job fails with the message naming the layer, prim, attribute and path
  (no worker ever claims it). A slow check of a huge stage therefore never holds a request
  thread: ``/health`` and ``GET /jobs`` stay fast under a flood of uploads.
  The server never imports USD: the check runs in a child process (``python -m service.assets``)
  with a memory cap and a timeout, so a hostile stage can crash, hang or bloat only that child,
  and the child dies with the server (``procs.die_with_parent``). A verdict is reused while
  every layer the stage uses keeps its real path, size, mtime and inode and every asset its
  real path, for at most ``CACHE_TTL`` seconds; so is a check that timed out, while the stage
  file is unchanged.
* **in the worker, before rendering** (in-process: the worker is disposable), so a stage whose
  layers changed after submission, or one whose submission check could not finish, is still
  never rendered unchecked.

When the submission check cannot finish (the stage does not open, or the child crashed or
timed out) the job is accepted and the worker's check decides, as before for unreadable stages.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Optional

__all__ = ["AssetChecker", "CheckQueue", "Verdict", "check_in_process", "allowed_roots", "display_name"]

log = logging.getLogger("illum.assets")

MAX_PARALLEL = 2          # child processes at once (the machine's cores are for rendering)
CACHE_TTL = 60.0          # seconds a verdict is reused, even when no file changed
CACHE_SIZE = 512
DEFAULT_MEMORY_MB = 4096  # address-space cap of the checking child


def allowed_roots(stage_root: str, uploads_dir: str, upload: bool) -> tuple[list[str], str]:
    """(directories a job may read, how messages name them)."""
    if upload:
        return [stage_root, uploads_dir], "the stage root and the uploads"
    return [stage_root], "the stage root"


def display_name(path: str, stage_root: str, uploads_dir: str) -> str:
    """What users call a server path: relative to the stage root, ``upload:NAME``, or the path."""
    real = os.path.realpath(path)
    for root, prefix in ((os.path.realpath(uploads_dir), "upload:"), (os.path.realpath(stage_root), "")):
        if real.startswith(root.rstrip(os.sep) + os.sep):
            rel = os.path.relpath(real, root).replace(os.sep, "/")
            return prefix + rel.split("-", 1)[-1] if prefix else rel
    return path


def check_in_process(stage_path: str, stage_root: str, uploads_dir: str, upload: bool) -> dict:
    """Run the check here (imports USD). Returns {"error": one-line message or None,
    "layers": [...], "assets": [...]}; raises StageError when the stage cannot be opened."""
    from renderer.usd.confine import find_escapes

    roots, where = allowed_roots(stage_root, uploads_dir, upload)
    report = find_escapes(stage_path, roots)
    error = None
    if report.escapes:
        first = report.escapes[0]
        error = str(first.error(lambda p: display_name(p, stage_root, uploads_dir), where,
                                more=len(report.escapes) - 1))
    return {"error": error, "layers": report.layers, "assets": report.assets}


@dataclass(frozen=True)
class Verdict:
    """error: the one-line refusal, or None. checked: False when the check could not finish
    (the job is accepted and the worker checks again); reason says why."""

    error: Optional[str]
    checked: bool
    reason: str = ""


def _signature(result: dict) -> tuple:
    """Everything a cached verdict depends on: real path and stat of each layer, real path of
    each asset (a retargeted symlink changes it)."""
    sig = []
    for p in result.get("layers", []):
        real = os.path.realpath(p)
        try:
            st = os.stat(real)
            sig.append((p, real, st.st_mtime_ns, st.st_size, st.st_ino))
        except OSError:
            sig.append((p, real, None))
    for p in result.get("assets", []):
        sig.append((p, os.path.realpath(p)))
    return tuple(sig)


class AssetChecker:
    """The server's submission-time check: child processes, a bounded pool, a verdict cache."""

    def __init__(self, stage_root: str, uploads_dir: str, *, timeout: float = 60.0,
                 memory_mb: int = DEFAULT_MEMORY_MB, max_parallel: int = MAX_PARALLEL):
        self.stage_root = stage_root
        self.uploads_dir = uploads_dir
        self.timeout = float(timeout)
        self.memory_mb = int(memory_mb)
        self._slots = threading.BoundedSemaphore(max_parallel)
        self._lock = threading.Lock()
        self._key_locks: dict = {}
        self._cache: dict = {}          # key -> (signature, result, time)

    def check(self, stage_path: str, upload: bool) -> Verdict:
        key = (os.path.realpath(stage_path), upload)
        with self._lock:
            key_lock = self._key_locks.setdefault(key, threading.Lock())
        with key_lock:  # concurrent submissions of one stage wait for one check
            hit = self._cached(key)
            if hit is not None:
                if "error" not in hit:
                    return Verdict(None, False, hit.get("reason", "unknown"))
                return Verdict(hit.get("error"), True)
            result = self._run_child(stage_path, upload)
            if "error" not in result:
                if not result.get("timed_out"):
                    return Verdict(None, False, result.get("reason", "unknown"))
                # A timeout is cached too (keyed on the stage file itself): resubmitting the same
                # huge stage must not cost another full timeout of a checking slot each time.
                result = {**result, "layers": [stage_path], "assets": []}
            with self._lock:
                if len(self._cache) >= CACHE_SIZE:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[key] = (_signature(result), result, time.monotonic())
            if "error" not in result:
                return Verdict(None, False, result["reason"])
            return Verdict(result["error"], True)

    def _cached(self, key) -> Optional[dict]:
        with self._lock:
            entry = self._cache.get(key)
        if entry is None:
            return None
        sig, result, t = entry
        if time.monotonic() - t > CACHE_TTL or _signature(result) != sig:
            with self._lock:
                self._cache.pop(key, None)
            return None
        return result

    def _run_child(self, stage_path: str, upload: bool) -> dict:
        cmd = [sys.executable, "-m", "service.assets", "--parent-pid", str(os.getpid()), "--stage-root", self.stage_root,
               "--uploads", self.uploads_dir, "--memory-mb", str(self.memory_mb),
               "--cpu-seconds", str(int(self.timeout) + 5)]
        if upload:
            cmd.append("--upload")
        cmd += ["--", stage_path]
        env = dict(os.environ)
        pkg_parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env["PYTHONPATH"] = os.pathsep.join(p for p in (pkg_parent, env.get("PYTHONPATH", "")) if p)
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = "1"
        env.pop("ILLUM_TOKEN", None)
        with self._slots:
            try:
                proc = subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, env=env,
                                      timeout=self.timeout, close_fds=True)
            except subprocess.TimeoutExpired:
                log.warning("asset check of %s timed out after %g s; the worker will check it", stage_path,
                            self.timeout)
                return {"reason": f"timed out after {self.timeout:g} s", "timed_out": True}
            except OSError as e:
                log.warning("asset check of %s could not start: %s", stage_path, e)
                return {"reason": f"could not start: {e}"}
        lines = proc.stdout.decode("utf-8", errors="replace").strip().splitlines()
        try:
            result = json.loads(lines[-1]) if lines else {}
        except ValueError:
            result = {}
        if proc.returncode != 0 or not isinstance(result, dict) or ("error" not in result and "reason" not in result):
            tail = proc.stderr.decode("utf-8", errors="replace").strip().splitlines()[-1:] or [""]
            log.warning("asset check of %s failed (exit %s): %s", stage_path, proc.returncode, tail[0][:300])
            return {"reason": f"the checking process exited with {proc.returncode}"}
        return result


class CheckQueue:
    """The server's asset checks, off the request path (module docstring).

    ``threads`` long-lived threads take the store's pending checks oldest first, run
    ``checker.check`` and record the verdict with ``store.check_done``; ``on_refused(job,
    message)`` is called for each job the check failed. ``notify`` wakes them for a new job; they
    also rescan every ``rescan`` seconds, so jobs left pending by a previous server (or queued
    by another process) are checked too. The threads are long-lived on purpose: a checking
    child's parent-death signal follows the thread that spawned it.
    """

    def __init__(self, store, checker: AssetChecker, *, threads: int = MAX_PARALLEL, rescan: float = 5.0,
                 on_refused=None):
        self.store = store
        self.checker = checker
        self.rescan = float(rescan)
        self.on_refused = on_refused
        self._cond = threading.Condition()
        self._taken: set = set()
        self._stopping = False
        self._threads = [threading.Thread(target=self._run, name=f"asset-check-{i}", daemon=True)
                         for i in range(max(1, int(threads)))]

    def start(self) -> None:
        for t in self._threads:
            t.start()

    def notify(self) -> None:
        with self._cond:
            self._cond.notify_all()

    def stop(self, timeout: float = 5.0) -> None:
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        for t in self._threads:
            if t.is_alive():
                t.join(timeout)

    def _next(self):
        with self._cond:
            while not self._stopping:
                try:
                    pending = self.store.pending_checks()
                except Exception:  # the database is busy or gone for a moment: retry later
                    log.exception("listing pending asset checks failed")
                    pending = []
                for job in pending:
                    if job.id not in self._taken:
                        self._taken.add(job.id)
                        return job
                self._cond.wait(self.rescan)
        return None

    def _run(self) -> None:
        while (job := self._next()) is not None:
            try:
                verdict = self.checker.check(job.stage, upload=job.stage_name.startswith("upload:"))
                if not verdict.checked:
                    log.info("asset check of %s could not finish (%s); the worker checks it", job.stage_name,
                             verdict.reason)
                if self.store.check_done(job.id, verdict.error) and verdict.error and self.on_refused:
                    self.on_refused(job, verdict.error)
            except Exception:
                # The worker checks again before rendering, so an unexpected failure here lets
                # the job through rather than leaving it pending forever.
                log.exception("asset check of job %s failed", job.id)
                try:
                    self.store.check_done(job.id, None)
                except Exception:
                    log.exception("recording the asset check of job %s failed", job.id)
            finally:
                with self._cond:
                    self._taken.discard(job.id)


def main(argv: list[str] | None = None) -> int:
    """Child entry point: print one JSON line {"error", "layers", "assets"} (or {"reason"} when
    the stage cannot be opened) and exit 0."""
    p = argparse.ArgumentParser(prog="python -m service.assets")
    p.add_argument("--stage-root", required=True)
    p.add_argument("--uploads", required=True)
    p.add_argument("--upload", action="store_true")
    p.add_argument("--memory-mb", type=int, default=DEFAULT_MEMORY_MB)
    p.add_argument("--cpu-seconds", type=int, default=0)
    p.add_argument("--parent-pid", type=int, default=None, help="exit when this process (the server) dies")
    p.add_argument("stage")
    a = p.parse_args(argv)
    if a.parent_pid is not None:
        from .procs import die_with_parent

        die_with_parent(a.parent_pid)
    from .procs import limit_resources

    limit_resources(a.memory_mb * 2**20, a.cpu_seconds)
    from renderer.errors import IllumError, SpecialFileError, StageError

    try:
        result = check_in_process(a.stage, a.stage_root, a.uploads, a.upload)
    except SpecialFileError as e:  # a FIFO or device layer: refused now, as the worker would
        where = display_name(e.file, a.stage_root, a.uploads) if e.file else ""
        result = {"error": str(StageError(e.message, file=where, prim=e.prim, attribute=e.attribute)),
                  "layers": [a.stage], "assets": []}
    except IllumError as e:
        result = {"reason": f"cannot open the stage: {e}"}
    sys.stdout.write(json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
