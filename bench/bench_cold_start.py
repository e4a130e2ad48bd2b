"""Cold start (issue 22, part 5): wall time of whole processes, from process start to exit.

In a fresh NUMBA_CACHE_DIR (and ILLUM_CACHE_DIR), per repetition:
  1. cold render: `illum render stages/cornell_box.usda --res 64 64 --spp 1` (compiles what it needs)
  2. `illum warmup` on the cache that render left (compiles the rest)
  3. warm render: the same render again (compiles nothing)
plus `illum warmup` from an empty cache, `illum warmup` on a warm cache, and the import time
of `renderer.render` (`python -c 'import renderer.render'`).

    PYTHONPATH=$PWD .venv/bin/python bench/bench_cold_start.py [--repeat 2]

The machine's load average is printed with each line: compile and load times scale with it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CORNELL = os.path.join(ROOT, "stages", "cornell_box.usda")


def run(args: list[str], env: dict) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{r.stderr}")
    return wall, r


def render(env: dict, d: str) -> str:
    stats = os.path.join(d, "s.json")
    wall, r = run(["-m", "renderer.cli", "render", CORNELL, "--res", "64", "64", "--spp", "1",
                   "-o", os.path.join(d, "o.exr"), "--stats", stats, "--quiet"], env)
    s = json.load(open(stats))
    return (f"{wall:6.1f} s  ({s['kernels_compiled']} kernels compiled in {s['seconds']['compile']:.1f} s; "
            f"load {s['seconds']['load']:.2f} s, build {s['seconds']['build']:.2f} s, render {s['seconds']['render']:.2f} s)")


def warmup(env: dict) -> str:
    wall, r = run(["-m", "renderer.cli", "warmup", "--quiet"], env)
    return f"{wall:6.1f} s  ({r.stderr.strip().splitlines()[-1]})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    load = lambda: "load avg %.1f" % os.getloadavg()[0]  # noqa: E731
    for i in range(a.repeat):
        with tempfile.TemporaryDirectory(prefix="illum-coldstart-") as d:
            env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(d, "numba"), ILLUM_CACHE_DIR=os.path.join(d, "irr"))
            print(f"[{i}] cold render   {render(env, d)}  [{load()}]", flush=True)
            print(f"[{i}] warmup rest   {warmup(env)}  [{load()}]", flush=True)
            print(f"[{i}] warm render   {render(env, d)}  [{load()}]", flush=True)
            print(f"[{i}] warm render   {render(env, d)}  [{load()}]", flush=True)
            print(f"[{i}] warmup warm   {warmup(env)}  [{load()}]", flush=True)
        with tempfile.TemporaryDirectory(prefix="illum-coldstart-") as d:
            env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(d, "numba"), ILLUM_CACHE_DIR=os.path.join(d, "irr"))
            print(f"[{i}] warmup cold   {warmup(env)}  [{load()}]", flush=True)
        wall, _ = run(["-c", "import renderer.render"], dict(os.environ))
        print(f"[{i}] import        {wall:6.1f} s  (python -c 'import renderer.render')  [{load()}]", flush=True)


if __name__ == "__main__":
    main()
