"""Scale-out: one job's sample passes spread over a Ray cluster.

A job of S samples per pixel is cut into *blocks* of B passes. Block b renders the whole image
with ``render(..., stream_seed=block_seed(base_seed, b))``: distinct seeds give independent
random streams, so the blocks' films are independent estimates, and ``Film.merge`` (which sums
sample sums, squares and counts) combines them with the right weights.

* ``PassActor``s (one CPU each, spread over the nodes) keep the loaded stage and its BVH resident
  between blocks and between jobs (``render(..., scene_cache=...)``): a block costs only its passes.
* The driver (a service worker process) hands blocks to idle actors, merges results as they
  arrive (``ray.wait``), and reports progress and snapshots to the same callbacks as a local
  render, so previews and checkpoints work unchanged. The checkpoint records which blocks are
  merged: a requeued job re-runs only the others.
* An actor that dies (node lost, ``ray.kill``, OOM) fails its in-flight block with
  ``RayActorError``: the block goes back to the queue and a new actor replaces the dead one.
* Cancel: the driver stops handing out blocks and tells busy actors to stop between passes
  (the actors are threaded, so ``stop`` runs while ``render_block`` is busy).

The stage path must be readable at the same path on every node (a shared filesystem).
"""

from __future__ import annotations

import collections
import math
import os
import threading
import time
import uuid
from typing import Callable, Optional

__all__ = ["PassActor", "RayPool", "get_pool", "block_seed", "plan_blocks"]


def block_seed(base_seed: int, block: int) -> int:
    """Seed of block ``block``: never equal to ``base_seed`` (a local render's seed, so a job
    resumed from a local checkpoint does not repeat its streams) nor to another block's."""
    return (int(base_seed) << 20) + 1 + int(block)


def plan_blocks(spp: int, actors: int, max_block: int = 16) -> int:
    """Passes per block: about four blocks per actor (load balance, and progressive merges),
    at most ``max_block`` passes so previews and checkpoints stay frequent."""
    return max(1, min(max_block, math.ceil(spp / max(1, 4 * actors))))


class _BlockStopped(Exception):
    """A block whose job was stopped before the block began."""


def _actor_class():
    """Define the actor lazily so importing this module never needs Ray."""
    import ray

    @ray.remote(num_cpus=1, max_concurrency=2)
    class PassActor:
        """Renders blocks of passes; the scene and BVH stay resident between calls."""

        def __init__(self):
            self.cache: dict = {}
            self.stopped: set = set()
            self.lock = threading.Lock()
            # Threaded actor (so ``stop`` runs while a block renders), but one render at a time:
            # a stopped job's last pass finishes before the next job's block starts.
            self.render_lock = threading.Lock()
            try:  # one CPU per actor: numba's parallel kernels too, or actors oversubscribe a node
                import numba

                numba.set_num_threads(1)
            except (ImportError, ValueError):
                pass
            # Compile or load every kernel before the first block (renderer/warmup.py), so no
            # job's time budget pays numba's first-run compile. Never fatal: a block compiles
            # what it needs, outside its budget.
            try:
                from renderer.warmup import warmup

                warmup(threads=1, if_needed=True)
            except Exception as e:  # noqa: BLE001
                import logging

                logging.getLogger("illum.ray").warning("actor warmup failed: %s: %s", type(e).__name__, e)

        def ping(self) -> dict:
            import socket

            return {"pid": os.getpid(), "host": socket.gethostname()}

        def stop(self, token: str) -> None:
            with self.lock:
                self.stopped.add(token)

        def render_block(self, stage: str, options, block: int, spp: int, time_budget: Optional[float],
                         token: str) -> tuple:
            from dataclasses import replace

            from renderer.render import render

            opts = replace(options, spp=int(spp), time_budget=time_budget, threads=1)
            with self.render_lock:
                if token in self.stopped:
                    raise _BlockStopped(block)
                t0 = time.perf_counter()
                result = render(stage, opts, cancel=lambda: token in self.stopped, scene_cache=self.cache,
                                stream_seed=block_seed(options.seed, block))
                info = {"spp": int(result.stats["spp"]), "seconds": dict(result.stats["seconds"]),
                        "rays": dict(result.stats["rays"]), "wall": time.perf_counter() - t0,
                        "pid": os.getpid()}
            return block, result.film, info, result.stats, result.metadata, list(result.warnings)

    return PassActor


_ACTOR = None


