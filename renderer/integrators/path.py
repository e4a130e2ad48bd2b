"""Wavefront path tracer: next-event estimation with MIS, Russian roulette, progressive passes.

One *pass* traces one path per pixel of the data window. The pass is cut into fixed-size chunks
of pixels; each chunk owns a random generator seeded from (seed, pass, chunk), so the image is
the same whatever the thread count, and chunks run on a thread pool (embree and most numpy
kernels release the GIL).

``max_depth`` counts scattering events, as pbrt's maxdepth does: 0 shows only emitters seen
directly, 1 is direct lighting, and so on.

Direct lighting at every scattering vertex is done *per light* by the estimator the light's
IllumLightAPI chose (renderer/estimators): the lighting service picks the light(s), the estimator
draws that light's own light and/or BSDF samples and returns its whole contribution.

Continuation MIS (pbrt's scheme, and the cheap common case): where a light's estimator is MIS
with one sample at this vertex, the estimator only draws the light half, weighted by
h(pmf·p_l, p_b), and the BSDF sample that continues the path *is* the BSDF half: when that ray
reaches the light, it adds L_e weighted by h(p_b, pmf·p_l), with pmf the probability that the
lighting service would have picked that light at the previous vertex. That saves a BSDF sample,
a light intersection and a shadow ray per light and vertex. It applies where the continuation
ray sees exactly what the estimator's BSDF sample would have seen: MIS with N = 1 at that vertex
(so every vertex but the first, where a light may take its own N), no per-light diffuse/specular
multiplier, no shadowLink set, and a vertex that is not the last one (there the extension ray is
never traced: max depth 1 traces no extension rays at all). Every other (vertex, light) pair
gets its whole contribution from its estimator, and the continuation ray adds nothing for that
light, so nothing is counted twice. ``stats["direct_rule"]["continuation_mis"]`` counts the pairs.

Rule for per-light sample counts (the talk's "interplay with path tracing"): at the first
scattering vertex every picked light gets its own N = illum:samples, so α = v̄ is formed from that
light's own samples; at deeper vertices each picked light gets N = 1, where α = v̄ is undefined and
the control variate uses α = 1. ``stats["direct_rule"]`` counts both cases.

Conventions: area lights are *transparent* to every ray (as in Cycles): a ray that crosses a
light picks up its emission and continues to the geometry behind it. Shadow rays likewise ignore
lights. Both choices keep next-event estimation and BSDF sampling estimating the same integral,
which MIS needs.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..accel import serial_tracing
from ..camera import Camera
from ..film import Film
from ..geometry import (coordinate_frame, dot, offset_origin, perturb_normals, surface_interaction, to_local,
                        to_world)
from ..lights.base import ShadingContext
from ..errors import SettingsError
from ..estimators import ALPHAS, HEURISTICS, REGISTRY, TOKENS, DirectQuery, DirectRandom
from ..estimators.mis import mis_light_half
from ..kernels.rows import add_rows, take_rows as _t
from ..kernels.sobol import pixel_keys
from ..sampling import balance_heuristic, pixel_sequence, power_heuristic, safe_div
from .shadow_api import visibility as shadow_visibility

ESTIMATOR_TOKENS = tuple(t for t in TOKENS if t != "auto")
ALPHA_TOKENS = ALPHAS
HEURISTIC_TOKENS = HEURISTICS
TOKEN_CV = ESTIMATOR_TOKENS.index("controlVariate")
ALPHA_ONE = ALPHA_TOKENS.index("one")

# Pixels per chunk of a pass: each chunk is traced by one thread with its own random stream
# (seeded by the chunk index), so the split depends on the pixel count only, never on the thread
# count. Large frames take PIXELS_PER_CHUNK (the per-bounce Python work amortised: 4096-pixel
# chunks cost a single thread ~10 % at 128x128); smaller ones are cut into MIN_CHUNKS chunks of
# at least MIN_CHUNK_PIXELS, so that a 128x128 frame still has work for several threads.
PIXELS_PER_CHUNK = 16384
MIN_CHUNKS = 4
MIN_CHUNK_PIXELS = 2048


def chunk_size(n: int) -> int:
    """Pixels per chunk for a pass over n pixels (see PIXELS_PER_CHUNK)."""
    return min(PIXELS_PER_CHUNK, max(MIN_CHUNK_PIXELS, -(-n // MIN_CHUNKS)))


@dataclass
class IntegratorOptions:
    """estimator / cv_alpha / light_samples: overrides, {"": value} for all lights or
    {"/Light/Path": value} for one (the CLI's --estimator, --cv-alpha, --light-samples).
    default_estimator: the stage-wide default for lights whose illum:estimator is unauthored
    ('' = the schema fallback); an override above wins over it and over authored tokens."""

    max_depth: int = 8
    rr_depth: int = 3
    seed: int = 0
    threads: int = 2
    estimator: dict = field(default_factory=dict)
    cv_alpha: dict = field(default_factory=dict)
    light_samples: dict = field(default_factory=dict)
    default_estimator: str = ""
    emitter_samples: int = 0  # camera samples per pass for emitters seen directly; 0 = auto
    fast_path: bool = True  # the compiled path vertex where the scene qualifies (fast_path.py)
    sampler: str = "sobol"  # the bounces' numbers: "sobol" (per pixel, kernels/sobol.py) or "independent"


# `auto` emitter samples: K = EMITTER_SAMPLES_AUTO when lights smaller than a pixel on screen
# (bounding radius < 1 px, centre inside the image) could touch at least this share of the
# pixels (4 pixels each): then anti-aliasing their directly seen emission is a large part of the
# image error (the talk's fireflies: 90 % of the light BVH's error), else K = 1.
EMITTER_SAMPLES_AUTO_SHARE = 0.01
EMITTER_SAMPLES_AUTO = 2


def resolve_estimators(lights, opt: IntegratorOptions) -> list[dict]:
    """Per-light estimator settings after CLI overrides and the `auto` rule.

    Returns one dict per light: token, alpha, samples, heuristic, auto (bool: chosen by auto).
    Unknown override paths or tokens raise SettingsError naming the flag.
    """
    paths = list(lights.paths)
    for flag, table in (("estimator", opt.estimator), ("cv-alpha", opt.cv_alpha),
                        ("light-samples", opt.light_samples)):
        for key in table:
            if key and key not in paths:
                raise SettingsError(f"no light at {key!r} (lights: {', '.join(paths) or 'none'})", attribute=flag)
    out = []
    for i, path in enumerate(paths):
        es = lights.estimators[i]
        own = es.estimator if es.estimator_authored else (opt.default_estimator or es.estimator)
        token = opt.estimator.get(path, opt.estimator.get("", own))
        alpha = opt.cv_alpha.get(path, opt.cv_alpha.get("", es.cv_alpha))
        samples = opt.light_samples.get(path, opt.light_samples.get("", es.samples))
        if token not in TOKENS:
            raise SettingsError(f"{token!r} is not one of {', '.join(TOKENS)}", prim=path, attribute="illum:estimator")
        if alpha not in ALPHAS:
            raise SettingsError(f"{alpha!r} is not one of {', '.join(ALPHAS)}", prim=path, attribute="illum:cv:alpha")
        if not isinstance(samples, (int, np.integer)) or samples < 1 or samples > 4096:
            raise SettingsError(f"{samples!r} must be an integer in [1, 4096]", prim=path, attribute="illum:samples")
        heuristic = es.mis_heuristic if es.mis_heuristic in HEURISTICS else "power"
        auto = token == "auto"
        if auto:
            token = auto_estimator(lights, i, int(samples))
        out.append({"path": path, "estimator": token, "cv_alpha": alpha, "samples": int(samples),
                    "mis_heuristic": heuristic, "auto": auto})
    return out


def small_lights_on_screen(spheres, finite: np.ndarray, camera: Camera) -> int:
    """How many of the finite lights ``finite`` (indices) have their centre inside the image, in
    front of the camera, and a bounding radius under one pixel there. spheres: the scene's
    (centre (count, 3), radius (count,)) light bounds (Scene.light_spheres)."""
    center, radius = spheres[0][finite], spheres[1][finite]
    ok = np.all(np.isfinite(center), axis=1)
    center = np.where(ok[:, None], center, 0.0)
    M = np.linalg.inv(camera.camera_to_world)
    p = center @ M[:3, :3].T + M[:3, 3]
    # Camera-space lengths per world length (a scaled camera matrix scales everything alike).
    scale = float(np.cbrt(abs(np.linalg.det(M[:3, :3])))) or 1.0
    wx0, wx1, wy0, wy1 = camera.window
    depth = -p[:, 2]
    if camera.orthographic:
        x, y = p[:, 0], p[:, 1]
        px_size = np.full(p.shape[0], (wx1 - wx0) / camera.width)
    else:
        ok &= depth > 0.0
        safe = np.where(depth > 0.0, depth, 1.0)
        x, y = p[:, 0] / safe, p[:, 1] / safe
        px_size = (wx1 - wx0) / camera.width * safe
    ok &= (x >= wx0) & (x <= wx1) & (y >= wy0) & (y <= wy1)
    return int(np.count_nonzero(ok & (radius * scale < px_size)))


def auto_estimator(lights, i: int, samples: int) -> str:
    """The `auto` choice before the pilot (integrators/auto.py) refines it: light sampling for
    delta lights (the only technique that reaches them), MIS, the robust default, otherwise."""
    if lights.delta[i]:
        return "lightSampling"
    return "mis"


@dataclass
class RayCounters:
    camera: int = 0
    extension: int = 0
    shadow: int = 0
    light_probe: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, **kw) -> None:
        with self.lock:
            for k, v in kw.items():
                setattr(self, k, getattr(self, k) + int(v))

    def as_dict(self) -> dict:
        return {"camera": self.camera, "extension": self.extension, "shadow": self.shadow,
                "light_probe": self.light_probe}


@dataclass
class Interaction:
    """Surface hits of the live rays. p: (n,3); ng, ns: (n,3) unit, flipped to face wo;
    wo: (n,3) unit toward the previous vertex; st: (n,2); mat, mesh, prim: (n,) int (prim: the
    triangle, for the origin offset's scale)."""

    p: np.ndarray
    ng: np.ndarray
    ns: np.ndarray
    wo: np.ndarray
    st: np.ndarray
    mat: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray


class PathIntegrator:
    """Unidirectional path tracing with NEE + MIS over a Scene, seen through a Camera."""

    def __init__(self, scene, camera: Camera, options: IntegratorOptions):
        self.scene = scene
        self.camera = camera
        self.opt = options
        self.rays = RayCounters()
        self.lights = scene.lights
        self.has_lights = scene.lights.count > 0
        self.infinite = np.nonzero(scene.lights.is_infinite)[0] if self.has_lights else np.zeros(0, np.int64)
        # Finite lights that rays cross (transparent); mesh lights are met as surfaces instead.
        self.finite = (np.nonzero(~scene.lights.is_infinite & ~scene.lights.is_geometry)[0] if self.has_lights
                       else np.zeros(0, np.int64))
        self.params_needed = scene.materials.params_needed
        self.pool = ThreadPoolExecutor(max(1, options.threads)) if options.threads > 1 else None
        self.skipped: list[str] = []
        self.fast = None  # the compiled-vertex tracer, where the scene qualifies (set below)
        self.rule_counts = {"own_samples": 0, "alpha_one_fallback": 0}
        self.light_settings = resolve_estimators(self.lights, options) if self.has_lights else []
        ls = self.light_settings
        auto_lights = [i for i, x in enumerate(ls) if x["auto"] and not self.lights.delta[i]]
        if auto_lights:
            # `auto` is decided by a pilot on this scene (integrators/auto.py); its shadow rays
            # are not the render's, so the counters restart after it.
            from . import auto as auto_mod

            for i, pick in auto_mod.choose(self, auto_lights, ls).items():
                ls[i]["estimator"] = pick["estimator"]
                if pick.get("cv_alpha"):
                    ls[i]["cv_alpha"] = pick["cv_alpha"]
                ls[i]["auto_scores"] = pick["scores"]
            self.rays = RayCounters()
        self.est_token = np.array([ESTIMATOR_TOKENS.index(x["estimator"]) for x in ls], dtype=np.int64)
        self.est_alpha = np.array([ALPHA_TOKENS.index(x["cv_alpha"]) for x in ls], dtype=np.int64)
        self.est_samples = np.array([x["samples"] for x in ls], dtype=np.int64)
        self.est_heuristic = np.array([HEURISTIC_TOKENS.index(x["mis_heuristic"]) for x in ls], dtype=np.int64)
        self.rule_counts["continuation_mis"] = 0
        # Lights whose MIS BSDF half may ride on the continuation ray (see the module docstring).
        if self.has_lights:
            lights = self.lights
            plain = (lights.diffuse_scale == 1.0) & (lights.specular_scale == 1.0)
            if scene.shadow_group is not None:
                plain &= scene.shadow_group < 0
            plain &= getattr(lights, "plain_shadows", np.ones(lights.count, dtype=bool))
            plain &= getattr(lights, "transparent", np.ones(lights.count, dtype=bool))
            self.cont_ok = (self.est_token == ESTIMATOR_TOKENS.index("mis")) & plain
        else:
            self.cont_ok = np.zeros(0, dtype=bool)
        self.samples_one = self.est_samples == 1
        # Emitter samples K (see trace_paths): K camera rays per pixel and pass see the emitters,
        # one of them continues as the path.
        k = int(options.emitter_samples)
        if k < 0 or k > 64:
            raise SettingsError(f"must be in [0, 64] (0 = auto), got {k}", attribute="emitter-samples")
        if k == 0:
            # Bounds exist where the light proxies were built anyway (more than a handful of
            # lights); scenes with fewer lights keep K = 1.
            spheres = getattr(scene, "light_spheres", None)
            small = small_lights_on_screen(spheres, self.finite, camera) if spheres is not None else 0
            k = EMITTER_SAMPLES_AUTO if 4 * small >= EMITTER_SAMPLES_AUTO_SHARE * camera.width * camera.height else 1
        self.emitter_samples = k
        # Whether a continuation ray can carry any light's MIS half, from a deeper vertex (1)
        # or from the first one (2). Where none can, continuation rays skip the light probes.
        self.cont_from = (bool(self.cont_ok.any()), bool((self.cont_ok & self.samples_one).any()))
        from .fast_path import FastPath, fast_path_reason

        self.fast_path_reason = fast_path_reason(self)
        if not self.fast_path_reason:
            self.fast = FastPath(self)
        # (The compiled route at max depth 1 traces them where a light is on continuation MIS at
        # the one vertex: its BSDF half rides on them, fast_path.py's module docstring.)
        if options.max_depth <= 1 and (self.fast is None or options.max_depth == 0 or not self.fast.cont_at[0].any()):
            self.skipped.append("max depth <= 1: no extension rays are traced (unless emissive geometry needs them)")

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=False)
            self.pool = None

    # ---------------------------------------------------------------------- passes
    def render_pass(self, film: Film, pass_index: int, rows: np.ndarray | None = None,
                    seed: int | None = None) -> None:
        """Add one sample to every pixel of the film's data window (a splatting film: one
        camera sample taken in every pixel, spread over the pixels its filter covers).

        rows: (n,) int64 flat data-window pixels to sample (ascending), None for all; the chunks
        (and their random streams) are cut from this list, so a pass over fewer pixels traces
        fewer rows on every route (adaptive sampling, renderer/adaptive.py). seed: the random
        seed of this pass's streams (chunk streams and pixel sequences) when not the
        integrator's; a second seed gives samples independent of the first's."""
        px, py = film.pixel_coords()
        if rows is not None:
            px, py = px[rows], py[rows]
        seed = self.opt.seed if seed is None else int(seed)
        n = px.size
        size = chunk_size(n)
        chunks = [(c, s, min(n, s + size)) for c, s in enumerate(range(0, n, size))]
        splat = film.splat is not None
        if splat and (self.camera.filter.name, self.camera.filter.radius) != ("box", 0.5):
            # The offsets below are u - 0.5: the camera must jitter uniformly (pixel_filter.jitter).
            raise ValueError("a splatting film needs a camera whose samples are uniform in the pixel")
        # The camera's exposure scales the image (UsdGeomCamera exposure, 2^exposure).
        exposure = self.camera.desc.exposure_scale

        def work(job):
            c, a, b = job
            rng = np.random.default_rng([seed, pass_index, c])
            if not splat:
                return a, b, self.trace_paths(px[a:b], py[a:b], rng, pass_index, film.width, seed=seed) * exposure
            # With K emitter samples, camera ray k's own L_k is splatted at its own position as
            # K L_k (ray 0 carries the path, weighted 1 / K in trace_paths): a sample (w_k, K L_k)
            # each, so sum(w K L) / sum(w) estimates the filtered pixel as the K-ray sum does
            # with filter importance sampling.
            K = self.emitter_samples
            return a, b, [(u - 0.5, L * (K * exposure))
                          for u, L in self.trace_paths(px[a:b], py[a:b], rng, pass_index, film.width, split=True,
                                                       seed=seed)]

        if self.pool is not None and len(chunks) > 1:
            # The chunks run in parallel, so each traces its rays in its own thread.
            def work_serial(job):
                with serial_tracing():
                    return work(job)

            results = self.pool.map(work_serial, chunks)
        else:
            results = map(work, chunks)
        for a, b, L in results:
            pixels = np.arange(a, b) if rows is None else rows[a:b]
            if not splat:
                film.add(pixels, L)
                continue
            for k, (offsets, L_k) in enumerate(L):
                film.add(pixels, L_k, offsets=offsets, count=k == 0)

    # ---------------------------------------------------------------------- paths
    def trace_paths(self, px: np.ndarray, py: np.ndarray, rng: np.random.Generator, pass_index: int | None = None,
                    width: int = 0, split: bool = False, seed: int | None = None):
        """Radiance estimates (m, 3) for one path through each pixel (px, py); with split, a
        list of (u_filter (m, 2), L_k (m, 3)) for each camera ray k, summing to that estimate.

        With pass_index, the filter samples are that pass's point of each pixel's own
        low-discrepancy sequence (sampling.pixel_sequence, scrambled by seed, else the
        integrator's); without, independent uniforms.

        With K = self.emitter_samples > 1, the emitters seen directly (depth 0: lights, the
        environment, emissive surfaces, through cutouts) are estimated from K camera rays per
        pixel, weighted 1/K each, and only the first ray continues as the path, whose depth-0
        emission is weighted 1/K too. Each part stays unbiased, and the anti-aliasing noise of
        small bright emitters on screen (a firefly covering part of a pixel) falls ~K-fold in
        variance (more, as the K rays continue the pixel's stratified sequence) for the cost of
        K - 1 rays that do not scatter.
        """
        m = px.size
        seed = self.opt.seed if seed is None else seed
        K = self.emitter_samples if pass_index is not None else 1
        pixel = py.astype(np.int64) * max(width, 1) + px
        # Draw only the numbers the camera uses (~9 ns a pixel otherwise): the filter's come from
        # the pixel's sequence in a progressive pass, the lens's only for a thin lens.
        u_filter = (pixel_sequence(seed, pixel, pass_index * K) if pass_index is not None
                    else rng.random((m, 2)))
        thin_lens = self.camera.lens_radius > 0.0
        u_lens = rng.random((m, 2)) if thin_lens else np.zeros((m, 2))
        rays = self.camera.generate(px, py, u_filter, u_lens)
        self.rays.add(camera=m)
        # Near clip: start the ray at the near plane.
        o, tmax = rays.at_near_plane()
        # The bounces' numbers: each pixel's low-discrepancy sequence at this pass (kernels/sobol.py),
        # on the compiled route; independent numbers without a pass or with --sampler independent.
        pixels = ((pixel_keys(seed, pixel), pass_index) if pass_index is not None and self.opt.sampler == "sobol"
                  else None)
        L = self._trace_camera(o, rays.d, tmax, rng, K, pixels)
        parts = [(u_filter, L)] if split else None
        for k in range(1, K):
            u_k = pixel_sequence(seed, pixel, pass_index * K + k)
            rays = self.camera.generate(px, py, u_k, rng.random((m, 2)) if thin_lens else u_lens)
            self.rays.add(camera=m)
            o, tmax = rays.at_near_plane()
            L_k = self.trace(o, rays.d, tmax, rng, emit0=1.0 / K, max_depth=0)
            if split:
                parts.append((u_k, L_k))
            else:
                L += L_k
        return parts if split else L

    def _trace_camera(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, rng: np.random.Generator,
                      K: int, pixels=None) -> np.ndarray:
        """trace for the path-carrying camera ray of trace_paths: the emission it sees directly
        weighted 1 / K. The compiled path weighs a camera ray's emission fully, so there
        (1 - 1/K) of it is taken off again, traced a second time at depth 0. That is the same
        emission (depth 0 draws no random number), except behind a stochastic cut-out, where the
        two presence draws are independent and each term stays unbiased."""
        if K == 1 or self.fast is None:
            return self.trace(o, d, tmax, rng, emit0=1.0 / K, pixels=pixels)
        L = self.fast.trace(o, d, tmax, rng, self.opt.max_depth, pixels)
        L -= (1.0 - 1.0 / K) * self.fast.trace(o, d, tmax, rng, 0)
        return L

    def trace(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, rng: np.random.Generator,
              emit0: float = 1.0, max_depth: int | None = None, pixels=None) -> np.ndarray:
        """Radiance (m, 3) arriving at the origins o (m, 3) along -d (unsampled primary rays).

        emit0: weight of the emission the unsampled rays see directly (see trace_paths);
        max_depth: override of the options' maximum depth (0: emitters seen directly only);
        pixels: (pixel keys (m,) uint64, pass index) for the compiled route's low-discrepancy
        numbers (FastPath.trace), None for independent ones (the general path's always are).
        """
        scene = self.scene
        opt = self.opt
        max_depth = opt.max_depth if max_depth is None else max_depth
        if self.fast is not None and (emit0 == 1.0 or max_depth == 0):
            # At depth 0 every contribution is emission seen directly: scaling by emit0 is exact.
            L = self.fast.trace(o, d, tmax, rng, max_depth, pixels)
            return L if emit0 == 1.0 else L * emit0
        m = o.shape[0]

        # ---- loop state: one row per live ray ---------------------------------------------
        L = np.zeros((m, 3))                 # accumulated radiance per path
        path = np.arange(m)                  # which path each live row belongs to
        beta = np.ones((m, 3))               # path throughput
        depth = np.zeros(m, dtype=np.int64)  # scattering events so far
        unsampled = np.ones(m, dtype=bool)   # True: no scattering yet, so emitters count fully
        # Continuation MIS: the vertex the ray left (p, ng, ns: columns 0:9), the BSDF pdf p_b of
        # its direction (column 9), that vertex's mesh, and cont = 0 (no MIS half rides on this
        # ray), 1 (left a deeper vertex), 2 (left the first vertex, where lights with N > 1
        # took their own BSDF samples).
        prev = np.zeros((m, 10))
        prev_mesh = np.zeros(m, dtype=np.int64)
        cont = np.zeros(m, dtype=np.int8)
        budget = max_depth + 64              # bound on loop trips (cutout pass-throughs included)

        while path.size and budget > 0:
            budget -= 1
            # ---- intersect -------------------------------------------------------------
            hits = scene.accel.intersect(o, d, tmax)
            t_geo = np.minimum(hits.t, tmax)

            # ---- emission from lights crossed before the surface, and from the environment:
            # in full on unsampled rays, MIS-weighted on continuation rays (module docstring).
            seen = unsampled | (cont > 0)
            if np.any(seen):
                em = _Emission(self, path, beta, d, unsampled, cont, prev, prev_mesh, emit0)
                if self.finite.size:
                    self._add_light_hits(L, em, o, t_geo, seen)
                if self.infinite.size:
                    # The environment is at infinity: a camera ray sees it whatever its far clip.
                    escaped = ~hits.hit & seen
                    if np.any(escaped):
                        self._add_escaped(L, em, escaped)
                if scene.tri_light is not None:
                    self._add_mesh_light_hits(L, em, hits.prim, seen)
            if scene.tri_absorb is not None:
                # noMaterialResponse mesh lights reflect nothing: the path ends at them.
                beta[hits.hit & scene.tri_absorb[np.maximum(hits.prim, 0)]] = 0.0

            # ---- surfaces ----------------------------------------------------------------
            keep = np.nonzero(hits.hit)[0]
            if not keep.size:
                break
            if (not scene.materials.has_cutout and not scene.materials.has_emission
                    and int(depth.min()) >= max_depth):
                break  # no row scatters, passes through or glows: the surfaces add nothing
            path, beta, o, d, tmax, depth = path[keep], _t(beta, keep), _t(o, keep), _t(d, keep), tmax[keep], depth[keep]
            unsampled, cont, prev, prev_mesh = unsampled[keep], cont[keep], _t(prev, keep), prev_mesh[keep]
            si = self._interaction(hits.prim[keep], hits.b1[keep], hits.b2[keep], d)
            t_hit = hits.t[keep]
            # Plain materials (no emission, cutout or textured BSDF input) need no per-hit inputs.
            params = scene.materials.evaluate(si.mat, si.st) if self.params_needed else None
            if scene.materials.has_normal_map:
                # Normal maps bend ns before anything (frame, light contexts, MIS) reads it.
                self._apply_normal_maps(si, hits.prim[keep], params)

            # Opacity as presence: a ray that passes through keeps its state, depth and MIS
            # bookkeeping, and continues from just past the surface.
            through = np.zeros(path.size, dtype=bool)
            if scene.materials.has_cutout:
                through = rng.random(path.size) >= scene.materials.presence(params)
            if np.any(through):
                tr = np.nonzero(through)[0]
                pass_o = offset_origin(si.p[tr], si.ng[tr], d[tr], scene.accel.ray_epsilon(si.p[tr], si.prim[tr]))
                pass_state = (path[tr], beta[tr], pass_o, d[tr], tmax[tr] - t_hit[tr], depth[tr], unsampled[tr],
                              cont[tr], prev[tr], prev_mesh[tr])
                solid = np.nonzero(~through)[0]
                path, beta, d, depth, unsampled = path[solid], beta[solid], d[solid], depth[solid], unsampled[solid]
                si = _take(si, solid)
                params = _take(params, solid)
            else:
                pass_state = None

            if scene.materials.has_emission and np.any(params.emission):
                # Emissive surfaces are reached by BSDF samples only (no MIS); seen directly,
                # they take the depth-0 weight.
                w_e = beta * params.emission
                if emit0 != 1.0:
                    w_e *= np.where(unsampled, emit0, 1.0)[:, None]
                add_rows(L, path, w_e)

            # ---- stop at the maximum depth -----------------------------------------------
            alive = depth < max_depth
            if not np.all(alive):
                a = np.nonzero(alive)[0]
                path, beta, d, depth = path[a], beta[a], d[a], depth[a]
                si = _take(si, a)
                params = _take(params, a) if params is not None else None

            n = path.size
            next_state = None
            if n:
                bsdf = scene.materials.bsdf(si.mat, params)
                s, t = coordinate_frame(si.ns)
                wo_l = to_local(si.wo, s, t, si.ns)
                # Precompute the BSDF's wo-dependent terms once per vertex (E(wo) albedo lookups).
                bsdf.bind_wo(wo_l)
                ctx = ShadingContext(si.p, si.ng, si.ns)
                eps = scene.accel.ray_epsilon(si.p, si.prim)
                # The continuation ray can carry MIS halves only where it is traced and its hit
                # may still add emission: not from the last scattering vertex.
                continues = depth + 1 < max_depth

                # ---- direct lighting, per light, by its estimator --------------------------
                if self.has_lights:
                    self._direct(L, path, beta, ctx, bsdf, wo_l, s, t, eps, rng, primary=depth == 0, mesh=si.mesh,
                                 continues=continues)

                # With no emissive geometry, a ray whose next vertex cannot scatter finds nothing.
                if not scene.materials.has_emission and not np.any(continues):
                    next_state = None
                    n = 0

                # ---- sample the BSDF for the extension ray --------------------------------
            if n:
                # The extension ray leaving the D-th vertex can still find emission (pbrt's
                # convention), but the vertex it reaches scatters no further.
                deep_ok, first_ok = self.cont_from
                next_cont = np.where(continues & np.where(depth == 0, first_ok, deep_ok),
                                     np.where(depth == 0, 2, 1), 0).astype(np.int8)
                depth = depth + 1
                # Russian roulette, driven by throughput, from rr_depth on.
                rr = depth >= opt.rr_depth
                u_bsdf = rng.random((n, 3))
                u_rr = rng.random(n) if np.any(rr) else np.ones(n)
                if hasattr(bsdf, "path_scatter"):
                    # One compiled pass: sample_f, to world, beta update, validity, roulette.
                    wi, beta, pdf_b, ok = bsdf.path_scatter(wo_l, s, t, si.ns, si.ng, beta, u_bsdf[:, 0],
                                                            u_bsdf[:, 1:], u_rr, rr)
                else:
                    bs = bsdf.sample_f(wo_l, u_bsdf[:, 0], u_bsdf[:, 1:])
                    wi = to_world(bs.wi, s, t, si.ns)
                    pdf_b = bs.pdf
                    ok = (bs.pdf > 0.0) & (dot(wi, si.ng) > 0.0)
                    beta = beta * safe_div(bs.f * np.abs(bs.wi[:, 2])[:, None], bs.pdf)
                    # Column-wise tests: numpy's axis=1 reductions over (n, 3) cost several times more.
                    ok &= (((beta[:, 0] > 0.0) | (beta[:, 1] > 0.0) | (beta[:, 2] > 0.0))
                           & np.isfinite(beta[:, 0] + beta[:, 1] + beta[:, 2]))
                    if np.any(rr):
                        b_max = np.maximum(np.maximum(beta[:, 0], beta[:, 1]), beta[:, 2])
                        q = np.where(rr, np.clip(1.0 - b_max, 0.0, 0.95), 0.0)
                        ok &= u_rr >= q
                        beta = beta / (1.0 - q)[:, None]

                k = np.nonzero(ok)[0]
                next_prev = np.empty((k.size, 10))
                p_k, ng_k, wi_k = _t(si.p, k), _t(si.ng, k), _t(wi, k)
                next_prev[:, 0:3], next_prev[:, 3:6], next_prev[:, 6:9], next_prev[:, 9] = p_k, ng_k, _t(si.ns, k), pdf_b[k]
                next_state = (path[k], _t(beta, k), offset_origin(p_k, ng_k, wi_k, eps[k]), wi_k,
                              np.full(k.size, np.inf), depth[k], np.zeros(k.size, bool),
                              next_cont[k], next_prev, si.mesh[k])
                self.rays.add(extension=k.size)

            # ---- gather the rays that continue ---------------------------------------------
            states = [st for st in (next_state, pass_state) if st is not None and st[0].size]
            if not states:
                break
            path, beta, o, d, tmax, depth, unsampled, cont, prev, prev_mesh = (
                states[0] if len(states) == 1 else tuple(np.concatenate(x) for x in zip(*states)))
        return L

    # ---------------------------------------------------------------------- pieces
    def _interaction(self, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray, d: np.ndarray) -> Interaction:
        g = self.scene.geometry
        p, ng, ns, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, prim, b1, b2, d)
        return Interaction(p=p, ng=ng, ns=ns, wo=-d, st=st, mat=g.material[prim], mesh=g.mesh[prim], prim=prim)

    def _apply_normal_maps(self, si: Interaction, prim: np.ndarray, params) -> None:
        """Replace si.ns by the normal-mapped shading normals (bent_normals); prim: (n,) the
        rows' triangles."""
        si.ns = self.bent_normals(prim, si.mat, si.ns, si.ng, si.wo, params)

    def bent_normals(self, prim, mat, ns, ng, wo, params) -> np.ndarray:
        """The shading normals (n, 3) of n hits on triangles prim (n,) of materials mat (n,), with
        interpolated normals ns, geometric normals ng and directions to the viewer wo (n, 3),
        bent by the normal maps of params (materials.evaluate at the hits) on rows of
        normal-mapped materials with a UV frame (geometry.perturb_normals); ns elsewhere. The
        one place both integrators (this one and fast_path.FastPath) bend normals."""
        g, mats = self.scene.geometry, self.scene.materials
        if g.tangent is None:  # no triangle of a normal-mapped material
            return ns
        return perturb_normals(ns, ng, wo, params.normal, mats.normal_mapped[mat], prim, g.tangent, g.handed,
                               g.face_normal)

    def _add_light_hits(self, L, em: "_Emission", o, t_limit, seen) -> None:
        """Add emission of every finite light crossed before t_limit by the rows in ``seen``
        (lights are transparent, so a ray may cross several), weighted by em."""
        rows_u = np.nonzero(seen)[0]
        if rows_u.size == seen.size:  # every row (deeper continuation rays): no copies
            rows, light, t_hit = self._light_hits(o, em.d, t_limit)
        else:
            rows, light, t_hit = self._light_hits(o[rows_u], em.d[rows_u], t_limit[rows_u])
            rows = rows_u[rows]
        if rows.size == 0:
            return
        w = em.weight(rows, light)
        if not np.any(w > 0.0):
            return
        d_rows = _t(em.d, rows)
        Le = self.lights.le(light, _t(o, rows) + d_rows * t_hit[:, None], d_rows)
        add_rows(L, em.path[rows], _t(em.beta, rows) * (Le * w[:, None]))

    def _add_mesh_light_hits(self, L, em: "_Emission", prim, seen) -> None:
        """Emission of mesh lights whose triangle is the surface hit (prim (n,) embree ids) by the
        rows in ``seen``, weighted by em: mesh lights are geometry, so they are counted here, at
        the hit, and never by the light-crossing test (self.finite excludes them)."""
        rows = np.nonzero(seen & (prim >= 0))[0]
        if not rows.size:
            return
        light = self.scene.tri_light[prim[rows]]
        k = light >= 0
        rows, light = rows[k], light[k]
        if not rows.size:
            return
        w = em.weight(rows, light)
        if not np.any(w > 0.0):
            return
        cos_front = -dot(em.d[rows], self.scene.geometry.face_normal[prim[rows]])
        Le, _ = self.lights.surface_emission(light, cos_front, em.d[rows])
        add_rows(L, em.path[rows], _t(em.beta, rows) * (Le * w[:, None]))

    def _light_hits(self, o, d, t_limit):
        """All (row, light, t) with an exact light hit at t < t_limit."""
        lights = self.lights
        scene = self.scene
        if scene.light_accel is None:
            rows_l, lights_l, ts = [], [], []
            n = o.shape[0]
            for li in self.finite:
                idx = np.full(n, li, dtype=np.int64)
                t = lights.intersect(idx, o, d)
                hit = np.nonzero(t < t_limit)[0]
                if hit.size:
                    rows_l.append(hit)
                    lights_l.append(idx[hit])
                    ts.append(t[hit])
            self.rays.add(light_probe=n)
            if not rows_l:
                return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
            return np.concatenate(rows_l), np.concatenate(lights_l), np.concatenate(ts)
        # Many lights: walk the proxy BVH, confirming each candidate exactly. A ray may cross
        # several proxies, so continue past each candidate until the surface is reached.
        rows_l, lights_l, ts = [], [], []
        active = np.arange(o.shape[0])
        t_start = np.zeros(o.shape[0])
        last_light = np.full(o.shape[0], -1, dtype=np.int64)
        for _ in range(32):
            if not active.size:
                break
            oa = o[active] + d[active] * t_start[active, None]
            h = scene.light_accel.intersect(oa, d[active], t_limit[active] - t_start[active])
            self.rays.add(light_probe=active.size)
            got = h.hit
            active = active[got]
            if not active.size:
                break
            t_proxy = t_start[active] + h.t[got]
            owner = scene.light_owner[h.prim[got]]
            # Exact test from a point just before the proxy hit.
            back = 1e-6 * np.maximum(t_proxy, 1e-12) + scene.accel.ray_epsilon(o[active]) * 0.0
            o_seg = o[active] + d[active] * (t_proxy - back)[:, None]
            t_ex = lights.intersect(owner, o_seg, d[active]) + (t_proxy - back)
            ok = (t_ex < t_limit[active]) & ~((owner == last_light[active]) & (t_ex <= t_start[active] * (1 + 1e-9)))
            if np.any(ok):
                rows_l.append(active[ok])
                lights_l.append(owner[ok])
                ts.append(t_ex[ok])
                last_light[active[ok]] = owner[ok]
            # Continue just past this proxy triangle.
            t_start[active] = t_proxy * (1.0 + 1e-7) + 1e-9 * scene.accel.diagonal
        if not rows_l:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        rows = np.concatenate(rows_l)
        light = np.concatenate(lights_l)
        t = np.concatenate(ts)
        # A light found twice by one ray (two proxy faces) counts once.
        key = rows * (lights.count + 1) + light
        _, first = np.unique(key, return_index=True)
        return rows[first], light[first], t[first]

    def _add_escaped(self, L, em: "_Emission", escaped) -> None:
        rows = np.nonzero(escaped)[0]
        for li in self.infinite:
            light = np.full(rows.size, li, dtype=np.int64)
            w = em.weight(rows, light)
            if not np.any(w > 0.0):
                continue
            Le = self.lights.le_escaped(light, em.d[rows])
            add_rows(L, em.path[rows], _t(em.beta, rows) * (Le * w[:, None]))

    def _visible(self, p, ng, wi, dist, eps, accel=None, shadow=None, rng=None) -> np.ndarray:
        """Shadow rays: (m,) True where nothing blocks p -> p + wi * dist (dist may be inf).

        accel: the BVH to test (a light's shadowLink BVH), default the whole scene.
        shadow: the light group's ShadowAPI params (integrators/shadow_api.py), or None for
        plain rays; with them the result is a fractional visibility (m,) float in [0, 1].
        rng: draws the presence of cut-out surfaces along the ray (scenes with opacity only).
        """
        o = offset_origin(p, ng, wi, eps)
        # Stop short of the light's surface by a relative margin and the origin offset.
        t_max = np.where(np.isfinite(dist), dist * (1.0 - 1e-5) - eps, np.inf)
        return self.visible_from(o, wi, t_max, accel, shadow, rng)

    def visible_from(self, o, wi, t_max, accel=None, shadow=None, rng=None) -> np.ndarray:
        """_visible for shadow rays whose origins o (m, 3) are offset already and whose far
        limits t_max (m,) stop short of the light: (m,) bool, or float with ``shadow``; counted
        in rays.shadow (ShadowAPI's disabled shadows trace none). The fast path's shadow rays of
        lights with a shadowLink or ShadowAPI settings go through here too (fast_path.py)."""
        if shadow is not None:
            v, traced = shadow_visibility(accel or self.scene.accel, o, wi, t_max, shadow)
            self.rays.add(shadow=traced)
            return v
        self.rays.add(shadow=o.shape[0])
        if self.scene.materials.has_cutout:
            return self._visible_through_cutouts(o, wi, t_max, rng, accel)
        return ~(accel or self.scene.accel).occluded(o, wi, t_max)

    def _visible_through_cutouts(self, o, wi, t_max, rng, accel=None) -> np.ndarray:
        """Shadow rays that see cut-out surfaces as camera and BSDF rays do: each surface met is
        present with its presence probability (materials.presence_at, stochastic for opacity in
        (0, 1) with opacityThreshold 0), so E[visibility] = prod (1 - presence) along the ray and
        next-event estimation and the continuation ray (which passes through with the same
        probability) estimate the same integral. An opaque query would let an opacity-0 card
        block all light. Closest-hit queries, continuing past each absent surface (at most 64).
        o, wi: (m, 3); t_max: (m,); accel: a shadowLink BVH over a subset of the triangles
        (its ``tri_index`` maps them to the scene's), default the scene's. Returns (m,) bool."""
        accel = accel or self.scene.accel
        g, mats = self.scene.geometry, self.scene.materials
        tri_index = accel.tri_index
        if rng is None:  # a caller without its own stream (fixed, so results stay reproducible)
            rng = np.random.default_rng(0x5EED)
        visible = np.ones(o.shape[0], dtype=bool)
        o = np.array(o, dtype=np.float64)
        t_left = np.array(t_max, dtype=np.float64)
        # Rays an any-hit query finds clear are visible whatever the presence draws: only the
        # others walk their closest hits (most shadow rays in an open scene are clear).
        active = np.nonzero(accel.occluded(o, wi, t_left))[0]
        for _ in range(64):
            if not active.size:
                break
            h = accel.intersect(o[active], wi[active], t_left[active])
            hit = np.nonzero(h.prim >= 0)[0]
            if not hit.size:
                break
            rows, prim = active[hit], h.prim[hit]
            tri = prim if tri_index is None else tri_index[prim]
            p, ng, _, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, tri, h.b1[hit],
                                               h.b2[hit], wi[rows])
            through = rng.random(rows.size) >= mats.presence_at(g.material[tri], st)
            visible[rows[~through]] = False
            k = np.nonzero(through)[0]
            rows = rows[k]
            # Continue just past the surface (ng faces the ray, so the offset goes behind it).
            o_next = offset_origin(p[k], ng[k], wi[rows], accel.ray_epsilon(p[k], prim[k]))
            t_left[rows] -= dot(o_next - o[rows], wi[rows])
            o[rows] = o_next
            active = rows[t_left[rows] > 0.0]
        return visible

    def _tracer_for(self, shadow_group: int, rng=None):
        if shadow_group < 0:
            if rng is None or not self.scene.materials.has_cutout:
                return self._visible
            return lambda p, ng, wi, dist, eps: self._visible(p, ng, wi, dist, eps, rng=rng)
        accel = self.scene.shadow_accels[shadow_group]
        params = self.scene.shadow_params[shadow_group] if self.scene.shadow_params else None
        return lambda p, ng, wi, dist, eps: self._visible(p, ng, wi, dist, eps, accel, params, rng)

    def _direct(self, L, path, beta, ctx, bsdf, wo_l, s, t, eps, rng, primary, mesh, continues) -> None:
        """Direct lighting at n shading points: lights picked by the lighting service, each
        estimated by its own estimator with its own sample count (see the module docstring)."""
        n = path.size
        lights = self.lights
        sampler = self.scene.light_sampler
        if getattr(sampler, "exhaustive", False):
            # Every light at every point (the talk's small scenes): pmf 1 per pair.
            rows = np.repeat(np.arange(n), lights.count)
            light = np.tile(np.arange(lights.count, dtype=np.int64), n)
            pmf = np.ones(rows.size)
            # Several lights with the same estimator settings put one row twice in a group.
            repeats = lights.count > 1
        else:
            repeats = False
            light, pmf = sampler.sample(ctx, rng.random(n))
            rows = np.nonzero(pmf > 0.0)[0]
            light, pmf = light[rows], pmf[rows]
        if self.scene.illuminates is not None:
            # lightLink: a light never illuminates geometry its collection excludes.
            linked = self.scene.illuminates[light, mesh[rows]]
            rows, light, pmf = rows[linked], light[linked], pmf[linked]
        if not rows.size:
            return
        control = None  # c(wo), wanted by every estimator but the fused light half
        tok = self.est_token[light]
        N = np.where(primary[rows], self.est_samples[light], 1)
        alpha = self.est_alpha[light]
        # α = v̄ needs N >= 2: at deeper vertices (N = 1) the control variate uses α = 1.
        fallback = (N < 2) & (alpha != ALPHA_ONE) & (tok == TOKEN_CV)
        self.rule_counts["own_samples"] += int((primary[rows] & (tok == TOKEN_CV)).sum())
        self.rule_counts["alpha_one_fallback"] += int(fallback.sum())
        alpha = np.where(N < 2, ALPHA_ONE, alpha)
        heur = self.est_heuristic[light]
        # MIS with one sample, where the continuation ray supplies the BSDF half.
        half = self.cont_ok[light] & (N == 1) & continues[rows]
        self.rule_counts["continuation_mis"] += int(half.sum())
        group = self.scene.shadow_group[light] + 1 if self.scene.shadow_group is not None else np.zeros_like(light)
        key = ((((tok * 8 + alpha) * 4 + heur) * 4096 + np.minimum(N, 4095)) * (len(self.scene.shadow_accels) + 1)
               + group) * 2 + half
        # One key (the common case: one estimator setting at this depth) needs no grouping.
        one_key = key.size == 0 or key.min() == key.max()
        for k in (key[:1] if one_key else np.unique(key)):
            g = np.arange(key.size) if one_key else np.nonzero(key == k)[0]
            r = rows[g]
            token = ESTIMATOR_TOKENS[tok[g[0]]]
            est = REGISTRY[token]
            Nk = int(N[g[0]])
            trace = self._tracer_for(int(group[g[0]]) - 1, rng)
            fused = half[g[0]] and hasattr(bsdf, "path_light_half")
            if control is None and not fused:
                control = bsdf.diffuse_constant(wo_l)
            # rows is sorted; without repeated rows, n of them are exactly 0..n-1.
            if r.size == n and (not repeats or np.all(r == np.arange(n))):
                # One group covering every point in order (e.g. a single light): no row copies.
                q = DirectQuery(ctx, s, t, wo_l, bsdf, light[g], eps, control, pmf[g])
            else:
                q = DirectQuery(ctx.take(r), _t(s, r), _t(t, r), _t(wo_l, r), bsdf.take(r), light[g], eps[r],
                                None if control is None else _t(control, r), pmf[g])
            if fused:
                self._light_half(L, path[r], _t(beta, r), q, trace, rng.random((g.size, 2)), heur[g])
                continue
            u = DirectRandom.draw(rng, g.size, Nk)
            if half[g[0]]:
                res = mis_light_half(q, lights, trace, Nk, u, HEURISTIC_TOKENS[heur[g[0]]])
            else:
                res = est.estimate(q, lights, trace, Nk, u, ALPHA_TOKENS[alpha[g[0]]], HEURISTIC_TOKENS[heur[g[0]]])
            add_rows(L, path[r], _t(beta, r) * safe_div(res.Ld, pmf[g]))


    def _light_half(self, L, path, beta, q: DirectQuery, trace, u, heur) -> None:
        """The light half of continuation MIS (estimators.mis.mis_light_half) in one compiled pass
        over the BSDF (bsdf.path_light_half), then shadow rays only where the result is > 0.
        path, beta: (m,), (m, 3) of the query's rows (a path may repeat: every light at every
        point); u: (m, 2); heur: (m,) heuristic tokens."""
        lights = self.lights
        ctx = q.ctx
        ls = lights.sample_li(q.light, ctx, u)
        c = q.bsdf.path_light_half(q.wo_l, q.s, q.t, ctx.ns, ctx.n, ls.wi, ls.L, ls.pdf, lights.delta[q.light],
                                   q.pmf, heur == HEURISTIC_TOKENS.index("power"), beta)
        idx = np.nonzero((c[:, 0] > 0.0) | (c[:, 1] > 0.0) | (c[:, 2] > 0.0))[0]
        if idx.size:
            v = trace(_t(ctx.p, idx), _t(ctx.n, idx), _t(ls.wi, idx), ls.dist[idx], q.eps[idx])
            k = idx[v]
            add_rows(L, path[k], _t(c, k))


