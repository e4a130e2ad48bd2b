#!/usr/bin/env python
"""Samples per second on a textured asset with normal maps and cut-outs (stages/plant): the
general integrator (--no-fast-path) against the compiled fast path, optionally against the
general path of another checkout (--base DIR, e.g. a tree of the commit before the fast path
served these materials), in alternated runs of ``illum render``.

Usage (from the repository root)::

    .venv/bin/python bench/bench_materials.py [--res 128] [--spp 16] [--repeats 3] [--base DIR]
                                              [--out bench/results/materials/compiled.md]

Each run is a fresh process that renders the stage once at 16x16 (numba caches, imports), then
times ``render()`` (load, build, render; one thread, the same options as ``illum render -j 1
[--no-fast-path]``) by its CPU time (time.process_time) and by the render's own wall-clock
samples/s (stats ``samples_per_second``). On a shared machine CPU time is the steadier number;
the table gives the median of the repeats.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STAGE = "stages/plant/plant.usda"


# The child: one warm-up render (numba caches, imports), then the timed render, one thread.
_CHILD = """
import json, sys, time
from renderer.render import RenderOptions, render
stage, res, spp, fast = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
render(stage, RenderOptions(spp=1, resolution=(16, 16), threads=1, fast_path=fast))
c, w = time.process_time(), time.perf_counter()
r = render(stage, RenderOptions(spp=spp, resolution=(res, res), threads=1, seed=1, fast_path=fast))
print(json.dumps({"cpu": time.process_time() - c, "wall": time.perf_counter() - w, "fast_path": r.stats["fast_path"],
                  "wall_sps": r.stats["samples_per_second"]}))
"""


def run(tree: str, res: int, spp: int, fast: bool) -> dict:
    """One child process in checkout ``tree``: CPU and wall time of render() (load, build,
    render) after a warm-up render."""
    out = subprocess.run([sys.executable, "-c", _CHILD, os.path.join(ROOT, STAGE), str(res), str(spp),
                          "1" if fast else "0"], check=True, cwd=tree, env={**os.environ, "PYTHONPATH": tree},
                         capture_output=True, text=True).stdout
    r = json.loads(out.strip().splitlines()[-1])
    r["cpu_sps"] = res * res * spp / r["cpu"]
    return r


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
    for _ in range(a.repeats):
        for name, tree, fast in configs:
            r = run(tree, a.res, a.spp, fast)
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
            "runs, each in a fresh process after a warm-up render. samples/CPU-s: pixels x spp over the CPU "
            "time of `render()` (load, build, render); wall: the render's own `samples_per_second` stat, "
            "on a machine shared with other jobs (2 cores, load ~8), so wall numbers are several times low.", "",
            f"    .venv/bin/python {cmd}", "",
            "| integrator | stats fast_path | samples / CPU-s | samples / s (wall) | vs general |",
            "|---|---|---|---|---|", *rows, ""]))
    print("wrote", os.path.relpath(a.out, ROOT))
    return 0


if __name__ == "__main__":
    sys.exit(main())
