"""Render throughput against raw embree, and before/after comparisons of two checkouts (#3, #8).

For each stage, one *probe* (a fresh child process, so numba caches and BVHs are warm in the
same way for every side) loads the stage, renders one warm-up pass, then renders ``--spp``
passes at ``--res`` and ``--max-depth`` with one thread, and reports:

* samples/s and Mrays/s of render() by **process CPU time** (the machine is shared, so wall
  time measures the other jobs too; with one render thread CPU time is the work done);
* raw embree Mrays/s by CPU time on the stage's camera rays and one diffuse bounce (the same
  float32 batches, no Python around them: ``renderer.bench.raw_throughput`` batches), and the
  ratio render / raw, the issue's "shading may cost at most as much time as tracing" (0.5);
* the rays traced by kind, so a change in work is visible next to a change in speed.

``--compare-to DIR`` runs the same probe from another checkout (e.g. ``git worktree add
/tmp/before <commit>``), alternating A, B, A, B, ... ``--repeats`` times, and reports the
median ratio, so that both sides see the same machine load.

    .venv/bin/python bench/bench_throughput.py [STAGES...] [--res 256 256] [--spp 16] [--max-depth 8]
        [--repeats 3] [--compare-to /tmp/before] [--out bench/results/throughput]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_STAGES = [os.path.join(ROOT, "stages", "cornell_box.usda"),
                  os.path.join(ROOT, "stages", "fireflies", "fireflies.usda")]


def probe(stage: str, res: tuple[int, int], spp: int, max_depth: int, raw: bool) -> dict:
    """Run in the child: one render of spp passes with one thread, timed by CPU."""
    from renderer.render import RenderOptions, render

    opts = dict(resolution=res, seed=0, threads=1, max_depth=max_depth)
    # Warm-up (numba caches, imports, lazy tables) that also loads the stage and builds the BVH
    # once: the timed render reuses them, so its CPU time is rendering alone. (Subtracting the
    # load/build *wall* seconds from CPU time instead went to <= 0 on a loaded machine.)
    cache: dict = {}
    render(stage, RenderOptions(spp=1, **opts), scene_cache=cache)
    c0, w0 = time.process_time(), time.perf_counter()
    r = render(stage, RenderOptions(spp=spp, **opts), scene_cache=cache)
    c1, w1 = time.process_time(), time.perf_counter()
    st = r.stats
    pre = 0.0
    cpu = max(c1 - c0, 1e-9)
    rays = st["rays"]
    traced = sum(v for k, v in rays.items() if k != "light_probe")
    out = {"stage": os.path.relpath(stage, ROOT), "res": list(res), "spp": spp, "max_depth": max_depth,
           "cpu_s": cpu, "wall_s": w1 - w0 - pre, "samples_per_cpu_s": res[0] * res[1] * spp / cpu,
           "mrays_per_cpu_s": traced / cpu / 1e6, "rays": rays}
    if raw:
        out["raw_mrays_per_cpu_s"] = _raw(stage, res)
        out["ratio_render_over_raw"] = out["mrays_per_cpu_s"] / out["raw_mrays_per_cpu_s"]
    return out


def _raw(stage: str, res: tuple[int, int]) -> float:
    """Embree alone (one thread, CPU time) on the stage's camera rays and one cosine bounce."""
    from renderer.accel import raw_throughput_probe
    from renderer.bench import raw_ray_batches
    from renderer.camera import Camera
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    desc = load_stage(stage)
    scene = build_scene(desc, threads=1)
    try:
        w, h = res
        cam = Camera(scene.desc.camera, w, h, desc.settings.pixel_aspect_ratio, desc.settings.aspect_ratio_conform_policy)
        batches = raw_ray_batches(scene, cam, w, h, seed=0, min_rays=131072)
        n = 0
        cpu = 0.0
        for oo, dd in batches.values():
            raw_throughput_probe(scene.accel, oo, dd)  # warm
            c0 = time.process_time()
            for _ in range(3):
                raw_throughput_probe(scene.accel, oo, dd)
            cpu += time.process_time() - c0
            n += 3 * oo.shape[0]
        return n / cpu / 1e6
    finally:
        scene.close()


