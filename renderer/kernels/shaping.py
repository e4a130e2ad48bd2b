"""Fused per-row kernel of the UsdLux ShapingAPI factor (see ``renderer.lights.shaping``).

One pass per row does what the factor's whole-array numpy form did in a dozen passes: gather
the row's light, map the emission direction to light space, apply focus, cone and the IES
profile's bilinear lookup, and multiply the row's radiance in place. Unshaped rows
(``row_of < 0``) cost one gather and a comparison. The formulas and guards are those
documented in ``renderer/lights/shaping.py`` and ``renderer/lights/ies.py``.

IES profiles are packed into flat tables: profile p's vertical angles are
``v_all[v_off[p]:v_off[p + 1]]``, its horizontal angles ``h_all[h_off[p]:h_off[p + 1]]`` and
its candela rows ``c_all[c_off[p]:c_off[p + 1]]`` (H x V, row-major).
"""

from __future__ import annotations

import math

from numba import njit

_PI = math.pi
_TWO_PI = 2.0 * math.pi


@njit(cache=True, nogil=True)
def _interval(a, lo, hi, x):
    """Index j in [lo, hi - 2] with a[j] <= x < a[j + 1] (numpy searchsorted 'right' - 1, clipped)."""
    # Binary search for the first index with a[k] > x.
    left, right = lo, hi
    while left < right:
        mid = (left + right) // 2
        if a[mid] <= x:
            left = mid + 1
        else:
            right = mid
    j = left - 1
    if j < lo:
        j = lo
    if j > hi - 2:
        j = hi - 2
    return j


@njit(cache=True, nogil=True)
def _ies_eval(p, theta, phi, v_all, v_off, h_all, h_off, c_all, c_off):
    v0, v1 = v_off[p], v_off[p + 1]
    if theta < v_all[v0] or theta > v_all[v1 - 1]:
        return 0.0
    nv = v1 - v0
    j = _interval(v_all, v0, v1, theta)
    s = (theta - v_all[j]) / (v_all[j + 1] - v_all[j])
    s = min(max(s, 0.0), 1.0)
    h0, h1 = h_off[p], h_off[p + 1]
    i = _interval(h_all, h0, h1, phi)
    t = (phi - h_all[i]) / (h_all[i + 1] - h_all[i])
    t = min(max(t, 0.0), 1.0)
    base = c_off[p]
    r0 = base + (i - h0) * nv + (j - v0)
    r1 = r0 + nv
    a = c_all[r0] * (1.0 - s) + c_all[r0 + 1] * s
    b = c_all[r1] * (1.0 - s) + c_all[r1 + 1] * s
    return a * (1.0 - t) + b * t


@njit(cache=True, nogil=True, error_model="numpy")
def shaping_factor_row(j, e0, e1, e2, to_local, focus, tint, theta_cut, theta_soft, ies_of, angle_scale, ies_scale,
                       v_all, v_off, h_all, h_off, c_all, c_off):
    """The factor (f0, f1, f2) of shaping row j toward the world emission direction (e0, e1, e2)
    (light -> receiver; any length, 0 for a zero vector): focus, cone and IES (module docstring
    of renderer/lights/shaping.py). The one formula every caller uses: shaping_apply_kernel
    (the general path) and the fast path's vertex kernel (renderer/integrators/_vertex_kernels.py)."""
    x = to_local[j, 0, 0] * e0 + to_local[j, 0, 1] * e1 + to_local[j, 0, 2] * e2
    y = to_local[j, 1, 0] * e0 + to_local[j, 1, 1] * e1 + to_local[j, 1, 2] * e2
    z = to_local[j, 2, 0] * e0 + to_local[j, 2, 1] * e1 + to_local[j, 2, 2] * e2
    length = math.sqrt(x * x + y * y + z * z)
    if not length > 0.0:
        return 0.0, 0.0, 0.0
    x /= length
    y /= length
    z /= length
    cos_off = min(max(-z, -1.0), 1.0)
    theta = math.atan2(math.hypot(x, y), -z)
    f0 = 1.0
    f1 = 1.0
    f2 = 1.0
    fo = focus[j]
    if fo > 0.0:
        ff = abs(cos_off) ** fo
        f0 *= tint[j, 0] + ff * (1.0 - tint[j, 0])
        f1 *= tint[j, 1] + ff * (1.0 - tint[j, 1])
        f2 *= tint[j, 2] + ff * (1.0 - tint[j, 2])
    soft = theta_soft[j]
    if soft < _PI:
        cut = theta_cut[j]
        width = cut - soft
        if width <= 0.0:
            w = 0.0 if theta > soft else 1.0
        else:
            t = min(max((theta - soft) / width, 0.0), 1.0)
            w = 1.0 - t * t * (3.0 - 2.0 * t)
        f0 *= w
        f1 *= w
        f2 *= w
    p = ies_of[j]
    if p >= 0:
        s = angle_scale[j]
        if s > 0.0:
            ti = theta / s
        elif s < 0.0:
            ti = (theta - _PI) / -s + _PI
        else:
            ti = theta
        ti = min(max(ti, 0.0), _PI)
        phi = math.atan2(-y, -x)
        if phi < 0.0:
            phi += _TWO_PI
        val = _ies_eval(p, ti, phi, v_all, v_off, h_all, h_off, c_all, c_off) * ies_scale[j]
        f0 *= val
        f1 *= val
        f2 *= val
    return f0, f1, f2


@njit(cache=True, nogil=True)
def shaping_apply_kernel(light, e, L, row_of, to_local, focus, tint, theta_cut, theta_soft, ies_of, angle_scale,
                         ies_scale, v_all, v_off, h_all, h_off, c_all, c_off):
    """L[i] *= factor(light[i], e[i]) for every row whose light is shaped; e is the world
    emission direction (light -> receiver). light (n,) int64; e, L (n, 3) float64."""
    for r in range(light.shape[0]):
        j = row_of[light[r]]
        if j < 0:
            continue
        f0, f1, f2 = shaping_factor_row(j, e[r, 0], e[r, 1], e[r, 2], to_local, focus, tint, theta_cut, theta_soft,
                                        ies_of, angle_scale, ies_scale, v_all, v_off, h_all, h_off, c_all, c_off)
        L[r, 0] *= f0
        L[r, 1] *= f1
        L[r, 2] *= f2
