"""Per-row kernels of the portal-angle luminance tables (``renderer/lights/portal.py``): window
integrals and windowed sampling, the same maths as that module's numpy reference functions.

Conventions as in ``renderer.kernels``. Tables: sat (T, N+1, N+1) prefix integrals over
[-pi/2, alpha_i] x [-pi/2, beta_j], col (T, N, N+1) prefix integrals along beta per alpha
column; the grid spacing is pi / N.

The second half is a dome's whole portal sampling per row (renderer/lights/dome.py's module
docstring states the rule): each portal's window and pick weight from a point, the mixture of
the portal part and the dome's own sampling, and its density. DomeLight.sample_li and pdf_li
run these rows (``portal_dome_sample_kernel``, ``portal_dome_pdf_kernel``), and so does the
compiled path's vertex kernel (renderer/integrators/_vertex_kernels.py), on the two arrays
DomeLight.portal_record() builds (PP_* columns).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.kernels import guard_cache, module_dispatchers
from renderer.kernels.lights import (
    _BELOW_ONE, _dir_dist, _dome_sample_row, _dome_texel_row, _sr_frame, _sr_sample, _sr_setup, _uniform_sphere_row,
)

_HALF_PI = 0.5 * math.pi
_INV_4PI = 0.25 / math.pi


@njit(cache=True, nogil=True)
def _coord(x, n):
    delta = math.pi / n
    u = (x + _HALF_PI) / delta
    u = min(max(u, 0.0), float(n))
    i = min(int(math.floor(u)), n - 1)
    return i, u - i


@njit(cache=True, nogil=True)
def _prefix(sat, t, a, b, n):
    i, fa = _coord(a, n)
    j, fb = _coord(b, n)
    return ((1.0 - fa) * (1.0 - fb) * sat[t, i, j] + fa * (1.0 - fb) * sat[t, i + 1, j]
            + (1.0 - fa) * fb * sat[t, i, j + 1] + fa * fb * sat[t, i + 1, j + 1])


@njit(cache=True, nogil=True)
def _column(col, t, i, b, n):
    j, fb = _coord(b, n)
    return (1.0 - fb) * col[t, i, j] + fb * col[t, i, j + 1]


@njit(cache=True, nogil=True)
def window_integral_row(sat, t, a0, a1, b0, b1):
    """The integral of table t over the window [a0, a1] x [b0, b1]."""
    n = sat.shape[1] - 1
    return (_prefix(sat, t, a1, b1, n) - _prefix(sat, t, a0, b1, n)
            - _prefix(sat, t, a1, b0, n) + _prefix(sat, t, a0, b0, n))


@njit(cache=True, nogil=True)
def window_integral_kernel(sat, t, a0, a1, b0, b1, out):
    """out[r] = integral of table t[r] over [a0, a1] x [b0, b1] (row r)."""
    for r in range(t.shape[0]):
        out[r] = window_integral_row(sat, t[r], a0[r], a1[r], b0[r], b1[r])


@njit(cache=True, nogil=True)
def window_sample_kernel(sat, col, t, a0, a1, b0, b1, u, out_alpha, out_beta):
    """(alpha, beta) distributed as table t[r] restricted to the row's window, from u[r, :2]
    (window_sample_row per row)."""
    for r in range(t.shape[0]):
        out_alpha[r], out_beta[r] = window_sample_row(sat, t[r], col, t[r], a0[r], a1[r], b0[r], b1[r], u[r, 0],
                                                      u[r, 1])


@njit(cache=True, nogil=True)
def window_sample_row(sat, tr, col, tc, lo, hi, blo, bhi, u0, u1):
    """(alpha, beta) distributed as the table whose prefix tables are sat[tr] and col[tc],
    restricted to the window [lo, hi] x [blo, bhi], from (u0, u1).

    The marginal over alpha and the conditional over beta are piecewise linear with a piece per
    grid cell: bisection over the cell boundaries inside the window, then the linear piece.
    """
    n = sat.shape[1] - 1
    delta = math.pi / n
    base = _prefix(sat, tr, lo, bhi, n) - _prefix(sat, tr, lo, blo, n)
    total = _prefix(sat, tr, hi, bhi, n) - _prefix(sat, tr, hi, blo, n) - base
    target = u0 * total
    # ---- alpha: the marginal M(a) = T(a, bhi) - T(a, blo) - base is non-decreasing.
    ilo = int(math.floor((lo + _HALF_PI) / delta))
    ihi = int(math.ceil((hi + _HALF_PI) / delta))
    while ihi - ilo > 1:
        mid = (ilo + ihi) // 2
        x = min(max(-_HALF_PI + mid * delta, lo), hi)
        if _prefix(sat, tr, x, bhi, n) - _prefix(sat, tr, x, blo, n) - base <= target:
            ilo = mid
        else:
            ihi = mid
    left = min(max(-_HALF_PI + ilo * delta, lo), hi)
    right = min(max(-_HALF_PI + ihi * delta, lo), hi)
    v0 = _prefix(sat, tr, left, bhi, n) - _prefix(sat, tr, left, blo, n) - base
    v1 = _prefix(sat, tr, right, bhi, n) - _prefix(sat, tr, right, blo, n) - base
    frac = (target - v0) / (v1 - v0) if v1 > v0 else 0.0
    alpha = left + min(max(frac, 0.0), 1.0) * (right - left)
    alpha = min(max(alpha, lo), hi)
    # ---- beta, in alpha's column: G(b) = C(b) - C(blo).
    i, _ = _coord(alpha, n)
    c0 = _column(col, tc, i, blo, n)
    target = u1 * (_column(col, tc, i, bhi, n) - c0)
    jlo = int(math.floor((blo + _HALF_PI) / delta))
    jhi = int(math.ceil((bhi + _HALF_PI) / delta))
    while jhi - jlo > 1:
        mid = (jlo + jhi) // 2
        y = min(max(-_HALF_PI + mid * delta, blo), bhi)
        if _column(col, tc, i, y, n) - c0 <= target:
            jlo = mid
        else:
            jhi = mid
    left = min(max(-_HALF_PI + jlo * delta, blo), bhi)
    right = min(max(-_HALF_PI + jhi * delta, blo), bhi)
    v0 = _column(col, tc, i, left, n) - c0
    v1 = _column(col, tc, i, right, n) - c0
    frac = (target - v0) / (v1 - v0) if v1 > v0 else 0.0
    beta = left + min(max(frac, 0.0), 1.0) * (right - left)
    return alpha, min(max(beta, blo), bhi)


# --------------------------------------------------------------------------------------
# A dome's portal sampling, per row (DomeLight's rule, renderer/lights/dome.py). The record is
# two arrays (DomeLight.portal_record; few arrays, since numba counts references per array each
# call that passes them): PP (P, NPP) a row per portal, columns PP_* (centre, full edges ex, ey,
# frame rows x, y, z out of the room, half sizes, windowed table or -1 for a constant dome's
# portal, the dome's share of samples drawn through its portals), and PT (3 T, N + 1, N + 1)
# the windowed tables of renderer/lights/portal.py, table t as f at 3 t (N x N used), sat at
# 3 t + 1 and col at 3 t + 2 (N x (N + 1) used). A dome's portals are rows first .. first +
# count - 1.
# --------------------------------------------------------------------------------------
PP_C = 0
PP_EX = 3
PP_EY = 6
PP_FR = 9  # rows x, y, z: 9 columns
PP_HALF = 18
PP_TABLE = 20
PP_FRACTION = 21
NPP = 22


@njit(cache=True, nogil=True)
def _pp3(PP, k, c):
    """Columns c..c+2 of portal row k as a 3-tuple."""
    return (PP[k, c], PP[k, c + 1], PP[k, c + 2])


@njit(cache=True, nogil=True)
def _to_portal(PP, k, v):
    """v in portal k's frame (its rows x, y, z applied to v)."""
    x = _pp3(PP, k, PP_FR)
    y = _pp3(PP, k, PP_FR + 3)
    z = _pp3(PP, k, PP_FR + 6)
    return (x[0] * v[0] + x[1] * v[1] + x[2] * v[2], y[0] * v[0] + y[1] * v[1] + y[2] * v[2],
            z[0] * v[0] + z[1] * v[1] + z[2] * v[2])


