"""Mesh lights: a gprim with UsdLuxMeshLightAPI (or LightAPI) that is both geometry and a light.

**Geometry.** The reader hands over exactly the world-space triangles of the gprim's MeshDesc
(same triangulation, same winding), so the light and the surface the BVH holds are one shape.
The gprim stays in the scene BVH: it occludes, and it is shaded by its material (see the
materialSyncMode notes below). Consequences for the integrator (path.py):

* its emission on camera rays is added *at the surface hit* (the hit triangle names the light,
  ``Scene.tri_light``), never by a light-ray crossing test, so it is counted exactly once; the
  kind therefore has no proxy triangles and LightSet marks it ``geometry``;
* shadow rays toward a sampled point stop short of it by the usual relative margin
  (dist (1 - 1e-5) - eps), so the emitting triangle does not shadow itself.

**Emission.** Radiance L = the LightAPI formula (intensity, exposure, color, colorTemperature,
``normalize`` over the *world* surface area of all triangles). The UsdLux docs do not say which
side a mesh light emits from; illum follows the area lights ("emit from their front side") and
the geometry: the front side of each triangle (counter-clockwise winding after the reader has
applied ``orientation``), and both sides when the gprim is ``doubleSided`` (the area used by
``normalize`` is still the surface area, counted once).

**Sampling** (per (light, point) row): a triangle is picked with a probability that depends on
the shading point (below), then a point on it with pbrt-v4's rule: spherical-triangle sampling
(Arvo) when the triangle's solid angle from p is in [3e-4, 6.22] sr, uniform area sampling
otherwise (kernels/mesh_light.py). The reported pdf is pick(triangle | p) * (that triangle's
solid-angle density) -- the density of the sampled *point*, which is what MIS and the
estimators need (a direction that crosses several triangles of the mesh also has samples on the
farther ones, but those are shadowed by the nearer one, so their weight never matters).

*The triangle pick* (``pick_mode``). Picking by area alone ("area", the alias table, kept for
comparison) wastes the samples of every triangle that faces away from p: about half of them on
a closed mesh. The default, "oriented", never picks a triangle that cannot contribute and is
exactly replayable by pdf_li, as MIS needs:

* lights of at most EXACT_PICK_TRIANGLES triangles: per row, each triangle weighted by its
  solid angle Omega from p (as 4 tan(Omega / 4), which needs no atan2), 0 where it faces away
  (one-sided lights) or lies wholly below the shading normal's tangent plane (a
  reflection-only BSDF gives it nothing); O(T) per sample and per pdf in a numba kernel, and
  the pdf of a spherical-sampled point is then about 1 / (visible solid angle), nearly
  uniform over the visible mesh;
* larger lights: a light BVH over the light's own triangles (light_samplers/bvh.py, one leaf
  per triangle: its AABB, area as power, its normal as a cone with theta_o = 0, pi when
  two-sided), traversed with the same importance as the scene's lighting service; O(log T),
  and its pmf replay is bit-exact by construction. Its bounds are conservative, so a descent
  can still end on a triangle turned away, or at a node whose two children can both send
  nothing (pbrt's "no light"): a failed sample, never a bias (13 % of the samples of the
  768-triangle neon ring in stages/lux_extra/mesh_light_room.usda, against 52 % for the area
  pick; the per-point kernel fails none).

pdf_li(wi) uses the *first* triangle of the light hit along wi (``intersect``): exact float64
Moller-Trumbore over the light's triangles in a numba kernel for lights of up to
BRUTE_FORCE_TRIANGLES triangles; larger lights get their own embree BVH (renderer/accel.py) to
find the triangle, then the distance is recomputed in float64 on that triangle's plane.

**le(p_light, wi)** needs the triangle under p_light only for its side: it is found by casting
from just before p_light along wi (a back-off of 1e-6 of the light's size plus a few float32
ulps of the coordinates, so an embree-traced light sees the origin in front of its surface).

**Light BVH** (light_samplers/bvh.py): one bounds per mesh light -- the triangles' AABB and
the cone of their front normals (axis = normalised area-weighted mean normal, theta_o = the
largest angle to a normal; pi for two-sided lights), as pbrt bounds a TriangleLight but for the
whole mesh. Per-triangle lights would give tighter cones but multiply the lighting service's
work by the triangle count; a mesh light is one UsdLux light with one estimator setting.

**Analytic F** (irradiance.py): Lambert's polygon formula per triangle clipped to the horizon
(lights/analytic.py), summed over the triangles that face p -- exact for a mesh light of
uniform radiance, and what the light samples estimate (they sample every facing triangle,
shadowed or not). Its cost is linear in the triangle count, so only lights of at most
EXACT_MAX_TRIANGLES triangles report an exact F; larger ones fall back to MIS.
"""

