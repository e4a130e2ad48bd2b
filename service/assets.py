"""Asset confinement of service jobs: a render job may read files only under the stage root
(an uploaded stage: under the stage root and the uploads directory).

The check is ``renderer.usd.confine.find_escapes`` (layers, composition arcs, value clips,
asset-valued attributes; see there). It runs twice:

* **at submission**, so ``POST /jobs`` answers 400 naming the layer, prim, attribute and path.
  The server never imports USD: the check runs in a child process (``python -m service.assets``)
  with a memory cap and a timeout, so a hostile stage can crash, hang or bloat only that child.
  At most ``MAX_PARALLEL`` children run at once, and a verdict is reused while every layer the
  stage uses keeps its real path, size, mtime and inode and every asset its real path, for at
  most ``CACHE_TTL`` seconds.
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

__all__ = ["AssetChecker", "Verdict", "check_in_process", "allowed_roots", "display_name"]

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
                return Verdict(hit.get("error"), True)
            result = self._run_child(stage_path, upload)
            if "error" not in result:
                return Verdict(None, False, result.get("reason", "unknown"))
            with self._lock:
                if len(self._cache) >= CACHE_SIZE:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[key] = (_signature(result), result, time.monotonic())
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
        cmd = [sys.executable, "-m", "service.assets", "--stage-root", self.stage_root,
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
                return {"reason": f"timed out after {self.timeout:g} s"}
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


def _limit_resources(memory_mb: int, cpu_seconds: int) -> None:
    try:
        import resource

        if memory_mb > 0:
            cap = memory_mb * 1024 * 1024
            resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
        if cpu_seconds > 0:
            resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds))
    except (ImportError, ValueError, OSError):  # not POSIX, or the hard limit is lower already
        pass


def main(argv: list[str] | None = None) -> int:
    """Child entry point: print one JSON line {"error", "layers", "assets"} (or {"reason"} when
    the stage cannot be opened) and exit 0."""
    p = argparse.ArgumentParser(prog="python -m service.assets")
    p.add_argument("--stage-root", required=True)
    p.add_argument("--uploads", required=True)
    p.add_argument("--upload", action="store_true")
    p.add_argument("--memory-mb", type=int, default=DEFAULT_MEMORY_MB)
    p.add_argument("--cpu-seconds", type=int, default=0)
    p.add_argument("stage")
    a = p.parse_args(argv)
    _limit_resources(a.memory_mb, a.cpu_seconds)
    from renderer.errors import IllumError

    try:
        result = check_in_process(a.stage, a.stage_root, a.uploads, a.upload)
    except IllumError as e:
        result = {"reason": f"cannot open the stage: {e}"}
    sys.stdout.write(json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
