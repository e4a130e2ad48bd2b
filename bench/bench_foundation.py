"""Foundation measurements (issue: a new user renders a stage end to end).

1. Load-and-build time and peak memory for a ~1M-triangle stage generated on the fly
   (bench/make_big_stage.py; nothing large is committed). Each phase runs in a fresh process
   so the peak RSS belongs to that phase alone.
2. Camera-ray throughput: our path (Camera.generate + Accel.intersect, float64 in and out)
   against raw embree (Accel's own route, native or embreex) on the very same float32 rays,
   as a ratio measured in one run.

    .venv/bin/python bench/bench_foundation.py [--triangles 1000000] [--res 1024 1024] [--threads 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def _load_build(stage: str) -> dict:
    """Run in a child process: load + build, report seconds and peak RSS (MiB)."""
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    t0 = time.perf_counter()
    desc = load_stage(stage)
    t1 = time.perf_counter()
    scene = build_scene(desc, threads=2)
    t2 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    out = {"triangles": int(scene.geometry.count), "load_s": t1 - t0, "build_s": t2 - t1,
           "peak_rss_mib": peak}
    scene.close()
    return out


def camera_throughput(stage: str, res: tuple[int, int], threads: int, repeats: int = 3) -> dict:
    from renderer.accel import Accel, raw_throughput_probe
    from renderer.camera import Camera
    from renderer.scene import build_geometry
    from renderer.usd import load_stage

    desc = load_stage(stage)
    geo = build_geometry(desc)
    accel = Accel(geo.vertices, threads=threads)
    cam = Camera(scene.desc.camera, res[0], res[1])
    ys, xs = np.mgrid[0:res[1], 0:res[0]]
    px, py = xs.ravel(), ys.ravel()
    n = px.size
    rng = np.random.default_rng(0)
    u_f, u_l = rng.random((n, 2)), rng.random((n, 2))
    best_ours = best_raw = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        rays = cam.generate(px, py, u_f, u_l)
        hits = accel.intersect(rays.o, rays.d, rays.tmax)
        best_ours = min(best_ours, time.perf_counter() - t0)
        best_raw = min(best_raw, raw_throughput_probe(accel, rays.o, rays.d))
    accel.close()
    return {"rays": n, "threads": threads, "hit_fraction": float(hits.hit.mean()),
            "ours_mrays_s": n / best_ours / 1e6, "raw_mrays_s": n / best_raw / 1e6,
            "ratio_ours_over_raw": best_raw / best_ours}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--res", type=int, nargs=2, default=(1024, 1024))
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(_load_build(a.child)))
        return
    stage = f"/tmp/illum_bench_{a.triangles}.usda"
    if not os.path.exists(stage):
        subprocess.run([sys.executable, os.path.join(ROOT, "bench", "make_big_stage.py"), stage,
                        "--triangles", str(a.triangles)], check=True, stdout=subprocess.DEVNULL)
    r = subprocess.run([sys.executable, __file__, "--child", stage], capture_output=True, text=True, check=True)
    lb = json.loads(r.stdout.strip().splitlines()[-1])
    print(f"load+build of {lb['triangles']:,} triangles: load {lb['load_s']:.2f} s, build {lb['build_s']:.2f} s, "
          f"peak RSS {lb['peak_rss_mib']:.0f} MiB")
    for th in a.threads:
        c = camera_throughput(stage, tuple(a.res), th)
        print(f"camera rays {a.res[0]}x{a.res[1]} ({c['hit_fraction']:.0%} hit), {th} thread(s): "
              f"ours {c['ours_mrays_s']:.2f} Mrays/s, raw embree {c['raw_mrays_s']:.2f} Mrays/s, "
              f"ratio {c['ratio_ours_over_raw']:.2f}")


if __name__ == "__main__":
    main()
