"""Per-row kernels of the cylinder lights (``renderer/lights/cylinder.py``): facing-band and line
sampling, the matching pdf, and the exact ray / side intersection.

Conventions as in ``renderer.kernels``; the formulas and guards are those documented in the
cylinder module (its numpy helpers ``_jacobian``, ``_world_normal``, ``_param_pdf`` state them).
Each light is one packed row of a float64 table (``CylinderLight.packed``, columns ``CY_*``):
center (3), m3, m3_inv, normal_m (3 x 3 each, row-major), a, b1, b2 (3 each), radius, half,
L (3) and delta (1.0 for a line light). The row functions read light j of a table T from column
offset o, T[j, o + CY_*]: the light's own kernels below pass the packed table (o = 0), and the
fast path's vertex kernel (renderer/integrators/_vertex_kernels.py) its light table, where a
cylinder's row carries the packed row from column LP_CY: one formula for both routes.
"""

from __future__ import annotations

import math

from numba import njit

CY_C = 0
CY_M3 = 3
CY_MI = 12
CY_NM = 21
CY_A = 30
CY_B1 = 33
CY_B2 = 36
CY_R = 39
CY_H = 40
CY_L = 41
CY_DELTA = 44
NCY = 45


@njit(cache=True, nogil=True)
def _mat_vec(T, j, c, v):
    """The 3 x 3 matrix stored row-major at T[j, c:c + 9] times v."""
    return (T[j, c] * v[0] + T[j, c + 1] * v[1] + T[j, c + 2] * v[2],
            T[j, c + 3] * v[0] + T[j, c + 4] * v[1] + T[j, c + 5] * v[2],
            T[j, c + 6] * v[0] + T[j, c + 7] * v[1] + T[j, c + 8] * v[2])


@njit(cache=True, nogil=True)
def _vec(T, j, c):
    return (T[j, c], T[j, c + 1], T[j, c + 2])


@njit(cache=True, nogil=True)
def _row(a, r):
    return (a[r, 0], a[r, 1], a[r, 2])


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
def _jacobian(T, j, o, phi):
    """|a x (-sin phi b1 + cos phi b2)|: world area per unit (s, phi)."""
    s, c = math.sin(phi), math.cos(phi)
    b1 = o + CY_B1
    b2 = o + CY_B2
    t = (-s * T[j, b1] + c * T[j, b2], -s * T[j, b1 + 1] + c * T[j, b2 + 1], -s * T[j, b1 + 2] + c * T[j, b2 + 2])
    x = _cross(_vec(T, j, o + CY_A), t)
    return math.sqrt(_dot(x, x))


@njit(cache=True, nogil=True)
def _world_normal(T, j, o, phi):
    n = _mat_vec(T, j, o + CY_NM, (0.0, math.cos(phi), math.sin(phi)))
    ln = math.sqrt(_dot(n, n))
    if ln > 0.0:
        return (n[0] / ln, n[1] / ln, n[2] / ln)
    return n


@njit(cache=True, nogil=True)
def _lateral(rho, r, psi):
    sh = math.sin(0.5 * psi)
    return math.sqrt((rho - r) * (rho - r) + 4.0 * rho * r * sh * sh)


@njit(cache=True, nogil=True)
def _param_pdf(s, psi, s_p, rho, r, hl):
    """Density of (s, phi) under the facing-band sampler (0 outside its support)."""
    ratio = min(max(r / rho, 0.0), 1.0) if rho > 0.0 else 1.0
    alpha_max = math.asin(ratio)
    h = _lateral(rho, r, psi)
    cosn = rho * math.cos(psi) - r
    if not (alpha_max > 0.0 and h > 0.0 and cosn > 0.0):
        return 0.0
    pdf_phi = r * cosn / (2.0 * alpha_max * h * h)
    span = math.atan2(hl - s_p, h) - math.atan2(-hl - s_p, h)
    if not (span > 0.0):
        return 0.0
    ds = s - s_p
    return pdf_phi * h / (span * (h * h + ds * ds))