@njit(cache=True, nogil=True)
def inverse_jacobian_row(alpha, beta):
    """d alpha d beta / d omega at (alpha, beta): 1 / J, J = sec^2 alpha sec^2 beta / (1 + tan^2 alpha
    + tan^2 beta)^(3/2) (0 at the window's +-pi/2 edges, where J is infinite)."""
    ta = math.tan(alpha)
    tb = math.tan(beta)
    ca = math.cos(alpha)
    cb = math.cos(beta)
    return ca * ca * cb * cb * (1.0 + ta * ta + tb * tb) ** 1.5


@njit(cache=True, nogil=True)
def jacobian_kernel(alpha, beta, out):
    """out[r] = J(alpha[r], beta[r]) = 1 / inverse_jacobian_row (0 where that is 0)."""
    for r in range(alpha.shape[0]):
        den = inverse_jacobian_row(alpha[r], beta[r])
        out[r] = 1.0 / den if den > 0.0 else 0.0


@njit(cache=True, nogil=True)
def portal_window_row(PP, PT, k, p, min_sa, graz):
    """Portal k seen from p (3-tuple): (weight, a0, a1, b0, b1), the window [a0, a1] x [b0, b1]
    of the portal-angle directions through it and its pick weight: the solid angle for a
    constant dome's portal (0 unless the spherical rectangle is usable: min_sa, graz as for rect
    lights), the window's luminance integral for a textured one's; 0 from the exterior side."""
    c = _pp3(PP, k, PP_C)
    rel = _to_portal(PP, k, (p[0] - c[0], p[1] - c[1], p[2] - c[2]))
    dz = -rel[2]
    inside = dz > 0.0
    dzs = dz if inside else 1.0
    ha = PP[k, PP_HALF]
    hb = PP[k, PP_HALF + 1]
    a0 = math.atan2(-ha - rel[0], dzs)
    a1 = math.atan2(ha - rel[0], dzs)
    b0 = math.atan2(-hb - rel[1], dzs)
    b1 = math.atan2(hb - rel[1], dzs)
    weight = 0.0
    if inside:
        t = int(PP[k, PP_TABLE])
        if t < 0:
            # Constant dome: uniform in the portal's solid angle (the spherical rectangle).
            st = _portal_rect(PP, k, p, min_sa, graz)
            weight = st[13] if st[14] else 0.0
        else:
            W = window_integral_row(PT, 3 * t + 1, a0, a1, b0, b1)
            weight = W if (W > 0.0 and math.isfinite(W)) else 0.0
    return weight, a0, a1, b0, b1


