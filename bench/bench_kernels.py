"""Per-point throughput of the light and BSDF hot paths, single-threaded and on two threads.

    .venv/bin/python bench/bench_kernels.py                       # this tree
    .venv/bin/python bench/bench_kernels.py --baseline /path/old  # also an older tree, side by side
    .venv/bin/python bench/bench_kernels.py --baseline /path/old --rounds 3   # on a busy machine

``--baseline`` points at the root of another copy of the repository (the directory holding its
``renderer`` package); the same measurements run there in a subprocess and the table shows
both. Operations the old tree lacks are emulated the way its callers did them (``f_parts`` as
``f_pdf`` + ``f_diffuse``).

For each operation and batch size n: the best of ``--repeat`` timings of back-to-back calls on
n points (1 thread), and of the same number of calls on n/2 points in each of two threads of a
ThreadPoolExecutor (2 threads); each timing lasts ~20 ms or one call. The machine may be
shared, so the minimum time is kept (the least disturbed run);
``--rounds`` repeats the whole measurement, alternating with the baseline, and keeps the best
round of each entry. Throughput is in
millions of points per second; "x2" is the 2-thread throughput over the 1-thread one, which
shows whether the work releases the GIL (numba ``nogil`` kernels) or serialises on it (numpy's
many small operations).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

SIZES = (16384, 262144)


# --------------------------------------------------------------------------------------
# Workloads: each returns (call(lo, hi), warm-up) over prebuilt inputs for n points
# --------------------------------------------------------------------------------------
def _ctx(p):
    from renderer.lights.base import ShadingContext

    z = np.zeros_like(p)
    return ShadingContext(p, z, z.copy())


def _split(arrays, lo, hi):
    return [a[lo:hi] for a in arrays]


def rect_scene(n, rng):
    """A 0.5 x 0.5 ceiling light facing down over a 2 x 2 x 2 box of shading points (Cornell-like:
    spherical-rectangle sampling for most points, area sampling near the ceiling's plane)."""
    from renderer.description import LightDesc
    from renderer.lights.rect import RectLight

    m = np.diag([1.0, 1.0, 1.0, 1.0])
    m[:3, 3] = (0.0, 0.0, 1.99)
    # local -Z emits; the light faces down (-Z world) with the identity rotation.
    light = RectLight.build([LightDesc("/Rect", "rect", m, width=0.5, height=0.5)])
    p = rng.uniform(-1.0, 1.0, (n, 3))
    p[:, 2] = rng.uniform(0.0, 1.98, n)
    return light, p


def sphere_scene(n, rng):
    from renderer.description import LightDesc
    from renderer.lights.sphere import SphereLight

    m = np.eye(4)
    m[:3, 3] = (0.0, 0.0, 1.5)
    light = SphereLight.build([LightDesc("/Sphere", "sphere", m, radius=0.3)])
    p = rng.uniform(-1.0, 1.0, (n, 3))
    return light, p


def light_ops(kind):
    def build(n, rng):
        light, p = (rect_scene if kind == "rect" else sphere_scene)(n, rng)
        idx = np.zeros(n, dtype=np.int64)
        u = rng.random((n, 2))
        wi = light.sample_li(idx, _ctx(p), u).wi
        return {
            f"{kind} sample_li": lambda lo, hi: light.sample_li(idx[lo:hi], _ctx(p[lo:hi]), u[lo:hi]),
            f"{kind} pdf_li": lambda lo, hi: light.pdf_li(idx[lo:hi], _ctx(p[lo:hi]), wi[lo:hi]),
            f"{kind} intersect": lambda lo, hi: light.intersect(idx[lo:hi], p[lo:hi], wi[lo:hi]),
        }

    return build


def bsdf_ops(n, rng):
    from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF

    def make():
        r = np.random.default_rng(5)
        return PreviewSurfaceBSDF.from_inputs(
            r.random((n, 3)), r.random((n, 3)), r.random(n) < 0.3, r.random(n) * (r.random(n) < 0.3),
            r.random(n), 1.0 + r.random(n),
        )

    bsdf = make()
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:, 2] = np.abs(wo[:, 2])
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    u_lobe = rng.random(n)
    u = rng.random((n, 2))
    # Per-thread halves are separate BSDF objects (take), as the integrator's chunks are.
    halves = {}

    def sub(lo, hi, bound=False):
        key = (lo, hi, bound)
        if key not in halves:
            b = bsdf.take(np.arange(lo, hi)) if (lo, hi) != (0, n) else bsdf
            if bound:
                b = make().take(np.arange(lo, hi)).bind_wo(wo[lo:hi])
            halves[key] = b
        return halves[key]

    def f_parts(b, wo_, wi_):
        if hasattr(b, "f_parts"):
            return b.f_parts(wo_, wi_)
        f, pdf = b.f_pdf(wo_, wi_)  # what split_integrand did before f_parts
        return f, b.f_diffuse(wo_, wi_), pdf

    ops = {
        "bsdf f": lambda lo, hi: sub(lo, hi).f(wo[lo:hi], wi[lo:hi]),
        "bsdf pdf": lambda lo, hi: sub(lo, hi).pdf(wo[lo:hi], wi[lo:hi]),
        "bsdf f_parts (f, f_d, pdf)": lambda lo, hi: f_parts(sub(lo, hi), wo[lo:hi], wi[lo:hi]),
        "bsdf diffuse_constant": lambda lo, hi: sub(lo, hi).diffuse_constant(wo[lo:hi]),
        "bsdf sample_f": lambda lo, hi: sub(lo, hi).sample_f(wo[lo:hi], u_lobe[lo:hi], u[lo:hi]),
    }
    if hasattr(bsdf, "bind_wo"):
        ops["bsdf f_parts, wo bound"] = lambda lo, hi: sub(lo, hi, True).f_parts(wo[lo:hi], wi[lo:hi])
        ops["bsdf sample_f, wo bound"] = lambda lo, hi: sub(lo, hi, True).sample_f(
            wo[lo:hi], u_lobe[lo:hi], u[lo:hi])
    return ops


