"""Per-row kernels of the mesh lights (``renderer/lights/mesh.py``): exact ray / triangle tests
over a light's triangles, and per-triangle sampling with its matching pdf.

Conventions as in ``renderer.kernels`` (njit, cache, nogil, no cross-module numba imports).
Triangles are a (T, 3, 3) float64 table; a light owns the contiguous range
[start[light], start[light] + count[light]). ``nrm`` (T, 3) are unit front normals
(counter-clockwise winding), ``area`` (T,) world areas. The probability that the light picked
the triangle (``pick``, per row) comes from the caller: the oriented pick below
(``mesh_pick_kernel`` / ``mesh_pick_pmf_kernel``), the light's triangle BVH, or the area table.

**Oriented pick** (lights of at most a few dozen triangles; renderer/lights/mesh.py): per row,
weight each triangle by 4 tan(Omega_t / 4), Omega_t its solid angle seen from p (equal to
Omega_t to first order, within 27 % up to a hemisphere, and with no atan2), and by 0 where it
cannot send
light that the estimators use -- it faces away from p (one-sided lights), or all three of its
vertices lie below the tangent plane of the shading normal ns (UsdPreviewSurface reflects only,
so the integrand, the control variate's g and every MIS partner are 0 there). The pmf is
w_t / sum(w), recomputed by the pdf kernel with the same helper in the same order, so sample
and pdf agree to the bit. With spherical-triangle sampling the pdf is then about 1 / sum(Omega):
the whole visible mesh is sampled nearly uniformly in solid angle. A facing triangle whose weight
rounds to 0 keeps a tiny positive one, so nothing that can contribute is ever left out.

Sampling of one triangle seen from p (pbrt-v4's rule, decided from the (triangle, point) pair
only so that the pdf kernel makes the same choice): spherical-triangle sampling (Arvo 1995),
pdf_w = 1 / Omega, when the solid angle Omega is within [min_sa, max_sa] (3e-4 and 6.22 sr: below,
the spherical construction loses precision; above, the triangle nearly fills a hemisphere);
otherwise uniform area sampling, pdf_w = d^2 / (A |cos theta_l|). The solid angle is
Van Oosterom & Strackee's tan(Omega / 2) = |a . (b x c)| / (1 + a.b + b.c + c.a), which stays
accurate for tiny triangles (the angle-excess form cancels).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.kernels import guard_cache, guarded_sources, module_dispatchers
from renderer.kernels.light_bvh import bvh_pick_row, bvh_pmf_row
from renderer.lights.analytic import polygon_F

_PI = math.pi


@njit(cache=True, nogil=True)
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True)
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True)
def _norm(a):
    return math.sqrt(_dot(a, a))


@njit(cache=True, nogil=True)
def _unit(a):
    n = _norm(a)
    if n > 0.0:
        return (a[0] / n, a[1] / n, a[2] / n), n
    return (0.0, 0.0, 0.0), 0.0


@njit(cache=True, nogil=True)
def _vert(tris, t, k):
    return (tris[t, k, 0], tris[t, k, 1], tris[t, k, 2])


@njit(cache=True, nogil=True)
def _row(a, r):
    return (a[r, 0], a[r, 1], a[r, 2])


# A ray leaving a point of a mesh light (a BSDF sample from its own surface, or the previous
# vertex of a continuation ray that hits the light) meets the triangle it starts on at t ~ 1e-16
# about half the time: no ray the scene traces (offset origins) sees that hit, and its pdf is ~0,
# which left the general path's emission weight at 1 (about 1 % too bright on the mesh-light
# room). Hits closer than this, relative to the origin's magnitude, are not hits.
SELF_HIT_REL = 1e-9


@njit(cache=True, nogil=True)
def _t_min(o):
    """The nearest distance (SELF_HIT_REL) at which a ray from o counts a hit."""
    return SELF_HIT_REL * (1.0 + max(abs(o[0]), abs(o[1]), abs(o[2])))


@njit(cache=True, nogil=True)
def _tri_hit(o, d, v0, v1, v2):
    """Moller-Trumbore, both sides: hit distance t > _t_min(o) or inf."""
    e1 = _sub(v1, v0)
    e2 = _sub(v2, v0)
    pv = _cross(d, e2)
    det = _dot(e1, pv)
    if det == 0.0 or not math.isfinite(det):
        return math.inf
    inv = 1.0 / det
    tv = _sub(o, v0)
    u = _dot(tv, pv) * inv
    if u < 0.0 or u > 1.0:
        return math.inf
    qv = _cross(tv, e1)
    v = _dot(d, qv) * inv
    if v < 0.0 or u + v > 1.0:
        return math.inf
    t = _dot(e2, qv) * inv
    if t > _t_min(o):
        return t
    return math.inf


@njit(cache=True, nogil=True)
def mesh_hit_row(o, d, s, c, tris):
    """First hit (t, global triangle) of the ray o + t d with triangles s..s+c (inf, -1: none)."""
    best = math.inf
    which = -1
    for t in range(s, s + c):
        th = _tri_hit(o, d, _vert(tris, t, 0), _vert(tris, t, 1), _vert(tris, t, 2))
        if th < best:
            best = th
            which = t
    return best, which


@njit(cache=True, nogil=True)
def mesh_hit_kernel(idx, o, d, start, count, tris, out_t, out_tri):
    """First hit (t, global triangle) of rays o + t d with light idx's triangles (inf, -1: none)."""
    for r in range(idx.shape[0]):
        li = idx[r]
        out_t[r], out_tri[r] = mesh_hit_row(_row(o, r), _row(d, r), start[li], count[li], tris)


