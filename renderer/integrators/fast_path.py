"""The fast path of the path tracer: one compiled vertex per bounce, for the common scene.

Where a scene needs none of the general integrator's machinery (renderer/integrators/path.py),
each bounce is two embree calls and one compiled kernel (``_vertex_kernels.vertex_kernel``)
instead of ~150 numpy passes. It estimates exactly what the general path estimates, with the
same sampling techniques and MIS weights; the tests (tests/integrators/test_fast_path.py, and
test_fast_path_estimators.py per estimator) z-test the two against each other.

A scene qualifies when it has
* no lights (emissive surfaces only, or black: the extension rays go on only where a surface
  emits, _trace_kernel.extension_useful), or only RectLights (textured ones by kernels/lights.py's
  rect_texel_* rows, off the vectorised batch sampler), SphereLights (treatAsPoint included),
  DiskLights, CylinderLights (treatAsLine included; renderer/kernels/cylinder.py's row functions),
  mesh lights (UsdLux MeshLightAPI, with the "oriented" triangle pick: kernels/mesh_light.py's
  rows; their emission is found where a ray hits one of their triangles, Scene.tri_light, and a
  noMaterialResponse one ends the path there, Scene.tri_absorb), DistantLights
  and DomeLights (lat-long textured or constant, with portals: kernels/portal.py's rows sample
  through them and give an escaped ray's pdf, as DomeLight does), ShapingAPI included (the kernel
  multiplies every light sample and every emission a ray sees by kernels/shaping.py's factor, the
  general path's), light linking (lightLink: the kernel skips a light at a vertex whose mesh it
  does not illuminate, and a continuation ray that left such a vertex adds none of its emission;
  shadowLink: the light's shadow rays are traced against its own BVH, scene.shadow_accels, by
  _trace_kernel.shadow_visibility_kernel), and ShadowAPI (lights with shadow:enable off, a shadow
  distance or falloff get their own shadow group like a shadowLink, traced by the same kernel
  with shadow_api.py's rules, and the blocked
  fraction of a shadow:color light's ray shows the colour: _vertex_kernels.add_visible_kernel),
  and any diffuse/specular multipliers (their lights' estimators apply them), under any lighting
  service: exhaustive
  (every light at every vertex, pmf 1), or uniform, power and bvh, which the kernel runs per row
  (renderer/kernels/light_pick.py: one pick per vertex, and the pmf replayed at the previous
  vertex for the MIS weight of a light the continuation ray reaches, as the general path's
  _Emission does; the lights a ray crosses come from a walk of the light BVH);
* any per-light estimator (lightSampling, bsdfSampling, mis with either heuristic and N samples,
  controlVariate with each alpha, ratio, or what `auto` picked), under path.py's rule: N =
  illum:samples at the first scattering vertex, 1 deeper. The service picks the light(s); a
  picked light on `mis` with N = 1 at a vertex takes continuation MIS there (the light half in
  the kernel weighted with pmf p_l, the BSDF half on the extension ray); every other picked
  (vertex, light) pair gets its whole contribution from its estimator (estimators/compiled.py on
  the samples _vertex_kernels._direct_pair draws) divided by the pmf, and the extension ray adds
  nothing for that light. A light with a diffuse or specular multiplier other than 1 is never on
  continuation MIS (path.py's cont_ok): its estimator scales the BSDF's lobes by them
  (_vertex_kernels._split_at, kernels.direct.split_kernel's rule). The control variate's and ratio's F (the analytic irradiance) is taken
  in the kernel for each (vertex, light) pair whose estimate uses it (_vertex_kernels._light_F:
  lights/irradiance.py's rule by the same compiled rows, about the bent shading normal);
* UsdPreviewSurface materials: one packed BSDF row per material, or, where inputs are textured,
  surfaces emit or normals are mapped, rows evaluated per hit by the vertex kernel itself
  (materials.surface_hits on FastPath.tex: the BSDF row, the emission and the bent shading normal
  of each hit, by the compiled rows MaterialTable.evaluate also runs); any maximum depth. With K
  emitter samples the K - 1
  extra camera rays are traced at depth 0, and the path-carrying ray's directly seen emission is
  weighted 1/K by PathIntegrator._trace_camera.

Cut-outs (opacity as presence, renderer/materials.py) as in the general path: a camera or
extension ray that finds a surface absent (one draw against its presence) goes on from just
behind it with its state unchanged; ``_through_cutouts`` walks only those rays on before the
kernel sees the bounce's hits, and hands the kernel the first present surface with its distance
from the ray's origin, so the lights the ray crosses on the way are counted as on one segment.
Shadow rays see cut-outs as the general path's ``_visible_through_cutouts`` does. Both walks are
compiled (_cutout_kernels.py, Embree called from the kernel) where accel.py has native Embree,
else numpy loops.
``PathIntegrator.fast_path_reason`` says why a scene does not qualify (stats "fast_path").

Where no bounce needs numpy work (``kernel_reason``: shadow groups are traced in compiled code,
_trace_kernel.shadow_visibility_kernel, and per-hit surfaces evaluated by the vertex kernel),
the whole bounce loop of a chunk of camera rays is one compiled call that traces Embree from
inside (renderer/integrators/_trace_kernel.py, packets of TRACE_WIDTH rays) and releases the GIL,
so render threads running chunks side by side scale; it makes the Python loop's calls with the
Python loop's keys, so the image is the same to the bit (tests/integrators/test_fast_path_kernel.py).

One difference in the order of work, not in the estimate: at the last scattering vertex
(depth D - 1 for max depth D) the general path runs the full MIS estimator (a light sample and
a BSDF sample of its own) for mis lights with N = 1, while the fast path keeps continuation MIS
there too and traces the extension ray for the emission it finds, as pbrt does. Both are unbiased estimates of the same
direct light; the variance differs slightly. That holds at max depth 1 (direct light only) too,
where the one vertex is the last: continuation MIS with its extension ray traced 4x the samples
per CPU-second of the lights' own estimators there (the Cornell box, 128x128: 1.1M against 0.26M;
the general path 0.46M; bench/results/shaping/shadow_groups_kernel.md). The extension rays that
leave the last scattering vertex are traced only where they can add something
(_trace_kernel.extension_useful: a light on continuation MIS there, or an emitting surface), so
a scene whose lights all take their own estimators there traces none at that bounce, and max
depth 0 only the camera rays.
"""

