"""Worker process: claims jobs from the store and runs them, one at a time.

Run as ``python -m service.worker --data DIR --id W1 ...`` (the supervisor does this; it can
also be started by hand on the same host to add capacity). Rendering happens here, never in
the server process.

Per job:
* a heartbeat thread refreshes the job's heartbeat every ``--heartbeat-interval`` seconds, with
  the process's peak memory during the job (PeakMemory); a rowcount of 0 (canceled, deleted or reassigned by the reaper) sets the stop flag, which the
  renderer's ``cancel`` callback returns between passes;
* progress (percent, spp, samples/s, ETA) goes to the store about twice a second;
* every ``--snapshot-interval`` seconds (and right after the first pass) the film is written as
  ``preview.exr`` + ``preview.png`` (+ ``thumb.png`` for the job list) and checkpointed (``Film.save_state``), so a worker killed
  with ``kill -9`` resumes from there when the reaper requeues the job;
* an IllumError fails the job with its one-line message (a user error: retrying cannot help),
  and so does a MemoryError (the same job would run out again under the same limit);
  any other exception requeues it until ``max_attempts``, then fails it with the error text;
* SIGTERM (server shutdown) checkpoints the running job and requeues it without counting the
  attempt.

Before its first job a worker warms up (renderer/warmup.py): it renders every route once at a
tiny size, so numba's kernels are compiled into the on-disk cache (a cold cache) or loaded from
it, and no job pays the compile. With the Ray backend the pool's actors do the same.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sqlite3
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .models import render_options
from .procs import die_with_parent, guard_process_group, limit_resources
from .store import Job, JobStore

__all__ = ["WorkerContext", "run_job", "main"]

log = logging.getLogger("illum.worker")

# File names inside a job directory (the API serves them; see service/app.py).
PREVIEW_EXR, PREVIEW_PNG = "preview.exr", "preview.png"
FINAL_EXR, FINAL_PNG, STATS_JSON = "final.exr", "final.png", "stats.json"
THUMB_PNG = "thumb.png"     # a small sRGB PNG of the latest image, for the job list
# With settings.denoise: the OIDN-denoised beauty as sRGB PNGs, of each snapshot and of the end
PREVIEW_DENOISED_PNG, FINAL_DENOISED_PNG = "preview_denoised.png", "final_denoised.png"
THUMB_SIZE = 64             # pixels on the longer side
CHECKPOINT, CHECKPOINT_META = "checkpoint.npz", "checkpoint.json"
JOB_LOG = "job.log"
PROGRESS_DB_INTERVAL = 0.5  # seconds between progress writes to the store


@dataclass
class WorkerContext:
    """What a worker knows beyond the job row."""

    store: JobStore
    worker_id: str
    data_dir: str
    heartbeat_interval: float = 0.5
    snapshot_interval: float = 2.0
    threads: Optional[int] = None
    max_time: Optional[float] = None
    max_side: int = 8192
    max_pixels: int = 8192 * 8192
    max_memory: Optional[int] = None                       # bytes per job (the server's --max-job-memory)
    backend: str = "local"
    ray_address: Optional[str] = None
    ray_actors: Optional[int] = None
    ray_drivers: int = 1                                   # workers sharing the cluster (pool sizing)
    stage_root: Optional[str] = None                       # render jobs read files only below it
    parent_pid: Optional[int] = None
    scene_cache: dict = field(default_factory=dict)       # keeps the last scene + BVH resident
    resolution_cache: dict = field(default_factory=dict)
    shutdown: threading.Event = field(default_factory=threading.Event)
    ray_pool: object = None
    warmup: bool = True                                   # warm the kernels before the first job
    current_stop: Optional[threading.Event] = None       # the running job's stop flag (for SIGTERM)
    current_job: Optional[Job] = None                     # the running job (for a stuck load)

    def job_dir(self, job_id: str) -> str:
        return os.path.join(self.data_dir, "jobs", job_id)

    def uploads_dir(self) -> str:
        return os.path.join(self.data_dir, "uploads")


class JobLog:
    """Appends timestamped lines to the job's log file (served by GET /jobs/{id}/log)."""

    def __init__(self, path: str, worker_id: str):
        self.path = path
        self.worker_id = worker_id

    def __call__(self, message: str) -> None:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime())
        line = f"{stamp} [{self.worker_id}] {message}\n"
        try:
            with open(self.path, "a", encoding="utf-8") as fh:
                fh.write(line)
        except OSError:  # the job directory was removed (job deleted): nothing to log to
            pass


class _Heartbeat(threading.Thread):
    """Refreshes the job's heartbeat, with the worker's peak memory during the job; sets
    ``stop`` when the store says the job is no longer ours (canceled, deleted, reassigned).
    Also exits the process if the server died (the parent pid changed), so orphans never keep
    rendering unsupervised."""

    def __init__(self, ctx: WorkerContext, job_id: str, stop: threading.Event):
        super().__init__(name=f"heartbeat-{job_id}", daemon=True)
        self.ctx = ctx
        self.job_id = job_id
        self.stop = stop
        self.lost = False
        self._done = threading.Event()
        self.memory = PeakMemory()

    def peak(self) -> int | None:
        """The largest resident set size (bytes) of this process since the job started."""
        return self.memory.peak()

    def run(self) -> None:
        while not self._done.wait(self.ctx.heartbeat_interval):
            _exit_if_orphaned(self.ctx)
            try:
                ok = self.ctx.store.heartbeat(self.job_id, self.ctx.worker_id, peak_memory=self.peak())
            except sqlite3.Error as e:  # busy beyond the timeout: try again next beat
                log.warning("heartbeat failed: %s", e)
                continue
            if not ok:
                self.lost = True
                self.stop.set()
                return

    def close(self) -> None:
        self._done.set()
        self.join()


