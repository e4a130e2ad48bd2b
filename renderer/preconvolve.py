"""Dome-light irradiance preconvolution (`illum preconvolve`, project issue #6).

The control variate of a textured DomeLight needs, for every shading normal n, the unshadowed
irradiance

    E(n) = ∫_{S²} L(ω) max(0, n·ω) dω                  (RGB, W/m² per nit of the texture)

The talk (Illumination 101) computes it "off-line, as an adjoint channel to the Dome texture".
This module writes that channel: a float32 lat-long EXR in the *same* orientation as the source
(USD-NOTES §1: texel (x, y) of a W x H map has u = (x+0.5)/W, v = (y+0.5)/H, lon = π − 2πu,
lat = π/2 − πv, dir = (sin lon cos lat, sin lat, cos lon cos lat)); output texel (x, y) holds
E(n) for n = the direction of its centre.

What is integrated
------------------
The renderer's DomeLight looks radiance up by *nearest texel* and samples directions uniformly
in solid angle inside a texel, so the quantity its light samples estimate is the integral of a
piecewise-constant radiance field:

    E(n) = Σ_t L_t ∫_{texel t} max(0, n·ω) dω                                       (1)

``exact`` computes (1) over every texel of the full-resolution source. To second order in the
texel size this is the midpoint sum Σ_t L_t Ω_t max(0, n·ω_t) of the issue; (1) is what keeps
the control variate unbiased even for small dome textures.

``exact``: aggregation that is exact where it aggregates
---------------------------------------------------------
For a texel entirely above the horizon of n the clamp is inactive and the cosine is *linear*:
∫_t max(0, n·ω) dω = n·M_t with the first moment M_t = ∫_t ω dω, which is analytic for a
lat-long cell (θ from +Y, z = cos θ, Δφ = 2π/W, φ_c the cell's centre longitude):

    M_x = S_r · 2 sin(Δφ/2) sin φ_c,   M_z = S_r · 2 sin(Δφ/2) cos φ_c,   M_y = Y_r · Δφ,
    S_r = ∫ sin²θ dθ over the row,      Y_r = (z_top² − z_bot²) / 2.

So along a row, any run of fully-lit texels contributes n·(Σ L_t M_t) with *no* error: two
lookups in per-row prefix sums of L·sin φ_c, L·cos φ_c and L (the summed-area level of the
hierarchy; no coarser level is needed, because aggregating lit texels costs no accuracy at all).
Texels entirely below the horizon contribute exactly 0. Only texels that *straddle* the horizon
of n — the cells a great circle passes through, O(W + H) per normal instead of W·H — are
integrated at full resolution, by K×K midpoint sub-sampling (equal-solid-angle sub-cells,
uniform in φ and z). A sun is therefore never averaged with its surroundings: it is either in
an exact lit run, dark, or sub-sampled at full resolution.

Classification (``_exact_rows``): on a parallel (a row boundary) n·ω = a + b cos(φ − φ_n), so the
lit corners of a row are an arc about φ_n found with one arccos. A cell is lit iff its four
corners are lit with the margin m = b(1 − cos Δφ) (between two corners a parallel can dip by at
most m; along a meridian n·ω = R cos(θ − θ*) has no interior minimum near the horizon), dark iff
its four corners are dark with the same margin; everything else straddles. Per normal the work
is O(H) arccos + prefix lookups and O(W + H) straddling cells. (The per-texel fallback
``_texel_list`` classifies by a bounding cone instead: centre c_t, exact radius β_r = distance
to the farthest corner, lit iff n·c_t ≥ sin β_r; the tests use it as an independent check.)

Error bound (documented tolerance ``STRADDLE_TOL`` = 1e-4, relative to the mean irradiance
π·L̄, L̄ = the solid-angle mean of the texels' max channel). For a straddling texel of solid
angle Ω and angular diameter d, the K×K midpoint rule errs by at most ≈ 2·L_t·Ω·d/K² (at most
~2K sub-cells contain the horizon and there max(0, n·ω) ∈ [0, d/K]; the others are linear up
to O(d²)). Summed over the band (~2πd/Ω texels) the bound is 4·L·d²/K² relative to πL, so each
row uses K_r = ceil(d_r · sqrt(4 / tol)) (capped at ``K_MAX`` = 32): K = 1 for 2k maps
(d ≈ 0.004), K ≈ 28 for a 64×32 map. A texel much brighter than L̄ (a sun) gets its own budget
tol/8: K_t = ceil(sqrt(16 L_t Ω d / (tol π L̄))) (K_t ≈ 10 for a 1e5 sun on a 2k map).
Everything else in (1) is exact up to float64 rounding. So the bound is ≈ tol·π·L̄ absolute
per normal; for a normal that sees a much darker hemisphere than average the *relative* error
can be larger (it is still ≤ tol·π·L̄ in absolute terms). Maps with cells of ~45° or more
(H < 4 or W < 4, or where K_MAX caps K) are coarser: ~1e-3 for a 4x8 map.

Memory and speed: the source is streamed from disk in row blocks of ~256k texels (one scan for
validation and L̄, one for the integral), each block gets its (R, W+1, 9) prefix sums, and the
normals sweep the block in sub-blocks that fit in L2; the normals × texels matrix never exists.
The numba kernels are ``nogil`` and *not* ``parallel`` (render threads may call them, see
bsdfs/_preview_kernels.py); a thread pool splits the output normals.

``sh``: order-2 spherical harmonics (Ramamoorthi & Hanrahan 2001) — 9 coefficients
L_lm = Σ_t L_t ∫_t Y_lm dω (exact texel integrals, so a constant map gives π L exactly),
E(n) = Σ Â_l L_lm Y_lm(n) with Â_0 = π, Â_1 = 2π/3, Â_2 = π/4. **Approximate**: exact only for
radiance with no l ≥ 3 content (the clamped cosine's higher coefficients are small but not
zero: ~0.5 % on a smooth sky, and tens of percent near a sun's horizon). Not for the control
variate, which needs the exact F.

Renderer hook
-------------
``dome_irradiance_table`` builds what ``DomeLight.irradiance_lookup`` interpolates: the authored
``illum:dome:irradiance`` file when its ``illum:sourceHash`` matches the dome texture and it is
``exact`` (else a warning and a recompute), otherwise an ``exact`` table of ``LOAD_SIZE`` x
``LOAD_SIZE/2`` computed from the renderer's own texels, cached on disk by content hash
(``$ILLUM_CACHE_DIR`` or ``~/.cache/illum/irradiance``). See ``IrradianceTable`` for the
interpolation (bilinear, with the smooth and the "sun" parts taken out analytically first).
"""

from __future__ import annotations

import math
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from renderer.assets import asset_sha256
from renderer.errors import IllumError, SettingsError

__all__ = [
    "preconvolve",
    "register_cli",
    "exact_irradiance",
    "sh_irradiance",
    "midpoint_irradiance",
    "latlong_directions",
    "texel_cos_integral",
    "file_sha256",
    "read_irradiance",
    "write_irradiance",
    "IrradianceTable",
    "dome_irradiance_table",
    "irradiance_cache_dir",
    "STRADDLE_TOL",
    "LOAD_SIZE",
]

STRADDLE_TOL = 1e-4  # straddling-texel error budget, relative to π·(mean radiance)
K_MAX = 32  # cap on the per-axis sub-sample count of a straddling texel
LOAD_SIZE = 64  # width of the table the renderer computes when no irradiance is authored
ALGO_VERSION = 1  # bump when the numbers change: part of the on-disk cache key
_BLOCK_TEXELS = 1 << 18  # texels per row block (≈ 256k: ~25 MB of prefix sums + texels)
_SUN_FRACTION = 1e-3  # texels with more than this share of the power are a "sun" (hook)
_SUN_MAX = 16  # at most this many sun texels are evaluated analytically per lookup
METHODS = ("exact", "sh")

# Clamped-cosine SH coefficients Â_l (R&H 2001), per basis function k = 0..8.
_SH_A = np.array([math.pi] + [2.0 * math.pi / 3.0] * 3 + [math.pi / 4.0] * 5)


# --------------------------------------------------------------------------------------
# Lat-long geometry
# --------------------------------------------------------------------------------------
def latlong_directions(h: int, w: int, r0: int = 0, r1: int | None = None) -> np.ndarray:
    """(r1 - r0, w, 3) unit directions of the texel centres of rows [r0, r1) (default: all) of an
    h x w lat-long map (USD-NOTES §1)."""
    r1 = h if r1 is None else r1
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(r0, r1) + 0.5) / h
    lon = np.pi - 2.0 * np.pi * u
    lat = 0.5 * np.pi - np.pi * v
    cl = np.cos(lat)[:, None]
    return np.stack([np.sin(lon)[None, :] * cl, np.broadcast_to(np.sin(lat)[:, None], (r1 - r0, w)),
                     np.cos(lon)[None, :] * cl], axis=-1)


