"""Exact unshadowed cosine-weighted solid-angle integrals of light shapes (control-variate F).

For a shading point p (n, 3) with unit normal nrm (n, 3) every function returns

    G = ∫_{light ∩ upper hemisphere of nrm} max(0, nrm·ω) dω        (n,) in steradians,

the *projected solid angle* of the part of the light that p sees and that lies above its
horizon. A uniform emitter of radiance L gives irradiance E = L·G, and a Lambert lobe of albedo
ρ gives the control-variate integral F = (ρ/π)·L·G. Visibility (shadowing) is not included.

Conventions
-----------
* float64 throughout, batch axis first, inputs broadcast against p's rows; nothing loops over
  rows in Python (loops over polygon vertices / quadrature nodes only).
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

import numpy as np

from renderer.geometry import coordinate_frame

__all__ = [
    "FAR_RATIO",
    "FAR_ORDER",
    "projected_solid_angle_polygon",
    "projected_solid_angle_rect",
    "projected_solid_angle_sphere",
    "projected_solid_angle_disk",
    "projected_solid_angle_ellipse",
    "projected_solid_angle_dome_constant",
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

_GL_CACHE: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}


def _gl(n: int):
    """Gauss-Legendre nodes/weights of order n on [-1, 1] and on [0, 1] (cached)."""
    if n not in _GL_CACHE:
        x, w = np.polynomial.legendre.leggauss(n)
        _GL_CACHE[n] = (x, w, 0.5 * (x + 1.0), 0.5 * w)
    return _GL_CACHE[n]


def _quad_order(r: np.ndarray) -> np.ndarray:
    """Order with r^(2n) ≤ 1e-17 (r < 1), at least FAR_ORDER, at most _MAX_ORDER."""
    rr = np.clip(r, 1e-300, 0.999)
    n = np.ceil(17.0 / (-2.0 * np.log10(rr)))
    return np.clip(n, FAR_ORDER, _MAX_ORDER).astype(int)


# ----------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------
def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _rows(a, n: int, width: int | None = 3) -> np.ndarray:
    """Broadcast an input to n rows: (width,) / (n, width) -> (n, width); scalar / (n,) -> (n,)."""
    a = np.asarray(a, dtype=np.float64)
    if width is None:
        return np.broadcast_to(a, (n,)).astype(np.float64, copy=True)
    return np.broadcast_to(a, (n, width)).astype(np.float64, copy=True)


def _unit(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit rows, lengths); zero rows stay zero."""
    length = np.sqrt(_dot(a, a))
    return a / np.where(length > 0.0, length, 1.0)[..., None], length


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _atanc(t: np.ndarray) -> np.ndarray:
    """atan(t)/t, = 1 at t = 0."""
    small = np.abs(t) < 1e-8
    ts = np.where(small, 1.0, t)
    return np.where(small, 1.0 - t * t / 3.0, np.arctan(ts) / ts)


def _log1pc(x: np.ndarray) -> np.ndarray:
    """log1p(x)/x for x > -1, = 1 at x = 0."""
    small = np.abs(x) < 1e-8
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - 0.5 * x, np.log1p(xs) / xs)


