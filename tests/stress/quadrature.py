"""Independent deterministic references for the unshadowed integral of a light.

Nothing here calls ``renderer.lights.analytic``. Each function returns the *projected solid
angle* G = ∫ max(0, nrm·ω) dω over the directions ω in which p sees the light's emitting side
(a uniform emitter of radiance L then gives the irradiance E = L·G), together with the plain
solid angle Ω of the light (used to scale error floors).

Planar lights (rect, circular disk) are integrated in area measure from the definition

    G = ∫_A max(0, nrm·(x − p)) · h / |x − p|⁴ dA ,

h the height of p above the light's plane on its emitting side, as iterated 1-D Gauss-Legendre
integrals (outer over y, inner over x). Panels are split at every kink (the horizon line of
nrm, the light's edges) and graded geometrically (ratio 2) towards the foot of p, starting at a
quarter of the height, so that points very close to a huge light are resolved: on every panel
the integrand's nearest complex singularity is several half-widths away and 12 nodes give
~1e-15 relative accuracy. The disk is parametrised by y = R sin θ (no square-root endpoint
behaviour).

The sphere uses the cone integral over the polar angle α about the direction to its centre,

    G = ∫_0^σ sin α · H(α) dα,   H(α) = ∫_0^{2π} max(0, sin e cos α + cos e sin α cos φ) dφ,

e the elevation of the centre above p's horizon; H is elementary and the kink at α = |e| is a
graded breakpoint.

The light's local frame (and p in it) is computed in extended precision (np.longdouble), so the
reference describes exactly the float64 geometry the renderer holds.
"""

from __future__ import annotations

import math

import numpy as np

_NG = 16
_GX, _GW = np.polynomial.legendre.leggauss(_NG)
_GX01 = 0.5 * (_GX + 1.0)
_GW01 = 0.5 * _GW
_LD = np.longdouble


# ----------------------------------------------------------------------------------------
# panels
# ----------------------------------------------------------------------------------------
def _graded(center: np.ndarray, scale: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            extra: list[np.ndarray] | None = None, refine: list[np.ndarray] | None = None) -> np.ndarray:
    """(M, B) sorted breakpoints in [lo, hi], graded (ratio 2) away from ``center``, first
    gap scale/4; ``extra`` (M,) arrays are kinks added as breakpoints; ``refine`` (M,) arrays
    are kinks towards which panels also shrink geometrically (for x^(3/2)-type behaviour)."""
    span = np.maximum(np.abs(center - lo), np.abs(hi - center))
    # A subnormal scale (hypothesis finds them) overflows the ratio to inf: the panel count
    # is capped below anyway.
    with np.errstate(over="ignore"):
        ratio = float(np.max(span / scale)) if span.size else 1.0
    ratio = min(ratio, 1e300)
    J = int(min(max(math.ceil(math.log2(max(ratio * 4.0, 1.0))) + 1, 1), 2100))
    g = 0.25 * scale[:, None] * 2.0 ** np.arange(J)[None, :]
    parts = [center[:, None] - g, center[:, None] + g, center[:, None], lo[:, None], hi[:, None]]
    for e in extra or []:
        parts.append(e[:, None])
    fine = (hi - lo)[:, None] * 2.0 ** -np.arange(1, 48)[None, :]
    for e in refine or []:
        parts.extend([e[:, None], e[:, None] - fine, e[:, None] + fine])
    cand = np.concatenate(parts, axis=1)
    cand = np.where(np.isfinite(cand), cand, lo[:, None])
    cand = np.clip(cand, lo[:, None], hi[:, None])
    cand.sort(axis=1)
    return cand


