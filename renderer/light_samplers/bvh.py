"""Light BVH: pick a light in proportion to an estimate of its contribution that is never 0
where the light can contribute.

The lighting service of Conty Estevez & Kulla 2018 ("Importance Sampling of Many Lights with
Adaptive Tree Splitting") in the form pbrt-v4 gives it (``BVHLightSampler``):

* every finite light gets ``LightBounds``: a world AABB ``[lo, hi]``, its power ``phi``
  (luminance-weighted, the same numbers the power sampler uses) and an orientation cone
  ``(w, theta_o, theta_e)``: all normals lie within theta_o of the axis w, and every normal
  emits within theta_e of itself. Rect and disk lights are one-sided: w = emitting normal,
  theta_o = 0, theta_e = pi/2. Sphere lights (and treatAsPoint point lights) emit everywhere:
  theta_o = pi, theta_e = pi/2; so do cylinder (and line) lights, whose normals circle their
  axis. A mesh light gets its triangles' AABB and the cone of their front normals (pbrt's
  TriangleLight bounds for the whole mesh; theta_o = pi when two-sided). A kind this module does not know yet is bounded by the AABB
  of its proxy triangles with theta_o = pi (always valid, merely loose). Lights shaped by
  UsdLux ShapingAPI (lights/shaping.py) get their shaped power and, where their transform
  preserves angles, the cone they actually emit into: w = the light axis and
  theta_o + theta_e = the largest off-axis angle with non-zero emission (cone angle, IES
  support), theta_o being the part where the cone term is still 1 (pbrt-v4's spot bounds).
* a binary tree whose leaves hold one light each; an interior node holds the union of its
  lights' bounds. At a shading point p with shading normal ns the *importance* of a node,

      I = phi * cos(theta') / max(d^2, r^2 / 3) * max(cos(theta_i'), 0)   (0 if theta' >= theta_e)

  (d the distance from p to the centre of the node's AABB, r half its diagonal) estimates
  what the lights below it send, the angular factors bounding it from above: theta' is the
  smallest angle between an emitting normal in the cone and the direction to p, less the
  half-angle theta_b that the node's bounding sphere subtends at p; theta_i' is the incidence
  angle at ns less theta_b (no incidence factor where the context has no normal). The traversal descends from the
  root choosing a child with probability proportional to its importance (pbrt: "no light"
  where both children have importance 0), and the product of those choices is the pmf.
* infinite lights (dome, distant) are not in the tree. They are picked first, with
  probability p_inf = k_inf / (k_inf + 1) (the tree counts as one more candidate), uniformly
  among themselves, as pbrt does, except that where the root's children both have importance
  0 the infinite lights get probability 1 (pbrt would waste 1 - p_inf of those samples).

**The d^2 clamp.** pbrt-v4 clamps the squared distance with ``Length(diagonal) / 2``, a
length compared with a squared length, so the clamp depends on the scene's unit (too weak in
metres for small nodes, too strong in centimetres for large ones). Here the clamp is a squared
length, a third of the squared radius of the node's bounding sphere, ``(|diagonal| / 2)^2 / 3``,
the same in any unit (tests/light_samplers checks that scaling a scene by 1024 leaves every
pmf unchanged). The factor 1/3 (renderer/kernels/light_bvh.py ``CLAMP_R2``, which says why)
makes a sphere light's leaf exact and cut the variance of the light choice on the fireflies
stage 4x against the full ``(|diagonal| / 2)^2``: with the full radius, every node that a
shading point sits in looked as far away as its bounding sphere is wide, so a firefly a few
centimetres from the point lost a factor at each such level above it. The clamp only shapes
the probabilities; it can never make one 0, so it cannot bias.

**Exactness of pmf.** ``pmf(ctx, light)`` replays the root-to-leaf path stored for that light
(a bit per level: 0 = first child, 1 = second) and evaluates the same importance function on
the same nodes with the same scalar float64 operations (one numba function, per row: nothing
whose rounding could depend on the batch), multiplying in the same order; so it reproduces bit
for bit the pmf that ``sample`` reported.

**Build.** Top-down, one tree level at a time, all the nodes of a level at once in numpy
(no Python loop over nodes or lights; lights of a node are a contiguous range, so node
unions are ``reduceat``). Each node is split along one of the three axes at one of the
boundaries between 12 centroid buckets (4 or 8 for nodes of <= 4 or <= 16 lights; two lights
are simply separated), choosing the split that minimises pbrt's cost
``phi * M_Omega * K_r * SurfaceArea`` summed over both sides, where M_Omega is the
cosine-weighted solid angle the orientation cone can emit into and K_r = max extent / extent
along the split axis penalises thin slabs; a node whose centroids coincide is split at the
middle. Two economies keep 100k lights near a second (bench/bench_light_samplers.py):
bucket statistics of nodes with more than SPLIT_SAMPLE lights come from an evenly strided
subset of their lights (a sampled SAH: the cost only ranks planes; every light is then
partitioned exactly), and the cones of candidate sides are measured about the node's own
axis, so that a side's M_Omega is a running maximum over buckets (pbrt merges bucket cones
pairwise about moving axes: slightly tighter cones, twice the build time here, no measurable
gain in sampling quality). The node cones that traversal relies on are exact unions: axis =
mean of the node's normals, theta_o = largest angle from it to a light's cone plus 1e-6 rad
for rounding, so they never exclude a light (which would be bias).

**Cost.** A pick visits O(depth) nodes, O(log n) for a balanced tree, evaluating both
children's importance at each: a per-row numba loop (renderer/kernels/light_bvh.py), ~0.5 us
of CPU per pick and ~0.4 us per pmf replay on the fireflies stage (5000 lights, mean depth
13; 0.86 and 0.81 us before its importance became branch-free), where the level-at-a-time
numpy traversal it replaced took ~3.5 us for either.
Memory per node (2 m - 1 nodes for m lights): 3 float64 + 8 float32 of bounds and 3 int32;
per light one 64-bit word of trail per 64 levels and an int32 depth; an int32 slot per global
light: about 140 bytes per light (``memory_bytes``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kernels import light_bvh as _kern
from ..lights.base import ShadingContext

__all__ = ["BVHLightSampler", "LightBounds", "light_bounds", "importance", "N_BUCKETS"]

# pbrt-v4 evaluates 12 candidate buckets per axis.
N_BUCKETS = 12
# Buckets per axis by node size: sizes <= 2 need no search (one light per child), <= 4 use 4,
# <= 8 use 8, larger nodes pbrt's 12.
_BUCKETS_BY_SIZE = (np.array([2, 4, 16]), (0, 4, 8, N_BUCKETS))
# Bucket statistics of a node are gathered from at most this many of its lights.
SPLIT_SAMPLE = 256
# Padding added to every node's cone half-angle (leaves too) so that rounding -- float64 in
# the build, float32 storage of the bounds (angles near a cone's edge to ~1e-7 rad) -- never
# makes a cone exclude a direction its lights emit into (a missed light would get pmf 0: bias).
# The traversal's constants (INCIDENCE_PAD, ONE_MINUS_EPSILON, MAX_IMPORTANCE, D2_MIN) live
# with its kernels in renderer/kernels/light_bvh.py.
CONE_PAD = 1e-4

# Column layout of the per-node float table.
_PC = slice(0, 3)      # centre of the node's AABB
_R2 = 3                # (|diagonal| / 2)^2: squared radius of the bounding sphere
_W = slice(4, 7)       # cone axis (unit)
_PHI = 7               # summed power
_COS_O = 8             # cos theta_o
_SIN_O = 9             # sin theta_o
_COS_E = 10            # cos theta_e
_NCOLS = 11


@dataclass(frozen=True)
class LightBounds:
    """Per-light bounds (structure of arrays over m finite lights).

    light: (m,) int64 global light index; lo, hi: (m, 3) world AABB (scene units);
    phi: (m,) luminance power (> 0); w: (m, 3) unit cone axis; theta_o, theta_e: (m,) cone
    half-angles in radians (theta_o in [0, pi], theta_e in [0, pi/2]).
    """

    light: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    phi: np.ndarray
    w: np.ndarray
    theta_o: np.ndarray
    theta_e: np.ndarray

    @property
    def count(self) -> int:
        return int(self.light.size)

    def take(self, rows: np.ndarray) -> "LightBounds":
        return LightBounds(self.light[rows], self.lo[rows], self.hi[rows], self.phi[rows], self.w[rows],
                           self.theta_o[rows], self.theta_e[rows])


def _empty_bounds() -> LightBounds:
    z3 = np.zeros((0, 3))
    z = np.zeros(0)
    return LightBounds(np.zeros(0, np.int64), z3, z3, z, z3, z, z)


def light_bounds(lights) -> LightBounds:
    """LightBounds of every finite light of a LightSet (infinite lights are picked apart; the
    sampler leaves out lights whose power is not > 0)."""
    if lights is None or lights.count == 0:
        return _empty_bounds()
    phi_all = np.asarray(lights.phi(), dtype=np.float64)
    parts = []
    for k, obj in enumerate(lights.kinds):
        if obj.count == 0 or obj.infinite:
            continue
        glob = np.asarray(lights._global_of[k], dtype=np.int64)
        m = obj.count
        w = np.zeros((m, 3))
        w[:, 2] = 1.0
        theta_e = np.full(m, 0.5 * np.pi)
        kind = getattr(obj, "name", "")
        if kind == "rect":
            half = 0.5 * (np.abs(obj.ex) + np.abs(obj.ey))  # AABB of c + a ex + b ey, |a|,|b| <= 1/2
            lo, hi = obj.center - half, obj.center + half
            w = np.asarray(obj.n, dtype=np.float64)
            theta_o = np.zeros(m)
        elif kind == "disk":
            # Ellipse c + e1 cos t + e2 sin t: per axis the extreme is sqrt(e1_k^2 + e2_k^2).
            half = np.sqrt(obj.e1**2 + obj.e2**2)
            lo, hi = obj.center - half, obj.center + half
            w = np.asarray(obj.n, dtype=np.float64)
            theta_o = np.zeros(m)
        elif kind == "sphere":
            r = np.where(obj.delta, 0.0, obj.radius)[:, None]
            lo, hi = obj.center - r, obj.center + r
            theta_o = np.full(m, np.pi)
        elif kind == "cylinder":
            # Side c + s a + cos(phi) b1 + sin(phi) b2, |s| <= l: per axis l |a_k| + |(b1_k, b2_k)|
            # (line lights: the segment). Normals circle the axis: emits all around (theta_o = pi).
            half = obj.half[:, None] * np.abs(obj.a) + np.where(
                obj.delta[:, None], 0.0, np.sqrt(obj.b1**2 + obj.b2**2))
            lo, hi = obj.center - half, obj.center + half
            theta_o = np.full(m, np.pi)
        elif kind == "mesh":
            # One bounds per mesh light: the triangles' AABB and the cone of their front normals
            # (lights/mesh.py; pi for two-sided lights).
            lo, hi = obj.lo, obj.hi
            w = np.asarray(obj.cone_w, dtype=np.float64)
            theta_o = np.asarray(obj.cone_theta, dtype=np.float64)
        else:
            # Unknown finite kind: the AABB of its conservative proxy triangles, emitting everywhere.
            tris, owner = obj.proxy_triangles()
            lo = np.full((m, 3), np.inf)
            hi = np.full((m, 3), -np.inf)
            np.minimum.at(lo, owner, tris.min(axis=1))
            np.maximum.at(hi, owner, tris.max(axis=1))
            theta_o = np.full(m, np.pi)
        shaping = getattr(lights, "shaping", None)
        if shaping is not None and getattr(lights, "shaping_aware", True):
            # ShapingAPI: the emission cone of a spot (cone angle, IES support) about the light axis.
            w, theta_o, theta_e = shaping.tighten_bounds(glob, np.asarray(w, float), theta_o, theta_e,
                                                         one_sided=kind in ("rect", "disk"))
        parts.append(LightBounds(glob, np.asarray(lo, float), np.asarray(hi, float), phi_all[glob],
                                 np.asarray(w, float), theta_o, theta_e))
    if not parts:
        return _empty_bounds()
    b = LightBounds(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                      ("light", "lo", "hi", "phi", "w", "theta_o", "theta_e")))
    return b


# ----------------------------------------------------------------------------------------
# Importance (pbrt-v4 LightBounds::Importance with the d^2 clamp fixed)
# ----------------------------------------------------------------------------------------
def importance(p: np.ndarray, nrm: np.ndarray, has_n: np.ndarray, node: np.ndarray) -> np.ndarray:
    """Importance (k,) float64 of k (point, node) pairs, exactly as the traversal computes it
    (renderer/kernels/light_bvh.py ``_importance``).

    p: (k, 3) shading points; nrm: (k, 3) shading normals (used where has_n (k,) bool);
    node: (k, 11) rows of the node table (see the column layout at the top of the module).
    """
    pc, nd = _traversal_columns(np.asarray(node, dtype=np.float64).T)
    k = pc.shape[1]
    out = np.empty(k)
    _kern.bvh_importance_kernel(np.ascontiguousarray(p, dtype=np.float64),
                                np.ascontiguousarray(nrm, dtype=np.float64), np.ascontiguousarray(has_n, dtype=bool),
                                np.ascontiguousarray(pc.T[:, None, :]), np.ascontiguousarray(nd.T[:, None, :]), out)
    return out


def _round32(x: np.ndarray, toward: float) -> np.ndarray:
    """float64 -> float32 rounded toward -inf or +inf (never across x), for conservative bounds."""
    y = np.asarray(x, dtype=np.float64).astype(np.float32)
    wrong = (y < x) if toward > 0 else (y > x)
    return np.where(wrong, np.nextafter(y, np.float32(toward)), y)


def _traversal_columns(cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node columns (11, ...) float64 -> (centres (3, ...) float64, the other 8 (8, ...) float32:
    r = sqrt(r2) the bounding sphere's radius, w (3), phi, cos_o, sin_o, cos_e). Each bound is
    rounded the conservative way: r and sin_o up, cos_o and cos_e down (wider cones, bigger
    spheres)."""
    pc = np.ascontiguousarray(cols[0:3])
    nd = np.zeros((8,) + cols.shape[1:], np.float32)
    nd[0] = _round32(np.sqrt(cols[_R2]), np.inf)
    nd[1:4] = cols[_W].astype(np.float32)
    nd[4] = cols[_PHI].astype(np.float32)
    nd[5] = _round32(cols[_COS_O], -np.inf)
    nd[6] = _round32(cols[_SIN_O], np.inf)
    nd[7] = _round32(cols[_COS_E], -np.inf)
    return pc, nd


