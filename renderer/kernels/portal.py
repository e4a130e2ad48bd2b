"""Per-row kernels of the portal-angle luminance tables (``renderer/lights/portal.py``): window
integrals and windowed sampling, the same maths as that module's numpy reference functions.

Conventions as in ``renderer.kernels``. Tables: sat (T, N+1, N+1) prefix integrals over
[-pi/2, alpha_i] x [-pi/2, beta_j], col (T, N, N+1) prefix integrals along beta per alpha
column; the grid spacing is pi / N.
"""

from __future__ import annotations

import math

from numba import njit

_HALF_PI = 0.5 * math.pi


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
def window_integral_kernel(sat, t, a0, a1, b0, b1, out):
    """out[r] = integral of table t[r] over [a0, a1] x [b0, b1] (row r)."""
    n = sat.shape[1] - 1
    for r in range(t.shape[0]):
        tr = t[r]
        out[r] = (_prefix(sat, tr, a1[r], b1[r], n) - _prefix(sat, tr, a0[r], b1[r], n)
                  - _prefix(sat, tr, a1[r], b0[r], n) + _prefix(sat, tr, a0[r], b0[r], n))


@njit(cache=True, nogil=True)
def window_sample_kernel(sat, col, t, a0, a1, b0, b1, u, out_alpha, out_beta):
    """(alpha, beta) distributed as table t[r] restricted to the row's window, from u[r, :2].

    The marginal over alpha and the conditional over beta are piecewise linear with a piece per
    grid cell: bisection over the cell boundaries inside the window, then the linear piece.
    """
    n = col.shape[1]
    delta = math.pi / n
    for r in range(t.shape[0]):
        tr = t[r]
        lo, hi = a0[r], a1[r]
        blo, bhi = b0[r], b1[r]
        base = _prefix(sat, tr, lo, bhi, n) - _prefix(sat, tr, lo, blo, n)
        total = _prefix(sat, tr, hi, bhi, n) - _prefix(sat, tr, hi, blo, n) - base
        target = u[r, 0] * total
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
        c0 = _column(col, tr, i, blo, n)
        target = u[r, 1] * (_column(col, tr, i, bhi, n) - c0)
        jlo = int(math.floor((blo + _HALF_PI) / delta))
        jhi = int(math.ceil((bhi + _HALF_PI) / delta))
        while jhi - jlo > 1:
            mid = (jlo + jhi) // 2
            y = min(max(-_HALF_PI + mid * delta, blo), bhi)
            if _column(col, tr, i, y, n) - c0 <= target:
                jlo = mid
            else:
                jhi = mid
        left = min(max(-_HALF_PI + jlo * delta, blo), bhi)
        right = min(max(-_HALF_PI + jhi * delta, blo), bhi)
        v0 = _column(col, tr, i, left, n) - c0
        v1 = _column(col, tr, i, right, n) - c0
        frac = (target - v0) / (v1 - v0) if v1 > v0 else 0.0
        beta = left + min(max(frac, 0.0), 1.0) * (right - left)
        out_alpha[r] = alpha
        out_beta[r] = min(max(beta, blo), bhi)
