"""What a sample costs under each estimator: samples per CPU second and shadow rays per sample of
one stage with every light forced to each (estimator, N), on the compiled route.

    PYTHONPATH=. .venv/bin/python bench/bench_estimator_cost.py stages/talk/disks.usda --out bench/results/estimators

Each configuration renders once to warm up (kernels, stage), then ``--repeats`` times, the
configurations rotated from one repeat to the next; the table gives the median samples per CPU
second (this process's CPU time: all render threads) and the shadow rays per camera sample.
Writes ``--out``/cost_<stage>.md.
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

from bench_mitsuba import _cpu, git_state  # noqa: E402

from renderer.render import RenderOptions, render  # noqa: E402

CONFIGS = (("mis", 1), ("controlVariate", 1), ("lightSampling", 4), ("mis", 4), ("ratio", 4),
           ("controlVariate", 4))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stage")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--max-depth", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="bench/results/estimators")
    a = ap.parse_args(argv)
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_estimator_cost.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    base = dict(resolution=(a.res, a.res), max_depth=a.max_depth, threads=a.threads, spp=a.spp)
    samples = a.res * a.res * a.spp
    cache: dict = {}

    def run(est, N, seed):
        kw = dict(estimator={"": est}, light_samples={"": N})
        c0 = time.process_time()
        r = render(a.stage, RenderOptions(seed=seed, **base, **kw), scene_cache=cache)
        return samples / (time.process_time() - c0), r.stats["rays"]["shadow"] / samples

    for est, N in CONFIGS:
        run(est, N, 99)
    rates = {c: [] for c in CONFIGS}
    shadow = {}
    for rep in range(a.repeats):
        k = rep % len(CONFIGS)
        for est, N in CONFIGS[k:] + CONFIGS[:k]:
            rate, sh = run(est, N, rep)
            rates[(est, N)].append(rate)
            shadow[(est, N)] = sh
    first = float(np.median(rates[CONFIGS[0]]))
    md = [f"# Cost of a sample by estimator: {a.stage}", "", "    " + cmd, "",
          f"Date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; illum {git_state()}; {_cpu()}; load "
          f"averages at the end {', '.join(f'{x:.1f}' for x in os.getloadavg())}. {a.res}x{a.res}, {a.spp} spp, max "
          f"depth {a.max_depth}, {a.threads} thread(s), every light forced to the estimator; median of "
          f"{a.repeats} rotated runs.", "",
          "| estimator | N | ksamples/CPU-s | shadow rays/sample | cost vs mis N=1 |", "|---|---|---|---|---|"]
    for c in CONFIGS:
        m = float(np.median(rates[c]))
        md.append(f"| {c[0]} | {c[1]} | {m / 1e3:.0f} | {shadow[c]:.2f} | {first / m:.2f}x |")
    text = "\n".join(md) + "\n"
    os.makedirs(a.out, exist_ok=True)
    name = os.path.splitext(os.path.basename(a.stage))[0]
    with open(os.path.join(a.out, f"cost_{name}.md"), "w") as fh:
        fh.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