# ----------------------------------------------------------------------------------------
# Cones and the build cost
# ----------------------------------------------------------------------------------------
def m_omega(theta_o: np.ndarray, theta_e: np.ndarray) -> np.ndarray:
    """pbrt's orientation measure: the cosine-weighted solid angle a cone (theta_o, theta_e)
    can emit into, 2 pi (1 - cos theta_o) + pi/2 (2 theta_w sin theta_o - cos(theta_o - 2 theta_w)
    - 2 theta_o sin theta_o + cos theta_o), theta_w = min(theta_o + theta_e, pi)."""
    tw = np.minimum(theta_o + theta_e, np.pi)
    so, co = np.sin(theta_o), np.cos(theta_o)
    return 2.0 * np.pi * (1.0 - co) + 0.5 * np.pi * (
        2.0 * tw * so - np.cos(theta_o - 2.0 * tw) - 2.0 * theta_o * so + co)


def _surface_area(lo: np.ndarray, hi: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """Surface area (...) of AABBs given component-major as (3, ...); each extent is raised to
    ``floor`` (...) so that flat or collinear groups (coplanar panels, points on a line) still
    rank splits by size. Empty boxes (lo = inf, hi = -inf) get the floor."""
    e = np.maximum(hi - lo, floor)
    return 2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])