BUILDERS = (light_ops("rect"), light_ops("sphere"), bsdf_ops)


# --------------------------------------------------------------------------------------
def _best(fn, repeats):
    from renderer.bench import best_seconds

    return best_seconds(fn, repeats)


def measure(repeat: int, sizes=SIZES, block: float = 0.02) -> dict:
    """{"name|n": (1-thread M points/s, 2-thread M points/s)}.

    Each timing covers ``calls`` back-to-back calls (enough for ~``block`` seconds), as the
    integrator's threads run many chunks: the 1-thread timing runs them on n points, the 2-thread
    timing runs them on each half of the points in two threads at once."""
    results = {}
    with ThreadPoolExecutor(2) as pool:
        for n in sizes:
            # Fewer timings of the 16x longer calls.
            reps = max(3, repeat // 4) if n > 16384 else repeat
            for build in BUILDERS:
                ops = build(n, np.random.default_rng(1))
                for name, op in ops.items():
                    half = n // 2
                    op(0, n), op(0, half), op(half, n)  # warm-up: compilation / cache load, allocations
                    t0 = time.perf_counter()
                    op(0, n)
                    calls = max(1, int(block / max(time.perf_counter() - t0, 1e-9)))

                    def run(lo, hi):
                        for _ in range(calls):
                            op(lo, hi)

                    def two():
                        a = pool.submit(run, 0, half)
                        b = pool.submit(run, half, n)
                        a.result()
                        b.result()

                    t1 = _best(lambda: run(0, n), reps) / calls
                    t2 = _best(two, reps) / calls
                    results[f"{name}|{n}"] = (n / t1 / 1e6, n / t2 / 1e6)
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", help="root of another tree to measure side by side")
    ap.add_argument("--repeat", type=int, default=20,
                    help="timings per measurement at n = 16384, a quarter of that at 262144 (best is kept)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="measure everything this many times (alternating trees), keep the best")
    ap.add_argument("--json", action="store_true", help="print raw results as JSON (used for --baseline)")
    args = ap.parse_args(argv)

    if args.json:
        print(json.dumps(measure(args.repeat)))
        return 0

    def best_of(acc, new):
        # Keep the highest throughput seen for each entry (the least disturbed round).
        for k, v in new.items():
            acc[k] = tuple(max(a, b) for a, b in zip(acc.get(k, v), v))

    results, base = {}, {}
    for _ in range(args.rounds):
        # Rounds alternate between the trees so both see the same mix of machine load.
        best_of(results, measure(args.repeat))
        if args.baseline:
            env = dict(os.environ, PYTHONPATH=os.path.abspath(args.baseline))
            out = subprocess.run(
                [sys.executable, os.path.abspath(__file__), "--json", "--repeat", str(args.repeat)],
                env=env, cwd=os.path.abspath(args.baseline), check=True, capture_output=True, text=True,
            ).stdout
            best_of(base, json.loads(out.strip().splitlines()[-1]))

    head = f"{'operation':32s} {'n':>7s} {'1 thread':>9s} {'2 threads':>9s} {'x2':>5s}"
    if base:
        head += f"   | {'base 1t':>8s} {'base 2t':>8s} {'x2':>5s} | {'speedup 1t':>10s} {'2t':>6s}"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"throughput in M points/s (best of {args.rounds} x {args.repeat} timings at n = 16384, "
          f"{args.rounds} x {max(3, args.repeat // 4)} at 262144; "
          f"load average {load:.1f} on {os.cpu_count()} CPUs)")
    print(head)
    print("-" * len(head))
    for key, (m1, m2) in results.items():
        name, n = key.split("|")
        line = f"{name:32s} {int(n):7d} {m1:9.2f} {m2:9.2f} {m2 / m1:5.2f}"
        if base:
            if key in base:
                b1, b2 = base[key]
                line += f"   | {b1:8.2f} {b2:8.2f} {b2 / b1:5.2f} | {m1 / b1:9.1f}x {m2 / b2:5.1f}x"
            else:
                line += "   |      (not in baseline)"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
