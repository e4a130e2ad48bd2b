"""Samples per CPU-second of one stage and estimator setting across several checkouts, alternated.

Each run is a fresh child process of *this* file with PYTHONPATH set to one checkout (e.g. ``git
worktree add /tmp/rg-94d3740 94d3740``, numba caches copied with ``cp -a`` to keep them warm), so
every side runs the same probe: one warm-up render (numba caches, the stage and its BVH, kept in a
scene cache), then ``--spp`` passes at ``--res`` and ``--max-depth`` with one thread, timed by
process CPU time (the machine is shared: wall time measures the other jobs too). The sides run
A, B, C, A, B, C, ... ``--repeats`` times, and the table gives each side's median and its median
ratio to the first side over the repeats (each ratio from runs next to each other).

    python bench/bench_ab.py STAGE --side head=. --side base=/tmp/rg-94d3740 [--estimator controlVariate]
        [--light-samples 4] [--cv-alpha one] [--res 128 96] [--spp 8] [--max-depth 4] [--repeats 5]
        [--vertex-kernel]

--vertex-kernel runs FastPath's bounce loop in Python (where a checkout has the compiled loop,
its kernel_reason is patched to refuse it) and also reports the CPU seconds spent inside
_vertex_kernels.vertex_kernel, the compiled per-bounce work alone.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from bench_throughput import run_probe  # bench/ is the script's own directory


def probe(stage, res, spp, max_depth, estimator, light_samples, cv_alpha, vertex_kernel=False) -> dict:
    """Run in the child: a warm-up render, then one render of spp passes timed by CPU."""
    from renderer.render import RenderOptions, render

    spent = [0.0]
    if vertex_kernel:
        from renderer.integrators import _vertex_kernels as vk
        from renderer.integrators import fast_path as fp

        if hasattr(fp.FastPath, "kernel_reason"):
            fp.FastPath.kernel_reason = lambda self: "the Python loop (bench_ab --vertex-kernel)"
        kernel = vk.vertex_kernel

        def timed(*args):
            c = time.process_time()
            kernel(*args)
            spent[0] += time.process_time() - c

        vk.vertex_kernel = timed  # FastPath calls it as vk.vertex_kernel

    over = {}
    if estimator:
        over["estimator"] = {"": estimator}
    if light_samples:
        over["light_samples"] = {"": light_samples}
    if cv_alpha:
        over["cv_alpha"] = {"": cv_alpha}
    opts = dict(resolution=tuple(res), seed=0, threads=1, max_depth=max_depth, **over)
    cache: dict = {}
    render(stage, RenderOptions(spp=1, **opts), scene_cache=cache)
    spent[0] = 0.0
    c0 = time.process_time()
    r = render(stage, RenderOptions(spp=spp, **opts), scene_cache=cache)
    cpu = max(time.process_time() - c0, 1e-9)
    return {"cpu_s": cpu, "samples_per_cpu_s": res[0] * res[1] * spp / cpu, "fast_path": r.stats.get("fast_path"),
            "rays": r.stats.get("rays"), "vertex_kernel_s": spent[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage")
    ap.add_argument("--side", action="append", default=[], metavar="NAME=DIR",
                    help="a checkout to measure (repeatable; the first is the ratios' reference)")
    ap.add_argument("--estimator")
    ap.add_argument("--light-samples", type=int)
    ap.add_argument("--cv-alpha")
    ap.add_argument("--res", nargs=2, type=int, default=(128, 96))
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--max-depth", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--vertex-kernel", action="store_true", help="Python bounce loop; time vertex_kernel too")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(probe(a.stage, a.res, a.spp, a.max_depth, a.estimator, a.light_samples, a.cv_alpha,
                               a.vertex_kernel)))
        return 0
    sides = [s.split("=", 1) for s in a.side]
    stage = os.path.abspath(a.stage)
    runs: dict[str, list[float]] = {name: [] for name, _ in sides}
    kernel_s: dict[str, list[float]] = {name: [] for name, _ in sides}
    for rep in range(a.repeats):
        for name, checkout in sides:
            checkout = os.path.abspath(checkout)
            cmd = [sys.executable, os.path.abspath(__file__), "--child", stage, "--res", *map(str, a.res),
                   "--spp", str(a.spp), "--max-depth", str(a.max_depth)]
            for flag, v in (("--estimator", a.estimator), ("--light-samples", a.light_samples),
                            ("--cv-alpha", a.cv_alpha)):
                if v:
                    cmd += [flag, str(v)]
            if a.vertex_kernel:
                cmd.append("--vertex-kernel")
            r = run_probe(cmd, checkout)
            runs[name].append(r["samples_per_cpu_s"])
            kernel_s[name].append(r["vertex_kernel_s"])
            print(f"#{rep} {name}: {r['samples_per_cpu_s']:.0f} samples/CPU-s ({r['cpu_s']:.2f} s, vertex_kernel "
                  f"{r['vertex_kernel_s']:.2f} s, fast path {r['fast_path']})", file=sys.stderr, flush=True)
    ref = sides[0][0]
    setting = " ".join(f"{k}={v}" for k, v in (("estimator", a.estimator), ("samples", a.light_samples),
                                                 ("alpha", a.cv_alpha)) if v) or "as authored"
    loop = ", Python bounce loop" if a.vertex_kernel else ""
    print(f"{os.path.basename(stage)} ({setting}), {a.res[0]}x{a.res[1]}, {a.spp} spp, max depth {a.max_depth}{loop}, "
          f"{a.repeats} alternated repeats, load {os.getloadavg()[0]:.1f}")
    extra = " vertex_kernel CPU-s (runs) |" if a.vertex_kernel else ""
    print("| side | median samples/CPU-s | runs | median ratio to " + ref + " |" + extra)
    print("|---|---|---|---|" + ("---|" if extra else ""))
    for name, _ in sides:
        ratio = np.median(np.array(runs[name]) / np.array(runs[ref]))
        ks = f" {' '.join(f'{x:.2f}' for x in kernel_s[name])} |" if extra else ""
        print(f"| {name} | {np.median(runs[name]):.0f} | {' '.join(f'{x:.0f}' for x in runs[name])} | {ratio:.2f} |"
              + ks)
    return 0


if __name__ == "__main__":
    sys.exit(main())
