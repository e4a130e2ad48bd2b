"""The white furnace under each direct-lighting estimator: how fast the sphere converges.

    .venv/bin/python bench/bench_furnace.py [--spp 1,4,16] [--res 128 96]

Renders stages/talk/furnace.usda (a white sphere in a constant dome) with `mis` and the control
variate's three alphas, 4 light samples per light, and prints the mean and standard deviation of
the pixels at the sphere's centre. The sphere converges to 1 (up to the Schlick grazing term of
UsdPreviewSurface); with alpha = v_bar the control variate returns the exact F at every fully lit
point, so only the specular residual's MIS noise is left.
"""
from __future__ import annotations

import argparse
import time

from renderer.render import RenderOptions, render

STAGE = "stages/talk/furnace.usda"
CONFIGS = (("mis", "one"), ("controlVariate", "one"), ("controlVariate", "averageVisibility"),
           ("controlVariate", "averageVisibilityUnbiased"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", default="1,4,16")
    ap.add_argument("--res", type=int, nargs=2, default=(128, 96))
    ap.add_argument("--max-depth", type=int, default=8)
    a = ap.parse_args()
    w, h = a.res
    print("| estimator | alpha | spp | centre mean | centre std | seconds |\n|---|---|---|---|---|---|")
    for spp in (int(s) for s in a.spp.split(",")):
        for est, alpha in CONFIGS:
            t0 = time.perf_counter()
            r = render(STAGE, RenderOptions(spp=spp, resolution=(w, h), max_depth=a.max_depth, seed=1,
                                            estimator={"": est}, cv_alpha={"": alpha}, light_samples={"": 4}))
            img = r.film.mean()[..., 1]
            c = img[h * 2 // 5:h * 3 // 5, w * 2 // 5:w * 3 // 5]  # well inside the sphere's silhouette
            print(f"| {est} | {alpha} | {spp} | {c.mean():.4f} | {c.std():.4f} | {time.perf_counter() - t0:.1f} |",
                  flush=True)


if __name__ == "__main__":
    main()