def _plane_frame(N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """In-plane orthonormal axes (t1, t2) for unit normals N (n, 3); zero rows get some frame."""
    ok = _dot(N, N) > 0.0
    Ns = np.where(ok[:, None], N, np.array([0.0, 0.0, 1.0]))
    return coordinate_frame(Ns)


# ----------------------------------------------------------------------------------------
# straight edges (shared by polygons and the disk's horizon chord)
# ----------------------------------------------------------------------------------------
def _edge_terms(delta, sa, L, h, c, m_n):
    """Green's-theorem flux of one straight edge, in the in-plane frame of the foot point q.

    delta: signed distance of the edge's line from q along the outward normal n (any shape);
    sa: tangential coordinate of the edge start relative to the foot of the perpendicular from
    q (the end is sa + L); L: edge length (0 for padding edges -> contributes 0);
    h: height of p above the plane (> 0); c = -nrm·N; m_n = m·n.
    Returns (linear, radial_direct, radial_minus_h0): the h-factored linear flux
    -h (m·n) Δ/(2w), the radial flux c δ Δ/(2w), and the radial flux minus its h = 0 value
    c·sign(δ)·Δ0/2 (evaluated without cancellation; sign(δ)·Δ0 is the signed in-plane angle the
    edge subtends at q, and these sum to q's winding angle, 0 when q is outside the region).
    """
    sb = sa + L
    w = np.hypot(delta, h)
    dw = np.arctan2(w * L, w * w + sa * sb)          # angle subtended by the edge at p
    ok = L > 0.0
    lin = np.where(ok, -0.5 * h * m_n * dw / w, 0.0)
    rad = np.where(ok, 0.5 * c * delta * dw / w, 0.0)
    # Difference from h = 0:  δΔ_w/w − sign(δ)Δ_0
    #   = (δ/w − sδ)Δ_w + sδ(Δ_w − Δ_0),   δ/w − sδ = −sδ h²/(w(w+|δ|)),
    #   Δ_w − Δ_0 = T(s_b) − T(s_a),  T(s) = atan(s/w) − atan(s/|δ|) = atan2(−s h²/(w+|δ|), w|δ| + s²).
    ad = np.abs(delta)
    sd = np.sign(delta)
    h2 = h * h
    wpd = w + ad
    t1 = -sd * h2 / (w * wpd) * dw
    Tb = np.arctan2(-sb * h2 / wpd, w * ad + sb * sb)
    Ta = np.arctan2(-sa * h2 / wpd, w * ad + sa * sa)
    diff = np.where(ok, 0.5 * c * (t1 + sd * (Tb - Ta)), 0.0)
    return lin, rad, diff


def _use_difference_form(outside_margin, h):
    """Where to evaluate the radial flux as "value minus its h = 0 value" (whose edge sum, the
    winding angle of q, is exactly 0 when the foot q is outside the region).

    outside_margin: how far q is outside the region (> 0 only if it is; a lower bound of its
    in-plane distance r_q to it). With the boundary known to rounding δx ~ ε·size, the in-plane
    angles at q carry errors ~δx/r_q. The plain sum passes them straight on when h ≪ r_q
    (its terms are ±c/2 times those angles, cancelling to ~h), while the difference form's
    terms are O(h²/r_q²) and damp them; when h ≳ r_q it is the other way round (the plain terms
    are then angles seen from p itself, well conditioned). So: difference form iff h < r_q.
    """
    return (outside_margin > 0.0) & (outside_margin > h)


# ----------------------------------------------------------------------------------------
# polygons
# ----------------------------------------------------------------------------------------
def _clip_polygon(P: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland-Hodgman clip of convex 2-D polygons to the half-plane z > 0.

    P: (n, k, 2) vertices; z: (n, k) signed (linear) clip function at the vertices.
    Returns Q (n, S, 2), S = max(k+1, largest count), the kept/created vertices in order with
    the tail padded by repeating the last one (zero-length edges contribute nothing), the
    vertex count (n,), and on_line (n, S): edge j (slot j -> j+1) is the new edge along the
    clip line. A vertex on the line (z = 0) counts as outside; the crossing point of an edge
    from it is then the vertex itself, so nothing is lost.
    """
    n, k, _ = P.shape
    Pn = np.roll(P, -1, axis=1)
    zn = np.roll(z, -1, axis=1)
    ins = z > 0.0
    insn = np.roll(ins, -1, axis=1)
    cross = ins != insn
    den = np.where(cross, z - zn, 1.0)
    t = np.where(cross, z / den, 0.0)
    X = P + t[..., None] * (Pn - P)
    slots = np.stack([P, X], axis=2).reshape(n, 2 * k, 2)
    valid = np.stack([ins, cross], axis=2).reshape(n, 2 * k)
    is_x = np.stack([np.zeros_like(ins), cross], axis=2).reshape(n, 2 * k)
    count = valid.sum(axis=1)
    S = max(k + 1, int(count.max()) if n else 0)
    order = np.argsort(~valid, axis=1, kind="stable")[:, :S]
    Q = np.take_along_axis(slots, order[..., None], axis=1)
    is_x = np.take_along_axis(is_x, order, axis=1)
    last = np.maximum(count - 1, 0)
    j = np.arange(S)[None, :]
    pick = np.where(j < count[:, None], j, last[:, None])
    Q = np.take_along_axis(Q, pick[..., None], axis=1)
    is_x = np.take_along_axis(is_x, pick, axis=1)
    # edge j runs from slot j to slot j+1: it lies on the clip line iff both ends are crossings
    # (an exit followed by an entry)
    on_line = is_x & np.roll(is_x, -1, axis=1)
    return Q, count, on_line


def _near_polygon(Q, count, on_line, h, c, m, orient):
    """Closed-form (Lambert/Green) G for clipped polygons Q (r, S, 2), in-plane coordinates
    relative to the foot q of p; on_line marks the edge created along the horizon line."""
    A = Q
    E = np.roll(Q, -1, axis=1) - Q                    # edge vectors from the accurate offsets
    L = np.hypot(E[..., 0], E[..., 1])
    Ls = np.where(L > 0.0, L, 1.0)
    tx, ty = E[..., 0] / Ls, E[..., 1] / Ls
    o = orient[:, None]
    nx, ny = o * ty, -o * tx                         # outward normal (right of a CCW edge)
    delta = A[..., 0] * nx + A[..., 1] * ny
    sa = A[..., 0] * tx + A[..., 1] * ty
    m_n = m[:, None, 0] * nx + m[:, None, 1] * ny
    # the horizon edge lies on m·ρ + h c = 0: outward normal −m̂, distance c·h/|m| from q
    # exactly (recomputing it from its end points would bury a tiny h in their rounding)
    mm = np.hypot(m[:, 0], m[:, 1])[:, None]
    line = on_line & (mm > 0.0)
    delta = np.where(line, c[:, None] * h[:, None] / np.where(line, mm, 1.0), delta)
    m_n = np.where(line, -mm, m_n)
    lin, rad, diff = _edge_terms(delta, sa, L, h[:, None], c[:, None], m_n)
    # radial part: plain sum, or, for grazing points whose foot q is clearly outside the
    # clipped polygon, the difference form (its h = 0 winding term is exactly 0)
    margin = np.where(L > 0.0, -delta, -np.inf).max(axis=1)   # distance beyond the worst edge line
    use_diff = _use_difference_form(margin, h) & (count >= 3)
    radial = np.where(use_diff, diff.sum(axis=1), rad.sum(axis=1))
    g = lin.sum(axis=1) + radial
    mag = np.abs(lin).sum(axis=1) + np.where(use_diff, np.abs(diff).sum(axis=1), np.abs(rad).sum(axis=1))
    return g, mag


def _far_polygon(Q, D2, rho_o, z_o, m, h, orient, order):
    """Area-quadrature G: order×order Gauss-Legendre on the collapsed square of each fan
    triangle of the clipped polygon (coordinates relative to the centroid o; D2 = |o − p|²,
    z_o = nrm·(o − p))."""
    _, _, X, W = _gl(order)
    A = Q[:, :1, :]
    B = Q[:, 1:-1, :]
    C = Q[:, 2:, :]
    e1 = B - A
    e2 = C - B
    area2 = _cross2(e1, e2)                                        # (r, T) signed, = 2·area
    u = X[:, None]
    v = X[None, :]
    pts = (A[:, :, None, None, :] + u[..., None] * e1[:, :, None, None, :]
           + (u * v)[..., None] * e2[:, :, None, None, :])        # (r, T, g, g, 2)
    wts = (W[:, None] * W[None, :]) * u                            # collapsed-square Jacobian
    num = np.maximum(z_o[:, None, None, None] + _dot(pts, m[:, None, None, None, :]), 0.0)
    den = D2[:, None, None, None] + 2.0 * _dot(pts, rho_o[:, None, None, None, :]) + _dot(pts, pts)
    f = num / (den * den)
    tot = np.einsum("rtij,ij,rt->r", f, wts, area2)
    return orient * h * tot


def _polygon_core(p, nrm, verts, front, o=None, rel=None, plane_n=None):
    """Shared polygon evaluation; front (n,) bool marks rows that may be non-zero.

    o, rel, plane_n: optional exact centre (n, 3), vertex offsets from it (n, k, 3) and plane
    normal (n, 3). A rect light passes its own (centre, ±ex/2 ± ey/2, ex × ey): rebuilding
    them from the float64 corners loses the offsets' low bits when the light is small and far
    from the origin, and the Newell normal's error then times the distance to p swamps p's
    height above a light seen edge-on (the stress suite's grazing case was off 3000x).
    """
    n = p.shape[0]
    k = verts.shape[1]
    if o is None:
        o = verts.mean(axis=1)
        rel = verts - o[:, None, :]                                # vertex offsets, accurate
    if plane_n is None:
        plane_n = np.cross(rel, np.roll(rel, -1, axis=1)).sum(axis=1)  # Newell normal (2·area·N)
    N, nlen = _unit(plane_n)
    D = o - p
    hs = -_dot(N, D)                                               # height of p along N
    sgn = np.where(hs < 0.0, -1.0, 1.0)
    N = N * sgn[:, None]                                           # N now points towards p
    h = np.abs(hs)
    ok = front & (nlen > 0.0) & (h > 0.0)
    out = np.zeros(n)
    if not np.any(ok):
        return out
    r = np.nonzero(ok)[0]
    N, h, D, rel, nrm = N[r], h[r], D[r], rel[r], nrm[r]
    t1, t2 = _plane_frame(N)
    sig = np.stack([_dot(rel, t1[:, None, :]), _dot(rel, t2[:, None, :])], axis=-1)  # (r, k, 2)
    rho_o = np.stack([_dot(D, t1), _dot(D, t2)], axis=-1)
    m = np.stack([_dot(nrm, t1), _dot(nrm, t2)], axis=-1)
    c = -_dot(nrm, N)
    z_o = _dot(nrm, D)
    z = z_o[:, None] + _dot(rel, nrm[:, None, :])                  # nrm·(v_i − p)
    area2 = _cross2(sig, np.roll(sig, -1, axis=1)).sum(axis=1)
    orient = np.where(area2 < 0.0, -1.0, 1.0)
    res = np.zeros(r.size)
    half = np.sqrt(_dot(sig, sig).max(axis=1))                     # radius about the centroid
    D2 = _dot(D, D)
    dc = np.sqrt(D2)
    rq = np.where(dc > half, half / np.where(dc > half, dc - half, 1.0), np.inf)
    quad = 2.0 * half < FAR_RATIO * dc
    near = ~quad
    if np.any(near):
        # near field: vertices relative to the foot q straight from v − p, so a vertex close
        # to p keeps full relative precision (no detour through the centroid)
        i = np.nonzero(near)[0]
        vp = verts[r[i]] - p[r[i], None, :]
        rho_v = np.stack([_dot(vp, t1[i, None, :]), _dot(vp, t2[i, None, :])], axis=-1)
        Q, count, on_line = _clip_polygon(rho_v, _dot(vp, nrm[i, None, :]))
        g, mag = _near_polygon(Q, count, on_line, h[i], c[i], m[i], orient[i])
        res[i] = np.where(count >= 3, g, 0.0)
        # slivers: terms cancel by > KAPPA_MAX -> area quadrature if the light is compact enough
        redo = (count >= 3) & (mag > KAPPA_MAX * np.abs(g)) & (rq[i] <= QUAD_MAX_R)
        quad[i[redo]] = True
    if np.any(quad):
        order = _quad_order(rq)
        for n_ in np.unique(order[quad]):
            i = np.nonzero(quad & (order == n_))[0]
            Q, count, _ = _clip_polygon(sig[i], z[i])
            g = _far_polygon(Q, D2[i], rho_o[i], z_o[i], m[i], h[i], orient[i], int(n_))
            res[i] = np.where(count >= 3, g, 0.0)
    out[r] = np.maximum(res, 0.0)
    return out


def projected_solid_angle_polygon(p, nrm, verts, e_n=None) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a planar convex polygon seen from p, horizon-clipped.

    p: (n, 3) shading points; nrm: (n, 3) unit normals at p.
    verts: (n, k, 3) or (k, 3) world-space corners of a convex planar polygon, in order (either
        winding); k ≥ 3. A (numerically) degenerate polygon gives 0.
    e_n: optional (n, 3) or (3,) emitting normal. If given the polygon is one-sided: rows with
        dot(p − centroid, e_n) ≤ 0 give 0. If None the polygon is two-sided (seen from either
        side). A point in the polygon's plane gives 0 in both cases.
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    nrm = _unit(_rows(nrm, n))[0]
    verts = np.asarray(verts, dtype=np.float64)
    verts = np.broadcast_to(verts, (n,) + verts.shape[-2:]).astype(np.float64, copy=True)
    if e_n is None:
        front = np.ones(n, dtype=bool)
    else:
        front = _dot(p - verts.mean(axis=1), _rows(e_n, n)) > 0.0
    return _polygon_core(p, nrm, verts, front)


def projected_solid_angle_rect(p, nrm, center, ex, ey, e_n) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided rectangle/parallelogram light.

    The light is {center + a·ex + b·ey : a, b ∈ [−½, ½]}, i.e. ex, ey are the FULL edge vectors
    (the convention of ``renderer.lights.rect``; a sheared transform gives a parallelogram).
    e_n: emitting normal; p sees the light iff dot(p − center, e_n) > 0.
    center, ex, ey, e_n: (n, 3) or (3,). p, nrm: (n, 3).
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    c = _rows(center, n)
    hx = 0.5 * _rows(ex, n)
    hy = 0.5 * _rows(ey, n)
    rel = np.stack([-hx - hy, hx - hy, hx + hy, -hx + hy], axis=1)
    verts = c[:, None, :] + rel
    front = _dot(p - c, _rows(e_n, n)) > 0.0
    return _polygon_core(p, _unit(_rows(nrm, n))[0], verts, front, o=c, rel=rel, plane_n=np.cross(hx, hy))


# ----------------------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------------------
def projected_solid_angle_sphere(p, nrm, center, radius) -> np.ndarray:
    """Projected solid angle (n,) [sr] of an outward-emitting sphere seen from p.

    p, nrm: (n, 3); center: (n, 3) or (3,); radius: (n,) or scalar (> 0).
    Points on or inside the sphere get 0.

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
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    nrm, nlen = _unit(_rows(nrm, n))
    r = _rows(radius, n, None)
    D = _rows(center, n) - p
    d = np.sqrt(_dot(D, D))
    z = _dot(nrm, D)
    valid = (r > 0.0) & (d > r) & (nlen > 0.0)
    ds = np.where(valid, d, 1.0)
    s = np.where(valid, r / ds, 0.0)
    s2 = s * s                                          # sin²σ without 1 − cos²
    cz = z / ds                                         # cos θ
    full = valid & (z >= r)
    part = valid & (np.abs(z) < r)
    a = np.sqrt(np.maximum((r - z) * (r + z), 0.0))
    b = np.sqrt(np.maximum((d - r) * (d + r), 0.0))
    bs = np.where(b > 0.0, b, 1.0)
    phi0 = np.arctan2(a * d, -z * b)
    beta = np.arctan2(a, b)
    tanb = a / bs
    small = beta < 0.05
    b2 = beta * beta
    # β − tan β = −(β³/3 + 2β⁵/15 + 17β⁷/315 + 62β⁹/2835 + 1382β¹¹/155925 + ...)
    series = -beta * b2 * (1.0 / 3.0 + b2 * (2.0 / 15.0 + b2 * (17.0 / 315.0 + b2 * (
        62.0 / 2835.0 + b2 * (1382.0 / 155925.0)))))
    g_small = s2 * (phi0 * cz + tanb) + series
    g_large = s2 * phi0 * cz + beta - a * b / (ds * ds)
    g_part = np.where(small, g_small, g_large)
    out = np.where(full, np.pi * s2 * cz, 0.0)
    out = np.where(part, g_part, out)
    return np.maximum(out, 0.0)


# ----------------------------------------------------------------------------------------
# disk
# ----------------------------------------------------------------------------------------
def _disk_D(psi, A_mB, kappa):
    """D(ψ)/B, where D = F − ψ, F the continuous antiderivative with ∫ dψ/(A − B cos ψ) =
    F(ψ)/√((A−B)(A+B)), i.e. tan(F/2) = κ tan(ψ/2), κ = √((A+B)/(A−B)).

    D = 2 atan2((κ−1) sin(ψ/2)cos(ψ/2), cos²(ψ/2) + κ sin²(ψ/2)) is 2π-periodic and smooth;
    dividing by B uses κ − 1 = 2B/((A−B)(κ+1)), so B → 0 is fine.
    """
    sh = np.sin(0.5 * psi)
    ch = np.cos(0.5 * psi)
    den = ch * ch + kappa * sh * sh
    q = 2.0 * sh * ch / (A_mB * (kappa + 1.0) * den)   # ((κ−1)/B)·sh·ch/den
    B_t = (kappa - 1.0) * sh * ch / den                  # = B·q, the atan argument
    return 2.0 * _atanc(B_t) * q


def _disk_E(psi, P, R, h, kappa, mu):
    """E(ψ) = D_0(ψ) − D_h(ψ) (the h = 0 minus the h > 0 correction), mu = |P − R| > 0 or = 0.

    = 2 atan2((κ0 − κh) sc, c² + κ0 κh s²), scaled by μ so κ0 = (P+R)/μ never appears:
    (κ0 − κh) μ = 4PRh² / ((μ² + h²)((P+R) + κh μ)).
    """
    sh = np.sin(0.5 * psi)
    ch = np.cos(0.5 * psi)
    k = 4.0 * P * R * h * h / ((mu * mu + h * h) * ((P + R) + kappa * mu))
    return 2.0 * np.arctan2(k * sh * ch, mu * ch * ch + (P + R) * kappa * sh * sh)


def _near_disk(P, rho_c, R, h, c, m, mm, zc, full, sa0, ca0, alpha0):
    """Closed-form G for a horizon-clipped disk (in-plane quantities relative to the foot q)."""
    # A − B, A = P² + R² + h², B = 2PR (> 0 as h > 0; the floor only guards underflow of h²)
    A_mB = np.maximum((P - R) ** 2 + h * h, np.finfo(np.float64).tiny)
    A_pB = (P + R) ** 2 + h * h
    A = 0.5 * (A_mB + A_pB)
    B = 2.0 * P * R
    Y = np.sqrt(A_mB * A_pB)
    kappa = np.sqrt(A_pB / A_mB)
    # frame: û towards the disk centre from q, v̂ = rot90(û); ψ = 0 at the rim point nearest q
    Ps = np.where(P > 0.0, P, 1.0)
    ux = np.where(P > 0.0, rho_c[:, 0] / Ps, 1.0)
    uy = np.where(P > 0.0, rho_c[:, 1] / Ps, 0.0)
    mms = np.where(mm > 0.0, mm, 1.0)
    mx = np.where(mm > 0.0, m[:, 0] / mms, 1.0)
    my = np.where(mm > 0.0, m[:, 1] / mms, 0.0)
    cos_g = mx * ux + my * uy
    sin_g = -mx * uy + my * ux                          # m̂·v̂ with v̂ = (−uy, ux)
    gamma = np.arctan2(sin_g, cos_g)
    m_u = m[:, 0] * ux + m[:, 1] * uy
    m_v = -m[:, 0] * uy + m[:, 1] * ux
    psi1 = gamma - np.pi - alpha0
    psi2 = gamma - np.pi + alpha0
    dpsi = 2.0 * alpha0
    dDq = np.where(full, 0.0, _disk_D(psi2, A_mB, kappa) - _disk_D(psi1, A_mB, kappa))
    dD = B * dDq
    C = (dpsi * B / (A + Y) + A * dDq) / Y            # ∫ cos ψ /(A − B cos ψ)
    cdiff = -2.0 * sin_g * sa0                         # cos ψ1 − cos ψ2
    s1 = np.sin(0.5 * psi1)
    den1 = A_mB + 2.0 * B * s1 * s1                    # A − B cos ψ1
    xk = np.maximum(B * cdiff / den1, -1.0 + 1e-16)    # > −1 exactly; guard rounding
    K = np.where(full, 0.0, _log1pc(xk) * cdiff / den1)  # ∫ sin ψ/(A − B cos ψ)
    lin = 0.5 * R * h * (m_u * C + m_v * K)
    # radial arc flux (c/2)·R·Ir, R·Ir = [(1 − ρh) Δψ − ρh ΔD]/2, ρh = X/Y, X = P² + h² − R²
    X = (P - R) * (P + R) + h * h
    YpX = Y + np.abs(X)                                # Y ± X without cancellation (Y ≥ |X|)
    q4 = 4.0 * h * h * R * R / (Y * YpX)              # = 1 − |ρh|, since Y² − X² = 4h²R²
    rho_h = X / Y
    one_m_rho = np.where(X > 0.0, q4, YpX / Y)
    rad_direct = 0.5 * c * 0.5 * (one_m_rho * dpsi - rho_h * dD)
    # ... minus its h = 0 value: [(ρ0 − ρh)(Δψ + ΔD) + ρ0 ΔE]/2, ρ0 = sign(P − R)
    rho0 = np.sign(P - R)
    r0_m_rh = np.where(P > R, q4, np.where(P == R, -rho_h, np.where(X < 0.0, -q4, -1.0 - rho_h)))
    mu = np.abs(P - R)
    dE = np.where(full, 0.0, _disk_E(psi2, P, R, h, kappa, mu) - _disk_E(psi1, P, R, h, kappa, mu))
    rad_diff = 0.5 * c * 0.5 * (r0_m_rh * (dpsi + dD) + rho0 * dE)
    # horizon chord (partial rows): from the arc end (α0) back to its start (−α0), outward −m̂
    # distance of the chord's line from q (only defined for clipped rows, where it is bounded
    # by P + R since |zc| < R|m|)
    delta = np.where(full, 0.0, c * h / np.where(full, 1.0, mms))
    perp_rho = -my * rho_c[:, 0] + mx * rho_c[:, 1]    # m̂⊥·ρ_c
    L = np.where(full, 0.0, 2.0 * R * sa0)
    sa = -perp_rho - R * sa0
    c_lin, c_rad, c_diff = _edge_terms(delta, sa, L, h, c, -mm)
    # radial part: plain, or for grazing points with q clearly outside, the difference form
    margin = np.maximum(P - R, np.where(full, -np.inf, -delta))
    use_diff = _use_difference_form(margin, h)
    radial = np.where(use_diff, rad_diff + c_diff, rad_direct + c_rad)
    g = lin + c_lin + radial
    # size of the individual terms, to detect cancellation (slivers)
    mag = (0.5 * R * h * (np.abs(m_u * C) + np.abs(m_v * K)) + np.abs(c_lin)
           + np.where(use_diff,
                      0.25 * np.abs(c) * (np.abs(r0_m_rh * (dpsi + dD)) + np.abs(dE)) + np.abs(c_diff),
                      0.25 * np.abs(c) * (np.abs(one_m_rho * dpsi) + np.abs(rho_h * dD)) + np.abs(c_rad)))
    return g, mag


def _far_ellipse(T, D2, rho_c, zc, m, h, order):
    """Area-quadrature G over the clipped ellipse {c + T ξ : |ξ| ≤ 1, zc + m·Tξ ≥ 0}.

    T: (r, 2, 2) in-plane semi-axis matrix (columns = semi-axes in the (t1, t2) frame; R·I for
    a disk); D2 = |c − p|²; rho_c: (r, 2) centre relative to the foot q; zc = nrm·(c − p);
    m: (r, 2) in-plane part of nrm; h: height. In the unit disk, ξ = cos φ m̂' + y m̂'⊥ with
    m' = Tᵀm, φ ∈ [0, α0], |y| ≤ sin φ (smooth in φ and y; the sin²φ factor needs ≥ 16 nodes
    in φ), Gauss-Legendre of order max(order, 16) in φ and order in y.
    """
    _, _, Xp, Wp = _gl(max(order, _DISK_PHI_ORDER))
    Xy, Wy, _, _ = _gl(order)
    mp = np.einsum("rji,rj->ri", T, m)                     # Tᵀ m
    mm = np.hypot(mp[:, 0], mp[:, 1])
    full = zc >= mm
    part = (zc < mm) & (zc > -mm)
    mms = np.where(part, mm, 1.0)
    sa0 = np.where(part, np.sqrt(np.maximum((mm - zc) * (mm + zc), 0.0)) / mms, 0.0)
    alpha0 = np.where(full, np.pi, np.where(part, np.arctan2(sa0, -zc / mms), 0.0))
    nz = mm > 0.0
    mms = np.where(nz, mm, 1.0)
    mx = np.where(nz, mp[:, 0] / mms, 1.0)
    my = np.where(nz, mp[:, 1] / mms, 0.0)
    phi = alpha0[:, None] * Xp[None, :]                       # (r, gφ)
    wphi = alpha0[:, None] * Wp[None, :]
    x = np.cos(phi)
    ys = np.sin(phi)
    y = ys[:, :, None] * Xy[None, None, :]                    # (r, gφ, gy)
    wy = ys[:, :, None] * Wy[None, None, :]
    xb = x[:, :, None]
    xi0 = xb * mx[:, None, None] - y * my[:, None, None]      # ξ in the unit disk
    xi1 = xb * my[:, None, None] + y * mx[:, None, None]
    sx = T[:, 0, 0, None, None] * xi0 + T[:, 0, 1, None, None] * xi1   # σ = T ξ
    sy = T[:, 1, 0, None, None] * xi0 + T[:, 1, 1, None, None] * xi1
    num = np.maximum(zc[:, None, None] + mm[:, None, None] * xb, 0.0)
    den = (D2[:, None, None] + 2.0 * (sx * rho_c[:, None, None, 0] + sy * rho_c[:, None, None, 1])
           + sx * sx + sy * sy)
    f = num / (den * den)
    # dA = |det T| · (sin φ dφ)·dy
    tot = (f * wy * (np.sin(phi) * wphi)[:, :, None]).sum(axis=(1, 2))
    det = np.abs(T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0])
    return h * det * tot


def _far_disk(R, D2, rho_c, zc, m, h, order):
    T = R[:, None, None] * np.eye(2)[None, :, :]
    return _far_ellipse(T, D2, rho_c, zc, m, h, order)


def projected_solid_angle_disk(p, nrm, center, e_n, radius) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided circular disk light, horizon-clipped.

    p, nrm: (n, 3); center, e_n: (n, 3) or (3,) (e_n: emitting normal, normalised here);
    radius: (n,) or scalar. p sees the disk iff dot(p − center, e_n) > 0.
    Exact closed form (elementary functions, see the module docstring); Gauss-Legendre over
    the clipped disk where that cancels (far or sliver), as for polygons.
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    nrm = _unit(_rows(nrm, n))[0]
    N = _unit(_rows(e_n, n))[0]
    R = _rows(radius, n, None)
    D = _rows(center, n) - p
    h = -_dot(N, D)                                      # height of p on the emitting side
    ok = (h > 0.0) & (R > 0.0)
    out = np.zeros(n)
    if not np.any(ok):
        return out
    r = np.nonzero(ok)[0]
    N, R, D, h, nrm = N[r], R[r], D[r], h[r], nrm[r]
    t1, t2 = _plane_frame(N)
    rho_c = np.stack([_dot(D, t1), _dot(D, t2)], axis=-1)   # disk centre relative to the foot q
    P = np.hypot(rho_c[:, 0], rho_c[:, 1])
    m = np.stack([_dot(nrm, t1), _dot(nrm, t2)], axis=-1)
    mm = np.hypot(m[:, 0], m[:, 1])
    c = -_dot(nrm, N)
    zc = _dot(nrm, D)                                    # nrm·(centre − p)
    Rm = R * mm
    full = zc >= Rm
    part = (zc < Rm) & (zc > -Rm)
    # clipped rim: σ = R(cos α m̂ + sin α m̂⊥), kept for |α| ≤ α0, cos α0 = −zc/(R|m|)
    Rms = np.where(part, Rm, 1.0)
    sa0 = np.where(part, np.sqrt(np.maximum((Rm - zc) * (Rm + zc), 0.0)) / Rms, 0.0)
    ca0 = np.where(part, -zc / Rms, -1.0)
    alpha0 = np.where(full, np.pi, np.arctan2(sa0, ca0))
    D2 = _dot(D, D)
    dc = np.sqrt(D2)
    rq = np.where(dc > R, R / np.where(dc > R, dc - R, 1.0), np.inf)
    res = np.zeros(r.size)
    vis = full | part
    quad = vis & (2.0 * R < FAR_RATIO * dc)
    near = vis & ~quad
    if np.any(near):
        i = np.nonzero(near)[0]
        g, mag = _near_disk(P[i], rho_c[i], R[i], h[i], c[i], m[i], mm[i], zc[i], full[i],
                            sa0[i], ca0[i], alpha0[i])
        res[i] = g
        redo = (mag > KAPPA_MAX * np.abs(g)) & (rq[i] <= QUAD_MAX_R)
        quad[i[redo]] = True
    if np.any(quad):
        order = _quad_order(rq)
        for n_ in np.unique(order[quad]):
            i = np.nonzero(quad & (order == n_))[0]
            res[i] = _far_disk(R[i], D2[i], rho_c[i], zc[i], m[i], h[i], int(n_))
    out[r] = np.maximum(res, 0.0)
    return out


# ----------------------------------------------------------------------------------------
# ellipse (a disk under non-uniform scale or shear)
# ----------------------------------------------------------------------------------------
_NEWTON_STEP = np.pi / 32     # largest Newton step (radians) when refining the nearest rim point


def _ellipse_poles(rho_c, A1, A2, h):
    """Complex zeros of |ρ(t)|² + h², ρ = ρ_c + A1 cos t + A2 sin t, as (Re t, |Im t|), each
    (r, 4). With z = e^{it}: z²(|ρ|² + h²) = c4 z⁴ + c3 z³ + c2 z² + c1 z + c0 where
    c4 = (k3 − i k4)/2, c3 = (k1 − i k2)/2, c2 = k0, c1 = conj(c3), c0 = conj(c4) for
    |ρ|² + h² = k0 + k1 cos t + k2 sin t + k3 cos 2t + k4 sin 2t; t = arg z − i ln|z|. Roots
    from the companion matrix (batched eigenvalues); a (near-)circle drops to the quadratic
    c3 z² + c2 z + c1 (its two other roots are at z ≈ 0, ∞: reported at distance π).
    Used only to place quadrature breakpoints (near-double roots are accurate to ~√ε)."""
    a11, a22, a12 = _dot(A1, A1), _dot(A2, A2), _dot(A1, A2)
    k0 = _dot(rho_c, rho_c) + 0.5 * (a11 + a22) + h * h
    k1, k2 = 2.0 * _dot(rho_c, A1), 2.0 * _dot(rho_c, A2)
    k3, k4 = 0.5 * (a11 - a22), a12
    c4 = 0.5 * (k3 - 1j * k4)
    c3 = 0.5 * (k1 - 1j * k2)
    c2 = k0 + 0j
    c1 = np.conj(c3)
    c0 = np.conj(c4)
    scale = np.abs(c3) + np.abs(c2)
    quartic = np.abs(c4) > 1e-8 * scale
    n = rho_c.shape[0]
    re = np.zeros((n, 4))
    im = np.full((n, 4), np.pi)
    if np.any(quartic):
        i = np.nonzero(quartic)[0]
        comp = np.zeros((i.size, 4, 4), dtype=complex)
        comp[:, 1, 0] = comp[:, 2, 1] = comp[:, 3, 2] = 1.0
        comp[:, :, 3] = -np.stack([c0[i], c1[i], c2[i], c3[i]], axis=1) / c4[i, None]
        z = np.linalg.eigvals(comp)
        re[i] = np.angle(z)
        im[i] = np.abs(np.log(np.maximum(np.abs(z), 1e-300)))
    if np.any(~quartic):
        i = np.nonzero(~quartic)[0]
        a, b, cc = c3[i], c2[i], c1[i]
        ok = np.abs(a) > 0                     # a = 0: circle centred on q, no preferred t
        a = np.where(ok, a, 1.0)
        disc = np.sqrt(b * b - 4.0 * a * cc)
        z = (-b + np.where((np.conj(b) * disc).real >= 0, -disc, disc)) / (2.0 * a)
        re[i, 0] = re[i, 1] = np.where(ok, np.angle(z), 0.0)
        im[i, 0] = im[i, 1] = np.where(ok, np.abs(np.log(np.maximum(np.abs(z), 1e-300))), np.pi)
    return re, im


def _near_ellipse(rho_c, A1, A2, h, c, m, zc):
    """Near-field G of a horizon-clipped ellipse {ρ_c + A1 cos t + A2 sin t} (in-plane, relative
    to the foot q; det[A1 A2] > 0) by the same Green's-theorem fluxes as the disk, with the arc
    integral evaluated by Gauss-Legendre (12 nodes per panel) on panels graded geometrically
    towards the integrand's complex poles (see below), so that a point close to the rim keeps
    ~1e-13. The horizon chord is a straight edge (_edge_terms). Returns (G, |terms|)."""
    r = rho_c.shape[0]
    det = _cross2(A1, A2)
    mA1, mA2 = _dot(m, A1), _dot(m, A2)
    mu = np.hypot(mA1, mA2)
    full = zc >= mu
    mus = np.where(full, 1.0, mu)
    sa0 = np.where(full, 0.0, np.sqrt(np.maximum((mu - zc) * (mu + zc), 0.0)) / mus)
    alpha0 = np.where(full, np.pi, np.arctan2(sa0, -zc / mus))
    t_m = np.arctan2(mA2, mA1)

    def rho(t):
        ct, st = np.cos(t), np.sin(t)
        return rho_c[:, None, :] + ct[..., None] * A1[:, None, :] + st[..., None] * A2[:, None, :]

    def drho(t):
        ct, st = np.cos(t), np.sin(t)
        return -st[..., None] * A1[:, None, :] + ct[..., None] * A2[:, None, :]

    # Quadrature breakpoints: the integrand's only singularities are the complex zeros of
    # |ρ(t)|² + h² (four; two near the real axis for each flank of a thin ellipse that is
    # close to q). Grade geometrically towards each zero's real part from half its distance to
    # the real axis. Zeros very close to the axis (p near the rim) are near-double and only
    # good to ~√ε, so the rim point nearest to q is also refined by Newton on ρ·ρ' = 0 and
    # graded from √(|ρ|² + h²)/|ρ'| there.
    pre, pim = _ellipse_poles(rho_c, A1, A2, h)
    # one zero per conjugate pair (the pairs z, 1/z̄ share their real part): the two nearest the
    # real axis that belong to different pairs (farthest apart in argument)
    k0 = np.argmin(pim, axis=1)
    a0 = pre[np.arange(r), k0]
    sep = np.abs(np.angle(np.exp(1j * (pre - a0[:, None]))))
    k1 = np.argmax(sep, axis=1)
    centres = [a0, pre[np.arange(r), k1]]
    widths = [np.clip(0.5 * pim[np.arange(r), k], 1e-300, np.pi / 8.0) for k in (k0, k1)]
    step_max = _NEWTON_STEP
    ts = a0.copy()
    for _ in range(8):
        q0, q1 = rho(ts[:, None])[:, 0], drho(ts[:, None])[:, 0]
        q2 = q0 - rho_c                                     # ρ'' = −(A1 cos t + A2 sin t)
        g1 = _dot(q1, q1) - _dot(q0, q2)
        step = -_dot(q0, q1) / np.where(g1 > 0.0, g1, 1.0)
        ts = ts + np.where(g1 > 0.0, np.clip(step, -step_max, step_max), 0.0)
    q0, q1 = rho(ts[:, None])[:, 0], drho(ts[:, None])[:, 0]
    dmin2 = _dot(q0, q0)
    # (caps: ≥ 16 panels per turn even for a smooth integrand, so 12 nodes give ~1e-15)
    centres.append(ts)
    widths.append(np.clip(np.sqrt(dmin2 + h * h) / np.maximum(np.sqrt(_dot(q1, q1)), 1e-300),
                          1e-300, np.pi / 8.0))
    # arc parameter range; each centre graded at its periodic copies next to the range (the
    # arc can reach the copy of a pole from either end)
    lo = np.where(full, centres[0] - np.pi, t_m - alpha0)
    hi = np.where(full, centres[0] + np.pi, t_m + alpha0)
    mid = 0.5 * (lo + hi)
    centres = [ts_ + 2.0 * np.pi * np.round((mid - ts_) / (2.0 * np.pi)) for ts_ in centres]
    # rows grouped by the number of grading levels they need (no Python loop over rows)
    levels = np.clip(np.ceil(np.log2(2.0 * np.pi / np.minimum.reduce(widths))) + 1, 1, 1100).astype(int)
    arc_lin = np.zeros(r)
    arc_rad = np.zeros(r)
    arc_diff = np.zeros(r)
    mag_lin = np.zeros(r)
    mag_rad = np.zeros(r)
    mag_diff = np.zeros(r)
    _, _, X, W = _gl(12)
    for J in np.unique(levels):
        i = np.nonzero(levels == J)[0]
        parts = [lo[i, None], hi[i, None]]
        for ts_, wdt in zip(centres, widths):
            g = wdt[i, None] * 2.0 ** np.arange(J + 1)[None, :]
            for shift in (-2.0 * np.pi, 0.0, 2.0 * np.pi):
                tc = ts_[i, None] + shift
                parts += [tc - g, tc, tc + g]
        cand = np.clip(np.concatenate(parts, axis=1), lo[i, None], hi[i, None])
        cand.sort(axis=1)
        a_, b_ = cand[:, :-1], cand[:, 1:]
        keep = (b_ > a_).any(axis=0)                         # drop all-empty panel columns
        a_, b_ = a_[:, keep], b_[:, keep]
        t = (a_[..., None] + (b_ - a_)[..., None] * X).reshape(i.size, -1)
        w = ((b_ - a_)[..., None] * W).reshape(i.size, -1)
        ct, st = np.cos(t), np.sin(t)
        R_ = rho_c[i, None, :] + ct[..., None] * A1[i, None, :] + st[..., None] * A2[i, None, :]
        dR = -st[..., None] * A1[i, None, :] + ct[..., None] * A2[i, None, :]
        r2 = _dot(R_, R_)
        hh = (h[i] * h[i])[:, None]
        d2 = r2 + hh
        cr = _cross2(R_, dR)                                   # ρ × ρ'
        lin = -0.5 * h[i, None] * _cross2(m[i, None, :], dR) / d2
        rad = 0.5 * c[i, None] * cr / d2
        diff = -0.5 * c[i, None] * cr * hh / (np.where(r2 > 0.0, r2, 1.0) * d2)
        arc_lin[i] = (lin * w).sum(axis=1)
        arc_rad[i] = (rad * w).sum(axis=1)
        arc_diff[i] = (diff * w).sum(axis=1)
        mag_lin[i] = (np.abs(lin) * w).sum(axis=1)
        mag_rad[i] = (np.abs(rad) * w).sum(axis=1)
        mag_diff[i] = (np.abs(diff) * w).sum(axis=1)
    # q outside the ellipse, or cut off by the chord: margin as for the disk
    xi = _cross2(-rho_c, A2) / det
    eta = _cross2(A1, -rho_c) / det
    outside_ell = xi * xi + eta * eta > 1.0
    # chord from the arc's end back to its start: a straight edge on the horizon line
    # m·ρ + h c = 0, so (as for the disk) its outward normal is −m̂, its direction −m̂⊥ and
    # its distance from q exactly c h/|m| (not recomputed from the end points, whose
    # rounding would swamp a tiny h)
    pa, pb = rho(hi[:, None])[:, 0], rho(lo[:, None])[:, 0]
    e = pb - pa
    L = np.where(full, 0.0, np.hypot(e[:, 0], e[:, 1]))
    mm = np.hypot(m[:, 0], m[:, 1])
    mms = np.where(mm > 0.0, mm, 1.0)
    mx, my = m[:, 0] / mms, m[:, 1] / mms
    delta = np.where(full, 0.0, c * h / np.where(full, 1.0, mms))
    sa = -(-my * pa[:, 0] + mx * pa[:, 1])                  # pa·(−m̂⊥)
    c_lin, c_rad, c_diff = _edge_terms(delta, sa, L, h, c, -mm)
    margin = np.maximum(np.where(outside_ell, np.sqrt(dmin2), -np.inf), np.where(full, -np.inf, -delta))
    use_diff = _use_difference_form(margin, h)
    gval = arc_lin + c_lin + np.where(use_diff, arc_diff + c_diff, arc_rad + c_rad)
    mag = (mag_lin + np.abs(c_lin)
           + np.where(use_diff, mag_diff + np.abs(c_diff), mag_rad + np.abs(c_rad)))
    return gval, mag


def projected_solid_angle_ellipse(p, nrm, center, e1, e2, e_n) -> np.ndarray:
    """Projected solid angle (n,) [sr] of a one-sided elliptical light, horizon-clipped.

    The light is {center + x·e1 + y·e2 : x² + y² ≤ 1}: e1, e2 (n, 3) or (3,) are two conjugate
    semi-diameters spanning the ellipse's plane (e.g. its principal semi-axes, as
    ``renderer.lights.disk`` stores them; any non-parallel pair works); e_n: emitting normal
    (normalised here); p sees the light iff dot(p − center, e_n) > 0.

    Not a closed form: the disk's Green's-theorem formulation with the arc flux integrated by
    Gauss-Legendre on panels graded from the rim point nearest to p's foot (relative error
    ~1e-13 in tests, also within 1e-10 of the rim), the chord and the grazing difference form
    exactly as for the disk; area quadrature (through the affine map of the unit disk) for
    small/far ellipses and slivers.
    """
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    n = p.shape[0]
    nrm, nlen = _unit(_rows(nrm, n))
    N = _unit(_rows(e_n, n))[0]
    e1 = _rows(e1, n)
    e2 = _rows(e2, n)
    D = _rows(center, n) - p
    h = -_dot(N, D)
    cr = np.cross(e1, e2)
    ok = (h > 0.0) & (_dot(cr, cr) > 0.0) & (nlen > 0.0)
    out = np.zeros(n)
    if not np.any(ok):
        return out
    r = np.nonzero(ok)[0]
    N, D, h, e1, e2, nrm = N[r], D[r], h[r], e1[r], e2[r], nrm[r]
    t1, t2 = _plane_frame(N)
    A1 = np.stack([_dot(e1, t1), _dot(e1, t2)], axis=-1)
    A2 = np.stack([_dot(e2, t1), _dot(e2, t2)], axis=-1)
    A2 = np.where((_cross2(A1, A2) < 0.0)[:, None], -A2, A2)    # counter-clockwise parameter
    rho_c = np.stack([_dot(D, t1), _dot(D, t2)], axis=-1)
    m = np.stack([_dot(nrm, t1), _dot(nrm, t2)], axis=-1)
    c = -_dot(nrm, N)
    zc = _dot(nrm, D)
    mu = np.hypot(_dot(m, A1), _dot(m, A2))
    vis = zc > -mu
    D2 = _dot(D, D)
    dc = np.sqrt(D2)
    half = np.sqrt(np.maximum(_dot(e1, e1), _dot(e2, e2)))
    rq = np.where(dc > half, half / np.where(dc > half, dc - half, 1.0), np.inf)
    quad = vis & (2.0 * half < FAR_RATIO * dc)
    near = vis & ~quad
    res = np.zeros(r.size)
    if np.any(near):
        i = np.nonzero(near)[0]
        g, mag = _near_ellipse(rho_c[i], A1[i], A2[i], h[i], c[i], m[i], zc[i])
        res[i] = g
        redo = (mag > KAPPA_MAX * np.abs(g)) & (rq[i] <= QUAD_MAX_R)
        quad[i[redo]] = True
    if np.any(quad):
        T = np.stack([A1, A2], axis=-1)                           # columns: semi-axes
        order = _quad_order(rq)
        for n_ in np.unique(order[quad]):
            i = np.nonzero(quad & (order == n_))[0]
            res[i] = _far_ellipse(T[i], D2[i], rho_c[i], zc[i], m[i], h[i], int(n_))
    out[r] = np.maximum(res, 0.0)
    return out


# ----------------------------------------------------------------------------------------
# dome
# ----------------------------------------------------------------------------------------
def projected_solid_angle_dome_constant() -> float:
    """∫_{hemisphere} cos θ dω = π: the projected solid angle of a constant dome (the textured
    dome's cosine convolution is precomputed elsewhere)."""
    return float(np.pi)