@njit(cache=True, nogil=True)
def plane_distance_row(t, o, d, tris, nrm):
    """Distance along o + t d to the plane of triangle t (inf where parallel / below _t_min)."""
    if t < 0:
        return math.inf
    nn = _row(nrm, t)
    den = _dot(nn, d)
    if den == 0.0:
        return math.inf
    x = _dot(nn, _sub(_vert(tris, t, 0), o)) / den
    return x if (x > _t_min(o) and math.isfinite(x)) else math.inf


@njit(cache=True, nogil=True)
def plane_distance_kernel(tri, o, d, tris, nrm, out_t):
    """Distance t (n,) along o + t d to the plane of triangle tri[r] (inf where parallel / none)."""
    for r in range(tri.shape[0]):
        out_t[r] = plane_distance_row(tri[r], _row(o, r), _row(d, r), tris, nrm)


@njit(cache=True, nogil=True)
def _solid_angle(a, b, c):
    """Solid angle of the spherical triangle of unit vectors a, b, c (Van Oosterom-Strackee)."""
    num = abs(_dot(a, _cross(b, c)))
    den = 1.0 + _dot(a, b) + _dot(b, c) + _dot(c, a)
    om = 2.0 * math.atan2(num, den)
    return om if om > 0.0 else 0.0


@njit(cache=True, nogil=True)
def _corner_angle(a, b, c):
    """Interior angle at vertex a of the spherical triangle (a, b, c) (unit vectors)."""
    tb = _sub(b, (a[0] * _dot(a, b), a[1] * _dot(a, b), a[2] * _dot(a, b)))
    tc = _sub(c, (a[0] * _dot(a, c), a[1] * _dot(a, c), a[2] * _dot(a, c)))
    return math.atan2(_norm(_cross(tb, tc)), _dot(tb, tc))


@njit(cache=True, nogil=True)
def _orth_unit(x, a):
    """normalize(x - (x . a) a) for unit a."""
    k = _dot(x, a)
    return _unit((x[0] - k * a[0], x[1] - k * a[1], x[2] - k * a[2]))[0]


