"""What the first-hit passes (renderer/aov.py) cost: samples/s of the beauty alone and with each
pass set, on the same stage, the configurations interleaved so load changes on a shared machine
hit all alike.

    PYTHONPATH=. .venv/bin/python bench/bench_aovs.py [--stage stages/cornell_box.usda] [--res 128] \
        [--spp 16] [--repeats 3] [--out bench/results/aovs]

Reports per set the median of the render phase's samples/s (load, build and write excluded) and
its ratio to the beauty alone.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys

from renderer.render import RenderOptions, render

SETS = {
    "beauty": {},
    "alpha": {"alpha": True},
    "albedo+N": {"aov": ("albedo", "N")},
    "all": {"alpha": True, "aov": ("albedo", "N", "normalCamera", "Z", "P", "primId", "materialId", "sampleCount")},
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stage", default="stages/cornell_box.usda")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="bench/results/aovs")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rates = {k: [] for k in SETS}
    render(a.stage, RenderOptions(spp=1, resolution=(a.res, a.res), **SETS["all"]))  # compile once, untimed
    for _ in range(a.repeats):
        for name, kw in SETS.items():
            r = render(a.stage, RenderOptions(spp=a.spp, resolution=(a.res, a.res), **kw))
            rates[name].append(r.stats["samples_per_second"])
    base = statistics.median(rates["beauty"])
    rows = [{"set": k, "samples_per_second": statistics.median(v), "ratio": statistics.median(v) / base,
             "all": v} for k, v in rates.items()]
    with open(os.path.join(a.out, "aovs.json"), "w") as fh:
        json.dump({"stage": a.stage, "res": a.res, "spp": a.spp, "rows": rows, "command": " ".join(sys.argv),
                   "machine": {"platform": platform.platform(), "cpus": os.cpu_count()}}, fh, indent=2)
    print("| pass set | samples/s (median) | vs beauty alone |")
    print("|---|---|---|")
    for x in rows:
        print(f"| {x['set']} | {x['samples_per_second']:.0f} | {x['ratio']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
