"""Per-row kernels of the cylinder lights (``renderer/lights/cylinder.py``): facing-band and line
sampling, the matching pdf, and the exact ray / side intersection.

Conventions as in ``renderer.kernels``; the formulas and guards are those documented in the
cylinder module (its numpy helpers ``_jacobian``, ``_world_normal``, ``_param_pdf`` state them).
Per-light tables: center (k, 3); m3, m3_inv, normal_m (k, 3, 3); a, b1, b2 (k, 3); radius,
half (k,); L (k, 3); delta (k,) bool (line lights).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True)
def _mat_vec(m, li, v):
    return (m[li, 0, 0] * v[0] + m[li, 0, 1] * v[1] + m[li, 0, 2] * v[2],
            m[li, 1, 0] * v[0] + m[li, 1, 1] * v[1] + m[li, 1, 2] * v[2],
            m[li, 2, 0] * v[0] + m[li, 2, 1] * v[1] + m[li, 2, 2] * v[2])


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
def _jacobian(a, b1, b2, li, phi):
    """|a x (-sin phi b1 + cos phi b2)|: world area per unit (s, phi)."""
    s, c = math.sin(phi), math.cos(phi)
    t = (-s * b1[li, 0] + c * b2[li, 0], -s * b1[li, 1] + c * b2[li, 1], -s * b1[li, 2] + c * b2[li, 2])
    x = _cross(_row(a, li), t)
    return math.sqrt(_dot(x, x))


@njit(cache=True, nogil=True)
def _world_normal(normal_m, li, phi):
    n = _mat_vec(normal_m, li, (0.0, math.cos(phi), math.sin(phi)))
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
def _solid_angle_pdf(a, b1, b2, normal_m, li, pdf_param, phi, w, dist):
    n = _world_normal(normal_m, li, phi)
    cos_l = -_dot(w, n)
    J = _jacobian(a, b1, b2, li, phi)
    if not (cos_l > 0.0 and J > 0.0 and pdf_param > 0.0 and math.isfinite(dist)):
        return 0.0
    out = pdf_param * dist * dist / (J * cos_l)
    return out if math.isfinite(out) else 0.0


@njit(cache=True, nogil=True)
def _frame(m3_inv, center, li, p, r):
    """(s_p, rho, phi_p, outside) of p in light li's local frame."""
    pl = _mat_vec(m3_inv, li, _sub(p, _row(center, li)))
    rho = math.hypot(pl[1], pl[2])
    return pl[0], rho, math.atan2(pl[2], pl[1]), rho > r * (1.0 + 1e-12)


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
def cylinder_sample_kernel(idx, p, u, center, m3, m3_inv, normal_m, a, b1, b2, radius, half, Lrad, delta,
                           out_L, out_wi, out_pdf, out_dist, out_p):
    """Facing-band sampling of tubes, equiangular segment sampling of line lights (pdf 1 and
    L = I_lin (theta_b - theta_a) / d, the delta-light convention). Failed rows: pdf 0, L 0."""
    for r in range(idx.shape[0]):
        li = idx[r]
        pr = _row(p, r)
        _store(r, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 1.0), 0.0, 0.0, pr, out_L, out_wi, out_pdf, out_dist, out_p)
        c = _row(center, li)
        if delta[li]:
            ax = _row(a, li)
            la = math.sqrt(_dot(ax, ax))
            if not (la > 0.0):
                continue
            ah = (ax[0] / la, ax[1] / la, ax[2] / la)
            hl = half[li] * la
            rel = _sub(pr, c)
            s_p = _dot(rel, ah)
            perp = (rel[0] - s_p * ah[0], rel[1] - s_p * ah[1], rel[2] - s_p * ah[2])
            h = math.sqrt(_dot(perp, perp))
            if not (h > 1e-12 * max(hl, 1e-300)):
                continue
            th_a = math.atan2(-hl - s_p, h)
            th_b = math.atan2(hl - s_p, h)
            theta = th_a + u[r, 0] * (th_b - th_a)
            s = min(max(s_p + h * math.tan(theta), -hl), hl)
            x = (c[0] + s * ah[0], c[1] + s * ah[1], c[2] + s * ah[2])
            v = _sub(x, pr)
            d = math.sqrt(_dot(v, v))
            if not (d > 0.0):
                continue
            w = (v[0] / d, v[1] / d, v[2] / d)
            _store(r, _row(Lrad, li), (th_b - th_a) / d, w, 1.0, d, x, out_L, out_wi, out_pdf, out_dist, out_p)
            continue
        rad = radius[li]
        hl = half[li]
        s_p, rho, phi_p, outside = _frame(m3_inv, center, li, pr, rad)
        if not outside:
            continue
        ratio = min(max(rad / rho, 0.0), 1.0)
        alpha = (2.0 * u[r, 0] - 1.0) * math.asin(ratio)
        sa, ca = math.sin(alpha), math.cos(alpha)
        root = math.sqrt(max(rad * rad - (rho * sa) * (rho * sa), 0.0))
        # Near hit of the 2-D ray with the circle, cancellation-free (see the cylinder module).
        t2 = (rho - rad) * (rho + rad) / max(rho * ca + root, 1e-300)
        psi = math.atan2(sa * t2, rho * sa * sa + root * ca)
        h = _lateral(rho, rad, psi)
        hs = h if h > 0.0 else 1.0
        th_a = math.atan2(-hl - s_p, hs)
        th_b = math.atan2(hl - s_p, hs)
        theta = th_a + u[r, 1] * (th_b - th_a)
        s = min(max(s_p + h * math.tan(theta), -hl), hl)
        phi = phi_p + psi
        xl = (s, rad * math.cos(phi), rad * math.sin(phi))
        xw = _mat_vec(m3, li, xl)
        x = (c[0] + xw[0], c[1] + xw[1], c[2] + xw[2])
        v = _sub(x, pr)
        d = math.sqrt(_dot(v, v))
        if not (d > 0.0):
            continue
        w = (v[0] / d, v[1] / d, v[2] / d)
        pw = _solid_angle_pdf(a, b1, b2, normal_m, li, _param_pdf(s, psi, s_p, rho, rad, hl), phi, w, d)
        if not (pw > 0.0):
            continue
        _store(r, _row(Lrad, li), 1.0, w, pw, d, x, out_L, out_wi, out_pdf, out_dist, out_p)


