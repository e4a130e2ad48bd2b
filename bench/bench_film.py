"""Splatting film against filter importance sampling at equal time (renderer/pixel_filter.py).

    PYTHONPATH=. .venv/bin/python bench/bench_film.py [--res 128] [--ref-spp 512] [--budget 1.5] \
        [--seeds 3] [--filter gaussian] [--width W] [--out bench/results/film]

For each stage and each mode, a converged reference at --ref-spp (same filter, same mode: each
mode is compared with its own limit), then --seeds renders of --budget seconds each, the modes
interleaved so load changes on a shared machine hit both alike. Reports per mode the passes
reached, the relMSE mean((x - ref)^2 / (ref^2 + 0.01)) against its own reference, and the
relMSE at equal passes (relMSE * spp / the other's spp is not used: both are measured).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

from renderer.render import RenderOptions, render

STAGES = ("stages/cornell_box.usda", "stages/talk/dome.usda")
MODES = ("splat", "importance")


def rel_mse(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.mean((x - ref) ** 2 / (ref * ref + 0.01)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("stages", nargs="*", default=list(STAGES))
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--budget", type=float, default=1.5)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--filter", default="gaussian")
    ap.add_argument("--width", type=float, default=None)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default="bench/results/film")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    for stage in a.stages:
        cache: dict = {}
        base = dict(resolution=(a.res, a.res), pixel_filter=a.filter, pixel_filter_width=a.width, threads=a.threads)
        refs = {}
        for mode in MODES:
            render(stage, RenderOptions(spp=1, pixel_filter_mode=mode, **base), scene_cache=cache)  # compile, load
            t0 = time.perf_counter()
            r = render(stage, RenderOptions(spp=a.ref_spp, seed=1000, pixel_filter_mode=mode, **base),
                       scene_cache=cache)
            refs[mode] = r.film.mean().astype(np.float64)
            print(f"{stage} {mode}: reference {a.ref_spp} spp in {time.perf_counter() - t0:.1f} s "
                  f"({r.stats['samples_per_second'] / 1e3:.0f} ksamples/s)", file=sys.stderr)
        for seed in range(1, a.seeds + 1):
            for mode in MODES:
                r = render(stage, RenderOptions(time_budget=a.budget, seed=seed, pixel_filter_mode=mode, **base),
                           scene_cache=cache)
                row = {"stage": stage, "mode": mode, "seed": seed, "spp": r.stats["spp"],
                       "seconds": r.stats["seconds"]["render"],
                       "samples_per_second": r.stats["samples_per_second"],
                       "rel_mse": rel_mse(r.film.mean().astype(np.float64), refs[mode])}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr)
    summary = []
    for stage in a.stages:
        per = {}
        for mode in MODES:
            rs = [r for r in rows if r["stage"] == stage and r["mode"] == mode]
            per[mode] = {"spp": float(np.mean([r["spp"] for r in rs])),
                         "ksps": float(np.mean([r["samples_per_second"] for r in rs])) / 1e3,
                         "rel_mse": float(np.mean([r["rel_mse"] for r in rs])),
                         # relMSE x seconds per pass: the equal-time figure with the pass-count
                         # granularity of a short budget taken out (lower is better).
                         "mse_time": float(np.mean([r["rel_mse"] * r["seconds"] / r["spp"] for r in rs]))}
        summary.append((stage, per))
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_film.py " + " ".join(argv if argv is not None else sys.argv[1:])
    md = [f"# Splatting vs filter importance sampling at equal time ({a.filter} filter"
          f"{'' if a.width is None else f', radius {a.width:g} px'})", "",
          f"`{cmd}`", "",
          f"{a.res}x{a.res}, {a.budget:g} s budget per render, {a.seeds} seeds, each mode against its own "
          f"{a.ref_spp}-spp reference. relMSE = mean((x - ref)^2 / (ref^2 + 0.01)); relMSE x s/pass is "
          "the equal-time figure per pass (lower is better). Machine: "
          f"{platform.platform()}, {os.cpu_count()} CPUs, shared with other jobs while measured.", "",
          "| stage | mode | passes in budget | ksamples/s | relMSE | relMSE x s/pass | importance / splat |",
          "|---|---|---|---|---|---|---|"]
    for stage, per in summary:
        ratio = per["importance"]["mse_time"] / per["splat"]["mse_time"]
        for mode in MODES:
            p = per[mode]
            md.append(f"| {stage} | {mode} | {p['spp']:.1f} | {p['ksps']:.0f} | {p['rel_mse']:.3e} | "
                      f"{p['mse_time']:.3e} | {ratio:.2f} |" if mode == "splat" else
                      f"| {stage} | {mode} | {p['spp']:.1f} | {p['ksps']:.0f} | {p['rel_mse']:.3e} | "
                      f"{p['mse_time']:.3e} | |")
    tag = a.filter + ("" if a.width is None else f"_{a.width:g}")
    with open(os.path.join(a.out, f"results_{tag}.md"), "w") as fh:
        fh.write("\n".join(md) + "\n")
    with open(os.path.join(a.out, f"results_{tag}.json"), "w") as fh:
        json.dump(rows, fh, indent=1)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
