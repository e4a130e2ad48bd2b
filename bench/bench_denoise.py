"""OIDN denoising (renderer/denoise.py) on the Cornell box: relMSE before and after, and its time.

    PYTHONPATH=. .venv/bin/python bench/bench_denoise.py [--stage stages/cornell_box.usda] [--res 128] \
        [--ref-spp 2048] [--spp 4 16 64] [--out bench/results/denoise]

A converged reference per pixel filter mode (two independent halves of --ref-spp/2 samples each,
seeds 1000 and 2000; their difference gives the relMSE floor the reference itself adds:
renderer/bench.split_half_floor), then for each mode (splat, importance) and each spp one render
(seed 0) with --denoise, whose raw and denoised beauty are compared with that mode's reference
(relMSE = mean (x - ref)^2 / (ref^2 + 0.01), renderer/bench.relmse). The same raw beauty is also
denoised with clean auxiliaries (OIDN cleanAux) and without any, to justify the default
(renderer/denoise.py CLEAN_AUX). The denoise time is OIDN's call alone (the first call of the
process, which loads the network, is reported separately). Results: one JSON per run and the
table printed (copied into bench/results/denoise/README.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

import numpy as np

from renderer.bench import relmse, split_half_floor
from renderer.denoise import denoise
from renderer.render import RenderOptions, render

MODES = ("splat", "importance")


def _beauty(stage: str, res: int, spp: int, seed: int, mode: str, **kw):
    r = render(stage, RenderOptions(spp=spp, seed=seed, resolution=(res, res), pixel_filter_mode=mode, **kw))
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stage", default="stages/cornell_box.usda")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--spp", type=int, nargs="+", default=[4, 16, 64])
    ap.add_argument("--modes", nargs="+", default=list(MODES))
    ap.add_argument("--out", default="bench/results/denoise")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rows = []
    # First OIDN call of the process: device creation and network load, reported on its own.
    t0 = time.perf_counter()
    denoise(np.ones((a.res, a.res, 3), np.float32))
    first_call = time.perf_counter() - t0
    for mode in a.modes:
        cache = os.path.join(tempfile.gettempdir(), f"illum_denoise_ref_{os.path.basename(a.stage)}_{a.res}_{a.ref_spp}_{mode}.npz")
        if os.path.exists(cache):
            z = np.load(cache)
            half_a, half_b = z["a"], z["b"]
        else:
            half_a = _beauty(a.stage, a.res, a.ref_spp // 2, 1000, mode).film.mean()
            half_b = _beauty(a.stage, a.res, a.ref_spp // 2, 2000, mode).film.mean()
            np.savez(cache, a=half_a, b=half_b)
        ref = 0.5 * (half_a.astype(np.float64) + half_b)
        floor = split_half_floor(half_a, half_b, ref)
        for spp in a.spp:
            r = _beauty(a.stage, a.res, spp, 0, mode, denoise=True)  # the mode given: splat stays splat
            raw = r.aovs.beauty(r.film)
            fh = r.aovs.passes
            albedo, normal = fh.image("albedo", r.film.count), fh.image("normal", r.film.count)
            clean, _ = denoise(raw, albedo, normal, clean_aux=True)
            plain, _ = denoise(raw)
            row = {"mode": mode, "spp": spp, "relmse_raw": relmse(raw, ref), "relmse_denoised": relmse(r.aovs.denoised, ref),
                   "relmse_denoised_clean_aux": relmse(clean, ref), "relmse_denoised_no_aux": relmse(plain, ref),
                   "reference_floor": floor, "denoise_seconds": r.aovs.denoise_seconds,
                   "render_seconds": r.stats["seconds"]["render"]}
            rows.append(row)
            print(json.dumps(row), flush=True)
    result = {"stage": a.stage, "res": a.res, "ref_spp": a.ref_spp, "first_oidn_call_seconds": first_call,
              "rows": rows, "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                        "python": platform.python_version()},
              "command": " ".join(sys.argv)}
    with open(os.path.join(a.out, f"denoise_{a.res}.json"), "w") as fh:
        json.dump(result, fh, indent=2)
    print("| mode | spp | relMSE raw | denoised (noisy aux, default) | clean aux | no aux | denoise s |")
    print("|---|---|---|---|---|---|---|")
    for x in rows:
        print(f"| {x['mode']} | {x['spp']} | {x['relmse_raw']:.5f} | {x['relmse_denoised']:.5f} | "
              f"{x['relmse_denoised_clean_aux']:.5f} | {x['relmse_denoised_no_aux']:.5f} | {x['denoise_seconds']:.3f} |")
    print(f"reference floor (split halves): {floor:.2e}; first OIDN call {first_call:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