@njit(cache=True, nogil=True)
def _solid_angle_pdf(T, j, o, pdf_param, phi, w, dist):
    n = _world_normal(T, j, o, phi)
    cos_l = -_dot(w, n)
    J = _jacobian(T, j, o, phi)
    if not (cos_l > 0.0 and J > 0.0 and pdf_param > 0.0 and math.isfinite(dist)):
        return 0.0
    out = pdf_param * dist * dist / (J * cos_l)
    return out if math.isfinite(out) else 0.0


@njit(cache=True, nogil=True)
def _frame(T, j, o, p, r):
    """(s_p, rho, phi_p, outside) of p in light j's local frame."""
    pl = _mat_vec(T, j, o + CY_MI, _sub(p, _vec(T, j, o + CY_C)))
    rho = math.hypot(pl[1], pl[2])
    return pl[0], rho, math.atan2(pl[2], pl[1]), rho > r * (1.0 + 1e-12)


@njit(cache=True, nogil=True)
def cylinder_sample_row(T, j, o, pr, u0, u1):
    """Light j's sample from pr with uniforms (u0, u1): (L (3-tuple), wi, pdf, dist, x (the point on
    the light)). Facing-band sampling of tubes, equiangular segment sampling of line lights (pdf 1
    and L = I_lin (theta_b - theta_a) / d, the delta-light convention). A failed sample has pdf 0
    and L 0."""
    none = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 0.0, 0.0, pr)
    c = _vec(T, j, o + CY_C)
    Lrad = _vec(T, j, o + CY_L)
    if T[j, o + CY_DELTA] != 0.0:
        ax = _vec(T, j, o + CY_A)
        la = math.sqrt(_dot(ax, ax))
        if not (la > 0.0):
            return none
        ah = (ax[0] / la, ax[1] / la, ax[2] / la)
        hl = T[j, o + CY_H] * la
        rel = _sub(pr, c)
        s_p = _dot(rel, ah)
        perp = (rel[0] - s_p * ah[0], rel[1] - s_p * ah[1], rel[2] - s_p * ah[2])
        h = math.sqrt(_dot(perp, perp))
        if not (h > 1e-12 * max(hl, 1e-300)):
            return none
        th_a = math.atan2(-hl - s_p, h)
        th_b = math.atan2(hl - s_p, h)
        theta = th_a + u0 * (th_b - th_a)
        s = min(max(s_p + h * math.tan(theta), -hl), hl)
        x = (c[0] + s * ah[0], c[1] + s * ah[1], c[2] + s * ah[2])
        v = _sub(x, pr)
        d = math.sqrt(_dot(v, v))
        if not (d > 0.0):
            return none
        k = (th_b - th_a) / d
        return (Lrad[0] * k, Lrad[1] * k, Lrad[2] * k), (v[0] / d, v[1] / d, v[2] / d), 1.0, d, x
    rad = T[j, o + CY_R]
    hl = T[j, o + CY_H]
    s_p, rho, phi_p, outside = _frame(T, j, o, pr, rad)
    if not outside:
        return none
    ratio = min(max(rad / rho, 0.0), 1.0)
    alpha = (2.0 * u0 - 1.0) * math.asin(ratio)
    sa, ca = math.sin(alpha), math.cos(alpha)
    root = math.sqrt(max(rad * rad - (rho * sa) * (rho * sa), 0.0))
    # Near hit of the 2-D ray with the circle, cancellation-free (see the cylinder module).
    t2 = (rho - rad) * (rho + rad) / max(rho * ca + root, 1e-300)
    psi = math.atan2(sa * t2, rho * sa * sa + root * ca)
    h = _lateral(rho, rad, psi)
    hs = h if h > 0.0 else 1.0
    th_a = math.atan2(-hl - s_p, hs)
    th_b = math.atan2(hl - s_p, hs)
    theta = th_a + u1 * (th_b - th_a)
    s = min(max(s_p + h * math.tan(theta), -hl), hl)
    phi = phi_p + psi
    xw = _mat_vec(T, j, o + CY_M3, (s, rad * math.cos(phi), rad * math.sin(phi)))
    x = (c[0] + xw[0], c[1] + xw[1], c[2] + xw[2])
    v = _sub(x, pr)
    d = math.sqrt(_dot(v, v))
    if not (d > 0.0):
        return none
    w = (v[0] / d, v[1] / d, v[2] / d)
    pw = _solid_angle_pdf(T, j, o, _param_pdf(s, psi, s_p, rho, rad, hl), phi, w, d)
    if not (pw > 0.0):
        return none
    return Lrad, w, pw, d, x