@njit(cache=True, nogil=True)
def _sph_tri_sample(a, b, c, u0, u1):
    """Arvo's uniform sample of the spherical triangle (a, b, c): a unit direction.

    A sub-triangle (a, b, c') of area u0 * Omega is cut off along the arc a -> c (its vertex c'
    solves the spherical law of cosines for the prescribed area), then the direction is drawn
    on the arc b -> c' with cos linear in u1, which makes the density uniform.
    """
    alpha = _corner_angle(a, b, c)
    beta = _corner_angle(b, c, a)
    gamma = _corner_angle(c, a, b)
    area = alpha + beta + gamma - _PI
    sub = u0 * area
    s = math.sin(sub - alpha)
    t = math.cos(sub - alpha)
    ca = math.cos(alpha)
    sa = math.sin(alpha)
    uu = t - ca
    vv = s + sa * _dot(a, b)
    den = (vv * s + uu * t) * sa
    q = ((vv * t - uu * s) * ca - vv) / den if den != 0.0 else 1.0
    q = min(max(q, -1.0), 1.0)
    w = _orth_unit(c, a)
    sq = math.sqrt(max(0.0, 1.0 - q * q))
    cp = (q * a[0] + sq * w[0], q * a[1] + sq * w[1], q * a[2] + sq * w[2])
    z = 1.0 - u1 * (1.0 - _dot(cp, b))
    z = min(max(z, -1.0), 1.0)
    w2 = _orth_unit(cp, b)
    sz = math.sqrt(max(0.0, 1.0 - z * z))
    out = (z * b[0] + sz * w2[0], z * b[1] + sz * w2[1], z * b[2] + sz * w2[2])
    return _unit(out)[0]


@njit(cache=True, nogil=True)
def _tri_pdf(p, tri, x, dist, tris, nrm, area, pick, two_sided, min_sa, max_sa):
    """Solid-angle pdf of the sampler for the point x (at distance dist) on triangle tri, which
    was picked with probability pick. 0 where the triangle faces away from p (one-sided lights)."""
    v0 = _vert(tris, tri, 0)
    nn = _row(nrm, tri)
    h = _dot(nn, _sub(p, v0))
    if area[tri] <= 0.0 or pick <= 0.0 or h == 0.0 or (h < 0.0 and not two_sided):
        return 0.0
    a = _unit(_sub(v0, p))[0]
    b = _unit(_sub(_vert(tris, tri, 1), p))[0]
    c = _unit(_sub(_vert(tris, tri, 2), p))[0]
    om = _solid_angle(a, b, c)
    if om >= min_sa and om <= max_sa:
        return pick / om
    if not (dist > 0.0):
        return 0.0
    cos_l = abs(h) / dist  # = |n . (p - x)| / |p - x| for x in the plane
    if cos_l <= 0.0:
        return 0.0
    out = pick * dist * dist / (area[tri] * cos_l)
    return out if math.isfinite(out) else 0.0


@njit(cache=True, nogil=True, inline="always")
def _store(r, L, k, w, pdf, d, x, out_L, out_wi, out_pdf, out_dist, out_p):
    """Write row r of a light sample: radiance L (3-tuple) times k, direction w, pdf,
    distance d and the point x on the light."""
    out_L[r, 0] = L[0] * k
    out_L[r, 1] = L[1] * k
    out_L[r, 2] = L[2] * k
    out_wi[r, 0] = w[0]
    out_wi[r, 1] = w[1]
    out_wi[r, 2] = w[2]
    out_pdf[r] = pdf
    out_dist[r] = d
    out_p[r, 0] = x[0]
    out_p[r, 1] = x[1]
    out_p[r, 2] = x[2]