from __future__ import annotations

import numpy as np

from ..estimators import ALPHAS, TOKENS
from ..geometry import dot, offset_origin, surface_interaction
from ..lights.disk import CLOSE_RATIO as DISK_CLOSE_RATIO
from ..lights.light_set import KIND_NAMES
from ..lights.shaping import empty_kernel_record
from ..lights.spherical_rect import GRAZING_NZ2, MIN_SOLID_ANGLE
from . import _cutout_kernels as ck
from . import _trace_kernel as tk
from . import _vertex_kernels as vk

# The light kinds the vertex kernel serves: the finite ones in its order, then the infinite ones.
FAST_KINDS = ("rect", "sphere", "disk")
FAST_INFINITE = ("dome", "distant")
# (Cylinder and mesh lights, after the disks in its order, it serves through its light table
# only: their row functions in kernels/cylinder.py and kernels/mesh_light.py.)
CUTOUT_PASSES = ck.CUTOUT_PASSES
# Rays per Embree call inside trace_kernel (1: rtcIntersect1 / rtcOccluded1; 4, 8, 16: packets).
TRACE_WIDTH = 8


def fast_path_reason(integ) -> str:
    """'' when the integrator's scene and options qualify for the fast path (module docstring),
    else the first reason why not."""
    scene, lights, opt = integ.scene, integ.lights, integ.opt
    if not getattr(opt, "fast_path", True):
        return "disabled (--no-fast-path)"
    mesh = lights.kinds[KIND_NAMES.index("mesh")]
    if mesh.count and getattr(mesh, "pick_mode", "oriented") != "oriented":
        # (The kernel's rows replay the oriented triangle pick only; "area" is a test setting.)
        return "mesh lights with the area pick"
    mats = scene.materials
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
        # The domes' images, then the textured RectLights' (texrect: their image in this set).
        from ..lights.texture import ImageSet

        rl = lights.kinds[KIND_NAMES.index("rect")]
        im = ImageSet.concat(dome.images, rl.images) if rl.images.count else dome.images
        self.images = im.kernel_record()
        mats = scene.materials
        # Textured inputs, textured emission or normal maps: the material is evaluated per hit
        # (st needed) and the kernel reads per-hit rows; otherwise one packed row per material
        # (cut-outs alone change no row: presence is the walks' business), and constant emission
        # one radiance per material, which the kernel reads by the hit's material as it does Pm.
        self.per_hit = bool(mats.params_needed and ((mats.has_emission and not mats.emission_is_constant)
                                                    or mats.has_normal_map or not mats.bsdf_is_constant))
        self.cutouts = bool(mats.has_cutout)
        # (The kernel reads the albedo tables as its own constants; packed_bsdf's are the same.)
        self.Pm = np.zeros((0, 0)) if self.per_hit else mats.packed_bsdf()[0]
        self.no_rows = np.zeros(0, dtype=np.int64)
        self.no_emission = np.zeros((0, 3))
        self.no_normals = np.zeros((0, 3))
        # The kernel's surface record (vertex_kernel's surf) where it is fixed for the render.
        self.surf = (self.Pm, self.no_rows, (np.ascontiguousarray(mats.const["emission"], dtype=np.float64)
                                             if mats.has_emission and not self.per_hit else self.no_emission),
                     self.no_normals)
        g = scene.geometry
        # Per-hit surfaces: the record the vertex kernel evaluates each hit's row, emission and
        # bent normal from (materials.surface_hits; vertex_kernel's tex), else None.
        self.tex = mats.hit_record(g) if self.per_hit else None
        f64 = np.float64
        self.geo = (np.ascontiguousarray(g.vertices, dtype=f64), np.ascontiguousarray(g.face_normal, dtype=f64),
                    np.ascontiguousarray(g.normals, dtype=f64), np.ascontiguousarray(g.material, dtype=np.int64),
                    scene.accel.tri_mag)
        self.walk = self._cutout_walk() if self.cutouts else None
        from ..estimators import HEURISTICS

        power = np.ascontiguousarray(integ.est_heuristic == HEURISTICS.index("power"))
        # The lighting service's record (light_pick.py), and each global light's index in the
        # kernel's order (rect, sphere, disk, then infinite lights).
        from ..light_samplers import make_light_sampler, pick_tables

        # (A scene without lights has no service to pick with: the exhaustive one visits none.)
        sampler = scene.light_sampler if lights.count else make_light_sampler("exhaustive", lights)
        self.picks = not getattr(sampler, "exhaustive", False)
        self.sp = pick_tables(sampler, lights)
        # Cylinder lights (treatAsLine included): their packed rows (renderer/kernels/cylinder.py),
        # radiance and global index, the kernel's cyl record.
        cy = lights.kinds[KIND_NAMES.index("cylinder")]
        self.cyl_light = np.ascontiguousarray(np.nonzero(lights.kind_of == KIND_NAMES.index("cylinder"))[0],
                                              dtype=np.int64)
        self.cyl = (np.ascontiguousarray(cy.packed.reshape(-1, vk.NCY)),
                    np.ascontiguousarray(np.reshape(cy.L, (-1, 3))), self.cyl_light)
        self.mesh_light = np.ascontiguousarray(np.nonzero(lights.kind_of == KIND_NAMES.index("mesh"))[0],
                                               dtype=np.int64)
        self.mesh = self._mesh_record(lights.kinds[KIND_NAMES.index("mesh")])
        fast_of = np.full(lights.count, -1, dtype=np.int64)
        order = np.concatenate([self.rect_light, self.sphere_light, self.disk_light, self.cyl_light, self.mesh_light,
                                self.inf_light])
        fast_of[order] = np.arange(order.size)
        # The UsdLux record (vertex_kernel's lux): ShapingAPI, each global light's row in the
        # shaping table (-1: unshaped) and the table's kernel arrays (lights/shaping.py).
        # lightLink: each triangle's mesh and illuminates[light, mesh] ((0, 0): no linking).
        sh = lights.shaping
        self.lux = (np.ascontiguousarray(sh.row_of[:lights.count] if sh is not None else np.full(lights.count, -1),
                                         dtype=np.int64),
                    sh.kernel_record() if sh is not None else empty_kernel_record(),
                    np.ascontiguousarray(g.mesh, dtype=np.int64),
                    np.ascontiguousarray(scene.illuminates if scene.illuminates is not None
                                         else np.zeros((0, 0), dtype=bool)))
        # Shadow rays of lights with a shadowLink or ShadowAPI settings (scene.shadow_group >= 0)
        # or a shadow colour are traced by _visibility; the others as before (_blocked).
        self.order = order
        self.shadow_group = (scene.shadow_group if scene.shadow_group is not None
                             else np.full(lights.count, -1, dtype=np.int64))
        self.shadow_tint = lights.shadow_tint
        self.lux_shadows = scene.shadow_group is not None or lights.shadow_tint is not None
        rl, sl, dl = self.rect, self.sphere, self.disk
        self.fcalc = self._f_record(order, dome, dist)
        # The lights' diffuse and specular multipliers in kernel order (their estimators apply them).
        self.mult = (np.ascontiguousarray(lights.diffuse_scale[order], dtype=np.float64),
                     np.ascontiguousarray(lights.specular_scale[order], dtype=np.float64))
        # Dome portals (DomeLight.portal_record, and each dome's first portal row and count:
        # kernels/portal.py's rows sample through them and give the escaped rays' pdf) and the
        # RectLights' textures (each rect's image in self.images, after the domes', or -1:
        # kernels/lights.py's rect_texel_* rows).
        self.portal = (*dome.portal_record(), np.ascontiguousarray(dome.portal_start, dtype=np.int64),
                       np.ascontiguousarray(dome.portal_count, dtype=np.int64))
        self.texrect = np.ascontiguousarray(np.where(rl.tex >= 0, rl.tex + dome.images.count, -1), dtype=np.int64)
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
            power, MIN_SOLID_ANGLE, GRAZING_NZ2, integ.opt.rr_depth, *scene.accel.epsilon_terms(), fast_of, self.sp,
            self.lux, self.fcalc, self.mult, self.cyl, self.mesh, self.portal, self.texrect, self.tex)
        # The per-light estimators by vertex depth (first, deeper), for both bounce loops.
        self.cont_at = [integ.cont_ok & integ.samples_one, integ.cont_ok.copy()]
        self.plan = self._plan()
        self._kernel = None  # trace_kernel's fixed arguments (_kernel_args), made on first use
        self._roles = self.sobol_roles()

    def _bounce_plan(self, bounce: int):
        """The estimators at the vertices of a bounce whose rows have depth ``bounce``: N (lights,)
        samples per light, cont and cont_prev (lights,) bool (on continuation MIS there, and at
        the vertex the rays left), cap: shadow rays a row may write, groups: the estimator groups
        (F's diffuse combinations) a row may write below the last bounce."""
        nl = self.integ.lights.count
        N = self.est_samples if bounce == 0 else np.ones(nl, dtype=np.int64)
        cont = self.cont_at[min(bounce, 1)]
        cont_prev = self.cont_at[min(bounce - 1, 1)] if bounce > 0 else np.ones(nl, dtype=bool)
        own = ~cont
        # A light sample and a BSDF sample per sample on the estimator's lights, one light-half
        # ray on the others: for every light, or for the one a picking service chose.
        per_light = np.where(own, 2 * N, 1)
        cap = max(1, int(per_light.max() if self.picks else per_light.sum()))
        n_f = int(np.count_nonzero(own & self.needs_F))
        groups = min(1, n_f) if self.picks else n_f
        return N, cont, cont_prev, cap, groups

    def _plan(self):
        """trace_kernel's estimator record (its docstring): the bounce plans of the first vertex
        and deeper ones, and the masks of the general path's rule counters."""
        first, deeper = self._bounce_plan(0), self._bounce_plan(1)
        cv = self.est_tok == TOKENS.index("controlVariate")
        fallback = np.stack([cv & (self.est_alpha != ALPHAS.index("one")) & (p[0] < 2) for p in (first, deeper)])
        c = np.ascontiguousarray
        return (self.est_tok, self.est_alpha, c(np.stack([first[0], deeper[0]]), dtype=np.int64),
                c(np.stack([first[2], first[1], deeper[1]]), dtype=np.bool_),
                np.array([first[3], deeper[3]], dtype=np.int64), np.array([first[4], deeper[4]], dtype=np.int64),
                c(cv), c(fallback), bool(self.integ.scene.materials.has_emission))

    def kernel_reason(self) -> str:
        """'' when trace runs as one compiled call (_trace_kernel.trace_kernel), else why this
        scene keeps the Python bounce loop (numpy work between the compiled calls)."""
        if self.integ.scene.accel.backend != "native":
            return "no native Embree"
        if self.cutouts and self.walk is None:
            return "cut-outs without the compiled walks"
        return ""

    def _keys(self, rng: np.random.Generator, max_depth: int):
        """The stream keys of a trace, drawn at once (a Generator call costs ~10 us): the
        vertex kernel's and the per-light estimators' (their own stream; plain scenes keep theirs
        as it was) per bounce (max_depth + 1,) int64, and the cut-out walks' (max_depth + 1, 2)
        (camera and extension rays, shadow rays)."""
        keys = rng.integers(0, 2 ** 63, size=max_depth + 1, dtype=np.int64)
        keys2 = (rng.integers(0, 2 ** 63, size=max_depth + 1, dtype=np.int64) if not np.all(self.cont_at[0])
                 else np.zeros(max_depth + 1, dtype=np.int64))
        ckeys = (rng.integers(0, 2 ** 63, size=(max_depth + 1, 2), dtype=np.int64) if self.cutouts
                 else np.zeros((max_depth + 1, 2), dtype=np.int64))
        return keys, keys2, ckeys

    def _kernel_args(self):
        """trace_kernel's arguments fixed for the render: (emb, surf, tables, plan, walk, shadows)."""
        if self._kernel is None:
            scene = self.integ.scene
            emb = (*scene.accel.packet_handles(TRACE_WIDTH), TRACE_WIDTH)
            self._kernel = (emb, self.surf, self.tables, self.plan, self.walk if self.cutouts else None,
                            self._shadow_record())
        return self._kernel

    def _shadow_record(self):
        """_trace_kernel.shadow_visibility_kernel's record of the shadow groups (its docstring),
        or None for a scene whose shadow rays are all plain and untinted: each light's group in
        the kernel's order (-1: the scene BVH, plain rays), each light's shadow:color (0: black
        shadows), and per group (scene.shadow_group, shadow_accels, shadow_params) the Embree
        scene of its shadowLink BVH, its ShadowAPI mode and (distance, falloff, gamma), and for
        scenes with cut-outs the cut-out walks' geometry of the triangles its BVH holds (in its
        own triangle order, from offset off[g]) with its ray epsilon terms."""
        if not self.lux_shadows:
            return None
        scene = self.integ.scene
        lights = self.integ.lights
        grp = np.ascontiguousarray(self.shadow_group[self.order], dtype=np.int64)
        tint = np.ascontiguousarray(self.shadow_tint[self.order] if self.shadow_tint is not None
                                    else np.zeros((lights.count, 3)), dtype=np.float64)
        accels = scene.shadow_accels
        n_g = len(accels)
        g_scene = np.array([a.packet_handles(TRACE_WIDTH)[0] for a in accels], dtype=np.int64)
        g_mode = np.zeros(n_g, dtype=np.int64)
        g_par = np.zeros((n_g, 3))
        for g in range(n_g):
            p = scene.shadow_params[g] if scene.shadow_params else None
            if p is None:
                g_mode[g] = tk.SH_PLAIN
            elif not p.enable:
                g_mode[g] = tk.SH_OFF
            else:
                g_mode[g] = tk.SH_FADE if p.falloff > 0.0 else tk.SH_NEAR
                g_par[g] = p.distance, p.falloff, p.gamma
        # The cut-out walks' geometry per group: the scene's arrays at the BVH's triangles.
        tris = [a.tri_index if a.tri_index is not None else np.arange(a.count) for a in accels] if self.cutouts \
            else [np.zeros(0, dtype=np.int64)] * n_g
        sel = np.concatenate([np.zeros(0, dtype=np.int64), *tris]).astype(np.int64)
        off = np.concatenate([[0], np.cumsum([t.size for t in tris])]).astype(np.int64)
        vertices, face_normal, normals, tri_mat, tri_mag = self.geo
        st = np.asarray(scene.geometry.st, dtype=np.float64) if self.cutouts else np.zeros((0, 3, 2))
        g_geo = (off, *(np.ascontiguousarray(a[sel]) for a in (vertices, face_normal, normals, st, tri_mat, tri_mag)))
        g_eps = np.array([a.epsilon_terms() for a in accels], dtype=np.float64).reshape(n_g, 3)
        return grp, tint, g_scene, g_mode, g_par, g_geo, g_eps

    def _count_traced(self, tally) -> None:
        """Add the BVH queries of a tally (trace_kernel's, shadow_visibility_kernel's) to the
        Accels that answered them: the scene's, and each shadow group's (from N_TALLY on)."""
        scene = self.integ.scene
        scene.accel.count_traced(tally[tk.T_INTERSECT], tally[tk.T_OCCLUDED])
        for g, a in enumerate(scene.shadow_accels):
            a.count_traced(tally[tk.N_TALLY + 2 * g], tally[tk.N_TALLY + 2 * g + 1])

    def _mesh_record(self, ml) -> tuple:
        """The kernel's mesh record: (MeshLight.compiled_record(), global index of each mesh
        light, and per scene triangle (T,): its mesh light's global index or -1
        (Scene.tri_light), its triangle in the record or -1 where the light's triangles are not
        its mesh's one for one (the kernel then finds it by exact tests), and whether it absorbs
        (Scene.tri_absorb))."""
        scene = self.integ.scene
        T = scene.geometry.vertices.shape[0]
        if scene.tri_light is None:
            return (ml.compiled_record(), self.mesh_light, np.zeros(0, np.int64), np.zeros(0, np.int64),
                    np.zeros(0, bool))
        prim_light = np.ascontiguousarray(scene.tri_light, dtype=np.int64)
        prim_tri = np.full(T, -1, dtype=np.int64)
        local = self.integ.lights.local_of
        for gl in self.mesh_light:
            j = int(local[gl])
            prims = np.nonzero(prim_light == gl)[0]
            s, c = int(ml.start[j]), int(ml.tri_count[j])
            # The reader hands the light its mesh's triangles in order (lights/mesh.py).
            if prims.size == c and np.allclose(scene.geometry.vertices[prims], ml.tris[s:s + c], rtol=1e-6,
                                               atol=1e-6 * max(float(ml.size[j]), 1e-30)):
                prim_tri[prims] = s + np.arange(c)
        absorb = (np.ascontiguousarray(scene.tri_absorb, dtype=bool) if scene.tri_absorb is not None
                  else np.zeros(T, bool))
        return ml.compiled_record(), self.mesh_light, prim_light, prim_tri, absorb

    def sobol_roles(self) -> np.ndarray:
        """(n_u, 2) int64: each uniform column's dimension pair (its first column) and coordinate
        in it, for the low-discrepancy numbers (kernels/sobol.py): the BSDF direction's two
        columns and each light sample's two are pairs; the lobe, the roulette and a picking
        service's pick are 1D."""
        n_u = self.n_u
        roles = np.zeros((n_u, 2), dtype=np.int64)
        roles[:, 0] = np.arange(n_u)
        first = vk.U_LIGHT + (1 if self.picks else 0)
        for a in (vk.U_DIR, *range(first, n_u - 1, 2)):
            roles[a + 1] = (a, 1)
        return roles

    @property
    def n_u(self) -> int:
        """Uniforms per row: the lobe's, the direction's two, the roulette's, then two per light,
        or the pick's and one light sample's two."""
        return vk.U_LIGHT + (3 if self.picks else 2 * self.integ.lights.count)

    def _lds(self, pixels, m: int):
        """trace_kernel's lds record for m rows: pixels = (pixel keys (m,) uint64, pass index)
        from PathIntegrator.trace_paths, or None for independent streams."""
        if pixels is None:
            return np.zeros(0, dtype=np.uint64), np.uint64(0), self._roles
        pix, index = pixels
        if pix.shape[0] != m:
            raise ValueError(f"{pix.shape[0]} pixel keys for {m} rays")
        return np.ascontiguousarray(pix, dtype=np.uint64), np.uint64(index), self._roles

    def trace(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, rng: np.random.Generator,
              max_depth: int, pixels=None) -> np.ndarray:
        """Radiance (m, 3) arriving at the origins o (m, 3) along -d: PathIntegrator.trace for a
        qualifying scene, with emit0 = 1. One compiled call (_trace_kernel) where kernel_reason
        finds none, else the bounce loop in Python; both give the same image. pixels: (keys (m,)
        uint64, pass index) of the rays' pixels (kernels/sobol.pixel_keys): the bounces draw
        those pixels' low-discrepancy numbers; None: independent numbers from rng."""
        keys = self._keys(rng, max_depth)
        lds = self._lds(pixels, o.shape[0])
        if self.kernel_reason():
            return self.trace_loop(o, d, tmax, rng, max_depth, *keys, lds=lds)
        return self.trace_compiled(o, d, tmax, max_depth, *keys, lds=lds)

    def trace_compiled(self, o, d, tmax, max_depth, keys, keys2, ckeys, lds=None) -> np.ndarray:
        """trace as one call of _trace_kernel.trace_kernel (GIL released), with the keys of _keys."""
        integ = self.integ
        emb, surf, tables, plan, walk, shadows = self._kernel_args()
        n_u = self.n_u
        L = np.zeros((o.shape[0], 3))
        tally = np.zeros(tk.N_TALLY + 2 * len(integ.scene.shadow_accels), dtype=np.int64)
        tk.trace_kernel(emb, np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64),
                        np.ascontiguousarray(tmax, dtype=np.float64), keys, keys2, ckeys, n_u, max_depth, surf, tables,
                        plan, walk, L, tally, shadows, self._lds(None, 0) if lds is None else lds)
        integ.rays.add(shadow=tally[tk.T_SHADOW], extension=tally[tk.T_EXTENSION])
        with integ.rays.lock:
            for name, t in (("continuation_mis", tk.T_CONTINUATION), ("own_samples", tk.T_OWN_SAMPLES),
                            ("alpha_one_fallback", tk.T_ALPHA_ONE_FALLBACK)):
                integ.rule_counts[name] += int(tally[t])
        self._count_traced(tally)
        return L

    def trace_loop(self, o, d, tmax, rng, max_depth, keys, keys2, ckeys, lds=None) -> np.ndarray:
        """trace with the bounce loop in Python, each bounce's compiled calls and numpy work in
        turn, with the keys of _keys (rng: the numpy cut-out walks' draws)."""
        integ = self.integ
        accel = integ.scene.accel
        nl = integ.lights.count
        n_u = self.n_u
        lds = self._lds(None, 0) if lds is None else lds
        m = o.shape[0]
        L = np.zeros((m, 3))
        path = np.arange(m, dtype=np.int64)
        depth = np.zeros(m, dtype=np.int64)
        unsampled = np.ones(m, dtype=bool)
        counts = np.zeros(4 + nl, dtype=np.int64)
        # The ray state, and the rays in embree's float32 format (the kernel writes the later
        # bounces' directly).
        S = np.empty((m, vk.NS))
        o32 = np.empty((m, 3), dtype=np.float32)
        d32 = np.empty((m, 3), dtype=np.float32)
        t32 = np.empty(m, dtype=np.float32)
        vk.start_kernel(np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64),
                        np.ascontiguousarray(tmax, dtype=np.float64), S, o32, d32, t32)
        pairs = 0
        # Continuation MIS at the first vertex and deeper: MIS lights with N = 1 there (path.py's
        # rule; cont_ok: on mis, with no multiplier or shadow setting that rules it out).
        cont_at = self.cont_at
        cv_tok = self.est_tok == TOKENS.index("controlVariate")
        one = ALPHAS.index("one")
        for bounce in range(max_depth + 1):
            n = path.size
            if not n:
                break
            prim, b1, b2 = accel.intersect_prepared(o32, d32, t32)
            if self.cutouts:
                self._through_cutouts(prim, b1, b2, t32, d32, S, rng, ckeys[bounce, 0])
            surf = self.surf
            # The kernel draws its uniforms from this key (a counter-based stream, _uniform_pass).
            key = np.uint64(keys[bounce])
            n_path = np.empty(n, dtype=np.int64)
            n_depth = np.empty(n, dtype=np.int64)
            n_S = np.empty((n, vk.NS))
            n_o32 = np.empty((n, 3), dtype=np.float32)
            n_d32 = np.empty((n, 3), dtype=np.float32)
            n_t32 = np.empty(n, dtype=np.float32)
            est, est_out, cap = self._estimators(bounce, max_depth, cont_at, keys2[bounce], n)
            sh_o = np.empty((n * cap, 3), dtype=np.float32)
            sh_d = np.empty((n * cap, 3), dtype=np.float32)
            sh_t = np.empty(n * cap, dtype=np.float32)
            sh_path = np.empty(n * cap, dtype=np.int64)
            sh_c = np.empty((n * cap, 3))
            counts[:] = 0
            # _vertex_kernels.lds_at's record, built here: numba would hand its uint64s back to
            # Python as ints, which the kernel would then type as int64.
            vk.vertex_kernel(path, depth, unsampled, S, t32, prim, b1, b2, key,
                             (lds[0], lds[1], np.uint64(bounce * n_u), lds[2]), n_u, surf, max_depth,
                             *self.tables, L, n_path, n_depth, n_S, n_o32, n_d32, n_t32, sh_o, sh_d, sh_t, sh_path,
                             sh_c, counts, est, est_out)
            k_next, k_sh, k_grp = int(counts[0]), int(counts[1]), int(counts[3])
            if not tk.extension_useful(bounce, max_depth, est[3], self.plan[-1]):
                k_next = 0
            # The (vertex, light) pairs each light got at this bounce (all, or the picked ones).
            per_light = counts[4:]
            cont = est[3]
            pairs += int(per_light[cont].sum())
            # The general path's rule counters (path.py _direct).
            if bounce == 0:
                integ.rule_counts["own_samples"] += int(per_light[cv_tok].sum())
            integ.rule_counts["alpha_one_fallback"] += int(per_light[cv_tok & (self.est_alpha != one)
                                                                     & (est[2] < 2)].sum())
            blocked = np.zeros(0, dtype=bool)
            v = np.zeros(0)
            traced = k_sh
            if k_sh and self.lux_shadows and accel.backend == "native":
                # The shadow groups by trace_kernel's own call (the same rays, keys and counts).
                emb, _, _, _, walk, shadows = self._kernel_args()
                v, tint = np.empty(k_sh), np.empty((k_sh, 3))
                tally = np.zeros(tk.N_TALLY + 2 * len(integ.scene.shadow_accels), dtype=np.int64)
                tk.shadow_visibility_kernel(emb, np.uint64(ckeys[bounce, 1]), sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh],
                                            est_out[4][:k_sh], walk, shadows, v, tint, tally)
                self._count_traced(tally)
                traced = int(tally[tk.T_SHADOW])
                vk.add_visible_kernel(L, sh_path[:k_sh], sh_c[:k_sh], v, tint)
            elif k_sh and self.lux_shadows:
                v, tint, traced = self._visibility(sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh], est_out[4][:k_sh], rng,
                                                   ckeys[bounce, 1])
                vk.add_visible_kernel(L, sh_path[:k_sh], sh_c[:k_sh], v, tint)
            elif k_sh:
                blocked = self._blocked(sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh], rng, ckeys[bounce, 1])
                vk.add_unblocked_kernel(L, sh_path[:k_sh], sh_c[:k_sh], blocked)
            if k_grp:
                sh_x, sh_cov, g_int, g_f = est_out[:4]
                if self.lux_shadows:
                    vk.resolve_groups_visible_kernel(L, g_int[:k_grp], g_f[:k_grp], sh_x[:k_sh], sh_cov[:k_sh], v)
                else:
                    vk.resolve_groups_kernel(L, g_int[:k_grp], g_f[:k_grp], sh_x[:k_sh], sh_cov[:k_sh], blocked)
            integ.rays.add(shadow=traced, extension=k_next)
            path, depth, S = n_path[:k_next], n_depth[:k_next], n_S[:k_next]
            o32, d32, t32 = n_o32[:k_next], n_d32[:k_next], n_t32[:k_next]
            unsampled = np.zeros(k_next, dtype=bool)
        integ.rule_counts["continuation_mis"] += pairs
        return L

    def _f_record(self, order, dome, dist):
        """The analytic integrals' record for _vertex_kernels._light_F, lights in the kernel's
        order (``order``: their global indices): (exact (lights,) bool: irradiance.py's rule,
        has_exact_integral, and for a textured dome its table; theta_max (lights,) of the
        distant lights (0 elsewhere); the quadrature switches FAR_RATIO and KAPPA_MAX as the
        numpy API passes them; the domes' preconvolved tables, preconvolve.pack_tables, table j
        for dome j (empty for a constant dome))."""
        from ..lights import analytic
        from ..lights.irradiance import has_exact_integral
        from ..preconvolve import pack_tables

        lights = self.integ.lights
        tables = list(getattr(dome, "irradiance", [None] * dome.count))
        exact = has_exact_integral(lights)
        for gl in np.nonzero(lights.kind_of == KIND_NAMES.index("dome"))[0]:
            # A textured dome without a table has no exact F (DomeLight.irradiance_lookup's ok).
            j = lights.local_of[gl]
            exact[gl] &= bool(dome.tex[j] < 0 or tables[j] is not None)
        theta = np.zeros(lights.count)
        theta[np.nonzero(lights.kind_of == KIND_NAMES.index("distant"))[0]] = np.reshape(dist.theta_max, dist.count)
        return (np.ascontiguousarray(exact[order]), np.ascontiguousarray(theta[order], dtype=np.float64),
                float(analytic.FAR_RATIO), float(analytic.KAPPA_MAX), pack_tables(tables))

    def _estimators(self, bounce, max_depth, cont_at, key2, n):
        """The vertex kernel's per-light estimator records for a bounce whose vertices have depth
        ``bounce`` (every row of a fast-path bounce has): est (tokens, alphas, N per light, on
        continuation MIS here, was at the vertex the rays left, the uniforms' key), est_out (each
        shadow ray's X (cap n, 3) and covered flag, the groups' (g, 5) int64 and (g, 6) records,
        each shadow ray's light (cap n,) int64 in the kernel's order), and cap: shadow rays per
        row at most. (F is taken in the kernel, _vertex_kernels._light_F.)"""
        N, cont, cont_prev, cap, groups = self._bounce_plan(bounce)
        n_groups = n * groups if bounce < max_depth else 0
        est = (self.est_tok, self.est_alpha, np.ascontiguousarray(N, dtype=np.int64), np.ascontiguousarray(cont),
               np.ascontiguousarray(cont_prev), np.uint64(key2))
        est_out = (np.empty((n * cap, 3)), np.empty(n * cap), np.empty((n_groups, 5), dtype=np.int64),
                   np.empty((n_groups, 6)), np.empty(n * cap, dtype=np.int64))
        return est, est_out, cap

    def _cutout_walk(self):
        """The compiled cut-out walks' scene record (_cutout_kernels: fns, geo, cut, tab, eps),
        or None where accel.py traces through embreex only (the numpy loops serve then)."""
        scene = self.integ.scene
        try:
            h = scene.accel.native_handles()
        except RuntimeError:
            return None
        vertices, face_normal, normals, tri_mat, tri_mag = self.geo
        mats = scene.materials
        return ((h.scene, h.intersect1, h.occluded1),
                (vertices, face_normal, normals, np.ascontiguousarray(scene.geometry.st, dtype=np.float64), tri_mat,
                 tri_mag),
                np.ascontiguousarray(mats.cutout_materials), mats.surface_record(), scene.accel.epsilon_terms())

    def _through_cutouts(self, prim, b1, b2, t32, d32, S, rng, key) -> None:
        """Camera and extension rays pass through absent cut-out surfaces, as in the general
        path (PathIntegrator.trace): each hit on a material that may be cut out is present with
        its presence (materials.presence_at) against one uniform; a ray whose surface is absent
        is traced on from just behind it, until a present surface or a miss (at most
        CUTOUT_PASSES surfaces). Updates in place the closest hits prim, b1, b2 (n,) and the hit
        distances t32 (n,) float32, measured from the ray's origin S[:, O] along d32 (n, 3)."""
        if self.walk is None:
            self._through_cutouts_numpy(prim, b1, b2, t32, d32, S, rng)
            return
        fns, geo, cut, tab, eps = self.walk
        traced = ck.through_cutouts_kernel(fns, np.uint64(key), S, d32, prim, b1, b2, t32, geo, cut, tab, eps)
        self.integ.rays.add(extension=traced)

    def _through_cutouts_numpy(self, prim, b1, b2, t32, d32, S, rng) -> None:
        """_through_cutouts without native Embree calls: numpy passes over the rays still on
        absent surfaces, each re-traced as one batch."""
        integ = self.integ
        scene = integ.scene
        g, mats, accel = scene.geometry, scene.materials, scene.accel
        rows = np.nonzero(prim >= 0)[0]
        for _ in range(CUTOUT_PASSES):
            rows = rows[mats.cutout_materials[g.material[prim[rows]]]]
            if not rows.size:
                return
            k = prim[rows].astype(np.int64)
            d = np.ascontiguousarray(S[rows, vk.D:vk.D + 3])
            p, ng, _, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, k, b1[rows], b2[rows], d)
            through = rng.random(rows.size) >= mats.presence_at(g.material[k], st)
            rows, k, p, ng, d = rows[through], k[through], p[through], ng[through], d[through]
            if not rows.size:
                return
            # On from just behind the surface (ng faces the ray, so the offset goes past it); the
            # distances stay measured from the ray's origin, where the kernel starts its light
            # crossings and far clip.
            o_next = offset_origin(p, ng, d, accel.ray_epsilon(p, k))
            t0 = dot(o_next - S[rows, vk.O:vk.O + 3], d)
            t_far = np.minimum(np.maximum(S[rows, vk.TMAX] - t0, 0.0), 1e37).astype(np.float32)
            hp, hu, hv = accel.intersect_prepared(o_next.astype(np.float32), np.ascontiguousarray(d32[rows]), t_far)
            integ.rays.add(extension=rows.size)
            prim[rows], b1[rows], b2[rows] = hp, hu, hv
            t32[rows] = (t0 + t_far).astype(np.float32)
            rows = rows[hp >= 0]

    def _visibility(self, sh_o, sh_d, sh_t, sh_l, rng, key):
        """(v (k,) float in [0, 1], tint (k, 3), plain rays traced) for the shadow rays sh_o, sh_d
        (k, 3), sh_t (k,) float32 of the lights sh_l (k,) (kernel order): each light's shadowLink
        BVH and ShadowAPI settings (scene.shadow_group, PathIntegrator.visible_from: what the
        general path's _visible does for them), the plain rays as _blocked; tint each ray's
        light's shadow:color (0: black shadows)."""
        integ = self.integ
        scene = integ.scene
        light = self.order[sh_l]
        grp = self.shadow_group[light]
        v = np.empty(sh_l.shape[0])
        plain = np.nonzero(grp < 0)[0]
        traced = plain.size
        if plain.size:
            v[plain] = ~self._blocked(sh_o[plain], sh_d[plain], sh_t[plain], rng, key)
        if traced < v.size:
            o, d, t = (a.astype(np.float64) for a in (sh_o, sh_d, sh_t))
            for g in np.unique(grp[grp >= 0]):
                rows = np.nonzero(grp == g)[0]
                params = scene.shadow_params[g] if scene.shadow_params else None
                # (visible_from counts these rays itself.)
                v[rows] = integ.visible_from(o[rows], d[rows], t[rows], scene.shadow_accels[g], params, rng)
        tint = (np.ascontiguousarray(self.shadow_tint[light], dtype=np.float64) if self.shadow_tint is not None
                else np.zeros((v.size, 3)))
        return v, tint, traced

    def _blocked(self, sh_o, sh_d, sh_t, rng, key) -> np.ndarray:
        """(k,) bool, True where the shadow rays sh_o, sh_d (k, 3), sh_t (k,) float32 (as the
        kernel wrote them, origins offset) are blocked; through cut-outs as the general path's
        PathIntegrator._visible_through_cutouts sees them."""
        if not self.cutouts:
            return self.integ.scene.accel.occluded_prepared(sh_o, sh_d, sh_t)
        if self.walk is not None:
            fns, geo, cut, tab, eps = self.walk
            blocked = np.empty(sh_o.shape[0], dtype=bool)
            ck.shadow_cutouts_kernel(fns, np.uint64(key), sh_o, sh_d, sh_t, geo, cut, tab, eps, blocked)
            return blocked
        return ~self.integ._visible_through_cutouts(sh_o.astype(np.float64), sh_d.astype(np.float64),
                                                    sh_t.astype(np.float64), rng)
