"""Samples per CPU-second of the UsdLux kinds that moved onto the compiled vertex kernel (#23):
CylinderLights and mesh lights, before (the general numpy path, ``fast_path=False``, the route
these stages took until then) and after (the compiled path), in alternated runs on one process
(compile caches warm and the scene loaded: one unmeasured render of each first). CPU seconds
(time.process_time around the render call, 1 thread, the scene cached) rather than wall seconds,
so a shared machine's load moves the numbers less.

Stages: stages/lux_extra/mesh_light_room.usda (a 768-triangle neon ring, a two-sided lampshade,
a ceiling tube) and the cylinder room of tests/integrators/test_fast_path_lux_extra.py (three
rect lights, a tube, a sheared tube and a line light), written to bench/out.

    .venv/bin/python bench/bench_compiled_lux_extra.py --res 160 120 --spp 16 --rounds 3
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
OUT = os.path.join(ROOT, "bench", "out")


def _stages():
    from pathlib import Path

    from tests.integrators.test_fast_path import _room
    from tests.integrators.test_fast_path_lux_extra import _add_cylinders

    os.makedirs(OUT, exist_ok=True)
    cyl = Path(OUT) / "cylinder_room.usda"
    _room(cyl)
    _add_cylinders(cyl)
    return {"mesh_light_room": os.path.join(ROOT, "stages", "lux_extra", "mesh_light_room.usda"),
            "cylinder_room": str(cyl)}


def main() -> None:
    from renderer.render import RenderOptions, render

    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, nargs=2, default=(160, 120))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--depth", type=int, default=5)
    a = ap.parse_args()
    rows = []
    for name, stage in _stages().items():
        rate = {True: [], False: []}
        route = {}
        cache: dict = {}
        for i in range(a.rounds + 1):
            for fast in ((True, False) if i % 2 == 0 else (False, True)):
                t0 = time.process_time()
                r = render(stage, RenderOptions(spp=a.spp, resolution=tuple(a.res), threads=1, max_depth=a.depth,
                                                seed=i, fast_path=fast), scene_cache=cache)
                cpu = time.process_time() - t0
                route[fast] = r.stats["fast_path"]
                if i:  # the first round warms the caches
                    rate[fast].append(a.spp * a.res[0] * a.res[1] / cpu)
        after, before = np.median(rate[True]), np.median(rate[False])
        rows.append((name, before, after, route[True]))
        print(f"{name}: before (general path) {before:,.0f} samples/CPU-s {np.round(rate[False], 0)}, "
              f"after ({route[True]}) {after:,.0f} samples/CPU-s {np.round(rate[True], 0)}: {after / before:.2f}x",
              flush=True)
    print("\n| stage | before (general path) | after | ratio | fast path |\n|---|---|---|---|---|")
    for name, b, f, why in rows:
        print(f"| {name} | {b:,.0f} | {f:,.0f} | {f / b:.2f}x | {why} |")


if __name__ == "__main__":
    main()