@njit(cache=True, nogil=True)
def mesh_sample_row(pr, t, pick, u0, u1, tris, nrm, area, ts, Lrad, min_sa, max_sa):
    """A point of triangle t (global index, picked with probability pick; two-sided ts) seen
    from pr with fresh uniforms (u0, u1): (L (3-tuple), wi, pdf, dist, x). A failed sample has
    pdf 0 and L 0."""
    none = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0, pr)
    if t < 0 or not (pick > 0.0):
        return none
    v0 = _vert(tris, t, 0)
    v1 = _vert(tris, t, 1)
    v2 = _vert(tris, t, 2)
    nn = _row(nrm, t)
    h = _dot(nn, _sub(pr, v0))
    if area[t] <= 0.0 or h == 0.0 or (h < 0.0 and not ts):
        return none
    a = _unit(_sub(v0, pr))[0]
    b = _unit(_sub(v1, pr))[0]
    c = _unit(_sub(v2, pr))[0]
    om = _solid_angle(a, b, c)
    if om >= min_sa and om <= max_sa:
        w = _sph_tri_sample(a, b, c, u0, u1)
        den = _dot(nn, w)
        if den == 0.0:
            return none
        dist = -h / den
        if not (dist > 0.0 and math.isfinite(dist)):
            return none
        x = (pr[0] + dist * w[0], pr[1] + dist * w[1], pr[2] + dist * w[2])
        pdf = pick / om
    else:
        su = math.sqrt(u0)
        b0 = 1.0 - su
        b1 = u1 * su
        b2 = 1.0 - b0 - b1
        x = (b0 * v0[0] + b1 * v1[0] + b2 * v2[0],
             b0 * v0[1] + b1 * v1[1] + b2 * v2[1],
             b0 * v0[2] + b1 * v1[2] + b2 * v2[2])
        w, dist = _unit(_sub(x, pr))
        if not (dist > 0.0):
            return none
        cos_l = abs(h) / dist
        if cos_l <= 0.0:
            return none
        pdf = pick * dist * dist / (area[t] * cos_l)
        if not math.isfinite(pdf):
            return none
    if not (pdf > 0.0):
        return none
    return Lrad, w, pdf, dist, x


@njit(cache=True, nogil=True)
def mesh_sample_kernel(idx, tri, pick, p, u, tris, nrm, area, two_sided, Lrad, min_sa, max_sa,
                       out_L, out_wi, out_pdf, out_dist, out_p):
    """Sample a point of triangle tri[r] (already picked, global index, with probability
    pick[r]) of light idx[r] from p: mesh_sample_row per row.

    u (n, 2) are fresh uniforms (the triangle pick's were remapped by the caller). Outputs are
    fully written; a failed sample has pdf 0, L 0.
    """
    for r in range(idx.shape[0]):
        li = idx[r]
        L, w, pdf, dist, x = mesh_sample_row(_row(p, r), tri[r], pick[r], u[r, 0], u[r, 1], tris, nrm, area,
                                             two_sided[li], _row(Lrad, li), min_sa, max_sa)
        _store(r, L, 1.0, w, pdf, dist, x, out_L, out_wi, out_pdf, out_dist, out_p)


@njit(cache=True, nogil=True)
def mesh_pdf_kernel(idx, tri, pick, t_hit, p, wi, tris, nrm, area, two_sided, min_sa, max_sa, out_pdf):
    """pdf (n,) of sampling wi: the density of the first-hit triangle tri[r] at distance t_hit[r],
    picked with probability pick[r]."""
    for r in range(idx.shape[0]):
        t = tri[r]
        if t < 0 or not math.isfinite(t_hit[r]):
            out_pdf[r] = 0.0
            continue
        pr = _row(p, r)
        d = t_hit[r]
        x = (pr[0] + d * wi[r, 0], pr[1] + d * wi[r, 1], pr[2] + d * wi[r, 2])
        out_pdf[r] = _tri_pdf(pr, t, x, d, tris, nrm, area, pick[r], two_sided[idx[r]], min_sa, max_sa)


