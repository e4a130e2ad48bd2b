"""Thread scaling of a small frame: render time with 1 and 2 threads, alternated.

    .venv/bin/python bench/bench_threads.py [STAGE] [--res 128 128] [--spp 48] [--repeats 7]

Prints the median render seconds (load and build excluded) per thread count and their ratio,
then the share g of a 1-thread render spent outside the compiled calls that release the GIL
(the fast path's trace_kernel and the film's splat kernel, timed around each call). Only that
share serialises threads (one thread's Python runs beside the other's kernels), so two threads
can at most reach min(2, 1 / g). On a machine shared with other sessions, Linux's autogroup
scheduler gives a session one share of the CPU however many threads it runs, so the wall-clock
ratio says nothing there; g does not depend on the load.
"""
from __future__ import annotations

import argparse
import statistics
import time

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
    if gil_share(a.stage, a.res, 2) is None:
        return
    shares = sorted(gil_share(a.stage, a.res, a.spp) for _ in range(3))
    g = shares[1]
    print(f"1 thread: {g:.1%} of the render outside GIL-free compiled calls (runs: "
          f"{', '.join(f'{x:.1%}' for x in shares)}): 2 threads at most {min(2.0, 1.0 / g):.2f}x")


def gil_share(stage, res, spp) -> float:
    """The share of a 1-thread render's time spent outside trace_kernel and the splat kernel
    (None before the compiled bounce loop existed)."""
    from renderer import film
    from renderer.integrators import fast_path

    if not hasattr(fast_path, "tk"):
        return None

    inside = [0.0]

    def timed(fn):
        def call(*a):
            t0 = time.perf_counter()
            try:
                return fn(*a)
            finally:
                inside[0] += time.perf_counter() - t0
        return call

    orig_trace, orig_splat = fast_path.tk.trace_kernel, film._splat_kernel
    fast_path.tk.trace_kernel, film._splat_kernel = timed(orig_trace), timed(orig_splat)
    try:
        r = render(stage, RenderOptions(spp=spp, resolution=tuple(res), threads=1))
    finally:
        fast_path.tk.trace_kernel, film._splat_kernel = orig_trace, orig_splat
    return 1.0 - inside[0] / r.stats["seconds"]["render"]


if __name__ == "__main__":
    main()
