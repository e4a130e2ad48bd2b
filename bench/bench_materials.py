#!/usr/bin/env python
"""Samples per second on a textured asset with normal maps and cut-outs (stages/plant): the
general integrator (--no-fast-path) against the compiled fast path, optionally against the
general path of another checkout (--base DIR, e.g. a tree of the commit before the fast path
served these materials), in alternated runs of ``illum render``.

Usage (from the repository root)::

    .venv/bin/python bench/bench_materials.py [--res 128] [--spp 16] [--repeats 3] [--base DIR]
                                              [--out bench/results/materials/compiled.md]

Each run is a fresh process rendering the stage with one thread (``-j 1``) after a warm-up run
per configuration (numba caches), and is timed by the CPU time of the child process (resource
RUSAGE_CHILDREN; load, build and render, the whole command) as well as by the render's own
wall-clock samples/s (stats ``samples_per_second``). On a shared machine CPU time is the steadier
number; the table gives the median of the repeats.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STAGE = "stages/plant/plant.usda"


def run(tree: str, res: int, spp: int, fast: bool, tmp: str) -> dict:
    stats = os.path.join(tmp, "stats.json")
    cmd = [sys.executable, "-m", "renderer.cli", "render", os.path.join(ROOT, STAGE), "--res", str(res), str(res),
           "--spp", str(spp), "-j", "1", "--seed", "1", "-o", os.path.join(tmp, "out.exr"), "--stats", stats,
           "--quiet", "--fast-path" if fast else "--no-fast-path"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, check=True, cwd=tree, env={**os.environ, "PYTHONPATH": tree})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    with open(stats) as fh:
        s = json.load(fh)
    return {"cpu": cpu, "wall_sps": s["samples_per_second"], "cpu_sps": res * res * spp / cpu,
            "fast_path": s["fast_path"], "render_s": s["seconds"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--base", default=None, help="another checkout whose general path to time too")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench/results/materials/compiled.md"))
    a = ap.parse_args(argv)
    configs = [("general (--no-fast-path)", ROOT, False), ("fast path", ROOT, True)]
    if a.base:
        configs.insert(0, (f"base general ({os.path.basename(os.path.abspath(a.base))})", a.base, False))
    results = {name: [] for name, _, _ in configs}
    with tempfile.TemporaryDirectory() as tmp:
        for _, tree, fast in configs:  # warm-up: numba caches
            run(tree, 16, 1, fast, tmp)
        for _ in range(a.repeats):
            for name, tree, fast in configs:
                r = run(tree, a.res, a.spp, fast, tmp)
                results[name].append(r)
                print(f"{name}: {r['cpu_sps']:.0f} samples/CPU-s, {r['wall_sps']:.0f} samples/s wall "
                      f"(fast_path: {r['fast_path']})", flush=True)
    rows = []
    ref = statistics.median(r["cpu_sps"] for r in results[configs[-2][0]])
    for name, _, _ in configs:
        cpu = statistics.median(r["cpu_sps"] for r in results[name])
        wall = statistics.median(r["wall_sps"] for r in results[name])
        rows.append(f"| {name} | {results[name][0]['fast_path']} | {cpu:,.0f} | {wall:,.0f} | {cpu / ref:.2f} |")
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    cmd = f"bench/bench_materials.py --res {a.res} --spp {a.spp} --repeats {a.repeats}" + (
        f" --base {a.base}" if a.base else "")
    with open(a.out, "w") as fh:
        fh.write("\n".join([
            "# Materials in the compiled integrator: normal maps and cut-outs (#23)", "",
            f"`{STAGE}` (300 cut-out leaf cards, normal-mapped trunk and ground, ~900 triangles; a dome and a sun) "
            f"at {a.res}x{a.res}, {a.spp} spp, max depth 7 (default), one thread, median of {a.repeats} alternated "
            "runs. samples/CPU-s: pixels x spp over the CPU time of the whole `illum render` process (load, "
            "build, render); wall: the render's own `samples_per_second` stat.", "",
            f"    .venv/bin/python {cmd}", "",
            "| integrator | stats fast_path | samples / CPU-s | samples / s (wall) | vs general |",
            "|---|---|---|---|---|", *rows, ""]))
    print("wrote", os.path.relpath(a.out, ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
