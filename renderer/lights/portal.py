"""Importance sampling of a textured dome through a rectangular portal (pbrt-v4's idea for its
PortalImageInfiniteLight, written from the maths): the dome's luminance is tabulated once per
portal in *portal angle space*, where the directions a point p sees through the portal form an
axis-aligned rectangle, so sampling restricted to that window is a summed-area-table lookup.

Portal frame: unit x (along the width), y (along the height) and z pointing out of the room
(the opposite of the PortalLight's transmit direction -Z). A direction w with w.z > 0 has angles

    alpha = atan2(w.x, w.z),  beta = atan2(w.y, w.z)   in (-pi/2, pi/2)^2,

and d omega = J d alpha d beta with J = sec^2(alpha) sec^2(beta) / (1 + tan^2 alpha + tan^2 beta)^(3/2).
From p at portal coordinates (px, py, -dz), dz > 0 (the interior side), w passes through the
rectangle [-a, a] x [-b, b] iff

    alpha in [atan((-a - px) / dz), atan((a - px) / dz)],  beta in [atan((-b - py) / dz), atan((b - py) / dz)]:

each axis separately, so the window is a rectangle in (alpha, beta).

Table: f(alpha, beta) = lum(L(w)) J on an N x N grid over (-pi/2, pi/2)^2, each cell the mean of
SUB x SUB samples of the dome (so a small sun is caught wherever it falls in the cell), plus a
floor of FLOOR_FRACTION of the mean so that no direction the portal passes has density 0.
Prefix sums make integrals of the piecewise-constant f over any window exact (bilinear in the
prefix table), the marginal over alpha and the conditional over beta are piecewise linear, and
sampling finds the cell by bisection and solves the linear piece (numba kernels in
renderer/kernels/portal.py; the ``*_reference`` functions here are the numpy statement).

The sample's density in (alpha, beta) is f(cell) / W (W = the window's integral of f), in solid
angle f(cell) / (W J(alpha, beta)) -- exact for this distribution; the radiance actually used is
the dome's own lookup, so the table only steers samples.
"""

from __future__ import annotations

import numpy as np

from renderer.color import luminance
from renderer.kernels import portal as kern

# Grid resolution per axis of the portal-angle table, and supersamples per cell per axis.
N_CELLS = 64
SUB = 4
# Floor added to every cell, as a fraction of the table's mean (keeps the support complete).
FLOOR_FRACTION = 1e-3
_HALF_PI = 0.5 * np.pi
_DELTA = np.pi / N_CELLS


