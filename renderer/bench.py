"""`illum bench`: equal-time error benchmark of direct-lighting estimators and light samplers.

For every stage and configuration (an estimator token, optionally with a control-variate alpha,
crossed with an optional light sampler) the bench renders at each time budget through the same
``render()`` entry point as ``illum render`` and measures the error against a reference:

* RMSE   = sqrt( mean over pixels and channels of (x - ref)^2 );
* relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + EPS), EPS = 1e-2.

relMSE is the usual "relative MSE" of the rendering literature (e.g. Rousselle et al. 2011,
Müller et al. 2017). EPS keeps black reference pixels from dividing by zero; with 1e-2 a pixel
darker than ~0.1 is judged on its absolute error, a brighter one on its relative error.
Efficiency = 1 / (relMSE * seconds), with the *measured* render seconds (load and BVH build
excluded, as in ``stats["seconds"]["render"]``), so a configuration that overshoots its budget
by part of a pass is charged for it. Higher is better; at equal time it is simply 1/relMSE.
The budgets are wall-clock seconds (``time_budget``); on a shared machine the CPU share a run
gets varies, so the bench also records the process CPU seconds of every render
(``time.process_time``, all threads) and ``efficiency_cpu`` = 1 / (relMSE * CPU seconds), the
fairer cost when other jobs compete for the cores.

The reference is either ``--reference REF.exr`` or a high-spp render that the bench makes itself
(``--reference-estimator``, default MIS, ``--reference-spp`` samples per pixel) and caches in
``OUT/references/``. The cache key hashes the *content* of the stage and of every file it
depends on (sublayers, references, textures: ``UsdUtils.ComputeAllDependencies``), the
resolution, the max depth and the reference's own settings (estimator, light samples, light
sampler, spp, seed); editing the stage or a texture therefore makes a new reference, moving it
does not. Delete ``OUT/references`` after changing the renderer itself.

Seeds are fixed: every measured render uses ``--seed`` (common random numbers across
configurations), the reference uses a different seed so that its noise is independent of the
measured images. ``--repeats R`` renders every (config, budget) R times with seeds seed..seed+R-1,
interleaved (repeat, budget, config), and the tables report medians and the range of each
repeat's ratio to MIS. The reference's own noise adds its variance to every measured MSE; results.md
reports that *floor* so one can tell when a measurement is close to it. The reference is rendered
as two independent halves (seeds s and s + 1) and merged; the floor is measured from their
difference (``split_half_floor``), not from the film's per-pixel variance estimate, which
heavy-tailed pixels make far too small.

``--raw-throughput`` adds a section comparing raw embree (``accel.raw_throughput_probe``) on the
first stage's camera rays and one bounce of cosine-distributed rays against our ``Accel.intersect``
wrapper on the same batches and against ``render()``'s end-to-end Mrays/s.

Outputs in ``--out`` (default ``bench/out``): ``results.csv``, ``results.md`` and
``error_vs_time.png`` (log-log relMSE vs seconds, one panel per stage, one curve per config).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .errors import SettingsError

__all__ = [
    "EPS",
    "BenchConfig",
    "BenchSettings",
    "rmse",
    "relmse",
    "parse_configs",
    "stage_content_hash",
    "reference_key",
    "get_reference",
    "run_bench",
    "raw_throughput",
    "machine_info",
    "register_cli",
]

EPS = 1e-2
DEFAULT_OUT = os.path.join("bench", "out")
DEFAULT_ESTIMATORS = "mis,lightSampling,bsdfSampling,controlVariate"
# The reference seed is offset from the measured renders' seed so their noise is independent.
REFERENCE_SEED_OFFSET = 7919
CSV_FIELDS = [
    "stage", "config", "estimator", "cv_alpha", "light_sampler", "light_samples", "budget_s", "seconds",
    "cpu_seconds", "spp", "samples_per_second", "mrays_per_second", "rmse", "relmse", "efficiency",
    "efficiency_cpu", "negative_pixels", "width",
    "height", "max_depth", "seed", "reference", "reference_floor_relmse", "repeat", "auto_choice",
    "pilot_cpu_seconds",
]


# ---------------------------------------------------------------------------------- metrics
def _check_shapes(img: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(img, dtype=np.float64)
    b = np.asarray(ref, dtype=np.float64)
    if a.shape != b.shape:
        raise SettingsError(f"image {a.shape} and reference {b.shape} differ in size", attribute="reference")
    return a, b


def rmse(img: np.ndarray, ref: np.ndarray) -> float:
    """Root mean squared error over all pixels and channels. img, ref: same shape, e.g. (h, w, 3)."""
    a, b = _check_shapes(img, ref)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def relmse(img: np.ndarray, ref: np.ndarray, eps: float = EPS) -> float:
    """Relative MSE: mean over pixels and channels of (img - ref)^2 / (ref^2 + eps)."""
    a, b = _check_shapes(img, ref)
    return float(np.mean((a - b) ** 2 / (b * b + eps)))


def relmse_floor(ref: np.ndarray, var_of_mean: np.ndarray, eps: float = EPS) -> float:
    """Expected relMSE that a noisy reference adds to every measurement: mean of Var[ref]/(ref^2+eps)."""
    r = np.asarray(ref, dtype=np.float64)
    return float(np.mean(np.asarray(var_of_mean, dtype=np.float64) / (r * r + eps)))


def split_half_floor(half_a: np.ndarray, half_b: np.ndarray, ref: np.ndarray, eps: float = EPS) -> float:
    """The relMSE a reference made of two independent halves adds to every measurement, measured
    rather than modelled: E[(a - b)^2] = 2 Var[half] = 4 Var[ref] for ref = (a + b) / 2, so the
    floor is mean((a - b)^2 / 4 / (ref^2 + eps)). Unlike relmse_floor it needs no per-pixel
    variance estimate, which heavy-tailed pixels (a few rare, very bright samples) make far too
    small: on stages/many_lights a 512-spp reference's variance floor was 0.00093 while two such
    references differed by relMSE 0.0207."""
    a, b = _check_shapes(half_a, half_b)
    r = np.asarray(ref, dtype=np.float64)
    return float(np.mean((a - b) ** 2 / 4.0 / (r * r + eps)))


def efficiency(rel: float, seconds: float) -> float:
    """1 / (relMSE * seconds); inf for an exact image (relMSE 0)."""
    d = rel * seconds
    return math.inf if d <= 0.0 else 1.0 / d


# ---------------------------------------------------------------------------------- configs
@dataclass(frozen=True)
class BenchConfig:
    """One configuration under test. None means "as the stage authors it" (no override).

    estimator: an illum:estimator token; cv_alpha: an illum:cv:alpha token;
    light_sampler: a lighting-service name (uniform, power, bvh, exhaustive, auto).
    """

    estimator: Optional[str] = None
    cv_alpha: Optional[str] = None
    light_sampler: Optional[str] = None

    @property
    def label(self) -> str:
        name = self.estimator or "stage"
        if self.cv_alpha:
            name += f":{self.cv_alpha}"
        if self.light_sampler:
            name += f"@{self.light_sampler}"
        return name


def parse_configs(estimators: str | None, light_samplers: str | None = None) -> list[BenchConfig]:
    """Configurations from the comma lists of --estimators and --light-samplers (their product).

    Estimator items are TOKEN or TOKEN:ALPHA (e.g. controlVariate:averageVisibilityUnbiased);
    'stage' means the stage's own IllumLightAPI opinions. Raises SettingsError on unknown tokens.
    """
    from .estimators import ALPHAS, TOKENS
    from .light_samplers import SAMPLERS

    ests: list[tuple[Optional[str], Optional[str]]] = []
    for item in _split(estimators) or [None]:
        if item is None or item == "stage":
            ests.append((None, None))
            continue
        token, _, alpha = item.partition(":")
        if token not in TOKENS:
            raise SettingsError(f"{token!r} is not one of stage, {', '.join(TOKENS)}", attribute="estimators")
        if alpha and alpha not in ALPHAS:
            raise SettingsError(f"{alpha!r} is not one of {', '.join(ALPHAS)}", attribute="estimators")
        if alpha and token != "controlVariate":
            raise SettingsError(f"an alpha only applies to controlVariate, got {item!r}", attribute="estimators")
        ests.append((token, alpha or None))
    samplers: list[Optional[str]] = []
    for item in _split(light_samplers) or [None]:
        if item is not None and item not in SAMPLERS and item != "auto":
            raise SettingsError(f"{item!r} is not one of auto, {', '.join(sorted(SAMPLERS))}",
                                attribute="light-samplers")
        samplers.append(item)
    out = [BenchConfig(e, a, s) for e, a in ests for s in samplers]
    labels = [c.label for c in out]
    if len(set(labels)) != len(labels):
        raise SettingsError(f"configurations repeat: {', '.join(labels)}", attribute="estimators")
    return out


def _split(s: str | None) -> list[str]:
    return [x.strip() for x in (s or "").split(",") if x.strip()]


def parse_budgets(s: str) -> list[float]:
    out = []
    for item in _split(s):
        try:
            v = float(item)
        except ValueError:
            raise SettingsError(f"{item!r} is not a number of seconds", attribute="budgets") from None
        if not (math.isfinite(v) and v > 0):
            raise SettingsError(f"budget {item!r} must be a positive number of seconds", attribute="budgets")
        out.append(v)
    if not out:
        raise SettingsError("no time budget given", attribute="budgets")
    return sorted(set(out))


@dataclass
class BenchSettings:
    """Everything but the stages. resolution None: each stage's RenderSettings resolution."""

    configs: list[BenchConfig] = field(default_factory=lambda: parse_configs(DEFAULT_ESTIMATORS))
    budgets: list[float] = field(default_factory=lambda: [1.0, 4.0, 16.0])
    out: str = DEFAULT_OUT
    resolution: Optional[tuple[int, int]] = None
    max_depth: int = 8
    seed: int = 0
    threads: Optional[int] = None
    light_samples: Optional[int] = None
    reference: Optional[str] = None
    reference_spp: int = 1024
    reference_estimator: str = "mis"
    raw_throughput: bool = False
    raw_max_depth: int = 8
    raw_seconds: float = 3.0
    # Independent repeats of every (config, budget) (seed + repeat), interleaved: each repeat runs
    # every config at one budget back to back, so they share the machine's load of the moment.
    repeats: int = 1
    command: str = ""
    log: Callable[[str], None] = field(default=lambda msg: None, repr=False)


