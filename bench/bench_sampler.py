"""The bounces' numbers: --sampler sobol (the default: each pixel's scrambled low-discrepancy
sequence, renderer/kernels/sobol.py) against --sampler independent, at equal samples and per CPU
second.

    PYTHONPATH=. .venv/bin/python bench/bench_sampler.py --out bench/results/sampler

Per stage (``STAGES``; 128 x 128, max depth 7, Russian roulette from 3, 1 thread): a reference
with independent numbers (``--ref-spp``; its noise floor, film.variance_of_mean(), is valid for
independent passes only), then for each spp count and seed one render per sampler, the order
alternating from seed to seed. Error: relMSE = mean((x - ref)^2 / (ref^2 + 0.01)) minus the
reference's floor, the measure of bench_mitsuba_table.py. Reported: each sampler's mean relMSE,
their ratio (independent / sobol: > 1 means sobol is better at equal samples), the samples per
CPU second of each, and the efficiency ratio (relMSE x CPU seconds, independent / sobol).
Writes ``--out``/sampler.md and sampler.json.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_film_mitsuba import floor, write_results  # noqa: E402
from bench_mitsuba import _cpu, git_state, relmse  # noqa: E402

from renderer.render import RenderOptions, render  # noqa: E402

STAGES = (
    ("Cornell box", "stages/cornell_box.usda"),
    ("sphere light + occluder", "stages/talk/sphere_occluder.usda"),
    ("three disk lights (controlVariate x4)", "stages/talk/disks.usda"),
    ("penumbra (controlVariate x4)", "stages/talk/penumbra.usda"),
    ("textured lat-long dome (controlVariate x4)", "stages/talk/dome.usda"),
    ("500 sphere lights (bvh)", "stages/many_lights/many_lights.usda"),
    ("plant (textures, normal maps, cut-outs)", "stages/plant/plant.usda"),
)
SAMPLERS = ("sobol", "independent")


def run_stage(a, label: str, stage: str) -> dict:
    base = dict(resolution=(a.res, a.res), max_depth=a.max_depth, rr_depth=a.rr_depth, threads=a.threads)
    cache: dict = {}
    render(stage, RenderOptions(spp=1, seed=99, **base), scene_cache=cache)  # load, kernels
    r = render(stage, RenderOptions(spp=a.ref_spp, seed=1000, sampler="independent", **base), scene_cache=cache)
    ref = r.film.mean().astype(np.float64)
    ref_floor = floor(ref, r.film.variance_of_mean())
    runs = []
    for spp in a.spp:
        for seed in range(a.seeds):
            order = SAMPLERS if seed % 2 == 0 else SAMPLERS[::-1]
            for sampler in order:
                c0, t0 = time.process_time(), time.perf_counter()
                r = render(stage, RenderOptions(spp=spp, seed=seed, sampler=sampler, **base), scene_cache=cache)
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                e = relmse(r.film.mean().astype(np.float64), ref) - ref_floor
                runs.append({"spp": spp, "seed": seed, "sampler": sampler, "relmse": e, "cpu_s": cpu,
                             "wall_s": wall, "render_s": r.stats["seconds"]["render"],
                             "samples_per_cpu_s": a.res * a.res * spp / max(cpu, 1e-9)})
    rows = []
    for spp in a.spp:
        m = {s: [x for x in runs if x["spp"] == spp and x["sampler"] == s] for s in SAMPLERS}
        e = {s: float(np.mean([x["relmse"] for x in m[s]])) for s in SAMPLERS}
        c = {s: float(np.mean([x["cpu_s"] for x in m[s]])) for s in SAMPLERS}
        rows.append({"spp": spp, "relmse": e, "cpu_s": c,
                     "samples_per_cpu_s": {s: a.res * a.res * spp / c[s] for s in SAMPLERS},
                     "error_ratio": e["independent"] / e["sobol"],
                     "efficiency_ratio": (e["independent"] * c["independent"]) / (e["sobol"] * c["sobol"])})
    print(f"{label}: " + ", ".join(f"{r['spp']} spp {r['error_ratio']:.2f}x" for r in rows), flush=True)
    return {"label": label, "stage": stage, "ref_spp": a.ref_spp, "ref_floor": ref_floor, "rows": rows, "runs": runs}


def table(a, results, cmd: str) -> str:
    md = ["# The default sampler (sobol) against independent numbers", "",
          "    " + cmd, "",
          f"Date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; illum {git_state()}; {_cpu()}, "
          f"{os.cpu_count()} CPUs; load averages at the end {', '.join(f'{x:.1f}' for x in os.getloadavg())}.", "",
          f"Setup: {a.res}x{a.res}, max depth {a.max_depth}, roulette from {a.rr_depth}, {a.threads} thread(s), "
          f"{a.seeds} seeds per spp, the samplers alternated; each stage's own estimators; reference "
          f"{a.ref_spp} spp with independent numbers, its floor subtracted. Error ratio = relMSE independent / "
          "relMSE sobol at equal samples (> 1: sobol better); efficiency ratio = relMSE x CPU s, independent / "
          "sobol.", "",
          "| scene | spp | relMSE sobol | relMSE independent | error ratio | Msamples/CPU-s sobol | "
          "Msamples/CPU-s independent | efficiency ratio |",
          "|---|---|---|---|---|---|---|---|"]
    for res in results:
        for r in res["rows"]:
            md.append(f"| {res['label']} | {r['spp']} | {r['relmse']['sobol']:.3e} | {r['relmse']['independent']:.3e} | "
                      f"{r['error_ratio']:.2f} | {r['samples_per_cpu_s']['sobol'] / 1e6:.3f} | "
                      f"{r['samples_per_cpu_s']['independent'] / 1e6:.3f} | {r['efficiency_ratio']:.2f} |")
    return "\n".join(md) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stages", nargs="*", help="stage paths (default: STAGES)")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--max-depth", type=int, default=7)
    ap.add_argument("--rr-depth", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--spp", default="16,64")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--out", default="bench/results/sampler")
    a = ap.parse_args(argv)
    a.spp = [int(x) for x in a.spp.split(",")]
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_sampler.py " + " ".join(argv if argv is not None else sys.argv[1:])
    stages = [(s, s) for s in a.stages] if a.stages else list(STAGES)
    results = [run_stage(a, label, stage) for label, stage in stages]
    md = table(a, results, cmd)
    write_results(a.out, "sampler.json", "sampler.md", cmd, results, md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
