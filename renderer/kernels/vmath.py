"""Transcendental functions that LLVM can vectorise, for the kernels' hot loops.

numba compiles ``math.sin``, ``math.cos`` and ``math.atan`` to calls into libm, and LLVM runs a
call one lane at a time even in a loop it otherwise vectorises: the sampling loops (the BSDF's
direction, the spherical rectangle's solid angle and inverse CDF, the sphere's cone) spent most
of their time in those calls. These are straight-line polynomial code with arithmetic selects
instead of branches, numba-inlined (``inline="always"``, scalars only), so they run packed
(4 or 8 lanes) wherever they are inlined. Each stays within a few units in the last place of
libm (tests/kernels/test_vmath.py).

A kernel module that uses them must list this file in its ``guard_cache`` call (numba's
on-disk cache is keyed on the defining file only; see renderer/kernels/__init__.py).
"""

from __future__ import annotations

import math

from numba import njit

_PI = math.pi
# pi/2 in two parts (Cody-Waite): x - k PIO2_HI is exact for the k of sampling angles.
_PIO2_HI = 1.5707963267341256
_PIO2_LO = 6.077100506506192e-11


@njit(cache=True, nogil=True, inline="always")
def sincos(x):
    """(sin x, cos x) for |x| up to a few thousand, branch-free: Taylor polynomials (to x^17 and
    x^16, whose first omitted terms are below 1e-16 relative on |r| <= pi/4) of the
    quadrant-reduced angle r, within 2.2e-16 of libm."""
    k = math.floor(x * (2.0 / math.pi) + 0.5)
    r = (x - k * _PIO2_HI) - k * _PIO2_LO
    r2 = r * r
    # 1/(2j+1)! and 1/(2j)! with alternating signs, by Estrin's scheme (pairs of terms, then
    # pairs in r^4, r^8): 4 dependent steps instead of Horner's 8, on the sampling loops'
    # critical path.
    r4 = r2 * r2
    r8 = r4 * r4
    ps = ((1.0 - r2 * (1.0 / 6.0)) + r4 * (1.0 / 120.0 - r2 * (1.0 / 5040.0))) + r8 * (
        (1.0 / 362880.0 - r2 * (1.0 / 39916800.0)) + r4 * (1.0 / 6227020800.0 - r2 * (1.0 / 1307674368000.0))
        + r8 * (1.0 / 355687428096000.0))
    pc = ((1.0 - r2 * 0.5) + r4 * (1.0 / 24.0 - r2 * (1.0 / 720.0))) + r8 * (
        (1.0 / 40320.0 - r2 * (1.0 / 3628800.0)) + r4 * (1.0 / 479001600.0 - r2 * (1.0 / 87178291200.0))
        + r8 * (1.0 / 20922789888000.0))
    sr = r * ps
    # Quadrant q = k mod 4: odd ones swap sin and cos; sin is negative in 2 and 3, cos in 1 and
    # 2. Arithmetic, not a chain of ifs (LLVM turns that into a switch it cannot vectorise).
    q = int(k) & 3
    odd = (q & 1) == 1
    sn = (1.0 - 2.0 * ((q >> 1) & 1)) * (pc if odd else sr)
    cs = (1.0 - 2.0 * (((q + 1) >> 1) & 1)) * (sr if odd else pc)
    return sn, cs


# tan(pi/8): above it, atan x = pi/4 + atan((x - 1) / (x + 1)), whose argument is within it.
_TAN_PI8 = 0.41421356237309503


@njit(cache=True, nogil=True, inline="always")
def atan_ratio(m, big):
    """atan(m / big) for 0 <= m <= big, big > 0, branch-free and with one division: the ratio
    (or, above tan(pi/8), (m - big) / (m + big), formed before dividing) is within tan(pi/8) of
    0, where the Taylor series of atan to t^41 leaves less than 3e-18 relative (the first
    omitted term, tan(pi/8)^42 / 43). A division costs as much as ~30 multiply-adds in a
    vectorised loop, so the long polynomial is the cheap part. Within a few ulp of libm."""
    upper = m > _TAN_PI8 * big
    t = (m - big if upper else m) / (m + big if upper else big)
    # sum_k (-1)^k z^k / (2k + 1), k = 0..20, by Estrin's scheme (pairs of terms, then pairs of
    # pairs in z^2, z^4, ...): Horner's 20 dependent multiply-adds were the loop's critical path
    # (the vectorised loop body is too long for the core to overlap iterations); this is 5 deep.
    z = t * t
    z2 = z * z
    z4 = z2 * z2
    z8 = z4 * z4
    q0 = 1.0 - z * (1.0 / 3.0)
    q1 = 1.0 / 5.0 - z * (1.0 / 7.0)
    q2 = 1.0 / 9.0 - z * (1.0 / 11.0)
    q3 = 1.0 / 13.0 - z * (1.0 / 15.0)
    q4 = 1.0 / 17.0 - z * (1.0 / 19.0)
    q5 = 1.0 / 21.0 - z * (1.0 / 23.0)
    q6 = 1.0 / 25.0 - z * (1.0 / 27.0)
    q7 = 1.0 / 29.0 - z * (1.0 / 31.0)
    q8 = 1.0 / 33.0 - z * (1.0 / 35.0)
    q9 = 1.0 / 37.0 - z * (1.0 / 39.0)
    q10 = 1.0 / 41.0
    r0 = q0 + z2 * q1
    r1 = q2 + z2 * q3
    r2 = q4 + z2 * q5
    r3 = q6 + z2 * q7
    r4 = q8 + z2 * q9
    s0 = r0 + z4 * r1
    s1 = r2 + z4 * r3
    s2 = r4 + z4 * q10
    p = s0 + z8 * (s1 + z8 * s2)
    r = t * p
    return 0.25 * _PI + r if upper else r


@njit(cache=True, nogil=True, inline="always")
def atan_unit(a):
    """atan a for a in [0, 1] (atan_ratio(a, 1))."""
    return atan_ratio(a, 1.0)


@njit(cache=True, nogil=True, inline="always")
def arg_upper(x, y):
    """arg(x + i y) in [0, pi] for y >= 0 (atan2(y, x) on the upper half plane), branch-free:
    atan_ratio(min(|x|, y), max(|x|, y)) folded by octant. 0 at x = y = 0. No squares of x or
    y, so no overflow for any finite input."""
    ax = abs(x)
    big = max(ax, y)
    t = atan_ratio(min(ax, y), big) if big > 0.0 else 0.0
    t = 0.5 * _PI - t if y > ax else t  # angle from the positive x axis for x >= 0
    return _PI - t if x < 0.0 else t