def _nodes(breaks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on every panel of (M, B) breakpoints -> (M, 12(B-1))."""
    a = breaks[:, :-1]
    w = breaks[:, 1:] - a
    x = a[..., None] + w[..., None] * _GX01
    wt = w[..., None] * _GW01
    return x.reshape(breaks.shape[0], -1), wt.reshape(breaks.shape[0], -1)


def _inner(y, xlo, xhi, px, py, h, nrm, clips=()):
    """∫_{xlo}^{xhi} max(0, nrm·(x − p)) Π_k [c_k·(x − p) > 0] h / d⁴ dx for each y (M,),
    p = (px, py, h) above the plane z = 0 (clips: local 3-vectors c_k of half-space occluders)."""
    dy = y - py
    k = np.sqrt(dy * dy + h * h)
    kinks = []
    for n in (nrm, *clips):
        if n[0] != 0.0:
            # n·(x − p) = n_x (x − px) + n_y dy − n_z h = 0. A subnormal n_x puts the kink at
            # infinity (outside [xlo, xhi]): it is no breakpoint then.
            with np.errstate(over="ignore"):
                kink = px + (n[2] * h - n[1] * dy) / n[0]
            kinks.append(np.where(np.isfinite(kink), kink, xlo))
    br = _graded(np.full(y.size, px), k, xlo, xhi, kinks)
    x, w = _nodes(br)
    dx = x - px
    d2 = dx * dx + (k * k)[:, None]
    num = np.maximum(nrm[0] * dx + nrm[1] * dy[:, None] - nrm[2] * h, 0.0)
    for c in clips:
        num = np.where(c[0] * dx + c[1] * dy[:, None] - c[2] * h > 0.0, num, 0.0)
    return (num * h / (d2 * d2) * w).sum(axis=1)


def _omega_inner(y, xlo, xhi, px, py, h):
    """∫ h / d³ dx (the solid-angle integrand) for each y."""
    dy = y - py
    k = np.sqrt(dy * dy + h * h)
    br = _graded(np.full(y.size, px), k, xlo, xhi)
    x, w = _nodes(br)
    dx = x - px
    d2 = dx * dx + (k * k)[:, None]
    return (h / (d2 * np.sqrt(d2)) * w).sum(axis=1)


def _outer_breaks(py: float, h: float, lo: float, hi: float, planes, kinks: list[np.ndarray]) -> np.ndarray:
    """(B,) breakpoints of the outer (y) integral: graded towards the foot py (the pole of the
    integrand at y = py ± i h) and, for each plane n (the horizon and the clips), towards the
    real part of the complex singularity where the inner integral's kink meets the inner pole,
    dy = h (n_z n_y ± i |n_x|) / (n_x² + n_y²)  (a near-real singularity when |n_x| is small)."""
    br = [_graded(np.array([py]), np.array([h]), np.array([lo]), np.array([hi]), kinks)[0]]
    for n in planes:
        m2 = n[0] * n[0] + n[1] * n[1]
        if m2 > 0.0 and n[0] != 0.0:
            re = h * n[2] * n[1] / m2
            im = h * abs(n[0]) / m2
            br.append(_graded(np.array([py + re]), np.array([im]), np.array([lo]), np.array([hi]))[0])
    return np.unique(np.concatenate(br))


# ----------------------------------------------------------------------------------------
# local frames (extended precision)
# ----------------------------------------------------------------------------------------
def _planar_local(p, center, e1, e2, e_n):
    """p in the frame (ê1, ê2⊥, ê_n) centred at ``center``: (px, py, h) floats, and the frame."""
    P = np.asarray(p, dtype=_LD)
    C = np.asarray(center, dtype=_LD)
    a = np.asarray(e1, dtype=_LD)
    a = a / np.sqrt((a * a).sum())
    b = np.asarray(e2, dtype=_LD)
    b = b - (b * a).sum() * a
    b = b / np.sqrt((b * b).sum())
    c = np.cross(a, b)
    if (c * np.asarray(e_n, dtype=_LD)).sum() < 0:
        b = -b
        c = -c
    D = P - C
    return float((D * a).sum()), float((D * b).sum()), float((D * c).sum()), (a, b, c)


def _local_normal(nrm, frame) -> np.ndarray:
    a, b, c = frame
    N = np.asarray(nrm, dtype=_LD)
    v = np.array([(N * a).sum(), (N * b).sum(), (N * c).sum()], dtype=_LD)
    v = v / np.sqrt((v * v).sum())
    return v.astype(np.float64)


# ----------------------------------------------------------------------------------------
# rect
# ----------------------------------------------------------------------------------------
def rect_G(p, nrm, center, ex, ey, e_n, clips=()) -> tuple[float, float]:
    """(G, Ω) of the one-sided rectangle {center + a ex + b ey : |a|, |b| ≤ ½} emitting along
    e_n, seen from the point p with unit normal nrm. ex ⟂ ey (up to rounding).
    clips: world 3-vectors c; only directions ω with c·ω > 0 count (half-space occluders
    through p); Ω ignores them."""
    px, py, h, frame = _planar_local(p, center, ex, ey, e_n)
    if not h > 0.0:
        return 0.0, 0.0
    n = _local_normal(nrm, frame)
    cl = [_local_normal(c, frame) for c in clips]
    A = 0.5 * float(np.linalg.norm(ex))
    ey_l = np.asarray(ey, dtype=np.float64)
    B = 0.5 * float(np.sqrt(max(ey_l @ ey_l - (ey_l @ frame[0].astype(np.float64)) ** 2, 0.0)))
    kinks = []
    for v in (n, *cl):
        if v[1] != 0.0:
            for xe in (-A, A):
                kinks.append(np.array([py + (v[2] * h - v[0] * (xe - px)) / v[1]]))
    br = _outer_breaks(py, h, -B, B, (n, *cl), kinks)[None, :]
    y, wy = _nodes(br)
    y, wy = y[0], wy[0]
    lo = np.full(y.size, -A)
    hi = np.full(y.size, A)
    G = float((_inner(y, lo, hi, px, py, h, n, cl) * wy).sum())
    Om = float((_omega_inner(y, lo, hi, px, py, h) * wy).sum())
    return G, Om


# ----------------------------------------------------------------------------------------
# disk
# ----------------------------------------------------------------------------------------
def disk_G(p, nrm, center, e_n, radius, clips=()) -> tuple[float, float]:
    """(G, Ω) of the one-sided circular disk of ``radius`` about ``center`` emitting along e_n
    (clips as for rect_G)."""
    e_n = np.asarray(e_n, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(e_n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, e_n)
    e2 = np.cross(e_n, e1)
    px, py, h, frame = _planar_local(p, center, e1, e2, e_n)
    if not (h > 0.0 and radius > 0.0):
        return 0.0, 0.0
    n = _local_normal(nrm, frame)
    cl = [_local_normal(c, frame) for c in clips]
    R = float(radius)
    # breakpoints in y (graded towards py, kinks where a horizon/clip line crosses the circle),
    # then mapped to θ = asin(y / R), where the chord half-length R cos θ is smooth.
    kinks = []
    for v in (n, *cl):
        mm = math.hypot(v[0], v[1])
        if mm > 0.0:
            K = v[2] * h + v[0] * px + v[1] * py      # line: v_x x + v_y y = K
            delta = K / mm
            if abs(delta) < R:
                s = math.sqrt((R - delta) * (R + delta))
                ux, uy = v[0] / mm, v[1] / mm
                for sgn in (-1.0, 1.0):
                    kinks.append(np.array([delta * uy + sgn * s * ux]))
    yb = _outer_breaks(py, h, -R, R, (n, *cl), kinks)
    tb = np.arcsin(np.clip(yb / R, -1.0, 1.0))[None, :]
    th, wt = _nodes(tb)
    th, wt = th[0], wt[0]
    y = R * np.sin(th)
    half = R * np.cos(th)
    jac = half * wt                                   # dy = R cos θ dθ
    G = float((_inner(y, -half, half, px, py, h, n, cl) * jac).sum())
    Om = float((_omega_inner(y, -half, half, px, py, h) * jac).sum())
    return G, Om


# ----------------------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------------------
def sphere_G(p, nrm, center, radius) -> tuple[float, float]:
    """(G, Ω) of an outward-emitting sphere; 0 on or inside it."""
    D = np.asarray(center, dtype=_LD) - np.asarray(p, dtype=_LD)
    d = np.sqrt((D * D).sum())
    r = float(radius)
    if not (r > 0.0 and float(d) > r):
        return 0.0, 0.0
    axis = D / d
    N = np.asarray(nrm, dtype=_LD)
    N = N / np.sqrt((N * N).sum())
    sin_e = float(np.clip((N * axis).sum(), -1, 1))
    cross = np.cross(N, axis)
    cos_e = float(np.sqrt((cross * cross).sum()))
    s = float(_LD(r) / d)
    sigma = math.asin(min(s, 1.0))
    one_minus_cos = s * s / (1.0 + math.sqrt(max((1.0 - s) * (1.0 + s), 0.0)))
    Om = 2.0 * math.pi * one_minus_cos
    e = abs(math.atan2(sin_e, cos_e))                 # kink at α = |elevation|
    refine = [np.array([e])] if e < sigma else []
    br = _graded(np.array([0.0]), np.array([max(sigma, 1e-300)]), np.array([0.0]), np.array([sigma]),
                 refine=refine)
    a, w = _nodes(br)
    a, w = a[0], w[0]
    A = sin_e * np.cos(a)
    B = cos_e * np.sin(a)
    full = A >= B
    part = (A < B) & (A > -B)
    Bs = np.where(B > 0.0, B, 1.0)
    phi0 = np.arccos(np.clip(-A / Bs, -1.0, 1.0))
    H = np.where(full, 2.0 * math.pi * A, np.where(part, 2.0 * (A * phi0 + B * np.sin(phi0)), 0.0))
    G = float((np.sin(a) * H * w).sum())
    return max(G, 0.0), Om


__all__ = ["rect_G", "disk_G", "sphere_G"]