# ----------------------------------------------------------------------------------------
# Oriented triangle pick (see the module docstring)
# ----------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _pick_weight(p, ns, t, tris, nrm, area, two_sided, horizon_pad, floor):
    """Unnormalised pick weight of triangle t seen from p with shading normal ns (zeros: no
    horizon test): its solid angle, at least floor, where it can contribute, else 0."""
    if area[t] <= 0.0:
        return 0.0
    v0 = _vert(tris, t, 0)
    h = _dot(_row(nrm, t), _sub(p, v0))
    # The sample kernel fails on exactly these triangles (same test, same arithmetic).
    if h == 0.0 or (h < 0.0 and not two_sided):
        return 0.0
    # Unnormalised corner vectors: Van Oosterom & Strackee's form needs no divisions,
    # tan(Omega / 2) = |A . (B x C)| / (abc + (A.B) c + (B.C) a + (C.A) b) = num / den.
    A = _sub(v0, p)
    B = _sub(_vert(tris, t, 1), p)
    C = _sub(_vert(tris, t, 2), p)
    la = _norm(A)
    lb = _norm(B)
    lc = _norm(C)
    # Entirely below the tangent plane (all three vertices, less a small pad for rounding):
    # a reflection-only BSDF sends nothing toward any point of it.
    if (_dot(A, ns) < -horizon_pad * la and _dot(B, ns) < -horizon_pad * lb
            and _dot(C, ns) < -horizon_pad * lc):
        return 0.0
    num = abs(_dot(A, _cross(B, C)))
    den = la * lb * lc + _dot(A, B) * lc + _dot(B, C) * la + _dot(C, A) * lb
    # 4 tan(Omega / 4) by the half-angle identity (valid for den < 0 too), not Omega itself:
    # no atan2, ~40 % cheaper; it is Omega (1 + Omega^2 / 48 + ...), within 27 % of Omega up
    # to a hemisphere, and only ratios of weights matter.
    # tan(x / 2) = y / (r + x) = (r - x) / y for the angle x = Omega / 2 of (den, num): each form
    # where it does not cancel (Omega > pi, den < 0: p close to a large triangle).
    r = math.sqrt(num * num + den * den)
    if den >= 0.0:
        w = 4.0 * num / (den + r) if r > 0.0 else 0.0
    elif num > 0.0:
        w = 4.0 * (r - den) / num
    else:
        w = 1e30   # p all but on the triangle: Omega -> 2 pi
    return w if (w > floor and w < 1e30) else (1e30 if w >= 1e30 else floor)


@njit(cache=True, nogil=True)
def mesh_pick_row(pr, nr, u0, s, c, tris, nrm, area, ts, horizon_pad, floor):
    """Pick one of triangles s..s+c seen from pr with shading normal nr with probability
    w_t / sum(w) (``_pick_weight``) by inverting the running sum with u0: (global triangle (-1:
    none can contribute), its probability (0: none), u0 rescaled into the chosen interval (a
    fresh uniform)). The weights are computed twice (total, then the walk) rather than stored:
    the same arithmetic gives the same numbers, and the total is summed in triangle order,
    exactly as mesh_pick_pmf_row sums it."""
    total = 0.0
    for k in range(c):
        total += _pick_weight(pr, nr, s + k, tris, nrm, area, ts, horizon_pad, floor)
    if not (total > 0.0) or not math.isfinite(total):
        return -1, 0.0, 0.0
    x = u0 * total
    run = 0.0
    last = -1
    last_run = 0.0
    w_last = 0.0
    for k in range(c):
        w = _pick_weight(pr, nr, s + k, tris, nrm, area, ts, horizon_pad, floor)
        if w <= 0.0:
            continue
        last, last_run, w_last = k, run, w
        if x < run + w:
            break
        run += w
    # (Rounding can leave x past the last interval: the last contributing triangle takes it.)
    v = (x - last_run) / w_last
    return s + last, w_last / total, min(max(v, 0.0), 1.0 - 2.0 ** -53)


@njit(cache=True, nogil=True)
def mesh_pick_kernel(idx, p, ns, u0, start, count, tris, nrm, area, two_sided, horizon_pad, floor,
                     out_tri, out_pick, out_u):
    """Pick a triangle of light idx[r] (mesh_pick_row per row). Writes the global triangle (-1:
    none can contribute), its probability (0: none) and u0 rescaled into the chosen interval."""
    for r in range(idx.shape[0]):
        li = idx[r]
        out_tri[r], out_pick[r], out_u[r] = mesh_pick_row(_row(p, r), _row(ns, r), u0[r], start[li], count[li],
                                                          tris, nrm, area, two_sided[li], horizon_pad, floor)


