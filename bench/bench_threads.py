"""Thread scaling of a small frame: render time with 1 and 2 threads, alternated.

    .venv/bin/python bench/bench_threads.py [STAGE] [--res 128 128] [--spp 48] [--repeats 7]

Prints the median render seconds (load and build excluded) per thread count and their ratio.
"""
from __future__ import annotations

import argparse
import statistics

from renderer.render import RenderOptions, render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage", nargs="?", default="stages/cornell_box.usda")
    ap.add_argument("--res", type=int, nargs=2, default=(128, 128))
    ap.add_argument("--spp", type=int, default=48)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--threads", default="1,2")
    a = ap.parse_args()
    counts = [int(t) for t in a.threads.split(",")]
    render(a.stage, RenderOptions(spp=2, resolution=tuple(a.res), threads=max(counts)))  # warm
    secs = {t: [] for t in counts}
    for rep in range(a.repeats):
        for t in (counts if rep % 2 == 0 else counts[::-1]):
            r = render(a.stage, RenderOptions(spp=a.spp, resolution=tuple(a.res), threads=t, seed=rep))
            secs[t].append(r.stats["seconds"]["render"])
    base = statistics.median(secs[counts[0]])
    for t in counts:
        m = statistics.median(secs[t])
        print(f"{a.stage} {a.res[0]}x{a.res[1]} {a.spp} spp, {t} thread(s): median {m:.3f} s, "
              f"scaling {base / m:.2f}x  (runs: {', '.join(f'{s:.3f}' for s in secs[t])})")


if __name__ == "__main__":
    main()
