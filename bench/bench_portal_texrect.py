"""Dome portals and textured RectLights on the compiled path (#23): samples per CPU-second on the
general path (``fast_path=False``, the route these scenes took before) against the compiled one.

Stages: stages/lux_extra/window_portal.usda (a textured sky through one portal) and a textured
RectLight stage written next to the results: stages/cornell_box.usda with a colour-ramp EXR on
its ceiling light (``inputs:texture:file``), so its light samples pick texels and the rays that
reach the light see their colour.

Each route renders once to warm up (numba caches, the scene built once into ``scene_cache``),
then ``--spp`` passes at ``--res`` with one thread, timed by process CPU time (the machine is
shared: wall time would measure the other jobs too). Routes alternate ``--repeats`` times; the
median is reported, with the ratio compiled / general.

    .venv/bin/python bench/bench_portal_texrect.py --res 96 72 --spp 8 --max-depth 4 --repeats 3 \\
        --out bench/results/lux_extra/portal.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
WINDOW = os.path.join(ROOT, "stages", "lux_extra", "window_portal.usda")
CORNELL = os.path.join(ROOT, "stages", "cornell_box.usda")


def textured_rect_stage(out_dir: str) -> str:
    """The Cornell box with a colour ramp (and one bright texel) on its RectLight; its path."""
    import OpenImageIO as oiio
    from pxr import Sdf, Usd, UsdLux

    os.makedirs(out_dir, exist_ok=True)
    h, w = 16, 16
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([0.3 + x / w, 0.4 + y / h, 1.3 - x / w], axis=-1).astype(np.float32)
    img[3, 11] = (8.0, 6.0, 2.0)
    tex = os.path.join(out_dir, "ramp.exr")
    assert oiio.ImageBuf(np.ascontiguousarray(img)).write(tex, oiio.FLOAT), oiio.geterror()
    stage = Usd.Stage.Open(CORNELL)
    rects = [p for p in stage.Traverse() if p.IsA(UsdLux.RectLight)]
    assert rects, "no RectLight in the Cornell box"
    for p in rects:
        UsdLux.RectLight(p).CreateTextureFileAttr(Sdf.AssetPath(tex))
    path = os.path.join(out_dir, "cornell_textured_rect.usda")
    stage.Export(path)
    return path


def measure(stage: str, fast: bool, res, spp: int, max_depth: int, cache: dict) -> dict:
    """One timed render (after the caller's warm-up) on one route: samples per CPU-second."""
    from renderer.render import RenderOptions, render

    opts = RenderOptions(resolution=tuple(res), seed=0, threads=1, max_depth=max_depth, spp=spp, fast_path=fast)
    c0 = time.process_time()
    r = render(stage, opts, scene_cache=cache)
    cpu = max(time.process_time() - c0, 1e-9)
    return {"route": r.stats["fast_path"], "cpu_s": cpu, "samples_per_cpu_s": res[0] * res[1] * spp / cpu}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", nargs=2, type=int, default=(96, 72))
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--max-depth", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    a = ap.parse_args(argv)
    from renderer.render import RenderOptions, render

    out_dir = os.path.join(ROOT, "bench", "out", "portal_texrect")
    stages = {"window_portal.usda": WINDOW, "cornell_box + textured RectLight": textured_rect_stage(out_dir)}
    rows = []
    for name, stage in stages.items():
        caches = {True: {}, False: {}}
        for fast in (True, False):
            render(stage, RenderOptions(resolution=tuple(a.res), seed=0, threads=1, max_depth=a.max_depth, spp=1,
                                        fast_path=fast), scene_cache=caches[fast])
        runs = {True: [], False: []}
        for rep in range(a.repeats):
            for fast in (False, True):
                runs[fast].append(measure(stage, fast, a.res, a.spp, a.max_depth, caches[fast]))
                print(f"{name} {'compiled' if fast else 'general'} #{rep}: "
                      f"{runs[fast][-1]['samples_per_cpu_s']:.0f} samples/CPU-s ({runs[fast][-1]['route']})",
                      file=sys.stderr, flush=True)
        med = {k: float(np.median([r["samples_per_cpu_s"] for r in v])) for k, v in runs.items()}
        rows.append({"stage": name, "general": med[False], "compiled": med[True], "ratio": med[True] / med[False],
                     "routes": [runs[False][0]["route"], runs[True][0]["route"]],
                     "all": {"general": [r["samples_per_cpu_s"] for r in runs[False]],
                             "compiled": [r["samples_per_cpu_s"] for r in runs[True]]},
                     "load_avg": os.getloadavg()})
    print("| stage | general path samples/CPU-s | compiled samples/CPU-s | compiled / general |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['stage']} | {r['general']:.0f} | {r['compiled']:.0f} | {r['ratio']:.2f}x |")
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"res": a.res, "spp": a.spp, "max_depth": a.max_depth, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