def _run_child(checkout: str, stage: str, a) -> dict:
    cmd = [sys.executable, os.path.join(checkout, "bench", "bench_throughput.py"), "--child", stage,
           "--res", str(a.res[0]), str(a.res[1]), "--spp", str(a.spp), "--max-depth", str(a.max_depth)]
    if a.raw:
        cmd.append("--raw")
    return run_probe(cmd, checkout)


def run_probe(cmd: list, checkout: str) -> dict:
    """Run a probe command in ``checkout`` (its own code on PYTHONPATH, one thread) and return the
    JSON object its last output line holds; a failed probe ends the bench with its stderr."""
    env = dict(os.environ, PYTHONPATH=checkout, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    out = subprocess.run(cmd, env=env, cwd=checkout, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"probe failed in {checkout}:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stages", nargs="*", default=DEFAULT_STAGES)
    ap.add_argument("--res", nargs=2, type=int, default=(256, 256))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--compare-to", metavar="DIR", help="another checkout to measure alternately")
    ap.add_argument("--out", default=None, help="write results.json and results.md here")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--raw", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        sys.path.insert(0, os.getcwd())
        print(json.dumps(probe(a.stages[0], tuple(a.res), a.spp, a.max_depth, a.raw)))
        return 0
    rows = []
    for stage in a.stages:
        stage = os.path.abspath(stage)
        a.raw = True
        sides = {"this": ROOT}
        if a.compare_to:
            sides["other"] = os.path.abspath(a.compare_to)
        runs: dict[str, list[dict]] = {k: [] for k in sides}
        for rep in range(a.repeats):
            for name, checkout in sides.items():
                runs[name].append(_run_child(checkout, stage, a))
                a.raw = False  # embree alone is the same on both sides: measure it once per stage
                print(f"{os.path.basename(stage)} {name} #{rep}: "
                      f"{runs[name][-1]['samples_per_cpu_s']:.0f} samples/CPU-s", file=sys.stderr, flush=True)
        row = {"stage": os.path.relpath(stage, ROOT), "load_avg": os.getloadavg()}
        for name, rs in runs.items():
            row[name] = {"samples_per_cpu_s": float(np.median([r["samples_per_cpu_s"] for r in rs])),
                         "mrays_per_cpu_s": float(np.median([r["mrays_per_cpu_s"] for r in rs])),
                         "rays": rs[0]["rays"], "all": [r["samples_per_cpu_s"] for r in rs]}
        first = runs["this"][0]
        row["raw_mrays_per_cpu_s"] = first["raw_mrays_per_cpu_s"]
        row["ratio_render_over_raw"] = row["this"]["mrays_per_cpu_s"] / first["raw_mrays_per_cpu_s"]
        if "other" in runs:
            row["speedup_this_over_other"] = float(np.median(
                [x["samples_per_cpu_s"] / y["samples_per_cpu_s"] for x, y in zip(runs["this"], runs["other"])]))
        rows.append(row)
    text = _markdown(rows, a)
    print(text)
    if a.out:
        os.makedirs(a.out, exist_ok=True)
        with open(os.path.join(a.out, "results.json"), "w") as f:
            json.dump(rows, f, indent=1)
        with open(os.path.join(a.out, "results.md"), "w") as f:
            f.write(text)
    return 0


def _markdown(rows, a) -> str:
    cmd = "python bench/bench_throughput.py " + " ".join(sys.argv[1:])
    lines = [f"# Render throughput (one thread, process CPU time)\n", f"`{cmd}`\n",
             f"{a.res[0]}x{a.res[1]}, {a.spp} spp, max depth {a.max_depth}; medians of {a.repeats} alternated runs.\n",
             "| stage | side | samples/CPU-s | Mrays/CPU-s | raw embree Mrays/CPU-s | ours/raw | speed-up |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        for side in ("this", "other"):
            if side not in r:
                continue
            s = r[side]
            ratio = s["mrays_per_cpu_s"] / r["raw_mrays_per_cpu_s"]
            up = f"{r['speedup_this_over_other']:.2f}x" if side == "this" and "speedup_this_over_other" in r else ""
            lines.append(f"| {r['stage']} | {side} | {s['samples_per_cpu_s']:.0f} | {s['mrays_per_cpu_s']:.3f} | "
                         f"{r['raw_mrays_per_cpu_s']:.2f} | {ratio:.3f} | {up} |")
    lines.append("\nLoad average during the run: " + ", ".join(f"{r['stage']}: {r['load_avg'][0]:.1f}" for r in rows))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