@njit(cache=True, nogil=True)
def _portal_rect(PP, k, p, min_sa, graz):
    """kernels/lights._sr_setup of portal k's rectangle seen from p."""
    c = _pp3(PP, k, PP_C)
    e1 = _pp3(PP, k, PP_EX)
    e2 = _pp3(PP, k, PP_EY)
    x_hat, y_hat, lx, ly = _sr_frame(e1, e2)
    corner = (c[0] - 0.5 * e1[0] - 0.5 * e2[0], c[1] - 0.5 * e1[1] - 0.5 * e2[1], c[2] - 0.5 * e1[2] - 0.5 * e2[2])
    return _sr_setup(p, corner, x_hat, y_hat, lx, ly, min_sa, graz)


@njit(cache=True, nogil=True)
def portal_total_row(PP, PT, first, count, p, min_sa, graz):
    """The summed pick weight of a dome's portals (rows first .. first + count - 1) from p (0:
    no portal usable, the dome samples as without portals)."""
    total = 0.0
    for k in range(first, first + count):
        total += portal_window_row(PP, PT, k, p, min_sa, graz)[0]
    return total


@njit(cache=True, nogil=True)
def portal_part_pdf_row(PP, PT, first, count, p, wi, total, min_sa, graz):
    """The portal part's solid-angle density along unit wi from p: over the usable portals wi
    passes, 1 for a constant dome's and f / J for a textured one's, divided by the total weight."""
    if not total > 0.0:
        return 0.0
    s = 0.0
    for k in range(first, first + count):
        weight, a0, a1, b0, b1 = portal_window_row(PP, PT, k, p, min_sa, graz)
        w = _to_portal(PP, k, wi)
        if not (weight > 0.0 and w[2] > 0.0):
            continue
        alpha = math.atan2(w[0], w[2])
        beta = math.atan2(w[1], w[2])
        if not (a0 <= alpha <= a1 and b0 <= beta <= b1):
            continue
        t = int(PP[k, PP_TABLE])
        if t < 0:
            s += 1.0
        else:
            # f_t / J at the cell of (alpha, beta) (f at PT[3 t], N x N).
            n = PT.shape[1] - 1
            i, _ = _coord(alpha, n)
            jj, _ = _coord(beta, n)
            s += PT[3 * t, i, jj] * inverse_jacobian_row(alpha, beta)
    return s / total


