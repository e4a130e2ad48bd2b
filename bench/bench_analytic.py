"""Rows per second of the analytic light integrals F (projected solid angle G, renderer/lights/
analytic.py): the numpy implementation before the port (commit 0332038, read with ``git show``)
against the compiled row functions after it, per light kind, on one thread.

    PYTHONPATH=$PWD .venv/bin/python bench/bench_analytic.py [--rows 100000] [--repeats 3] [--compile]

Two workloads of ``--rows`` rows per kind:

* ``scene``: a light of about 1 m at 1 m height (rect 1 × 0.5, disk r 0.5, ellipse 0.6 × 0.3,
  sphere r 0.3, a triangle and a pentagon of a mesh light, all facing down), shading points
  uniform in an 8 × 8 × 4.5 m box around it (some behind or beside it), random normals: what a
  render's shading points see.
* ``stress``: the 800 randomised configurations per kind of tests/analytic/data/
  numpy_reference.npz (grazing, in the plane, near edges and rims, far, tiny; configs.py),
  tiled to the row count: the hard cases, where the near-field closed forms, the slivers'
  area quadrature and the ellipse's graded arc panels all run.

The old numpy code is called in chunks of 16384 rows (its ellipse arrays grow with rows × arc
panels; whole 1e5-row batches exhaust the memory on the stress mix); the compiled code through
the same numpy API (a compiled loop over rows; the per-row cost inside another kernel is the
same). Times are CPU seconds of this process, the best of ``--repeats`` runs (the machine is
shared). The last column is the share of rows with G > 0 where both agree to 1e-9 relative (the
rest are rows whose inputs do not determine G that well; tests/analytic/test_compiled_rows.py
checks them against the inputs' rounding sensitivity). ``--compile`` also times a
cold compile of the row functions in a subprocess with an empty numba cache.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from renderer.lights import analytic as an  # noqa: E402
from tests.analytic.make_numpy_reference import OLD_COMMIT, old_module  # noqa: E402

CHUNK = 16384
KINDS = ("rect", "disk", "ellipse", "sphere", "triangle", "pentagon")


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def scene_inputs(n, rng):
    """Arguments per kind for the API functions (mod: an old or the new analytic module)."""
    p = rng.uniform([-4.0, -4.0, -3.5], [4.0, 4.0, 1.0], (n, 3))
    nrm = _unit(rng.normal(size=(n, 3)))
    c = np.array([0.0, 0.0, 1.0])
    down = np.array([0.0, 0.0, -1.0])
    ang = 2.0 * np.pi * np.arange(5) / 5 + 0.3
    penta = np.stack([0.5 * np.cos(ang), 0.5 * np.sin(ang), np.ones(5)], axis=1)[::-1]   # faces down
    tri = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 1.0], [0.7, 0.0, 1.0]])
    return {
        "rect": ("projected_solid_angle_rect", (p, nrm, c, [1.0, 0, 0], [0, 0.5, 0], down), {}),
        "disk": ("projected_solid_angle_disk", (p, nrm, c, down, 0.5), {}),
        "ellipse": ("projected_solid_angle_ellipse", (p, nrm, c, [0.6, 0, 0], [0, 0.3, 0], down), {}),
        "sphere": ("projected_solid_angle_sphere", (p, nrm, c, 0.3), {}),
        "triangle": ("projected_solid_angle_polygon", (p, nrm, tri), {"e_n": down}),
        "pentagon": ("projected_solid_angle_polygon", (p, nrm, penta), {"e_n": down}),
    }


def stress_inputs(n):
    ref = np.load(os.path.join(ROOT, "tests", "analytic", "data", "numpy_reference.npz"))

    def tile(key):
        a = ref[key]
        reps = -(-n // a.shape[0])
        return np.ascontiguousarray(np.concatenate([a] * reps)[:n])

    def args(pre, keys):
        return tuple(tile(f"{pre}_{k}") for k in keys)

    return {
        "rect": ("projected_solid_angle_rect", args("rect", ("p", "nrm", "c", "ex", "ey", "en")), {}),
        "disk": ("projected_solid_angle_disk", args("disk", ("p", "nrm", "c", "en", "R")), {}),
        "ellipse": ("projected_solid_angle_ellipse", args("ellipse", ("p", "nrm", "c", "e1", "e2", "en")), {}),
        "sphere": ("projected_solid_angle_sphere", args("sphere", ("p", "nrm", "c", "R")), {}),
        "triangle": ("projected_solid_angle_polygon", args("polygon3", ("p", "nrm", "V")),
                     {"e_n": tile("polygon3_en")}),
        "pentagon": ("projected_solid_angle_polygon", args("polygon5", ("p", "nrm", "V")),
                     {"e_n": tile("polygon5_en")}),
    }


def _chunk(a, lo, hi, n):
    a = np.asarray(a)
    return a[lo:hi] if a.ndim >= 1 and a.shape[0] == n and not (a.ndim == 1 and n == 3) else a


def run(mod, name, args, kw, n, chunk):
    fn = getattr(mod, name)
    out = []
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        out.append(fn(*[_chunk(a, lo, hi, n) for a in args], **{k: _chunk(v, lo, hi, n) for k, v in kw.items()}))
    return np.concatenate(out)


def best_time(fn, repeats):
    """Least CPU time (process_time: all threads of this process) of ``repeats`` runs, and the
    result. CPU rather than wall time: the machine is shared, and waiting for a core is not the
    code's cost."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        res = fn()
        best = min(best, time.process_time() - t0)
    return best, res


