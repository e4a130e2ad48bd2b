"""The single render entry point used by the CLI, the benchmarks and the service.

``render(stage, options)`` loads the stage (renderer/usd), builds the scene once, then runs
progressive passes (one sample per pixel of the whole data window per pass) until the sample
count or the time budget is reached, or ``cancel()`` returns True. Callbacks report progress and
hand out snapshots of the film for previews and checkpoints.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .adaptive import Adaptive, adaptive_settings, check_mode
from .allocator import tune_allocator
from .deadline import deadline
from .errors import SettingsError
from .film import Film
from .memory import MemoryBudget
from .options import make_options_class
from .pixel_filter import jitter

__all__ = ["RenderOptions", "RenderResult", "render", "write_outputs", "VERSION"]

VERSION = "0.1.0"
DEFAULT_SPP = 64


# One field per option declared in renderer/options.py (the CLI flags and the service's request
# model come from the same declaration); validate() checks each against its declaration.
RenderOptions = make_options_class(__name__, "RenderOptions", doc=(
    """What the user asked for; None means "use the stage's RenderSettings or our default".

    The fields, their defaults and bounds are declared in renderer/options.py (OPTIONS).
    resolution: (width, height) override. time_budget: seconds of rendering (load, build and
    kernel compilation excluded: a cold first run renders as many samples as a warm one). spp:
    samples per pixel; with a time budget and no spp the budget alone decides.
    estimator / cv_alpha / light_samples: {"": value} for all lights or {light path: value}.
    default_estimator: the estimator of lights whose illum:estimator is unauthored (None: the
    stage's IllumRenderSettingsAPI illum:estimator, else mis).
    pixel_filter, pixel_filter_width, pixel_filter_mode: None means the RenderSettings'
    illum:pixelFilter attributes, else renderer/pixel_filter.py's defaults.
    """))


@dataclass
class RenderResult:
    film: Film
    stats: dict
    metadata: dict
    camera: object
    warnings: list[str]
    aovs: object = None   # renderer/aov.py AovResult: alpha, passes, denoised beauty
    # The traced scene's translation (renderer/scene.py recentre): camera is in the re-centred
    # frame, p_world = p + origin.
    origin: object = None
    # renderer/adaptive.py Adaptive (its decision film, which pixels stopped), None when uniform.
    adaptive: object = None


ProgressFn = Callable[[int, Optional[int], float], None]   # (spp done, spp target or None, fraction 0..1)
SnapshotFn = Callable[[Film, int], None]                     # (film, spp done)


def render(
    stage_path: str,
    options: RenderOptions | None = None,
    *,
    progress: ProgressFn | None = None,
    snapshot: SnapshotFn | None = None,
    snapshot_interval: float = 5.0,
    cancel: Callable[[], bool] | None = None,
    resume: Film | None = None,
    scene_cache: dict | None = None,
    stream_seed: int | None = None,
    on_loaded: Callable[[object], None] | None = None,
    shared: dict | None = None,
) -> RenderResult:
    """Render a stage progressively. See the module docstring.

    resume: a film checkpoint to continue (its samples count toward spp; pass indices continue
    after its sample count so the random streams never repeat).
    scene_cache: optional dict reused across calls (e.g. by a service worker or a Ray actor) to
    keep the loaded scene and BVH resident for the same (stage, frame, options) key.
    stream_seed: the integrator's random seed when it is not ``options.seed`` (the Ray backend
    gives each block its own stream; any non-negative integer, where a user's --seed stays below
    2^31 so that every file format's int attribute can record it).
    on_loaded: called with the stage's SceneDescription once it is read, before the film is
    allocated and any sample is taken (the CLI checks the productName's output path there).
    shared: what a frame range keeps between its frames' render() calls: under "stage" the
    stage opened once (renderer.usd.stage_reader.open_stage), read again at each frame's time
    code; under "textures" (filled here) the TextureCache, so each image file is decoded once.
    Geometry, BVHs and light tables are rebuilt per frame (each frame's are its own).
    """
    from .accel import default_threads
    from .camera import Camera
    from .integrators.path import IntegratorOptions, PathIntegrator
    from .scene import build_scene
    from .usd import load_stage, read_stage
    from .warmup import COMPILES

    opt = options or RenderOptions()
    opt.validate()
    if opt.denoise:
        from .denoise import require_oidn

        require_oidn()  # exit 2 before any work when OIDN is missing
    tune_allocator()  # keep bounce temporaries' memory in the process (renderer/allocator.py)
    threads = opt.threads or default_threads()
    phases = {}
    t_start = time.perf_counter()
    # numba compiles a kernel on its first call when its cache is cold (renderer/warmup.py): the
    # seconds that takes are kept out of the time budget and of the "render" phase.
    k_start, c_start = COMPILES.kernels, COMPILES.seconds()

    # ---- load + build (cached for resident workers) --------------------------------------
    key = (os.path.abspath(stage_path), os.path.getmtime(stage_path) if os.path.exists(stage_path) else 0,
           opt.camera, opt.settings, opt.frame, opt.purposes, opt.light_sampler, threads, opt.strict,
           opt.subdiv_level)
    cached = scene_cache.get(key) if scene_cache is not None else None
    if cached is None:
        t0 = time.perf_counter()
        where = dict(camera=opt.camera, settings=opt.settings, frame=opt.frame, purposes=opt.purposes,
                     strict=opt.strict, subdiv_level=opt.subdiv_level)
        opened = shared.get("stage") if shared is not None else None
        # Meshes and images are charged to the budget as the reader meets them, the film here,
        # all before the scene is built (renderer/memory.py).
        budget = MemoryBudget.for_options(opt.max_memory)
        with deadline(opt.load_timeout, "opening and reading the stage", file=stage_path):
            desc = (load_stage(stage_path, memory=budget, **where) if opened is None
                    else read_stage(opened, source=stage_path, memory=budget, **where))
        phases["load"] = time.perf_counter() - t0
        if resume is None:
            _check_film_memory(opt, desc.settings, budget)
        t0 = time.perf_counter()
        textures = None
        if shared is not None:
            from .textures import TextureCache

            textures = shared.setdefault("textures", TextureCache(missing="error" if opt.strict else "fallback",
                                                                  strict=opt.strict))
        with deadline(opt.load_timeout, "reading the stage's images and building the scene", file=stage_path):
            scene = build_scene(desc, threads=threads, light_sampler=opt.light_sampler, textures=textures,
                                resolution=opt.resolution)
        phases["build"] = time.perf_counter() - t0
        if scene_cache is not None:
            scene_cache.clear()
            scene_cache[key] = (desc, scene)
    else:
        desc, scene = cached
        phases["load"] = 0.0
        phases["build"] = 0.0
        if resume is None:
            _check_film_memory(opt, desc.settings, MemoryBudget.for_options(opt.max_memory))

    try:  # a refusal here (output path, film memory, checkpoint) must not leak the built scene
        if on_loaded is not None:
            on_loaded(desc)
        settings = desc.settings
        width, height = opt.resolution or settings.resolution
        width, height = int(width), int(height)
        pixel_filter, mode = _pixel_filter(opt, settings)
        splat = pixel_filter if mode == "splat" else None
        # The traced camera: re-centred with the scene (scene.origin; renderer/scene.py recentre).
        camera = Camera(scene.desc.camera, width, height, settings.pixel_aspect_ratio, settings.aspect_ratio_conform_policy,
                        sample_filter=jitter() if splat is not None else pixel_filter)
        window = _data_window(settings.data_window_ndc, width, height)
        film = resume if resume is not None else Film(width, height, window, splat)
        if resume is not None and (resume.width, resume.height, resume.window) != (width, height, window):
            raise SettingsError("checkpoint does not match the requested resolution/data window", attribute="resume")
        if resume is not None and (resume.mode, repr(resume.splat)) != (mode, repr(splat)):
            raise SettingsError(f"checkpoint was rendered with pixel filter mode {resume.mode} "
                                f"({resume.splat or 'filter importance sampling'}), not {mode} ({pixel_filter})",
                                attribute="resume")
    except BaseException:
        if scene_cache is None:
            scene.close()
        raise

    # What lights without an authored illum:estimator use: --estimator TOKEN (or
    # --default-estimator), else IllumRenderSettingsAPI illum:estimator, else the schema fallback.
    default_estimator = opt.default_estimator or settings.estimator or "mis"
    # The light and BSDF kernels release the GIL, so shading threads scale too, if not fully: the
    # numpy glue between kernels holds it (Cornell box 512^2, depth 8, quiet machine: 590-614k
    # samples/s on 2 threads against 409-426k on 1).
    shading_threads = threads
    integrator = PathIntegrator(scene, camera, IntegratorOptions(
        max_depth=opt.max_depth, rr_depth=opt.rr_depth, seed=opt.seed if stream_seed is None else int(stream_seed), threads=shading_threads,
        estimator=dict(opt.estimator), cv_alpha=dict(opt.cv_alpha), light_samples=dict(opt.light_samples),
        default_estimator=default_estimator,
        emitter_samples=int(opt.emitter_samples), fast_path=bool(opt.fast_path), sampler=str(opt.sampler)))
    aovs = _aov_setup(opt, desc, scene, camera, film, integrator)
    first_hit = aovs.passes
    target = opt.spp if opt.spp is not None else (None if opt.time_budget else DEFAULT_SPP)
    done = int(film.count.max()) if film.count.size else 0
    # Adaptive sampling (renderer/adaptive.py): passes over the pixels still active, some into
    # the decision film (adaptive.decisions); image passes keep their own index (image_pass).
    threshold, min_spp = adaptive_settings(opt, settings)
    adaptive = Adaptive(film, threshold, min_spp, integrator.opt.seed) if threshold > 0.0 else None
    image_pass = done
    samples = 0
    t0 = time.perf_counter()
    c0 = COMPILES.seconds()
    last_snapshot = t0
    passes = 0

    def rendering(now: float) -> float:
        """Seconds of the pass loop so far, without its compiles."""
        return now - t0 - (COMPILES.seconds() - c0)

    try:
        while True:
            if target is not None and done >= target:
                break
            elapsed = rendering(time.perf_counter())
            if opt.time_budget is not None and elapsed >= opt.time_budget and passes > 0:
                break
            if cancel is not None and cancel():
                break
            rows = adaptive.rows() if adaptive is not None else None
            samples += film.count.size if rows is None else rows.size
            if adaptive is not None and adaptive.is_decision_pass(passes):
                adaptive.decision_pass(integrator, rows)
            else:
                integrator.render_pass(film, image_pass, rows=rows)
                if first_hit is not None:
                    first_hit.render_pass(film, image_pass, pool=integrator.pool, rows=rows)
                image_pass += 1
            active = adaptive.update(film) if adaptive is not None else 1
            done += 1
            passes += 1
            now = time.perf_counter()
            if progress is not None:
                fr = []
                if target is not None:
                    fr.append(done / target)
                if opt.time_budget is not None:
                    fr.append(rendering(now) / opt.time_budget)
                progress(done, target, min(1.0, max(fr) if fr else 0.0))
            if snapshot is not None and now - last_snapshot >= snapshot_interval:
                if getattr(snapshot, "takes_aovs", False) and opt.denoise:
                    snapshot(film, done, aovs=aovs)   # a denoised preview needs the guides (denoise_film)
                else:
                    snapshot(film, done)
                last_snapshot = now
            if not active:
                break   # every pixel has stopped
    finally:
        integrator.close()
        if scene_cache is None:
            scene.close()
    phases["render"] = rendering(time.perf_counter())
    phases["compile"] = COMPILES.seconds() - c_start
    if opt.denoise:
        aovs.denoised, aovs.denoise_seconds = denoise_film(film, aovs)
        phases["denoise"] = aovs.denoise_seconds

    rays = integrator.rays.as_dict()
    total_rays = rays["camera"] + rays["extension"] + rays["shadow"]
    r_sec = max(phases["render"], 1e-9)
    light_info = integrator.light_settings
    fallback_notes = _exactness_notes(scene.lights, light_info)
    stats = {
        "illum_version": VERSION,
        "stage": os.path.abspath(stage_path),
        "resolution": [width, height],
        "data_window": list(window),
        "product_name": settings.product_name,
        "spp": done,
        "passes_this_run": passes,
        "seed": opt.seed,
        "threads": threads,
        # What render() was asked for, every declared option (tests/service/test_options.py checks
        # that each reaches it through `illum render`, `illum submit` and the HTTP API).
        "options": opt.as_json(),
        "max_depth": opt.max_depth,
        "light_sampler": getattr(scene.light_sampler, "name", str(scene.light_sampler)),
        "default_estimator": default_estimator,
        "emitter_samples": integrator.emitter_samples,
        # The bounces' numbers: each pixel's low-discrepancy sequence on the compiled route,
        # independent ones there on request and always on the general path.
        "sampler": opt.sampler if integrator.fast is not None else "independent",
        "pixel_filter": {"name": pixel_filter.name, "radius": pixel_filter.radius, "mode": mode},
        # The compiled path vertex (integrators/fast_path.py): "on", or why the scene needs the
        # general path.
        "fast_path": "on" if integrator.fast is not None else integrator.fast_path_reason,
        "wall_seconds": time.perf_counter() - t_start,
        # numba compiles during this call (0 when the kernel cache is warm: `illum warmup`).
        "kernels_compiled": COMPILES.kernels - k_start,
        "seconds": phases,
        "rays": rays,
        "mrays_per_second": total_rays / r_sec / 1e6,
        "samples_per_second": samples / r_sec,
        "nonfinite_dropped": film.nonfinite_dropped,
        "negative_samples": film.negative_samples,
        "skipped": list(scene.skipped) + list(integrator.skipped),
        "lights": light_info,
        # Each material and the network it was read from: 'mtlx:<surface>' (MaterialX, preferred
        # where a material has both) or 'UsdPreviewSurface' (renderer/usd/mtlx.py).
        "materials": [{"path": m.path, "source": m.source} for m in desc.materials],
        "direct_rule": {"rule": "first vertex: each picked light takes its own N samples (alpha = v_bar "
                                "formed per light); deeper vertices: N = 1, control variate alpha = 1",
                        **integrator.rule_counts},
        "warnings": list(scene.warnings) + fallback_notes,
        "aovs": [{"name": r.name, "source": r.source, "render_var": r.path} for r in aovs.requests],
        "adaptive": adaptive.stats(film) if adaptive is not None else None,
        "alpha": {"written": aovs.alpha, "dome_transparent": first_hit is not None and first_hit.dome_transparent},
        "triangles": int(scene.geometry.count),
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "cpus": os.cpu_count()},
    }
    metadata = {
        "illum:version": VERSION,
        "illum:spp": done,
        "illum:renderSeconds": float(phases["render"]),
        "illum:seed": int(opt.seed),
        "illum:maxDepth": int(opt.max_depth),
        "illum:stage": os.path.abspath(stage_path),
        "illum:camera": desc.camera.path,
        "illum:estimators": {li["path"]: li["estimator"] for li in light_info},
        "illum:lightSampler": stats["light_sampler"],
        "illum:pixelFilter": f"{pixel_filter.name} {pixel_filter.radius:g} {mode}",
        **_camera_metadata(camera, scene.origin),
    }
    metadata.update(aovs.metadata())
    metadata["illum:frame"] = float(desc.time_code)
    if adaptive is not None:
        aovs.sample_count = adaptive.count(film)
        metadata["illum:noiseThreshold"] = float(threshold)
        metadata["illum:adaptiveMinSpp"] = int(min_spp)
    count = aovs.sample_count if aovs.sample_count is not None else film.count
    if count.size:
        metadata["illum:sppRange"] = f"{int(count.min())} {int(count.max())}"

    return RenderResult(film=film, stats=stats, metadata=metadata, camera=camera, warnings=list(scene.warnings),
                        aovs=aovs, origin=scene.origin, adaptive=adaptive)


def _aov_setup(opt: RenderOptions, desc, scene, camera, film, integrator):
    """The render's AovResult (renderer/aov.py): the passes of --aov, else the product's
    RenderVars; alpha where --alpha, a transparent dome or an alpha pass asks for it; and the
    first-hit pass over the camera rays when any of them (or --denoise's guides) needs one."""
    from .aov import AovResult, FirstHitPass, requests_from_names, requests_from_vars

    settings = desc.settings
    requests = requests_from_names(opt.aov) if opt.aov else requests_from_vars(settings.render_vars)
    dome_transparent = (opt.alpha_dome_transparent if opt.alpha_dome_transparent is not None
                        else settings.alpha_dome_transparent)
    sources = {r.source for r in requests} - {"color", "sampleCount"}
    alpha = bool(opt.alpha or dome_transparent or "alpha" in sources)
    if opt.denoise:
        sources |= {"albedo", "normal"}
    passes = None
    if alpha or sources:
        passes = FirstHitPass(scene, camera, film, sorted(sources - {"alpha"}), seed=integrator.opt.seed,
                              emitter_samples=integrator.emitter_samples, exposure=camera.desc.exposure_scale,
                              dome_transparent=dome_transparent, bend=getattr(integrator, "bent_normals", None))
    return AovResult(requests=requests, alpha=alpha, passes=passes,
                     material_paths=tuple(m.path for m in desc.materials))


def _pixel_filter(opt: RenderOptions, settings) -> tuple:
    """(PixelFilter, mode) of a render: each of filter, radius and mode from the options where
    given, else from IllumRenderSettingsAPI where authored, else the defaults
    (renderer/pixel_filter.py; with --denoise or adaptive sampling the mode's default is
    importance, and adaptive sampling refuses splat). A width given
    without a filter applies to the stage's filter."""
    from .pixel_filter import DEFAULT_FILTER, DEFAULT_MODE, PixelFilter

    name = opt.pixel_filter or settings.pixel_filter or DEFAULT_FILTER
    if opt.pixel_filter_width is not None:
        radius = opt.pixel_filter_width
    elif settings.pixel_filter_width and name == (settings.pixel_filter or DEFAULT_FILTER):
        radius = settings.pixel_filter_width   # the stage's width belongs to the stage's filter
    else:
        radius = None
    # --denoise with no mode chosen: filter importance sampling, whose per-pixel independent
    # noise OIDN removes far better than a splatted film's, correlated across neighbours (Cornell
    # box, 4 spp: denoised relMSE 0.0020 against 0.0138; bench/results/denoise/README.md).
    # Adaptive sampling needs it (renderer/adaptive.py check_mode).
    adaptive = adaptive_settings(opt, settings)[0] > 0.0
    default_mode = "importance" if opt.denoise or adaptive else DEFAULT_MODE
    mode = opt.pixel_filter_mode or settings.pixel_filter_mode or default_mode
    if adaptive:
        check_mode(mode, "--pixel-filter-mode" if opt.pixel_filter_mode else
                   "the RenderSettings' illum:pixelFilter:mode")
    # PixelFilter validates name and radius (SettingsError naming the attribute).
    return PixelFilter(name, radius), mode


def _exactness_notes(lights, light_info: list[dict]) -> list[str]:
    """Mark the lights whose ShapingAPI emission or ShadowAPI shadow colour rules out an exact
    unshadowed integral F (LightSet.inexact_reason): each such entry of the stats' "lights"
    gets ``exact_integral: false`` and the reason, and a light whose estimator wanted F
    (controlVariate, ratio, or auto with N >= 2) yields a note that it falls back to MIS."""
    reasons = getattr(lights, "inexact_reason", None) or {}
    notes = []
    for i, li in enumerate(light_info):
        reason = reasons.get(i)
        if reason is None:
            continue
        li["exact_integral"] = False
        li["no_exact_integral_because"] = reason
        est = li.get("estimator")
        if est in ("controlVariate", "ratio"):
            notes.append(f"{li['path']}: {reason} has no exact unshadowed integral; {est} falls back to MIS")
        elif li.get("auto") and est == "mis" and li.get("samples", 1) >= 2:
            notes.append(f"{li['path']}: {reason} has no exact unshadowed integral; auto chose MIS instead "
                         f"of the control variate")
    return notes


def _data_window(ndc, width: int, height: int) -> tuple[int, int, int, int]:
    """UsdRender dataWindowNDC (xmin, ymin, xmax, ymax; (0,0) bottom-left) -> pixel window
    (x0, y0, x1, y1) with y down, clamped to the image (overscan is not rendered).

    UsdRenderSettingsBase: "A pixel is included in the rendered result if the pixel center is
    contained by the data window". A centre exactly on the boundary counts as inside at
    xmin / ymin and outside at xmax / ymax (half-open, so adjacent windows tile the image)."""
    xmin, ymin, xmax, ymax = (float(v) for v in ndc)
    if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)) or xmax <= xmin or ymax <= ymin:
        raise SettingsError(f"dataWindowNDC {tuple(ndc)} is empty or not finite", attribute="dataWindowNDC")
    eps = 1e-9  # decimal NDC values (0.35 * 20) land on pixel centres up to rounding
    # column x's centre x + 0.5 lies in [xmin W, xmax W)
    x0 = int(np.clip(math.ceil(xmin * width - 0.5 - eps), 0, width))
    x1 = int(np.clip(math.ceil(xmax * width - 0.5 - eps), 0, width))
    # row y (down) has NDC centre 1 - (y + 0.5) / H, in [ymin, ymax)
    y0 = int(np.clip(math.floor((1.0 - ymax) * height - 0.5 + eps) + 1, 0, height))
    y1 = int(np.clip(math.floor((1.0 - ymin) * height - 0.5 + eps) + 1, 0, height))
    if x1 <= x0 or y1 <= y0:
        raise SettingsError(f"dataWindowNDC {tuple(ndc)} covers no pixel", attribute="dataWindowNDC")
    return x0, y0, x1, y1


def _check_film_memory(opt: RenderOptions, settings, budget) -> None:
    """Charge the film (renderer/film.py Film.bytes_per_pixel) to the render's MemoryBudget
    (renderer/memory.py) before the scene is built: a film that cannot fit is refused
    (MemoryLimitError naming the resolution), not a MemoryError after the load, or mid-render."""
    width, height = (int(v) for v in (opt.resolution or settings.resolution))
    window = _data_window(settings.data_window_ndc, width, height)
    x0, y0, x1, y1 = window
    splat = _pixel_filter(opt, settings)[1] == "splat"
    budget.need((x1 - x0) * (y1 - y0) * Film.bytes_per_pixel(splat), f"a {width}x{height} film",
                attribute="resolution")


# OpenEXR's camera space is left-handed (x right, y up, +z the viewing direction); USD's camera
# looks down -z, so OpenEXR's worldToCamera is USD's world-to-camera with z negated.
_USD_TO_EXR_CAMERA = np.diag([1.0, 1.0, -1.0, 1.0])
# Screen [-1, 1]^2 (y up) -> OpenEXR NDC: (0, 0) the display window's top-left corner, (1, 1)
# its bottom-right one (x right, y down).
_SCREEN_TO_NDC = np.array([[0.5, 0, 0, 0.5], [0, -0.5, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1]])


def _camera_metadata(camera, origin=None) -> dict:
    """The camera matrices of an EXR, as OpenEXR's standard attributes define them (column-vector
    here; the writer stores their transposes, Imath's row-vector form): worldToCamera,
    worldToNDC (a world point times it, divided by w, gives NDC x, y), and worldToScreen (the
    same with screen coordinates in [-1, 1], y up, as RenderMan and Nuke read it).
    origin: (3,) the scene's re-centring (Scene.origin): the camera traces in coordinates moved
    by -origin, and the matrices map world points, so they move them first."""
    world_to_camera = camera.world_to_camera()
    if origin is not None:
        to_traced = np.eye(4)
        to_traced[:3, 3] = -np.asarray(origin, dtype=np.float64)
        world_to_camera = world_to_camera @ to_traced
    world_to_screen = camera.projection_matrix() @ world_to_camera
    return {"worldToCamera": _USD_TO_EXR_CAMERA @ world_to_camera,
            "worldToScreen": world_to_screen,
            "worldToNDC": _SCREEN_TO_NDC @ world_to_screen}


def write_outputs(result: RenderResult, exr: str | None = None, png: str | None = None,
                  stats_json: str | None = None, *, compression: str = "zip", half: bool = False) -> dict:
    """Write the requested files and return the write time in seconds.

    exr: the beauty image (by extension: EXR with the render's metadata, or a display-referred
    PNG/JPEG/TIFF); png: a display-referred preview of the full image. Every file goes to a
    temporary name first; they are renamed together once all are written
    (renderer/output.py AtomicFiles), so a failing preview leaves no EXR behind either.
    compression, half: the EXR's compression and half-float pixels."""
    from .film import write_exr, write_png
    from .output import AtomicFiles, write_image

    t0 = time.perf_counter()
    with AtomicFiles() as files:
        aovs = result.aovs
        if exr:
            base, ext = os.path.splitext(exr)
            if aovs is None or not aovs.layered:
                if ext.lower() == ".exr":
                    write_exr(exr, result.film, result.metadata, files=files, compression=compression, half=half)
                else:
                    write_png(exr, result.film, files=files)
            elif ext.lower() == ".exr":
                pixels, names = aovs.layers(result.film)
                x0, y0, _, _ = result.film.window
                write_image(exr, pixels, result.metadata, files=files, origin=(x0, y0), channels=names,
                            full=(result.film.width, result.film.height), compression=compression, half=half)
            else:  # display formats hold the beauty (RGBA where asked); the denoised one is a file
                write_png(exr, full_image(result.film, aovs.beauty(result.film)), files=files)
                if aovs.denoised is not None:
                    den = aovs.denoised
                    if aovs.alpha:  # the beauty's alpha: the denoised RGB is premultiplied by it too
                        den = np.concatenate([den, aovs.passes.image("alpha", result.film.count)], axis=2)
                    write_png(f"{base}_denoised{ext}", full_image(result.film, den), files=files)
        if png:
            write_png(png, result.film if aovs is None or aovs.passes is None
                      else full_image(result.film, aovs.beauty(result.film)), files=files)
        write_s = time.perf_counter() - t0
        result.stats["seconds"]["write"] = write_s
        if stats_json:
            write_json(stats_json, result.stats, files=files)
    return {"write": write_s}


def denoise_film(film: Film, aovs, full: bool = False) -> tuple[np.ndarray, float]:
    """(denoised beauty RGB, seconds) of ``film`` so far: OIDN guided by the first-hit albedo
    and normal of ``aovs`` (renderer/denoise.py). The data window (h, w, 3), or with ``full`` the
    full image (H, W, 3). The final denoised layer and a service's denoised previews are this."""
    from .denoise import denoise

    den, seconds = denoise(aovs.beauty(film)[:, :, :3], aovs.passes.image("albedo", film.count),
                           aovs.passes.image("normal", film.count))
    return (full_image(film, den) if full else den), seconds


def full_image(film: Film, window_pixels: np.ndarray) -> np.ndarray:
    """Data-window pixels (h, w, C) placed in the full image (zeros outside the window)."""
    x0, y0, x1, y1 = film.window
    full = np.zeros((film.height, film.width, window_pixels.shape[2]), dtype=np.float32)
    full[y0:y1, x0:x1] = window_pixels
    return full


def write_json(path: str, obj, *, files=None) -> None:
    """``obj`` as indented JSON (numpy values as Python ones), atomically: joining ``files``
    (renderer/output.py AtomicFiles) or renamed into place alone."""
    from .output import joining

    with joining(files) as f, open(f.temp(path), "w") as fh:
        json.dump(obj, fh, indent=2, default=_json_default)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    return str(o)