def _solid_angles(h: int, w: int) -> np.ndarray:
    """(h,) texel solid angle per row: the renderer's ``latlong_texel_solid_angles``."""
    from renderer.lights.dome import latlong_texel_solid_angles

    return latlong_texel_solid_angles(h, w)


@dataclass(frozen=True)
class _Rows:
    """Per-row constants of an h x w lat-long map (all (h,) float64 / int64, row 0 = top).

    cz, sz: cos/sin of the centre colatitude; zt, zb: cos θ at the top/bottom edges;
    zm, sm: the equal-area midpoint z = (zt + zb)/2 and sqrt(1 − zm²); omega: texel solid angle
    (sr); S, Y: moment factors (module docstring); sinb: sin of the bounding-cone radius;
    K: base sub-sample count; kb: bright-texel factor (K_t² ≥ kb · max-channel radiance);
    cpar, spar (h+1,): cos/sin θ of the parallels bounding the rows.
    """

    cz: np.ndarray
    sz: np.ndarray
    zt: np.ndarray
    zb: np.ndarray
    zm: np.ndarray
    sm: np.ndarray
    omega: np.ndarray
    S: np.ndarray
    Y: np.ndarray
    sinb: np.ndarray
    K: np.ndarray
    kb: np.ndarray
    cpar: np.ndarray
    spar: np.ndarray

    def take(self, r0: int, r1: int) -> "_Rows":
        """Rows [r0, r1) (parallels r0..r1)."""
        f = {k: getattr(self, k)[r0:r1] for k in self.__dataclass_fields__}
        f["cpar"] = self.cpar[r0:r1 + 1]
        f["spar"] = self.spar[r0:r1 + 1]
        return _Rows(**f)


def _row_params(h: int, w: int, L_ref: float, tol: float = STRADDLE_TOL) -> _Rows:
    """Row constants of the whole map. L_ref: mean max-channel radiance over the sphere (nits)."""
    r = np.arange(h, dtype=np.float64)
    th_t = np.pi * r / h
    th_b = np.pi * (r + 1.0) / h
    th_c = np.pi * (r + 0.5) / h
    dth = np.pi / h
    zt, zb = np.cos(th_t), np.cos(th_b)
    zm = 0.5 * (zt + zb)
    omega = _solid_angles(h, w)
    S = 0.5 * dth - 0.5 * np.cos(th_b + th_t) * np.sin(dth)  # ∫ sin²θ dθ, no cancellation
    Y = 0.5 * (zt - zb) * (zt + zb)
    # Bounding cone about the centre: the farthest point of a lat-long cell is a corner
    # (distance along a parallel grows with |Δφ|, along a meridian it is unimodal).
    s2 = math.sin(0.5 * np.pi / w) ** 2  # centre-to-corner half longitude π/w

    def hav_dist(th):
        hav = np.sin(0.5 * (th_c - th)) ** 2 + np.sin(th_c) * np.sin(th) * s2
        return 2.0 * np.arcsin(np.sqrt(np.minimum(1.0, hav)))

    beta = np.maximum(hav_dist(th_t), hav_dist(th_b)) * (1.0 + 1e-9) + 1e-12
    sinb = np.sin(np.minimum(beta, 0.5 * np.pi))
    d = 2.0 * beta
    K = np.clip(np.ceil(d * math.sqrt(4.0 / tol)), 1, K_MAX).astype(np.int64)
    kb = 16.0 * omega * d / (tol * math.pi * L_ref) if L_ref > 0.0 else np.zeros(h)
    th_p = np.pi * np.arange(h + 1) / h
    return _Rows(np.cos(th_c), np.sin(th_c), zt, zb, zm, np.sqrt(np.maximum(0.0, 1.0 - zm * zm)), omega,
                 S, Y, sinb, K, kb, np.cos(th_p), np.sin(th_p))


def _col_params(w: int) -> tuple[np.ndarray, np.ndarray]:
    """(sin φ_c, cos φ_c) (w,) of the column centres."""
    lon = np.pi - 2.0 * np.pi * (np.arange(w) + 0.5) / w
    return np.sin(lon), np.cos(lon)


# --------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def _texel_weight(ny, t, cz, sz, zt, zb, omega, S, Y, sinb, dlon, K, nx, nz, slc, clc, tbuf):
    """∫_texel max(0, n·ω) dω (sr) of one lat-long texel.

    t = nx sin φ_c + nz cos φ_c (φ_c its centre longitude, slc/clc = sin/cos φ_c); cz, sz: cos/sin
    of its centre colatitude; zt, zb: cos θ of its top/bottom edges; omega its solid angle; S, Y
    the row's moment factors; sinb: sin of its bounding-cone radius; dlon = 2π/W; K sub-samples
    per axis if it straddles the horizon; tbuf: scratch (≥ K,).
    """
    g = ny * cz + sz * t  # n · centre
    if g >= sinb:  # fully lit: the exact first moment n · M_t
        return S * 2.0 * math.sin(0.5 * dlon) * t + ny * Y * dlon
    if g <= -sinb:
        return 0.0
    # K x K midpoint sub-cells, uniform in longitude and z (equal solid angle).
    step = dlon / K
    al = 0.5 * dlon - 0.5 * step  # centre lon -> first sub-column (lon_L - step/2)
    ca, sa = math.cos(al), math.sin(al)
    s = slc * ca + clc * sa
    c = clc * ca - slc * sa
    cs, ss = math.cos(step), math.sin(step)
    for j in range(K):
        tbuf[j] = nx * s + nz * c
        s, c = s * cs - c * ss, c * cs + s * ss  # lon -= step
    dz = (zt - zb) / K
    acc = 0.0
    for i in range(K):
        z = zt - (i + 0.5) * dz
        sr = math.sqrt(max(0.0, 1.0 - z * z))
        a = ny * z
        for j in range(K):
            v = a + sr * tbuf[j]
            if v > 0.0:
                acc += v
    return omega * acc / (K * K)


@njit(cache=True, nogil=True, inline="always")
def _texel_k(Krow, kb, m, kmax):
    """Sub-samples per axis of a straddling texel of max-channel radiance m."""
    k = Krow
    x = kb * m
    if x > k * k:
        k = min(kmax, int(math.ceil(math.sqrt(x))))
    return k


@njit(cache=True, nogil=True)
def _prefix(px, slon, clon, P):
    """Row prefix sums P (R, W+1, 9) of [L·sin φ_c (3), L·cos φ_c (3), L (3)] over px (R, W, 3).

    Interleaved so one column position is two cache lines (the kernel reads two per row).
    """
    R, W = px.shape[0], px.shape[1]
    for i in range(R):
        for q in range(9):
            P[i, 0, q] = 0.0
        for c in range(W):
            for ch in range(3):
                v = px[i, c, ch]
                P[i, c + 1, ch] = P[i, c, ch] + v * slon[c]
                P[i, c + 1, 3 + ch] = P[i, c, 3 + ch] + v * clon[c]
                P[i, c + 1, 6 + ch] = P[i, c, 6 + ch] + v


@njit(cache=True, nogil=True, inline="always")
def _arcs(a, b, m):
    """Half-widths (rad) about φ_n of the lit arc {a + b cos Δ > m} and of the not-dark arc
    {a + b cos Δ ≥ −m} on one parallel (b ≥ 0). 4.0 = the whole circle, -1.0 = empty."""
    if b <= 1e-300:
        return (4.0 if a > m else -1.0), (-1.0 if a < -m else 4.0)
    x = (m - a) / b
    if x < -1.0:
        al = 4.0
    elif x >= 1.0:
        al = -1.0
    else:
        al = math.acos(x)
    y = (-m - a) / b
    if y <= -1.0:
        be = 4.0
    elif y > 1.0:
        be = -1.0
    else:
        be = math.acos(y)
    return al, be