# Packed per-light build columns (one gather moves a light's whole record).
_F_LO = slice(0, 3)
_F_HI = slice(3, 6)
_F_PHI = 6
_F_W = slice(7, 10)
_F_TO = 10
_F_TE = 11
_F_DIR = 12      # 1 for lights with a cone narrower than the sphere (they vote on a node's axis)
_NF = 13


def _node_rows(F: np.ndarray, sizes: np.ndarray, same_te: bool):
    """Node table rows (S, 11) and AABBs lo, hi (S, 3) of S groups of lights stored one group
    after the other in F (k, _NF), sizes (S,) >= 1: the union of each group's bounds.

    The cone axis is the mean of the directional lights' normals (any light's axis when there
    are none) and theta_o the largest angle from it to a light's cone, plus CONE_PAD, so the
    cone bounds every light (a single light keeps its own cone, padded).
    """
    S = sizes.size
    offs = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    lo = np.minimum.reduceat(F[:, _F_LO], offs, axis=0)
    hi = np.maximum.reduceat(F[:, _F_HI], offs, axis=0)
    w = F[:, _F_W]
    wsum = np.add.reduceat(w * F[:, _F_DIR, None], offs, axis=0)
    wlen = np.sqrt(np.einsum("ij,ij->i", wsum, wsum))
    axis = np.where((wlen > 1e-9)[:, None], wsum / np.where(wlen > 0.0, wlen, 1.0)[:, None], w[offs])
    single = sizes == 1
    if np.all(single):
        theta_o = np.minimum(F[:, _F_TO] + CONE_PAD, np.pi)
    else:
        # A node holding an omni light (theta_o = pi) emits everywhere: no angles needed.
        has_omni = np.minimum.reduceat(F[:, _F_DIR], offs) == 0.0
        theta_o = np.where(single, np.minimum(F[offs, _F_TO] + CONE_PAD, np.pi), np.pi)
        todo = ~single & ~has_omni
        if np.any(todo):
            in_todo = np.repeat(todo, sizes)
            t_sizes = sizes[todo]
            t_offs = np.concatenate(([0], np.cumsum(t_sizes)[:-1]))
            wt = w[in_todo]
            cosang = np.clip(np.einsum("ij,ij->i", np.repeat(axis[todo], t_sizes, axis=0), wt), -1.0, 1.0)
            spread = np.maximum.reduceat(np.arccos(cosang) + F[in_todo, _F_TO], t_offs)
            theta_o[todo] = np.minimum(spread + CONE_PAD, np.pi)
    theta_e = F[offs, _F_TE] if same_te else np.maximum.reduceat(F[:, _F_TE], offs)
    rows = np.zeros((S, _NCOLS))
    rows[:, _PC] = 0.5 * (lo + hi)
    diag = hi - lo
    rows[:, _R2] = 0.25 * np.einsum("ij,ij->i", diag, diag)
    rows[:, _W] = axis
    rows[:, _PHI] = np.add.reduceat(F[:, _F_PHI], offs)
    full = theta_o >= np.pi
    rows[:, _COS_O] = np.where(full, -1.0, np.cos(theta_o))
    rows[:, _SIN_O] = np.where(full, 0.0, np.sin(theta_o))
    # theta_e = pi/2 exactly gives cos 0 (np.cos would leave 6e-17).
    rows[:, _COS_E] = np.where(theta_e == 0.5 * np.pi, 0.0, np.cos(theta_e))
    return rows, lo, hi


