"""The fast path of the path tracer: one compiled vertex per bounce, for the common scene.

Where a scene needs none of the general integrator's machinery (renderer/integrators/path.py),
each bounce is two embree calls and one compiled kernel (``_vertex_kernels.vertex_kernel``)
instead of ~150 numpy passes. It estimates exactly what the general path estimates, with the
same sampling techniques and MIS weights; the tests (tests/integrators/test_fast_path.py, and
test_fast_path_estimators.py per estimator) z-test the two against each other.

A scene qualifies when it has
* only RectLights (untextured), SphereLights (treatAsPoint included), DiskLights, DistantLights
  and DomeLights (lat-long textured or constant, without portals), without ShapingAPI, ShadowAPI or
  light linking, with unit diffuse/specular multipliers, few enough for the exhaustive light
  sampler (every light at every vertex, pmf 1);
* any per-light estimator (lightSampling, bsdfSampling, mis with either heuristic and N samples,
  controlVariate with each alpha, ratio, or what `auto` picked), under path.py's rule: N =
  illum:samples at the first scattering vertex, 1 deeper. A light on `mis` with N = 1 at a
  vertex takes continuation MIS there (the light half in the kernel, the BSDF half on the
  extension ray); every other (vertex, light) pair gets its whole contribution from its estimator
  (estimators/compiled.py on the samples _vertex_kernels._direct_pair draws), and the extension
  ray adds nothing for that light. The control variate's and ratio's F (the analytic irradiance,
  lights/irradiance.py, numpy) is computed per bounce before the kernel for the hits that need it;
* UsdPreviewSurface materials without normal maps or cutouts: one packed BSDF row per material,
  or, where inputs are textured or surfaces emit, rows evaluated per hit before the kernel runs, no mesh lights, one camera ray per pixel and pass (emitter samples 1), and a
  maximum depth of at least 2.
``PathIntegrator.fast_path_reason`` says why a scene does not qualify (stats "fast_path").

One difference in the order of work, not in the estimate: at the last scattering vertex
(depth D - 1 for max depth D) the general path runs the full MIS estimator (a light sample and
a BSDF sample of its own) for mis lights with N = 1, while the fast path keeps continuation MIS
there too and traces the extension ray for the emission it finds, as pbrt does. Both are unbiased estimates of the same
direct light; the variance differs slightly.
"""

from __future__ import annotations

import numpy as np

from ..estimators import ALPHAS, TOKENS
from ..geometry import surface_interaction
from ..lights.base import ShadingContext
from ..lights.disk import CLOSE_RATIO as DISK_CLOSE_RATIO
from ..lights.light_set import KIND_NAMES
from ..lights.spherical_rect import GRAZING_NZ2, MIN_SOLID_ANGLE
from . import _vertex_kernels as vk

# The light kinds the vertex kernel serves: the finite ones in its order, then the infinite ones.
FAST_KINDS = ("rect", "sphere", "disk")
FAST_INFINITE = ("dome", "distant")


def fast_path_reason(integ) -> str:
    """'' when the integrator's scene and options qualify for the fast path (module docstring),
    else the first reason why not."""
    scene, lights, opt = integ.scene, integ.lights, integ.opt
    if not getattr(opt, "fast_path", True):
        return "disabled (--no-fast-path)"
    if not integ.has_lights:
        return "no lights"
    rect = KIND_NAMES.index("rect")
    if not np.all(np.isin(lights.kind_of, [KIND_NAMES.index(k) for k in FAST_KINDS + FAST_INFINITE])):
        return "a light other than a Rect, Sphere, Disk, Distant or DomeLight"
    rl = lights.kinds[rect]
    if np.any(rl.tex >= 0):
        return "a textured RectLight"
    dome = lights.kinds[KIND_NAMES.index("dome")]
    if np.any(getattr(dome, "has_portals", np.zeros(dome.count, bool))):
        return "dome portals"
    if not getattr(scene.light_sampler, "exhaustive", False):
        return "a stochastic light sampler"
    if lights.shaping is not None or scene.shadow_group is not None or scene.illuminates is not None:
        return "ShapingAPI, ShadowAPI or light linking"
    plain = ((lights.diffuse_scale == 1.0) & (lights.specular_scale == 1.0)
             & getattr(lights, "plain_shadows", np.ones(lights.count, dtype=bool))
             & getattr(lights, "transparent", np.ones(lights.count, dtype=bool)))
    if not np.all(plain):
        return "a light with a diffuse or specular multiplier or a ShadowAPI shadow"
    if scene.tri_light is not None or scene.tri_absorb is not None:
        return "mesh lights"
    if integ.emitter_samples != 1:
        return "emitter samples > 1"
    if opt.max_depth <= 1:
        # Direct lighting only: the general path traces no extension rays at all there, where
        # this one would trace one per pixel for the BSDF half (module docstring).
        return "max depth <= 1"
    mats = scene.materials
    if getattr(mats, "has_normal_map", False):
        return "normal-mapped materials"
    if mats.has_cutout:
        return "cut-out materials (opacity)"
    if not mats.params_needed and mats.packed_bsdf() is None:
        return "no packed UsdPreviewSurface rows"
    return ""