@njit(cache=True, nogil=True)
def portal_part_sample_row(PP, PT, first, count, p, u0, u1, total, min_sa, graz):
    """A direction through a dome's portals from p: a usable portal picked in proportion to
    its weight by u0 (remapped within the pick), then a direction through it (the spherical
    rectangle for a constant dome, the windowed table for a textured one) by (u0', u1).
    (wi, good): good False where no direction came out (the caller keeps the dome's own)."""
    last = first + count - 1
    target = u0 * total
    # The first portal whose running weight passes the target (the last one if rounding runs
    # past it), and the weight before it.
    pick = last
    prev = 0.0
    cum = 0.0
    for k in range(first, last + 1):
        prev = cum
        cum += portal_window_row(PP, PT, k, p, min_sa, graz)[0]
        if cum > target:
            pick = k
            break
    weight, a0, a1, b0, b1 = portal_window_row(PP, PT, pick, p, min_sa, graz)
    u_in = min(max((target - prev) / (weight if weight > 0.0 else 1.0), 0.0), _BELOW_ONE)
    if not weight > 0.0:
        return (0.0, 0.0, 0.0), False
    t = int(PP[pick, PP_TABLE])
    if t < 0:
        wi, d = _dir_dist(p, _sr_sample(p, _portal_rect(PP, pick, p, min_sa, graz), u_in, u1))
        return wi, d > 0.0
    alpha, beta = window_sample_row(PT, 3 * t + 1, PT, 3 * t + 2, a0, a1, b0, b1, u_in, u1)
    lx = math.tan(alpha)
    ly = math.tan(beta)
    inv = 1.0 / math.sqrt(lx * lx + ly * ly + 1.0)
    # frame^T local (the frame's rows are the portal's axes in world space).
    x = _pp3(PP, pick, PP_FR)
    y = _pp3(PP, pick, PP_FR + 3)
    z = _pp3(PP, pick, PP_FR + 6)
    wi = ((x[0] * lx + y[0] * ly + z[0]) * inv, (x[1] * lx + y[1] * ly + z[1]) * inv,
          (x[2] * lx + y[2] * ly + z[2]) * inv)
    return wi, True


@njit(cache=True, nogil=True)
def _dome_own_pdf(wi, tex, rot, im_height, im_width, im_weight, im_total, im_offset):
    """The dome's own sampling's pdf along wi and the texel wi meets (-1 for a constant dome)."""
    if tex < 0:
        return _INV_4PI, -1
    return _dome_texel_row(wi, tex, rot, im_height, im_width, im_weight, im_total, im_offset)


@njit(cache=True, nogil=True)
def _mixture(PP, PT, first, count, p, wi, pdf_d, total, min_sa, graz):
    """f * the portal part's density + (1 - f) * the dome's own pdf_d where a portal is usable
    from p (total > 0), else pdf_d."""
    if not total > 0.0:
        return pdf_d
    f = PP[first, PP_FRACTION]
    part = portal_part_pdf_row(PP, PT, first, count, p, wi, total, min_sa, graz)
    return f * part + ((1.0 - f) * pdf_d if f < 1.0 else 0.0)


@njit(cache=True, nogil=True)
def portal_dome_pdf_row(PP, PT, first, count, p, wi, tex, rot, im_height, im_width, im_weight, im_total, im_offset,
                        min_sa, graz):
    """DomeLight.pdf_li of a dome with portals (rows first .. first + count - 1) from p along
    unit wi: f * the portal part's density + (1 - f) * the dome's own where a portal is usable
    from p, else the dome's own (tex: its image or -1, rot its local -> world rotation, im_*:
    the domes' ImageSet). Returns (pdf, texel wi meets or -1)."""
    pdf_d, kt = _dome_own_pdf(wi, tex, rot, im_height, im_width, im_weight, im_total, im_offset)
    total = portal_total_row(PP, PT, first, count, p, min_sa, graz)
    return _mixture(PP, PT, first, count, p, wi, pdf_d, total, min_sa, graz), kt


