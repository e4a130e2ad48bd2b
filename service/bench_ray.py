"""Measure the Ray backend's scaling: the same job on 1 actor, then on N actors.

    .venv/bin/python -m service.bench_ray [--stage stages/cornell_box.usda] [--res 96 96]
                                          [--spp 24] [--actors 2] [--repeats 2] [--json OUT.json]

Starts a local Ray, warms every actor up (the stage is loaded and its BVH built once per actor
and then stays resident, as in the service), then times whole jobs on a 1-actor pool and an
N-actor pool, alternating: wall time from the first block handed out to the last one merged.
Each actor renders with one thread. For reference it also times a local single-process render
with 1 and N threads. Prints the speedup of N actors over 1 (best of ``--repeats`` each).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def _time_job(pool, stage: str, opts) -> float:
    t0 = time.perf_counter()
    r = pool.render(stage, opts)
    assert r.stats["spp"] == opts.spp
    return time.perf_counter() - t0


def _time_local(stage: str, opts, threads: int, repeats: int) -> float:
    from dataclasses import replace

    from renderer.render import render

    try:  # the same CPU budget for numba's parallel kernels as for the embree threads
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except ImportError:
        pass
    cache: dict = {}
    render(stage, replace(opts, spp=1, threads=threads), scene_cache=cache)
    best = float("inf")
    try:
        for _ in range(repeats):
            r = render(stage, replace(opts, threads=threads), scene_cache=cache)
            best = min(best, r.stats["seconds"]["render"])
    finally:
        for _, (_, scene) in cache.items():
            scene.close()
    return best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m service.bench_ray", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stage", default=os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                                   "stages", "cornell_box.usda"))
    p.add_argument("--res", nargs=2, type=int, default=(96, 96), metavar=("W", "H"))
    p.add_argument("--spp", type=int, default=24)
    p.add_argument("--actors", type=int, default=2)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--json", default=None, help="also write the numbers here")
    a = p.parse_args(argv)

    import ray

    from renderer.render import RenderOptions

    from .ray_backend import RayPool

    opts = RenderOptions(spp=a.spp, resolution=tuple(a.res))
    # Both pools live side by side and their runs alternate, so a change in machine load hits
    # both alike. Ray counts CPUs logically: one extra lets the idle pool's actor stay resident.
    ray.init(num_cpus=a.actors + 1, include_dashboard=False, log_to_driver=False, namespace="illum-bench")
    try:
        one, many = RayPool(actors=1), RayPool(actors=a.actors)
        for pool in (one, many):  # warm-up: every actor loads the stage and builds its BVH
            pool.render(a.stage, RenderOptions(spp=len(pool.actors), resolution=tuple(a.res)), block_spp=1)
        t1 = tn = float("inf")
        for _ in range(a.repeats):
            t1 = min(t1, _time_job(one, a.stage, opts))
            tn = min(tn, _time_job(many, a.stage, opts))
        one.close()
        many.close()
    finally:
        ray.shutdown()
    local1 = _time_local(a.stage, opts, 1, a.repeats)
    localn = _time_local(a.stage, opts, a.actors, a.repeats)
    samples = a.spp * a.res[0] * a.res[1]
    out = {
        "stage": os.path.basename(a.stage), "resolution": list(a.res), "spp": a.spp, "cpus": os.cpu_count(),
        "load_average": os.getloadavg()[0],
        "ray_1_actor_s": t1, f"ray_{a.actors}_actors_s": tn, "ray_speedup": t1 / tn,
        "local_1_thread_s": local1, f"local_{a.actors}_threads_s": localn, "local_thread_speedup": local1 / localn,
        "ray_samples_per_s": {"1": samples / t1, str(a.actors): samples / tn},
    }
    print(f"{out['stage']} {a.res[0]}x{a.res[1]} {a.spp} spp on {out['cpus']} CPUs "
          f"(load average {out['load_average']:.1f})")
    print(f"  ray, 1 actor:        {t1:7.2f} s  ({samples / t1 / 1e3:6.1f} ksamples/s)")
    print(f"  ray, {a.actors} actors:       {tn:7.2f} s  ({samples / tn / 1e3:6.1f} ksamples/s)  "
          f"speedup {t1 / tn:.2f}x")
    print(f"  local, 1 thread:     {local1:7.2f} s")
    print(f"  local, {a.actors} threads:    {localn:7.2f} s  speedup {local1 / localn:.2f}x")
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
