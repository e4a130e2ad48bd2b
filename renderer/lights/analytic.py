"""Exact unshadowed cosine-weighted solid-angle integrals of light shapes (control-variate F).

For a shading point p with unit normal nrm every function returns

    G = ∫_{light ∩ upper hemisphere of nrm} max(0, nrm·ω) dω        in steradians,

the *projected solid angle* of the part of the light that p sees and that lies above its
horizon. A uniform emitter of radiance L gives irradiance E = L·G, and a Lambert lobe of albedo
ρ gives the control-variate integral F = (ρ/π)·L·G. Visibility (shadowing) is not included.

Conventions
-----------
* Each formula is one compiled row function, one shading point and one light per call:
  ``rect_F``, ``polygon_F`` (a mesh light's triangle too), ``sphere_F``, ``disk_F``,
  ``ellipse_F``, ``dome_constant_F``. Scalars and 3-tuples in (world units), G out;
  ``@njit(cache=True, nogil=True, error_model="numpy")``, no allocation, no Python objects,
  so other kernels call them (the fused path vertex: it must then list this file and
  renderer/geometry.py, whose ``frame_row`` these inline, in its ``guard_cache``; see
  renderer/kernels/__init__.py). The quadrature switches FAR_RATIO and KAPPA_MAX are
  arguments defaulting to the module constants (the kernels' rule: no globals frozen across
  files; the numpy API passes the module's current values, which tests patch).
* The numpy API (``projected_solid_angle_*``: (n, 3) rows, parameters broadcast against p's
  rows, (n,) out) is a compiled loop over rows calling the row functions.
* All the kinds live in this one file rather than in renderer/lights/<kind>.py: they share
  the Green's-theorem edge flux, the horizon clip, the grazing difference form, the sliver
  test and the Gauss-Legendre area quadrature (rect/polygon/mesh, disk and ellipse), and
  numba keys its on-disk cache on the defining file, so one file keeps each formula once
  without cross-file cache guards. A light kind's file imports its row function from here.
* float64 throughout.
* One-sided emitters: a rect/disk emits along its unit normal e_n and p sees it iff
  dot(p − c, e_n) > 0 (p in the light's plane gets 0); a sphere emits outward, so a point on
  or inside it gets 0.
* Results are finite, ≥ 0, and computed without floating-point warnings.

How each integral is evaluated (all exact up to rounding)
---------------------------------------------------------
Planar lights (polygon, rect, disk) use Lambert's formula in an in-plane form. With q the
foot of p on the light's plane, h > 0 the height of p above it, ρ the 2-D in-plane position
relative to q, c = −nrm·N and m the in-plane part of nrm (N: plane normal towards p),

    G = ∫_A h (m·ρ + h c) / (|ρ|² + h²)² dA          (cos_p cos_l / d², horizon-clipped).

The horizon clip is the half-plane m·ρ + h c ≥ 0 (exact 2-D Sutherland-Hodgman). By Green's
theorem the integrand is the divergence of F = c ρ / (2(|ρ|²+h²)) − (h/2) m / (|ρ|²+h²), so G
is a sum of boundary fluxes with elementary closed forms:

* straight edge at signed distance δ from q, tangential end coordinates s_a < s_b, outward
  normal n:  (c δ − h m·n) Δ / (2w), w = √(δ²+h²), Δ = atan2(w L, w² + s_a s_b). This is term
  for term Lambert's ½ θ_i nrm·normalize(v_i × v_{i+1}) with θ_i = Δ computed by atan2, but
  written so that the factor h of the linear part is explicit.
* circular arc (disk): ∫ (a0 + a1 cos ψ + b1 sin ψ) / (A − B cos ψ) dψ, integrated in closed
  form with the periodic "eccentric anomaly" correction D(ψ) = F(ψ) − ψ, so there are no
  branch cuts and no cancellation when B ≪ A or when p is near the rim (peaky integrand).
* grazing points (h smaller than the distance from q to the clipped light): the radial part
  is evaluated as the difference from its h = 0 value (the in-plane winding angle of q,
  exactly 0 outside), which removes the cancellation ~ε·r_q/h of the plain sum.

Area quadrature replaces the boundary sums where they cancel (their terms are O(angular size)
while G is O(angular size²)): for lights smaller than FAR_RATIO × distance, and for "slivers"
(thin lights, lights sliced thinly by the horizon) whose terms cancel by more than KAPPA_MAX,
when the light's radius is below QUAD_MAX_R × its distance. The same integrand is integrated
over the clipped area by Gauss-Legendre (collapsed-square fan triangles for polygons, a
polar-segment map for disks) in coordinates relative to the light's centre, with an order
chosen so that the error bound r^(2·order) (r = radius / distance) is below 1e-17.

Ellipse (a disk under non-uniform scale): the same Green's-theorem fluxes, with the arc flux
integrated numerically (Gauss-Legendre on panels graded towards the integrand's complex poles,
which are the roots of a quartic) — not a closed form, but accurate to ~1e-13 in the tests.

Sphere: exact closed form. Fully above the horizon (cos θ ≥ sin σ): π sin²σ cos θ. Straddling:
Snyder (1996) / Frostbite's expression, which is *exact* (see projected_solid_angle_sphere for
the derivation and for the rearrangement that avoids cancellation at tiny σ and near the
sphere's surface).

Accuracy (tests/analytic, against independent quadrature over thousands of configurations
with sizes 1e-6..1e6 and distance/size 1e-12..1e12): relative error ≤ ~1e-9 wherever G is
determined by the float64 inputs to better than that; see tests/analytic/report_errors.py.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.geometry import frame_row
from renderer.kernels import guard_cache, module_dispatchers

__all__ = [
    "FAR_RATIO",
    "FAR_ORDER",
    "projected_solid_angle_polygon",
    "projected_solid_angle_rect",
    "projected_solid_angle_sphere",
    "projected_solid_angle_disk",
    "projected_solid_angle_ellipse",
    "projected_solid_angle_dome_constant",
    "rect_F",
    "polygon_F",
    "sphere_F",
    "disk_F",
    "ellipse_F",
    "dome_constant_F",
    "distant_F",
    "projected_solid_angle_distant",
]

# Light diameter / distance below which the far-field quadrature replaces the boundary sums,
# which lose ~ε·(distance/size) relative to cancellation there.
FAR_RATIO = 1e-2
# Minimum Gauss-Legendre order per dimension of the area quadrature. The order actually used
# grows with r = (light radius)/(lower bound of its distance) so that r^(2·order) < 1e-17.
FAR_ORDER = 6
# Boundary sums whose terms cancel by more than this factor (slivers: thin lights, or lights
# sliced thinly by the horizon) are recomputed by area quadrature when r ≤ QUAD_MAX_R.
KAPPA_MAX = 1e5
QUAD_MAX_R = 0.35
_MAX_ORDER = 24
# The disk's polar-segment map carries a sin²φ factor (area element × chord length) that is
# not a polynomial in φ: 16 nodes integrate it over [0, π] to ~1e-16 (6 would leave ~1e-6).
_DISK_PHI_ORDER = 16
# Gauss-Legendre order of each panel of the ellipse's arc quadrature.
_ARC_ORDER = 12
_NEWTON_STEP = np.pi / 32     # largest Newton step (radians) when refining the nearest rim point
_TINY = float(np.finfo(np.float64).tiny)
_EPS = float(np.finfo(np.float64).eps)
_PI = math.pi
_TWO_PI = 2.0 * math.pi


def _gl_tables():
    """Gauss-Legendre nodes/weights of every order n ≤ _MAX_ORDER: row n holds order n's nodes
    (first n entries) on [-1, 1] (x, w) and on [0, 1] (x01, w01). numba freezes these module
    arrays into the compiled code as constants (no allocation in the kernels)."""
    x = np.zeros((_MAX_ORDER + 1, _MAX_ORDER))
    w = np.zeros_like(x)
    for n in range(1, _MAX_ORDER + 1):
        x[n, :n], w[n, :n] = np.polynomial.legendre.leggauss(n)
    return x, w, 0.5 * (x + 1.0), 0.5 * w


_GL_X, _GL_W, _GL_X01, _GL_W01 = _gl_tables()

# error_model="numpy": IEEE results instead of ZeroDivisionError checks (no exception exits in
# the callers' loops; the formulas guard their divisions themselves), as in renderer/kernels.
_jit = njit(cache=True, nogil=True, error_model="numpy")


# ----------------------------------------------------------------------------------------
# small scalar helpers (3-vectors and 2-vectors are tuples of floats)
# ----------------------------------------------------------------------------------------
@_jit
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@_jit
def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@_jit
def _scale(k, a):
    return (k * a[0], k * a[1], k * a[2])


@_jit
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@_jit
def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@_jit
def _unit(a):
    """(unit vector, length); a zero vector stays zero."""
    length = math.sqrt(_dot(a, a))
    ls = length if length > 0.0 else 1.0
    return (a[0] / ls, a[1] / ls, a[2] / ls), length


@_jit
def _vec(V, i):
    """Vertex i of V, a (k, 3) array or a tuple of 3-tuples, as a 3-tuple of floats."""
    v = V[i]
    return (float(v[0]), float(v[1]), float(v[2]))


@_jit
def _row(a, i):
    return (a[i, 0], a[i, 1], a[i, 2])


@_jit
def _sign(x):
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@_jit
def _atanc(t):
    """atan(t)/t, = 1 at t = 0."""
    if abs(t) < 1e-8:
        return 1.0 - t * t / 3.0
    return math.atan(t) / t


@_jit
def _log1pc(x):
    """log1p(x)/x for x > -1, = 1 at x = 0."""
    if abs(x) < 1e-8:
        return 1.0 - 0.5 * x
    return math.log1p(x) / x


@_jit
def _quad_order(r):
    """Order with r^(2n) ≤ 1e-17 (r < 1), at least FAR_ORDER, at most _MAX_ORDER."""
    rr = min(max(r, 1e-300), 0.999)
    n = math.ceil(17.0 / (-2.0 * math.log10(rr)))
    return int(min(max(n, FAR_ORDER), _MAX_ORDER))


# ----------------------------------------------------------------------------------------
# straight edges (shared by polygons and the disk's / ellipse's horizon chord)
# ----------------------------------------------------------------------------------------
@_jit
def _edge_terms(delta, sa, L, h, c, m_n, diff_form):
    """Green's-theorem flux of one straight edge, in the in-plane frame of the foot point q.

    delta: signed distance of the edge's line from q along the outward normal n; sa: tangential
    coordinate of the edge start relative to the foot of the perpendicular from q (the end is
    sa + L); L: edge length (≤ 0 -> contributes 0); h: height of p above the plane (> 0);
    c = -nrm·N; m_n = m·n (lengths in any one unit; the terms are dimensionless).
    Returns (linear, radial): the h-factored linear flux -h (m·n) Δ/(2w), and the radial flux
    c δ Δ/(2w), or with diff_form that radial flux minus its h = 0 value c·sign(δ)·Δ0/2
    (evaluated without cancellation; sign(δ)·Δ0 is the signed in-plane angle the edge subtends
    at q, and these sum to q's winding angle, 0 when q is outside the region).
    """
    if not L > 0.0:
        return 0.0, 0.0
    sb = sa + L
    w = math.hypot(delta, h)
    dw = math.atan2(w * L, w * w + sa * sb)          # angle subtended by the edge at p
    lin = -0.5 * h * m_n * dw / w
    if not diff_form:
        return lin, 0.5 * c * delta * dw / w
    # Difference from h = 0:  δΔ_w/w − sign(δ)Δ_0
    #   = (δ/w − sδ)Δ_w + sδ(Δ_w − Δ_0),   δ/w − sδ = −sδ h²/(w(w+|δ|)),
    #   Δ_w − Δ_0 = T(s_b) − T(s_a),  T(s) = atan(s/w) − atan(s/|δ|) = atan2(−s h²/(w+|δ|), w|δ| + s²).
    ad = abs(delta)
    sd = _sign(delta)
    h2 = h * h
    wpd = w + ad
    t1 = -sd * h2 / (w * wpd) * dw
    Tb = math.atan2(-sb * h2 / wpd, w * ad + sb * sb)
    Ta = math.atan2(-sa * h2 / wpd, w * ad + sa * sa)
    return lin, 0.5 * c * (t1 + sd * (Tb - Ta))


@_jit
def _use_difference_form(outside_margin, h):
    """Whether to evaluate the radial flux as "value minus its h = 0 value" (whose edge sum, the
    winding angle of q, is exactly 0 when the foot q is outside the region).

    outside_margin: how far q is outside the region (> 0 only if it is; a lower bound of its
    in-plane distance r_q to it). With the boundary known to rounding δx ~ ε·size, the in-plane
    angles at q carry errors ~δx/r_q. The plain sum passes them straight on when h ≪ r_q
    (its terms are ±c/2 times those angles, cancelling to ~h), while the difference form's
    terms are O(h²/r_q²) and damp them; when h ≳ r_q it is the other way round (the plain terms
    are then angles seen from p itself, well conditioned). So: difference form iff h < r_q.
    """
    return outside_margin > 0.0 and outside_margin > h


# ----------------------------------------------------------------------------------------
# polygons
# ----------------------------------------------------------------------------------------
@_jit
def _rel(V, R, o, has_rel, i):
    """Offset of vertex i from the centre o: R[i] exactly if given (a rect's ±ex/2 ± ey/2),
    else V[i] − o."""
    if has_rel:
        return _vec(R, i)
    return _sub(_vec(V, i), o)


@_jit
def _clip_vertex(V, R, o, has_rel, p, t1, t2, nrm, z_o, near, i):
    """In-plane coordinates (x, y) and clip function z of vertex i: relative to the foot q
    straight from v − p in the near field (a vertex close to p keeps full relative precision),
    relative to the centre o for the area quadrature."""
    if near:
        vp = _sub(_vec(V, i), p)
        return _dot(vp, t1), _dot(vp, t2), _dot(vp, nrm)
    r = _rel(V, R, o, has_rel, i)
    return _dot(r, t1), _dot(r, t2), z_o + _dot(r, nrm)


@_jit
def _clip_emit(slot, x0, y0, z0, x1, y1, z1):
    """Sutherland-Hodgman clip of a convex polygon to the half-plane z > 0, for its edge from
    vertex 0 to vertex 1 (in-plane x, y and clip function z): slot 0 is vertex 0 (kept iff
    inside), slot 1 the edge's crossing of the line (if it crosses). Returns (kept, x, y,
    is_crossing). A vertex on the line (z = 0) counts as outside; the crossing of an edge from
    it is then the vertex itself, so nothing is lost."""
    if slot == 0:
        return z0 > 0.0, x0, y0, False
    if (z0 > 0.0) == (z1 > 0.0):
        return False, 0.0, 0.0, False
    t = z0 / (z0 - z1)
    return True, x0 + t * (x1 - x0), y0 + t * (y1 - y0), True


@_jit
def _near_edge(ax, ay, a_x, bx, by, b_x, h, c, m, mm, orient):
    """Geometry of the clipped polygon's edge a → b (in-plane, relative to the foot q; a_x, b_x:
    both ends are crossings, i.e. the edge runs along the horizon line): (δ, s_a, L, m·n) for
    _edge_terms, L = 0 for an empty edge."""
    ex = bx - ax
    ey = by - ay
    L = math.hypot(ex, ey)
    if not L > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    tx, ty = ex / L, ey / L
    nx, ny = orient * ty, -orient * tx               # outward normal (right of a CCW edge)
    if a_x and b_x and mm > 0.0:
        # the horizon edge lies on m·ρ + h c = 0: outward normal −m̂, distance c·h/|m| from q
        # exactly (recomputing it from its end points would bury a tiny h in their rounding)
        return c * h / mm, ax * tx + ay * ty, L, -mm
    return ax * nx + ay * ny, ax * tx + ay * ty, L, m[0] * nx + m[1] * ny


@_jit
def _near_polygon_pass(V, R, o, has_rel, p, t1, t2, nrm, h, c, m, orient, mode):
    """One pass over the edges of the horizon-clipped polygon (in-plane coordinates relative to
    the foot q, straight from v − p: a vertex close to p keeps full relative precision).
    mode 0: (margin, clipped vertex count), margin = max over non-empty edges of −δ (how far q
    lies beyond the worst edge line); mode 1 / 2: (Σ lin + radial, Σ |lin| + |radial|) with the
    plain / the difference radial form."""
    k = len(V)
    mm = math.hypot(m[0], m[1])
    s_lin = s_rad = a_lin = a_rad = 0.0
    margin = -np.inf
    fx = fy = px = py = 0.0
    f_x = p_x = False
    n_emit = 0
    vx, vy, vz = _clip_vertex(V, R, o, has_rel, p, t1, t2, nrm, 0.0, True, 0)
    x0, y0, z0 = vx, vy, vz                            # vertex i, carried along
    x1 = y1 = z1 = 0.0
    for s in range(2 * k + 1):
        i = s >> 1
        if s < 2 * k:
            if (s & 1) == 0:                           # vertex i + 1 (vertex 0 again at the end)
                x1, y1, z1 = vx, vy, vz
                if i < k - 1:
                    x1, y1, z1 = _clip_vertex(V, R, o, has_rel, p, t1, t2, nrm, 0.0, True, i + 1)
            kept, x, y, isx = _clip_emit(s & 1, x0, y0, z0, x1, y1, z1)
            if (s & 1) == 1:
                x0, y0, z0 = x1, y1, z1
            if not kept:
                continue
        else:                                          # closing edge back to the first vertex
            x, y, isx = fx, fy, f_x
        if n_emit == 0:
            fx, fy, f_x = x, y, isx
        else:
            delta, sa, L, m_n = _near_edge(px, py, p_x, x, y, isx, h, c, m, mm, orient)
            if mode == 0:
                if L > 0.0:
                    margin = max(margin, -delta)
            else:
                lin, rad = _edge_terms(delta, sa, L, h, c, m_n, mode == 2)
                s_lin += lin
                s_rad += rad
                a_lin += abs(lin)
                a_rad += abs(rad)
        px, py, p_x = x, y, isx
        n_emit += 1
    if mode == 0:
        return margin, float(n_emit - 1)
    return s_lin + s_rad, a_lin + a_rad


@_jit
def _near_polygon(V, R, o, has_rel, p, t1, t2, nrm, h, c, m, orient):
    """Closed-form (Lambert/Green) G of the horizon-clipped polygon. Returns (G, sum of |terms|,
    clipped vertex count)."""
    margin, count = _near_polygon_pass(V, R, o, has_rel, p, t1, t2, nrm, h, c, m, orient, 0)
    if count < 3.0:
        return 0.0, 0.0, int(count)
    # radial part: plain sum, or, for grazing points whose foot q is clearly outside the
    # clipped polygon, the difference form (its h = 0 winding term is exactly 0)
    mode = 2 if _use_difference_form(margin, h) else 1
    g, mag = _near_polygon_pass(V, R, o, has_rel, p, t1, t2, nrm, h, c, m, orient, mode)
    return g, mag, int(count)


@_jit
def _far_triangle(ax, ay, bx, by, cx, cy, D2, rho_o, z_o, m, order):
    """∫ max(0, z_o + m·σ)/(D2 + 2 σ·ρ_o + |σ|²)² dA over the triangle (a, b, c) (signed by its
    winding): order×order Gauss-Legendre on the collapsed square σ = a + u e1 + u v e2."""
    e1x, e1y = bx - ax, by - ay
    e2x, e2y = cx - bx, cy - by
    area2 = e1x * e2y - e1y * e2x                   # signed, = 2·area
    tot = 0.0
    for i in range(order):
        u = _GL_X01[order, i]
        for j in range(order):
            uv = u * _GL_X01[order, j]
            sx = ax + u * e1x + uv * e2x
            sy = ay + u * e1y + uv * e2y
            wts = (_GL_W01[order, i] * _GL_W01[order, j]) * u   # collapsed-square Jacobian
            num = max(z_o + (sx * m[0] + sy * m[1]), 0.0)
            den = D2 + 2.0 * (sx * rho_o[0] + sy * rho_o[1]) + (sx * sx + sy * sy)
            tot += num / (den * den) * wts * area2
    return tot


@_jit
def _far_polygon(V, R, o, has_rel, t1, t2, nrm, z_o, D2, rho_o, m, h, orient, order):
    """Area-quadrature G: Gauss-Legendre on each fan triangle of the clipped polygon
    (coordinates relative to the centre o; D2 = |o − p|², z_o = nrm·(o − p)). Returns
    (G, clipped vertex count)."""
    k = len(V)
    p0 = (0.0, 0.0, 0.0)
    tot = 0.0
    fx = fy = px = py = 0.0
    n_emit = 0
    vx, vy, vz = _clip_vertex(V, R, o, has_rel, p0, t1, t2, nrm, z_o, False, 0)
    x0, y0, z0 = vx, vy, vz                            # vertex i, carried along
    x1 = y1 = z1 = 0.0
    for s in range(2 * k):
        i = s >> 1
        if (s & 1) == 0:                               # vertex i + 1 (vertex 0 again at the end)
            x1, y1, z1 = vx, vy, vz
            if i < k - 1:
                x1, y1, z1 = _clip_vertex(V, R, o, has_rel, p0, t1, t2, nrm, z_o, False, i + 1)
        kept, x, y, _ = _clip_emit(s & 1, x0, y0, z0, x1, y1, z1)
        if (s & 1) == 1:
            x0, y0, z0 = x1, y1, z1
        if not kept:
            continue
        if n_emit == 0:
            fx, fy = x, y
        elif n_emit >= 2:
            tot += _far_triangle(fx, fy, px, py, x, y, D2, rho_o, z_o, m, order)
        px, py = x, y
        n_emit += 1
    return orient * h * tot, n_emit


@_jit
def _polygon_core(p, nrm, V, R, o, plane_n, has_rel, front, far_ratio, kappa_max):
    """G of the planar convex polygon V (k vertices, array (k, 3) or tuple of 3-tuples) seen
    from p with unit normal nrm; 0 unless front. o: centre; R: exact offsets of the vertices
    from o if has_rel (a rect passes its own ±ex/2 ± ey/2: rebuilding them from the float64
    corners loses the offsets' low bits when the light is small and far from the origin, and
    a Newell normal's error then times the distance to p swamps p's height above a light seen
    edge-on); plane_n: plane normal (any length, either sign)."""
    N, nlen = _unit(plane_n)
    D = _sub(o, p)
    hs = -_dot(N, D)                                   # height of p along N
    N = _scale(-1.0 if hs < 0.0 else 1.0, N)          # N now points towards p
    h = abs(hs)
    if not (front and nlen > 0.0 and h > 0.0):
        return 0.0
    t1, t2 = frame_row(N)
    rho_o = (_dot(D, t1), _dot(D, t2))
    m = (_dot(nrm, t1), _dot(nrm, t2))
    c = -_dot(nrm, N)
    z_o = _dot(nrm, D)
    k = len(V)
    area2 = 0.0
    half2 = 0.0
    for i in range(k):
        ri = _rel(V, R, o, has_rel, i)
        rj = _rel(V, R, o, has_rel, (i + 1) % k)
        sx, sy = _dot(ri, t1), _dot(ri, t2)
        area2 += sx * _dot(rj, t2) - sy * _dot(rj, t1)
        half2 = max(half2, sx * sx + sy * sy)
    orient = -1.0 if area2 < 0.0 else 1.0
    half = math.sqrt(half2)                            # radius about the centre
    D2 = _dot(D, D)
    dc = math.sqrt(D2)
    rq = half / (dc - half) if dc > half else np.inf
    quad = 2.0 * half < far_ratio * dc
    res = 0.0
    if not quad:
        g, mag, count = _near_polygon(V, R, o, has_rel, p, t1, t2, nrm, h, c, m, orient)
        if count >= 3:
            res = g
            # slivers: terms cancel by > kappa_max -> area quadrature if the light is compact enough
            quad = mag > kappa_max * abs(g) and rq <= QUAD_MAX_R
    if quad:
        g, count = _far_polygon(V, R, o, has_rel, t1, t2, nrm, z_o, D2, rho_o, m, h, orient,
                                _quad_order(rq))
        res = g if count >= 3 else 0.0
    return max(res, 0.0)


@_jit
def polygon_F(p, nrm, V, e_n, one_sided, far_ratio=FAR_RATIO, kappa_max=KAPPA_MAX):
    """Projected solid angle G [sr] of a planar convex polygon seen from one shading point.

    p, nrm: 3-tuples, the shading point (world units) and its normal (normalised here; a zero
    normal gives 0). V: the k ≥ 3 corners in order (either winding), a (k, 3) float64 array or
    a tuple of k 3-tuples (a mesh light's triangle). e_n: 3-tuple emitting normal, used iff
    one_sided (then p sees the polygon iff (p − centroid)·e_n > 0); two-sided otherwise. A
    point in the polygon's plane or a (numerically) degenerate polygon gives 0.
    far_ratio, kappa_max: the switches to area quadrature (module FAR_RATIO, KAPPA_MAX).
    """
    k = len(V)
    sx = sy = sz = 0.0
    for i in range(k):
        v = _vec(V, i)
        sx += v[0]
        sy += v[1]
        sz += v[2]
    o = (sx / k, sy / k, sz / k)                       # centroid; offsets from it are accurate
    front = True
    if one_sided:
        front = _dot(_sub(p, o), e_n) > 0.0
    nx = ny = nz = 0.0                                 # Newell normal (2·area·N)
    for i in range(k):
        a = _sub(_vec(V, i), o)
        b = _sub(_vec(V, (i + 1) % k), o)
        cr = _cross(a, b)
        nx += cr[0]
        ny += cr[1]
        nz += cr[2]
    return _polygon_core(p, _unit(nrm)[0], V, V, o, (nx, ny, nz), False, front, far_ratio, kappa_max)


@_jit
def rect_F(p, nrm, center, ex, ey, e_n, far_ratio=FAR_RATIO, kappa_max=KAPPA_MAX):
    """Projected solid angle G [sr] of a one-sided rectangle/parallelogram light from one point.

    The light is {center + a·ex + b·ey : a, b ∈ [−½, ½]}: ex, ey are the FULL edge vectors (the
    convention of ``renderer.lights.rect``; a sheared transform gives a parallelogram). All
    arguments are 3-tuples in world units: shading point p, its normal nrm (normalised here),
    center, ex, ey and the emitting normal e_n (p sees the light iff (p − center)·e_n > 0).
    far_ratio, kappa_max: the switches to area quadrature (module FAR_RATIO, KAPPA_MAX).
    """
    hx = _scale(0.5, ex)
    hy = _scale(0.5, ey)
    mhx = _scale(-1.0, hx)
    R = (_sub(mhx, hy), _sub(hx, hy), _add(hx, hy), _add(mhx, hy))
    V = (_add(center, R[0]), _add(center, R[1]), _add(center, R[2]), _add(center, R[3]))
    front = _dot(_sub(p, center), e_n) > 0.0
    return _polygon_core(p, _unit(nrm)[0], V, R, center, _cross(hx, hy), True, front, far_ratio, kappa_max)


# ----------------------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------------------
@_jit
def sphere_F(p, nrm, center, radius):
    """Projected solid angle G [sr] of an outward-emitting sphere seen from one point.

    p, nrm, center: 3-tuples (world units; nrm normalised here, zero gives 0); radius: float.
    Points on or inside the sphere, and radius ≤ 0, give 0.

    Derivation (exact). Let d = |c − p|, sin σ = r/d (cone half-angle), cos θ = nrm·(c−p)/d.
    By Stokes, ∫_R ω dω = ½∮_{∂R} ω × dω. Parametrise the cone's rim as
    ω(φ) = cos σ a + sin σ (cos φ e1 + sin φ e2) with nrm = cos θ a + sin θ e1; then
    ½ nrm·(ω × dω) = ½ sin σ (sin σ cos θ − cos σ sin θ cos φ) dφ. The rim is above the horizon
    for |φ| ≤ φ0, cos φ0 = −cot θ cot σ; the region is closed by a great-circle horizon arc whose
    flux is half its angle, α/2 = asin(sin σ sin φ0). Hence

        G = φ0 sin²σ cos θ − sin σ cos σ sin θ sin φ0 + asin(sin σ sin φ0),

    (= π sin²σ cos θ when φ0 = π). Snyder's form with atan(s/x) is the same number, since
    asin(sin σ sin φ0) = atan(tan σ sin θ sin φ0). With z = nrm·(c − p), a = √((r−z)(r+z)),
    b = √((d−r)(d+r)) (so sin²σ − cos²θ = a²/d², cos σ = b/d) this becomes

        β = atan2(a, b) = asin(sin σ sin φ0),  tan β = a/b,  φ0 = atan2(a d, −z b),
        G = (r/d)²·(φ0 z/d + tan β) + (β − tan β)            (small β: series for β − tan β)
          = (r/d)²·φ0 z/d + β − a b/d²                         (otherwise; finite as d → r)

    which has no cancellation for tiny σ (every term is O(σ³)) and uses r²/d² directly.
    """
    n, nlen = _unit(nrm)
    r = radius
    D = _sub(center, p)
    d = math.sqrt(_dot(D, D))
    z = _dot(n, D)
    if not (r > 0.0 and d > r and nlen > 0.0):
        return 0.0
    s = r / d
    s2 = s * s                                         # sin²σ without 1 − cos²
    cz = z / d                                         # cos θ
    if z >= r:
        return max(_PI * s2 * cz, 0.0)
    if not abs(z) < r:
        return 0.0
    a = math.sqrt(max((r - z) * (r + z), 0.0))
    b = math.sqrt(max((d - r) * (d + r), 0.0))
    phi0 = math.atan2(a * d, -z * b)
    beta = math.atan2(a, b)
    if beta < 0.05:
        tanb = a / (b if b > 0.0 else 1.0)
        b2 = beta * beta
        # β − tan β = −(β³/3 + 2β⁵/15 + 17β⁷/315 + 62β⁹/2835 + 1382β¹¹/155925 + ...)
        series = -beta * b2 * (1.0 / 3.0 + b2 * (2.0 / 15.0 + b2 * (17.0 / 315.0 + b2 * (
            62.0 / 2835.0 + b2 * (1382.0 / 155925.0)))))
        g = s2 * (phi0 * cz + tanb) + series
    else:
        g = s2 * phi0 * cz + beta - a * b / (d * d)
    return max(g, 0.0)


@_jit
def distant_F(nrm, axis, theta_max):
    """Projected solid angle G [sr] of a DistantLight's cone: the directions within theta_max
    of the unit axis (towards the light), horizon-clipped about nrm (3-tuples; nrm normalised
    here). The cone is what a sphere of radius sin θmax at unit distance subtends, so this is
    sphere_F of that sphere; the point itself does not matter. theta_max outside (0, π/2)
    gives 0 (a delta light has no cone, a wider one no such sphere: irradiance.py's rule)."""
    if not (theta_max > 0.0 and theta_max < 0.5 * _PI):
        return 0.0
    return sphere_F((0.0, 0.0, 0.0), nrm, axis, math.sin(theta_max))


# ----------------------------------------------------------------------------------------
# disk
# ----------------------------------------------------------------------------------------
@_jit
def _disk_D(psi, A_mB, kappa):
    """D(ψ)/B, where D = F − ψ, F the continuous antiderivative with ∫ dψ/(A − B cos ψ) =
    F(ψ)/√((A−B)(A+B)), i.e. tan(F/2) = κ tan(ψ/2), κ = √((A+B)/(A−B)).

    D = 2 atan2((κ−1) sin(ψ/2)cos(ψ/2), cos²(ψ/2) + κ sin²(ψ/2)) is 2π-periodic and smooth;
    dividing by B uses κ − 1 = 2B/((A−B)(κ+1)), so B → 0 is fine.
    """
    sh = math.sin(0.5 * psi)
    ch = math.cos(0.5 * psi)
    den = ch * ch + kappa * sh * sh
    q = 2.0 * sh * ch / (A_mB * (kappa + 1.0) * den)   # ((κ−1)/B)·sh·ch/den
    B_t = (kappa - 1.0) * sh * ch / den                  # = B·q, the atan argument
    return 2.0 * _atanc(B_t) * q


@_jit
def _disk_E(psi, P, R, h, kappa, mu):
    """E(ψ) = D_0(ψ) − D_h(ψ) (the h = 0 minus the h > 0 correction), mu = |P − R| > 0 or = 0.

    = 2 atan2((κ0 − κh) sc, c² + κ0 κh s²), scaled by μ so κ0 = (P+R)/μ never appears:
    (κ0 − κh) μ = 4PRh² / ((μ² + h²)((P+R) + κh μ)).
    """
    sh = math.sin(0.5 * psi)
    ch = math.cos(0.5 * psi)
    k = 4.0 * P * R * h * h / ((mu * mu + h * h) * ((P + R) + kappa * mu))
    return 2.0 * math.atan2(k * sh * ch, mu * ch * ch + (P + R) * kappa * sh * sh)


@_jit
def _near_disk(P, rho_c, R, h, c, m, mm, full, sa0, alpha0):
    """Closed-form G for a horizon-clipped disk (in-plane quantities relative to the foot q:
    P = |ρ_c|, m the in-plane part of nrm, mm = |m|; the kept rim is |α| ≤ α0 about m̂, sa0 =
    sin α0, full: not clipped). Returns (G, sum of |terms|)."""
    # A − B, A = P² + R² + h², B = 2PR (> 0 as h > 0; the floor only guards underflow of h²)
    A_mB = max((P - R) * (P - R) + h * h, _TINY)
    A_pB = (P + R) * (P + R) + h * h
    A = 0.5 * (A_mB + A_pB)
    B = 2.0 * P * R
    Y = math.sqrt(A_mB * A_pB)
    kappa = math.sqrt(A_pB / A_mB)
    # frame: û towards the disk centre from q, v̂ = rot90(û); ψ = 0 at the rim point nearest q
    ux, uy = (rho_c[0] / P, rho_c[1] / P) if P > 0.0 else (1.0, 0.0)
    mms = mm if mm > 0.0 else 1.0
    mx, my = (m[0] / mms, m[1] / mms) if mm > 0.0 else (1.0, 0.0)
    cos_g = mx * ux + my * uy
    sin_g = -mx * uy + my * ux                          # m̂·v̂ with v̂ = (−uy, ux)
    gamma = math.atan2(sin_g, cos_g)
    m_u = m[0] * ux + m[1] * uy
    m_v = -m[0] * uy + m[1] * ux
    psi1 = gamma - _PI - alpha0
    psi2 = gamma - _PI + alpha0
    dpsi = 2.0 * alpha0
    dDq = 0.0 if full else _disk_D(psi2, A_mB, kappa) - _disk_D(psi1, A_mB, kappa)
    dD = B * dDq
    C = (dpsi * B / (A + Y) + A * dDq) / Y            # ∫ cos ψ /(A − B cos ψ)
    K = 0.0                                            # ∫ sin ψ/(A − B cos ψ)
    if not full:
        cdiff = -2.0 * sin_g * sa0                     # cos ψ1 − cos ψ2
        s1 = math.sin(0.5 * psi1)
        den1 = A_mB + 2.0 * B * s1 * s1                # A − B cos ψ1
        xk = max(B * cdiff / den1, -1.0 + 1e-16)       # > −1 exactly; guard rounding
        K = _log1pc(xk) * cdiff / den1
    lin = 0.5 * R * h * (m_u * C + m_v * K)
    # radial arc flux (c/2)·R·Ir, R·Ir = [(1 − ρh) Δψ − ρh ΔD]/2, ρh = X/Y, X = P² + h² − R²
    X = (P - R) * (P + R) + h * h
    YpX = Y + abs(X)                                   # Y ± X without cancellation (Y ≥ |X|)
    q4 = 4.0 * h * h * R * R / (Y * YpX)              # = 1 − |ρh|, since Y² − X² = 4h²R²
    rho_h = X / Y
    one_m_rho = q4 if X > 0.0 else YpX / Y
    # horizon chord (clipped rows): from the arc end (α0) back to its start (−α0), outward −m̂,
    # at distance c h/|m| from q (bounded by P + R since |zc| < R|m|)
    delta = 0.0 if full else c * h / mms
    margin = P - R if full else max(P - R, -delta)
    # radial part: plain, or for grazing points with q clearly outside, the difference form
    diff_form = _use_difference_form(margin, h)
    c_lin = c_rad = 0.0
    if not full:
        perp_rho = -my * rho_c[0] + mx * rho_c[1]      # m̂⊥·ρ_c
        c_lin, c_rad = _edge_terms(delta, -perp_rho - R * sa0, 2.0 * R * sa0, h, c, -mm, diff_form)
    mag_lin = 0.5 * R * h * (abs(m_u * C) + abs(m_v * K)) + abs(c_lin)
    if not diff_form:
        g = lin + c_lin + (0.5 * c * 0.5 * (one_m_rho * dpsi - rho_h * dD) + c_rad)
        return g, mag_lin + 0.25 * abs(c) * (abs(one_m_rho * dpsi) + abs(rho_h * dD)) + abs(c_rad)
    # ... minus its h = 0 value: [(ρ0 − ρh)(Δψ + ΔD) + ρ0 ΔE]/2, ρ0 = sign(P − R)
    rho0 = _sign(P - R)
    if P > R:
        r0_m_rh = q4
    elif P == R:
        r0_m_rh = -rho_h
    elif X < 0.0:
        r0_m_rh = -q4
    else:
        r0_m_rh = -1.0 - rho_h
    mu = abs(P - R)
    dE = 0.0 if full else _disk_E(psi2, P, R, h, kappa, mu) - _disk_E(psi1, P, R, h, kappa, mu)
    g = lin + c_lin + (0.5 * c * 0.5 * (r0_m_rh * (dpsi + dD) + rho0 * dE) + c_rad)
    return g, mag_lin + 0.25 * abs(c) * (abs(r0_m_rh * (dpsi + dD)) + abs(dE)) + abs(c_rad)


@_jit
def _far_ellipse(T00, T01, T10, T11, D2, rho_c, zc, m, h, order):
    """Area-quadrature G over the clipped ellipse {c + T ξ : |ξ| ≤ 1, zc + m·Tξ ≥ 0}.

    T = [[T00, T01], [T10, T11]]: in-plane semi-axis matrix (columns = semi-axes in the
    (t1, t2) frame; R·I for a disk); D2 = |c − p|²; rho_c: centre relative to the foot q;
    zc = nrm·(c − p); m: in-plane part of nrm; h: height. In the unit disk,
    ξ = cos φ m̂' + y m̂'⊥ with m' = Tᵀm, φ ∈ [0, α0], |y| ≤ sin φ (smooth in φ and y; the
    sin²φ factor needs ≥ 16 nodes in φ): Gauss-Legendre of order max(order, 16) in φ and
    order in y.
    """
    po = max(order, _DISK_PHI_ORDER)
    mp0 = T00 * m[0] + T10 * m[1]                      # Tᵀ m
    mp1 = T01 * m[0] + T11 * m[1]
    mm = math.hypot(mp0, mp1)
    if zc >= mm:
        alpha0 = _PI
    elif zc > -mm:
        sa0 = math.sqrt(max((mm - zc) * (mm + zc), 0.0)) / mm
        alpha0 = math.atan2(sa0, -zc / mm)
    else:
        return 0.0
    mx, my = (mp0 / mm, mp1 / mm) if mm > 0.0 else (1.0, 0.0)
    tot = 0.0
    for a in range(po):
        phi = alpha0 * _GL_X01[po, a]
        wphi = alpha0 * _GL_W01[po, a]
        x = math.cos(phi)
        ys = math.sin(phi)
        num = max(zc + mm * x, 0.0)
        wa = ys * wphi                                 # dA = |det T| · (sin φ dφ)·dy
        for b in range(order):
            y = ys * _GL_X[order, b]
            wy = ys * _GL_W[order, b]
            xi0 = x * mx - y * my                      # ξ in the unit disk
            xi1 = x * my + y * mx
            sx = T00 * xi0 + T01 * xi1                 # σ = T ξ
            sy = T10 * xi0 + T11 * xi1
            den = D2 + 2.0 * (sx * rho_c[0] + sy * rho_c[1]) + sx * sx + sy * sy
            tot += num / (den * den) * wy * wa
    return h * abs(T00 * T11 - T01 * T10) * tot


@_jit
def disk_F(p, nrm, center, e_n, radius, far_ratio=FAR_RATIO, kappa_max=KAPPA_MAX):
    """Projected solid angle G [sr] of a one-sided circular disk light from one point.

    p, nrm, center, e_n: 3-tuples in world units (nrm and the emitting normal e_n are
    normalised here); radius: float. p sees the disk iff (p − center)·e_n > 0.
    Exact closed form (elementary functions, see the module docstring); Gauss-Legendre over
    the clipped disk where that cancels (far or sliver), as for polygons.
    far_ratio, kappa_max: the switches to area quadrature (module FAR_RATIO, KAPPA_MAX).
    """
    nrm = _unit(nrm)[0]
    N = _unit(e_n)[0]
    R = radius
    D = _sub(center, p)
    h = -_dot(N, D)                                    # height of p on the emitting side
    if not (h > 0.0 and R > 0.0):
        return 0.0
    t1, t2 = frame_row(N)
    rho_c = (_dot(D, t1), _dot(D, t2))                 # disk centre relative to the foot q
    P = math.hypot(rho_c[0], rho_c[1])
    m = (_dot(nrm, t1), _dot(nrm, t2))
    mm = math.hypot(m[0], m[1])
    c = -_dot(nrm, N)
    zc = _dot(nrm, D)                                  # nrm·(centre − p)
    Rm = R * mm
    full = zc >= Rm
    if not (full or (zc < Rm and zc > -Rm)):
        return 0.0
    # clipped rim: σ = R(cos α m̂ + sin α m̂⊥), kept for |α| ≤ α0, cos α0 = −zc/(R|m|)
    sa0 = 0.0
    alpha0 = _PI
    if not full:
        sa0 = math.sqrt(max((Rm - zc) * (Rm + zc), 0.0)) / Rm
        alpha0 = math.atan2(sa0, -zc / Rm)
    D2 = _dot(D, D)
    dc = math.sqrt(D2)
    rq = R / (dc - R) if dc > R else np.inf
    quad = 2.0 * R < far_ratio * dc
    res = 0.0
    if not quad:
        res, mag = _near_disk(P, rho_c, R, h, c, m, mm, full, sa0, alpha0)
        quad = mag > kappa_max * abs(res) and rq <= QUAD_MAX_R
    if quad:
        res = _far_ellipse(R, 0.0, 0.0, R, D2, rho_c, zc, m, h, _quad_order(rq))
    return max(res, 0.0)


# ----------------------------------------------------------------------------------------
# ellipse (a disk under non-uniform scale or shear)
# ----------------------------------------------------------------------------------------
@_jit
def _repulsion(zi, zj, other):
    """1/(zi − zj) for another, distinct root estimate zj, else 0."""
    d = zi - zj
    return 1.0 / d if other and d != 0.0 else 0j


@_jit
def _log_abs(b):
    """log|b| (−inf for 0)."""
    a = abs(b)
    return math.log(a) if a > 0.0 else -np.inf


@_jit
def _on_newton_polygon(y, k):
    """Is (k, y[k]) a vertex of the upper convex hull of the points (j, y[j]), j = 0..4 (y[j] =
    log|coefficient of z^j|; the ends are always vertices, collinear points are not)?"""
    if k == 0 or k == 4:
        return True
    if not y[k] > -np.inf:
        return False
    for i in range(k):
        for j in range(k + 1, 5):
            if y[i] > -np.inf and y[j] > -np.inf and y[k] <= y[i] + (y[j] - y[i]) * (k - i) / (j - i):
                return False
    return True


@_jit
def _aberth_seed(y, q):
    """Starting point q (0..3) of the Aberth iteration for a monic quartic with log|coefficients|
    y (Bini's choice): each edge of the Newton polygon from vertex x1 to x2 puts x2 − x1 points
    on the circle of radius exp((y[x1] − y[x2])/(x2 − x1)) (where that many roots lie, roughly),
    spread in angle and offset from the other circles'."""
    x1 = q
    while not _on_newton_polygon(y, x1):
        x1 -= 1
    x2 = q + 1
    while not _on_newton_polygon(y, x2):
        x2 += 1
    r = math.exp((y[x1] - y[x2]) / (x2 - x1))
    ang = _TWO_PI * (q - x1) / (x2 - x1) + 0.5 * _PI * x1 + 0.4
    return complex(r * math.cos(ang), r * math.sin(ang))


@_jit
def _quartic_roots(c4, c3, c2, c1, c0):
    """The four complex roots of c4 z⁴ + c3 z³ + c2 z² + c1 z + c0 (c4 ≠ 0) by the Aberth-Ehrlich
    iteration (simultaneous Newton with repulsion; cubic convergence to simple roots), seeded on
    the circles of the Newton polygon (_aberth_seed: ~6 sweeps instead of ~25 from one circle).
    A root estimate is final once |p(z)| is at the rounding level of its evaluation,
    8ε·Σ|b_k||z|^k (a backward-error test, so near-double roots stop at their attainable ~√ε
    instead of iterating on rounding noise), which is all the callers need; at most 64 sweeps."""
    b3, b2, b1, b0 = c3 / c4, c2 / c4, c1 / c4, c0 / c4
    y = (_log_abs(b0), _log_abs(b1), _log_abs(b2), _log_abs(b3), 0.0)
    z0 = _aberth_seed(y, 0)
    z1 = _aberth_seed(y, 1)
    z2 = _aberth_seed(y, 2)
    z3 = _aberth_seed(y, 3)
    a3, a2, a1, a0 = abs(b3), abs(b2), abs(b1), abs(b0)
    for _ in range(64):
        done = True
        for i in range(4):
            zi = z0 if i == 0 else (z1 if i == 1 else (z2 if i == 2 else z3))
            pz = (((zi + b3) * zi + b2) * zi + b1) * zi + b0
            az = abs(zi)
            if abs(pz) <= 8.0 * _EPS * ((((az + a3) * az + a2) * az + a1) * az + a0):
                continue
            done = False
            dp = ((4.0 * zi + 3.0 * b3) * zi + 2.0 * b2) * zi + b1
            rep = _repulsion(zi, z0, i != 0) + _repulsion(zi, z1, i != 1) + _repulsion(zi, z2, i != 2) \
                + _repulsion(zi, z3, i != 3)
            ratio = pz / dp if dp != 0.0 else 1e-3 * (1.0 + az) + 0j
            zi = zi - ratio / (1.0 - ratio * rep)
            if i == 0:
                z0 = zi
            elif i == 1:
                z1 = zi
            elif i == 2:
                z2 = zi
            else:
                z3 = zi
        if done:
            break
    return z0, z1, z2, z3


@_jit
def _pole(z):
    """(Re t, |Im t|) of t = arg z − i ln|z| ((0, π), i.e. no breakpoints, if the root
    iteration failed)."""
    if not (math.isfinite(z.real) and math.isfinite(z.imag)):
        return 0.0, _PI
    return math.atan2(z.imag, z.real), abs(math.log(max(abs(z), 1e-300)))


@_jit
def _ellipse_poles(rho_c, A1, A2, h):
    """Complex zeros of |ρ(t)|² + h², ρ = ρ_c + A1 cos t + A2 sin t, as two 4-tuples (Re t,
    |Im t|). With z = e^{it}: z²(|ρ|² + h²) = c4 z⁴ + c3 z³ + c2 z² + c1 z + c0 where
    c4 = (k3 − i k4)/2, c3 = (k1 − i k2)/2, c2 = k0, c1 = conj(c3), c0 = conj(c4) for
    |ρ|² + h² = k0 + k1 cos t + k2 sin t + k3 cos 2t + k4 sin 2t; t = arg z − i ln|z|. A
    (near-)circle drops to the quadratic c3 z² + c2 z + c1 (its two other roots are at z ≈ 0,
    ∞: reported at distance π). Used only to place quadrature breakpoints (near-double roots
    are accurate to ~√ε)."""
    a11 = A1[0] * A1[0] + A1[1] * A1[1]
    a22 = A2[0] * A2[0] + A2[1] * A2[1]
    a12 = A1[0] * A2[0] + A1[1] * A2[1]
    k0 = rho_c[0] * rho_c[0] + rho_c[1] * rho_c[1] + 0.5 * (a11 + a22) + h * h
    k1 = 2.0 * (rho_c[0] * A1[0] + rho_c[1] * A1[1])
    k2 = 2.0 * (rho_c[0] * A2[0] + rho_c[1] * A2[1])
    k3 = 0.5 * (a11 - a22)
    k4 = a12
    c4 = complex(0.5 * k3, -0.5 * k4)
    c3 = complex(0.5 * k1, -0.5 * k2)
    c2 = complex(k0, 0.0)
    c1 = c3.conjugate()
    c0 = c4.conjugate()
    if abs(c4) > 1e-8 * (abs(c3) + abs(c2)):
        z0, z1, z2, z3 = _quartic_roots(c4, c3, c2, c1, c0)
        r0, i0 = _pole(z0)
        r1, i1 = _pole(z1)
        r2, i2 = _pole(z2)
        r3, i3 = _pole(z3)
        return (r0, r1, r2, r3), (i0, i1, i2, i3)
    if not abs(c3) > 0.0:                              # circle centred on q: no preferred t
        return (0.0, 0.0, 0.0, 0.0), (_PI, _PI, _PI, _PI)
    disc = (c2 * c2 - 4.0 * c3 * c1) ** 0.5
    if (c2.conjugate() * disc).real >= 0.0:
        disc = -disc
    r, i = _pole((-c2 + disc) / (2.0 * c3))
    return (r, r, 0.0, 0.0), (i, i, _PI, _PI)


@_jit
def _ell_point(rho_c, A1, A2, t):
    """(ρ(t), ρ'(t)) of the ellipse ρ = ρ_c + A1 cos t + A2 sin t."""
    ct = math.cos(t)
    st = math.sin(t)
    return ((rho_c[0] + ct * A1[0] + st * A2[0], rho_c[1] + ct * A1[1] + st * A2[1]),
            (-st * A1[0] + ct * A2[0], -st * A1[1] + ct * A2[1]))


@_jit
def _next_graded(t, tc, w, J):
    """Smallest point > t of the breakpoints {tc} ∪ {tc ± w·2^j : 0 ≤ j ≤ J} graded
    geometrically about tc (inf if none)."""
    if t < tc:
        # left points tc − w·2^j decrease with j: the largest j whose point is still > t
        if tc - w * 2.0 ** J > t:
            return tc - w * 2.0 ** J
        j = int(min(max(math.floor(math.log2((tc - t) / w)), -1.0), float(J)))
        while j >= 0 and not tc - w * 2.0 ** j > t:
            j -= 1
        while j < J and tc - w * 2.0 ** (j + 1) > t:
            j += 1
        return tc - w * 2.0 ** j if j >= 0 else tc
    # right points tc + w·2^j increase with j: the smallest j whose point is > t
    if not tc + w * 2.0 ** J > t:
        return np.inf
    x = (t - tc) / w
    j = int(min(max(math.ceil(math.log2(x)), 0.0), float(J))) if x > 0.0 else 0
    while j > 0 and tc + w * 2.0 ** (j - 1) > t:
        j -= 1
    while not tc + w * 2.0 ** j > t:
        j += 1
    return tc + w * 2.0 ** j


@_jit
def _near_ellipse(rho_c, A1, A2, h, c, m, zc):
    """Near-field G of a horizon-clipped ellipse {ρ_c + A1 cos t + A2 sin t} (in-plane, relative
    to the foot q; det[A1 A2] > 0) by the same Green's-theorem fluxes as the disk, with the arc
    integral evaluated by Gauss-Legendre (12 nodes per panel) on panels graded geometrically
    towards the integrand's complex poles (see below), so that a point close to the rim keeps
    ~1e-13. The horizon chord is a straight edge (_edge_terms). Returns (G, |terms|)."""
    det = A1[0] * A2[1] - A1[1] * A2[0]
    mA1 = m[0] * A1[0] + m[1] * A1[1]
    mA2 = m[0] * A2[0] + m[1] * A2[1]
    mu = math.hypot(mA1, mA2)
    full = zc >= mu
    alpha0 = _PI
    if not full:
        sa0 = math.sqrt(max((mu - zc) * (mu + zc), 0.0)) / mu
        alpha0 = math.atan2(sa0, -zc / mu)
    t_m = math.atan2(mA2, mA1)
    # Quadrature breakpoints: the integrand's only singularities are the complex zeros of
    # |ρ(t)|² + h² (four; two near the real axis for each flank of a thin ellipse that is
    # close to q). Grade geometrically towards each zero's real part from half its distance to
    # the real axis. Zeros very close to the axis (p near the rim) are near-double and only
    # good to ~√ε, so the rim point nearest to q is also refined by Newton on ρ·ρ' = 0 and
    # graded from √(|ρ|² + h²)/|ρ'| there.
    pre, pim = _ellipse_poles(rho_c, A1, A2, h)
    # one zero per conjugate pair (the pairs z, 1/z̄ share their real part): the two nearest the
    # real axis that belong to different pairs (farthest apart in argument)
    k0 = 0
    for k in range(1, 4):
        if pim[k] < pim[k0]:
            k0 = k
    a0 = pre[k0]
    k1 = 0
    best = -1.0
    for k in range(4):
        dk = pre[k] - a0
        sep = abs(math.atan2(math.sin(dk), math.cos(dk)))
        if sep > best:
            best = sep
            k1 = k
    w0 = min(max(0.5 * pim[k0], 1e-300), _PI / 8.0)
    w1 = min(max(0.5 * pim[k1], 1e-300), _PI / 8.0)
    ts = a0
    for _ in range(8):
        q0, q1 = _ell_point(rho_c, A1, A2, ts)
        q2x, q2y = q0[0] - rho_c[0], q0[1] - rho_c[1]    # ρ'' = −(A1 cos t + A2 sin t)
        g1 = q1[0] * q1[0] + q1[1] * q1[1] - (q0[0] * q2x + q0[1] * q2y)
        if g1 > 0.0:
            step = -(q0[0] * q1[0] + q0[1] * q1[1]) / g1
            ts = ts + min(max(step, -_NEWTON_STEP), _NEWTON_STEP)
    q0, q1 = _ell_point(rho_c, A1, A2, ts)
    dmin2 = q0[0] * q0[0] + q0[1] * q0[1]
    # (caps: ≥ 16 panels per turn even for a smooth integrand, so 12 nodes give ~1e-15)
    w2 = min(max(math.sqrt(dmin2 + h * h) / max(math.sqrt(q1[0] * q1[0] + q1[1] * q1[1]), 1e-300),
                 1e-300), _PI / 8.0)
    # arc parameter range; each centre graded at its periodic copies next to the range (the
    # arc can reach the copy of a pole from either end)
    lo = a0 - _PI if full else t_m - alpha0
    hi = a0 + _PI if full else t_m + alpha0
    mid = 0.5 * (lo + hi)
    cs = (a0 + _TWO_PI * np.rint((mid - a0) / _TWO_PI), pre[k1] + _TWO_PI * np.rint((mid - pre[k1]) / _TWO_PI),
          ts + _TWO_PI * np.rint((mid - ts) / _TWO_PI))
    ws = (w0, w1, w2)
    J = int(min(max(math.ceil(math.log2(_TWO_PI / min(w0, w1, w2))) + 1.0, 1.0), 1100.0))
    # chord from the arc's end back to its start: a straight edge on the horizon line
    # m·ρ + h c = 0, so (as for the disk) its outward normal is −m̂, its direction −m̂⊥ and
    # its distance from q exactly c h/|m| (not recomputed from the end points, whose
    # rounding would swamp a tiny h)
    mm = math.hypot(m[0], m[1])
    mms = mm if mm > 0.0 else 1.0
    delta = c * h / mms
    # radial part: plain, or (q outside the ellipse, or cut off by the chord: margin as for the
    # disk) the difference form
    xi = (-rho_c[0] * A2[1] + rho_c[1] * A2[0]) / det
    eta = (-A1[0] * rho_c[1] + A1[1] * rho_c[0]) / det
    margin = math.sqrt(dmin2) if xi * xi + eta * eta > 1.0 else -np.inf
    if not full:
        margin = max(margin, -delta)
    diff_form = _use_difference_form(margin, h)
    arc_lin = arc_rad = mag_lin = mag_rad = 0.0
    hh = h * h
    a = lo
    while a < hi:
        b = hi
        for kc in range(3):
            for shift in (-_TWO_PI, 0.0, _TWO_PI):
                b = min(b, _next_graded(a, cs[kc] + shift, ws[kc], J))
        for kn in range(_ARC_ORDER):
            t = a + (b - a) * _GL_X01[_ARC_ORDER, kn]
            w = (b - a) * _GL_W01[_ARC_ORDER, kn]
            R_, dR = _ell_point(rho_c, A1, A2, t)
            r2 = R_[0] * R_[0] + R_[1] * R_[1]
            d2 = r2 + hh
            cr = R_[0] * dR[1] - R_[1] * dR[0]         # ρ × ρ'
            lin = -0.5 * h * (m[0] * dR[1] - m[1] * dR[0]) / d2
            if diff_form:
                rad = -0.5 * c * cr * hh / ((r2 if r2 > 0.0 else 1.0) * d2)
            else:
                rad = 0.5 * c * cr / d2
            arc_lin += lin * w
            arc_rad += rad * w
            mag_lin += abs(lin) * w
            mag_rad += abs(rad) * w
        a = b
    c_lin = c_rad = 0.0
    if not full:
        pa = _ell_point(rho_c, A1, A2, hi)[0]
        pb = _ell_point(rho_c, A1, A2, lo)[0]
        L = math.hypot(pb[0] - pa[0], pb[1] - pa[1])
        sa = -(-(m[1] / mms) * pa[0] + (m[0] / mms) * pa[1])   # pa·(−m̂⊥)
        c_lin, c_rad = _edge_terms(delta, sa, L, h, c, -mm, diff_form)
    return arc_lin + c_lin + (arc_rad + c_rad), mag_lin + abs(c_lin) + (mag_rad + abs(c_rad))


@_jit
def ellipse_F(p, nrm, center, e1, e2, e_n, far_ratio=FAR_RATIO, kappa_max=KAPPA_MAX):
    """Projected solid angle G [sr] of a one-sided elliptical light from one point.

    The light is {center + x·e1 + y·e2 : x² + y² ≤ 1}: e1, e2 are two conjugate semi-diameters
    spanning the ellipse's plane (e.g. its principal semi-axes, as ``renderer.lights.disk``
    stores them; any non-parallel pair works). All arguments are 3-tuples in world units:
    shading point p, its normal nrm and the emitting normal e_n (both normalised here; p sees
    the light iff (p − center)·e_n > 0).

    Not a closed form: the disk's Green's-theorem formulation with the arc flux integrated by
    Gauss-Legendre on panels graded from the rim point nearest to p's foot (relative error
    ~1e-13 in tests, also within 1e-10 of the rim), the chord and the grazing difference form
    exactly as for the disk; area quadrature (through the affine map of the unit disk) for
    small/far ellipses and slivers. far_ratio, kappa_max: as for disk_F.
    """
    nrm, nlen = _unit(nrm)
    N = _unit(e_n)[0]
    D = _sub(center, p)
    h = -_dot(N, D)
    cr = _cross(e1, e2)
    if not (h > 0.0 and _dot(cr, cr) > 0.0 and nlen > 0.0):
        return 0.0
    t1, t2 = frame_row(N)
    A1 = (_dot(e1, t1), _dot(e1, t2))
    A2 = (_dot(e2, t1), _dot(e2, t2))
    if A1[0] * A2[1] - A1[1] * A2[0] < 0.0:           # counter-clockwise parameter
        A2 = (-A2[0], -A2[1])
    rho_c = (_dot(D, t1), _dot(D, t2))
    m = (_dot(nrm, t1), _dot(nrm, t2))
    c = -_dot(nrm, N)
    zc = _dot(nrm, D)
    mu = math.hypot(m[0] * A1[0] + m[1] * A1[1], m[0] * A2[0] + m[1] * A2[1])
    if not zc > -mu:
        return 0.0
    D2 = _dot(D, D)
    dc = math.sqrt(D2)
    half = math.sqrt(max(_dot(e1, e1), _dot(e2, e2)))
    rq = half / (dc - half) if dc > half else np.inf
    quad = 2.0 * half < far_ratio * dc
    res = 0.0
    if not quad:
        res, mag = _near_ellipse(rho_c, A1, A2, h, c, m, zc)
        quad = mag > kappa_max * abs(res) and rq <= QUAD_MAX_R
    if quad:
        res = _far_ellipse(A1[0], A2[0], A1[1], A2[1], D2, rho_c, zc, m, h, _quad_order(rq))
    return max(res, 0.0)


# ----------------------------------------------------------------------------------------
# dome
# ----------------------------------------------------------------------------------------
@_jit
def dome_constant_F():
    """∫_{hemisphere} cos θ dω = π [sr]: the projected solid angle of a constant dome (the
    textured dome's cosine convolution is precomputed elsewhere, renderer/preconvolve.py)."""
    return _PI


# ----------------------------------------------------------------------------------------
# compiled loops over rows, and the numpy API
# ----------------------------------------------------------------------------------------
@_jit
def _rect_rows(p, nrm, center, ex, ey, e_n, far_ratio, kappa_max, out):
    for i in range(p.shape[0]):
        out[i] = rect_F(_row(p, i), _row(nrm, i), _row(center, i), _row(ex, i), _row(ey, i),
                        _row(e_n, i), far_ratio, kappa_max)


@_jit
def _polygon_rows(p, nrm, verts, e_n, one_sided, far_ratio, kappa_max, out):
    for i in range(p.shape[0]):
        out[i] = polygon_F(_row(p, i), _row(nrm, i), verts[i], _row(e_n, i), one_sided, far_ratio, kappa_max)


@_jit
def _sphere_rows(p, nrm, center, radius, out):
    for i in range(p.shape[0]):
        out[i] = sphere_F(_row(p, i), _row(nrm, i), _row(center, i), radius[i])


@_jit
def _distant_rows(p, nrm, axis, theta_max, out):
    for i in range(p.shape[0]):
        out[i] = distant_F(_row(nrm, i), _row(axis, i), theta_max[i])


@_jit
def _disk_rows(p, nrm, center, e_n, radius, far_ratio, kappa_max, out):
    for i in range(p.shape[0]):
        out[i] = disk_F(_row(p, i), _row(nrm, i), _row(center, i), _row(e_n, i), radius[i], far_ratio,
                        kappa_max)


@_jit
def _ellipse_rows(p, nrm, center, e1, e2, e_n, far_ratio, kappa_max, out):
    for i in range(p.shape[0]):
        out[i] = ellipse_F(_row(p, i), _row(nrm, i), _row(center, i), _row(e1, i), _row(e2, i),
                           _row(e_n, i), far_ratio, kappa_max)


def _rows(a, n: int, width: int | tuple | None = 3) -> np.ndarray:
    """Broadcast an input to n rows: (width,) / (n, width) -> (n, width); scalar / (n,) -> (n,)
    for width None; a tuple width is a row's whole shape (a polygon's (k, 3) vertices).
    Always a writable C-contiguous float64 array (a read-only one, e.g. a broadcast view, would
    be another numba type: another compilation of the loop)."""
    shape = (n,) + (() if width is None else (width,) if isinstance(width, int) else tuple(width))
    a = np.asarray(a, dtype=np.float64)
    return _c_rows(a if a.shape == shape else np.broadcast_to(a, shape))


def _c_rows(a: np.ndarray) -> np.ndarray:
    """a itself if it is a writable C-contiguous float64 array, else a copy that is."""
    if a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=np.float64, order="C")


def _points(p) -> np.ndarray:
    return _c_rows(np.asarray(p, dtype=np.float64).reshape(-1, 3))


def _over_rows(loop, p, params, *switches) -> np.ndarray:
    """G (n,) from a compiled row loop: loop(p, *params broadcast to p's n rows, *switches, out).
    params: (value, width) pairs, width 3 for vectors, None for scalars per row."""
    p = _points(p)
    n = p.shape[0]
    out = np.zeros(n)
    loop(p, *[_rows(a, n, w) for a, w in params], *switches, out)
    return out


def projected_solid_angle_polygon(p, nrm, verts, e_n=None) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a planar convex polygon seen from p, horizon-clipped
    (polygon_F per row).

    p: (n, 3) shading points; nrm: (n, 3) unit normals at p.
    verts: (n, k, 3) or (k, 3) world-space corners of a convex planar polygon, in order (either
        winding); k ≥ 3. A (numerically) degenerate polygon gives 0.
    e_n: optional (n, 3) or (3,) emitting normal. If given the polygon is one-sided: rows with
        dot(p − centroid, e_n) ≤ 0 give 0. If None the polygon is two-sided (seen from either
        side). A point in the polygon's plane gives 0 in both cases.
    """
    verts = np.asarray(verts, dtype=np.float64)
    return _over_rows(_polygon_rows, p, ((nrm, 3), (verts, verts.shape[-2:]), (0.0 if e_n is None else e_n, 3)),
                      e_n is not None, float(FAR_RATIO), float(KAPPA_MAX))


def projected_solid_angle_rect(p, nrm, center, ex, ey, e_n) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided rectangle/parallelogram light (rect_F per
    row).

    The light is {center + a·ex + b·ey : a, b ∈ [−½, ½]}, i.e. ex, ey are the FULL edge vectors
    (the convention of ``renderer.lights.rect``; a sheared transform gives a parallelogram).
    e_n: emitting normal; p sees the light iff dot(p − center, e_n) > 0.
    center, ex, ey, e_n: (n, 3) or (3,). p, nrm: (n, 3).
    """
    return _over_rows(_rect_rows, p, ((nrm, 3), (center, 3), (ex, 3), (ey, 3), (e_n, 3)),
                      float(FAR_RATIO), float(KAPPA_MAX))


def projected_solid_angle_sphere(p, nrm, center, radius) -> np.ndarray:
    """Projected solid angle (n,) [sr] of an outward-emitting sphere seen from p (sphere_F per
    row, which has the derivation).

    p, nrm: (n, 3); center: (n, 3) or (3,); radius: (n,) or scalar (> 0).
    Points on or inside the sphere get 0.
    """
    return _over_rows(_sphere_rows, p, ((nrm, 3), (center, 3), (radius, None)))


def projected_solid_angle_distant(nrm, axis, theta_max) -> np.ndarray:
    """Projected solid angle (n,) [sr] of DistantLight cones (distant_F per row).

    nrm: (n, 3) unit normals; axis: (n, 3) or (3,) unit directions towards the light;
    theta_max: (n,) or scalar half-angles (rad), 0 outside (0, π/2).
    """
    return _over_rows(_distant_rows, nrm, ((nrm, 3), (axis, 3), (theta_max, None)))


def projected_solid_angle_disk(p, nrm, center, e_n, radius) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided circular disk light, horizon-clipped
    (disk_F per row).

    p, nrm: (n, 3); center, e_n: (n, 3) or (3,) (e_n: emitting normal, normalised here);
    radius: (n,) or scalar. p sees the disk iff dot(p − center, e_n) > 0.
    """
    return _over_rows(_disk_rows, p, ((nrm, 3), (center, 3), (e_n, 3), (radius, None)),
                      float(FAR_RATIO), float(KAPPA_MAX))


def projected_solid_angle_ellipse(p, nrm, center, e1, e2, e_n) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided elliptical light, horizon-clipped
    (ellipse_F per row).

    The light is {center + x·e1 + y·e2 : x² + y² ≤ 1}: e1, e2 (n, 3) or (3,) are two conjugate
    semi-diameters (see ellipse_F); e_n: emitting normal (normalised here); p sees the light
    iff dot(p − center, e_n) > 0.
    """
    return _over_rows(_ellipse_rows, p, ((nrm, 3), (center, 3), (e1, 3), (e2, 3), (e_n, 3)),
                      float(FAR_RATIO), float(KAPPA_MAX))


def projected_solid_angle_dome_constant() -> float:
    """∫_{hemisphere} cos θ dω = π: the projected solid angle of a constant dome (dome_constant_F)."""
    return float(dome_constant_F())


# The row functions inline frame_row from renderer/geometry.py (see renderer/kernels/__init__.py).
guard_cache(__name__, module_dispatchers(globals()), ["renderer/geometry.py"])