@njit(cache=True, nogil=True)
def cylinder_pdf_kernel(idx, p, wi, center, m3_inv, normal_m, a, b1, b2, radius, half, delta, out_pdf):
    """pdf of sampling wi: the densities at the side's front crossing (0: miss, inside, line)."""
    for r in range(idx.shape[0]):
        li = idx[r]
        out_pdf[r] = 0.0
        if delta[li]:
            continue
        rad = radius[li]
        hl = half[li]
        pr = _row(p, r)
        w = _row(wi, r)
        s_p, rho, phi_p, outside = _frame(m3_inv, center, li, pr, rad)
        if not outside:
            continue
        ol = _mat_vec(m3_inv, li, _sub(pr, _row(center, li)))
        dl = _mat_vec(m3_inv, li, w)
        qa = dl[1] * dl[1] + dl[2] * dl[2]
        qb = ol[1] * dl[1] + ol[2] * dl[2]
        rr = math.hypot(ol[1], ol[2])
        qc = (rr - rad) * (rr + rad)
        disc = qb * qb - qa * qc
        if not (qa > 0.0 and qc > 0.0 and qb < 0.0 and disc >= 0.0):
            continue
        q = -qb + math.sqrt(disc)
        t = min(qc / q, q / qa)
        s = ol[0] + t * dl[0]
        if abs(s) > hl:
            continue
        phi = math.atan2(ol[2] + t * dl[2], ol[1] + t * dl[1])
        psi = phi - phi_p
        psi = math.atan2(math.sin(psi), math.cos(psi))  # wrapped to (-pi, pi]
        out_pdf[r] = _solid_angle_pdf(a, b1, b2, normal_m, li, _param_pdf(s, psi, s_p, rho, rad, hl), phi, w, t)
