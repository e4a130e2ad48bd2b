"""Cylinder lights, mesh lights and dome portals (issue #9): what a light sample costs, and what
the mesh lights' oriented triangle pick and the portals buy at equal time.

1. ``cost``: LightSet.sample_li and LightSet.pdf_li in nanoseconds per row, on batches of random
   receivers inside each stage's room (floor and walls, with their normals), best of
   ``--repeats``: the CylinderLight tube and the same light as a line (treatAsLine), the two
   mesh lights of stages/lux_extra/mesh_light_room.usda (a 768-triangle one-sided neon ring, a
   48-triangle two-sided lampshade) with the area pick and the oriented pick, the textured dome
   of stages/lux_extra/window_portal.usda with and without its portal, and for scale the
   Cornell box's rect light. Also the share of samples that come back valid (pdf > 0).
2. ``meshpick``: stages/lux_extra/mesh_light_room.usda with its two mesh lights only (the
   cylinder removed, so the image's noise is theirs), direct lighting (max depth 1), equal
   render time: the area pick against the oriented pick (per-point solid angles up to
   EXACT_PICK_TRIANGLES triangles, the triangle BVH above: the neon ring), and the oriented
   pick with the per-point kernel for every light. relMSE against an oriented-pick reference.
3. ``portal``: stages/lux_extra/window_portal.usda at equal render time, the dome sampled
   through its portal against the same dome with ``portals`` removed (same image in
   expectation), at max depth 1 and 4. relMSE against a with-portal reference.

relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01), the median over seeds.
Renders go through renderer.render.render with the prebuilt scene in its ``scene_cache``.

    .venv/bin/python bench/bench_lux_extra.py cost --repeats 3
    .venv/bin/python bench/bench_lux_extra.py meshpick --budget 8 --res 128 96 --seeds 3
    .venv/bin/python bench/bench_lux_extra.py portal --budget 8 --res 128 96 --seeds 3
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
ROOM = os.path.join(ROOT, "stages", "lux_extra", "mesh_light_room.usda")
WINDOW = os.path.join(ROOT, "stages", "lux_extra", "window_portal.usda")
CORNELL = os.path.join(ROOT, "stages", "cornell_box.usda")
OUT = os.path.join(ROOT, "bench", "out")
REL_EPS = 1e-2


def _load(stage, edit=None):
    from renderer.usd import load_stage

    desc = load_stage(stage)
    if edit is not None:
        desc = dataclasses.replace(desc, lights=[x for x in (edit(d) for d in desc.lights) if x is not None])
    return desc


def _build(desc, threads):
    from renderer.scene import build_scene

    return build_scene(desc, threads=threads, light_sampler="bvh")


def _mesh_kind(scene):
    return next(k for k in scene.lights.kinds if getattr(k, "name", "") == "mesh")


def _render(stage, desc, scene, threads, res, max_depth, **kw):
    """render() on a prebuilt scene: the cache key is the one render() computes."""
    from renderer.render import RenderOptions, render

    key = (os.path.abspath(stage), os.path.getmtime(stage), None, None, None, None, "bvh", threads)
    opt = RenderOptions(resolution=res, light_sampler="bvh", threads=threads, max_depth=max_depth, **kw)
    return render(stage, opt, scene_cache={key: (desc, scene)})


def _best(fn, repeats):
    from renderer.bench import best_seconds

    return best_seconds(fn, repeats)


def _receivers(n, lo, hi, seed=3):
    """Random points on the floor and the back (-Z) wall of the box [lo, hi], with normals."""
    from renderer.lights.base import ShadingContext

    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    p = lo + rng.random((n, 3)) * (hi - lo)
    nrm = np.zeros((n, 3))
    half = n // 2
    p[:half, 1] = lo[1] + 1e-3
    nrm[:half, 1] = 1.0
    p[half:, 2] = lo[2] + 1e-3
    nrm[half:, 2] = 1.0
    return ShadingContext(p, nrm, nrm.copy()), rng


# ----------------------------------------------------------------------------------------
def cost(args) -> None:
    n = args.n
    rows = []

    def measure(label, scene, path, ctx, rng):
        lights = scene.lights
        g = lights.paths.index(path) if hasattr(lights, "paths") else None
        light = np.full(n, g, dtype=np.int64)
        u = rng.random((n, 2))
        lights.sample_li(light[:1000], ctx.take(np.arange(1000)), u[:1000])      # compile / warm up
        t_s = _best(lambda: lights.sample_li(light, ctx, u), args.repeats)
        s = lights.sample_li(light, ctx, u)
        ok = np.nonzero(s.pdf > 0)[0]
        c_ok = ctx.take(ok)
        t_p = _best(lambda: lights.pdf_li(light[ok], c_ok, s.wi[ok]), args.repeats) if ok.size else 0.0
        rows.append((label, 1e9 * t_s / n, 1e9 * t_p / max(ok.size, 1), ok.size / n))

    # Cornell box rect light, for scale.
    desc = _load(CORNELL)
    scene = _build(desc, args.threads)
    rect = next(d.path for d in desc.lights if d.kind == "rect")
    ctx, rng = _cornell_receivers(n, desc)
    measure("rect (Cornell box)", scene, rect, ctx, rng)
    scene.close()

    # Mesh-light room: the tube, the tube as a line, both mesh lights with both picks.
    ctx, rng = _receivers(n, (-2.0, 0.0, -2.0), (2.0, 2.6, 2.0))
    for line in (False, True):
        desc = _load(ROOM, lambda d: dataclasses.replace(d, treat_as_line=line) if d.kind == "cylinder" else d)
        scene = _build(desc, args.threads)
        tube = next(d.path for d in desc.lights if d.kind == "cylinder")
        measure("cylinder, treatAsLine" if line else "cylinder (tube)", scene, tube, ctx, rng)
        if not line:
            mk = _mesh_kind(scene)
            for d in desc.lights:
                if d.kind != "mesh":
                    continue
                T = int(np.asarray(d.mesh_triangles).reshape(-1, 9).shape[0])
                name = f"mesh {d.path.rsplit('/', 1)[-1]} ({T} tris{', two-sided' if d.mesh_two_sided else ''})"
                for mode in ("area", "oriented"):
                    mk.use_pick(mode)
                    measure(f"{name}, {mode} pick", scene, d.path, ctx, rng)
                mk.use_pick("oriented", exact_max_triangles=10**9)
                measure(f"{name}, oriented, per-point kernel for all", scene, d.path, ctx, rng)
                from renderer.lights.mesh import EXACT_PICK_TRIANGLES
                mk.use_pick("oriented", exact_max_triangles=EXACT_PICK_TRIANGLES)
        scene.close()

    # Window portal: the dome with and without its portal, receivers inside the room.
    ctx, rng = _receivers(n, (-2.0, 0.0, -2.0), (2.0, 2.8, 2.0))
    for portals in (True, False):
        desc = _load(WINDOW, None if portals else
                     (lambda d: dataclasses.replace(d, portals=None, portal_paths=()) if d.kind == "dome" else d))
        scene = _build(desc, args.threads)
        dome = next(d.path for d in desc.lights if d.kind == "dome")
        measure("textured dome, through its portal" if portals else "textured dome, no portal", scene, dome, ctx, rng)
        scene.close()

    print(f"\n## Cost per light sample: {n} rows, random receivers on the floor and back wall, best of "
          f"{args.repeats}\n")
    print("| light | sample_li ns / row | pdf_li ns / row | valid samples |")
    print("|---|---|---|---|")
    for label, ts, tp, ok in rows:
        print(f"| {label} | {ts:.0f} | {tp:.0f} | {100 * ok:.1f} % |")


def _cornell_receivers(n, desc):
    """Random points on the Cornell box floor (the box's lowest extent, normal +Y)."""
    from renderer.lights.base import ShadingContext

    pts = np.concatenate([np.asarray(m.points, float).reshape(-1, 3) for m in desc.meshes])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    rng = np.random.default_rng(5)
    p = lo + rng.random((n, 3)) * (hi - lo)
    p[:, 1] = lo[1] + 1e-3 * (hi[1] - lo[1])
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1))
    return ShadingContext(p, nrm, nrm.copy()), rng