@njit(cache=True, nogil=True)
def mesh_pick_pmf_row(pr, nr, t, s, c, tris, nrm, area, ts, horizon_pad, floor):
    """The probability that mesh_pick_row picks global triangle t (0 for -1)."""
    if t < 0:
        return 0.0
    total = 0.0
    for k in range(s, s + c):
        total += _pick_weight(pr, nr, k, tris, nrm, area, ts, horizon_pad, floor)
    if not (total > 0.0) or not math.isfinite(total):
        return 0.0
    return _pick_weight(pr, nr, t, tris, nrm, area, ts, horizon_pad, floor) / total


@njit(cache=True, nogil=True)
def mesh_pick_pmf_kernel(idx, tri, p, ns, start, count, tris, nrm, area, two_sided, horizon_pad, floor,
                         out_pick):
    """The probability (n,) that mesh_pick_kernel picks global triangle tri[r] (0 for -1)."""
    for r in range(idx.shape[0]):
        li = idx[r]
        out_pick[r] = mesh_pick_pmf_row(_row(p, r), _row(ns, r), tri[r], start[li], count[li], tris, nrm, area,
                                        two_sided[li], horizon_pad, floor)


# ----------------------------------------------------------------------------------------
# A whole mesh light per row, for compiled integrators (the fast path's vertex kernel)
# ----------------------------------------------------------------------------------------
# The record MS (MeshLight.compiled_record): (tris, nrm, area, start, count, two_sided, L,
# has_tree (k,) bool, TR, consts). TR: the triangle BVHs of the lights that have one (lights/mesh.py:
# more than EXACT_PICK_TRIANGLES triangles) concatenated, (pair_start (k + 1,), pair_next,
# pair_c, pair_b (light j's pairs at pair_start[j]:pair_start[j + 1], child indices local to
# it), slot, depth, trail (rows of light j's triangles: its leaves), root_light, root_c, root_b,
# p_inf (k,) per light, is_inf (T,) all False, infinite (0,)), which light_bvh's rows take as
# slices; consts: (horizon_pad, floor, min_sa, max_sa). The same pick, sample and pdf as
# MeshLight.sample_li / pdf_li with the "oriented" pick (the numpy route's kernels above, and
# light_bvh's rows for the large lights).
@njit(cache=True, nogil=True)
def mesh_light_pick_row(MS, j, p, ns, u0):
    """Light j's triangle pick at p with shading normal ns from u0: (global triangle or -1,
    probability, remapped uniform)."""
    tris, nrm, area, start, count, two_sided, _L, has_tree, TR, K = MS
    if has_tree[j]:
        a, b = TR[0][j], TR[0][j + 1]
        loc, pr, uu, _tree = bvh_pick_row(u0, p[0], p[1], p[2], ns[0], ns[1], ns[2], True, TR[10][j], TR[12],
                                          TR[1][a:b], TR[7][j], TR[8][j:j + 1], TR[9][j:j + 1], TR[2][a:b],
                                          TR[3][a:b])
        if not (pr > 0.0):
            return -1, 0.0, 0.0
        return start[j] + loc, pr, uu
    return mesh_pick_row(p, ns, u0, start[j], count[j], tris, nrm, area, two_sided[j], K[0], K[1])


@njit(cache=True, nogil=True)
def mesh_light_pick_prob_row(MS, j, p, ns, t):
    """The probability that mesh_light_pick_row at p, ns picks global triangle t (0 for -1)."""
    tris, nrm, area, start, count, two_sided, _L, has_tree, TR, K = MS
    if t < 0:
        return 0.0
    if has_tree[j]:
        a, b = TR[0][j], TR[0][j + 1]
        s, c = start[j], count[j]
        return bvh_pmf_row(t - s, p[0], p[1], p[2], ns[0], ns[1], ns[2], True, TR[10][j], TR[11][s:s + c], 0,
                           TR[4][s:s + c], TR[5][s:s + c], TR[6][s:s + c], TR[1][a:b], TR[7][j], TR[8][j:j + 1],
                           TR[9][j:j + 1], TR[2][a:b], TR[3][a:b])
    return mesh_pick_pmf_row(p, ns, t, start[j], count[j], tris, nrm, area, two_sided[j], K[0], K[1])