class PeakMemory:
    """Peak resident memory of this process over one job (Linux; None elsewhere).

    The kernel's high-water mark (VmHWM) is reset when the job starts (``5`` written to
    /proc/self/clear_refs), so an earlier, larger job in the same worker does not count; where
    the reset is refused, the mark is sampled against the RSS at start instead, and the larger
    of the current RSS and the samples is kept."""

    def __init__(self):
        self._max = 0
        self._reset = False
        try:
            with open("/proc/self/clear_refs", "w") as fh:
                fh.write("5")
            self._reset = True
        except OSError:
            pass
        self.peak()

    def peak(self) -> int | None:
        from renderer.memory import resident_memory

        m = resident_memory()
        if m is None:
            return None
        rss, hwm = m
        self._max = max(self._max, rss, hwm if self._reset else 0)
        return self._max


def _exit_if_orphaned(ctx: WorkerContext) -> None:
    if ctx.parent_pid is not None and os.getppid() != ctx.parent_pid:
        # The server is gone. Our job's heartbeat goes stale and the next server's reaper
        # requeues it; it resumes from the last checkpoint.
        os._exit(3)


# ------------------------------------------------------------------------------ job running
class _Canceled(Exception):
    """Raised internally when a job stops without finishing (cancel, loss, shutdown)."""


def run_job(ctx: WorkerContext, job: Job) -> str:
    """Run one claimed job to its end. Returns the outcome: succeeded, failed, requeued,
    canceled (stopped because the job was no longer ours) or shutdown (requeued on SIGTERM)."""
    from renderer.errors import IllumError

    jobdir = ctx.job_dir(job.id)
    os.makedirs(jobdir, exist_ok=True)
    jlog = JobLog(os.path.join(jobdir, JOB_LOG), ctx.worker_id)
    if job.run_attempt == 1:
        # A new run (a new job, or one a user requeued): whatever a discarded run left as its
        # result is stale (a job running has no result yet); the checkpoint is kept to resume.
        for name in (FINAL_EXR, FINAL_PNG, FINAL_DENOISED_PNG, STATS_JSON):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(os.path.join(jobdir, name))
    requeues = int(job.row.get("requeues") or 0)
    again = f" (attempt {job.attempts} in all; {requeues} requeue{'s' if requeues > 1 else ''})" if requeues else ""
    jlog(f"attempt {job.run_attempt} of {job.max_attempts}{again} on worker {ctx.worker_id} (pid {os.getpid()}, "
         f"backend {ctx.backend}): {job.kind} {job.stage_name}")
    stop = threading.Event()
    ctx.current_stop = stop
    ctx.current_job = job
    if ctx.shutdown.is_set():  # SIGTERM arrived between the claim and here
        stop.set()
    hb = _Heartbeat(ctx, job.id, stop)
    hb.start()
    try:
        try:
            if job.kind == "render":
                result = _run_render(ctx, job, stop, jlog)
            elif job.kind == "preconvolve":
                result = _run_preconvolve(ctx, job, jlog)
            else:
                raise IllumError(f"unknown job kind {job.kind!r}")
        except _Canceled:
            return _stopped(ctx, job, hb, jlog)
        except (IllumError, _FramesFailed) as e:
            msg = _clean(str(e), job)
            jlog(f"error: {msg}")
            ctx.store.finish(job.id, ctx.worker_id, "failed", error=msg, peak_memory=hb.peak())
            return "failed"
        except MemoryError as e:
            # The hard address-space limit (or the machine) ran out: the same job would run out
            # again, so this is permanent, never retried as transient.
            from renderer.memory import format_size

            cap = f" (this server's limit per job is {format_size(ctx.max_memory)}, --max-job-memory)" \
                if ctx.max_memory else ""
            msg = _clean(f"out of memory{': ' + str(e) if str(e) else ''}{cap}", job)
            jlog(f"error: {msg}\n{traceback.format_exc()}")
            ctx.store.finish(job.id, ctx.worker_id, "failed", error=msg, peak_memory=hb.peak())
            return "failed"
        except Exception as e:  # an internal error: may be transient (disk, memory), so retry
            msg = _clean(f"internal error: {type(e).__name__}: {e}", job)
            jlog(msg + "\n" + traceback.format_exc())
            if stop.is_set():
                return _stopped(ctx, job, hb, jlog)
            if job.run_attempt < job.max_attempts:
                ctx.store.finish(job.id, ctx.worker_id, "queued", error=msg, peak_memory=hb.peak())
                jlog(f"requeued (attempt {job.run_attempt} of {job.max_attempts})")
                return "requeued"
            ctx.store.finish(job.id, ctx.worker_id, "failed", peak_memory=hb.peak(),
                             error=f"{msg} (attempt {job.run_attempt} of {job.max_attempts}; giving up)")
            return "failed"
        if not ctx.store.finish(job.id, ctx.worker_id, "succeeded", result=result, progress=100.0,
                                spp_done=int(result.get("spp", 0)), render_seconds=float(result.get("render_seconds", 0)),
                                peak_memory=hb.peak()):
            jlog("finished, but the job was no longer ours (canceled or reassigned); result discarded")
            return "canceled"
        jlog(f"succeeded: {json.dumps(result, sort_keys=True)}")
        return "succeeded"
    finally:
        hb.close()
        ctx.current_stop = None
        ctx.current_job = None


