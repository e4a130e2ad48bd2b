"""Adaptive sampling (renderer/adaptive.py) against uniform sampling at equal cost, on a room lit
by the sky it opens onto: the sky fills part of the frame (easy pixels, zero variance), the room's
far corner under the ceiling sees the sky only through bounces (dark, noisy).

    PYTHONPATH=. .venv/bin/python bench/bench_adaptive.py [--res 64] [--ref-spp 2048] \
        [--uniform-spp 64 256] [--thresholds 0.02 0.05 0.1] [--cap 512] [--min-spp 32] \
        [--out bench/results/adaptive]

The stage is tests/stage_builders.py sky_room_stage at --res. A converged reference (two
independent uniform halves of --ref-spp/2 samples, seeds 1000 and 2000, filter importance
sampling; renderer/bench.split_half_floor measures the relMSE floor it adds), then uniform
renders at --uniform-spp (importance, which adaptive sampling uses, and splat, illum's default)
and one adaptive render per threshold capped at --cap spp, all seed 0. relMSE = mean
(x - ref)^2 / (ref^2 + 0.01) (renderer/bench.relmse) over the frame and over its darkest quarter
(by reference luminance), each less the reference's split-half floor, and the 99th percentile of
the per-pixel relMSE (the worst pixels, which a threshold bounds; the floor kept).

Equal cost: a uniform render's relMSE falls as 1 / cost, so relMSE x cost is its constant, and a
uniform render at an adaptive render's cost would have relMSE = constant / cost. Cost is counted
two ways: rays traced (camera, extension and shadow: deterministic) and render seconds (equal
time, but on a shared machine as noisy as its load). The gain is that predicted uniform relMSE
over the adaptive render's. Results: one JSON and the table printed (copied into
bench/results/adaptive/README.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile

import numpy as np

from renderer.bench import EPS, relmse, split_half_floor
from renderer.color import luminance
from renderer.render import RenderOptions, render


def _run(stage: str, **kw) -> dict:
    r = render(stage, RenderOptions(seed=0, **kw))
    count = r.adaptive.count(r.film) if r.adaptive is not None else r.film.count
    rays = r.stats["rays"]
    return {"img": r.film.mean().astype(np.float64), "render_s": float(r.stats["seconds"]["render"]),
            "mean_spp": float(count.mean()), "mrays": (rays["camera"] + rays["extension"] + rays["shadow"]) / 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--uniform-spp", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0.02, 0.05, 0.1])
    ap.add_argument("--cap", type=int, default=512)
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
    floor_dark = split_half_floor(half_a[dark], half_b[dark], ref[dark])

    # One render first, so that no measured one pays the process's first-call costs.
    render(stage, RenderOptions(spp=4, seed=99, resolution=(16, 16), noise_threshold=0.1, adaptive_min_spp=2))
    rows = []
    runs = [(f"uniform {mode} {n} spp", mode, dict(spp=n, pixel_filter_mode=mode))
            for mode in ("importance", "splat") for n in a.uniform_spp]
    runs += [(f"adaptive T={t:g}", "adaptive", dict(spp=a.cap, noise_threshold=t, adaptive_min_spp=a.min_spp))
             for t in a.thresholds]
    for name, kind, kw in runs:
        r = _run(stage, **kw)
        img = r.pop("img")
        per_pixel = np.mean((img - ref) ** 2 / (ref * ref + EPS), axis=2)
        # The reference's own noise (its split-half floor) taken off, so that uniform's relMSE
        # scales as 1 / cost; the p99 keeps it.
        row = {"method": name, "kind": kind, **r, "relmse": relmse(img, ref) - floor,
               "relmse_dark_quarter": relmse(img[dark], ref[dark]) - floor_dark,
               "relmse_p99": float(np.quantile(per_pixel, 0.99))}
        rows.append(row)
        print(f"{name:28s} render {r['render_s']:6.2f}s  Mrays {r['mrays']:7.2f}  spp {r['mean_spp']:7.1f}  "
              f"relMSE {row['relmse']:.5f}  dark quarter {row['relmse_dark_quarter']:.5f}  "
              f"p99 {row['relmse_p99']:.5f}", flush=True)

    # Uniform importance sampling's constants relMSE x cost (the mean over its spp counts).
    base = [r for r in rows if r["kind"] == "importance"]
    const = {(m, c): float(np.mean([r[m] * r[c] for r in base]))
             for m in ("relmse", "relmse_dark_quarter", "relmse_p99") for c in ("mrays", "render_s")}
    print("\n| method | mean spp | Mrays | render s | relMSE | darkest quarter | pixel p99 "
          "| gain, equal rays: relMSE / dark / p99 | gain, equal time: relMSE |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        gain = {k: const[k] / r[k[1]] / r[k[0]] for k in const}
        r["gain_vs_uniform_importance"] = {f"{m} at equal {c}": v for (m, c), v in gain.items()}
        print(f"| {r['method']} | {r['mean_spp']:.1f} | {r['mrays']:.2f} | {r['render_s']:.2f} | {r['relmse']:.5f} "
              f"| {r['relmse_dark_quarter']:.5f} | {r['relmse_p99']:.4f} "
              f"| {gain[('relmse', 'mrays')]:.2f}x / {gain[('relmse_dark_quarter', 'mrays')]:.2f}x / "
              f"{gain[('relmse_p99', 'mrays')]:.2f}x | {gain[('relmse', 'render_s')]:.2f}x |")
    out = {"res": a.res, "ref_spp": a.ref_spp, "reference_floor": floor, "reference_floor_dark": floor_dark,
           "min_spp": a.min_spp, "cap": a.cap,
           "rows": rows,
           "machine": {"platform": platform.platform(), "cpus": os.cpu_count()}}
    with open(os.path.join(a.out, f"adaptive_{a.res}.json"), "w") as f:
        json.dump(out, f, indent=2)
    print(f"\nreference floor (split halves): {floor:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