@njit(cache=True, nogil=True)
def portal_dome_sample_row(PP, PT, first, count, p, u0, u1, tex, rot, im_height, im_width, im_row_cdf,
                           im_row_cdf_start, im_col_cdf, im_col_cdf_start, im_weight, im_total, im_offset, min_sa,
                           graz):
    """DomeLight.sample_li of a dome with portals from p with (u0, u1): through the portals
    with probability f where one is usable from p (u0 < f), else the dome's own sampling, u0
    remapped to [0, 1) within the branch taken. Returns (wi, pdf, texel wi meets or -1): pdf the
    mixture's density at wi (portal_dome_pdf_row's); the radiance is the dome's along wi."""
    total = portal_total_row(PP, PT, first, count, p, min_sa, graz)
    f = PP[first, PP_FRACTION] if total > 0.0 else 0.0
    through = u0 < f
    if through:
        u0 = u0 / (f if f > 0.0 else 1.0)
    else:
        u0 = (u0 - f) / (1.0 - f if f < 1.0 else 1.0)
    u0 = min(max(u0, 0.0), _BELOW_ONE)
    # The dome's own sample, drawn either way (DomeLight.sample_li keeps it where the portal
    # sample fails).
    if tex >= 0:
        wi, _pdf, _kt = _dome_sample_row(u0, u1, tex, rot, im_height, im_width, im_row_cdf, im_row_cdf_start,
                                         im_col_cdf, im_col_cdf_start, im_weight, im_total, im_offset)
    else:
        wi = _uniform_sphere_row(u0, u1)
    if through:
        w, good = portal_part_sample_row(PP, PT, first, count, p, u0, u1, total, min_sa, graz)
        if good:
            wi = w
    pdf_d, kt = _dome_own_pdf(wi, tex, rot, im_height, im_width, im_weight, im_total, im_offset)
    return wi, _mixture(PP, PT, first, count, p, wi, pdf_d, total, min_sa, graz), kt


@njit(cache=True, nogil=True)
def portal_dome_sample_kernel(idx, p, u, PP, PT, start, count, tex, rot, im_height, im_width, im_row_cdf,
                              im_row_cdf_start, im_col_cdf, im_col_cdf_start, im_weight, im_total, im_offset, min_sa,
                              graz, out_wi, out_pdf, out_kt):
    """portal_dome_sample_row for rows of domes idx (n,) with portals (start, count (domes,)
    their rows in PP) at points p (n, 3), u (n, 2): out_wi (n, 3), out_pdf (n,), out_kt (n,)
    int64 the texel each wi meets (-1: constant dome)."""
    for r in range(idx.shape[0]):
        j = idx[r]
        wi, pdf, kt = portal_dome_sample_row(PP, PT, start[j], count[j], (p[r, 0], p[r, 1], p[r, 2]), u[r, 0],
                                             u[r, 1], tex[j], rot[j], im_height, im_width, im_row_cdf,
                                             im_row_cdf_start, im_col_cdf, im_col_cdf_start, im_weight, im_total,
                                             im_offset, min_sa, graz)
        for c in range(3):
            out_wi[r, c] = wi[c]
        out_pdf[r] = pdf
        out_kt[r] = kt


@njit(cache=True, nogil=True)
def portal_dome_pdf_kernel(idx, p, wi, PP, PT, start, count, tex, rot, im_height, im_width, im_weight, im_total,
                           im_offset, min_sa, graz, out_pdf):
    """portal_dome_pdf_row for rows of domes idx (n,) with portals at p (n, 3) along wi (n, 3)."""
    for r in range(idx.shape[0]):
        j = idx[r]
        out_pdf[r] = portal_dome_pdf_row(PP, PT, start[j], count[j], (p[r, 0], p[r, 1], p[r, 2]),
                                         (wi[r, 0], wi[r, 1], wi[r, 2]), tex[j], rot[j], im_height, im_width,
                                         im_weight, im_total, im_offset, min_sa, graz)[0]


guard_cache(__name__, module_dispatchers(globals()), ["renderer/kernels/lights.py", "renderer/kernels/vmath.py"])