def _stopped(ctx: WorkerContext, job: Job, hb: _Heartbeat, jlog: JobLog) -> str:
    if ctx.shutdown.is_set() and not hb.lost:
        ctx.store.finish(job.id, ctx.worker_id, "queued", refund_attempt=True, peak_memory=hb.peak())
        jlog("worker shutting down: checkpointed and requeued")
        return "shutdown"
    ctx.store.release(ctx.worker_id)
    jlog("stopped: the job was canceled, deleted or reassigned")
    return "canceled"


def _clean(message: str, job: Job) -> str:
    """Errors name the stage as the user named it, not by the server's absolute path."""
    return message.replace(job.stage, job.stage_name).strip().splitlines()[0] if message.strip() else message


class _Checkpoint:
    """checkpoint.npz (Film.save_state) + checkpoint.json (spp, render seconds, backend state)."""

    def __init__(self, jobdir: str):
        self.npz = os.path.join(jobdir, CHECKPOINT)
        self.meta = os.path.join(jobdir, CHECKPOINT_META)

    def load(self, jlog: JobLog):
        """(film, meta dict) of the last checkpoint, or (None, {}) when there is none usable."""
        from renderer.film import Film

        if not (os.path.exists(self.npz) and os.path.exists(self.meta)):
            return None, {}
        try:
            with open(self.meta, encoding="utf-8") as fh:
                meta = json.load(fh)
            film = Film.load_state(self.npz)
        except (OSError, ValueError, KeyError) as e:
            jlog(f"checkpoint unreadable ({e}); starting over")
            return None, {}
        return film, meta

    def save(self, film, meta: dict) -> None:
        # Film first, then the meta that describes it: a crash in between leaves a newer film
        # with older meta, which only under-counts render time (never double-counts samples,
        # since the sample count lives in the film itself).
        film.save_state(self.npz)
        tmp = self.meta + ".tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(meta, fh)
        os.replace(tmp, self.meta)

    def remove(self) -> None:
        for p in (self.npz, self.meta):
            try:
                os.unlink(p)
            except FileNotFoundError:
                pass