def cold_compile_seconds():
    """(CPU, wall) seconds to import analytic.py and compile every row function (one call of each
    numpy API function) with an empty numba cache, in a fresh process."""
    code = ("import time, numpy as np; t = time.perf_counter(); c = time.process_time(); "
            "from renderer.lights import analytic as an; "
            "p = np.array([[0.1, 0.2, 1.0]]); z = [0, 0, -1.0]; "
            "an.projected_solid_angle_rect(p, z, [0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]); "
            "an.projected_solid_angle_disk(p, z, [0, 0, 0], [0, 0, 1.0], 1.0); "
            "an.projected_solid_angle_ellipse(p, z, [0, 0, 0], [1, 0, 0], [0, 0.5, 0], [0, 0, 1.0]); "
            "an.projected_solid_angle_sphere(p, z, [0, 0, -2.0], 1.0); "
            "an.projected_solid_angle_polygon(p, z, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], e_n=[0, 0, 1.0]); "
            "an.projected_solid_angle_polygon(p, z, [[0, 0, 0], [1, 0, 0], [0, 1, 0]]); "
            "print(time.process_time() - c, time.perf_counter() - t)")
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=ROOT)
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    cpu, wall = out.stdout.strip().splitlines()[-1].split()
    return float(cpu), float(wall)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--compile", action="store_true", help="also time a cold compile (fresh numba cache)")
    a = ap.parse_args()
    old = old_module()
    n = a.rows
    print(f"rows per CPU second, one thread, {n} rows per kind, best of {a.repeats}; numpy = analytic.py at "
          f"{OLD_COMMIT} (chunks of {CHUNK}), compiled = this tree\n")
    print("| workload | kind | numpy rows/s | compiled rows/s | speed-up | agree to 1e-9 (G > 0) |")
    print("|---|---|---:|---:|---:|---:|")
    for wl, inputs in (("scene", scene_inputs(n, np.random.default_rng(1))), ("stress", stress_inputs(n))):
        for kind in KINDS:
            name, args, kw = inputs[kind]
            run(an, name, args, kw, min(n, 64), n)                      # compile / warm
            t_old, g_old = best_time(lambda: run(old, name, args, kw, n, CHUNK), a.repeats)
            t_new, g_new = best_time(lambda: run(an, name, args, kw, n, n), a.repeats)
            pos = g_old > 0
            agree = float(np.mean(np.abs(g_new[pos] - g_old[pos]) <= 1e-9 * g_old[pos])) if pos.any() else 1.0
            print(f"| {wl} | {kind} | {n / t_old:,.0f} | {n / t_new:,.0f} | {t_old / t_new:.1f}× | {agree:.1%} |",
                  flush=True)
    if a.compile:
        cpu, wall = cold_compile_seconds()
        print(f"\ncold compile of every row function (fresh numba cache, new process): {cpu:.1f} s CPU, "
              f"{wall:.1f} s wall")


if __name__ == "__main__":
    main()