@njit(cache=True, nogil=True)
def mesh_light_sample_row(MS, j, p, ns, u0, u1):
    """Light j's sample from p (shading normal ns) with uniforms (u0, u1): (L, wi, pdf, dist, x)
    as mesh_sample_row; pdf 0 where it fails."""
    tris, nrm, area, _start, _count, two_sided, L, _has_tree, _TR, K = MS
    t, pick, uu = mesh_light_pick_row(MS, j, p, ns, u0)
    return mesh_sample_row(p, t, pick, uu, u1, tris, nrm, area, two_sided[j], (L[j, 0], L[j, 1], L[j, 2]), K[2],
                           K[3])


@njit(cache=True, nogil=True)
def mesh_light_pdf_row(MS, j, p, ns, wi, t, dist):
    """The solid-angle pdf with which light j's sampler at p (shading normal ns) gives wi,
    whose first triangle of the light is t (global, -1: none) at distance dist."""
    tris, nrm, area, _start, _count, two_sided, _L, _has_tree, _TR, K = MS
    if t < 0 or not math.isfinite(dist):
        return 0.0
    pick = mesh_light_pick_prob_row(MS, j, p, ns, t)
    x = (p[0] + dist * wi[0], p[1] + dist * wi[1], p[2] + dist * wi[2])
    return _tri_pdf(p, t, x, dist, tris, nrm, area, pick, two_sided[j], K[2], K[3])


@njit(cache=True, nogil=True)
def mesh_light_emission_row(MS, j, cos_front):
    """Radiance (3-tuple) of light j toward a viewer at cos_front = -d . n_front of the triangle
    it sees (MeshLight.surface_emission): its front, or either side when two-sided."""
    two_sided, L = MS[5], MS[6]
    if cos_front > 0.0 or (two_sided[j] and cos_front != 0.0):
        return (L[j, 0], L[j, 1], L[j, 2])
    return (0.0, 0.0, 0.0)


@njit(cache=True, nogil=True)
def mesh_light_along_row(MS, j, p, ns, wi):
    """Light j seen from p along wi (estimators.base.light_along, then pdf_li where seen): (t,
    Le, p_l); (inf, black, 0) where wi misses it. Its first triangle by exact float64 tests
    (the numpy route asks a large light's own embree BVH)."""
    tris, nrm = MS[0], MS[1]
    start, count = MS[3], MS[4]
    t_hit, t = mesh_hit_row(p, wi, start[j], count[j], tris)
    if t < 0:
        return math.inf, (0.0, 0.0, 0.0), 0.0
    Le = mesh_light_emission_row(MS, j, -_dot(wi, _row(nrm, t)))
    return t_hit, Le, mesh_light_pdf_row(MS, j, p, ns, wi, t, t_hit)


@njit(cache=True, nogil=True)
def mesh_G_row(p, ns, s, c, tris, nrm, ts, far_ratio, kappa_max):
    """Projected solid angle [sr] of triangles s..s+c seen from p about the shading normal ns:
    Lambert's polygon formula per triangle (lights/analytic.polygon_F, one-sided about its front
    normal unless ts), summed in triangle order. Times the light's radiance: its irradiance."""
    G = 0.0
    for t in range(s, s + c):
        G += polygon_F(p, ns, (_vert(tris, t, 0), _vert(tris, t, 1), _vert(tris, t, 2)), _row(nrm, t), not ts,
                       far_ratio, kappa_max)
    return G


@njit(cache=True, nogil=True)
def mesh_G_kernel(idx, p, ns, start, count, tris, nrm, two_sided, far_ratio, kappa_max, out):
    """mesh_G_row for rows (light idx[r] at p[r], ns[r]) into out (n,)."""
    for r in range(idx.shape[0]):
        li = idx[r]
        out[r] = mesh_G_row(_row(p, r), _row(ns, r), start[li], count[li], tris, nrm, two_sided[li], far_ratio,
                            kappa_max)


# The row functions inline light_bvh's walks and analytic.polygon_F (see renderer/kernels/__init__.py).
guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/kernels/light_bvh.py", *guarded_sources("renderer.lights.analytic")])