class _Tracker:
    """The renderer's callbacks for one job: cancel (and render-start time), progress to the
    store, snapshots (preview + checkpoint) to the job directory."""

    def __init__(self, ctx: WorkerContext, job: Job, jobdir: str, stop: threading.Event, jlog: JobLog, *,
                 target: int | None, budget: float | None, used_seconds: float, start_spp: int,
                 task: Optional["_TaskRun"] = None):
        self.ctx, self.job, self.jobdir, self.stop, self.jlog = ctx, job, jobdir, stop, jlog
        self.task = task                      # the frame task rendering (a frame-range job), else None
        self.target = target
        self.budget = budget                  # total budget of the job (all attempts)
        self.used = used_seconds              # render seconds of earlier attempts
        self.start_spp = start_spp
        self.t0: float | None = None          # first cancel() call = start of this run's passes
        self.t_created = time.monotonic()
        self.last_db = 0.0
        self.last_snap = -1e30                # the first pass is snapshotted at once (early preview)
        self.snap_cost = 0.0                  # seconds the last snapshot took to write
        self.last_logged_pct = -1
        self.ckpt = _Checkpoint(task.dir if task is not None else jobdir)
        self.state_extra: dict = {}           # backend state saved with the checkpoint (Ray blocks)
        self.film = None
        self.aovs = None
        self.denoise_failed = False
        self.done = start_spp

    # renderer callbacks -------------------------------------------------------------
    def cancel(self) -> bool:
        if self.t0 is None:  # the renderer asks before its first pass: load and build are done
            self.t0 = time.monotonic()
            self.jlog(f"rendering (scene ready after {self.t0 - self.t_created:.2f} s)")
        return self.stop.is_set()

    def progress(self, done: int, target, fraction: float) -> None:
        self.done = done

    def snapshot(self, film, done: int, extra: dict | None = None, aovs=None) -> None:
        """Called after every pass (snapshot_interval=0); throttles its own writes. ``aovs``
        (with settings.denoise): the render's passes, whose guides denoise the preview."""
        self.film = film
        self.aovs = aovs
        self.done = done
        if extra is not None:
            self.state_extra = extra
        now = time.monotonic()
        if self.t0 is None:
            self.t0 = now
        if now - self.last_db >= PROGRESS_DB_INTERVAL:
            self.last_db = now
            self._report(film, done, now)
        if now - self.last_snap >= max(self.ctx.snapshot_interval, 10.0 * self.snap_cost):
            self.last_snap = now
            self.write_snapshot(film, done, now)
            # Keep snapshot I/O under ~10 % of the time: a 4K checkpoint is hundreds of MB.
            self.snap_cost = time.monotonic() - now

    snapshot.takes_aovs = True   # render() passes its AOVs when the job denoises

    # helpers ------------------------------------------------------------------------
    def elapsed(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        return 0.0 if self.t0 is None else now - self.t0

    def fraction(self, done: int, now: float) -> float:
        fr = []
        if self.target:
            fr.append(done / self.target)
        if self.budget:
            fr.append((self.used + self.elapsed(now)) / self.budget)
        return min(1.0, max(fr)) if fr else 0.0

    def _report(self, film, done: int, now: float) -> None:
        el = max(self.elapsed(now), 1e-6)
        h, w = film.shape
        passes = max(done - self.start_spp, 0)
        sps = passes * w * h / el
        etas = []
        if passes > 0 and self.target:
            etas.append(max(self.target - done, 0) * el / passes)
        if self.budget:
            etas.append(max(self.budget - self.used - el, 0.0))
        frac = self.fraction(done, now)
        task, job_frac, render_seconds = None, frac, self.used + el
        if self.task is not None:
            # The job's progress covers the whole range; the task row has the frame's own.
            t = self.task
            task = (t.idx, {"progress": round(100.0 * frac, 2), "spp_done": int(done), "render_seconds": self.used + el})
            job_frac = (t.done + frac) / t.count
            render_seconds = t.seconds_before + self.used + el
            if etas and frac > 0:   # this frame's ETA, and the frames after it at this frame's pace
                etas = [min(etas) + (t.count - t.done - 1) * (self.used + el) / frac]
        if not self.ctx.store.progress(self.job.id, self.ctx.worker_id, task=task,
                                       progress=round(100.0 * job_frac, 2), spp_done=int(done),
                                       spp_target=self.target, samples_per_second=sps,
                                       eta_seconds=min(etas) if etas else None, render_seconds=render_seconds):
            self.stop.set()
        pct = int(frac * 100) // 10 * 10
        if pct != self.last_logged_pct:
            self.last_logged_pct = pct
            head = f"frame {self.task.frame:g}: " if self.task is not None else ""
            self.jlog(f"{head}progress {pct}% ({done} spp, {sps / 1e3:.1f} ksamples/s)")

    def write_snapshot(self, film, done: int, now: float | None = None) -> None:
        """Preview EXR + PNG, then the checkpoint, all written atomically."""
        from renderer.film import write_exr, write_png

        if self.stop.is_set() and not self.ctx.shutdown.is_set():
            return  # canceled: do not write into a directory that may be going away
        write_exr(os.path.join(self.jobdir, PREVIEW_EXR), film, {"illum:spp": int(done), "illum:jobId": self.job.id})
        write_png(os.path.join(self.jobdir, PREVIEW_PNG), film)
        if self.aovs is not None and self.aovs.passes is not None and not self.denoise_failed:
            from renderer.render import denoise_film

            try:
                write_png(os.path.join(self.jobdir, PREVIEW_DENOISED_PNG), denoise_film(film, self.aovs, full=True)[0])
            except RuntimeError as e:   # OIDN failed: the render goes on, without denoised previews
                self.denoise_failed = True
                self.jlog(f"warning: no denoised preview: {e}")
        write_thumbnail(os.path.join(self.jobdir, THUMB_PNG), film.image())
        self.ckpt.save(film, {"spp": int(done), "render_seconds": self.used + self.elapsed(now),
                              "attempt": self.job.attempts, **self.state_extra})


def frame_dir(idx: int) -> str:
    """A frame task's directory inside its job's: its checkpoint and final images."""
    return os.path.join("frames", f"{int(idx):04d}")


@dataclass
class _TaskRun:
    """The frame task a frame-range job is rendering: its index and time code, its directory
    (checkpoint, final images), and where it stands in the range (for the job's progress)."""

    idx: int
    frame: float
    dir: str
    count: int                 # frames in the range
    done: int                  # frames of the range already ended (succeeded or failed)
    seconds_before: float      # render seconds of the frames already rendered


def thumbnail(image: np.ndarray, size: int = THUMB_SIZE) -> np.ndarray:
    """Box-filtered reduction of a scene-linear image (h, w, C) so that its longer side is at
    most ``size`` pixels (never enlarged): each output pixel is the mean of the input pixels it
    covers, averaged in linear light before any display encoding."""
    h, w = image.shape[:2]
    scale = max(h, w) / size
    if scale <= 1.0:
        return np.asarray(image, dtype=np.float32)
    oh, ow = max(1, round(h / scale)), max(1, round(w / scale))
    rows = (np.arange(oh) * h) // oh       # first input row of each output row
    cols = (np.arange(ow) * w) // ow
    sums = np.add.reduceat(np.add.reduceat(np.asarray(image, dtype=np.float64), rows, axis=0), cols, axis=1)
    counts = np.diff(np.append(rows, h))[:, None] * np.diff(np.append(cols, w))[None, :]
    return (sums / counts[:, :, None]).astype(np.float32)


def write_thumbnail(path: str, image: np.ndarray) -> None:
    """THUMB_PNG: the image reduced by ``thumbnail``, display-encoded as the previews are (sRGB),
    written under a temporary name and renamed."""
    from renderer.film import write_png

    write_png(path, thumbnail(image))


def _check_stage_resolution(ctx: WorkerContext, job: Job, opts) -> None:
    """With no resolution override the stage's RenderSettings decide: hold them to the same
    server limits as a request (an uploaded stage could ask for any size)."""
    from renderer.errors import SettingsError

    if opts.resolution is not None:
        return
    key = (job.stage, os.path.getmtime(job.stage), opts.settings, opts.camera, opts.frame, opts.purposes,
           opts.strict)
    res = ctx.resolution_cache.get(key)
    if res is None:
        from renderer.memory import MemoryBudget
        from renderer.usd import load_stage

        # Only the resolution is wanted: meshes are read as their cages (no subdivision).
        desc = load_stage(job.stage, camera=opts.camera, settings=opts.settings, frame=opts.frame,
                          purposes=opts.purposes, strict=opts.strict, subdiv_level=0,
                          memory=MemoryBudget.for_options(opts.max_memory))
        res = tuple(int(v) for v in desc.settings.resolution)
        ctx.resolution_cache.clear()
        ctx.resolution_cache[key] = res
    w, h = res
    if w > ctx.max_side or h > ctx.max_side or w * h > ctx.max_pixels:
        raise SettingsError(f"the stage asks for {w}x{h}, beyond this server's limit of {ctx.max_side} pixels "
                            f"per side / {ctx.max_pixels} pixels; pass settings.resolution", attribute="resolution")


def _check_stage_assets(ctx: WorkerContext, job: Job) -> None:
    """The stage may read files only below the stage root (uploads: and the uploads): the
    submission checked this already, but layers can change while a job waits."""
    from renderer.errors import StageError

    from .assets import check_in_process

    root = ctx.stage_root or ctx.store.get_meta("stage_root")
    if not root:
        raise StageError("this worker does not know the server's stage root (start it with --stage-root)")
    result = check_in_process(job.stage, root, ctx.uploads_dir(), job.stage_name.startswith("upload:"))
    if result["error"]:
        raise StageError(result["error"])


def _run_render(ctx: WorkerContext, job: Job, stop: threading.Event, jlog: JobLog) -> dict:
    jobdir = ctx.job_dir(job.id)
    opts = render_options(job.settings, threads=ctx.threads, max_memory=ctx.max_memory)
    tasks = ctx.store.tasks(job.id)
    if tasks:  # checked at the first frame still to render
        opts.frame = next((t["frame"] for t in tasks if t["state"] in ("queued", "running")), tasks[0]["frame"])
    opts.validate()
    from renderer.deadline import deadline

    with deadline(opts.load_timeout, "checking the stage's files", file=job.stage):
        _check_stage_assets(ctx, job)
    with deadline(opts.load_timeout, "reading the stage's render settings", file=job.stage):
        _check_stage_resolution(ctx, job, opts)
    if tasks:
        return _run_frames(ctx, job, opts, stop, jlog, len(tasks))
    result, render_seconds, start_spp = _render_film(ctx, job, opts, jobdir, stop, jlog)
    return _write_final(ctx, job, opts, result, jobdir, render_seconds, start_spp, jlog)


def _render_film(ctx: WorkerContext, job: Job, opts, jobdir: str, stop: threading.Event, jlog: JobLog,
                 task: Optional[_TaskRun] = None, shared: dict | None = None):
    """Render one frame (resuming from its checkpoint, in ``task.dir`` for a frame task) with
    the job's callbacks. Returns (RenderResult, render seconds over all attempts, spp resumed
    from); raises _Canceled when the job stopped."""
    from renderer.render import render

    user_budget = opts.time_budget
    total_budget = min(user_budget, ctx.max_time) if (user_budget and ctx.max_time) else (user_budget or ctx.max_time)
    ckpt = _Checkpoint(task.dir if task is not None else jobdir)
    resume, meta = ckpt.load(jlog)
    used = float(meta.get("render_seconds", 0.0)) if resume is not None else 0.0
    start_spp = int(resume.count.max()) if resume is not None and resume.count.size else 0
    if resume is not None:
        jlog(f"{'frame %g: ' % task.frame if task else ''}resuming from checkpoint: {start_spp} spp, "
             f"{used:.1f} s rendered before")
    if total_budget is not None:
        # The budget covers all attempts; a resumed job renders at least one more pass.
        opts.time_budget = max(total_budget - used, 1e-3)
    tracker = _Tracker(ctx, job, jobdir, stop, jlog, target=opts.spp, budget=total_budget, used_seconds=used,
                       start_spp=start_spp, task=task)

    if ctx.backend == "ray":
        from .ray_backend import get_pool

        pool = get_pool(ctx)
        result = pool.render(job.stage, opts, progress=tracker.progress, snapshot=tracker.snapshot,
                             cancel=tracker.cancel, resume=resume, resume_state=meta if resume is not None else {},
                             log=jlog)
    else:
        result = render(job.stage, opts, progress=tracker.progress, snapshot=tracker.snapshot,
                        snapshot_interval=0.0, cancel=tracker.cancel, resume=resume,
                        scene_cache=None if shared is not None else ctx.scene_cache, shared=shared)
    if stop.is_set():
        if ctx.shutdown.is_set() and result.film is not None:
            tracker.write_snapshot(result.film, int(result.stats["spp"]))
        raise _Canceled()
    return result, used + float(result.stats["seconds"]["render"]), start_spp


def _write_final(ctx: WorkerContext, job: Job, opts, result, outdir: str, render_seconds: float, start_spp: int,
                 jlog: JobLog, head: str = "") -> dict:
    """The final EXR, PNG, statistics and thumbnail of a render in ``outdir``; the checkpoint
    there is removed. Returns the job's (or frame task's) result summary."""
    from renderer.render import write_outputs

    # The EXR carries the render metadata, minus the server's absolute paths.
    result.metadata["illum:stage"] = job.stage_name
    result.metadata["illum:jobId"] = job.id
    result.stats["stage"] = job.stage_name
    result.stats["job"] = {"id": job.id, "attempts": job.attempts, "render_seconds_all_attempts": render_seconds,
                           "resumed_from_spp": start_spp}
    write_outputs(result, exr=os.path.join(outdir, FINAL_EXR), png=os.path.join(outdir, FINAL_PNG),
                  stats_json=os.path.join(outdir, STATS_JSON))
    write_thumbnail(os.path.join(outdir, THUMB_PNG), result.film.image())
    if result.aovs is not None and result.aovs.denoised is not None:
        from renderer.film import write_png
        from renderer.render import full_image

        write_png(os.path.join(outdir, FINAL_DENOISED_PNG), full_image(result.film, result.aovs.denoised))
    _Checkpoint(outdir).remove()
    for w in result.warnings:
        jlog(f"{head}warning: {_clean(w, job)}")
    if opts.spp is not None and result.stats["spp"] < opts.spp:
        jlog(f"{head}warning: stopped at {result.stats['spp']} of {opts.spp} spp by the time budget")
    s = result.stats
    if s.get("kernels_compiled"):  # the warm-up missed a route (renderer/warmup.py ROUTES)
        jlog(f"compiled {s['kernels_compiled']} kernels in {s['seconds'].get('compile', 0.0):.1f} s "
             f"(a cold kernel cache; not counted in the time budget)")
    return {"spp": int(s["spp"]), "resolution": s["resolution"], "render_seconds": render_seconds,
            "samples_per_second": float(s["samples_per_second"]), "warnings": [_clean(w, job) for w in result.warnings],
            "files": [FINAL_EXR, FINAL_PNG, STATS_JSON], "resumed_from_spp": start_spp}


class _FramesFailed(Exception):
    """Some frames of a frame-range job failed for good: the job fails, not retried (each frame
    had its own attempts)."""


def _run_frames(ctx: WorkerContext, job: Job, opts, stop: threading.Event, jlog: JobLog, count: int) -> dict:
    """A frame-range job: render its tasks still queued, lowest index first, each with its own
    checkpoint and final images (frame_dir) and its own attempts; the stage is composed once for
    all of them (render(shared=...)), as ``illum render --frames`` does. A frame that fails
    for good (a user error, out of memory, or attempts spent) does not stop the others; the
    job then fails naming them. Frames already rendered (an earlier attempt) are never redone."""
    import dataclasses

    from renderer.errors import IllumError

    jobdir = ctx.job_dir(job.id)
    shared: dict | None = {} if ctx.backend != "ray" else None
    while True:
        if stop.is_set():
            raise _Canceled()
        row = ctx.store.start_task(job.id, ctx.worker_id)
        if row is False:
            stop.set()
            raise _Canceled()
        if row is None:
            break
        tasks = ctx.store.tasks(job.id)
        ended = [t for t in tasks if t["state"] in ("succeeded", "failed")]
        task = _TaskRun(idx=row["idx"], frame=row["frame"], dir=os.path.join(jobdir, frame_dir(row["idx"])),
                        count=count, done=len(ended),
                        seconds_before=sum(t["render_seconds"] for t in ended))
        os.makedirs(task.dir, exist_ok=True)
        run_attempt = row["attempts"] - row["attempt_base"]
        head = f"frame {task.frame:g}: "
        jlog(f"{head}[{task.idx + 1}/{count}] attempt {run_attempt} of {job.max_attempts}")
        frame_opts = dataclasses.replace(opts, frame=task.frame)
        try:
            if shared is not None and "stage" not in shared:
                from renderer.deadline import deadline
                from renderer.usd.stage_reader import open_stage

                with deadline(opts.load_timeout, "opening the stage", file=job.stage):
                    shared["stage"] = open_stage(job.stage)
            result, seconds, start_spp = _render_film(ctx, job, frame_opts, jobdir, stop, jlog, task=task,
                                                      shared=shared)
            summary = _write_final(ctx, job, frame_opts, result, task.dir, seconds, start_spp, jlog, head)
        except _Canceled:
            raise
        except (IllumError, MemoryError) as e:   # the same frame would fail the same way again
            msg = _clean(str(e) if isinstance(e, IllumError) else f"out of memory: {e}", job)
            jlog(f"{head}error: {msg}")
            if not ctx.store.finish_task(job.id, ctx.worker_id, task.idx, "failed", error=msg):
                raise _Canceled() from None
            continue
        except Exception as e:  # may be transient: this frame alone is retried, up to max_attempts
            if stop.is_set():
                raise _Canceled() from None
            msg = _clean(f"internal error: {type(e).__name__}: {e}", job)
            jlog(f"{head}{msg}\n{traceback.format_exc()}")
            again = run_attempt < job.max_attempts
            if not ctx.store.finish_task(job.id, ctx.worker_id, task.idx, "queued" if again else "failed",
                                         error=msg if again else f"{msg} (attempt {run_attempt} of "
                                                                 f"{job.max_attempts}; giving up)"):
                raise _Canceled() from None
            continue
        # The job's own preview and thumbnail follow the range: the page shows the last frame done.
        from renderer.film import write_exr, write_png

        write_exr(os.path.join(jobdir, PREVIEW_EXR), result.film, {"illum:spp": summary["spp"],
                                                                    "illum:jobId": job.id,
                                                                    "illum:frame": float(task.frame)})
        write_png(os.path.join(jobdir, PREVIEW_PNG), result.film)
        write_thumbnail(os.path.join(jobdir, THUMB_PNG), result.film.image())
        if not ctx.store.finish_task(job.id, ctx.worker_id, task.idx, "succeeded", spp_done=summary["spp"],
                                     render_seconds=seconds, progress=100.0):
            raise _Canceled()
        jlog(f"{head}succeeded: {summary['spp']} spp, {seconds:.2f} s")
    if shared and "stage" in shared:
        shared.clear()
    tasks = ctx.store.tasks(job.id)
    failed = [t for t in tasks if t["state"] == "failed"]
    if failed:
        first = failed[0]
        listed = ", ".join(f"{t['frame']:g}" for t in failed[:10]) + (", ..." if len(failed) > 10 else "")
        raise _FramesFailed(f"{len(failed)} of {len(tasks)} frames failed ({listed}); frame {first['frame']:g}: "
                            f"{first['error']}")
    spp = min(t["spp_done"] for t in tasks)
    return {"frames": len(tasks), "spp": spp, "render_seconds": sum(t["render_seconds"] for t in tasks),
            "files": [os.path.join(frame_dir(t["idx"]), n) for t in tasks for n in (FINAL_EXR, FINAL_PNG, STATS_JSON)]}


def _run_preconvolve(ctx: WorkerContext, job: Job, jlog: JobLog) -> dict:
    """Dome preconvolution (renderer.preconvolve). It has no cancel hook: a canceled one is
    stopped by the supervisor after the cancel grace period."""
    from renderer.errors import IllumError
    from renderer.film import read_exr, write_png

    try:
        from renderer.preconvolve import preconvolve
    except ModuleNotFoundError as e:
        if e.name != "renderer.preconvolve":
            raise
        raise IllumError("this server has no dome preconvolution (renderer.preconvolve is missing)") from None
    jobdir = ctx.job_dir(job.id)
    out = os.path.join(jobdir, FINAL_EXR)
    t0 = time.monotonic()
    last = [0.0]

    def progress(rows_done: int, rows_total: int) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_DB_INTERVAL and rows_total:
            last[0] = now
            frac = rows_done / rows_total
            el = now - t0
            ctx.store.progress(job.id, ctx.worker_id, progress=round(100.0 * frac, 2), render_seconds=el,
                               eta_seconds=el * (1 - frac) / frac if frac > 0 else None)

    s = job.settings
    preconvolve(job.stage, out, size=int(s["size"]), method=s["method"], sanitize=bool(s.get("sanitize")),
                progress=progress)
    seconds = time.monotonic() - t0
    img, _ = read_exr(out)
    write_png(os.path.join(jobdir, FINAL_PNG), img[:, :, :3])
    write_thumbnail(os.path.join(jobdir, THUMB_PNG), img[:, :, :3])
    jlog(f"preconvolved {job.stage_name} to {img.shape[1]}x{img.shape[0]} ({s['method']}) in {seconds:.2f} s")
    return {"resolution": [int(img.shape[1]), int(img.shape[0])], "render_seconds": seconds,
            "method": s["method"], "files": [FINAL_EXR, FINAL_PNG]}


# ------------------------------------------------------------------------------ main loop
def _warm_up(ctx: WorkerContext) -> None:
    """Compile or load every kernel before the first job (the module docstring), heartbeating
    meanwhile so the reaper keeps the worker's row (a cold compile takes minutes). A failure is
    logged, never fatal: a job then compiles what it needs, outside its time budget."""
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(ctx.heartbeat_interval):
            try:
                ctx.store.worker_heartbeat(ctx.worker_id)
            except sqlite3.Error as e:
                log.warning("heartbeat failed: %s", e)

    beater = threading.Thread(target=beat, name="warmup-heartbeat", daemon=True)
    beater.start()
    try:
        _warm_up_kernels(ctx)
    finally:
        stop.set()
        beater.join()


def _warm_up_kernels(ctx: WorkerContext) -> None:
    from renderer.warmup import warmup

    t0 = time.perf_counter()
    try:
        if ctx.backend == "ray":
            from .ray_backend import get_pool

            ready = get_pool(ctx).wait_ready(timeout=900.0)  # actors warm up as they start
            log.info("warmup: Ray pool %s after %.1f s", "ready" if ready else "still starting",
                     time.perf_counter() - t0)
            return
        res = warmup(report=lambda line: log.info("warmup: %s", line), threads=ctx.threads,
                     cancel=ctx.shutdown.is_set, if_needed=True)
        if res["skipped"]:
            log.info("warmup: the kernel cache is warm (%.1f s)", time.perf_counter() - t0)
            return
    except Exception as e:  # noqa: BLE001 (the worker must serve jobs anyway)
        log.warning("warmup failed (%s: %s); jobs compile kernels as they need them", type(e).__name__, e)
        return
    log.info("warmup: %d routes rendered, %d kernels compiled (%.1f s), %.1f s in all", res["routes"],
             res["kernels_compiled"], res["compile_seconds"], time.perf_counter() - t0)


def serve_forever(ctx: WorkerContext, poll_interval: float = 0.2, max_jobs: int | None = None) -> int:
    """Claim and run jobs until SIGTERM/SIGINT (or ``max_jobs``). Returns an exit code."""
    ctx.store.register_worker(ctx.worker_id, os.getpid(), ctx.backend)
    if ctx.warmup:
        _warm_up(ctx)  # registered first: the server sees the worker while it warms
    done = 0
    last_beat = 0.0
    try:
        while not ctx.shutdown.is_set():
            _exit_if_orphaned(ctx)
            try:
                job = ctx.store.claim(ctx.worker_id)
            except sqlite3.Error as e:
                log.warning("claim failed: %s", e)
                job = None
            if job is None:
                now = time.monotonic()
                if now - last_beat >= ctx.heartbeat_interval:
                    last_beat = now
                    try:
                        if not ctx.store.worker_heartbeat(ctx.worker_id):
                            ctx.store.register_worker(ctx.worker_id, os.getpid(), ctx.backend)
                    except sqlite3.Error as e:
                        log.warning("heartbeat failed: %s", e)
                ctx.shutdown.wait(poll_interval)
                continue
            outcome = run_job(ctx, job)
            log.info("job %s: %s", job.id, outcome)
            done += 1
            if max_jobs is not None and done >= max_jobs:
                break
    finally:
        try:
            ctx.store.unregister_worker(ctx.worker_id)
        except sqlite3.Error:
            pass
        if ctx.ray_pool is not None:
            ctx.ray_pool.close()
        for key, (desc, scene) in list(ctx.scene_cache.items()):
            scene.close()
        ctx.scene_cache.clear()
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m service.worker", description="illum render worker")
    p.add_argument("--data", required=True, help="the server's data directory (holds jobs.db)")
    p.add_argument("--id", required=True, help="worker id (unique per server)")
    p.add_argument("--heartbeat-interval", type=float, default=0.5)
    p.add_argument("--snapshot-interval", type=float, default=2.0)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--max-time", type=float, default=None)
    p.add_argument("--max-side", type=int, default=8192)
    p.add_argument("--max-pixels", type=int, default=8192 * 8192)
    p.add_argument("--max-memory", type=int, default=None,
                   help="bytes a job may use: its render's memory cap; with the local backend the process's "
                        "address space is also limited to it plus WORKER_BASE_ADDRESS_SPACE (service/config.py)")
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--ray-address", default=None)
    p.add_argument("--ray-actors", type=int, default=None)
    p.add_argument("--ray-drivers", type=int, default=1, help="workers sharing the Ray cluster")
    p.add_argument("--stage-root", default=None,
                   help="the server's stage root: render jobs may read files only below it "
                        "(default: the one the server recorded in jobs.db)")
    p.add_argument("--supervised", action="store_true", help="exit when the spawning process dies")
    p.add_argument("--no-warmup", dest="warmup", action="store_false",
                   help="skip compiling the kernels before the first job (renderer/warmup.py)")
    p.add_argument("--max-jobs", type=int, default=None, help=argparse.SUPPRESS)
    return p


def main(argv: list[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format=f"%(asctime)s {a.id} %(levelname)s %(message)s")
    if a.supervised:
        die_with_parent()
        guard_process_group()
    if a.max_memory and a.backend == "local":
        # A hard ceiling under the estimate (renderer/memory.py): what it misses fails with
        # MemoryError (a permanent failure of the job) rather than waking the OOM killer. Not
        # with Ray: the cluster processes this worker starts would inherit it.
        from .config import WORKER_BASE_ADDRESS_SPACE

        limit_resources(a.max_memory + WORKER_BASE_ADDRESS_SPACE)
    ctx = WorkerContext(store=JobStore(os.path.join(a.data, "jobs.db")), worker_id=a.id, data_dir=a.data,
                        heartbeat_interval=a.heartbeat_interval, snapshot_interval=a.snapshot_interval,
                        threads=a.threads, max_time=a.max_time, max_side=a.max_side, max_pixels=a.max_pixels,
                        max_memory=a.max_memory,
                        backend=a.backend, ray_address=a.ray_address, ray_actors=a.ray_actors,
                        ray_drivers=a.ray_drivers, stage_root=a.stage_root, warmup=a.warmup,
                        parent_pid=os.getppid() if a.supervised else None)
    def on_term(signum, frame):
        # Graceful: stop the render between passes, checkpoint, requeue (see _stopped).
        ctx.shutdown.set()
        stop = ctx.current_stop
        if stop is not None:
            stop.set()

    def on_stuck(message: str) -> None:
        # A load blocked in C++ past its deadline (renderer/deadline.py): fail the job for good
        # (a retry would block the same way), then leave; the supervisor starts a new worker.
        job = ctx.current_job
        if job is not None:
            msg = _clean(message, job)
            try:
                JobLog(os.path.join(ctx.job_dir(job.id), JOB_LOG), ctx.worker_id)(f"error: {msg}")
                ctx.store.finish(job.id, ctx.worker_id, "failed", error=msg)
            except Exception:  # noqa: BLE001 (exit regardless: this thread cannot be freed)
                log.exception("failing job %s after a stuck load failed", job.id)
        log.error("%s: exiting", message)
        os._exit(4)

    from renderer.deadline import set_stuck_handler

    set_stuck_handler(on_stuck)
    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    _exit_if_orphaned(ctx)
    log.info("worker %s started (pid %d, backend %s)", a.id, os.getpid(), a.backend)
    return serve_forever(ctx, max_jobs=a.max_jobs)


if __name__ == "__main__":
    sys.exit(main())