@njit(cache=True, nogil=True)
def cylinder_front_hit_row(T, j, o, pr, w):
    """The ray pr + t w's crossing of light j's side from outside onto its emitting face:
    (t, s, phi), t = inf where there is none (pr inside, moving away, past the ends, a line)."""
    if T[j, o + CY_DELTA] != 0.0:
        return math.inf, 0.0, 0.0
    rad = T[j, o + CY_R]
    ol = _mat_vec(T, j, o + CY_MI, _sub(pr, _vec(T, j, o + CY_C)))
    dl = _mat_vec(T, j, o + CY_MI, w)
    qa = dl[1] * dl[1] + dl[2] * dl[2]
    qb = ol[1] * dl[1] + ol[2] * dl[2]
    rr = math.hypot(ol[1], ol[2])
    qc = (rr - rad) * (rr + rad)
    disc = qb * qb - qa * qc
    if not (qa > 0.0 and qc > 0.0 and qb < 0.0 and disc >= 0.0 and rr > rad * (1.0 + 1e-12)):
        return math.inf, 0.0, 0.0
    q = -qb + math.sqrt(disc)
    t = min(qc / q, q / qa)
    s = ol[0] + t * dl[0]
    if abs(s) > T[j, o + CY_H]:
        return math.inf, 0.0, 0.0
    return t, s, math.atan2(ol[2] + t * dl[2], ol[1] + t * dl[1])


@njit(cache=True, nogil=True)
def cylinder_pdf_row(T, j, o, pr, w):
    """pdf of light j's sampler from pr producing w: the densities at the side's front crossing
    (0: miss, inside, line)."""
    t, s, phi = cylinder_front_hit_row(T, j, o, pr, w)
    if not (t < math.inf):
        return 0.0
    rad = T[j, o + CY_R]
    s_p, rho, phi_p, _outside = _frame(T, j, o, pr, rad)
    psi = phi - phi_p
    psi = math.atan2(math.sin(psi), math.cos(psi))  # wrapped to (-pi, pi]
    return _solid_angle_pdf(T, j, o, _param_pdf(s, psi, s_p, rho, rad, T[j, o + CY_H]), phi, w, t)


@njit(cache=True, nogil=True, inline="always")
def _store(r, L, k, w, pdf, d, x, out_L, out_wi, out_pdf, out_dist, out_p):
    """Write row r of a light sample: radiance L (3-tuple or row) times k, direction w,
    pdf, distance d and the point x on the light."""
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
def cylinder_sample_kernel(idx, p, u, packed, out_L, out_wi, out_pdf, out_dist, out_p):
    """cylinder_sample_row for rows (light idx[r], point p[r], uniforms u[r]) of the packed
    table. Failed rows: pdf 0, L 0."""
    for r in range(idx.shape[0]):
        L, w, pdf, d, x = cylinder_sample_row(packed, idx[r], 0, _row(p, r), u[r, 0], u[r, 1])
        _store(r, L, 1.0, w, pdf, d, x, out_L, out_wi, out_pdf, out_dist, out_p)


@njit(cache=True, nogil=True)
def cylinder_pdf_kernel(idx, p, wi, packed, out_pdf):
    """cylinder_pdf_row for rows (light idx[r], point p[r], direction wi[r])."""
    for r in range(idx.shape[0]):
        out_pdf[r] = cylinder_pdf_row(packed, idx[r], 0, _row(p, r), _row(wi, r))