class FastPath:
    """The compiled-vertex tracer for one PathIntegrator (see the module docstring)."""

    def __init__(self, integ):
        self.integ = integ
        scene = integ.scene
        lights = integ.lights
        self.rect = lights.kinds[KIND_NAMES.index("rect")]
        self.sphere = lights.kinds[KIND_NAMES.index("sphere")]
        self.disk = lights.kinds[KIND_NAMES.index("disk")]
        # The global index of each rect, sphere and disk light (their uniforms and power flags).
        self.rect_light, self.sphere_light, self.disk_light = (
            np.ascontiguousarray(np.nonzero(lights.kind_of == KIND_NAMES.index(k))[0], dtype=np.int64)
            for k in FAST_KINDS)
        # Infinite lights as one table: domes (i_dome; lat-long textured or constant) then distant
        # lights; the domes' images (their texel-luminance distributions) ride along in self.images.
        dome, dist = (lights.kinds[KIND_NAMES.index(k)] for k in FAST_INFINITE)
        nd, nt = dome.count, dist.count
        self.inf_light = np.ascontiguousarray(np.concatenate(
            [np.nonzero(lights.kind_of == KIND_NAMES.index(k))[0] for k in FAST_INFINITE]), dtype=np.int64)
        self.inf = (np.concatenate([np.ones(nd, bool), np.zeros(nt, bool)]),
                    np.ascontiguousarray(np.concatenate([np.zeros((nd, 3)), np.reshape(dist.axis, (nt, 3))]),
                                         np.float64),
                    np.ascontiguousarray(np.concatenate([np.zeros(nd), np.reshape(dist.omc, nt)]), np.float64),
                    np.concatenate([np.zeros(nd, bool), np.reshape(dist.delta, nt).astype(bool)]),
                    np.ascontiguousarray(np.concatenate([np.reshape(dome.L, (nd, 3)), np.reshape(dist.L, (nt, 3))]),
                                         np.float64),
                    self.inf_light,
                    np.ascontiguousarray(np.concatenate([np.reshape(dome.tex, nd), np.full(nt, -1)]), np.int64),
                    np.ascontiguousarray(np.concatenate([np.reshape(dome.rot, (nd, 3, 3)), np.zeros((nt, 3, 3))]),
                                         np.float64))
        im = dome.images
        f64, i64 = np.float64, np.int64
        self.images = tuple(np.ascontiguousarray(a, dtype=t) for a, t in (
            (np.reshape(im.texels, (-1, 3)), f64), (im.offset, i64), (im.height, i64), (im.width, i64),
            (im.weight, f64), (im.total, f64), (im.row_cdf, f64), (im.row_cdf_start, i64), (im.col_cdf, f64),
            (im.col_cdf_start, i64)))
        mats = scene.materials
        # Textured inputs or emission: the material is evaluated per hit (st needed) and the
        # kernel reads per-hit rows; otherwise one packed row per material.
        self.per_hit = bool(mats.params_needed)
        # (The kernel reads the albedo tables as its own constants; packed_bsdf's are the same.)
        self.Pm = np.zeros((0, 0)) if self.per_hit else mats.packed_bsdf()[0]
        self.no_rows = np.zeros(0, dtype=np.int64)
        self.no_emission = np.zeros((0, 3))
        g = scene.geometry
        f64 = np.float64
        self.geo = (np.ascontiguousarray(g.vertices, dtype=f64), np.ascontiguousarray(g.face_normal, dtype=f64),
                    np.ascontiguousarray(g.normals, dtype=f64), np.ascontiguousarray(g.material, dtype=np.int64),
                    scene.accel.tri_mag)
        from ..estimators import HEURISTICS

        power = np.ascontiguousarray(integ.est_heuristic == HEURISTICS.index("power"))
        rl, sl, dl = self.rect, self.sphere, self.disk
        # The vertex kernel's scene arguments, in its order (fixed for the render).
        # The per-light estimators (see the module docstring): token, alpha, samples per light.
        self.est_tok = np.ascontiguousarray(integ.est_token, dtype=np.int64)
        self.est_alpha = np.ascontiguousarray(integ.est_alpha, dtype=np.int64)
        self.est_samples = np.ascontiguousarray(integ.est_samples, dtype=np.int64)
        # Lights whose estimator needs F (the control variate and ratio).
        self.needs_F = np.isin(self.est_tok, [TOKENS.index("controlVariate"), TOKENS.index("ratio")])
        self.tables = (
            *self.geo,
            rl.center, rl.ex, rl.ey, rl.x_hat, rl.y_hat, rl.edge_len, rl.n, rl.area, rl.L, rl.is_rectangle,
            rl.ex_dual, rl.ey_dual, self.rect_light, sl.center, sl.radius, sl.L, sl.delta, self.sphere_light,
            dl.center, dl.n, dl.u1, dl.u2, dl.e1, dl.e2, dl.s1, dl.s2, dl.area, dl.L, self.disk_light,
            DISK_CLOSE_RATIO, *self.inf, *self.images,
            power, MIN_SOLID_ANGLE, GRAZING_NZ2, integ.opt.rr_depth, *scene.accel.epsilon_terms())

    def trace(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, rng: np.random.Generator,
              max_depth: int) -> np.ndarray:
        """Radiance (m, 3) arriving at the origins o (m, 3) along -d: PathIntegrator.trace for a
        qualifying scene, with emit0 = 1."""
        integ = self.integ
        accel = integ.scene.accel
        nl = integ.lights.count
        m = o.shape[0]
        L = np.zeros((m, 3))
        path = np.arange(m, dtype=np.int64)
        depth = np.zeros(m, dtype=np.int64)
        unsampled = np.ones(m, dtype=bool)
        counts = np.zeros(4, dtype=np.int64)
        # The ray state, and the rays in embree's float32 format (the kernel writes the later
        # bounces' directly).
        S = np.empty((m, vk.NS))
        o32 = np.empty((m, 3), dtype=np.float32)
        d32 = np.empty((m, 3), dtype=np.float32)
        t32 = np.empty(m, dtype=np.float32)
        vk.start_kernel(np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64),
                        np.ascontiguousarray(tmax, dtype=np.float64), S, o32, d32, t32)
        pairs = 0
        # One stream key per bounce, drawn at once (a Generator call costs ~10 us).
        keys = rng.integers(0, 2 ** 63, size=max_depth + 1, dtype=np.int64)
        # Continuation MIS at the first vertex and deeper: MIS lights with N = 1 there (path.py's
        # rule; cont_ok: on mis, with no multiplier or shadow setting that rules it out).
        cont_at = [integ.cont_ok & integ.samples_one, integ.cont_ok.copy()]
        # The per-light estimators' uniforms: their own stream (plain scenes keep theirs as it was).
        keys2 = (rng.integers(0, 2 ** 63, size=max_depth + 1, dtype=np.int64) if not np.all(cont_at[0])
                 else np.zeros(max_depth + 1, dtype=np.int64))
        cv_tok = self.est_tok == TOKENS.index("controlVariate")
        one = ALPHAS.index("one")
        for bounce in range(max_depth + 1):
            n = path.size
            if not n:
                break
            prim, b1, b2 = accel.intersect_prepared(o32, d32, t32)
            Pm, mat_row, emission = self._surfaces(prim, b1, b2, S) if self.per_hit else (
                self.Pm, self.no_rows, self.no_emission)
            # The kernel draws its uniforms from this key (a counter-based stream, _uniform_pass).
            key = np.uint64(keys[bounce])
            n_path = np.empty(n, dtype=np.int64)
            n_depth = np.empty(n, dtype=np.int64)
            n_S = np.empty((n, vk.NS))
            n_o32 = np.empty((n, 3), dtype=np.float32)
            n_d32 = np.empty((n, 3), dtype=np.float32)
            n_t32 = np.empty(n, dtype=np.float32)
            est, est_out, cap = self._estimators(bounce, max_depth, cont_at, keys2[bounce], prim, b1, b2, S)
            sh_o = np.empty((n * cap, 3), dtype=np.float32)
            sh_d = np.empty((n * cap, 3), dtype=np.float32)
            sh_t = np.empty(n * cap, dtype=np.float32)
            sh_path = np.empty(n * cap, dtype=np.int64)
            sh_c = np.empty((n * cap, 3))
            vk.vertex_kernel(path, depth, unsampled, S, t32, prim, b1, b2, key, vk.U_LIGHT + 2 * nl, Pm, mat_row, emission, max_depth,
                             *self.tables, L, n_path, n_depth, n_S, n_o32, n_d32, n_t32, sh_o, sh_d, sh_t, sh_path,
                             sh_c, counts, est, est_out)
            k_next, k_sh, k_grp = int(counts[0]), int(counts[1]), int(counts[3])
            vertices = int(counts[2])
            cont = est[3]
            pairs += vertices * int(np.count_nonzero(cont))
            # The general path's rule counters (path.py _direct).
            if bounce == 0:
                integ.rule_counts["own_samples"] += vertices * int(np.count_nonzero(cv_tok))
            integ.rule_counts["alpha_one_fallback"] += vertices * int(np.count_nonzero(
                cv_tok & (self.est_alpha != one) & (est[2] < 2)))
            blocked = np.zeros(0, dtype=bool)
            if k_sh:
                blocked = accel.occluded_prepared(sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh])
                vk.add_unblocked_kernel(L, sh_path[:k_sh], sh_c[:k_sh], blocked)
            if k_grp:
                sh_x, sh_cov, g_int, g_f = est_out
                vk.resolve_groups_kernel(L, g_int[:k_grp], g_f[:k_grp], sh_x[:k_sh], sh_cov[:k_sh], blocked)
            integ.rays.add(shadow=k_sh, extension=k_next)
            path, depth, S = n_path[:k_next], n_depth[:k_next], n_S[:k_next]
            o32, d32, t32 = n_o32[:k_next], n_d32[:k_next], n_t32[:k_next]
            unsampled = np.zeros(k_next, dtype=bool)
        integ.rule_counts["continuation_mis"] += pairs
        return L

    def _estimators(self, bounce, max_depth, cont_at, key2, prim, b1, b2, S):
        """The vertex kernel's per-light estimator records for a bounce whose vertices have depth
        ``bounce`` (every row of a fast-path bounce has): est (tokens, alphas, N per light, on
        continuation MIS here, was at the vertex the rays left, E (n, lights, 3), exact (n,
        lights), the uniforms' key), est_out (each shadow ray's X (cap n, 3) and covered flag,
        the groups' (g, 5) int64 and (g, 6) records), and cap: shadow rays per row at most."""
        integ = self.integ
        nl = integ.lights.count
        n = prim.shape[0]
        N = self.est_samples if bounce == 0 else np.ones(nl, dtype=np.int64)
        cont = cont_at[min(bounce, 1)]
        cont_prev = cont_at[min(bounce - 1, 1)] if bounce > 0 else np.ones(nl, dtype=bool)
        own = ~cont
        # A light sample and a BSDF sample per sample on the estimator's lights, one light-half
        # ray on the others.
        cap = max(1, int(np.sum(np.where(own, 2 * N, 1))))
        want = own & self.needs_F if bounce < max_depth else np.zeros(nl, dtype=bool)
        E = np.zeros((n if want.any() else 0, nl, 3))
        exact = np.zeros((E.shape[0], nl), dtype=bool)
        if want.any():
            hit = np.nonzero(prim >= 0)[0]
            if hit.size:
                g = integ.scene.geometry
                p, ng, ns, _ = surface_interaction(g.vertices, g.face_normal, g.normals, g.st,
                                                   prim[hit].astype(np.int64), b1[hit], b2[hit],
                                                   np.ascontiguousarray(S[hit, vk.D:vk.D + 3]))
                ctx = ShadingContext(p, ng, ns)
                for li in np.nonzero(want)[0]:
                    E[hit, li], exact[hit, li] = integ.lights.irradiance(np.full(hit.size, li, dtype=np.int64), ctx)
        n_groups = n * int(np.count_nonzero(want))
        est = (self.est_tok, self.est_alpha, np.ascontiguousarray(N, dtype=np.int64), np.ascontiguousarray(cont),
               np.ascontiguousarray(cont_prev), E, exact, np.uint64(key2))
        est_out = (np.empty((n * cap, 3)), np.empty(n * cap), np.empty((n_groups, 5), dtype=np.int64),
                   np.empty((n_groups, 6)))
        return est, est_out, cap

    def _surfaces(self, prim, b1, b2, S):
        """Per-hit material rows for textured or emissive materials: (P (h, K) packed
        UsdPreviewSurface rows of the h hits, row (n,) int64 index into P per ray (-1: missed),
        emission (h, 3) radiance, or (0, 3) when no material emits)."""
        scene = self.integ.scene
        g = scene.geometry
        row = np.full(prim.shape[0], -1, dtype=np.int64)
        hit = np.nonzero(prim >= 0)[0]
        row[hit] = np.arange(hit.size)
        k = prim[hit].astype(np.int64)
        # Only st is wanted here; the kernel recomputes p and the normals itself (~18 ns a hit),
        # which keeps its per-row state small.
        _, _, _, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, k, b1[hit], b2[hit],
                                          np.ascontiguousarray(S[hit, vk.D:vk.D + 3]))
        mat = g.material[k]
        params = scene.materials.evaluate(mat, st)
        P = np.ascontiguousarray(scene.materials.bsdf(mat, params).packed)
        emission = (np.ascontiguousarray(params.emission, dtype=np.float64) if scene.materials.has_emission
                    else self.no_emission)
        return P, row, emission
