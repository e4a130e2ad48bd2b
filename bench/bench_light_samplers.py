"""Lighting services: BVH build cost, image error at equal time, the variance of the light
choice, and render throughput (project issues #5 and #8).

1. ``build``: BVHLightSampler build time (wall and CPU, best of N), memory held by the tree
   and peak allocation during the build (tracemalloc), tree depth, and the cost of a pick
   (sample) and of its replay (pmf) per row, at 1k, 10k and 100k synthetic lights (half
   omni spheres, half one-sided quads with random normals, in a 20 m box) and for the
   fireflies stage's real LightSet.
2. ``quality``: relMSE against a high-spp reference at equal render time, for the uniform,
   power and bvh samplers on stages/fireflies and stages/city_lights. Each render is
   ``renderer.render.render(stage, RenderOptions(light_sampler=..., seed=..., threads=...))``
   at a small resolution, after a 1-spp warm-up that loads the scene, for ``--budget``
   seconds: CPU seconds by default (``--equal cpu``: a 2 s calibration render measures the
   sampler's passes per CPU second and the render takes the spp that fill the budget; on a
   shared machine the share of a core a render gets varies, CPU time does much less), or
   the render's own wall-clock ``time_budget`` (``--equal wall``). The reference (bvh, --ref-spp samples) is cached
   with its per-pixel variance under bench/out/ (gitignored), keyed by stage, resolution and
   spp.

       relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01)

   The error is decomposed: relMSE over the pixels that cannot see any light directly
   ("surf.", a conservative geometric mask, see emitter_mask) and over the others; the share
   of the error sum in emitter-visible pixels and in the worst 1 % of pixels; the reference's
   own relMSE (its "floor", from its variance); and the *anti-aliasing floor*, the relMSE
   that camera rays catching subpixel emitters add at the spp a sampler reached (renders at
   max_depth 0 show only those), which no lighting service can reduce. "relMSE - floors" is
   what is left for the lighting service. Error maps go to
   bench/out/light_samplers_errmaps_STAGE.png. Other processes on the machine still add
   noise (the load average is recorded); the table also prints the samples per pixel each
   sampler reached, the CPU seconds it took, and mean(image)/mean(ref) as a bias check (~1).
   Errors are heavy-tailed, so the summary takes the median over seeds. The table ends with
   relMSE x CPU seconds, the comparison at exactly equal CPU time. A run at another ``--res``
   than 160x90 (the stages' own 480x270, where a subpixel firefly covers a smaller share of
   the pixels) keeps its JSON and error maps under names ending in _WxH (and the JSON of a
   run of some of the stages, _STAGE...), and ``report`` shows those first.
3. ``pick``: the exact, noise-free relative variance of the light *choice* at the camera's
   first hits (every light's unoccluded irradiance against the sampler's pmf; bench_pick),
   with the share of it from lights picked far less often than their share ("tails"), by
   distance. Quick (about 30 s per stage) and the first thing to run after changing the BVH
   importance.
4. ``throughput``: samples/s of render() (fireflies, 160x90, one thread, max depth 8), each
   run in its own process, alternating with a ``--baseline`` source tree, by wall and by
   CPU time. ``profile``: cProfile of one such render (top functions by own and cumulative
   time).
5. ``report``: writes bench/results/light_samplers/results.md from the JSON files the modes
   above leave in bench/out/.

    .venv/bin/python bench/bench_light_samplers.py build
    .venv/bin/python bench/bench_light_samplers.py quality --budget 20 --seeds 1 2 --threads 1
    .venv/bin/python bench/bench_light_samplers.py pick --stride 2
    git archive REV | tar -x -C /tmp/base     # a tree to compare with (read-only for git)
    .venv/bin/python bench/bench_light_samplers.py throughput --stages fireflies --samplers bvh uniform \
        --budget 8 --rounds 5 --baseline /tmp/base
    .venv/bin/python bench/bench_light_samplers.py profile --stages fireflies --samplers bvh --budget 8
    .venv/bin/python bench/bench_light_samplers.py report
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
    "many_lights": os.path.join(ROOT, "stages", "many_lights", "many_lights.usda"),
}
# The stages ``--stages`` takes by default (many_lights is asked for by name).
DEFAULT_STAGES = ["fireflies", "city_lights"]
REL_EPS = 1e-2
# The bench's default resolution; quality runs at another one (e.g. the stages' own 480x270)
# keep their JSON and error maps under names with the resolution, so both stay reportable.
DEFAULT_RES = (160, 90)


def _res_suffix(res) -> str:
    """'' at DEFAULT_RES, else '_WxH' (file names of quality runs)."""
    return "" if tuple(res) == DEFAULT_RES else f"_{res[0]}x{res[1]}"


# Independent max_depth-0 renders per (stage, sampler) that measure the anti-aliasing floor.
AA_RENDERS = 4


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


def reference(stage: str, res: tuple[int, int], spp: int, seed: int = 987_654,
              threads: int | None = None, extra: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) bvh render with spp samples per pixel and the (H, W, 3) variance of each pixel's
    mean (from the film's per-pixel second moments; an over-estimate where the stratified pixel
    samples beat independent ones), cached in bench/out/ as .npz. The variance gives the
    reference's own relMSE (the *floor* every measurement contains, since the reference's
    noise adds to the measured error). extra: more RenderOptions (e.g. an estimator the fast
    path takes: any unbiased route renders the same image, so the cache ignores it)."""
    from renderer.render import RenderOptions, render

    os.makedirs(OUT, exist_ok=True)
    name = os.path.splitext(os.path.basename(stage))[0]
    # "v2": made after the pixel filter moved to per-pixel scrambled Sobol' samples, with the
    # variance stored beside the image (the older EXR references had no variance).
    path = os.path.join(OUT, f"ref_{name}_{res[0]}x{res[1]}_{spp}spp_v2.npz")
    if os.path.exists(path):
        z = np.load(path)
        return z["image"], z["var"]
    print(f"rendering reference {path} (bvh, {spp} spp) ...", flush=True)
    t0 = time.perf_counter()
    r = render(stage, RenderOptions(spp=spp, resolution=res, light_sampler="bvh", seed=seed, threads=threads,
                                    **(extra or {})))
    img = r.film.image().astype(np.float64)
    var = np.zeros_like(img)
    x0, y0, x1, y1 = r.film.window
    var[y0:y1, x0:x1] = r.film.variance_of_mean()
    np.savez_compressed(path, image=img, var=var)
    print(f"  done in {time.perf_counter() - t0:.0f} s", flush=True)
    return img, var


