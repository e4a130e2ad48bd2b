"""UsdLux ShapingAPI: what shaping costs, and what shaping-aware light picking buys (issue #9).

1. ``cost``: the spotlight stage (stages/shaping/spotlights.usda, 42 shaped lights) rendered
   with direct lighting only (max depth 1) in three variants built from the same stage:
   *unshaped* (every light's ShapingAPI removed), *cone/focus* (IES profiles removed) and
   *shaped* (as authored: cones, focus, IES). Reported: render seconds, shadow rays, microseconds
   of render time per shadow ray, and -- measured apart, on 1M light samples from random
   receivers -- the nanoseconds per sample of LightSet.sample_li with and without the shaping
   factor and of the factor alone (``ShapingTable.factor``: focus + cone, or + IES lookup).
   All variants run back to back, several times, and the best time is kept (the machine is
   shared); the ratios are what to read.
2. ``quality``: relMSE against a high-spp reference at equal render time, for the light BVH
   with the shaped power and cone bounds (the default) and without (``LightSet.shaping_aware
   = False``: unshaped power, omnidirectional/hemispherical bounds; same unbiased estimate), at
   max depth 1. Renders go through ``renderer.render.render`` with the prebuilt scene passed in
   its ``scene_cache``. relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01);
   the median over seeds is reported.

3. ``waste``: where shaped light samples carry no light (see ``waste``): how much sampling only
   the lit part of each light could save.

    .venv/bin/python bench/bench_shaping.py cost
    .venv/bin/python bench/bench_shaping.py quality --budget 10 --res 160 120 --ref-spp 1024 --seeds 3
    .venv/bin/python bench/bench_shaping.py waste
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
STAGE = os.path.join(ROOT, "stages", "shaping", "spotlights.usda")
OUT = os.path.join(ROOT, "bench", "out")
REL_EPS = 1e-2


def _desc(variant: str):
    from renderer.usd import load_stage

    desc = load_stage(STAGE)
    lights = []
    for d in desc.lights:
        if variant == "unshaped":
            d = dataclasses.replace(d, shaping=None)
        elif variant == "cone/focus" and d.shaping is not None:
            d = dataclasses.replace(d, shaping=dataclasses.replace(d.shaping, ies_file="", ies_profile=None))
        lights.append(d)
    return dataclasses.replace(desc, lights=lights)


def _scene(variant: str, threads: int, shaping_aware: bool = True):
    from renderer.light_samplers import make_light_sampler
    from renderer.scene import build_scene

    desc = _desc(variant)
    scene = build_scene(desc, threads=threads, light_sampler="bvh")
    if not shaping_aware:
        scene.lights.shaping_aware = False
        scene.light_sampler = make_light_sampler("bvh", scene.lights)
    return desc, scene


def _render(desc, scene, threads, res, **kw):
    """render() on a prebuilt scene: the cache key is the one render() computes."""
    from renderer.render import RenderOptions, render

    key = (os.path.abspath(STAGE), os.path.getmtime(STAGE), None, None, None, None, "bvh", threads)
    opt = RenderOptions(resolution=res, light_sampler="bvh", threads=threads, max_depth=1, **kw)
    return render(STAGE, opt, scene_cache={key: (desc, scene)})


# ----------------------------------------------------------------------------------------
def cost(args) -> None:
    from renderer.lights.base import ShadingContext

    variants = ("unshaped", "cone/focus", "shaped")
    built = {v: _scene(v, args.threads) for v in variants}
    best = {v: None for v in variants}
    for _ in range(args.repeats):
        for v in variants:
            desc, scene = built[v]
            r = _render(desc, scene, args.threads, tuple(args.res), spp=args.spp, seed=1)
            secs, rays = r.stats["seconds"]["render"], r.stats["rays"]["shadow"]
            if best[v] is None or secs < best[v][0]:
                best[v] = (secs, rays)
    print(f"\n## Cost: {os.path.relpath(STAGE, ROOT)}, {args.res[0]}x{args.res[1]}, {args.spp} spp, "
          f"max depth 1, bvh, {args.threads} thread(s), best of {args.repeats}\n")
    print("| variant | render s | render time vs unshaped | shadow rays | us of render per shadow ray |")
    print("|---|---|---|---|---|")
    for v in variants:
        s, n = best[v]
        print(f"| {v} | {s:.2f} | {s / best['unshaped'][0]:.2f}x | {n} | {1e6 * s / n:.2f} |")

    # Per-sample costs on 1M samples from random receivers below the lights.
    n = 1_000_000
    rng = np.random.default_rng(3)
    p = np.c_[rng.uniform(-6, 6, n), np.zeros(n), rng.uniform(-3, 5, n)]
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    ctx = ShadingContext(p, nrm, nrm)
    u = rng.random((n, 2))
    rows = {}
    for v in variants:
        lights = built[v][1].lights
        light = rng.integers(0, lights.count, n)
        t_sample = _best(lambda: lights.sample_li(light, ctx, u), args.repeats)
        s = lights.sample_li(light, ctx, u)
        e = np.ascontiguousarray(-s.wi)
        buf = np.ones((n, 3))
        t_factor = _best(lambda: lights.shaping.apply(light, e, buf), args.repeats) if lights.shaping else 0.0
        rows[v] = (t_sample, t_factor)
    per_ray = 1e9 * best["unshaped"][0] / best["unshaped"][1]
    print(f"\n1M light samples toward random receivers (the factor applied in place, as sample_li and le do);"
          f" last column: the factor's cost against the unshaped render's {per_ray:.0f} ns of render time per"
          f" shadow ray.\n")
    print("| variant | sample_li ns / sample | shaping factor ns / sample | factor / (render time per shadow ray) |")
    print("|---|---|---|---|")
    for v in variants:
        ts, tf = rows[v]
        print(f"| {v} | {1e9 * ts / n:.0f} | {1e9 * tf / n:.0f} | {100 * 1e9 * tf / n / per_ray:.1f} % |")
    for d, sc in built.values():
        sc.close()


def _best(fn, repeats):
    from renderer.bench import best_seconds

    return best_seconds(fn, repeats)


# ----------------------------------------------------------------------------------------
def quality(args) -> None:
    import OpenImageIO as oiio

    from renderer.film import write_exr

    res = tuple(args.res)
    os.makedirs(OUT, exist_ok=True)
    ref_path = os.path.join(OUT, f"shaping_ref_{res[0]}x{res[1]}_{args.ref_spp}spp.exr")
    if not os.path.exists(ref_path):
        desc, scene = _scene("shaped", args.threads)
        t0 = time.perf_counter()
        r = _render(desc, scene, args.threads, res, spp=args.ref_spp, seed=999)
        write_exr(ref_path, r.film, r.metadata)
        print(f"reference: {args.ref_spp} spp in {time.perf_counter() - t0:.0f} s -> {os.path.relpath(ref_path, ROOT)}")
        scene.close()
    buf = oiio.ImageBuf(ref_path)
    ref = buf.get_pixels(oiio.FLOAT)[:, :, :3].astype(np.float64)
    configs = {"bvh + shaped power and cone bounds": True, "bvh, unshaped bounds": False}
    built = {name: _scene("shaped", args.threads, aware) for name, aware in configs.items()}
    results = {name: [] for name in configs}
    for seed in range(args.seeds):
        for name in configs:   # alternate the configs so machine load hits both alike
            desc, scene = built[name]
            r = _render(desc, scene, args.threads, res, time_budget=args.budget, seed=seed + 1)
            img = r.film.mean()[:, :, :3].astype(np.float64)
            rel = float(np.mean((img - ref) ** 2 / (ref**2 + REL_EPS)))
            results[name].append((rel, r.stats["spp"], img.mean() / ref.mean()))
    print(f"\n## Equal time: {os.path.relpath(STAGE, ROOT)}, {res[0]}x{res[1]}, {args.budget:g} s per render, "
          f"max depth 1, {args.seeds} seeds, reference {args.ref_spp} spp\n")
    print("| light picking | relMSE (median) | spp reached | mean / ref | relMSE ratio |")
    print("|---|---|---|---|---|")
    med = {k: float(np.median([x[0] for x in v])) for k, v in results.items()}
    first = next(iter(configs))
    for name, rows in results.items():
        spp = int(np.median([x[1] for x in rows]))
        bias = float(np.mean([x[2] for x in rows]))
        print(f"| {name} | {med[name]:.4g} | {spp} | {bias:.3f} | {med[name] / med[first]:.2f}x |")
    for d, sc in built.values():
        sc.close()


# ----------------------------------------------------------------------------------------
def waste(args) -> None:
    """Where shaped light samples carry no light, and what sampling only the lit part of each
    light could save. Receivers on the floor pick a light with the shaping-aware BVH, as the
    renderer does, then draw K light samples of it. A (receiver, light) pair is *dark* when
    all K samples have shaped radiance 0 (the cone misses the receiver from every point of the
    light: no area sampling can help; only the light pick could), *mixed* when some are 0 and
    some are not (the receiver is in the penumbra band of the cone's edge: the samples wasted
    there are all that sampling only the lit part of the light could recover), *lit* otherwise."""
    from renderer.lights.base import ShadingContext

    desc, scene = _scene("shaped", args.threads)
    n, K = 20_000, 16
    rng = np.random.default_rng(11)
    p = np.c_[rng.uniform(-6, 6, n), np.zeros(n), rng.uniform(-3, 5, n)]
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    light, pmf = scene.light_sampler.sample(ShadingContext(p, nrm, nrm), rng.random(n))
    keep = np.nonzero(pmf > 0)[0]
    rows = np.repeat(keep, K)
    ctx = ShadingContext(p[rows], nrm[rows], nrm[rows])
    s = scene.lights.sample_li(light[rows], ctx, rng.random((rows.size, 2)))
    valid = (s.pdf > 0) & (np.einsum("ij,ij->i", s.wi, ctx.ns) > 0)
    zero = (valid & np.all(s.L == 0.0, axis=1)).reshape(-1, K)
    valid = valid.reshape(-1, K)
    nz = zero.sum(axis=1)
    nv = valid.sum(axis=1)
    dark = (nv > 0) & (nz == nv)
    mixed = (nz > 0) & (nz < nv)
    total = valid.sum()
    print(f"\n## Where shaped samples are wasted: {os.path.relpath(STAGE, ROOT)}, {keep.size} floor receivers, "
          f"one BVH-picked light each, {K} light samples per pair\n")
    print("| pairs | share of pairs | share of all valid samples with shaped radiance 0 |")
    print("|---|---|---|")
    for name, m in (("dark (cone misses the receiver)", dark), ("mixed (penumbra band)", mixed),
                    ("lit", ~dark & ~mixed & (nv > 0))):
        print(f"| {name} | {100 * m.mean():.1f} % | {100 * zero[m].sum() / total:.2f} % |")
    scene.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", nargs="?", default="both", choices=("cost", "quality", "both", "waste"))
    ap.add_argument("--res", type=int, nargs=2, default=(160, 120))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--budget", type=float, default=10.0)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args(argv)
    if args.what in ("cost", "both"):
        cost(args)
    if args.what in ("quality", "both"):
        quality(args)
    if args.what == "waste":
        waste(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