def _choose_split(F: np.ndarray, sizes: np.ndarray, nb: int, n_lo, n_hi, n_axis, same_te: bool) -> np.ndarray:
    """Binned split of T nodes along all three axes at once. Returns (k,) bool, True where the
    light goes to the second child.

    F: (k, _NF) the nodes' lights, node after node, with sizes (T,) >= 3; nb buckets per axis;
    n_lo, n_hi: (T, 3) node AABBs. A candidate's cost is pbrt's EvaluateCost summed over both
    sides, phi * M_Omega(theta_o, theta_e) * K_r * SurfaceArea with K_r = max extent / extent
    along the axis; splits that leave a side empty are invalid. Rows below are (axis, node)
    pairs, axis-major: R = 3 T.
    """
    T = sizes.size
    k = F.shape[0]
    offs = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    sid_all = np.repeat(np.arange(T), sizes)
    c_all = 0.5 * (F[:, _F_LO] + F[:, _F_HI])
    cmin = np.minimum.reduceat(c_all, offs, axis=0)
    ext = np.maximum.reduceat(c_all, offs, axis=0) - cmin
    ok_axis = ext > 0.0                                         # (T, 3)
    scale = np.where(ok_axis, nb / np.where(ok_axis, ext, 1.0), 0.0)
    # Bucket statistics of big nodes come from an evenly strided subset of at most
    # SPLIT_SAMPLE lights (a sampled SAH: the cost only ranks candidate planes); every light
    # is then sent left or right by the exact bucket test, so both children stay non-empty.
    stride = -(-sizes // SPLIT_SAMPLE)
    if np.any(stride > 1):
        sub = (np.arange(k) - offs[sid_all]) % stride[sid_all] == 0
        F, sid, c = F[sub], sid_all[sub], c_all[sub]
    else:
        sid, c = sid_all, c_all
    bk = ((c - cmin[sid]) * scale[sid]).astype(np.int64)          # (k', 3) bucket per axis
    np.minimum(bk, nb - 1, out=bk)
    R = 3 * T
    K = R * nb
    key = ((np.arange(3) * T)[None, :] + sid[:, None]) * nb + bk  # (k, 3)
    key = key.T.ravel()                                           # (3k,) axis-major
    cnt = np.bincount(key, minlength=K).reshape(R, nb)
    b_phi = np.bincount(key, weights=np.tile(F[:, _F_PHI], 3), minlength=K).reshape(R, nb)
    # Per-component 1-D ufunc.at takes numpy's fast path (the 2-D form is ~10x slower).
    b_lo = np.full((3, K), np.inf)
    b_hi = np.full((3, K), -np.inf)
    for j in range(3):
        np.minimum.at(b_lo[j], key, np.tile(F[:, j], 3))
        np.maximum.at(b_hi[j], key, np.tile(F[:, 3 + j], 3))
    b_lo = b_lo.reshape(3, R, nb)     # component-major: the sweeps below run along contiguous rows
    b_hi = b_hi.reshape(3, R, nb)

    # ---- orientation: M_Omega of both sides of every boundary ----------------------------
    # Cones are measured about the node's axis (the mean normal of its lights): light i fits
    # in the cone of half-angle ang_i = angle(axis, w_i) + theta_o_i about it, and a side's
    # cone is the widest of its lights'. M_Omega grows with theta_o, so when all lights share
    # theta_e (always, for UsdLux lights) a side's M_Omega is the largest M_Omega(ang_i) of
    # its lights: a running maximum over buckets, no cone algebra per candidate. (pbrt
    # merges bucket cones pairwise around moving axes, which is tighter; here that doubled
    # the build time without a measurable gain in sampling quality.)
    if np.any(F[:, _F_DIR] > 0.0):
        ang = np.arccos(np.clip(np.einsum("ij,ij->i", n_axis[sid], F[:, _F_W]), -1.0, 1.0)) + F[:, _F_TO]
        ang = np.minimum(ang, np.pi)
    else:
        ang = np.full(sid.size, np.pi)          # every cone is the whole sphere (fireflies)

    def side_max(v):
        """Per (row, boundary): the max of v over the lights left / right of the boundary."""
        b = np.zeros(K)
        np.maximum.at(b, key, np.tile(v, 3))
        b = b.reshape(R, nb)
        return np.maximum.accumulate(b, axis=1)[:, :-1], np.maximum.accumulate(b[:, ::-1], axis=1)[:, ::-1][:, 1:]

    if same_te:
        l_m, r_m = side_max(m_omega(ang, F[:, _F_TE]))
    else:
        (l_to, r_to), (l_te, r_te) = side_max(ang), side_max(F[:, _F_TE])
        l_m, r_m = m_omega(l_to, l_te), m_omega(r_to, r_te)

    l_lo = np.minimum.accumulate(b_lo, axis=2)[..., :-1]
    l_hi = np.maximum.accumulate(b_hi, axis=2)[..., :-1]
    r_lo = np.minimum.accumulate(b_lo[..., ::-1], axis=2)[..., ::-1][..., 1:]
    r_hi = np.maximum.accumulate(b_hi[..., ::-1], axis=2)[..., ::-1][..., 1:]
    l_phi = np.cumsum(b_phi, axis=1)[:, :-1]
    r_phi = np.cumsum(b_phi[:, ::-1], axis=1)[:, ::-1][:, 1:]
    l_cnt = np.cumsum(cnt, axis=1)[:, :-1]
    r_cnt = np.cumsum(cnt[:, ::-1], axis=1)[:, ::-1][:, 1:]
    node_ext = n_hi - n_lo
    max_ext = node_ext.max(axis=1)
    kr = (max_ext[None, :] / np.where(node_ext.T > 0.0, node_ext.T, 1.0)).reshape(R, 1)
    floor = np.broadcast_to(np.tile(1e-3 * max_ext, 3)[:, None], (R, nb - 1))   # see _surface_area
    cost = kr * (l_phi * l_m * _surface_area(l_lo, l_hi, floor) + r_phi * r_m * _surface_area(r_lo, r_hi, floor))
    valid = (l_cnt > 0) & (r_cnt > 0) & ok_axis.T.reshape(R, 1) & np.isfinite(cost)
    cost = np.where(valid, cost, np.inf)
    # Per node: the cheapest (axis, boundary), the first one on ties (pbrt's order).
    cost = cost.reshape(3, T, nb - 1).transpose(1, 0, 2).reshape(T, 3 * (nb - 1))
    best = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(T), best])
    best_axis, best_split = np.divmod(best, nb - 1)
    ax = best_axis[sid_all]
    rows = np.arange(k)
    b_all = ((c_all[rows, ax] - cmin[sid_all, ax]) * scale[sid_all, ax]).astype(np.int64)
    go_right = np.minimum(b_all, nb - 1) > best_split[sid_all]
    # Nodes with no valid split (all centroids coincide): halve the range.
    if not np.all(found):
        rank = rows - offs[sid_all]
        go_right = np.where(found[sid_all], go_right, rank >= sizes[sid_all] // 2)
    return go_right


# ----------------------------------------------------------------------------------------
# The sampler
# ----------------------------------------------------------------------------------------
class BVHLightSampler:
    """Light BVH lighting service (see the module docstring).

    Attributes: ``root_c``, ``root_b``, ``pair_c``, ``pair_b`` the node bounds in traversal
    layout (``nodes`` rebuilds the (N, 11) table); ``child`` (N,) int32 index of the first
    child (the second is child + 1), -1 for leaves; ``leaf_light`` (N,) int32 global light of
    a leaf, -1 for interior nodes; ``pair_next`` (P, 2) and ``root_light``, the same links in
    the traversal's pair form (renderer/kernels/light_bvh.py); ``trail`` (m, words) uint64
    root-to-leaf bits per tree light; ``depth`` (m,) int32; ``slot`` (count,) int32 tree light of each global light, -1
    when the light is infinite or not in the tree; ``infinite`` (k,) int64 global indices;
    ``p_infinite`` the probability of picking an infinite light; ``build_seconds``.
    """

    name = "bvh"

    def __init__(self, lights=None, *, bounds: LightBounds | None = None, infinite=None, count: int | None = None):
        """Build from a LightSet, or (for tests and benchmarks) from precomputed ``bounds`` plus
        the global indices of ``infinite`` lights and the total light ``count``."""
        import time

        t0 = time.perf_counter()
        if bounds is None:
            bounds = light_bounds(lights)
            count = 0 if lights is None else int(lights.count)
            infinite = np.zeros(0, np.int64) if lights is None else np.asarray(lights.infinite, np.int64)
            if lights is not None and lights.count:
                phi = np.asarray(lights.phi(), dtype=np.float64)
                infinite = infinite[phi[infinite] > 0.0]   # zero-power guard for infinite lights too
        infinite = np.zeros(0, np.int64) if infinite is None else np.asarray(infinite, np.int64)
        # Zero-power guard: lights that emit nothing are never in the tree, so never picked.
        finite = np.all(np.isfinite(bounds.lo) & np.isfinite(bounds.hi), axis=1)
        ok = np.isfinite(bounds.phi) & (bounds.phi > 0.0) & finite
        if not np.all(ok):
            bounds = bounds.take(np.nonzero(ok)[0])
        if count is None:
            count = int(max(bounds.light.max(initial=-1), infinite.max(initial=-1)) + 1)
        self.count = int(count)
        self.infinite = infinite
        self._build(bounds)
        has_tree = self.child.size > 0
        k = self.infinite.size
        self.p_infinite = k / (k + (1 if has_tree else 0)) if (k or has_tree) else 0.0
        self.build_seconds = time.perf_counter() - t0

    # ------------------------------------------------------------------------------------
    # Build
    # ------------------------------------------------------------------------------------
    def _build(self, b: LightBounds) -> None:
        m = b.count
        # int32 indices: half the memory of int64, and numpy indexes with them just as well.
        self.slot = np.full(self.count, -1, dtype=np.int32)
        self.depth = np.zeros(m, dtype=np.int32)
        self.max_depth = 0
        # The node table while building; afterwards it is kept in traversal layout (_finish).
        nodes = np.zeros((max(2 * m - 1, 0), _NCOLS))
        self.child = np.full(max(2 * m - 1, 0), -1, dtype=np.int32)
        self.leaf_light = np.full(max(2 * m - 1, 0), -1, dtype=np.int32)
        self.trail = np.zeros((m, 1), np.uint64)
        if m == 0:
            self._finish(nodes)
            return
        self.slot[b.light] = np.arange(m)
        F = np.zeros((m, _NF))
        F[:, _F_LO], F[:, _F_HI], F[:, _F_PHI] = b.lo, b.hi, b.phi
        F[:, _F_W] = b.w / np.maximum(np.linalg.norm(b.w, axis=1), 1e-300)[:, None]
        F[:, _F_TO] = np.clip(b.theta_o, 0.0, np.pi)
        F[:, _F_TE] = np.clip(b.theta_e, 0.0, 0.5 * np.pi)
        F[:, _F_DIR] = F[:, _F_TO] < np.pi
        same_te = bool(np.all(F[:, _F_TE] == F[0, _F_TE]))
        ids = np.arange(m)
        # AABBs of the nodes still to split (for K_r and the area floor of the cost).
        rows, box_lo, box_hi = _node_rows(F, np.array([m]), same_te)
        nodes[0] = rows[0]
        box_w = rows[:, _W]
        if m == 1:
            self.leaf_light[0] = b.light[0]
            self._finish(nodes)
            return
        words: list[np.ndarray] = []   # trail bits, one uint64 word per 64 levels
        # Level state: the nodes still to split (all hold >= 2 lights) and, in F / ids, their
        # lights node after node, so every node is a contiguous range (reduceat).
        sizes = np.array([m], np.int64)
        seg_node = np.zeros(1, np.int64)
        next_free = 1
        level = 0
        while sizes.size:
            T = sizes.size
            offs = np.concatenate(([0], np.cumsum(sizes)[:-1]))
            sid = np.repeat(np.arange(T), sizes)

            # ---- choose a split per node (binned SAH-like cost) ----------------------------
            # Two lights: one per child, whatever the cost. Small nodes use fewer buckets
            # (as many as they could fill), so the work per level stays O(lights) rather
            # than O(nodes * 12) at the deep levels where nodes hold 3-8 lights.
            go_right = (np.arange(sid.size) - offs[sid]) >= 1
            size_class = np.searchsorted(_BUCKETS_BY_SIZE[0], sizes)
            for cls, nb in enumerate(_BUCKETS_BY_SIZE[1]):
                segs = np.nonzero(size_class == cls)[0] if nb else ()
                if not len(segs):
                    continue
                if segs.size == T:
                    go_right = _choose_split(F, sizes, nb, box_lo, box_hi, box_w, same_te)
                else:
                    sel = size_class[sid] == cls
                    go_right[sel] = _choose_split(F[sel], sizes[segs], nb, box_lo[segs], box_hi[segs],
                                                  box_w[segs], same_te)

            # ---- record the branch in every light's trail ----------------------------------
            word, bit = divmod(level, 64)
            if word == len(words):
                words.append(np.zeros(m, np.uint64))
            words[word][ids] |= go_right.astype(np.uint64) << np.uint64(bit)

            # ---- partition (stable: first child's lights first), make the children -------
            # Counting partition, O(lights): destination = node start + rank within its side.
            is_l = (~go_right).astype(np.int64)
            cl = np.cumsum(is_l)
            cr = np.arange(1, sid.size + 1) - cl
            before_l = (cl - is_l)[offs]
            before_r = (cr - (1 - is_l))[offs]
            n_right = np.add.reduceat(go_right.astype(np.int64), offs)
            n_left = sizes - n_right
            dest = np.where(go_right, offs[sid] + n_left[sid] + (cr - 1 - before_r[sid]),
                            offs[sid] + (cl - 1 - before_l[sid]))
            perm = np.zeros(sid.size, np.int64)
            perm[dest] = np.arange(sid.size)
            c_sizes = np.stack((sizes - n_right, n_right), axis=1).ravel()    # (2T,)
            first = next_free + 2 * np.arange(T, dtype=np.int64)
            next_free += 2 * T
            self.child[seg_node] = first
            c_node = np.stack((first, first + 1), axis=1).ravel()
            leaf = c_sizes == 1
            in_leaf = np.repeat(leaf, c_sizes)             # per light, in partitioned order
            if np.any(leaf):
                lp = perm[in_leaf]
                nodes[c_node[leaf]] = _node_rows(F[lp], np.ones(lp.size, np.int64), same_te)[0]
                self.leaf_light[c_node[leaf]] = b.light[ids[lp]]
                self.depth[ids[lp]] = level + 1
            keep = perm[~in_leaf]
            F, ids = F[keep], ids[keep]
            sizes, seg_node = c_sizes[~leaf], c_node[~leaf]
            if sizes.size:
                rows, box_lo, box_hi = _node_rows(F, sizes, same_te)
                nodes[seg_node] = rows
                box_w = rows[:, _W]
            level += 1

        self.trail = np.stack(words, axis=1)
        self.max_depth = int(self.depth.max())
        self._finish(nodes)

    def _finish(self, nodes: np.ndarray) -> None:
        """Keep the node table (N, 11) in traversal layout: the root's values as (1, 1, ...)
        arrays and every sibling pair's as (P, 2, ...) arrays (one pair contiguous), split into
        float64 centres (.., 3) and float32 bounds (.., 8) (_traversal_columns). Children are
        allocated in pairs after the root, so nodes c (odd) and c + 1 are pair (c - 1) / 2. The
        float64 table itself is dropped (see ``nodes``)."""
        pc, nd = _traversal_columns(nodes[0] if nodes.shape[0] else np.zeros(_NCOLS))
        self.root_c = np.ascontiguousarray(pc.reshape(1, 1, 3))
        self.root_b = np.ascontiguousarray(nd.reshape(1, 1, 8))
        pc, nd = _traversal_columns(nodes[1:].reshape(-1, 2, _NCOLS).transpose(2, 0, 1))   # (.., P, 2)
        self.pair_c = np.ascontiguousarray(pc.transpose(1, 2, 0))
        self.pair_b = np.ascontiguousarray(nd.transpose(1, 2, 0))
        # The traversal walks sibling pairs: per node of a pair, the pair of its own children,
        # or -1 - its light for a leaf (one load per level; the kernel module says why).
        P = self.pair_c.shape[0]
        node = 1 + np.arange(2 * P)
        ch = self.child[node]
        self.pair_next = np.where(ch >= 0, (ch - 1) >> 1, -1 - self.leaf_light[node]).astype(np.int32).reshape(P, 2)
        self.root_light = int(self.leaf_light[0]) if self.child.size == 1 else -1
        self._is_inf = np.zeros(self.count, bool)
        self._is_inf[self.infinite] = True

    @property
    def nodes(self) -> np.ndarray:
        """(N, 11) node table rebuilt from the traversal layout (bounds as the traversal sees
        them, float32-rounded outward), for inspection and tests."""
        def rows(pc, nd):
            cols = np.zeros(pc.shape[:-1] + (_NCOLS,))
            cols[..., 0:3] = pc
            cols[..., _R2] = np.square(nd[..., 0], dtype=np.float64)
            cols[..., _W], cols[..., _PHI] = nd[..., 1:4], nd[..., 4]
            cols[..., _COS_O], cols[..., _SIN_O], cols[..., _COS_E] = nd[..., 5], nd[..., 6], nd[..., 7]
            return cols.reshape(-1, _NCOLS)

        root = rows(self.root_c, self.root_b)
        pairs = rows(self.pair_c, self.pair_b)
        return np.concatenate((root, pairs)) if self.child.size else pairs

    # ------------------------------------------------------------------------------------
    # Traversal (renderer/kernels/light_bvh.py)
    # ------------------------------------------------------------------------------------
    @staticmethod
    def _points(ctx: ShadingContext) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ctx's points, geometric and shading normals (n, 3) float64 C-contiguous (no copy
        when they already are); the kernels take ns, else n, for the incidence bound."""
        def c(a):
            return np.ascontiguousarray(a, dtype=np.float64)
        return c(ctx.p), c(ctx.n), c(ctx.ns)

    def sample(self, ctx: ShadingContext, u: np.ndarray, remapped: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Pick one light per row. u: (n,) in [0, 1). Returns (global index (n,) int64, pmf (n,));
        pmf 0 (index 0) where no light can contribute. remapped: optional (n,) float64 output
        that receives, on rows given a tree light, u rescaled into that leaf's interval (a fresh
        uniform in [0, 1), as pbrt reuses it; mesh lights' triangle BVHs sample the triangle
        with it).

        Infinite lights (dome, distant) are picked first with probability p_inf, uniformly
        among themselves; where the tree cannot give any light at all they take its share
        (pbrt would return "no light" with probability 1 - p_inf there)."""
        u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1)
        n = u.size
        index = np.zeros(n, np.int64)
        pmf = np.zeros(n)
        if n == 0 or (self.infinite.size == 0 and self.child.size == 0):
            return index, pmf
        p, ng, ns = self._points(ctx)
        out_u = remapped if remapped is not None else np.empty(n)
        _kern.bvh_sample_kernel(u, p, ng, ns, float(self.p_infinite), self.infinite, self.pair_next,
                                self.root_light, self.root_c, self.root_b, self.pair_c, self.pair_b,
                                index, pmf, out_u)
        return index, pmf

    def pmf(self, ctx: ShadingContext, index: np.ndarray) -> np.ndarray:
        """(n,) probability that ``sample`` at ctx picks the given global light index (n,): the
        light's root-to-leaf path (its trail bits) replayed with the same arithmetic as
        sample(), so the two agree bit for bit."""
        index = np.ascontiguousarray(index, dtype=np.int64).reshape(-1)
        n = index.size
        out = np.zeros(n)
        if n == 0 or self.count == 0:
            return out
        p, ng, ns = self._points(ctx)
        _kern.bvh_pmf_kernel(index, p, ng, ns, float(self.p_infinite), self._is_inf, int(self.infinite.size),
                             self.slot, self.depth, self.trail, self.pair_next, self.root_light, self.root_c,
                             self.root_b, self.pair_c, self.pair_b, out)
        return out

    # ------------------------------------------------------------------------------------
    def memory_bytes(self) -> int:
        """Bytes held by the tree and the per-light replay data."""
        return int(self.root_c.nbytes + self.root_b.nbytes + self.pair_c.nbytes
                   + self.pair_b.nbytes + self.pair_next.nbytes + self.child.nbytes + self.leaf_light.nbytes
                   + self.trail.nbytes
                   + self.depth.nbytes + self.slot.nbytes + self.infinite.nbytes + self._is_inf.nbytes)