def _pixel_rel_err(img: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(H, W) per-pixel relMSE term, averaged over the channels: rel_mse(img, ref) is its mean."""
    d = img.astype(np.float64) - ref
    return np.mean(d * d / (ref * ref + REL_EPS), axis=2)


def _error_maps_png(path: str, ref: np.ndarray, images: dict, errs: dict, mask: np.ndarray) -> None:
    """One small PNG: a row per sampler (tone-mapped image | per-pixel relMSE term on a log
    scale from 1e-4 (black) to 1e2 (white)), the reference on top, emitter pixels outlined."""
    from renderer.film import write_png

    def tone(x):
        return np.clip(x / (1.0 + x), 0.0, 1.0)

    def logmap(e):
        v = np.clip((np.log10(np.maximum(e, 1e-30)) + 4.0) / 6.0, 0.0, 1.0)
        rgb = np.stack((v, v, v), axis=2)
        # Emitter-visible pixels tinted red, so one sees which error they carry.
        rgb[mask] *= np.array([1.0, 0.55, 0.55])
        return rgb

    h, w = mask.shape
    gap = np.ones((h, 4, 3))
    rows = [np.concatenate((tone(ref), gap, logmap(mask * 1e-2)), axis=1)]
    for name in images:
        rows.append(np.concatenate((tone(images[name]), gap, logmap(errs[name])), axis=1))
    sep = np.ones((4, rows[0].shape[1], 3))
    out = np.concatenate([x for r in rows for x in (r, sep)][:-1], axis=0)
    # write_png expects linear values and sRGB-encodes them: undo that so the panel shows what
    # was computed above (already display values).
    # At 1x (small enough to commit) and 2x nearest (to see single pixels).
    write_png(path.replace(".png", "_1x.png"), np.power(out, 2.2).astype(np.float32))
    out = np.repeat(np.repeat(out, 2, axis=0), 2, axis=1)
    write_png(path, np.power(out, 2.2).astype(np.float32))


def _equal_time_render(stage: str, res, sampler: str, seed: int, budget: float, threads, equal: str,
                       extra: dict | None = None):
    """One measured render of ``budget`` seconds: (RenderResult, CPU seconds of its render loop).

    The scene is loaded by a 1-spp warm-up render first (kept in a scene cache, which also
    compiles any numba kernel), so only the render loop is timed. equal='wall': the render's
    own wall-clock time_budget (what the issue says, but on a shared machine the share of a
    core a render gets varies from run to run). equal='cpu': a 2-second calibration render
    measures this sampler's passes per CPU second, and the measured render then takes the spp
    that fill ``budget`` CPU seconds (with one render thread, CPU time is the work done; the
    CPU seconds it really took are reported next to it)."""
    from renderer.render import RenderOptions, render

    cache: dict = {}
    base = dict(resolution=res, light_sampler=sampler, threads=threads, **(extra or {}))
    render(stage, RenderOptions(spp=1, seed=seed + 50_000, **base), scene_cache=cache)
    if equal == "wall":
        c0 = time.process_time()
        r = render(stage, RenderOptions(time_budget=budget, seed=seed, **base), scene_cache=cache)
        return r, time.process_time() - c0
    c0 = time.process_time()
    cal = render(stage, RenderOptions(time_budget=2.0, seed=seed + 60_000, **base), scene_cache=cache)
    per_cpu_s = cal.stats["passes_this_run"] / max(time.process_time() - c0, 1e-9)
    spp = max(1, int(round(budget * per_cpu_s)))
    c0 = time.process_time()
    r = render(stage, RenderOptions(spp=spp, seed=seed, **base), scene_cache=cache)
    return r, time.process_time() - c0


def bench_quality(stages, res, budget: float, ref_spp: int, seeds, samplers=("uniform", "power", "bvh"),
                  threads: int | None = 1, equal: str = "cpu", extra: dict | None = None) -> list[dict]:
    """Equal-time relMSE per stage, sampler and seed, with the decomposition of the error: the
    reference's floor, the share of the whole-image error sum carried by emitter-visible pixels
    and by the worst 1 % of pixels, and error maps (bench/out/light_samplers_errmaps_STAGE.png)."""
    from renderer.render import RenderOptions, render

    rows = []
    info = {}
    for name in stages:
        stage = STAGES[name]
        ref, ref_var = reference(stage, res, ref_spp, threads=threads, extra=extra)
        m = emitter_mask(stage, res)
        keep = ~m
        floor_px = np.mean(ref_var / (ref * ref + REL_EPS), axis=2)
        info[name] = {"mask_fraction": float(m.mean()), "floor": float(floor_px.mean()),
                      "floor_surfaces": float(floor_px[keep].mean()),
                      "floor_emitter_share": float(floor_px[m].sum() / max(floor_px.sum(), 1e-300))}
        images, errs = {}, {}
        # Seeds outermost, so that changing load on the machine hits every sampler alike.
        for seed in seeds:
            for sampler in samplers:
                r, cpu = _equal_time_render(stage, res, sampler, seed, budget, threads, equal, extra)
                img = r.film.image().astype(np.float64)
                ep = _pixel_rel_err(img, ref)
                e = float(ep.mean())
                e_s = float(ep[keep].mean())
                top = np.sort(ep.ravel())[::-1]
                n_top = max(1, top.size // 100)
                if seed == seeds[0]:
                    images[sampler], errs[sampler] = img, ep
                rows.append({"stage": name, "sampler": sampler, "seed": seed, "spp": r.stats["spp"],
                             "fast_path": r.stats.get("fast_path", ""),
                             "render_s": r.stats["seconds"]["render"], "cpu_s": cpu, "equal": equal,
                             "samples_per_s": r.stats["samples_per_second"], "relMSE": e,
                             "relMSE_surfaces": e_s, "relMSE_emitter_px": float(ep[m].mean()),
                             "emitter_share": float(ep[m].sum() / max(ep.sum(), 1e-300)),
                             "top1pct_share": float(top[:n_top].sum() / max(ep.sum(), 1e-300)),
                             "relMSE_x_spp": e * r.stats["spp"], "relMSE_surf_x_spp": e_s * r.stats["spp"],
                             "mean_ratio": float(img.mean() / ref.mean())})
                x = rows[-1]
                print(f"  {name:12} {sampler:8} seed {seed} ({x['fast_path']}): spp {x['spp']:4d}  relMSE {e:.4g}  surfaces {e_s:.4g}"
                      f"  emitter px {x['relMSE_emitter_px']:.4g} ({100 * x['emitter_share']:.0f} % of the sum)"
                      f"  worst 1 % px: {100 * x['top1pct_share']:.0f} %", flush=True)
        _error_maps_png(os.path.join(OUT, f"light_samplers_errmaps_{name}{_res_suffix(res)}.png"), ref, images, errs, m)
        # The anti-aliasing floor: the relMSE that emitters seen directly by camera rays add at
        # a sampler's spp, whatever the lighting service (max_depth 0 renders only them). The
        # spread of AA_RENDERS independent renders at that spp measures it without bias,
        # stratification included: each pixel's sample variance over the renders is the
        # variance of one render (several renders, because the terms are heavy-tailed).
        aa_cache: dict = {}
        for sampler in samplers:
            spp = int(np.median([r["spp"] for r in rows if r["stage"] == name and r["sampler"] == sampler]))
            aa_opt = {k: v for k, v in (extra or {}).items() if k not in ("max_depth", "fast_path")}
            ab = np.stack([render(stage, RenderOptions(spp=spp, resolution=res, max_depth=0, seed=1001 + k,
                                                       threads=threads, **aa_opt), scene_cache=aa_cache)
                           .film.image().astype(np.float64) for k in range(AA_RENDERS)])
            aa = float(np.mean(np.var(ab, axis=0, ddof=1) / (ref * ref + REL_EPS)))
            for r in rows:
                if r["stage"] == name and r["sampler"] == sampler:
                    r["aa_floor"] = aa
                    r["ref_floor"] = info[name]["floor"]
                    r["relMSE_lighting"] = r["relMSE"] - aa - info[name]["floor"]
            print(f"  {name:12} {sampler:8}: anti-aliasing floor at {spp} spp: relMSE {aa:.4g}", flush=True)
    print(f"\nrelMSE at equal {equal} time ({budget:g} s per render, {res[0]}x{res[1]}, threads {threads}, reference bvh "
          f"{ref_spp} spp; median over seeds). 'surf.': pixels that cannot see a light directly; 'emit %': "
          "share of the whole-image error sum in emitter-visible pixels; 'floor': the reference's own relMSE.")
    print(format_quality_table(rows, info, samplers))
    for r in rows:
        r.update({f"stage_{k}": v for k, v in info[r["stage"]].items()})
    return rows


def format_quality_table(rows: list[dict], info: dict, samplers=("uniform", "power", "bvh")) -> str:
    """Markdown table of the medians over seeds (rows as bench_quality returns them).

    The last three columns, relMSE x CPU s (per seed, then the median) and its ratios, put the
    samplers on exactly equal CPU time: the calibrated spp miss the budget by up to ~20 % on a
    loaded machine (the *CPU s* column), and relMSE falls as 1 / time where the reference's
    floor (which does not) is small against it (at 480x270; not quite at 160x90)."""
    keys = ("spp", "cpu_s", "relMSE", "relMSE_surfaces", "relMSE_emitter_px", "emitter_share",
            "top1pct_share", "relMSE_x_spp", "relMSE_surf_x_spp", "mean_ratio", "aa_floor", "relMSE_lighting",
            "relMSE_x_cpu")
    out = ["| stage | sampler | spp | CPU s | relMSE | uniform/x | power/x | surf. relMSE | uniform/x | "
           "power/x | emitter-px relMSE | emit % | worst 1 % px | AA floor | relMSE - floors | uniform/x | "
           "power/x | relMSE x spp | surf. x spp | mean/ref | relMSE x CPU s | uniform/x | power/x |",
           "|---|---|" + "---:|" * 21]
    for name in dict.fromkeys(r["stage"] for r in rows):
        agg = {}
        for sampler in samplers:
            sel = [r for r in rows if r["stage"] == name and r["sampler"] == sampler]
            sel = [dict(r, relMSE_x_cpu=r["relMSE"] * r["cpu_s"]) for r in sel]
            agg[sampler] = {k: float(np.median([r[k] for r in sel])) for k in keys}
        u, p = agg["uniform"], agg["power"]

        def light(a):
            """relMSE - floors and its ratios; unresolved (within the floors' noise) when <= 0."""
            x = a["relMSE_lighting"]
            if x <= 0.0:
                return "<= 0 (within the floors) | - | -"
            rat = [f"{b['relMSE_lighting'] / x:.2f}" if b["relMSE_lighting"] > 0.0 else "-" for b in (u, p)]
            return f"{x:.4g} | {rat[0]} | {rat[1]}"

        for sampler in samplers:
            a = agg[sampler]
            out.append(f"| {name} | {sampler} | {a['spp']:.0f} | {a['cpu_s']:.1f} | {a['relMSE']:.4g} | "
                       f"{u['relMSE'] / a['relMSE']:.2f} | {p['relMSE'] / a['relMSE']:.2f} | "
                       f"{a['relMSE_surfaces']:.4g} | {u['relMSE_surfaces'] / a['relMSE_surfaces']:.2f} | "
                       f"{p['relMSE_surfaces'] / a['relMSE_surfaces']:.2f} | {a['relMSE_emitter_px']:.4g} | "
                       f"{100 * a['emitter_share']:.0f} | {100 * a['top1pct_share']:.0f} % | {a['aa_floor']:.3g} | "
                       f"{light(a)} | "
                       f"{a['relMSE_x_spp']:.3g} | {a['relMSE_surf_x_spp']:.3g} | {a['mean_ratio']:.3f} | "
                       f"{a['relMSE_x_cpu']:.3g} | {u['relMSE_x_cpu'] / a['relMSE_x_cpu']:.2f} | "
                       f"{p['relMSE_x_cpu'] / a['relMSE_x_cpu']:.2f} |")
        i = info[name]
        out.append(f"| {name} | *reference floor* | | | {i['floor']:.3g} | | | {i['floor_surfaces']:.3g} | | | | "
                   f"{100 * i['floor_emitter_share']:.0f} | | | | | | | | | | | |")
    return "\n".join(out)


# ----------------------------------------------------------------------------------------
# 3. pick: the exact variance of the light choice at the camera's first hits
# ----------------------------------------------------------------------------------------
def first_hits(stage: str, res: tuple[int, int], stride: int = 1):
    """Camera first hits through the centres of every stride-th pixel (both axes):
    (ShadingContext of the hits, their (H, W) pixel rows/cols, the LightSet)."""
    from renderer.camera import Camera
    from renderer.geometry import surface_interaction
    from renderer.lights.base import ShadingContext
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    w, h = res
    desc = load_stage(stage)
    st = desc.settings
    scene = build_scene(desc, threads=1, light_sampler="uniform")
    cam = Camera(scene.desc.camera, w, h, st.pixel_aspect_ratio, st.aspect_ratio_conform_policy)
    ys, xs = np.mgrid[0:h:stride, 0:w:stride]
    n = xs.size
    rays = cam.generate(xs.ravel(), ys.ravel(), np.full((n, 2), 0.5), np.full((n, 2), 0.5))
    hits = scene.accel.intersect(rays.o, rays.d)
    ok = np.nonzero(hits.hit)[0]
    g = scene.geometry
    p, ng, ns, _ = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, hits.prim[ok], hits.b1[ok],
                                       hits.b2[ok], rays.d[ok])
    lights = scene.lights
    scene.close()
    return ShadingContext(p, ng, ns), ys.ravel()[ok], xs.ravel()[ok], lights


def bench_pick(stages, res, stride: int, samplers=("uniform", "power", "bvh"), chunk_rows: int = 400_000) -> list[dict]:
    """Exact variance of the light *choice* (unshadowed, noise-free: no sampling of it at all).

    At each camera first hit x with irradiance E_i from light i (exact, unshadowed, about the
    shading normal; lights.irradiance) and E = sum E_i, a one-light estimate E_i / pmf_i has
    relative variance  V = sum_i E_i^2 / pmf_i / E^2 - 1  (0 for pmf_i = E_i / E, the ideal
    sampler). This is the part of the noise that the lighting service decides; visibility, the
    BSDF and the sampling inside a light come on top and are the same for every sampler.

    Reported per sampler: mean V over points weighted by ref^2 / (ref^2 + eps) (how relMSE
    weighs a pixel; ref = the cached reference's pixel luminance, 1 without one), median and
    99th percentile of V; 'missed': the share of E from lights with pmf 0 (must be 0:
    bias); and the *tail*: the share of sum E_i^2 / pmf_i from lights picked more than 10x
    less often than their share of E (r = E_i / (E pmf_i) > 10), split by how close the light is
    (distance to its centre over its bounding radius: < 3, 3-30, > 30).
    """
    from renderer.color import luminance
    from renderer.light_samplers import make_light_sampler
    from renderer.light_samplers.bvh import light_bounds
    from renderer.lights.base import ShadingContext

    rows_out = []
    for name in stages:
        stage = STAGES[name]
        ctx, py, px, lights = first_hits(stage, tuple(res), stride)
        k = lights.count
        npts = ctx.p.shape[0]
        ref_path = os.path.join(OUT, f"ref_{name}_{res[0]}x{res[1]}_2048spp_v2.npz")
        if os.path.exists(ref_path):
            ref = luminance(np.load(ref_path)["image"][py, px])
            wgt = ref * ref / (ref * ref + REL_EPS)
        else:
            wgt = np.ones(npts)
        b = light_bounds(lights)
        cen = np.zeros((k, 3))
        rad = np.full(k, np.inf)
        cen[b.light] = 0.5 * (b.lo + b.hi)
        rad[b.light] = np.maximum(0.5 * np.linalg.norm(b.hi - b.lo, axis=1), 1e-12)
        smp = {s: make_light_sampler(s, lights) for s in samplers}
        t0 = time.perf_counter()
        per = max(1, chunk_rows // k)
        E_tot = np.zeros(npts)
        M2 = {s: np.zeros(npts) for s in samplers}
        missed = {s: np.zeros(npts) for s in samplers}
        tail = {s: np.zeros((npts, 3)) for s in samplers}
        for a in range(0, npts, per):
            pts = np.arange(a, min(npts, a + per))
            pi = np.repeat(pts, k)
            li = np.tile(np.arange(k), pts.size)
            c = ShadingContext(ctx.p[pi], ctx.n[pi], ctx.ns[pi])
            Ei = luminance(lights.irradiance(li, c)[0]).reshape(pts.size, k)
            Ei = np.maximum(Ei, 0.0)
            E = Ei.sum(axis=1)
            E_tot[pts] = E
            dist = np.linalg.norm(ctx.p[pi] - cen[li], axis=1).reshape(pts.size, k) / rad[None, :]
            near = np.digitize(dist, [3.0, 30.0])            # 0: < 3 radii, 1: 3-30, 2: > 30
            for s in samplers:
                pm = smp[s].pmf(c, li).reshape(pts.size, k)
                pos = pm > 0.0
                contrib = np.where(pos, Ei * Ei / np.where(pos, pm, 1.0), 0.0)
                M2[s][pts] = contrib.sum(axis=1)
                missed[s][pts] = np.where(pos, 0.0, Ei).sum(axis=1)
                r = np.where(pos, Ei / np.maximum(E[:, None], 1e-300) / np.where(pos, pm, 1.0), 0.0)
                big = r > 10.0
                for j in range(3):
                    tail[s][pts, j] = np.where(big & (near == j), contrib, 0.0).sum(axis=1)
        lit = E_tot > 0.0
        print(f"\n{name}: {npts} first hits ({lit.sum()} lit), {k} lights, {time.perf_counter() - t0:.0f} s")
        print(f"{'sampler':>8} {'V (wtd)':>9} {'V med':>8} {'V p99':>9} {'missed':>8} "
              f"{'tail<3r':>8} {'3-30r':>7} {'>30r':>7}")
        for s in samplers:
            V = M2[s][lit] / E_tot[lit] ** 2 - 1.0
            wl = wgt[lit]
            tail_share = tail[s][lit].sum(axis=0) / max(M2[s][lit].sum(), 1e-300)
            row = {"stage": name, "sampler": s, "points": int(lit.sum()),
                   "V_weighted": float(np.sum(V * wl) / max(wl.sum(), 1e-300)),
                   "V_median": float(np.median(V)), "V_p99": float(np.percentile(V, 99)),
                   "missed_share": float(missed[s][lit].sum() / E_tot[lit].sum()),
                   "tail_near": float(tail_share[0]), "tail_mid": float(tail_share[1]),
                   "tail_far": float(tail_share[2])}
            rows_out.append(row)
            print(f"{s:>8} {row['V_weighted']:>9.4g} {row['V_median']:>8.4g} {row['V_p99']:>9.4g} "
                  f"{row['missed_share']:>8.2g} {100 * row['tail_near']:>7.1f}% {100 * row['tail_mid']:>6.1f}% "
                  f"{100 * row['tail_far']:>6.1f}%")
    return rows_out


# ----------------------------------------------------------------------------------------
# 4. throughput (interleaved against a baseline tree) and profile
# ----------------------------------------------------------------------------------------
_THROUGHPUT_CHILD = """
import json, os, sys, time
tree, stage, w, h, budget, sampler, depth, extra = sys.argv[1:9]
sys.path.insert(0, tree)
os.chdir(tree)
import renderer
assert os.path.abspath(renderer.__file__).startswith(os.path.abspath(tree)), renderer.__file__
from renderer.render import RenderOptions, render
cache = {}
opt = dict(resolution=(int(w), int(h)), threads=1, max_depth=int(depth), light_sampler=sampler, **json.loads(extra))
render(stage, RenderOptions(spp=2, seed=99, **opt), scene_cache=cache)   # warm-up: numba, lazy tables
c0 = time.process_time()
r = render(stage, RenderOptions(time_budget=float(budget), seed=1, **opt), scene_cache=cache)
cpu = time.process_time() - c0
w, h = r.film.shape[1], r.film.shape[0]
print(json.dumps({"samples_per_s": r.stats["samples_per_second"], "spp": r.stats["spp"],
                  "fast_path": r.stats.get("fast_path", ""),
                  "samples_per_cpu_s": r.stats["passes_this_run"] * w * h / cpu,
                  "mrays_per_s": r.stats["mrays_per_second"], "render_s": r.stats["seconds"]["render"]}))
"""


def bench_throughput(stage_names, res, budget: float, rounds: int, samplers, baseline: str | None,
                     max_depth: int = 8, current: str = ROOT, extra: dict | None = None,
                     paths=("default",)) -> list[dict]:
    """samples/s of render() (threads 1, max depth 8, after a warm-up render), for the current
    tree (this one, or ``current``) and optionally a baseline tree (e.g. ``git archive REV | tar
    -x -C /tmp/base``), each run in its own process, alternating current / baseline (order
    flipped every round) so that load from other processes on the machine hits both alike.
    Both render this tree's stage files. samples/s is by wall time (what render() reports) and
    by the process's CPU time (with one render thread, the work done; less sensitive to the
    other jobs on a shared machine). extra: more RenderOptions for every render (e.g. the
    estimator); paths: 'fast' and / or 'general' (fast_path True / False) measured as separate
    trees of the same source, alternated like a baseline, or 'default' (the render's own
    choice)."""
    import subprocess

    trees = [("current", os.path.abspath(current))] + ([("baseline", os.path.abspath(baseline))] if baseline else [])
    if tuple(paths) != ("default",):
        trees = [(f"{label}/{p}", tree) for label, tree in trees for p in paths]
    rows = []
    for rnd in range(rounds):
        for name in stage_names:
            for sampler in samplers:
                for label, tree in (trees if rnd % 2 == 0 else trees[::-1]):
                    opt = dict(extra or {})
                    if label.endswith("/fast") or label.endswith("/general"):
                        opt["fast_path"] = label.endswith("/fast")
                    out = subprocess.run([sys.executable, "-c", _THROUGHPUT_CHILD, tree, STAGES[name], str(res[0]),
                                          str(res[1]), str(budget), sampler, str(max_depth), json.dumps(opt)],
                                         capture_output=True, text=True, check=True)
                    r = json.loads(out.stdout.strip().splitlines()[-1])
                    r.update({"tree": label, "stage": name, "sampler": sampler, "round": rnd,
                              "load_avg_1min": os.getloadavg()[0]})
                    rows.append(r)
                    print(f"  round {rnd} {name:12} {sampler:8} {label:8} ({r['fast_path']}): "
                          f"{r['samples_per_s']:9.0f} samples/s "
                          f"({r['samples_per_cpu_s']:.0f} per CPU s) "
                          f"({r['spp']} spp, {r['mrays_per_s']:.3f} Mrays/s, load {r['load_avg_1min']:.2f})",
                          flush=True)
    print(f"\nsamples/s, median over {rounds} rounds ({res[0]}x{res[1]}, {budget:g} s, threads 1, "
          f"max depth {max_depth}{', ' + json.dumps(extra) if extra else ''})")
    print(format_throughput_table(rows))
    return rows


def format_throughput_table(rows: list[dict]) -> str:
    """Markdown: median samples/s per stage, sampler and tree, by wall and by CPU time."""
    trees = list(dict.fromkeys(r["tree"] for r in rows))
    both = "baseline" in trees
    head = "| stage | sampler | " + " | ".join(f"{t} samples/s (wall) | {t} samples/CPU s" for t in trees)
    head += " | current / baseline (wall) | (CPU) |" if both else " |"
    out = [head, "|---|---|" + "---:|" * (2 * len(trees) + 2 * both)]
    for name in dict.fromkeys(r["stage"] for r in rows):
        for sampler in dict.fromkeys(r["sampler"] for r in rows):
            def med(t, k):
                return float(np.median([r[k] for r in rows if r["tree"] == t and r["stage"] == name
                                        and r["sampler"] == sampler]))
            line = f"| {name} | {sampler} | " + " | ".join(
                f"{med(t, 'samples_per_s'):.0f} | {med(t, 'samples_per_cpu_s'):.0f}" for t in trees)
            if both:
                line += (f" | {med('current', 'samples_per_s') / med('baseline', 'samples_per_s'):.2f}x"
                         f" | {med('current', 'samples_per_cpu_s') / med('baseline', 'samples_per_cpu_s'):.2f}x |")
            else:
                line += " |"
            out.append(line)
    return "\n".join(out)


def bench_profile(name: str, res, budget: float, sampler: str, top: int = 25) -> str:
    """cProfile of one render() (after a warm-up render with the scene cached, so only the
    render loop is profiled); returns the top functions by own time and by cumulative time."""
    import cProfile
    import io
    import pstats

    from renderer.render import RenderOptions, render

    cache = {}
    opt = dict(resolution=tuple(res), threads=1, max_depth=8, light_sampler=sampler)
    render(STAGES[name], RenderOptions(spp=2, seed=99, **opt), scene_cache=cache)
    pr = cProfile.Profile()
    pr.enable()
    r = render(STAGES[name], RenderOptions(time_budget=budget, seed=1, **opt), scene_cache=cache)
    pr.disable()
    buf = io.StringIO()
    buf.write(f"{name} {sampler}: {r.stats['spp']} spp in {r.stats['seconds']['render']:.2f} s, "
              f"{r.stats['samples_per_second']:.0f} samples/s (under cProfile)\n")
    ps = pstats.Stats(pr, stream=buf)
    ps.sort_stats("tottime").print_stats(top)
    ps.sort_stats("cumtime").print_stats(top)
    text = buf.getvalue().replace(ROOT + "/", "")
    print(text)
    return text


# ----------------------------------------------------------------------------------------
# 5. report: the committed summary
# ----------------------------------------------------------------------------------------
RESULTS = os.path.join(ROOT, "bench", "results", "light_samplers")


def _load(what: str):
    path = os.path.join(OUT, f"light_samplers_{what}.json")
    if not os.path.exists(path):
        return None
    with open(path) as fh:
        return json.load(fh)


def _load_line(rep: dict) -> str:
    m = rep["machine"]
    return (f"Machine: {m['cpus']} CPUs, load average (1, 5, 15 min) before "
            f"{', '.join(f'{x:.2f}' for x in m['load_avg_before'])}, after "
            f"{', '.join(f'{x:.2f}' for x in m.get('load_avg_after', []))}.")


def write_report() -> str:
    """bench/results/light_samplers/results.md from the JSON files the other modes left in
    bench/out/ (each section starts with the exact command that made it), plus the fireflies
    error maps (one small PNG)."""
    import shutil

    os.makedirs(RESULTS, exist_ok=True)
    L = ["# Lighting services: results", "",
         "Made by `bench/bench_light_samplers.py` (its docstring explains every column); this file by "
         "`.venv/bin/python bench/bench_light_samplers.py report` from the JSON files the runs below left in "
         "`bench/out/`. Wall-clock budgets on a shared 2-core machine: the load average is given with each run.", ""]
    # Quality runs: the stages' own resolution first (the honest whole-image number), then the
    # bench's default 160x90 (cheaper references; emitter pixels weigh more there).
    pre = "light_samplers_quality_"
    extra = sorted((f[len("light_samplers_"):-len(".json")] for f in os.listdir(OUT)
                    if f.startswith(pre) and f.endswith(".json") and f[len(pre):][:1].isdigit()),
                   key=lambda k: (k.split("_")[1], [i for i, st in enumerate(STAGES) if st in k][:1]))
    for key in extra + ["quality"]:
        q = _load(key)
        if not q:
            continue
        res = tuple(q.get("res", DEFAULT_RES))
        role = ("the stages' own resolution" if res == (480, 270) else
                "secondary: the bench's default resolution" if res == DEFAULT_RES else "")
        rows = q["quality"]
        stages = list(dict.fromkeys(r["stage"] for r in rows))
        L += [f"## relMSE at equal time, {res[0]}x{res[1]}" + (f" ({role})" if role else "")
              + (f": {', '.join(stages)}" if res != DEFAULT_RES else ""), "",
              f"    .venv/bin/python {q['command']}", "", _load_line(q), ""]
        if q.get("uptime"):
            L += [f"`uptime` before the run: {q['uptime']}", ""]
        info = {r["stage"]: {"floor": r["stage_floor"], "floor_surfaces": r["stage_floor_surfaces"],
                             "floor_emitter_share": r["stage_floor_emitter_share"]} for r in rows}
        masks = ", ".join(f"{k} {100 * r['stage_mask_fraction']:.0f} %" for k, r in
                          {r["stage"]: r for r in rows}.items())
        L += [format_quality_table(rows, info), "",
              f"Medians over seeds. *surf.*: pixels that cannot see a light directly (emitter_mask; the others, "
              f"emitter-visible, are {masks} of the image); "
              "*emit %*: share of the whole-image error sum in the emitter-visible pixels; *AA floor*: "
              f"relMSE of the emitters seen directly at that spp (max_depth 0, the spread of {AA_RENDERS} independent "
              "renders; heavy-tailed, so only indicative), which no lighting service changes; *relMSE - floors*: "
              "relMSE less the AA floor and the reference's own floor, the part the lighting service decides "
              "(unresolved where the floors take it all). *relMSE x spp*: per-sample error. *relMSE x CPU s*: the "
              "error at exactly equal CPU time (the calibrated spp miss the budget by up to ~20 % on a loaded "
              "machine, see *CPU s*), with its ratios. The reference is bvh "
              f"at {q.get('ref_spp', 2048)} spp; *mean/ref* checks bias. Equal CPU time: each render's spp is "
              "calibrated to fill the budget in CPU seconds (a 2 s calibration render per sampler); *CPU s* is what "
              "it took.", ""]
        suffix = _res_suffix(res)
        if "fireflies" not in stages:
            continue
        png = os.path.join(OUT, f"light_samplers_errmaps_fireflies{suffix}_1x.png")
        png2 = os.path.join(OUT, f"light_samplers_errmaps_fireflies{suffix}.png")
        if not os.path.exists(png) and os.path.exists(png2):
            import OpenImageIO as oiio

            buf = oiio.ImageBuf(png2)
            px = buf.get_pixels(oiio.UINT8)[::2, ::2]
            out = oiio.ImageOutput.create(png)
            out.open(png, oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], oiio.UINT8))
            out.write_image(np.ascontiguousarray(px))
            out.close()
        if os.path.exists(png) and os.path.getsize(png) > 400_000:
            L += [f"Error maps: `bench/out/{os.path.basename(png)}` (too large to commit).", ""]
        elif os.path.exists(png):
            shutil.copy(png, os.path.join(RESULTS, f"errmaps_fireflies{suffix}.png"))
            L += [f"![per-pixel error, fireflies](errmaps_fireflies{suffix}.png)", "",
                  "Fireflies, first seed: reference and emitter mask (top), then uniform, power, bvh: the image "
                  "(tone-mapped) and its per-pixel relMSE term on a log scale from 1e-4 (black) to 1e2 (white); "
                  "emitter-visible pixels tinted red.", ""]
    pk = _load("pick")
    if pk:
        L += ["## Variance of the light choice at the camera's first hits (noise-free)", "",
              f"    .venv/bin/python {pk['command']}", "",
              "| stage | sampler | points | V (weighted) | V median | V p99 | missed | tail: < 3 r | 3-30 r | > 30 r |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in pk["pick"]:
            L.append(f"| {r['stage']} | {r['sampler']} | {r['points']} | {r['V_weighted']:.3g} | {r['V_median']:.3g} | "
                     f"{r['V_p99']:.3g} | {r['missed_share']:.2g} | {100 * r['tail_near']:.0f} % | "
                     f"{100 * r['tail_mid']:.0f} % | {100 * r['tail_far']:.0f} % |")
        pb = _load("pick_baseline")
        if pb:
            for r in pb["pick"]:
                L.append(f"| {r['stage']} | {r['sampler']} (baseline) | {r['points']} | {r['V_weighted']:.3g} | "
                         f"{r['V_median']:.3g} | {r['V_p99']:.3g} | {r['missed_share']:.2g} | "
                         f"{100 * r['tail_near']:.0f} % | {100 * r['tail_mid']:.0f} % | {100 * r['tail_far']:.0f} % |")
            L += ["", f"*(baseline)*: the same command run in the baseline tree (`{pb['command']}`), i.e. the BVH "
                  "with the d^2 clamp at the full squared bounding radius."]
        L += ["", "V = sum_i E_i^2 / pmf_i / E^2 - 1, the relative variance of a one-light estimate of the unoccluded "
              "irradiance E = sum_i E_i (exact per light); weighted by ref^2 / (ref^2 + 0.01) as relMSE weighs a pixel. "
              "*tail*: share of sum E_i^2 / pmf_i from lights picked > 10x less often than their share of E, by "
              "distance in bounding radii.", ""]
    b = _load("build")
    if b:
        L += ["## BVH build and pick cost", "", f"    .venv/bin/python {b['command']}", "", _load_line(b), "",
              "| lights | source | build wall s | build CPU s | tree MB | build peak MB | depth | sample us/row | pmf us/row |",
              "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in b["build"]:
            L.append(f"| {r['lights']} | {r['source']} | {r['build_wall_s']:.3f} | {r['build_cpu_s']:.3f} | "
                     f"{r['tree_MB']:.2f} | {r['build_peak_MB']:.1f} | {r['depth']} | {r['sample_us_per_row']:.2f} | "
                     f"{r['pmf_us_per_row']:.2f} |")
        L += ["", "Best of 3 builds; memory: the tree and replay data (`memory_bytes`) and the peak allocation "
              "during a build (tracemalloc); pick cost in CPU time over a batch of 100k random points.", ""]
    t = _load("throughput")
    if t:
        L += ["## Render throughput, before / after", "", f"    .venv/bin/python {t['command']}", "", _load_line(t), "",
              format_throughput_table(t["throughput"]), "",
              "Each figure is the median over rounds of one render() process each (160x90, 8 s, threads 1, max depth 8, "
              "after a warm-up render), current and baseline alternating. "
              + (t.get("note") or "The trees are named in the command (`--current`, `--baseline`); once committed, "
                 "`git archive <commit before> | tar -x -C /tmp/base` and `--baseline /tmp/base` reproduce it."), ""]
    for key, title in (("profile_baseline", "baseline tree, the command run there"), ("profile", "current")):
        pr = _load(key)
        if pr:
            L += [f"## Profile ({title})", "", f"    .venv/bin/python {pr['command']}", "", _load_line(pr), ""]
            for sampler, text in pr["profile"].items():
                lines = text.splitlines()
                head = [ln for ln in lines[:1]]
                body = []
                for i, ln in enumerate(lines):
                    if "Ordered by: internal time" in ln:
                        body = [x for x in lines[i + 3:i + 3 + 14] if x.strip()]
                        break
                L += ["```", *head, *body, "```", ""]
    text = "\n".join(L)
    with open(os.path.join(RESULTS, "results.md"), "w") as fh:
        fh.write(text)
    print(text)
    return text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", nargs="?", choices=["build", "quality", "pick", "throughput", "profile", "report", "all"],
                    default="all")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stages", nargs="+", default=DEFAULT_STAGES, choices=list(STAGES))
    ap.add_argument("--samplers", nargs="+", default=["uniform", "power", "bvh"])
    ap.add_argument("--res", type=int, nargs=2, default=list(DEFAULT_RES))
    ap.add_argument("--budget", type=float, default=30.0, help="seconds of rendering per sampler and seed")
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--threads", type=int, default=1, help="render threads (quality, reference)")
    ap.add_argument("--equal", choices=["cpu", "wall"], default="cpu",
                    help="quality: equal CPU time (calibrated spp; default) or the render's wall-clock budget")
    ap.add_argument("--stride", type=int, default=2, help="pick: every stride-th pixel centre")
    ap.add_argument("--rounds", type=int, default=3, help="throughput: alternations")
    ap.add_argument("--baseline", default=None, help="throughput: another source tree to compare with")
    ap.add_argument("--current", default=ROOT, help="throughput: the tree measured as 'current' (default: this one)")
    ap.add_argument("--note", default="", help="throughput: what the trees are (printed in the report)")
    ap.add_argument("--max-depth", type=int, default=8, help="throughput: max depth")
    ap.add_argument("--paths", nargs="+", default=["default"], choices=["default", "fast", "general"],
                    help="throughput: measure the fast path and / or the general one (fast_path on / off)")
    ap.add_argument("--extra", default="{}",
                    help='quality, throughput: more RenderOptions as JSON, e.g. \'{"estimator": {"": "mis"}}\'')
    args = ap.parse_args(argv)
    if args.what == "report":
        write_report()
        return
    report = {"command": " ".join(["bench/bench_light_samplers.py"] + list(argv if argv is not None else sys.argv[1:])),
              "machine": {"cpus": os.cpu_count(), "load_avg_before": os.getloadavg()}, "note": args.note}
    try:   # `uptime` as the shell prints it (load and how long the machine has been busy)
        import subprocess

        report["uptime"] = subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    if args.what in ("build", "all"):
        report["build"] = bench_build(tuple(args.sizes), args.repeats)
    if args.what in ("quality", "all"):
        report["quality"] = bench_quality(args.stages, tuple(args.res), args.budget, args.ref_spp, args.seeds,
                                          tuple(args.samplers), args.threads, args.equal, json.loads(args.extra))
        report["res"], report["ref_spp"] = list(args.res), args.ref_spp
    if args.what == "pick":
        report["pick"] = bench_pick(args.stages, tuple(args.res), args.stride, tuple(args.samplers))
    if args.what == "throughput":
        report["throughput"] = bench_throughput(args.stages, tuple(args.res), args.budget, args.rounds,
                                                tuple(args.samplers), args.baseline, args.max_depth,
                                                current=args.current, extra=json.loads(args.extra),
                                                paths=args.paths)
    if args.what == "profile":
        report["profile"] = {s: bench_profile(args.stages[0], args.res, args.budget, s) for s in args.samplers}
    report["machine"]["load_avg_after"] = os.getloadavg()
    os.makedirs(OUT, exist_ok=True)
    suffix = ""
    if args.what == "quality":
        # Runs at another resolution, or of a subset of the stages, keep their own file.
        suffix = _res_suffix(args.res)
        if list(args.stages) != DEFAULT_STAGES:
            suffix += "_" + "_".join(args.stages)
    path = os.path.join(OUT, f"light_samplers_{args.what}{suffix}.json")
    with open(path, "w") as fh:
        json.dump(report, fh, indent=1)
    print(f"\nload average before {report['machine']['load_avg_before']}, after {report['machine']['load_avg_after']}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