# ----------------------------------------------------------------------------------------
def _equal_time(stage, configs, ref_name, args, max_depth, tag):
    """configs: {name: (desc, scene, prepare)}; renders ref_name at --ref-spp once (cached on disk)."""
    import OpenImageIO as oiio

    from renderer.film import write_exr

    res = tuple(args.res)
    os.makedirs(OUT, exist_ok=True)
    ref_path = os.path.join(OUT, f"{tag}_d{max_depth}_ref_{res[0]}x{res[1]}_{args.ref_spp}spp.exr")
    if not os.path.exists(ref_path):
        desc, scene, prep = configs[ref_name]
        prep()
        t0 = time.perf_counter()
        r = _render(stage, desc, scene, args.threads, res, max_depth, spp=args.ref_spp, seed=999)
        write_exr(ref_path, r.film, r.metadata)
        print(f"reference: {args.ref_spp} spp in {time.perf_counter() - t0:.0f} s -> {os.path.relpath(ref_path, ROOT)}",
              flush=True)
    ref = oiio.ImageBuf(ref_path).get_pixels(oiio.FLOAT)[:, :, :3].astype(np.float64)
    results = {name: [] for name in configs}
    for seed in range(args.seeds):
        for name, (desc, scene, prep) in configs.items():   # alternate, so machine load hits all alike
            prep()
            r = _render(stage, desc, scene, args.threads, res, max_depth, time_budget=args.budget, seed=seed + 1)
            img = r.film.mean()[:, :, :3].astype(np.float64)
            rel = float(np.mean((img - ref) ** 2 / (ref**2 + REL_EPS)))
            results[name].append((rel, r.stats["spp"], img.mean() / ref.mean()))
    med = {k: float(np.median([x[0] for x in v])) for k, v in results.items()}
    first = next(iter(configs))
    print("| variant | relMSE (median) | spp reached | mean / ref | relMSE vs first row |")
    print("|---|---|---|---|---|")
    for name, rs in results.items():
        spp = int(np.median([x[1] for x in rs]))
        bias = float(np.mean([x[2] for x in rs]))
        print(f"| {name} | {med[name]:.4g} | {spp} | {bias:.3f} | {med[name] / med[first]:.2f}x |")