@njit(cache=True, nogil=True)
def _exact_rows(nrm, k0, k1, px, P, cpar, spar, zm, sm, cz, sz, zt, zb, omega, S, Y, sinb, Krow, kb,
                rowmax, slon, clon, sub, kmax, out):
    """Add the contributions of rows px (R, W, 3) to E for normals k0..k1-1.

    nrm (N, 3) unit dome-local normals; P (R, W+1, 9) row prefix sums (``_prefix``);
    cpar, spar (R+1,) cos/sin θ of the row boundaries (parallels); zm, sm (R,) midpoint z and
    sqrt(1 − zm²); cz, sz, zt, zb, omega, S, Y, sinb, Krow, kb (R,) row constants (``_Rows``);
    rowmax (R,) the rows' largest texel value; slon, clon (W,) column-centre sin/cos φ; sub: rows
    per cache block; out (N, 3) += E.

    A cell is lit iff its four corners are lit with margin m = b(1 − cos Δφ) (between corners
    a parallel's a + b cos Δ can dip by at most m; along a meridian f = R cos(θ − θ*) has no
    interior minimum near the horizon), dark iff its corners are dark with the same margin.
    On a parallel the lit corners are an arc about φ_n, so each row's lit cells are a run of
    columns (prefix sums) and the straddling cells two short runs.
    """
    R, W = px.shape[0], px.shape[1]
    dlon = 2.0 * math.pi / W
    cw = W / (2.0 * math.pi)  # columns per radian
    two_sin = 2.0 * math.sin(0.5 * dlon)
    mfac = 1.0 - math.cos(dlon)
    tbuf = np.empty(kmax)
    al = np.empty(sub + 1)
    be = np.empty(sub + 1)
    for s0 in range(0, R, sub):
        s1 = min(R, s0 + sub)
        for k in range(k0, k1):
            nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
            rho = math.sqrt(nx * nx + nz * nz)
            xc = cw * (math.pi - math.atan2(nx, nz))  # the normal's column coordinate
            for j in range(s0, s1 + 1):
                b = rho * spar[j]
                al[j - s0], be[j - s0] = _arcs(ny * cpar[j], b, b * mfac + 1e-12)
            e0 = 0.0
            e1 = 0.0
            e2 = 0.0
            for i in range(s0, s1):
                alpha = min(al[i - s0], al[i - s0 + 1])
                beta = max(be[i - s0], be[i - s0 + 1])
                # Lit: both edges of the column within the lit arc: c ∈ (xc − αc, xc + αc − 1).
                p0 = 0
                pl = 0
                if alpha > math.pi:
                    pl = W
                elif alpha >= 0.0:
                    ac = alpha * cw
                    p0 = int(math.floor(xc - ac)) + 1
                    pl = int(math.ceil(xc + ac - 1.0)) - p0
                    if pl >= W:
                        p0 = 0
                        pl = W
                    elif pl < 0:
                        pl = 0
                # Not dark: the column meets the not-dark arc: c ∈ [xc − βc − 1, xc + βc].
                q0 = 0
                ql = 0
                qfull = False
                if beta > math.pi:
                    qfull = True
                elif beta >= 0.0:
                    bc = beta * cw
                    q0 = int(math.ceil(xc - bc - 1.0))
                    ql = int(math.floor(xc + bc)) + 1 - q0
                    if pl > 0 and pl < W:  # keep the lit run inside whatever the rounding
                        if q0 > p0:
                            ql += q0 - p0
                            q0 = p0
                        if q0 + ql < p0 + pl:
                            ql = p0 + pl - q0
                    if ql >= W or pl == W:
                        qfull = True
                    elif ql < 0:
                        ql = 0
                if pl > 0:
                    s = p0 % W
                    e = s + pl
                    fx = S[i] * two_sin
                    fy = Y[i] * dlon * ny
                    if e <= W:
                        e0 += fx * (nx * (P[i, e, 0] - P[i, s, 0]) + nz * (P[i, e, 3] - P[i, s, 3])) \
                            + fy * (P[i, e, 6] - P[i, s, 6])
                        e1 += fx * (nx * (P[i, e, 1] - P[i, s, 1]) + nz * (P[i, e, 4] - P[i, s, 4])) \
                            + fy * (P[i, e, 7] - P[i, s, 7])
                        e2 += fx * (nx * (P[i, e, 2] - P[i, s, 2]) + nz * (P[i, e, 5] - P[i, s, 5])) \
                            + fy * (P[i, e, 8] - P[i, s, 8])
                    else:
                        e -= W
                        e0 += fx * (nx * (P[i, W, 0] - P[i, s, 0] + P[i, e, 0])
                                    + nz * (P[i, W, 3] - P[i, s, 3] + P[i, e, 3])) \
                            + fy * (P[i, W, 6] - P[i, s, 6] + P[i, e, 6])
                        e1 += fx * (nx * (P[i, W, 1] - P[i, s, 1] + P[i, e, 1])
                                    + nz * (P[i, W, 4] - P[i, s, 4] + P[i, e, 4])) \
                            + fy * (P[i, W, 7] - P[i, s, 7] + P[i, e, 7])
                        e2 += fx * (nx * (P[i, W, 2] - P[i, s, 2] + P[i, e, 2])
                                    + nz * (P[i, W, 5] - P[i, s, 5] + P[i, e, 5])) \
                            + fy * (P[i, W, 8] - P[i, s, 8] + P[i, e, 8])
                # Straddling: not-dark minus lit, at most two circular runs.
                Ki = Krow[i]
                kbi = kb[i] if kb[i] * rowmax[i] > Ki * Ki else 0.0  # any texel needing more than Ki?
                omi = omega[i]
                a_m = ny * zm[i]
                s_m = sm[i]
                for piece in range(2):
                    if qfull:
                        if pl == W or piece == 1:
                            continue
                        if pl == 0:
                            st, ln = 0, W
                        else:
                            st, ln = p0 + pl, W - pl
                    elif ql > 0:
                        if pl == 0:
                            if piece == 1:
                                continue
                            st, ln = q0, ql
                        elif piece == 0:
                            st, ln = q0, p0 - q0
                        else:
                            st, ln = p0 + pl, q0 + ql - (p0 + pl)
                    else:
                        continue
                    c = st % W
                    for _ in range(ln):
                        r0 = px[i, c, 0]
                        r1 = px[i, c, 1]
                        r2 = px[i, c, 2]
                        t = nx * slon[c] + nz * clon[c]
                        K = Ki
                        if kbi > 0.0:
                            K = _texel_k(Ki, kbi, max(r0, max(r1, r2)), kmax)
                        if K == 1:  # midpoint (equal-area centre of the cell)
                            v = a_m + s_m * t
                            wgt = omi * v if v > 0.0 else 0.0
                        else:
                            wgt = _texel_weight(ny, t, cz[i], sz[i], zt[i], zb[i], omi, S[i], Y[i], sinb[i],
                                                dlon, K, nx, nz, slon[c], clon[c], tbuf)
                        e0 += wgt * r0
                        e1 += wgt * r1
                        e2 += wgt * r2
                        c += 1
                        if c == W:
                            c = 0
            out[k, 0] += e0
            out[k, 1] += e1
            out[k, 2] += e2


@njit(cache=True, nogil=True)
def _texel_list(nrm, rows, cols, rad, Ks, cz, sz, zt, zb, omega, S, Y, sinb, slon, clon, W, kmax, out):
    """out (N, 3) += Σ over listed texels of rad_t ∫_t max(0, n·ω) dω (same rule as _exact_rows).

    rows, cols, Ks (T,) int64; rad (T, 3) radiance; row constants are full-map (H,) arrays.
    """
    dlon = 2.0 * math.pi / W
    tbuf = np.empty(kmax)
    for k in range(nrm.shape[0]):
        nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
        for t in range(rows.shape[0]):
            i = rows[t]
            c = cols[t]
            wgt = _texel_weight(ny, nx * slon[c] + nz * clon[c], cz[i], sz[i], zt[i], zb[i], omega[i], S[i],
                                Y[i], sinb[i], dlon, Ks[t], nx, nz, slon[c], clon[c], tbuf)
            out[k, 0] += wgt * rad[t, 0]
            out[k, 1] += wgt * rad[t, 1]
            out[k, 2] += wgt * rad[t, 2]