# ---------------------------------------------------------------------------------- references
def stage_content_hash(stage_path: str) -> str:
    """sha256 over the contents of the stage and every file it depends on (layers and assets).

    The digests are sorted, so the hash depends on what the files hold, not where they are.
    """
    from .usd.dependencies import stage_dependencies

    files, unresolved = stage_dependencies(stage_path)
    digests = []
    for f in files:
        if os.path.isfile(f):
            with open(f, "rb") as fh:
                digests.append(hashlib.sha256(fh.read()).hexdigest())
    h = hashlib.sha256()
    for d in sorted(digests):
        h.update(d.encode())
    # A missing dependency still changes the key (by name), so fixing it makes a new reference.
    for u in sorted(unresolved):
        h.update(b"unresolved:" + u.encode())
    return h.hexdigest()


def reference_key(content_hash: str, resolution: tuple[int, int], max_depth: int, settings: dict) -> str:
    """Cache key of a reference: 20 hex digits of sha256 over the stage content hash, the
    resolution, the max depth and the reference's own render settings."""
    payload = json.dumps({"stage": content_hash, "resolution": list(resolution), "max_depth": int(max_depth),
                          **settings}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


@dataclass
class Reference:
    """image: (H, W, 3) float64 full display window; floor: the reference's own relMSE (or None
    for a user-supplied EXR); path: the EXR; info: what made it."""

    image: np.ndarray
    path: str
    floor: Optional[float]
    info: dict
    cached: bool


def _stage_resolution(stage_path: str) -> tuple[int, int]:
    from .usd import load_stage

    w, h = load_stage(stage_path).settings.resolution
    return int(w), int(h)


def _overrides(cfg: BenchConfig, light_samples: Optional[int]) -> dict:
    """RenderOptions keyword arguments that apply a configuration to every light."""
    kw: dict = {}
    if cfg.estimator:
        kw["estimator"] = {"": cfg.estimator}
    if cfg.cv_alpha:
        kw["cv_alpha"] = {"": cfg.cv_alpha}
    if light_samples:
        kw["light_samples"] = {"": int(light_samples)}
    kw["light_sampler"] = cfg.light_sampler or "auto"
    return kw


def get_reference(stage_path: str, resolution: tuple[int, int], s: BenchSettings,
                  scene_cache: dict | None = None) -> Reference:
    """The user's --reference, or the cached reference for this stage, or a fresh one (cached)."""
    from .film import read_exr, write_exr
    from .render import RenderOptions, render

    if s.reference:
        img, _ = read_exr(s.reference)
        if img.shape[:2] != (resolution[1], resolution[0]):
            raise SettingsError(f"{s.reference} is {img.shape[1]}x{img.shape[0]}, the bench renders "
                                f"{resolution[0]}x{resolution[1]}", attribute="reference")
        return Reference(img[:, :, :3].astype(np.float64), os.path.abspath(s.reference), None,
                         {"source": "user"}, cached=True)

    ref_cfg = parse_configs(s.reference_estimator)[0]
    ref_settings = {"estimator": ref_cfg.label, "light_samples": s.light_samples, "spp": int(s.reference_spp),
                    "seed": int(s.seed) + REFERENCE_SEED_OFFSET}
    key = reference_key(stage_content_hash(stage_path), resolution, s.max_depth, ref_settings)
    ref_dir = os.path.join(s.out, "references")
    stem = os.path.splitext(os.path.basename(stage_path))[0]
    exr = os.path.join(ref_dir, f"{stem}-{key}.exr")
    meta = exr[:-4] + ".json"
    if os.path.exists(exr) and os.path.exists(meta):
        img, _ = read_exr(exr)
        with open(meta) as fh:
            info = json.load(fh)
        s.log(f"bench: {stem}: reusing reference {_display_path(exr)}")
        return Reference(img[:, :, :3].astype(np.float64), os.path.abspath(exr), info.get("floor_relmse"),
                         info, cached=True)

    s.log(f"bench: {stem}: rendering reference ({ref_cfg.label}, {s.reference_spp} spp, "
          f"{resolution[0]}x{resolution[1]}, max depth {s.max_depth})")
    # Two independent halves (seeds seed and seed + 1), merged into the reference: their
    # difference measures the reference's own error (split_half_floor). With fewer than 2 spp
    # there is no second half, and the film's variance estimate (relmse_floor) stands in.
    spp = int(s.reference_spp)
    halves = [spp // 2, spp - spp // 2] if spp >= 2 else [spp]
    films, seconds = [], 0.0
    for k, n in enumerate(halves):
        opts = RenderOptions(spp=n, resolution=tuple(resolution), seed=ref_settings["seed"] + k,
                             threads=s.threads, max_depth=s.max_depth, **_overrides(ref_cfg, s.light_samples))
        res = render(stage_path, opts, scene_cache=scene_cache)
        films.append(res.film)
        seconds += res.stats["seconds"]["render"]
    film = films[0].copy()
    for other in films[1:]:
        film.merge(other)
    image = film.image().astype(np.float64)
    if len(films) == 2:
        floor = split_half_floor(films[0].image(), films[1].image(), image)
    else:
        # Over the full display window like relmse(): pixels outside the data window are exact zeros.
        var = np.zeros_like(image)
        x0, y0, x1, y1 = film.window
        var[y0:y1, x0:x1] = film.variance_of_mean()
        floor = relmse_floor(image, var)
    os.makedirs(ref_dir, exist_ok=True)
    write_exr(exr, film, res.metadata)
    info = {"stage": os.path.abspath(stage_path), "key": key, "resolution": list(resolution),
            "max_depth": s.max_depth, **ref_settings, "seconds": seconds, "floor_relmse": floor,
            "floor_method": "split halves" if len(films) == 2 else "film variance"}
    tmp = meta + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(info, fh, indent=2)
    os.replace(tmp, meta)
    return Reference(image, os.path.abspath(exr), floor, info, cached=False)


# ---------------------------------------------------------------------------------- the bench
def run_bench(stages: list[str], s: BenchSettings) -> dict:
    """Render every (stage, config, budget), score it, write results.csv/.md and the plot.

    Returns {"rows": [...], "references": {stage: Reference}, "raw": dict or None, "files": [...]}.
    """
    from .render import RenderOptions, render

    if not stages:
        raise SettingsError("no stage given", attribute="stages")
    for st in stages:
        if not os.path.exists(st):
            raise SettingsError(f"{st}: no such stage file", attribute="stages")
    os.makedirs(s.out, exist_ok=True)
    machine = machine_info()
    rows: list[dict] = []
    refs: dict = {}
    for stage in stages:
        name = os.path.splitext(os.path.basename(stage))[0]
        resolution = tuple(s.resolution) if s.resolution else _stage_resolution(stage)
        # One loaded scene per stage and light sampler: the estimators live in the integrator,
        # so every configuration and budget reuses the BVH (render time excludes the build anyway).
        # The light sampler is part of render()'s cache key, so each sampler gets its own cache
        # dict; one shared dict would be cleared (and its scene leaked, unclosed) at every switch.
        caches: dict[str, dict] = {}
        try:
            ref = get_reference(stage, resolution, s, scene_cache=caches.setdefault("auto", {}))
            refs[name] = ref
            pilots: dict[str, float] = {}
            for cfg in s.configs:
                cache = caches.setdefault(cfg.light_sampler or "auto", {})
                # Warm-up pass, discarded: the first use of a code path pays one-off costs (numba
                # kernels loading or compiling, lazily built tables) that would otherwise be
                # charged to whichever configuration happens to run first. For `auto` it also
                # runs the pilot, whose decision the loaded scene keeps for the timed renders.
                warm = render(stage, RenderOptions(spp=1, resolution=resolution, seed=s.seed, threads=s.threads,
                                                   max_depth=s.max_depth, **_overrides(cfg, s.light_samples)),
                              scene_cache=cache)
                pilots[cfg.label] = sum(li.get("auto_pilot", {}).get("cpu_seconds", 0.0)
                                        for li in warm.stats["lights"])
            for rep, budget, cfg in ((r, b, c) for r in range(s.repeats) for b in s.budgets for c in s.configs):
                cache = caches.setdefault(cfg.light_sampler or "auto", {})
                opts = RenderOptions(time_budget=float(budget), resolution=resolution, seed=s.seed + rep,
                                     threads=s.threads, max_depth=s.max_depth,
                                     **_overrides(cfg, s.light_samples))
                cpu0 = time.process_time()
                res = render(stage, opts, scene_cache=cache)
                cpu = time.process_time() - cpu0
                img = res.film.image().astype(np.float64)
                secs = float(res.stats["seconds"]["render"])
                rel = relmse(img, ref.image)
                row = {
                    "stage": name, "config": cfg.label, "estimator": cfg.estimator or "stage",
                    "cv_alpha": cfg.cv_alpha or "", "light_sampler": res.stats["light_sampler"],
                    "light_samples": s.light_samples or "", "budget_s": budget, "seconds": secs,
                    "cpu_seconds": cpu,
                    "spp": int(res.stats["spp"]), "samples_per_second": float(res.stats["samples_per_second"]),
                    "mrays_per_second": float(res.stats["mrays_per_second"]), "rmse": rmse(img, ref.image),
                    "relmse": rel, "efficiency": efficiency(rel, secs), "efficiency_cpu": efficiency(rel, cpu),
                    "negative_pixels": int(np.any(res.film.mean() < 0.0, axis=2).sum()),
                    "width": resolution[0], "height": resolution[1], "max_depth": s.max_depth,
                    "seed": s.seed + rep, "reference": _display_path(ref.path),
                    "reference_floor_relmse": "" if ref.floor is None else ref.floor,
                    "repeat": rep,
                    # What `auto` picked, per auto light, and its pilot's one-off CPU seconds.
                    "auto_choice": " ".join(li["estimator"] for li in res.stats["lights"] if li.get("auto")),
                    "pilot_cpu_seconds": pilots.get(cfg.label, 0.0),
                }
                rows.append(row)
                s.log(f"bench: {name:18s} {cfg.label:44s} {budget:6.2f} s budget"
                      f"{f' (repeat {rep})' if s.repeats > 1 else ''}: {secs:6.2f} s "
                      f"({cpu:5.2f} cpu s), "
                      f"{row['spp']:5d} spp, relMSE {rel:.4g}, RMSE {row['rmse']:.4g}")
        finally:
            for cache in caches.values():
                for _desc, scene in cache.values():
                    scene.close()
                cache.clear()

    raw = None
    if s.raw_throughput:
        raw = raw_throughput(stages[0], s)
    files = write_results(rows, refs, raw, machine, s)
    return {"rows": rows, "references": refs, "raw": raw, "files": files}


# ---------------------------------------------------------------------------------- raw throughput
def raw_ray_batches(scene, cam, w: int, h: int, seed: int, min_rays: int = 65536) -> dict:
    """The batches raw embree is timed on: {"camera": (o, d), "bounce": (o, d)}, float64 (n, 3).

    Camera rays over the whole image (several per pixel, so a batch has >= min_rays rays and is
    long enough to time), and one cosine-distributed bounce from each of their hits.
    """
    from .geometry import coordinate_frame, offset_origin, to_world
    from .sampling import sample_cosine_hemisphere

    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:h, 0:w]
    reps = max(1, int(math.ceil(min_rays / (w * h))))
    px, py = np.tile(xs.ravel(), reps), np.tile(ys.ravel(), reps)
    n = px.size
    rays = cam.generate(px, py, rng.random((n, 2)), rng.random((n, 2)))
    o_cam, _ = rays.at_near_plane()
    hits = scene.accel.intersect(o_cam, rays.d)
    hit = hits.hit
    p = o_cam[hit] + rays.d[hit] * hits.t[hit][:, None]
    ng = scene.geometry.face_normal[hits.prim[hit]]
    # Face the normal toward the incoming ray so bounces leave on the visible side.
    ng = np.where((np.sum(ng * rays.d[hit], axis=1) > 0.0)[:, None], -ng, ng)
    s_, t_ = coordinate_frame(ng)
    wi = to_world(sample_cosine_hemisphere(rng.random((p.shape[0], 2))), s_, t_, ng)
    o_b = offset_origin(p, ng, wi, scene.accel.ray_epsilon(p, hits.prim[hit]))
    return {"camera": (o_cam, rays.d), "bounce": (o_b, wi)}


def raw_throughput(stage: str, s: BenchSettings) -> dict:
    """Mrays/s of raw embree vs our Accel wrapper vs render(), on the stage's camera rays and one
    bounce. The same float32 batches go to raw embree and to ``Accel.intersect``; ``render()`` is
    run for ``raw_seconds`` at ``raw_max_depth`` and reports its own (camera + extension +
    shadow) Mrays/s. ratio = render / raw: the share of embree's speed the whole renderer keeps."""
    from .accel import raw_throughput_probe
    from .camera import Camera
    from .render import RenderOptions, render
    from .scene import build_scene
    from .usd import load_stage

    desc = load_stage(stage)
    w, h = tuple(s.resolution) if s.resolution else desc.settings.resolution
    scene = build_scene(desc, threads=s.threads)
    try:
        accel = scene.accel
        if accel.count == 0:
            raise SettingsError(f"{stage}: no geometry to trace", attribute="raw-throughput")
        cam = Camera(scene.desc.camera, int(w), int(h), desc.settings.pixel_aspect_ratio,
                     desc.settings.aspect_ratio_conform_policy)
        batches = raw_ray_batches(scene, cam, int(w), int(h), s.seed)
        out: dict = {"stage": os.path.abspath(stage), "resolution": [int(w), int(h)], "threads": accel.threads,
                     "batches": {}}
        tot_rays = tot_raw = tot_ours = 0.0
        for label, (o, d) in batches.items():
            raw_t, ours_t = _timed_pair(lambda: raw_throughput_probe(accel, o, d, "INTERSECT"),
                                        lambda: _time_call(lambda: accel.intersect(o, d)), s.raw_seconds / 2)
            out["batches"][label] = {"rays": int(o.shape[0]), "raw_mrays_per_second": o.shape[0] / raw_t / 1e6,
                                     "accel_mrays_per_second": o.shape[0] / ours_t / 1e6}
            tot_rays += o.shape[0]
            tot_raw += raw_t
            tot_ours += ours_t
    finally:
        scene.close()
    out["raw_mrays_per_second"] = tot_rays / tot_raw / 1e6
    out["accel_mrays_per_second"] = tot_rays / tot_ours / 1e6
    res = render(stage, RenderOptions(time_budget=s.raw_seconds, resolution=(int(w), int(h)), seed=s.seed,
                                      threads=s.threads, max_depth=s.raw_max_depth))
    st = res.stats
    out["render"] = {"max_depth": s.raw_max_depth, "seconds": st["seconds"]["render"], "spp": st["spp"],
                     "rays": st["rays"], "mrays_per_second": st["mrays_per_second"],
                     "samples_per_second": st["samples_per_second"]}
    out["ratio_render_over_raw"] = st["mrays_per_second"] / out["raw_mrays_per_second"]
    out["ratio_accel_over_raw"] = out["accel_mrays_per_second"] / out["raw_mrays_per_second"]
    s.log(f"bench: raw throughput on {os.path.basename(stage)}: embree {out['raw_mrays_per_second']:.2f}, "
          f"Accel {out['accel_mrays_per_second']:.2f}, render() {st['mrays_per_second']:.2f} Mrays/s "
          f"(ratio {out['ratio_render_over_raw']:.3f})")
    return out


def best_seconds(fn: Callable[[], object], repeats: int) -> float:
    """Fastest of ``repeats`` calls of fn, in wall seconds (the benches' micro-timings: the
    minimum is the least disturbed by other jobs on the machine)."""
    best = float("inf")
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _time_call(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _timed_pair(probe_a: Callable[[], float], probe_b: Callable[[], float], min_seconds: float) -> tuple[float, float]:
    """Median seconds of two probes, run alternately (a, b, a, b, ...) after one warm-up call of
    each, at least 3 times and until min_seconds are spent. Alternating exposes both to the same
    load on a shared machine; the median resists the other jobs' bursts better than the mean."""
    probe_a()
    probe_b()
    ta: list[float] = []
    tb: list[float] = []
    t0 = time.perf_counter()
    while len(ta) < 3 or (time.perf_counter() - t0 < min_seconds and len(ta) < 200):
        ta.append(probe_a())
        tb.append(probe_b())
    return float(np.median(ta)), float(np.median(tb))


# ---------------------------------------------------------------------------------- reporting
def machine_info() -> dict:
    """CPU model, cores, load and library versions, for results.md."""
    import importlib.metadata as md

    cpu = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    versions = {}
    for pkg in ("numpy", "embreex", "usd-core", "OpenImageIO", "numba", "matplotlib"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = "not installed"
    from .render import VERSION

    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "illum": VERSION, "versions": versions,
            "loadavg_at_start": [round(x, 2) for x in load]}


def _display_path(path: str) -> str:
    """Relative to the working directory when inside it (readable, machine-independent in a
    committed results.md), absolute otherwise."""
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


def _fmt(v, digits=4) -> str:
    if isinstance(v, float):
        if math.isinf(v):
            return "inf"
        return f"{v:.{digits}g}"
    return str(v)


def write_results(rows: list[dict], refs: dict, raw: Optional[dict], machine: dict, s: BenchSettings) -> list[str]:
    """results.csv, results.md and error_vs_time.png in s.out; returns their paths."""
    os.makedirs(s.out, exist_ok=True)
    csv_path = os.path.join(s.out, "results.csv")
    md_path = os.path.join(s.out, "results.md")
    png_path = os.path.join(s.out, "error_vs_time.png")

    tmp = csv_path + ".tmp"
    with open(tmp, "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        wr.writeheader()
        for r in rows:
            wr.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, csv_path)

    tmp = md_path + ".tmp"
    with open(tmp, "w") as fh:
        fh.write(_markdown(rows, refs, raw, machine, s))
    os.replace(tmp, md_path)

    _plot(rows, png_path, {name: ref.floor for name, ref in refs.items()})
    return [csv_path, md_path, png_path]


def _markdown(rows, refs, raw, machine, s: BenchSettings) -> str:
    L = ["# illum bench results", ""]
    if s.command:
        L += ["Command:", "", "```sh", s.command, "```", ""]
    v = machine["versions"]
    L += ["## Machine", "",
          f"- CPU: {machine['cpu']}, {machine['cores']} cores; load average at start "
          f"{', '.join(map(str, machine['loadavg_at_start']))}",
          f"- {machine['platform']}, Python {machine['python']}, illum {machine['illum']}",
          f"- numpy {v['numpy']}, embreex {v['embreex']}, usd-core {v['usd-core']}, OpenImageIO {v['OpenImageIO']}, "
          f"numba {v['numba']}",
          f"- threads: {s.threads or 'all cores'}; seed {s.seed}; max depth {s.max_depth}; "
          f"light samples: {s.light_samples or 'as authored'}", ""]
    L += ["## Metric", "",
          f"relMSE = mean over pixels and RGB channels of (x - ref)^2 / (ref^2 + {EPS:g}); "
          "RMSE = sqrt(mean (x - ref)^2). Efficiency = 1 / (relMSE x render seconds), higher is better; "
          "'vs MIS' is efficiency relative to the `mis` configuration at the same budget. Budgets are "
          "wall-clock seconds; 'CPU' columns use the process CPU seconds of the render instead (all threads), "
          "which is the fairer cost when other jobs share the machine (see the load average above). "
          "'relMSE x spp' is the error per sample, blind to speed (lower is better): it separates a better "
          "estimator from a cheaper one. 'neg px' counts pixels whose mean is negative in some channel. "
          "The reference floor is the reference's own relMSE, measured from the difference of its two "
          "independent halves: every measured relMSE contains it, so values near the floor are not "
          "resolved.", ""]
    L += ["## References", "", "| stage | reference | made with | spp | seconds | floor relMSE |",
          "|---|---|---|---|---|---|"]
    for name, ref in refs.items():
        info = ref.info
        L.append(f"| {name} | `{_display_path(ref.path)}`{' (cached)' if ref.cached else ''} | "
                 f"{info.get('estimator', 'user EXR')} | {info.get('spp', '')} | "
                 f"{_fmt(info['seconds'], 3) if 'seconds' in info else ''} | "
                 f"{'' if ref.floor is None else _fmt(ref.floor, 3)} |")
    L.append("")
    reps = max(int(r.get("repeat", 0)) for r in rows) + 1 if rows else 1
    if reps > 1:
        L += [f"Every (config, budget) ran {reps} times (seeds {s.seed}..{s.seed + reps - 1}, interleaved: each "
              "repeat runs all configs at one budget back to back). Tables show medians; 'vs MIS' is the median "
              "of each repeat's ratio to the MIS run of the same repeat and budget, with its range.", ""]
    for name in dict.fromkeys(r["stage"] for r in rows):
        srows = [r for r in rows if r["stage"] == name]
        budgets = sorted({r["budget_s"] for r in srows})
        configs = list(dict.fromkeys(r["config"] for r in srows))
        agg = _aggregate(srows)
        mis = {(r["budget_s"], r.get("repeat", 0)): r["efficiency"] for r in srows if r["config"] == "mis"}
        L += [f"## {name}", "", "relMSE and efficiency relative to MIS by budget (wall and CPU seconds); "
                                "efficiency and relMSE x spp at the largest budget:", ""]
        L.append("| config | " + " | ".join(f"relMSE @ {b:g} s" for b in budgets) + " | " +
                 " | ".join(f"vs MIS @ {b:g} s" for b in budgets) + " | " +
                 " | ".join(f"vs MIS (CPU) @ {b:g} s" for b in budgets) +
                 " | efficiency | efficiency (CPU) | relMSE x spp | neg px |")
        L.append("|---|" + "---|" * (3 * len(budgets) + 4))
        bmax = budgets[-1]
        for c in configs:
            last = agg[(c, bmax)]
            L.append(f"| {c} | " + " | ".join(_fmt(agg[(c, b)]["relmse"]) for b in budgets) + " | " +
                     " | ".join(_ratio_cell(agg[(c, b)], "vs") for b in budgets) + " | " +
                     " | ".join(_ratio_cell(agg[(c, b)], "vs_cpu") for b in budgets) +
                     f" | {_fmt(last['efficiency'])} | {_fmt(last['efficiency_cpu'])} | "
                     f"{_fmt(last['rel_spp'], 3)} | {last['negative_pixels']} |")
        picks = {r["auto_choice"] for r in srows if r.get("auto_choice")}
        if picks:
            pilot = max(float(r.get("pilot_cpu_seconds") or 0.0) for r in srows if r.get("auto_choice"))
            cpu_max = float(np.median([r["cpu_seconds"] for r in srows if r["budget_s"] == bmax]))
            L += ["", f"`auto` picked **{', '.join(sorted(picks))}**. Its pilot ran once for the stage "
                      f"({_fmt(pilot, 3)} CPU s, {100 * pilot / max(cpu_max, 1e-9):.1f} % of a {bmax:g} s render's "
                      "median CPU seconds; the loaded scene keeps the decision, so the timed renders above do not "
                      "include it)."]
        L += ["", "<details><summary>all runs</summary>", "",
              "| config | budget s | repeat | render s | CPU s | spp | ksamples/s | Mrays/s | RMSE | relMSE | "
              "efficiency | vs MIS |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in srows:
            m = mis.get((r["budget_s"], r.get("repeat", 0)))
            vs = _fmt(r["efficiency"] / m, 3) if m else ""
            L.append(f"| {r['config']} | {r['budget_s']:g} | {r.get('repeat', 0)} | {r['seconds']:.2f} | "
                     f"{r['cpu_seconds']:.2f} | {r['spp']} | "
                     f"{r['samples_per_second'] / 1e3:.0f} | {r['mrays_per_second']:.3f} | {_fmt(r['rmse'])} | "
                     f"{_fmt(r['relmse'])} | {_fmt(r['efficiency'])} | {vs} |")
        L += ["", "</details>", ""]
    if raw is not None:
        rr = raw["render"]
        L += ["## Raw throughput", "",
              f"Stage `{os.path.basename(raw['stage'])}` at {raw['resolution'][0]}x{raw['resolution'][1]}, "
              f"{raw['threads']} threads. Raw embree: `accel.raw_throughput_probe` (float32 batches, the same "
              "chunking and threads as Accel, no conversion); Accel: `Accel.intersect` on the same batches; "
              f"render(): end-to-end Mrays/s (camera + extension + shadow rays) at max depth {rr['max_depth']}.", "",
              "| batch | rays | raw embree Mrays/s | Accel.intersect Mrays/s |", "|---|---|---|---|"]
        for label, b in raw["batches"].items():
            L.append(f"| {label} | {b['rays']} | {b['raw_mrays_per_second']:.2f} | {b['accel_mrays_per_second']:.2f} |")
        L += ["", f"- raw embree (camera + bounce): **{raw['raw_mrays_per_second']:.2f} Mrays/s**",
              f"- Accel.intersect wrapper: {raw['accel_mrays_per_second']:.2f} Mrays/s "
              f"(ratio {raw['ratio_accel_over_raw']:.3f})",
              f"- render(): {rr['mrays_per_second']:.3f} Mrays/s, {rr['samples_per_second'] / 1e3:.0f} ksamples/s, "
              f"{rr['spp']} spp in {rr['seconds']:.2f} s",
              f"- **ratio ours / raw = {raw['ratio_render_over_raw']:.4f}**", ""]
    return "\n".join(L) + "\n"


def _aggregate(srows: list[dict]) -> dict:
    """Per (config, budget) of one stage: medians over repeats of relMSE, efficiencies and
    relMSE x spp, and each repeat's efficiency ratio to the MIS run of the same repeat and
    budget (median, min, max; wall "vs" and CPU "vs_cpu"). One repeat gives that run's values."""
    mis = {(r["budget_s"], r.get("repeat", 0)): r for r in srows if r["config"] == "mis"}
    out: dict = {}
    for key in dict.fromkeys((r["config"], r["budget_s"]) for r in srows):
        runs = [r for r in srows if (r["config"], r["budget_s"]) == key]
        a = {"relmse": float(np.median([r["relmse"] for r in runs])),
             "efficiency": float(np.median([r["efficiency"] for r in runs])),
             "efficiency_cpu": float(np.median([r["efficiency_cpu"] for r in runs])),
             "rel_spp": float(np.median([r["relmse"] * r["spp"] for r in runs])),
             "negative_pixels": max(r["negative_pixels"] for r in runs), "n": len(runs)}
        for field_, col in (("vs", "efficiency"), ("vs_cpu", "efficiency_cpu")):
            ratios = [r[col] / mis[(r["budget_s"], r.get("repeat", 0))][col] for r in runs
                      if (r["budget_s"], r.get("repeat", 0)) in mis and mis[(r["budget_s"], r.get("repeat", 0))][col]]
            a[field_] = [float(np.median(ratios)), min(ratios), max(ratios)] if ratios else None
        out[key] = a
    return out


def _ratio_cell(a: dict, field_: str) -> str:
    """'1.23' for one run, '1.23 (1.1-1.4)' (median and range) for several."""
    v = a.get(field_)
    if not v:
        return ""
    if a["n"] == 1:
        return _fmt(v[0], 3)
    return f"{_fmt(v[0], 3)} ({_fmt(v[1], 2)}-{_fmt(v[2], 2)})"


def _plot(rows: list[dict], path: str, floors: dict | None = None) -> None:
    """Log-log relMSE vs render seconds, one panel per stage, one curve per configuration, and
    the reference's own relMSE (the floor every measurement contains) as a dashed line.

    Uses the Agg canvas directly (no pyplot): no global backend state, no GUI, thread-safe."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    stages = list(dict.fromkeys(r["stage"] for r in rows)) or ["(no runs)"]
    ncol = min(2, len(stages))
    nrow = int(math.ceil(len(stages) / ncol))
    fig = Figure(figsize=(6.0 * ncol, 4.2 * nrow), dpi=100)
    FigureCanvasAgg(fig)
    configs = list(dict.fromkeys(r["config"] for r in rows))
    markers = "osD^v<>ph*"
    for i, name in enumerate(stages):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        for k, c in enumerate(configs):
            runs = [r for r in rows if r["stage"] == name and r["config"] == c and r["relmse"] > 0]
            # One point per budget: the medians over repeats.
            pts = sorted((float(np.median([r["seconds"] for r in runs if r["budget_s"] == b])),
                          float(np.median([r["relmse"] for r in runs if r["budget_s"] == b])))
                         for b in dict.fromkeys(r["budget_s"] for r in runs))
            if not pts:
                continue
            xs, ys = zip(*pts)
            ax.plot(xs, ys, marker=markers[k % len(markers)], label=c, color=f"C{k % 10}")
        floor = (floors or {}).get(name)
        if floor and ax.lines:
            ax.axhline(floor, color="0.5", linestyle="--", linewidth=1, label="reference floor")
        ax.set_xscale("log")
        ax.set_yscale("log")
        # Ticks at the budgets, in plain seconds ("2", "8"): a log axis within one decade
        # would otherwise show no labelled tick at all.
        budgets = sorted({float(r["budget_s"]) for r in rows if r["stage"] == name})
        if budgets:
            ax.set_xticks(budgets)
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(name)
        ax.set_xlabel("render seconds")
        ax.set_ylabel(f"relMSE (eps {EPS:g})")
        ax.grid(True, which="both", alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7, framealpha=0.8)
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp)
    os.replace(tmp, path)


# ---------------------------------------------------------------------------------- CLI
def register_cli(subparsers) -> None:
    """Add `illum bench` to the illum command line."""
    p = subparsers.add_parser(
        "bench", help="equal-time error benchmark of estimators and light samplers",
        description="Render each stage with each configuration at each time budget and report RMSE, "
                    "relMSE and efficiency against a reference (see renderer/bench.py and bench/README.md).")
    p.add_argument("stages", nargs="*", metavar="STAGE",
                   help=".usda stages (default: the talk's story stages, stages/talk/*.usda)")
    p.add_argument("--estimators", default=DEFAULT_ESTIMATORS,
                   help="comma list of estimator tokens, TOKEN:ALPHA for controlVariate, or 'stage' "
                        f"(default {DEFAULT_ESTIMATORS})")
    p.add_argument("--light-samplers", default=None,
                   help="comma list of light samplers to cross with the estimators (default: the stage's)")
    p.add_argument("--light-samples", type=int, default=None, metavar="N",
                   help="illum:samples override for every light (default: as authored)")
    p.add_argument("--budgets", default="1,4,16", help="comma list of render seconds (default 1,4,16)")
    p.add_argument("--reference", metavar="REF.exr", help="reference image (only with one stage)")
    p.add_argument("--reference-spp", type=int, default=1024, help="spp of a bench-made reference (default 1024)")
    p.add_argument("--reference-estimator", default="mis", help="estimator of a bench-made reference (default mis)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--res", nargs=2, type=int, metavar=("W", "H"), help="resolution (default: each stage's)")
    p.add_argument("--max-depth", type=int, default=8, help="max scattering events (1 = direct lighting)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--repeats", type=int, default=1,
                   help="independent runs of every (config, budget), interleaved; tables show medians (default 1)")
    p.add_argument("--raw-throughput", action="store_true",
                   help="also compare raw embree vs render() Mrays/s on the first stage")
    p.add_argument("--raw-max-depth", type=int, default=8, help="max depth of the raw-throughput render()")
    p.add_argument("--raw-seconds", type=float, default=3.0, help="seconds per raw-throughput measurement")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")
    p.set_defaults(func=cmd_bench)


def default_stages() -> list[str]:
    """stages/talk/*.usda of this checkout (empty when illum runs from an installed wheel)."""
    talk = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "stages", "talk")
    if not os.path.isdir(talk):
        return []
    return sorted(os.path.join(talk, f) for f in os.listdir(talk) if f.endswith(".usda"))


def settings_from_args(a) -> BenchSettings:
    if not a.stages:
        a.stages = default_stages()
        if not a.stages:
            raise SettingsError("no stage given (and no stages/talk/ next to this renderer)", attribute="stages")
    if a.reference and len(a.stages) > 1:
        raise SettingsError("--reference needs exactly one stage", attribute="reference")
    if a.reference and not os.path.exists(a.reference):
        raise SettingsError(f"{a.reference}: no such file", attribute="reference")
    if a.reference_spp < 1:
        raise SettingsError("must be >= 1", attribute="reference-spp")
    if a.light_samples is not None and a.light_samples < 1:
        raise SettingsError("must be >= 1", attribute="light-samples")
    if a.res is not None and (a.res[0] < 1 or a.res[1] < 1):
        raise SettingsError("must be positive", attribute="res")
    if a.repeats < 1:
        raise SettingsError("must be >= 1", attribute="repeats")
    if not (math.isfinite(a.raw_seconds) and a.raw_seconds > 0):
        raise SettingsError("must be a positive number of seconds", attribute="raw-seconds")
    parse_configs(a.reference_estimator)
    quiet = a.quiet
    return BenchSettings(
        configs=parse_configs(a.estimators, a.light_samplers),
        budgets=parse_budgets(a.budgets),
        out=a.out,
        resolution=tuple(a.res) if a.res else None,
        max_depth=a.max_depth,
        seed=a.seed,
        threads=a.threads,
        light_samples=a.light_samples,
        reference=a.reference,
        reference_spp=a.reference_spp,
        reference_estimator=a.reference_estimator,
        raw_throughput=a.raw_throughput,
        raw_max_depth=a.raw_max_depth,
        raw_seconds=a.raw_seconds,
        repeats=a.repeats,
        command="illum bench " + " ".join(_quote(x) for x in _argv_of(a)),
        log=(lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True)),
    )


def _argv_of(a) -> list[str]:
    """The bench flags as a command line, rebuilt from the parsed arguments (so results.md shows
    every effective value, defaults included, however the bench was invoked)."""
    out = list(a.stages)
    out += ["--estimators", a.estimators, "--budgets", a.budgets, "--max-depth", str(a.max_depth),
            "--seed", str(a.seed), "--out", a.out]
    if a.light_samplers:
        out += ["--light-samplers", a.light_samplers]
    if a.light_samples:
        out += ["--light-samples", str(a.light_samples)]
    if a.res:
        out += ["--res", str(a.res[0]), str(a.res[1])]
    if a.reference:
        out += ["--reference", a.reference]
    else:
        out += ["--reference-spp", str(a.reference_spp)]
        if a.reference_estimator != "mis":
            out += ["--reference-estimator", a.reference_estimator]
    if a.repeats > 1:
        out += ["--repeats", str(a.repeats)]
    if a.raw_throughput:
        out += ["--raw-throughput", "--raw-max-depth", str(a.raw_max_depth)]
    return out


def _quote(x: str) -> str:
    import shlex

    return shlex.quote(x)


def cmd_bench(a) -> int:
    s = settings_from_args(a)  # fills in a.stages when none were given
    result = run_bench(list(a.stages), s)
    if not a.quiet:
        for f in result["files"]:
            print(f"illum: wrote {f}", file=sys.stderr)
    return 0