def PassActor():  # noqa: N802  (reads as the class it returns)
    """The Ray actor class (created on first use)."""
    global _ACTOR
    if _ACTOR is None:
        _ACTOR = _actor_class()
    return _ACTOR


class RayPool:
    """A driver-side pool of PassActors on one Ray cluster.

    address: a cluster address ('auto', 'ray://host:10001', 'host:6379'); None starts a local
    Ray with ``num_cpus`` CPUs. actors: pool size (default: the cluster's CPUs // drivers).
    """

    def __init__(self, address: str | None = None, actors: int | None = None, num_cpus: int | None = None,
                 drivers: int = 1):
        import ray

        if not ray.is_initialized():
            kw = dict(include_dashboard=False, log_to_driver=False, namespace="illum")
            if address:
                ray.init(address=address, **kw)
            else:
                ray.init(num_cpus=num_cpus, **kw)
        self.ray = ray
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.size = int(actors) if actors else max(1, cpus // max(1, drivers))
        self.actors = [self._new_actor() for _ in range(self.size)]
        self.lost_actors = 0

    def _new_actor(self):
        return PassActor().options(scheduling_strategy="SPREAD").remote()

    def wait_ready(self, timeout: float) -> bool:
        """Wait until every actor has started (and warmed up: PassActor's constructor); False
        if some had not after ``timeout`` seconds (they keep starting; blocks queue behind)."""
        try:
            self.ray.get([a.ping.remote() for a in self.actors], timeout=timeout)
            return True
        except self.ray.exceptions.GetTimeoutError:
            return False

    def close(self) -> None:
        for a in self.actors:
            try:
                self.ray.kill(a)
            except Exception:  # already dead
                pass
        self.actors = []

    # ------------------------------------------------------------------ one job
    def render(self, stage: str, options, *, progress: Callable | None = None, snapshot: Callable | None = None,
               cancel: Callable[[], bool] | None = None, resume=None, resume_state: dict | None = None,
               log: Callable[[str], None] | None = None, block_spp: int | None = None):
        """Render like ``renderer.render.render`` but across the pool. ``snapshot`` is called as
        ``snapshot(film, spp_done, state)`` where state goes into the checkpoint; ``resume`` and
        ``resume_state`` continue from one. Returns a RenderResult (camera None)."""
        from ray.exceptions import RayActorError, RayTaskError

        from renderer.render import DEFAULT_SPP, RenderResult

        ray = self.ray
        log = log or (lambda msg: None)
        state = dict(resume_state or {})
        film = resume
        done_spp = int(film.count.max()) if film is not None and film.count.size else 0
        start_spp = done_spp
        target = options.spp if options.spp is not None else (None if options.time_budget else DEFAULT_SPP)
        budget = options.time_budget

        # ---- the block plan (kept in the checkpoint so a resumed job re-runs only missing blocks)
        if "blocks_done" in state and state.get("plan_target") == target:
            bspp = int(state["block_spp"])
            base = int(state["block_base"])
            plan_spp = state["plan_spp"]
            blocks_done = set(int(b) for b in state["blocks_done"])
        else:
            # Fresh, or resumed from a local-backend checkpoint: plan what is still missing.
            plan_spp = None if target is None else max(target - done_spp, 0)
            bspp = block_spp or plan_blocks(plan_spp if plan_spp is not None else 16 * self.size, self.size)
            base = int(state.get("block_base_next", 0))
            blocks_done = set()
        if plan_spp is not None:
            nblocks = math.ceil(plan_spp / bspp)
            queue = collections.deque(b for b in range(nblocks) if b not in blocks_done)
        else:
            queue = None  # time budget only: blocks keep coming until it runs out
        next_block = (max(blocks_done) + 1) if blocks_done else 0

        def block_size(b: int) -> int:
            return bspp if plan_spp is None else min(bspp, plan_spp - b * bspp)

        token = uuid.uuid4().hex
        in_flight: dict = {}           # ref -> (actor index, block)
        idle = list(range(len(self.actors)))
        t0 = time.monotonic()
        first_stats = first_meta = None
        warnings: list = []
        rays = collections.Counter()
        load_build = {"load": 0.0, "build": 0.0}
        canceled = False
        blocks_run = 0
        lost_here = 0

        def remaining_budget() -> float | None:
            return None if budget is None else budget - (time.monotonic() - t0)

        try:
            while True:
                if cancel is not None and cancel():
                    canceled = True
                    break
                # hand out blocks to idle actors
                while idle:
                    rb = remaining_budget()
                    if rb is not None and rb <= 0:
                        break
                    if queue is not None:
                        if not queue:
                            break
                        b = queue.popleft()
                    else:
                        b = next_block
                        next_block += 1
                    i = idle.pop()
                    ref = self.actors[i].render_block.remote(stage, options, base + b, block_size(b),
                                                             None if rb is None else max(rb, 1e-3), token)
                    in_flight[ref] = (i, b)
                if not in_flight:
                    break
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=0.2)
                for ref in ready:
                    i, b = in_flight.pop(ref)
                    try:
                        _, bfilm, info, stats, meta, warns = ray.get(ref)
                    except RayActorError as e:
                        # The actor is gone: its block was not merged, so run it again elsewhere.
                        self.lost_actors += 1
                        lost_here += 1
                        log(f"ray: actor {i} lost ({type(e).__name__}); re-running block {b}")
                        if lost_here > 3 * len(self.actors):
                            raise RuntimeError(f"Ray actors keep dying ({lost_here} lost in this job); "
                                               f"last: {e}") from None
                        self.actors[i] = self._new_actor()
                        if queue is not None:
                            queue.appendleft(b)
                        idle.append(i)
                        continue
                    except RayTaskError as e:
                        cause = getattr(e, "cause", None)
                        raise (cause if isinstance(cause, BaseException) else e) from None
                    idle.append(i)
                    blocks_run += 1
                    if film is None:
                        # Arrays from the object store are read-only views: own them to accumulate.
                        film = bfilm.copy()
                    else:
                        film.merge(bfilm)
                    blocks_done.add(b)
                    rays.update(info["rays"])
                    for k in load_build:
                        load_build[k] = max(load_build[k], float(info["seconds"].get(k, 0.0)))
                    if first_stats is None:
                        first_stats, first_meta, warnings = stats, meta, warns
                    done_spp = int(film.count.max())
                    frac = []
                    if target:
                        frac.append(done_spp / target)
                    if budget:
                        frac.append((time.monotonic() - t0) / budget)
                    if progress is not None:
                        progress(done_spp, target, min(1.0, max(frac) if frac else 0.0))
                    if snapshot is not None:
                        snapshot(film, done_spp, {"backend": "ray", "blocks_done": sorted(blocks_done),
                                                  "block_spp": bspp, "block_base": base, "plan_spp": plan_spp,
                                                  "plan_target": target,
                                                  "block_base_next": base + (max(blocks_done) + 1)})
        finally:
            if in_flight:
                # Cancel or error: ask busy actors to stop between passes, and drop their blocks.
                for ref, (i, _) in in_flight.items():
                    self.actors[i].stop.remote(token)
                # Do not wait for them: the cancel deadline is short, and each actor finishes at
                # most one pass before it is free again (its render lock orders the next job).
                for ref in in_flight:
                    ray.cancel(ref)
        wall = time.monotonic() - t0
        if film is None:
            if canceled:
                from renderer.film import Film

                film = Film(1, 1)
            else:
                raise RuntimeError("the Ray pool rendered no block")
        h, w = film.shape
        stats = dict(first_stats or {})
        samples = (done_spp - start_spp) * w * h
        stats.update({
            "spp": int(film.count.max()) if film.count.size else 0,
            "seconds": {**load_build, "render": wall},
            "rays": dict(rays),
            "samples_per_second": samples / max(wall, 1e-9),
            "passes_this_run": done_spp - start_spp,
            "nonfinite_dropped": film.nonfinite_dropped,
            "negative_samples": film.negative_samples,
            "ray": {"actors": len(self.actors), "block_spp": bspp, "blocks_run": blocks_run,
                    "lost_actors": self.lost_actors},
        })
        meta = dict(first_meta or {})
        meta.update({"illum:spp": stats["spp"], "illum:renderSeconds": wall,
                     "illum:seed": int(options.seed), "illum:rayActors": len(self.actors)})
        return RenderResult(film=film, stats=stats, metadata=meta, camera=None, warnings=list(warnings))


_POOL: RayPool | None = None


def get_pool(ctx) -> RayPool:
    """The worker process's pool (created on first use: starting Ray takes seconds)."""
    global _POOL
    if _POOL is None:
        _POOL = RayPool(address=ctx.ray_address, actors=ctx.ray_actors, drivers=ctx.ray_drivers)
        ctx.ray_pool = _POOL
    return _POOL