class _Emission:
    """How much of a light's emission a ray adds when it reaches that light.

    Unsampled rays (camera rays, and their cutout pass-throughs) add it in full. A continuation
    ray adds h(p_b, pmf·p_l) of it for the lights whose MIS BSDF half it carries at the vertex
    it left (cont > 0, see the module docstring), and nothing for the others, whose estimators
    covered them already. Arrays are the live rows of the tracing loop.
    """

    def __init__(self, integ: "PathIntegrator", path, beta, d, unsampled, cont, prev, prev_mesh, emit0=1.0):
        self.integ = integ
        self.emit0 = emit0  # weight of emission seen directly (unsampled rays; see trace_paths)
        self.path, self.beta, self.d = path, beta, d
        self.unsampled, self.cont, self.prev, self.prev_mesh = unsampled, cont, prev, prev_mesh

    def weight(self, rows: np.ndarray, light: np.ndarray) -> np.ndarray:
        """(m,) weight of each (row, light) pair's emission."""
        integ = self.integ
        w = self.unsampled[rows] * self.emit0
        cont = self.cont[rows]
        mis = (cont > 0) & integ.cont_ok[light] & ((cont == 1) | integ.samples_one[light])
        if integ.scene.illuminates is not None:
            mis &= integ.scene.illuminates[light, self.prev_mesh[rows]]
        k = np.nonzero(mis)[0]
        if not k.size:
            return w
        rk, lk = rows[k], light[k]
        pv = _t(self.prev, rk)
        ctx = ShadingContext(pv[:, 0:3], pv[:, 3:6], pv[:, 6:9])
        p_l = integ.lights.pdf_li(lk, ctx, _t(self.d, rk))
        sampler = integ.scene.light_sampler
        if not getattr(sampler, "exhaustive", False):
            p_l = p_l * sampler.pmf(ctx, lk)
        p_b = pv[:, 9]
        power = integ.est_heuristic[lk] == HEURISTIC_TOKENS.index("power")
        if np.all(power):  # the usual case: one heuristic, computed once
            w[k] = power_heuristic(1, p_b, 1, p_l)
        elif not np.any(power):
            w[k] = balance_heuristic(1, p_b, 1, p_l)
        else:
            w[k] = np.where(power, power_heuristic(1, p_b, 1, p_l), balance_heuristic(1, p_b, 1, p_l))
        return w


def _take(obj, mask):
    """Row-select every array field of a dataclass."""
    import dataclasses

    vals = {}
    for f_ in dataclasses.fields(obj):
        v = getattr(obj, f_.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1:
            v = v[mask] if mask.dtype == bool else _t(v, mask)
        vals[f_.name] = v
    return type(obj)(**vals)
