"""Lighting services: BVH build cost, and image error at equal time (project issue #5).

1. ``build``: BVHLightSampler build time (wall and CPU, best of N), memory held by the tree
   and peak allocation during the build (tracemalloc), tree depth, and the cost of a pick
   (sample) and of its replay (pmf) per row, at 1k, 10k and 100k synthetic lights (half
   omni spheres, half one-sided quads with random normals, in a 20 m box) and for the
   fireflies stage's real LightSet.
2. ``quality``: relMSE against a high-spp reference at equal render time, for the uniform,
   power and bvh samplers on stages/fireflies and stages/city_lights. Each render is
   ``renderer.render.render(stage, RenderOptions(light_sampler=..., time_budget=..., seed=...))``
   at a small resolution. The reference (bvh, --ref-spp samples) is cached as an EXR under
   bench/out/ (gitignored), keyed by stage, resolution and spp.

       relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01)

   Camera rays that catch a subpixel emitter (a firefly of hundreds of nits in a dark pixel)
   are noise that no lighting service can reduce, and with thousands of fireflies on screen
   they dominate relMSE; so the table also gives relMSE over the pixels that cannot see any
   light directly ("surf.", a conservative geometric mask, see emitter_mask). The budget is
   wall-clock time, so other processes on the machine add noise; the table also prints the
   samples per pixel each sampler reached, and mean(image)/mean(ref) as a bias check (~1).
   Errors are heavy-tailed (a shading point millimetres from a firefly, picked with a small
   pmf, can put 1e4 into a dark pixel), so the summary takes the median over seeds.

    .venv/bin/python bench/bench_light_samplers.py build
    .venv/bin/python bench/bench_light_samplers.py quality --budget 30 --res 160 90 --ref-spp 1024
    .venv/bin/python bench/bench_light_samplers.py            # both, default settings
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tracemalloc

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
OUT = os.path.join(ROOT, "bench", "out")
STAGES = {
    "fireflies": os.path.join(ROOT, "stages", "fireflies", "fireflies.usda"),
    "city_lights": os.path.join(ROOT, "stages", "city_lights", "city_lights.usda"),
}
REL_EPS = 1e-2


# ----------------------------------------------------------------------------------------
# 1. build
# ----------------------------------------------------------------------------------------
def synthetic_bounds(m: int, seed: int = 0):
    from renderer.light_samplers.bvh import LightBounds

    rng = np.random.default_rng(seed)
    c = rng.uniform(-10.0, 10.0, (m, 3))
    r = rng.uniform(0.01, 0.1, m)[:, None]
    w = rng.normal(size=(m, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    omni = rng.random(m) < 0.5
    return LightBounds(np.arange(m), c - r, c + r, rng.uniform(0.1, 10.0, m), w,
                       np.where(omni, np.pi, 0.0), np.full(m, np.pi / 2))


def _time_build(make, repeats: int):
    walls, cpus = [], []
    sampler = None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        sampler = make()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    tracemalloc.start()
    make()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return sampler, min(walls), min(cpus), peak


def _time_pick(sampler, p, nrm, repeats: int = 3) -> tuple[float, float]:
    from renderer.lights.base import ShadingContext

    ctx = ShadingContext(p, nrm, nrm)
    u = np.random.default_rng(1).random(p.shape[0])
    ts, tp = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        index, pmf = sampler.sample(ctx, u)
        ts.append(time.process_time() - c0)
        c0 = time.process_time()
        sampler.pmf(ctx, index)
        tp.append(time.process_time() - c0)
    n = p.shape[0]
    return min(ts) / n * 1e6, min(tp) / n * 1e6


def bench_build(sizes=(1_000, 10_000, 100_000), repeats: int = 3) -> list[dict]:
    from renderer.light_samplers.bvh import BVHLightSampler

    rows = []
    rng = np.random.default_rng(2)
    n_pick = 100_000
    p = rng.uniform(-10.0, 10.0, (n_pick, 3))
    nrm = rng.normal(size=(n_pick, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    for m in sizes:
        b = synthetic_bounds(m)
        s, wall, cpu, peak = _time_build(lambda: BVHLightSampler(bounds=b, count=m), repeats)
        us_s, us_p = _time_pick(s, p, nrm)
        rows.append({"lights": m, "source": "synthetic", "build_wall_s": wall, "build_cpu_s": cpu,
                     "tree_MB": s.memory_bytes() / 1e6, "build_peak_MB": peak / 1e6, "depth": s.max_depth,
                     "sample_us_per_row": us_s, "pmf_us_per_row": us_p})
    # The fireflies stage's real lights (LightSet from the USD stage).
    from renderer.lights.light_set import LightSet
    from renderer.usd import load_stage

    desc = load_stage(STAGES["fireflies"])
    lights = LightSet.build(desc.lights, (0.0, 0.0, -20.0), 50.0)
    s, wall, cpu, peak = _time_build(lambda: BVHLightSampler(lights), repeats)
    g = np.column_stack((rng.uniform(-20, 20, n_pick), rng.uniform(-0.5, 0.5, n_pick), rng.uniform(-45, 5, n_pick)))
    up = np.tile([0.0, 1.0, 0.0], (n_pick, 1))
    us_s, us_p = _time_pick(s, g, up)
    rows.append({"lights": lights.count, "source": "fireflies.usda", "build_wall_s": wall, "build_cpu_s": cpu,
                 "tree_MB": s.memory_bytes() / 1e6, "build_peak_MB": peak / 1e6, "depth": s.max_depth,
                 "sample_us_per_row": us_s, "pmf_us_per_row": us_p})
    print("\nBVH build (best of %d) and pick cost (batch of %d rows, CPU time)" % (repeats, n_pick))
    print(f"{'lights':>8} {'source':>15} {'wall s':>8} {'cpu s':>8} {'tree MB':>8} {'peak MB':>8} {'depth':>6} "
          f"{'sample us':>10} {'pmf us':>8}")
    for r in rows:
        print(f"{r['lights']:>8} {r['source']:>15} {r['build_wall_s']:>8.3f} {r['build_cpu_s']:>8.3f} "
              f"{r['tree_MB']:>8.2f} {r['build_peak_MB']:>8.1f} {r['depth']:>6} {r['sample_us_per_row']:>10.2f} "
              f"{r['pmf_us_per_row']:>8.2f}")
    return rows


# ----------------------------------------------------------------------------------------
# 2. quality at equal time
# ----------------------------------------------------------------------------------------
def rel_mse(img: np.ndarray, ref: np.ndarray) -> float:
    d = img.astype(np.float64) - ref
    return float(np.mean(d * d / (ref * ref + REL_EPS)))


def emitter_mask(stage: str, res: tuple[int, int], margin_px: float = 2.5) -> np.ndarray:
    """(H, W) bool: pixels whose footprint may see a light directly (conservative: occlusion
    ignored). A light counts if its bounding sphere comes within margin_px pixels (the 1.5 px
    Gaussian filter plus half a pixel, rounded up) of the pixel-centre ray. Camera rays that
    catch a subpixel emitter of hundreds of nits are noise no lighting service can touch, and
    the fireflies stage has thousands of them, so the table also reports relMSE without them.
    """
    from renderer.camera import Camera
    from renderer.light_samplers.bvh import light_bounds
    from renderer.lights.light_set import LightSet
    from renderer.usd import load_stage

    w, h = res
    desc = load_stage(stage)
    st = desc.settings
    cam = Camera(desc.camera, w, h, st.pixel_aspect_ratio, st.aspect_ratio_conform_policy)
    ys, xs = np.mgrid[0:h, 0:w]
    n = w * h
    rays = cam.generate(xs.ravel(), ys.ravel(), np.full((n, 2), 0.5), np.full((n, 2), 0.5))
    d = rays.d.reshape(h, w, 3)
    step = max(float(np.max(np.arccos(np.clip(np.sum(d[:, 1:] * d[:, :-1], axis=2), -1, 1)))),
               float(np.max(np.arccos(np.clip(np.sum(d[1:] * d[:-1], axis=2), -1, 1)))))
    b = light_bounds(LightSet.build(desc.lights))
    c = 0.5 * (b.lo + b.hi)
    R = 0.5 * np.linalg.norm(b.hi - b.lo, axis=1)
    v = c - rays.o[0]
    dist = np.linalg.norm(v, axis=1)
    u = v / np.maximum(dist, 1e-30)[:, None]
    alpha = np.where(dist > R, np.arcsin(np.minimum(R / np.maximum(dist, 1e-30), 1.0)), np.pi)
    cos_lim = np.cos(np.minimum(alpha + margin_px * step, np.pi))
    mask = np.zeros(n, bool)
    dirs = rays.d
    for i in range(0, u.shape[0], 256):
        mask |= np.any(dirs @ u[i:i + 256].T >= cos_lim[i:i + 256], axis=1)
    return mask.reshape(h, w)


def reference(stage: str, res: tuple[int, int], spp: int, seed: int = 987_654) -> np.ndarray:
    """(H, W, 3) bvh render with spp samples per pixel, cached in bench/out/."""
    from renderer.film import read_exr, write_exr
    from renderer.render import RenderOptions, render

    os.makedirs(OUT, exist_ok=True)
    name = os.path.splitext(os.path.basename(stage))[0]
    path = os.path.join(OUT, f"ref_{name}_{res[0]}x{res[1]}_{spp}spp.exr")
    if os.path.exists(path):
        return read_exr(path)[0][..., :3].astype(np.float64)
    print(f"rendering reference {path} (bvh, {spp} spp) ...", flush=True)
    t0 = time.perf_counter()
    r = render(stage, RenderOptions(spp=spp, resolution=res, light_sampler="bvh", seed=seed))
    write_exr(path, r.film, r.metadata)
    print(f"  done in {time.perf_counter() - t0:.0f} s", flush=True)
    return r.film.image().astype(np.float64)


def bench_quality(stages, res, budget: float, ref_spp: int, seeds, samplers=("uniform", "power", "bvh")) -> list[dict]:
    from renderer.render import RenderOptions, render

    rows = []
    masks = {}
    for name in stages:
        stage = STAGES[name]
        ref = reference(stage, res, ref_spp)
        masks[name] = m = emitter_mask(stage, res)
        keep = ~m
        # Seeds outermost, so that changing load on the machine hits every sampler alike.
        for seed in seeds:
            for sampler in samplers:
                r = render(stage, RenderOptions(time_budget=budget, resolution=res, light_sampler=sampler, seed=seed))
                img = r.film.image().astype(np.float64)
                e = rel_mse(img, ref)
                e_s = rel_mse(img[keep], ref[keep])
                rows.append({"stage": name, "sampler": sampler, "seed": seed, "spp": r.stats["spp"],
                             "render_s": r.stats["seconds"]["render"], "relMSE": e, "relMSE_surfaces": e_s,
                             "relMSE_x_spp": e * r.stats["spp"], "mean_ratio": float(img.mean() / ref.mean())})
                print(f"  {name:12} {sampler:8} seed {seed}: spp {r.stats['spp']:4d}  relMSE {e:.4g}  "
                      f"without emitter pixels {e_s:.4g}", flush=True)
    print(f"\nrelMSE at equal time ({budget:g} s per render, {res[0]}x{res[1]}, reference bvh {ref_spp} spp; "
          "median over seeds, which a single heavy-tailed outlier cannot swing; the JSON has every run). "
          "'surf.': pixels that cannot see a light directly.")
    print(f"{'stage':>12} {'sampler':>8} {'spp':>5} {'relMSE':>8} {'unif/x':>7} {'power/x':>7} "
          f"{'surf.':>8} {'unif/x':>7} {'power/x':>7} {'surf.%':>6} {'mean/ref':>8}")
    keys = ("spp", "relMSE", "relMSE_surfaces", "relMSE_x_spp", "mean_ratio")
    for name in stages:
        agg = {}
        for sampler in samplers:
            sel = [r for r in rows if r["stage"] == name and r["sampler"] == sampler]
            agg[sampler] = {k: float(np.median([r[k] for r in sel])) for k in keys}
        for sampler in samplers:
            a, u, p = agg[sampler], agg["uniform"], agg["power"]
            print(f"{name:>12} {sampler:>8} {a['spp']:>5.0f} {a['relMSE']:>8.4g} "
                  f"{u['relMSE'] / a['relMSE']:>7.2f} {p['relMSE'] / a['relMSE']:>7.2f} "
                  f"{a['relMSE_surfaces']:>8.4g} {u['relMSE_surfaces'] / a['relMSE_surfaces']:>7.2f} "
                  f"{p['relMSE_surfaces'] / a['relMSE_surfaces']:>7.2f} {100 * (1 - masks[name].mean()):>6.1f} "
                  f"{a['mean_ratio']:>8.3f}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", nargs="?", choices=["build", "quality", "all"], default="all")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stages", nargs="+", default=list(STAGES), choices=list(STAGES))
    ap.add_argument("--res", type=int, nargs=2, default=[160, 90])
    ap.add_argument("--budget", type=float, default=30.0, help="seconds of rendering per sampler and seed")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    args = ap.parse_args(argv)
    report = {"machine": {"cpus": os.cpu_count(), "load_avg": os.getloadavg()}}
    if args.what in ("build", "all"):
        report["build"] = bench_build(tuple(args.sizes), args.repeats)
    if args.what in ("quality", "all"):
        report["quality"] = bench_quality(args.stages, tuple(args.res), args.budget, args.ref_spp, args.seeds)
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, f"light_samplers_{args.what}.json")
    with open(path, "w") as fh:
        json.dump(report, fh, indent=1)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