def jacobian(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """d omega / (d alpha d beta) at (alpha, beta) (n,) (kernels/portal.inverse_jacobian_row)."""
    a = np.ascontiguousarray(alpha, dtype=np.float64).ravel()
    out = np.empty(a.size)
    kern.jacobian_kernel(a, np.ascontiguousarray(beta, dtype=np.float64).ravel(), out)
    return out.reshape(np.shape(alpha))


def build_table(frame: np.ndarray, radiance) -> np.ndarray:
    """f (N, N) for one portal. frame: (3, 3) rows x, y, z (z out of the room); radiance(w (m, 3))
    -> (m, 3) the dome's radiance arriving along -w."""
    k = N_CELLS * SUB
    g = -_HALF_PI + (np.arange(k) + 0.5) * (np.pi / k)
    A, B = np.meshgrid(g, g, indexing="ij")
    A, B = A.ravel(), B.ravel()
    local = np.stack([np.tan(A), np.tan(B), np.ones_like(A)], axis=1)
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    w = local @ frame
    f = luminance(radiance(w)) * jacobian(A, B)
    f = f.reshape(N_CELLS, SUB, N_CELLS, SUB).mean(axis=(1, 3))
    f = np.where(np.isfinite(f) & (f > 0.0), f, 0.0)
    return f + FLOOR_FRACTION * max(float(f.mean()), 1e-300)


def prefix_tables(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sat (N+1, N+1): integral of f over [-pi/2, alpha_i] x [-pi/2, beta_j];
    col (N, N+1): integral along beta within column i, up to beta_j)."""
    n = f.shape[0]
    sat = np.zeros((n + 1, n + 1))
    sat[1:, 1:] = np.cumsum(np.cumsum(f, axis=0), axis=1) * _DELTA * _DELTA
    col = np.zeros((n, n + 1))
    col[:, 1:] = np.cumsum(f, axis=1) * _DELTA
    return sat, col


def _coord(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell index (n,) int in [0, N-1] and fraction (n,) of angles x in [-pi/2, pi/2]."""
    u = np.clip((x + _HALF_PI) / _DELTA, 0.0, float(N_CELLS))
    i = np.minimum(np.floor(u).astype(np.int64), N_CELLS - 1)
    return i, u - i


def _prefix(sat: np.ndarray, t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Integral of f_t over [-pi/2, a] x [-pi/2, b] (n,): bilinear in the prefix table, exact."""
    i, fa = _coord(a)
    j, fb = _coord(b)
    s00, s10 = sat[t, i, j], sat[t, i + 1, j]
    s01, s11 = sat[t, i, j + 1], sat[t, i + 1, j + 1]
    return (1 - fa) * (1 - fb) * s00 + fa * (1 - fb) * s10 + (1 - fa) * fb * s01 + fa * fb * s11


def window_integral_reference(sat, t, a0, a1, b0, b1) -> np.ndarray:
    """Integral W (n,) of f_t over the window [a0, a1] x [b0, b1] (numpy statement)."""
    return _prefix(sat, t, a1, b1) - _prefix(sat, t, a0, b1) - _prefix(sat, t, a1, b0) + _prefix(sat, t, a0, b0)


def window_integral(sat, t, a0, a1, b0, b1) -> np.ndarray:
    """Integral W (n,) of f_t over the window [a0, a1] x [b0, b1] (numba kernel)."""
    out = np.empty(np.size(t))
    kern.window_integral_kernel(sat, *(np.ascontiguousarray(x, dtype=np.float64) if k else
                                       np.ascontiguousarray(x, dtype=np.int64)
                                       for k, x in enumerate((t, a0, a1, b0, b1))), out)
    return out


def _invert(value_at, lo: np.ndarray, hi: np.ndarray, target: np.ndarray) -> np.ndarray:
    """x in [lo, hi] (n,) with value_at(x) = target for a non-decreasing piecewise-linear function
    whose pieces are the grid cells: bisection over cell boundaries, then the linear piece."""
    ilo = np.floor((lo + _HALF_PI) / _DELTA).astype(np.int64)
    ihi = np.ceil((hi + _HALF_PI) / _DELTA).astype(np.int64)
    # Invariant: value(left) <= target, with left/right cell boundaries clipped into [lo, hi].
    for _ in range(int(np.ceil(np.log2(N_CELLS))) + 1):
        mid = (ilo + ihi) // 2
        x = np.clip(-_HALF_PI + mid * _DELTA, lo, hi)
        go_right = value_at(x) <= target
        ilo = np.where(go_right & (ihi - ilo > 1), mid, ilo)
        ihi = np.where(~go_right & (ihi - ilo > 1), mid, ihi)
    left = np.clip(-_HALF_PI + ilo * _DELTA, lo, hi)
    right = np.clip(-_HALF_PI + ihi * _DELTA, lo, hi)
    v0, v1 = value_at(left), value_at(right)
    slope = v1 - v0
    frac = np.divide(target - v0, slope, out=np.zeros_like(slope), where=slope > 0.0)
    return np.clip(left + np.clip(frac, 0.0, 1.0) * (right - left), lo, hi)


def sample_window(sat, col, t, a0, a1, b0, b1, u) -> tuple[np.ndarray, np.ndarray]:
    """(alpha, beta) (n,) each, distributed as f_t restricted to the window. u (n, 2).
    The numba kernel of sample_window_reference."""
    n = np.size(t)
    alpha, beta = np.empty(n), np.empty(n)
    f64 = [np.ascontiguousarray(x, dtype=np.float64) for x in (a0, a1, b0, b1)]
    kern.window_sample_kernel(sat, col, np.ascontiguousarray(t, dtype=np.int64), *f64,
                              np.ascontiguousarray(u, dtype=np.float64), alpha, beta)
    return alpha, beta


def sample_window_reference(sat, col, t, a0, a1, b0, b1, u) -> tuple[np.ndarray, np.ndarray]:
    """(alpha, beta) (n,) each, distributed as f_t restricted to the window. u (n, 2) (numpy)."""
    W = window_integral_reference(sat, t, a0, a1, b0, b1)

    def marginal(a):
        return _prefix(sat, t, a, b1) - _prefix(sat, t, a, b0) - _prefix(sat, t, a0, b1) + _prefix(sat, t, a0, b0)

    alpha = _invert(marginal, a0, a1, u[:, 0] * W)
    i, _ = _coord(alpha)

    def column(b):
        j, fb = _coord(b)
        return (1 - fb) * col[t, i, j] + fb * col[t, i, j + 1]

    c0 = column(b0)
    G = column(b1) - c0
    beta = _invert(lambda b: column(b) - c0, b0, b1, u[:, 1] * G)
    return alpha, beta