def meshpick(args) -> None:
    desc = _load(ROOM, lambda d: None if d.kind == "cylinder" else d)
    scene = _build(desc, args.threads)
    mk = _mesh_kind(scene)
    from renderer.lights.mesh import EXACT_PICK_TRIANGLES

    # Per-sample variance of the unshadowed estimate L cos / pdf, per light and pick, at M random
    # receivers on the floor and back wall with K samples each: the mean over receivers of the
    # per-receiver variance, over the squared mean estimate (shadowing left out: it is the
    # same for every pick).
    M, K = 400, 64
    ctx0, rng = _receivers(M, (-2.0, 0.0, -2.0), (2.0, 2.6, 2.0), seed=7)
    rows = np.repeat(np.arange(M), K)
    ctx = ctx0.take(rows)
    u = rng.random((M * K, 2))
    picks = (("area", None), ("oriented", EXACT_PICK_TRIANGLES), ("oriented", 10**9))
    print(f"\n## Per-sample variance: {os.path.relpath(ROOM, ROOT)}, {M} receivers (floor, back wall) x {K} "
          f"samples, unshadowed L cos / pdf\n")
    print("| light | pick | relative variance | failed samples | variance vs area pick |")
    print("|---|---|---|---|---|")
    for d in desc.lights:
        g = scene.lights.paths.index(d.path)
        light = np.full(M * K, g, dtype=np.int64)
        base = None
        for mode, exact in picks:
            mk.use_pick(mode, exact)
            s = scene.lights.sample_li(light, ctx, u)
            ok = s.pdf > 0
            cos = np.maximum(0.0, np.einsum("ij,ij->i", s.wi, ctx.ns))
            est = np.where(ok, s.L[:, 1] * cos / np.where(ok, s.pdf, 1.0), 0.0).reshape(M, K)
            rel = float(est.var(axis=1).mean() / est.mean() ** 2)
            base = rel if base is None else base
            label = {"area": "area", "oriented": "oriented"}[mode]
            if exact is not None and exact > EXACT_PICK_TRIANGLES:
                label += ", per-point kernel for every light"
            T = int(np.asarray(d.mesh_triangles).reshape(-1, 9).shape[0])
            print(f"| {d.path} ({T} tris) | {label} | {rel:.4g} | {100 * (1 - ok.mean()):.1f} % | {rel / base:.3f}x |")
    mk.use_pick("oriented", EXACT_PICK_TRIANGLES)

    configs = {
        "area pick": (desc, scene, lambda: mk.use_pick("area")),
        f"oriented pick (solid angle <= {EXACT_PICK_TRIANGLES} tris, triangle BVH above)":
            (desc, scene, lambda: mk.use_pick("oriented", EXACT_PICK_TRIANGLES)),
        "oriented pick, per-point solid angles for every light":
            (desc, scene, lambda: mk.use_pick("oriented", 10**9)),
    }
    res = tuple(args.res)
    print(f"\n## Equal time: {os.path.relpath(ROOM, ROOT)} (mesh lights only), {res[0]}x{res[1]}, "
          f"{args.budget:g} s per render, max depth 1, {args.seeds} seeds, reference {args.ref_spp} spp "
          f"(oriented pick)\n", flush=True)
    _equal_time(ROOM, configs, list(configs)[1], args, 1, "meshpick")
    scene.close()


def portal(args) -> None:
    with_p = _load(WINDOW)
    without = _load(WINDOW, lambda d: dataclasses.replace(d, portals=None, portal_paths=()) if d.kind == "dome" else d)
    s_with, s_without = _build(with_p, args.threads), _build(without, args.threads)
    configs = {"dome sampled through its portal": (with_p, s_with, lambda: None),
               "dome without portal": (without, s_without, lambda: None)}
    res = tuple(args.res)
    for depth in args.depths:
        print(f"\n## Equal time: {os.path.relpath(WINDOW, ROOT)}, {res[0]}x{res[1]}, {args.budget:g} s per render, "
              f"max depth {depth}, {args.seeds} seeds, reference {args.ref_spp} spp (with portal)\n", flush=True)
        _equal_time(WINDOW, configs, "dome sampled through its portal", args, depth, "portal")
    s_with.close()
    s_without.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("cost", "meshpick", "portal"))
    ap.add_argument("--n", type=int, default=200_000, help="rows per cost measurement")
    ap.add_argument("--res", type=int, nargs=2, default=(128, 96))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--budget", type=float, default=8.0)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--depths", type=int, nargs="+", default=(1, 4))
    args = ap.parse_args(argv)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    {"cost": cost, "meshpick": meshpick, "portal": portal}[args.what](args)
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