from __future__ import annotations

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.kernels import mesh_light as kern
from renderer.lights._common import as_points, dot, invalid_sample
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.radiometry import emitted_radiance
from renderer.sampling import AliasTable

# pbrt-v4's solid-angle window for spherical triangle sampling (sr).
MIN_SPHERICAL_SOLID_ANGLE = 3e-4
MAX_SPHERICAL_SOLID_ANGLE = 6.22
# Lights with more triangles find their first hit with a per-light embree BVH.
BRUTE_FORCE_TRIANGLES = 64
# Lights with at most this many triangles pick one by its solid angle, per shading point
# (O(T), ~25 ns per triangle); larger ones through a light BVH over their triangles (O(log T)).
EXACT_PICK_TRIANGLES = 64
# The oriented pick drops a triangle whose three vertices are all below the tangent plane by
# more than this cosine (rounding margin), and gives a facing triangle whose solid angle
# rounds to 0 this weight (so it keeps a non-zero probability).
HORIZON_PAD = 1e-7
PICK_FLOOR = 1e-290
# Lights with more triangles report no exact unshadowed integral (MIS fallback): the polygon
# formula costs ~9 us per (shading point, triangle) in numpy, so only small panels (a quad, a
# few facets) are worth it.
EXACT_MAX_TRIANGLES = 16


def mesh_triangles(desc: LightDesc) -> np.ndarray:
    """(T, 3, 3) float64 world triangles of a mesh light (empty when none)."""
    if desc.mesh_triangles is None:
        return np.zeros((0, 3, 3))
    return np.asarray(desc.mesh_triangles, dtype=np.float64).reshape(-1, 3, 3)


def triangle_areas(tris: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)


