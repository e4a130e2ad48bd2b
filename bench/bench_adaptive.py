"""Adaptive sampling (renderer/adaptive.py) against uniform sampling at equal time, on a room lit
by the sky it opens onto: the sky fills part of the frame (easy pixels, zero variance), the room's
far corner under the ceiling sees the sky only through bounces (dark, noisy).

    PYTHONPATH=. .venv/bin/python bench/bench_adaptive.py [--res 64] [--ref-spp 2048] \
        [--budgets 4 8 16] [--thresholds 0.02 0.05 0.1] [--min-spp 32] [--out bench/results/adaptive]

The stage is tests/stage_builders.py sky_room_stage at --res. A converged reference (two
independent uniform halves of --ref-spp/2 samples, seeds 1000 and 2000, filter importance
sampling; renderer/bench.split_half_floor measures the relMSE floor it adds), then for each time
budget (rendering seconds, load and build excluded) one uniform render per film mode (importance,
which adaptive sampling uses, and splat, illum's default) and one adaptive render per threshold,
all seed 0 and capped by the budget alone. relMSE = mean (x - ref)^2 / (ref^2 + 0.01)
(renderer/bench.relmse) over the frame and over its darkest quarter (by reference luminance).
Results: one JSON and the table printed (copied into bench/results/adaptive/README.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile

import numpy as np

from renderer.bench import relmse, split_half_floor
from renderer.color import luminance
from renderer.render import RenderOptions, render


def _run(stage: str, **kw):
    r = render(stage, RenderOptions(seed=0, **kw))
    count = r.adaptive.count(r.film) if r.adaptive is not None else r.film.count
    return r.film.mean().astype(np.float64), float(r.stats["seconds"]["render"]), float(count.mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--budgets", type=float, nargs="+", default=[4.0, 8.0, 16.0])
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0.02, 0.05, 0.1])
    ap.add_argument("--min-spp", type=int, default=32)
    ap.add_argument("--out", default="bench/results/adaptive")
    a = ap.parse_args(argv)
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from tests.stage_builders import sky_room_stage

    os.makedirs(a.out, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix="illum_adaptive_")
    stage = os.path.join(tmp, "sky_room.usda")
    sky_room_stage(stage, res=(a.res, a.res))
    cache = os.path.join(tempfile.gettempdir(), f"illum_adaptive_ref_{a.res}_{a.ref_spp}.npz")
    if os.path.exists(cache):
        z = np.load(cache)
        half_a, half_b = z["a"], z["b"]
    else:
        half_a, half_b = (render(stage, RenderOptions(spp=a.ref_spp // 2, seed=s, pixel_filter_mode="importance"))
                          .film.mean().astype(np.float64) for s in (1000, 2000))
        np.savez(cache, a=half_a, b=half_b)
    ref = (half_a + half_b) / 2.0
    floor = split_half_floor(half_a, half_b, ref)
    dark = luminance(ref) <= np.quantile(luminance(ref), 0.25)

    rows = []
    for budget in a.budgets:
        runs = [("uniform importance", dict(pixel_filter_mode="importance")),
                ("uniform splat (default)", dict(pixel_filter_mode="splat"))]
        runs += [(f"adaptive T={t:g}", dict(noise_threshold=t, adaptive_min_spp=a.min_spp)) for t in a.thresholds]
        for name, kw in runs:
            img, seconds, spp = _run(stage, time_budget=budget, **kw)
            row = {"budget_s": budget, "method": name, "render_s": seconds, "mean_spp": spp,
                   "relmse": relmse(img, ref), "relmse_dark_quarter": relmse(img[dark], ref[dark])}
            rows.append(row)
            print(f"{budget:5.1f}s  {name:24s} render {seconds:6.2f}s  spp {spp:7.1f}  relMSE {row['relmse']:.5f}"
                  f"  dark quarter {row['relmse_dark_quarter']:.5f}", flush=True)

    print("\n| budget s | method | render s | mean spp | relMSE | relMSE darkest quarter | vs uniform importance |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        base = next(b for b in rows if b["budget_s"] == r["budget_s"] and b["method"] == "uniform importance")
        print(f"| {r['budget_s']:g} | {r['method']} | {r['render_s']:.2f} | {r['mean_spp']:.1f} | {r['relmse']:.5f} "
              f"| {r['relmse_dark_quarter']:.5f} | {base['relmse'] / r['relmse']:.2f}x |")
    out = {"res": a.res, "ref_spp": a.ref_spp, "reference_floor": floor, "min_spp": a.min_spp, "rows": rows,
           "machine": {"platform": platform.platform(), "cpus": os.cpu_count()}}
    with open(os.path.join(a.out, f"adaptive_{a.res}.json"), "w") as f:
        json.dump(out, f, indent=2)
    print(f"\nreference floor (split halves): {floor:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