@njit(cache=True, nogil=True)
def _midpoint_rows(nrm, px, dirs, omega, out):
    """Brute force: out (N, 3) += Σ_t L_t Ω_t max(0, n·ω_t) over the rows px (R, W, 3).

    dirs (R, W, 3) texel-centre directions, omega (R,). Rows are swept a few at a time for all
    normals, so the texels stay in cache.
    """
    R, W = px.shape[0], px.shape[1]
    step = max(1, 4096 // W)
    for r0 in range(0, R, step):
        r1 = min(R, r0 + step)
        for k in range(nrm.shape[0]):
            nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
            e0 = 0.0
            e1 = 0.0
            e2 = 0.0
            for i in range(r0, r1):
                oi = omega[i]
                for c in range(W):
                    v = nx * dirs[i, c, 0] + ny * dirs[i, c, 1] + nz * dirs[i, c, 2]
                    if v > 0.0:
                        v *= oi
                        e0 += v * px[i, c, 0]
                        e1 += v * px[i, c, 1]
                        e2 += v * px[i, c, 2]
            out[k, 0] += e0
            out[k, 1] += e1
            out[k, 2] += e2


# --------------------------------------------------------------------------------------
# Accumulators (in-memory or streamed rows)
# --------------------------------------------------------------------------------------
def _threads() -> int:
    return max(1, min(8, os.cpu_count() or 1))


class _ExactAccumulator:
    """E (N, 3) of the exact method, fed row blocks of one h x w map."""

    def __init__(self, normals: np.ndarray, h: int, w: int, L_ref: float, tol: float = STRADDLE_TOL):
        self.n = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
        self.h, self.w = h, w
        self.rows = _row_params(h, w, L_ref, tol)
        self.slon, self.clon = _col_params(w)
        self.E = np.zeros((self.n.shape[0], 3))
        nthreads = _threads()
        n = self.n.shape[0]
        parts = max(1, min(n, nthreads * 4))
        cuts = np.linspace(0, n, parts + 1).astype(np.int64)
        self.chunks = [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
        self.pool = ThreadPoolExecutor(nthreads) if nthreads > 1 and len(self.chunks) > 1 else None

    def add(self, r0: int, px: np.ndarray) -> None:
        """Rows [r0, r0 + R) of radiance px (R, w, 3) float64."""
        R = px.shape[0]
        if self.h < 4 or self.w < 4:  # cells too big for the corner test: integrate each texel
            rr, cc = np.divmod(np.arange(R * self.w), self.w)
            rows = (rr + r0).astype(np.int64)
            m = px.reshape(-1, 3).max(axis=1)
            Ks = np.array([_texel_k_py(int(self.rows.K[i]), float(self.rows.kb[i]), float(v))
                           for i, v in zip(rows, m)], dtype=np.int64)
            rp = self.rows
            _texel_list(self.n, rows, cc.astype(np.int64), np.ascontiguousarray(px.reshape(-1, 3)), Ks, rp.cz,
                        rp.sz, rp.zt, rp.zb, rp.omega, rp.S, rp.Y, rp.sinb, self.slon, self.clon, self.w, K_MAX,
                        self.E)
            return
        rw = self.rows.take(r0, r0 + R)
        P = np.empty((R, self.w + 1, 9))
        _prefix(px, self.slon, self.clon, P)
        # Rows per cache block: ~1 MB of prefix sums stays in L2 while every normal reads it.
        sub = max(1, min(R, (1 << 20) // (72 * (self.w + 1))))
        args = (px, P, rw.cpar, rw.spar, rw.zm, rw.sm, rw.cz, rw.sz, rw.zt, rw.zb, rw.omega, rw.S, rw.Y,
                rw.sinb, rw.K, rw.kb, px.max(axis=(1, 2)), self.slon, self.clon, sub, K_MAX, self.E)

        def run(ch):
            _exact_rows(self.n, ch[0], ch[1], *args)

        if self.pool is None:
            for ch in self.chunks:
                run(ch)
        else:
            list(self.pool.map(run, self.chunks))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
            self.pool = None


# Real SH basis, l ≤ 2 (R&H 2001 order: 00, 1-1, 10, 11, 2-2, 2-1, 20, 21, 22).
@njit(cache=True, nogil=True, inline="always")
def _sh_row(x, y, z):
    """The real SH basis (9-tuple, l <= 2, R&H order) at the unit direction (x, y, z)."""
    c0 = 0.5 * math.sqrt(1.0 / math.pi)
    c1 = math.sqrt(3.0 / (4.0 * math.pi))
    c2 = 0.5 * math.sqrt(15.0 / math.pi)
    c3 = 0.25 * math.sqrt(5.0 / math.pi)
    c4 = 0.25 * math.sqrt(15.0 / math.pi)
    return (c0, c1 * y, c1 * z, c1 * x, c2 * x * y, c2 * y * z, c3 * (3.0 * z * z - 1.0), c2 * x * z,
            c4 * (x * x - y * y))


@njit(cache=True, nogil=True)
def _sh_basis_rows(d, out):
    for i in range(d.shape[0]):
        b = _sh_row(d[i, 0], d[i, 1], d[i, 2])
        for k in range(9):
            out[i, k] = b[k]


def _sh_basis(d: np.ndarray) -> np.ndarray:
    """(..., 9) real SH basis at unit directions d (..., 3) (_sh_row per direction)."""
    d = np.asarray(d, dtype=np.float64)
    flat = np.ascontiguousarray(d.reshape(-1, 3))
    out = np.empty((flat.shape[0], 9))
    _sh_basis_rows(flat, out)
    return out.reshape(d.shape[:-1] + (9,))


@njit(cache=True, nogil=True)
def _sh_rows(px, rowI, colJ, coef):
    """coef (9, 3) += Σ_t L_t ∫_t Y_k(ω) dω over rows px (R, W, 3): exact texel integrals of the
    basis (``_sh_basis``), from rowI (R, 6) = ∫ du of [1, u, s, u·s, s², u²] (u = cos θ = y,
    s = sin θ) and colJ (W, 5) = ∫ dφ of [1, sin φ, cos φ, sin²φ, sin φ cos φ] (``_sh_tables``)."""
    c0 = 0.5 * math.sqrt(1.0 / math.pi)
    c1 = math.sqrt(3.0 / (4.0 * math.pi))
    c2 = 0.5 * math.sqrt(15.0 / math.pi)
    c3 = 0.25 * math.sqrt(5.0 / math.pi)
    c4 = 0.25 * math.sqrt(15.0 / math.pi)
    yk = np.empty(9)
    for i in range(px.shape[0]):
        i1, iu, i_s, ius, iss, iuu = rowI[i, 0], rowI[i, 1], rowI[i, 2], rowI[i, 3], rowI[i, 4], rowI[i, 5]
        for c in range(px.shape[1]):
            j1, js, jc, jss, jsc = colJ[c, 0], colJ[c, 1], colJ[c, 2], colJ[c, 3], colJ[c, 4]
            jcc = j1 - jss
            yk[0] = c0 * i1 * j1
            yk[1] = c1 * iu * j1  # y
            yk[2] = c1 * i_s * jc  # z = s cos φ
            yk[3] = c1 * i_s * js  # x = s sin φ
            yk[4] = c2 * ius * js  # x y
            yk[5] = c2 * ius * jc  # y z
            yk[6] = c3 * (3.0 * iss * jcc - i1 * j1)  # 3 z² − 1
            yk[7] = c2 * iss * jsc  # x z
            yk[8] = c4 * (iss * jss - iuu * j1)  # x² − y²
            for ch in range(3):
                v = px[i, c, ch]
                for k in range(9):
                    coef[k, ch] += yk[k] * v


def _sh_tables(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Row (h, 6) and column (w, 5) integral tables of ``_sh_rows`` (dω = du dφ)."""
    th_t = np.pi * np.arange(h) / h
    th_b = np.pi * (np.arange(h) + 1.0) / h
    ut, ub = np.cos(th_t), np.cos(th_b)
    du = ut - ub
    iu = 0.5 * (ut - ub) * (ut + ub)
    i_s = 0.5 * (th_b - th_t) - 0.5 * np.cos(th_b + th_t) * np.sin(th_b - th_t)  # ∫ sin²θ dθ
    ius = (np.sin(th_b) ** 3 - np.sin(th_t) ** 3) / 3.0
    iuu = (ut ** 3 - ub ** 3) / 3.0
    rowI = np.stack([du, iu, i_s, ius, du - iuu, iuu], axis=1)
    dphi = 2.0 * np.pi / w
    phc = np.pi - dphi * (np.arange(w) + 0.5)
    hs = 2.0 * math.sin(0.5 * dphi)
    colJ = np.stack([np.full(w, dphi), hs * np.sin(phc), hs * np.cos(phc),
                     0.5 * dphi - 0.5 * np.cos(2.0 * phc) * math.sin(dphi), 0.5 * np.sin(2.0 * phc) * math.sin(dphi)],
                    axis=1)
    return np.ascontiguousarray(rowI), np.ascontiguousarray(colJ)


class _SHAccumulator:
    """Order-2 SH projection L_lm (9, 3) of the piecewise-constant radiance, fed row blocks."""

    def __init__(self, h: int, w: int):
        self.h, self.w = h, w
        self.rowI, self.colJ = _sh_tables(h, w)
        self.coef = np.zeros((9, 3))

    def add(self, r0: int, px: np.ndarray) -> None:
        _sh_rows(px, self.rowI[r0:r0 + px.shape[0]], self.colJ, self.coef)

    def evaluate(self, normals: np.ndarray) -> np.ndarray:
        """E (N, 3) at unit normals (N, 3)."""
        return _sh_basis(normals) @ (_SH_A[:, None] * self.coef)

    def close(self) -> None:
        pass


def _feed(acc, img: np.ndarray, block_rows: int | None = None) -> None:
    h, w = img.shape[:2]
    br = block_rows or max(1, _BLOCK_TEXELS // max(1, w))
    for r0 in range(0, h, br):
        acc.add(r0, np.ascontiguousarray(img[r0:r0 + br], dtype=np.float64))


def _mean_max_radiance(img: np.ndarray) -> float:
    h, w = img.shape[:2]
    return float(np.einsum("hw,h->", img.max(axis=2), _solid_angles(h, w)) / (4.0 * np.pi))


def exact_irradiance(img: np.ndarray, normals: np.ndarray, tol: float = STRADDLE_TOL) -> np.ndarray:
    """E (N, 3) of an in-memory lat-long radiance map img (H, W, 3) at unit normals (N, 3)
    (same frame as the map), by the exact method (equation (1) of the module docstring)."""
    img = np.asarray(img, dtype=np.float64)
    h, w = img.shape[:2]
    acc = _ExactAccumulator(normals, h, w, _mean_max_radiance(img), tol)
    try:
        _feed(acc, img)
    finally:
        acc.close()
    return acc.E


def sh_irradiance(img: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """E (N, 3) by order-2 spherical harmonics (approximate) at unit normals (N, 3)."""
    img = np.asarray(img, dtype=np.float64)
    acc = _SHAccumulator(*img.shape[:2])
    _feed(acc, img)
    return acc.evaluate(np.asarray(normals, dtype=np.float64).reshape(-1, 3))


def midpoint_irradiance(img: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Brute-force reference E (N, 3) = Σ_t L_t Ω_t max(0, n·ω_t) over every texel (O(N·H·W))."""
    img = np.ascontiguousarray(img, dtype=np.float64)
    h, w = img.shape[:2]
    n = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((n.shape[0], 3))
    dirs = latlong_directions(h, w)
    omega = _solid_angles(h, w)
    nthreads = _threads()
    cuts = np.linspace(0, n.shape[0], nthreads + 1).astype(np.int64)

    def run(k):
        a, b = cuts[k], cuts[k + 1]
        if b > a:
            _midpoint_rows(n[a:b], img, dirs, omega, out[a:b])

    with ThreadPoolExecutor(nthreads) as pool:
        list(pool.map(run, range(nthreads)))
    return out


def texel_cos_integral(h: int, w: int, row: int, col: int, normals: np.ndarray, L_ref: float = 0.0,
                       K: int | None = None) -> np.ndarray:
    """(N,) ∫_{texel (row, col)} max(0, n·ω) dω (sr) of an h x w lat-long map, as ``exact``
    integrates it (K overrides the sub-sample count of a straddling texel)."""
    rp = _row_params(h, w, L_ref)
    slon, clon = _col_params(w)
    n = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    out = np.zeros((n.shape[0], 3))
    k = int(rp.K[row]) if K is None else int(K)
    _texel_list(n, np.array([row]), np.array([col]), np.ones((1, 3)), np.array([k]), rp.cz, rp.sz,
                rp.zt, rp.zb, rp.omega, rp.S, rp.Y, rp.sinb, slon, clon, w, max(K_MAX, k), out)
    return out[:, 0]


# --------------------------------------------------------------------------------------
# Reading the source (streamed, with the renderer's decoding and validation)
# --------------------------------------------------------------------------------------
def file_sha256(path: str) -> str:
    """Hex sha256 of a file's bytes (the content hash recorded as illum:sourceHash)."""
    return asset_sha256(path)


class _Source:
    """A lat-long image read in row blocks as linear float64 RGB (the renderer's decoding:
    8-bit files are sRGB, 1–2 channel files grey, extra channels ignored)."""

    def __init__(self, path: str):
        import OpenImageIO as oiio

        self.path = path
        if not os.path.isfile(path):
            raise IllumError("file not found", file=path)
        inp = oiio.ImageInput.open(path)
        if inp is None:
            raise IllumError(f"cannot read image: {oiio.geterror()}", file=path)
        self.inp = inp
        spec = inp.spec()
        self.w, self.h, self.nch = spec.width, spec.height, spec.nchannels
        self.tile_h = spec.tile_height if spec.tile_width > 0 else 0
        self.srgb = spec.format.basetype in (oiio.UINT8, oiio.INT8)
        if self.w <= 0 or self.h <= 0 or self.nch <= 0:
            raise IllumError("empty image", file=path)

    def block_rows(self) -> int:
        br = max(1, _BLOCK_TEXELS // self.w)
        if self.tile_h:
            br = max(self.tile_h, (br // self.tile_h) * self.tile_h)
        return br

    def blocks(self):
        """Yield (r0, px (R, W, 3) float64)."""
        import OpenImageIO as oiio

        from renderer.lights.texture import srgb_to_linear

        br = self.block_rows()
        nch = min(self.nch, 3) if self.nch >= 3 else 1
        for r0 in range(0, self.h, br):
            r1 = min(self.h, r0 + br)
            if self.tile_h:
                px = self.inp.read_tiles(0, 0, 0, self.w, r0, r1, 0, 1, 0, nch, oiio.FLOAT)
            else:
                px = self.inp.read_scanlines(0, 0, r0, r1, 0, 0, nch, oiio.FLOAT)
            if px is None:
                raise IllumError(f"cannot read rows {r0}..{r1}: {self.inp.geterror()}", file=self.path)
            px = np.asarray(px, dtype=np.float64).reshape(r1 - r0, self.w, nch)
            if nch == 1:
                px = np.repeat(px, 3, axis=2)
            if self.srgb:
                px = srgb_to_linear(px)
            yield r0, np.ascontiguousarray(px)

    def close(self) -> None:
        self.inp.close()


@dataclass
class _Scan:
    nan: int = 0
    posinf: int = 0
    neginf: int = 0
    negative: int = 0
    max_finite: float = 0.0
    power: float = 0.0  # Σ max-channel radiance × Ω (after sanitizing)

    @property
    def bad(self) -> int:
        return self.nan + self.posinf + self.neginf + self.negative


def _sanitize(px: np.ndarray, max_finite: float) -> np.ndarray:
    """NaN, −Inf and negative -> 0; +Inf -> the map's largest finite value."""
    px = np.where(np.isposinf(px), max_finite, px)
    return np.where(np.isnan(px) | (px < 0.0), 0.0, px)


@njit(cache=True, nogil=True)
def _scan_block(px, omega, counts):
    """counts (6,) += [NaN, +Inf, −Inf, negative texels, max finite value, Σ max(0, max channel)·Ω]
    over px (R, W, 3); a texel counts once, under its first bad kind in that order."""
    mx = counts[4]
    power = 0.0
    for i in range(px.shape[0]):
        row = 0.0
        for c in range(px.shape[1]):
            kind = -1
            m = 0.0
            for ch in range(3):
                v = px[i, c, ch]
                if v != v:
                    kind = 0
                elif v == np.inf:
                    if kind < 0 or kind > 1:
                        kind = 1
                elif v == -np.inf:
                    if kind < 0 or kind > 2:
                        kind = 2
                else:
                    if v < 0.0:
                        if kind < 0:
                            kind = 3
                    elif v > m:
                        m = v
            if kind >= 0:
                counts[kind] += 1.0
            if m > mx:
                mx = m
            row += m
        power += row * omega[i]
    counts[4] = mx
    counts[5] += power


def _scan(src: _Source) -> _Scan:
    """One streamed pass: bad-texel counts (per texel), max finite value, power."""
    omega = _solid_angles(src.h, src.w)
    counts = np.zeros(6)
    for r0, px in src.blocks():
        _scan_block(px, omega[r0:r0 + px.shape[0]], counts)
    return _Scan(nan=int(counts[0]), posinf=int(counts[1]), neginf=int(counts[2]), negative=int(counts[3]),
                 max_finite=float(counts[4]), power=float(counts[5]))


# --------------------------------------------------------------------------------------
# Irradiance EXR I/O
# --------------------------------------------------------------------------------------
def write_irradiance(path: str, E: np.ndarray, meta: dict) -> None:
    """Write E (h, w, 3) as a float32 RGB EXR with string/int/float metadata (atomically), so a
    reader (or a parallel render filling the cache) never sees a half-written file."""
    from .film import write_rgb_exr

    try:
        write_rgb_exr(path, E, meta)
    except OSError as e:
        raise IllumError(str(e), file=path) from e


def read_irradiance(path: str) -> tuple[np.ndarray, dict]:
    """(E (h, w, 3) float64, metadata {illum:source, illum:sourceHash, illum:method, illum:size, ...})."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise IllumError(f"cannot read irradiance map: {oiio.geterror()}", file=path)
    try:
        spec = inp.spec()
        px = inp.read_image(0, 0, 0, min(3, spec.nchannels), oiio.FLOAT)
        meta = {}
        for k in ("illum:source", "illum:sourceHash", "illum:method", "illum:size", "illum:sourceSize",
                  "illum:version", "illum:tolerance", "illum:sanitized"):
            v = spec.getattribute(k)
            if v is not None:
                meta[k] = v
    finally:
        inp.close()
    if px is None:
        raise IllumError("cannot read irradiance map pixels", file=path)
    px = np.asarray(px, dtype=np.float64).reshape(spec.height, spec.width, -1)
    if px.shape[2] == 1:
        px = np.repeat(px, 3, axis=2)
    return px, meta


# --------------------------------------------------------------------------------------
# The tool
# --------------------------------------------------------------------------------------
def _output_shape(size: int) -> tuple[int, int]:
    if not isinstance(size, (int, np.integer)) or size < 4 or size % 2:
        raise SettingsError(f"must be an even integer >= 4 (the output is WIDTH x WIDTH/2), got {size!r}",
                            attribute="--size")
    return int(size) // 2, int(size)


def preconvolve(src: str, out: str, size: int = 128, method: str = "exact", sanitize: bool = False,
                force: bool = False, progress=None) -> dict:
    """Write the cosine-convolved irradiance of lat-long map ``src`` to EXR ``out``.

    src: .exr/.hdr/.tx (any OIIO format) lat-long radiance map, 2:1 unless force.
    out: output EXR path; size x size/2 float32 RGB, same orientation as src; metadata
        illum:source (absolute path), illum:sourceHash (sha256 hex of src's bytes),
        illum:method, illum:size ('WxH'), plus illum:sourceSize, illum:version, illum:tolerance.
    method: 'exact' (equation (1), error bound STRADDLE_TOL·π·L̄) or 'sh' (approximate).
    sanitize: clamp NaN/−Inf/negative texels to 0 and +Inf to the largest finite value
        (otherwise they raise IllumError with their count).
    progress: optional callable(rows_done, rows_total).
    Returns a report dict (paths, hash, shapes, seconds, sanitized counts, ...).
    Raises IllumError (CLI exit 2) for unreadable/invalid input.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise SettingsError(f"unknown method '{method}' (use exact or sh)", attribute="--method")
    oh, ow = _output_shape(size)
    src_abs = os.path.abspath(src)
    out_abs = os.path.abspath(out)
    if src_abs == out_abs:
        raise IllumError("output would overwrite the source map", file=src)
    source = _Source(src_abs)
    try:
        H, W = source.h, source.w
        if W != 2 * H and not force:
            raise IllumError(f"not a 2:1 lat-long map ({W}x{H}); use --force to treat it as one anyway",
                             file=src)
        src_hash = file_sha256(src_abs)
        scan = _scan(source)
        sanitized = {"nan": scan.nan, "posinf": scan.posinf, "neginf": scan.neginf, "negative": scan.negative}
        if scan.bad and not sanitize:
            raise IllumError(
                f"{scan.bad} texel(s) with NaN ({scan.nan}), infinite ({scan.posinf + scan.neginf}) or "
                f"negative ({scan.negative}) values; rerun with --sanitize to clamp them", file=src)
        L_ref = scan.power / (4.0 * np.pi)
        normals = latlong_directions(oh, ow).reshape(-1, 3)
        if method == "exact":
            acc = _ExactAccumulator(normals, H, W, L_ref)
        else:
            acc = _SHAccumulator(H, W)
        t_compute = time.perf_counter()
        try:
            done = 0
            for r0, px in source.blocks():
                if scan.bad:
                    px = _sanitize(px, scan.max_finite)
                acc.add(r0, px)
                done += px.shape[0]
                if progress is not None:
                    progress(done, H)
        finally:
            acc.close()
        E = acc.E if method == "exact" else acc.evaluate(normals)
        t_compute = time.perf_counter() - t_compute
    finally:
        source.close()
    E = E.reshape(oh, ow, 3)
    meta = {
        "illum:source": src_abs,
        "illum:sourceHash": src_hash,
        "illum:method": method,
        "illum:size": f"{ow}x{oh}",
        "illum:sourceSize": f"{W}x{H}",
        "illum:version": ALGO_VERSION,
        "illum:tolerance": float(STRADDLE_TOL) if method == "exact" else 0.0,
        "illum:sanitized": int(scan.bad),
    }
    write_irradiance(out_abs, E, meta)
    return {
        "source": src_abs,
        "output": out_abs,
        "source_hash": src_hash,
        "method": method,
        "size": (ow, oh),
        "source_size": (W, H),
        "sanitized": sanitized if scan.bad else {},
        "seconds": time.perf_counter() - t_start,
        "compute_seconds": t_compute,
        "warnings": [],
    }


# --------------------------------------------------------------------------------------
# Renderer hook: interpolation table
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, error_model="numpy")
def irradiance_row(nx, ny, nz, grid, h, w, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz, zt, zb, omega, S, Y,
                   sinb, slon, clon, src_w, tbuf):
    """IrradianceTable.lookup at one dome-local normal (nx, ny, nz) (normalised here): E as a
    3-tuple, per unit light radiance multiplier. The one formula of the lookup, which the numpy
    API (IrradianceTable.lookup, a loop over rows) and the fast path's vertex kernel both call.

    grid ((h + 2) w, 3): the table's residual grid, row-major; sh (9, 3); the sun texels (T,)
    sun_rows, sun_cols, sun_K, sun_rad (T, 3); the source map's full-row constants (H,) (_Rows
    cz ... sinb) and column centres slon, clon (W,) with src_w = W; tbuf scratch (>= max K)."""
    ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    nx, ny, nz = nx / ln, ny / ln, nz / ln
    a0, a1, a2 = analytic_row(nx, ny, nz, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz, zt, zb, omega, S, Y, sinb,
                              slon, clon, src_w, tbuf)
    # The residual grid, bilinear (longitude wraps; the pole rows 0 and h + 1 close the caps).
    theta = math.atan2(math.hypot(nx, nz), ny)
    u = (math.pi - math.atan2(nx, nz)) / (2.0 * math.pi)
    fx = u * w - 0.5
    fc = math.floor(fx)
    tx = fx - fc
    col0 = int(fc) % w
    col1 = (col0 + 1) % w
    fy = theta / math.pi * h - 0.5
    r0 = min(max(math.floor(fy), 0.0), float(h - 2))
    ty = fy - r0
    e0 = int(r0) + 1
    if fy < 0.0:
        ty = (fy + 0.5) / 0.5
        e0 = 0
    elif fy > h - 1:
        ty = (fy - (h - 1)) / 0.5
        e0 = h
    e1 = e0 + 1
    i00, i01, i10, i11 = e0 * w + col0, e0 * w + col1, e1 * w + col0, e1 * w + col1
    return (_bilinear(a0, grid, 0, i00, i01, i10, i11, tx, ty), _bilinear(a1, grid, 1, i00, i01, i10, i11, tx, ty),
            _bilinear(a2, grid, 2, i00, i01, i10, i11, tx, ty))


@njit(cache=True, nogil=True, error_model="numpy")
def analytic_row(nx, ny, nz, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz, zt, zb, omega, S, Y, sinb, slon, clon,
                 src_w, tbuf):
    """IrradianceTable.analytic at one unit dome-local normal: A(n) as a 3-tuple, the order-2 SH
    irradiance (sh (9, 3) on _sh_row) plus the sun texels' exact ∫ max(0, n·ω) dω (_texel_weight);
    arguments as irradiance_row."""
    yk = _sh_row(nx, ny, nz)
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    for k in range(9):
        a0 += yk[k] * sh[k, 0]
        a1 += yk[k] * sh[k, 1]
        a2 += yk[k] * sh[k, 2]
    dlon = 2.0 * math.pi / src_w
    for t in range(sun_rows.shape[0]):
        i = sun_rows[t]
        c = sun_cols[t]
        wgt = _texel_weight(ny, nx * slon[c] + nz * clon[c], cz[i], sz[i], zt[i], zb[i], omega[i], S[i], Y[i],
                            sinb[i], dlon, sun_K[t], nx, nz, slon[c], clon[c], tbuf)
        a0 += wgt * sun_rad[t, 0]
        a1 += wgt * sun_rad[t, 1]
        a2 += wgt * sun_rad[t, 2]
    return a0, a1, a2


@njit(cache=True, nogil=True, error_model="numpy")
def _analytic_rows(n, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz, zt, zb, omega, S, Y, sinb, slon, clon, src_w,
                   out):
    """out (m, 3) = analytic_row at each unit dome-local normal n (m, 3)."""
    tbuf = np.empty(max(K_MAX, sun_K.max() if sun_K.shape[0] else 0))
    for r in range(n.shape[0]):
        out[r, 0], out[r, 1], out[r, 2] = analytic_row(n[r, 0], n[r, 1], n[r, 2], sh, sun_rows, sun_cols, sun_rad,
                                                       sun_K, cz, sz, zt, zb, omega, S, Y, sinb, slon, clon, src_w,
                                                       tbuf)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _bilinear(a, grid, ch, i00, i01, i10, i11, tx, ty):
    """a + the grid's channel ch interpolated between rows i00, i01 (top) and i10, i11 (bottom)."""
    top = grid[i00, ch] * (1.0 - tx) + grid[i01, ch] * tx
    bot = grid[i10, ch] * (1.0 - tx) + grid[i11, ch] * tx
    return a + top * (1.0 - ty) + bot * ty


@njit(cache=True, nogil=True, error_model="numpy")
def _lookup_rows(n, grid, h, w, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz, zt, zb, omega, S, Y, sinb, slon,
                 clon, src_w, out):
    """out (m, 3) = irradiance_row at each dome-local normal n (m, 3)."""
    tbuf = np.empty(max(K_MAX, sun_K.max() if sun_K.shape[0] else 0))
    for r in range(n.shape[0]):
        e = irradiance_row(n[r, 0], n[r, 1], n[r, 2], grid, h, w, sh, sun_rows, sun_cols, sun_rad, sun_K, cz, sz,
                           zt, zb, omega, S, Y, sinb, slon, clon, src_w, tbuf)
        out[r, 0] = e[0]
        out[r, 1] = e[1]
        out[r, 2] = e[2]


def _table_arrays(t: "IrradianceTable") -> tuple:
    """The arrays irradiance_row takes for table t, in its order from grid to src_w."""
    rp = t.src_rows
    if t._cols is None:
        t._cols = _col_params(t.src_w)
    h, w = t.shape
    f64, i64 = np.float64, np.int64
    c = np.ascontiguousarray
    return (c(t.grid.reshape(-1, 3), f64), h, w, c(t.sh, f64), c(t.sun_rows, i64), c(t.sun_cols, i64),
            c(np.reshape(t.sun_rad, (-1, 3)), f64), c(t.sun_K, i64),
            *(c(getattr(rp, k), f64) for k in ("cz", "sz", "zt", "zb", "omega", "S", "Y", "sinb")),
            c(t._cols[0], f64), c(t._cols[1], f64), int(t.src_w))


def pack_tables(tables) -> tuple:
    """Several IrradianceTables (a list; None entries give nothing) as one record for compiled
    code, table j looked up by ``packed_row``: (grid (G, 3), g_off (k + 1,), hw (k, 2) int64,
    sh (k, 9, 3), s_off (k + 1,), sun_rows, sun_cols, sun_rad (T, 3), sun_K, r_off (k + 1,), the
    eight row-constant arrays concatenated, c_off (k + 1,), slon, clon, src_w (k,), kmax), k the
    number of tables (None ones included, empty)."""
    arrs = [_table_arrays(t) if t is not None else None for t in tables]
    k = len(arrs)
    f64, i64 = np.float64, np.int64

    def cat(i, shape, dtype):
        parts = [a[i] for a in arrs if a is not None]
        return np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros(shape), dtype=dtype)

    def off(i):
        return np.ascontiguousarray(np.concatenate([[0], np.cumsum([0 if a is None else a[i].shape[0]
                                                                     for a in arrs])]), dtype=i64)

    hw = np.array([[a[1], a[2]] if a is not None else [0, 0] for a in arrs], dtype=i64).reshape(k, 2)
    sh = np.array([a[3] if a is not None else np.zeros((9, 3)) for a in arrs], dtype=f64).reshape(k, 9, 3)
    rows = tuple(cat(i, (0,), f64) for i in range(8, 16))
    src_w = np.array([a[18] if a is not None else 1 for a in arrs], dtype=i64)
    sun_K = cat(7, (0,), i64)
    kmax = int(max(K_MAX, sun_K.max() if sun_K.size else 0))
    return (cat(0, (0, 3), f64), off(0), hw, sh, off(4), cat(4, (0,), i64), cat(5, (0,), i64), cat(6, (0, 3), f64),
            sun_K, off(8), *rows, off(16), cat(16, (0,), f64), cat(17, (0,), f64), src_w, kmax)


@njit(cache=True, nogil=True, error_model="numpy")
def packed_row(PK, j, nx, ny, nz, tbuf):
    """irradiance_row of table j of a pack_tables record at dome-local normal (nx, ny, nz)."""
    (grid, g_off, hw, sh, s_off, sun_rows, sun_cols, sun_rad, sun_K, r_off, cz, sz, zt, zb, omega, S, Y, sinb,
     c_off, slon, clon, src_w, _kmax) = PK
    g0, g1 = g_off[j], g_off[j + 1]
    s0, s1 = s_off[j], s_off[j + 1]
    r0, r1 = r_off[j], r_off[j + 1]
    q0, q1 = c_off[j], c_off[j + 1]
    return irradiance_row(nx, ny, nz, grid[g0:g1], hw[j, 0], hw[j, 1], sh[j], sun_rows[s0:s1], sun_cols[s0:s1],
                          sun_rad[s0:s1], sun_K[s0:s1], cz[r0:r1], sz[r0:r1], zt[r0:r1], zb[r0:r1], omega[r0:r1],
                          S[r0:r1], Y[r0:r1], sinb[r0:r1], slon[q0:q1], clon[q0:q1], src_w[j], tbuf)


@dataclass
class IrradianceTable:
    """Interpolated unshadowed irradiance of one dome texture (per unit of the light's L).

    lookup(n) = A(n) + bilinear(E − A)(n), where E (h, w, 3) is the exact irradiance at the
    output texel centres, plus the two poles, and A is computed exactly at any n:
      * the order-2 SH irradiance of the texture minus its sun texels (the smooth bulk of E),
      * the exact contribution (1) of the ≤ _SUN_MAX brightest texels holding more than
        _SUN_FRACTION of the power (their max(0, n·s) ramps are what bilinear cannot follow).
    At the texel centres lookup == E exactly; between them only the residual E − A is
    interpolated (longitude wraps; rows extend to pole values so the caps are second order).

    grid: (h + 2, w, 3) residual, ext row 0 = north pole (+Y), ext row h+1 = south pole.
    """

    grid: np.ndarray
    sh: np.ndarray  # (9, 3) Â_l·L_lm
    sun_rows: np.ndarray
    sun_cols: np.ndarray
    sun_rad: np.ndarray  # (T, 3)
    sun_K: np.ndarray
    src_rows: _Rows
    src_w: int
    E: np.ndarray | None = None  # (h, w, 3) the exact E at the texel centres (what is cached)
    source: str = ""  # where E came from: 'authored' | 'cache' | 'computed'
    info: dict = field(default_factory=dict)
    _cols: tuple | None = field(default=None, repr=False)  # (sin φ_c, cos φ_c) of the source columns

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape[0] - 2, self.grid.shape[1]

    def analytic(self, n: np.ndarray) -> np.ndarray:
        """A(n) (m, 3) at unit dome-local normals n (m, 3): analytic_row per normal."""
        n = np.ascontiguousarray(np.asarray(n, dtype=np.float64).reshape(-1, 3))
        A = np.empty((n.shape[0], 3))
        arrs = _table_arrays(self)
        _analytic_rows(n, *arrs[3:], A)
        return A

    def lookup(self, n: np.ndarray) -> np.ndarray:
        """E (m, 3) at unit dome-local normals n (m, 3) (per unit light radiance multiplier):
        irradiance_row per normal."""
        n = np.ascontiguousarray(np.asarray(n, dtype=np.float64).reshape(-1, 3))
        out = np.empty((n.shape[0], 3))
        _lookup_rows(n, *_table_arrays(self), out)
        return out


def _sun_texels(m: np.ndarray, p: np.ndarray, rp: _Rows):
    """Texels holding > _SUN_FRACTION of the power (at most _SUN_MAX): (rows, cols, K) int64.
    m (H, W) max-channel radiance, p (H, W) its power m·Ω."""
    w = m.shape[1]
    flat = p.ravel()
    total = float(flat.sum())
    k = min(_SUN_MAX, flat.size)
    if total <= 0.0 or k == 0:
        z = np.zeros(0, dtype=np.int64)
        return z, z, z
    top = np.argpartition(flat, flat.size - k)[flat.size - k:]
    top = np.sort(top[flat[top] > _SUN_FRACTION * total])
    rows, cols = (top // w).astype(np.int64), (top % w).astype(np.int64)
    Ks = np.array([_texel_k_py(int(rp.K[r]), float(rp.kb[r]), float(m[r, c])) for r, c in zip(rows, cols)],
                  dtype=np.int64)
    return rows, cols, Ks


def _texel_k_py(Krow: int, kb: float, m: float) -> int:
    return int(_texel_k(Krow, kb, m, K_MAX))


def _pole_irradiance(img: np.ndarray) -> np.ndarray:
    """Exact E (2, 3) at +Y and −Y: ∫_texel max(0, ±z) dω = Δφ (max(0, ±z)² at its ends) / 2."""
    h, w = img.shape[:2]
    z = np.cos(np.pi * np.arange(h + 1) / h)
    rows = img.sum(axis=1)  # (H, 3)
    up = 0.5 * (np.maximum(z[:-1], 0.0) ** 2 - np.maximum(z[1:], 0.0) ** 2)
    down = 0.5 * (np.maximum(-z[1:], 0.0) ** 2 - np.maximum(-z[:-1], 0.0) ** 2)
    dphi = 2.0 * np.pi / w
    return dphi * np.stack([up @ rows, down @ rows])


def build_table(img: np.ndarray, E: np.ndarray | None = None, size: int = LOAD_SIZE,
                analytic: bool = True) -> IrradianceTable:
    """IrradianceTable of radiance img (H, W, 3); E (h, w, 3) the exact irradiance at the texel
    centres of an h x w grid if already known (authored / cached), else computed (size x size/2).
    analytic=False interpolates E itself (plain bilinear; kept to measure what A(n) buys)."""
    img = np.ascontiguousarray(img, dtype=np.float64)
    H, W = img.shape[:2]
    omega = _solid_angles(H, W)
    m = img.max(axis=2)
    p = m * omega[:, None]
    L_ref = float(p.sum()) / (4.0 * np.pi)
    rp = _row_params(H, W, L_ref)
    if E is None:
        oh, ow = _output_shape(size)
        acc = _ExactAccumulator(latlong_directions(oh, ow).reshape(-1, 3), H, W, L_ref)
        try:
            _feed(acc, img)
        finally:
            acc.close()
        # Rounded as the float32 cache file will hold it: a render is the same whether the
        # table was just computed or read back.
        E = acc.E.reshape(oh, ow, 3).astype(np.float32).astype(np.float64)
    h, w = E.shape[:2]
    sh = np.zeros((9, 3))
    rows = cols = Ks = np.zeros(0, dtype=np.int64)
    rad = np.zeros((0, 3))
    if analytic:
        rows, cols, Ks = _sun_texels(m, p, rp)
        rad = np.ascontiguousarray(img[rows, cols])
        sh_acc = _SHAccumulator(H, W)
        _feed(sh_acc, img)
        # The SH part covers the texture minus its sun texels (projection is linear).
        sun = _SHAccumulator(H, W)
        for r, c, v in zip(rows, cols, rad):
            one = np.zeros((1, W, 3))
            one[0, c] = v
            sun.add(int(r), one)
        sh = _SH_A[:, None] * (sh_acc.coef - sun.coef)
    table = IrradianceTable(grid=np.zeros((h + 2, w, 3)), sh=sh, sun_rows=rows, sun_cols=cols, sun_rad=rad,
                            sun_K=Ks, src_rows=rp, src_w=W, E=E)
    table.grid[1:h + 1] = E - table.analytic(latlong_directions(h, w).reshape(-1, 3)).reshape(h, w, 3)
    poles = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    resid = _pole_irradiance(img) - table.analytic(poles)
    table.grid[0] = resid[0]
    table.grid[h + 1] = resid[1]
    return table


def irradiance_cache_dir() -> str:
    """$ILLUM_CACHE_DIR if set, else ~/.cache/illum/irradiance."""
    d = os.environ.get("ILLUM_CACHE_DIR")
    return d if d else os.path.join(os.path.expanduser("~"), ".cache", "illum", "irradiance")


def dome_irradiance_table(texture_file: str, img: np.ndarray, authored: str = "", prim: str = "",
                          size: int = LOAD_SIZE, texture_data: bytes | None = None
                          ) -> tuple[IrradianceTable, list[str]]:
    """The table DomeLight.irradiance_lookup interpolates, and warnings.

    texture_file: the dome's texture (its sha256 is the freshness key); img (H, W, 3) its
    texels as the renderer loaded them; texture_data: the texture's bytes when it is not a file
    (inside a .usdz package: LightDesc.texture_data); authored: absolute path of
    illum:dome:irradiance ('').
    Authored maps are used when their illum:sourceHash matches and their method is 'exact';
    otherwise (stale, approximate, unreadable) a warning and the load-time computation, cached
    on disk by content hash.
    """
    warnings: list[str] = []
    t0 = time.perf_counter()
    src_hash = asset_sha256(texture_file, texture_data)
    label = prim or texture_file
    if authored:
        why = ""
        try:
            E, meta = read_irradiance(authored)
        except IllumError as e:
            why, E, meta = f"cannot be read ({e})", None, {}
        if E is not None:
            if meta.get("illum:sourceHash") != src_hash:
                why = (f"is stale: its illum:sourceHash ({str(meta.get('illum:sourceHash', 'missing'))[:12]}) "
                       f"does not match the texture '{os.path.basename(texture_file)}' ({src_hash[:12]})")
            elif meta.get("illum:method", "exact") != "exact":
                why = f"was made with the approximate method '{meta.get('illum:method')}'"
            elif not np.all(np.isfinite(E)) or E.shape[0] < 2:
                why = "holds non-finite values or is too small"
        if not why:
            table = build_table(img, E)
            table.source = "authored"
            table.info = {"seconds": time.perf_counter() - t0, "file": authored}
            return table, warnings
        warnings.append(f"{label}: illum:dome:irradiance '{authored}' {why}; recomputing it at load "
                        f"(rerun `illum preconvolve`)")
    oh, ow = _output_shape(size)
    cache = os.path.join(irradiance_cache_dir(), f"{src_hash}-{ow}x{oh}-v{ALGO_VERSION}.exr")
    E = None
    if os.path.isfile(cache):
        try:
            E, meta = read_irradiance(cache)
            if meta.get("illum:sourceHash") != src_hash or E.shape[:2] != (oh, ow):
                E = None
        except IllumError:
            E = None
    if E is not None:
        table = build_table(img, E)
        table.source = "cache"
    else:
        table = build_table(img, None, size)
        table.source = "computed"
        E = table.E
        meta = {"illum:source": os.path.abspath(texture_file), "illum:sourceHash": src_hash,
                "illum:method": "exact", "illum:size": f"{ow}x{oh}",
                "illum:sourceSize": f"{img.shape[1]}x{img.shape[0]}", "illum:version": ALGO_VERSION,
                "illum:tolerance": float(STRADDLE_TOL), "illum:sanitized": 0}
        try:
            write_irradiance(cache, E, meta)
        except (OSError, IllumError) as e:
            warnings.append(f"{label}: cannot cache the dome irradiance in '{cache}': {e}")
    table.info = {"seconds": time.perf_counter() - t0, "file": cache}
    return table, warnings


# --------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------
def _default_output(src: str) -> str:
    base, _ = os.path.splitext(src)
    return base + "_irradiance.exr"


def cmd_preconvolve(a) -> int:
    if (a.stage is None) != (a.light is None):
        raise SettingsError("--stage and --light go together", attribute="--stage" if a.stage is None else "--light")
    out = a.output or _default_output(a.env)
    if a.stage:  # check the light before spending the compute
        from renderer.usd.preconvolve_author import open_dome

        open_dome(a.stage, a.light)
    bar = None
    progress = None
    if not a.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=1, unit="row", desc="preconvolve", file=sys.stderr)

        def progress(done, total):
            bar.total = total
            bar.n = done
            bar.refresh()
    try:
        rep = preconvolve(a.env, out, size=a.size, method=a.method, sanitize=a.sanitize, force=a.force,
                          progress=progress)
    finally:
        if bar is not None:
            bar.close()
    notes, warnings = [], []
    if rep["sanitized"]:
        s = rep["sanitized"]
        notes.append(f"sanitized {sum(s.values())} texel(s): {s['nan']} NaN, {s['posinf']} +Inf, "
                     f"{s['neginf']} -Inf, {s['negative']} negative")
    if a.stage:
        from renderer.usd.preconvolve_author import author_dome_irradiance

        auth = author_dome_irradiance(a.stage, a.light, rep["output"], source_hash=rep["source_hash"])
        rep["authored"] = auth
        warnings.extend(auth.get("warnings", []))
        if a.method != "exact":
            warnings.append(f"--method {a.method} is approximate: the renderer does not use it as the control "
                            f"variate's integral (it recomputes an exact one at load)")
    if not a.quiet:
        for m in notes:
            print(f"illum: {m}", file=sys.stderr)
        for m in warnings:
            print(f"illum: warning: {m}", file=sys.stderr)
        w, h = rep["size"]
        print(f"illum: wrote {rep['output']} ({w}x{h}, {rep['method']}, {rep['seconds']:.2f} s)", file=sys.stderr)
        if a.stage:
            print(f"illum: authored illum:dome:irradiance = @{rep['authored']['value']}@ on {a.light} in "
                  f"{rep['authored']['layer']}", file=sys.stderr)
    return 0


def register_cli(subparsers) -> None:
    """Add `illum preconvolve` to the `illum` argument parser."""

    def size(s):
        try:
            return int(s)
        except ValueError:
            import argparse

            raise argparse.ArgumentTypeError(f"--size expects an integer, got {s!r}")

    p = subparsers.add_parser("preconvolve", help="precompute a DomeLight texture's irradiance map",
                              description="Cosine-convolve a lat-long HDR into an irradiance map "
                                          "(E(n) = ∫ L max(0, n·ω) dω) for the dome control variate.")
    p.add_argument("env", metavar="ENV", help="lat-long radiance map (.exr, .hdr, .tx)")
    p.add_argument("-o", "--output", help="output EXR (default: ENV_irradiance.exr)")
    p.add_argument("--size", type=size, default=128, metavar="WIDTH",
                   help="output width (height = WIDTH/2; default 128)")
    p.add_argument("--method", choices=METHODS, default="exact",
                   help="exact (full-resolution integral) or sh (order-2 spherical harmonics, approximate)")
    p.add_argument("--stage", help="also author illum:dome:irradiance on --light in this stage")
    p.add_argument("--light", help="DomeLight prim path (with --stage)")
    p.add_argument("--sanitize", action="store_true", help="clamp NaN/Inf/negative texels instead of failing")
    p.add_argument("--force", action="store_true", help="accept a map that is not 2:1")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.set_defaults(func=cmd_preconvolve)