class MeshLight:
    """All mesh lights as structure-of-arrays.

    tris: (T, 3, 3) every light's triangles, light i owning [start[i], start[i] + tri_count[i]);
    nrm: (T, 3) unit front normals; area, pmf, alias_q: (T,) (pmf: the area pick's probability);
    alias: (T,) int64 global triangle indices; tri_owner: (T,) local light index; L: (count, 3)
    radiance; two_sided, absorbing: (count,) bool (absorbing: materialSyncMode
    noMaterialResponse, the surface reflects nothing); total_area: (count,); lo, hi: (count, 3)
    AABBs; cone_w (count, 3), cone_theta (count,): bounding cone of the emitting normals;
    pick_mode, _tri_bvh: the triangle pick (see the module docstring).
    """

    name = "mesh"
    infinite = False
    geometry = True

    def __init__(self, paths, mesh_paths, tris, start, tri_count, L, two_sided, absorbing, accels):
        self.paths = list(paths)
        self.count = len(self.paths)
        self.mesh_paths = list(mesh_paths)
        self.tris = np.ascontiguousarray(tris, dtype=np.float64).reshape(-1, 3, 3)
        self.start = np.ascontiguousarray(start, dtype=np.int64)
        self.tri_count = np.ascontiguousarray(tri_count, dtype=np.int64)
        self.L = as_points(L)
        self.two_sided = np.ascontiguousarray(two_sided, dtype=bool)
        self.absorbing = np.ascontiguousarray(absorbing, dtype=bool)
        self.delta = np.zeros(self.count, dtype=bool)
        self.warnings: list[str] = []
        self._accels = accels  # per light: renderer.accel.Accel or None
        # "oriented" (default) or "area": how a triangle is picked (see the module docstring).
        self.pick_mode = "oriented"
        T = self.tris.shape[0]
        cr = np.cross(self.tris[:, 1] - self.tris[:, 0], self.tris[:, 2] - self.tris[:, 0]) if T else np.zeros((0, 3))
        ln = np.linalg.norm(cr, axis=1)
        self.area = 0.5 * ln
        self.nrm = np.ascontiguousarray(cr / np.where(ln > 0.0, ln, 1.0)[:, None])
        self.tri_owner = np.repeat(np.arange(self.count, dtype=np.int64), self.tri_count)
        self.pmf = np.zeros(T)
        self.alias_q = np.zeros(T)
        self.alias = np.zeros(T, dtype=np.int64)
        self.total_area = np.zeros(self.count)
        self.lo = np.zeros((self.count, 3))
        self.hi = np.zeros((self.count, 3))
        self.cone_w = np.zeros((self.count, 3))
        self.cone_w[:, 2] = 1.0
        self.cone_theta = np.full(self.count, np.pi)
        self.size = np.ones(self.count)
        for i in range(self.count):  # per light, not per row: building the tables
            s, c = int(self.start[i]), int(self.tri_count[i])
            a = self.area[s:s + c]
            self.total_area[i] = a.sum()
            table = AliasTable.build(a)
            self.pmf[s:s + c] = table.pmf
            self.alias_q[s:s + c] = table.q
            self.alias[s:s + c] = table.alias + s
            pts = self.tris[s:s + c].reshape(-1, 3)
            self.lo[i], self.hi[i] = pts.min(axis=0), pts.max(axis=0)
            self.size[i] = max(float(np.linalg.norm(self.hi[i] - self.lo[i])), 1e-30)
            if not self.two_sided[i]:
                mean = (self.nrm[s:s + c] * a[:, None]).sum(axis=0)
                m = float(np.linalg.norm(mean))
                if m > 0.0:
                    w = mean / m
                    cosines = np.clip(self.nrm[s:s + c][a > 0.0] @ w, -1.0, 1.0)
                    self.cone_w[i] = w
                    self.cone_theta[i] = float(np.arccos(cosines.min())) if cosines.size else np.pi
        self._tri_bvh = [self._triangle_bvh(i) if self.tri_count[i] > EXACT_PICK_TRIANGLES else None
                         for i in range(self.count)]

    def _triangle_bvh(self, i: int):
        """A light BVH over light i's triangles (leaf k = local triangle k): per triangle its
        AABB, its area as power and its front normal as the cone (theta_o = pi when two-sided)."""
        from renderer.light_samplers.bvh import BVHLightSampler, LightBounds

        s, c = int(self.start[i]), int(self.tri_count[i])
        t = self.tris[s:s + c]
        theta_o = np.full(c, np.pi if self.two_sided[i] else 0.0)
        b = LightBounds(np.arange(c, dtype=np.int64), t.min(axis=1), t.max(axis=1), self.area[s:s + c].copy(),
                        self.nrm[s:s + c].copy(), theta_o, np.full(c, 0.5 * np.pi))
        return BVHLightSampler(bounds=b, count=c)

    def use_pick(self, mode: str, exact_max_triangles: int | None = None) -> None:
        """Switch the triangle pick (benchmarks and tests): ``mode`` "oriented" or "area"; with
        exact_max_triangles, lights of up to that many triangles use the per-point kernel and
        larger ones a triangle BVH (built here if missing)."""
        if mode not in ("oriented", "area"):
            raise ValueError(f"unknown mesh-light pick mode {mode!r}")
        self.pick_mode = mode
        if exact_max_triangles is not None:
            self._tri_bvh = [None if self.tri_count[i] <= exact_max_triangles else
                             self._tri_bvh[i] if self._tri_bvh[i] is not None else self._triangle_bvh(i)
                             for i in range(self.count)]

    def compiled_record(self) -> tuple:
        """The record MS of the compiled per-row functions (kernels/mesh_light.py
        mesh_light_*_row, which lists its fields) with the "oriented" pick: the triangle BVHs
        of the large lights concatenated, each light's pairs at pair_start[j]:pair_start[j + 1]
        and its leaves' replay tables at its triangles' rows."""
        k, T = self.count, self.tris.shape[0]
        trees = [(j, b) for j, b in enumerate(self._tri_bvh) if b is not None]
        width = max([b.trail.shape[1] for _, b in trees] + [1])
        pair_start = np.zeros(k + 1, np.int64)
        slot = np.full(T, -1, np.int32)
        depth = np.zeros(T, np.int32)
        trail = np.zeros((T, width), np.uint64)
        root_light = np.full(k, -1, np.int64)
        root_c = np.zeros((k, 1, 3))
        root_b = np.zeros((k, 1, 8), np.float32)
        p_inf = np.zeros(k)
        pc, pb, pn = [np.zeros((0, 2, 3))], [np.zeros((0, 2, 8), np.float32)], [np.zeros((0, 2), np.int32)]
        sizes = np.zeros(k, np.int64)
        for j, b in trees:
            s0, m = int(self.start[j]), b.depth.shape[0]
            sizes[j] = b.pair_c.shape[0]
            pc.append(b.pair_c)
            pb.append(b.pair_b)
            pn.append(b.pair_next)
            slot[s0:s0 + b.slot.shape[0]] = b.slot
            depth[s0:s0 + m] = b.depth
            trail[s0:s0 + m, :b.trail.shape[1]] = b.trail
            root_light[j] = int(b.root_light)
            root_c[j], root_b[j], p_inf[j] = b.root_c[0], b.root_b[0], float(b.p_infinite)
        pair_start[1:] = np.cumsum(sizes)
        TR = (pair_start, np.ascontiguousarray(np.concatenate(pn), dtype=np.int32),
              np.ascontiguousarray(np.concatenate(pc), dtype=np.float64),
              np.ascontiguousarray(np.concatenate(pb), dtype=np.float32), slot, depth, trail, root_light, root_c,
              root_b, p_inf, np.zeros(T, bool), np.zeros(0, np.int64))
        has_tree = np.array([b is not None for b in self._tri_bvh], dtype=bool)
        consts = np.array([HORIZON_PAD, PICK_FLOOR, MIN_SPHERICAL_SOLID_ANGLE, MAX_SPHERICAL_SOLID_ANGLE])
        return (self.tris, self.nrm, np.ascontiguousarray(self.area), self.start, self.tri_count, self.two_sided,
                np.ascontiguousarray(self.L), has_tree, TR, consts)

    # ----------------------------------------------------------------------------------
    # Build
    # ----------------------------------------------------------------------------------
    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """World-space surface area of the light's triangles (each counted once)."""
        return float(triangle_areas(mesh_triangles(desc)).sum())

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=None, scene_radius: float = 1.0) -> "MeshLight":
        from renderer.accel import Accel

        k = len(descs)
        tris, counts, L, two, absorb, accels = [], [], np.zeros((k, 3)), [], [], []
        for i, d in enumerate(descs):
            t = mesh_triangles(d)
            tris.append(t)
            counts.append(t.shape[0])
            L[i] = emitted_radiance(d, cls.world_area(d))
            two.append(bool(d.mesh_two_sided))
            absorb.append(d.material_sync_mode == "noMaterialResponse")
            accels.append(Accel(t, threads=1) if t.shape[0] > BRUTE_FORCE_TRIANGLES else None)
        counts = np.asarray(counts, dtype=np.int64)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if k else np.zeros(0, np.int64)
        all_tris = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        return cls([d.path for d in descs], [d.mesh_path for d in descs], all_tris, start, counts, L,
                   two, absorb, accels)

    # ----------------------------------------------------------------------------------
    # Geometry queries
    # ----------------------------------------------------------------------------------
    def _hit(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hit (t (n,), global triangle (n,) or -1) of rays o + t d with light idx."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n = idx.size
        t = np.full(n, np.inf)
        tri = np.full(n, -1, dtype=np.int64)
        if n == 0:
            return t, tri
        o = as_points(o)
        d = as_points(d)
        big = np.array([a is not None for a in self._accels], dtype=bool)[idx] if self.count else np.zeros(n, bool)
        small = np.nonzero(~big)[0]
        if small.size:
            ts = np.empty(small.size)
            trs = np.empty(small.size, dtype=np.int64)
            kern.mesh_hit_kernel(np.ascontiguousarray(idx[small]), np.ascontiguousarray(o[small]),
                                 np.ascontiguousarray(d[small]), self.start, self.tri_count, self.tris, ts, trs)
            t[small], tri[small] = ts, trs
        if big.any():
            for li in np.unique(idx[big]):  # one embree query per large light present
                rows = np.nonzero(idx == li)[0]
                h = self._accels[li].intersect(o[rows], d[rows])
                g = np.where(h.prim >= 0, h.prim + self.start[li], -1)
                tp = np.empty(rows.size)
                kern.plane_distance_kernel(np.ascontiguousarray(g), np.ascontiguousarray(o[rows]),
                                           np.ascontiguousarray(d[rows]), self.tris, self.nrm, tp)
                ok = (g >= 0) & np.isfinite(tp)
                t[rows] = np.where(ok, tp, np.inf)
                tri[rows] = np.where(ok, g, -1)
                # Embree's hit on the triangle the ray starts on (kernels/mesh_light.SELF_HIT_REL):
                # the first hit past it by the exact tests.
                redo = rows[(g >= 0) & ~ok]
                if redo.size:
                    ts = np.empty(redo.size)
                    trs = np.empty(redo.size, dtype=np.int64)
                    kern.mesh_hit_kernel(np.ascontiguousarray(idx[redo]), np.ascontiguousarray(o[redo]),
                                         np.ascontiguousarray(d[redo]), self.start, self.tri_count, self.tris, ts,
                                         trs)
                    t[redo], tri[redo] = ts, trs
        return t, tri

    def _triangle_at(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Global triangle (n,) under the points p_light, found from just before them along wi."""
        # Relative to the light's size, plus a few float32 ulps of the coordinates: a large light
        # is found by its embree BVH, which must see the origin strictly in front of the surface.
        back = 1e-6 * self.size[idx] + 4e-6 * np.abs(p_light).max(axis=1)
        o = as_points(p_light - wi * back[:, None])
        t, tri = self._hit(idx, o, wi)
        found = t <= 3.0 * back
        miss = np.nonzero(~found)[0]
        if miss.size:
            # The point is on the light, so a miss is float32 (embree) disagreeing with float64
            # at a grazing silhouette: ask the exact kernel for those few rows.
            tm = np.empty(miss.size)
            trm = np.empty(miss.size, dtype=np.int64)
            kern.mesh_hit_kernel(np.ascontiguousarray(idx[miss], dtype=np.int64), np.ascontiguousarray(o[miss]),
                                 as_points(wi[miss]), self.start, self.tri_count, self.tris, tm, trm)
            t[miss], tri[miss] = tm, trm
            found = t <= 3.0 * back
        return np.where(found, tri, -1)

    # ----------------------------------------------------------------------------------
    # LightKind protocol
    # ----------------------------------------------------------------------------------
    def _pick(self, idx: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Alias-table triangle pick per row: (global triangle (n,), remapped uniform (n,))."""
        cnt = self.tri_count[idx]
        x = u0 * cnt
        i = np.minimum(x.astype(np.int64), np.maximum(cnt - 1, 0))
        frac = x - i
        g = self.start[idx] + i
        q = self.alias_q[g]
        accept = frac < q
        tri = np.where(accept, g, self.alias[g])
        u_new = np.where(accept, np.divide(frac, q, out=np.zeros_like(frac), where=q > 0.0),
                         np.divide(frac - q, 1.0 - q, out=np.zeros_like(frac), where=q < 1.0))
        tri = np.where(cnt > 0, tri, -1)
        return tri, np.clip(u_new, 0.0, np.nextafter(1.0, 0.0))

    def _pick_oriented(self, idx: np.ndarray, ctx: ShadingContext, u0: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Oriented triangle pick per row: (global triangle (n,) or -1, its probability (n,),
        remapped uniform (n,)). See the module docstring."""
        n = idx.size
        tri = np.full(n, -1, dtype=np.int64)
        pick = np.zeros(n)
        u_new = np.zeros(n)
        has_bvh = np.array([b is not None for b in self._tri_bvh], dtype=bool)
        big = has_bvh[idx]
        small = np.nonzero(~big)[0]
        if small.size:
            ts, ps, us = np.empty(small.size, np.int64), np.empty(small.size), np.empty(small.size)
            kern.mesh_pick_kernel(np.ascontiguousarray(idx[small]), as_points(ctx.p[small]),
                                  as_points(ctx.ns[small]), np.ascontiguousarray(u0[small], dtype=np.float64),
                                  self.start, self.tri_count, self.tris, self.nrm, self.area, self.two_sided,
                                  HORIZON_PAD, PICK_FLOOR, ts, ps, us)
            tri[small], pick[small], u_new[small] = ts, ps, us
        if big.any():
            for li in np.unique(idx[big]):  # one traversal per large light present
                rows = np.nonzero(idx == li)[0]
                ur = np.zeros(rows.size)
                loc, pr = self._tri_bvh[li].sample(ctx.take(rows), u0[rows], remapped=ur)
                ok = pr > 0.0
                tri[rows] = np.where(ok, loc + self.start[li], -1)
                pick[rows] = pr
                u_new[rows] = ur
        return tri, pick, u_new

    def _pick_prob(self, idx: np.ndarray, ctx: ShadingContext, tri: np.ndarray) -> np.ndarray:
        """(n,) probability that sample_li at ctx picks global triangle tri (0 for -1)."""
        n = idx.size
        if self.pick_mode == "area":
            return np.where(tri >= 0, self.pmf[np.maximum(tri, 0)], 0.0)
        pick = np.zeros(n)
        has_bvh = np.array([b is not None for b in self._tri_bvh], dtype=bool)
        big = has_bvh[idx]
        small = np.nonzero(~big)[0]
        if small.size:
            ps = np.empty(small.size)
            kern.mesh_pick_pmf_kernel(np.ascontiguousarray(idx[small]), np.ascontiguousarray(tri[small]),
                                      as_points(ctx.p[small]), as_points(ctx.ns[small]), self.start,
                                      self.tri_count, self.tris, self.nrm, self.area, self.two_sided,
                                      HORIZON_PAD, PICK_FLOOR, ps)
            pick[small] = ps
        if big.any():
            for li in np.unique(idx[big]):
                rows = np.nonzero((idx == li) & (tri >= 0))[0]
                if rows.size:
                    pick[rows] = self._tri_bvh[li].pmf(ctx.take(rows), tri[rows] - self.start[li])
        return pick

    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Pick a triangle (``pick_mode``), then a point on it (spherical or area sampling).
        u (n, 2)."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n = idx.size
        if n == 0:
            return invalid_sample(0)
        u = as_points(u, 2)
        if self.pick_mode == "area":
            tri, u0 = self._pick(idx, u[:, 0])
            pick = np.where(tri >= 0, self.pmf[np.maximum(tri, 0)], 0.0)
        else:
            tri, pick, u0 = self._pick_oriented(idx, ctx, u[:, 0])
        uu = np.ascontiguousarray(np.stack([u0, u[:, 1]], axis=1))
        L = np.empty((n, 3))
        wi = np.empty((n, 3))
        pdf = np.empty(n)
        dist = np.empty(n)
        p_l = np.empty((n, 3))
        kern.mesh_sample_kernel(idx, np.ascontiguousarray(tri), np.ascontiguousarray(pick), as_points(ctx.p), uu,
                                self.tris, self.nrm, self.area, self.two_sided, self.L, MIN_SPHERICAL_SOLID_ANGLE,
                                MAX_SPHERICAL_SOLID_ANGLE, L, wi, pdf, dist, p_l)
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_l)

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """pdf (n,) of sample_li producing wi, from the first triangle hit along wi (0: none, or
        it faces away from a one-sided light)."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n = idx.size
        if n == 0:
            return np.zeros(0)
        p = as_points(ctx.p)
        wi = as_points(wi)
        t, tri = self._hit(idx, p, wi)
        pick = self._pick_prob(idx, ctx, tri)
        out = np.empty(n)
        kern.mesh_pdf_kernel(idx, tri, pick, t, p, wi, self.tris, self.nrm, self.area, self.two_sided,
                             MIN_SPHERICAL_SOLID_ANGLE, MAX_SPHERICAL_SOLID_ANGLE, out)
        return out

    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First hit distance (n,) with the light's triangles (either side), inf where none."""
        return self._hit(idx, o, d)[0]

    def le(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """L toward -wi from the triangle under p_light when wi arrives on its emitting side."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros((0, 3))
        tri = self._triangle_at(idx, as_points(p_light), as_points(wi))
        cos_front = -dot(wi, self.nrm[np.maximum(tri, 0)])
        return self.surface_emission(idx, np.where(tri >= 0, cos_front, 0.0))[0]

    def surface_emission(self, idx: np.ndarray, cos_front: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Le (n, 3), absorbing (n,)) at surface hits of light idx, where cos_front = -d . n_front
        of the hit triangle (> 0: the ray arrives on the front)."""
        idx = np.asarray(idx, dtype=np.int64)
        emits = (cos_front > 0.0) | (self.two_sided[idx] & (cos_front != 0.0))
        return np.where(emits[:, None], self.L[idx], 0.0), self.absorbing[idx]

    def phi(self) -> np.ndarray:
        """(count,) luminance power pi * A * lum(L) (twice that for two-sided lights)."""
        return np.pi * self.total_area * luminance(self.L) * np.where(self.two_sided, 2.0, 1.0)

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """None: mesh lights are real geometry in the scene BVH (see the module docstring)."""
        return np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64)

    def irradiance(self, idx: np.ndarray, ctx: ShadingContext) -> tuple[np.ndarray, np.ndarray]:
        """Unshadowed irradiance (n, 3) about ctx.ns and exact (n,) bool (see the module docstring):
        Lambert's polygon formula per triangle (kernels/mesh_light.mesh_G_row, the compiled
        path's F too)."""
        from renderer.lights.analytic import FAR_RATIO, KAPPA_MAX

        idx = np.asarray(idx, dtype=np.int64)
        n = idx.size
        E = np.zeros((n, 3))
        exact = self.tri_count[idx] <= EXACT_MAX_TRIANGLES
        rows = np.nonzero(exact)[0]
        if rows.size:
            G = np.zeros(rows.size)
            kern.mesh_G_kernel(np.ascontiguousarray(idx[rows]), np.ascontiguousarray(ctx.p[rows], dtype=np.float64),
                               np.ascontiguousarray(ctx.ns[rows], dtype=np.float64), self.start, self.tri_count,
                               self.tris, self.nrm, self.two_sided, float(FAR_RATIO), float(KAPPA_MAX), G)
            E[rows] = G[:, None] * self.L[idx[rows]]
        return E, exact
