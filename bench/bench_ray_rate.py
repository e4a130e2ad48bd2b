"""The renderer's ray rate against native Embree's single-ray rate, stage by stage.

    .venv/bin/python bench/bench_ray_rate.py [STAGES ...] [--res 256 256] [--seconds 4] [--threads 2]

For each stage (default: every .usda under stages/, the many-light ones included): render() for
``--seconds`` at ``--res`` and max depth 7, and take its total ray rate (camera + extension +
shadow rays per second of render, from its stats); then time native Embree alone, one ray per
``rtcIntersect1`` call from a nogil kernel on the Accel's threads, on the stage's camera rays and
one cosine bounce from their hits (renderer.bench.raw_ray_batches), best of three. The ratio is
the share of Embree's own single-ray speed the whole renderer keeps (the one-integrator issue's
target: at least 0.8). Prints a markdown table.

--cpu: both rates per CPU second of this process instead of per wall second, one thread each
(the render's CPU time from its start to its end, load and build included). On a machine shared
with other sessions the wall-clock rates swing with the load (Linux's autogroup scheduler gives a
session one share of the CPU whatever it runs), the CPU-time ones much less.
"""
from __future__ import annotations

import argparse
import glob
import os
import time

import numpy as np

from renderer.bench import raw_ray_batches
from renderer.camera import Camera
from renderer.render import RenderOptions, render
from renderer.scene import build_scene
from renderer.usd import load_stage

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def single_ray_rate(stage: str, res, threads: int, seed: int = 0, clock=time.perf_counter) -> float:
    """Mrays/s of native Embree, one ray per call, on the stage's camera and bounce rays (per
    second of ``clock``)."""
    desc = load_stage(stage)
    scene = build_scene(desc, threads=threads)
    try:
        accel = scene.accel
        cam = Camera(scene.desc.camera, res[0], res[1], desc.settings.pixel_aspect_ratio,
                     desc.settings.aspect_ratio_conform_policy)
        rays = secs = 0.0
        for o, d in raw_ray_batches(scene, cam, res[0], res[1], seed).values():
            o32 = np.ascontiguousarray(o, dtype=np.float32)
            d32 = np.ascontiguousarray(d, dtype=np.float32)
            best = np.inf
            for _ in range(3):
                t32 = np.full(o32.shape[0], 3.0e37, dtype=np.float32)
                t0 = clock()
                accel.intersect_prepared(o32, d32, t32, width=1)
                best = min(best, clock() - t0)
            rays += o32.shape[0]
            secs += best
        return rays / secs / 1e6
    finally:
        scene.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stages", nargs="*")
    ap.add_argument("--res", type=int, nargs=2, default=(256, 256))
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--cpu", action="store_true", help="rays per CPU second, one thread")
    a = ap.parse_args()
    if a.cpu:
        a.threads = 1
    clock = time.process_time if a.cpu else time.perf_counter
    stages = a.stages or sorted(p for p in glob.glob(os.path.join(ROOT, "stages", "**", "*.usda"), recursive=True)
                                if "/textures/" not in p)
    print("| stage | route | samples/s | renderer Mrays/s | Embree single-ray Mrays/s | ratio |\n|---|---|---|---|---|---|")
    for st in stages:
        name = os.path.relpath(st, os.path.join(ROOT, "stages"))
        try:
            c0 = clock()
            r = render(st, RenderOptions(time_budget=a.seconds, resolution=tuple(a.res), threads=a.threads,
                                         max_depth=7))
            ours = r.stats["mrays_per_second"]
            if a.cpu:
                ours = sum(r.stats["rays"][k] for k in ("camera", "extension", "shadow")) / (clock() - c0) / 1e6
            raw = single_ray_rate(st, tuple(a.res), a.threads, clock=clock)
        except Exception as e:  # noqa: BLE001 (a stage without geometry, say: report and go on)
            print(f"| {name} | - | - | - | - | {type(e).__name__}: {e} |", flush=True)
            continue
        route = "fast" if r.stats["fast_path"] == "on" else "general"
        print(f"| {name} | {route} | {r.stats['samples_per_second'] / 1e3:.0f} k | {ours:.2f} | {raw:.2f} | "
              f"{ours / raw:.2f} |", flush=True)


if __name__ == "__main__":
    main()
