"""numba kernels for the hot paths of PreviewSurfaceBSDF (evaluation, sampling, wo terms).

One loop over rows with scalar math: no (n,)-sized temporaries, about 20x faster than the
equivalent numpy expression. The formulas are exactly those of ``preview_surface.py`` and
``microfacet.py`` (the numpy versions there are the reference the tests compare against).

Kernels are compiled with ``nogil=True`` (render threads can run them concurrently) and
``cache=True`` (compiled once per machine, into __pycache__), and are *not* ``parallel``: numba's
default threading layer is not safe to enter from several Python threads at once, and the
integrator already parallelises over threads.

Per-point parameters live in one packed (n, K) float64 array ``P`` (columns below), so that
``take(rows)`` is a single gather and the kernels read one row of one array per point:

    RHO..RHO+2   rho_d, diffuse base albedo            F0..F0+2    specular F0 (normal incidence)
    F90..F90+2   specular F90 (grazing; Schlick F = F0 + (F90 - F0)(1 - wo.h)^5)
    ALPHA        GGX alpha (>= ALPHA_MIN)              KD..KD+2    rho_d / (pi (1 - E_avg))
    INV_OMA..+2  1 / (1 - E_avg) (0 if E_avg ~ 1)
    J0, FY       the alpha coordinate of the albedo tables (node index as a float, fraction):
                 wo- and wi-independent, so computed once at construction (saves a log per lookup)
    COS_B        cos_o = wo.z the wo terms below were computed for (NaN: none yet)
    AO_B, BO_B   (A, B) = albedo-table lookup at (COS_B, alpha), i.e. E(wo) = F0 A + F90 B
    PD_B         P_diffuse(wo), the lobe-selection probability

The wo terms depend on wo only through wo.z, so a kernel that meets ``wo[r, 2] == P[r, COS_B]``
reuses them bit for bit instead of repeating the table lookup (the GGX albedo lookup was the
most repeated piece of work per vertex: diffuse_constant, f, f_diffuse, pdf and sample_f all
need E(wo)). The check is by value, so any wo (the bound array, a row subset of it, a copy)
gets exactly the results it would get without the cache.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.bsdfs.microfacet import ALPHA_MIN, LUMINANCE, N_A, N_MU
from renderer.kernels import guard_cache, module_dispatchers
from renderer.kernels.vmath import sincos

_LOG_ALPHA_MIN = math.log(ALPHA_MIN)
_INV_PI = 1.0 / math.pi
_LUM_R, _LUM_G, _LUM_B = (float(v) for v in LUMINANCE)

# Packed parameter columns (see the module docstring).
RHO = 0
F0 = 3
ALPHA = 6
KD = 7
INV_OMA = 10
J0 = 13
FY = 14
COS_B = 15
AO_B = 16
BO_B = 17
PD_B = 18
F90 = 19
K = 22


# Helpers are ordinary njit functions taking and returning scalars (plus the tables, in the
# branch-free ``_lookup``); LLVM inlines them. Array reads with branches around them stay in the
# kernels' own loop bodies: an earlier version with ``inline="always"`` helpers that took the
# arrays and returned from several branches ran f + pdf at ~150 ns per row instead of ~37.
@njit(cache=True, nogil=True)
def _alpha_coord(alpha):
    """(j0, fy): the log-alpha table coordinate, as AlbedoTables._r_coord."""
    la = math.log(min(max(alpha, ALPHA_MIN), 1.0))
    y = (1.0 - la / _LOG_ALPHA_MIN) * (N_A - 1)
    j0 = min(max(int(y), 0), N_A - 2)
    fy = min(max(y - j0, 0.0), 1.0)
    return j0, fy


@njit(cache=True, nogil=True, inline="always")
def _lookup_weights(mu, fy):
    """(i0, w00, w10, w01, w11): the mu row and the bilinear weights of _lookup's four nodes
    (scalars only, so the fast path's vectorised passes can inline it)."""
    m = min(max(mu, 0.0), 1.0)
    x = math.sqrt(m) * (N_MU - 1)
    i0 = min(int(x), N_MU - 2)
    fx = x - i0
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    return i0, w00, w10, w01, w11


@njit(cache=True, nogil=True)
def _lookup(mu, j0, fy, ta, tb):
    """Bilinear (A, B) at (mu, alpha coordinate (j0, fy)); as AlbedoTables.lookup. Branch-free."""
    i0, w00, w10, w01, w11 = _lookup_weights(mu, fy)
    a = ta[i0, j0] * w00 + ta[i0 + 1, j0] * w10 + ta[i0, j0 + 1] * w01 + ta[i0 + 1, j0 + 1] * w11
    b = tb[i0, j0] * w00 + tb[i0 + 1, j0] * w10 + tb[i0, j0 + 1] * w01 + tb[i0 + 1, j0 + 1] * w11
    return a, b


@njit(cache=True, nogil=True)
def _p_diffuse(rho0, rho1, rho2, f00, f01, f02, g0, g1, g2, ao, bo):
    """Probability of picking the diffuse lobe: lum(rho_d (1 - E_o)) / (that + lum(E_o)), with
    E_o = F0 ao + F90 bo per channel (F0 = f0k, F90 = gk)."""
    e0 = f00 * ao + g0 * bo
    e1 = f01 * ao + g1 * bo
    e2 = f02 * ao + g2 * bo
    wd = _LUM_R * rho0 * (1.0 - e0) + _LUM_G * rho1 * (1.0 - e1) + _LUM_B * rho2 * (1.0 - e2)
    ws = _LUM_R * e0 + _LUM_G * e1 + _LUM_B * e2
    tot = wd + ws
    return wd / tot if tot > 0.0 else 0.5


@njit(cache=True, nogil=True)
def _specular(wox, woy, woz, wix, wiy, wiz, a):
    """Specular factors of (wo, wi) for GGX alpha a: (ok, D V, Schlick weight, pdf_specular).

    ok: both directions above the surface and h = wo + wi non-degenerate (else all 0)."""
    hx = wox + wix
    hy = woy + wiy
    hz = woz + wiz
    hl = math.sqrt(hx * hx + hy * hy + hz * hz)
    ok = woz > 0.0 and wiz > 0.0 and hl > 1e-12
    dv = 0.0
    w = 0.0
    pdf_s = 0.0
    if ok:
        inv = 1.0 / hl  # one division, three products (the division unit bounds the fast path)
        hx *= inv
        hy *= inv
        hz *= inv
        a2 = a * a
        # GGX D(h).
        t = hz * hz * (a2 - 1.0) + 1.0
        den = math.pi * t * t
        d = a2 / den if (hz > 0.0 and den > 0.0) else 0.0
        # Height-correlated visibility V = 1 / (2 (cos_i s_o + cos_o s_i)).
        s_o = math.sqrt(max(woz * woz + a2 * (1.0 - woz * woz), 0.0))
        s_i = math.sqrt(max(wiz * wiz + a2 * (1.0 - wiz * wiz), 0.0))
        vden = 2.0 * (wiz * s_o + woz * s_i)
        v = 1.0 / vden if vden > 0.0 else 0.0
        dv = d * v
        # Schlick weight on wo.h.
        cd = min(max(wox * hx + woy * hy + woz * hz, 0.0), 1.0)
        m1 = 1.0 - cd
        m2 = m1 * m1
        w = m2 * m2 * m1
        # VNDF reflection pdf G1(wo) D / (4 cos_o) = D / (2 (cos_o + s_o)).
        pden = 2.0 * (woz + s_o)
        pdf_s = d / pden if pden > 0.0 else 0.0
    return ok, dv, w, pdf_s


@njit(cache=True, nogil=True)
def _sample_dir(wox, woy, woz, a, pick_diffuse, u0, u1):
    """The sampled wi (3 floats) of sample_f: cosine-weighted (concentric map) if pick_diffuse,
    else a GGX visible normal (spherical caps, Dupuy & Benyoub 2023) reflected; +z if wo.z <= 0.

    Both lobes' arithmetic is written without branches around it and share one cos and one sin
    (of the concentric map's angle or of the cap's azimuth): the fast path's vectorised surface
    pass computes both lobes for every lane, and cos and sin are its costliest calls."""
    # Cosine-weighted hemisphere via the concentric disk map (sampling.py's warp).
    sa = 2.0 * u0 - 1.0
    sb = 2.0 * u1 - 1.0
    major_a = abs(sa) > abs(sb)
    rad = sa if major_a else sb
    # One division for both branches' ratios (sb / sa or sa / sb): the fast path's vectorised
    # surface pass computes both lobes for every lane and is bound by the division unit.
    ratio = (sb if major_a else sa) / (sa if major_a else (sb if sb != 0.0 else 1.0))
    th = (math.pi / 4.0) * ratio if major_a else (math.pi / 2.0) - (math.pi / 4.0) * ratio
    phi = th if pick_diffuse else 2.0 * math.pi * u0
    sin_phi, cos_phi = sincos(phi)
    dx = rad * cos_phi
    dy = rad * sin_phi
    dz = math.sqrt(max(0.0, 1.0 - dx * dx - dy * dy))
    # GGX visible normal: the cap around the stretched wo, reflected.
    vx = wox * a
    vy = woy * a
    vz = woz
    vl = math.sqrt(vx * vx + vy * vy + vz * vz)
    # Normalised by one division and three products here and below (see above).
    inv = 1.0 / vl if vl > 0.0 else 1.0
    vx *= inv
    vy *= inv
    vz *= inv
    z = (1.0 - u1) * (1.0 + vz) - vz
    st = math.sqrt(min(max(1.0 - z * z, 0.0), 1.0))
    hx = (st * cos_phi + vx) * a
    hy = (st * sin_phi + vy) * a
    hz = max(z + vz, 0.0)
    # wo reflected about h = H / |H|: r = 2 (wo.H) H / |H|^2 - wo, with no square root (and no
    # final normalisation: r is unit to rounding, as wo is). Both sit on the vectorised surface
    # pass's critical path of dependent square roots and divisions. H = 0 (a measure-zero set of
    # u) falls back to the macro normal.
    hl2 = hx * hx + hy * hy + hz * hz
    if not hl2 > 0.0:
        hx = 0.0
        hy = 0.0
        hz = 1.0
        hl2 = 1.0
    k = 2.0 * (wox * hx + woy * hy + woz * hz) / hl2
    rx = k * hx - wox
    ry = k * hy - woy
    rz = k * hz - woz
    if not woz > 0.0:
        return 0.0, 0.0, 1.0
    if pick_diffuse:
        return dx, dy, dz
    return rx, ry, rz


@njit(cache=True, nogil=True)
def _clip01(x):
    """np.clip(x, 0, 1), NaN passing through as in numpy."""
    return x if x != x else min(max(x, 0.0), 1.0)


# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, _nrt=False)
def inputs_row(P, r, d0, d1, d2, s0, s1, s2, use_spec, metallic, roughness, ior):
    """Row r of P from one point's UsdPreviewSurface inputs (diffuse d0..d2, specular colour
    s0..s2, the workflow flag, metallic, roughness, ior): the RHO, F0, F90 and ALPHA columns
    (PreviewSurfaceBSDF.from_inputs: same formulas and NaN behaviour as the numpy path). The one
    input mapping: inputs_kernel and the per-hit surface rows (renderer/materials.py) call it."""
    m = _clip01(metallic)
    x = ior
    eta = x if x != x else max(x, 0.0)
    q = (eta - 1.0) / (eta + 1.0)  # eta + 1 >= 1
    f0_dielectric = q * q
    for k in range(3):
        d = _clip01(d0 if k == 0 else (d1 if k == 1 else d2))
        if use_spec:
            P[r, F0 + k] = _clip01(s0 if k == 0 else (s1 if k == 1 else s2))
            P[r, F90 + k] = 1.0
            P[r, RHO + k] = d
        else:
            P[r, F0 + k] = f0_dielectric * (1.0 - m) + d * m
            P[r, F90 + k] = (1.0 - m) + d * m
            P[r, RHO + k] = d * (1.0 - m)
    rough = _clip01(roughness)
    a = rough * rough
    P[r, ALPHA] = a if a != a else max(a, ALPHA_MIN)


@njit(cache=True, nogil=True)
def inputs_kernel(diffuse, spec, use_spec, metallic, roughness, ior, P):
    """PreviewSurfaceBSDF.from_inputs: UsdPreviewSurface inputs (colours (n, 3), the rest (n,))
    -> the RHO, F0, F90 and ALPHA columns of P (inputs_row per row)."""
    for r in range(P.shape[0]):
        inputs_row(P, r, diffuse[r, 0], diffuse[r, 1], diffuse[r, 2], spec[r, 0], spec[r, 1], spec[r, 2],
                   use_spec[r], metallic[r], roughness[r], ior[r])


@njit(cache=True, nogil=True, _nrt=False)
def init_row(P, r, ta_avg, tb_avg):
    """Fill the derived columns of row r of P from RHO, F0, F90, ALPHA: KD, INV_OMA, J0, FY;
    clear the wo terms (init_kernel's row)."""
    j0, fy = _alpha_coord(P[r, ALPHA])
    P[r, J0] = j0
    P[r, FY] = fy
    a_avg = ta_avg[j0] * (1.0 - fy) + ta_avg[j0 + 1] * fy
    b_avg = tb_avg[j0] * (1.0 - fy) + tb_avg[j0 + 1] * fy
    for k in range(3):
        oma = 1.0 - (P[r, F0 + k] * a_avg + P[r, F90 + k] * b_avg)
        ok = oma > 1e-9
        P[r, KD + k] = P[r, RHO + k] * _INV_PI / oma if ok else 0.0
        P[r, INV_OMA + k] = 1.0 / oma if ok else 0.0
    P[r, COS_B] = np.nan
    P[r, AO_B] = 0.0
    P[r, BO_B] = 0.0
    P[r, PD_B] = 0.0


@njit(cache=True, nogil=True)
def init_kernel(P, ta_avg, tb_avg):
    """Fill the derived columns of P from RHO, F0, F90, ALPHA: KD, INV_OMA, J0, FY; clear the wo terms."""
    for r in range(P.shape[0]):
        init_row(P, r, ta_avg, tb_avg)


@njit(cache=True, nogil=True)
def bind_kernel(wo, P, ta, tb):
    """Store the wo terms (A_o, B_o, P_d) of wo (n, 3) in P's bound columns."""
    for r in range(wo.shape[0]):
        woz = wo[r, 2]
        ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
        P[r, AO_B] = ao
        P[r, BO_B] = bo
        P[r, PD_B] = _p_diffuse(
            P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
            P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
        )
        P[r, COS_B] = woz


# The wo terms of row r for cosine woz, as a kernel-body snippet would compute them. Written
# out in each kernel (see the note above the helpers). Re-measured in session 4: moving it into
# a plain njit helper `_wo_terms(P, r, woz, ta, tb)` made scatter_kernel 4-11 %, the light half
# 8-14 % and eval 10 % slower per row (16384 random rows, alternated runs), so it stays inline:
#
#     if P[r, COS_B] == woz:      # bound for this very cosine: reuse
#         ao, bo, p_d = P[r, AO_B], P[r, BO_B], P[r, PD_B]
#     else:                       # table lookup + lobe probability
#         ao, bo = _lookup(woz, ...); p_d = _p_diffuse(...)


@njit(cache=True, nogil=True)
def _diffuse_constant(rho, f0, f90, ao, bo):
    """diffuse_constant in one channel for wo.z > 0: rho_d (1 - E(wo)) / pi, with E(wo) =
    F0 A(wo) + F90 B(wo) from the wo terms (ao, bo)."""
    return rho * (1.0 - (f0 * ao + f90 * bo)) * _INV_PI


@njit(cache=True, nogil=True)
def wo_kernel(wo, P, ta, tb, out_dc, out_pd):
    """Per row: diffuse_constant(wo) = rho_d (1 - E(wo)) / pi (0 for wo.z <= 0) into out_dc (n, 3)
    and P_diffuse(wo) into out_pd (n,). Either output may have 0 rows (not wanted)."""
    want_dc = out_dc.shape[0] > 0
    want_pd = out_pd.shape[0] > 0
    for r in range(wo.shape[0]):
        woz = wo[r, 2]
        if P[r, COS_B] == woz:
            ao = P[r, AO_B]
            bo = P[r, BO_B]
            p_d = P[r, PD_B]
        else:
            ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
            p_d = _p_diffuse(
                P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
                P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
            )
        if want_pd:
            out_pd[r] = p_d
        if want_dc:
            up = woz > 0.0
            for k in range(3):
                out_dc[r, k] = _diffuse_constant(P[r, RHO + k], P[r, F0 + k], P[r, F90 + k], ao, bo) if up else 0.0


@njit(cache=True, nogil=True)
def eval_kernel(wo, wi, P, ta, tb, out_f, out_fd, out_fs, out_pdf):
    """f (n, 3), f_diffuse (n, 3), f_specular (n, 3) and the mixture pdf (n,) of (wo, wi);
    outputs with 0 rows are skipped.

    f, f_specular and pdf are 0 unless both directions are above the surface and h = wo + wi is
    non-degenerate; f_diffuse needs only the two cosines (exactly as the numpy methods)."""
    want_f = out_f.shape[0] > 0
    want_fd = out_fd.shape[0] > 0
    want_fs = out_fs.shape[0] > 0
    want_pdf = out_pdf.shape[0] > 0
    want_spec = want_f or want_fs or want_pdf
    for r in range(wo.shape[0]):
        woz = wo[r, 2]
        wiz = wi[r, 2]
        if P[r, COS_B] == woz:
            ao = P[r, AO_B]
            bo = P[r, BO_B]
            p_d = P[r, PD_B]
        else:
            ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
            p_d = _p_diffuse(
                P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
                P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
            )
        both_up = woz > 0.0 and wiz > 0.0
        if both_up:
            ai, bi = _lookup(wiz, int(P[r, J0]), P[r, FY], ta, tb)
        else:
            ai = 0.0
            bi = 0.0
        ok = False
        dv = 0.0
        w = 0.0
        pdf_s = 0.0
        if want_spec:
            ok, dv, w, pdf_s = _specular(wo[r, 0], wo[r, 1], woz, wi[r, 0], wi[r, 1], wiz, P[r, ALPHA])
        for k in range(3):
            fk = P[r, F0 + k]
            gk = P[r, F90 + k]
            c_o = 1.0 - (fk * ao + gk * bo)
            c_i = 1.0 - (fk * ai + gk * bi)
            fd = P[r, KD + k] * c_o * c_i if both_up else 0.0
            fs = (fk + (gk - fk) * w) * dv if ok else 0.0
            if want_f:
                out_f[r, k] = fd + fs if ok else 0.0
            if want_fd:
                out_fd[r, k] = fd
            if want_fs:
                out_fs[r, k] = fs
        if want_pdf:
            out_pdf[r] = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s if ok else 0.0


@njit(cache=True, nogil=True)
def sample_kernel(wo, u_lobe, u, P, ta, tb, out_wi, out_f, out_pdf, out_lobe):
    """Lobe choice with u_lobe, cosine or VNDF sampling with u, then f and pdf at the sample."""
    for r in range(wo.shape[0]):
        wox = wo[r, 0]
        woy = wo[r, 1]
        woz = wo[r, 2]
        a = P[r, ALPHA]
        if P[r, COS_B] == woz:
            ao = P[r, AO_B]
            bo = P[r, BO_B]
            p_d = P[r, PD_B]
        else:
            ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
            p_d = _p_diffuse(
                P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
                P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
            )
        pick_diffuse = u_lobe[r] < p_d
        out_lobe[r] = 0 if pick_diffuse else 1
        wix, wiy, wiz = _sample_dir(wox, woy, woz, a, pick_diffuse, u[r, 0], u[r, 1])
        out_wi[r, 0] = wix
        out_wi[r, 1] = wiy
        out_wi[r, 2] = wiz
        ok, dv, w, pdf_s = _specular(wox, woy, woz, wix, wiy, wiz, a)
        if ok:
            ai, bi = _lookup(wiz, int(P[r, J0]), P[r, FY], ta, tb)
            for k in range(3):
                fk = P[r, F0 + k]
                gk = P[r, F90 + k]
                c_o = 1.0 - (fk * ao + gk * bo)
                c_i = 1.0 - (fk * ai + gk * bi)
                out_f[r, k] = P[r, KD + k] * c_o * c_i + (fk + (gk - fk) * w) * dv
            out_pdf[r] = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s
        else:
            out_f[r, 0] = 0.0
            out_f[r, 1] = 0.0
            out_f[r, 2] = 0.0
            out_pdf[r] = 0.0


# --------------------------------------------------------------------------------------
# Path-vertex kernels: the BSDF's part of one path vertex, fused with the integrator's
# arithmetic around it, so a vertex is a few kernel calls instead of ~60 numpy passes. They
# live here (not in the integrator) because numba's cache is keyed on the defining file only
# (renderer/kernels/__init__.py): the BSDF maths they inline must come from this file.
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _mis_weight(p_this, p_other, power):
    """h(p_this, p_other) with one sample each: power (beta = 2) or balance heuristic.
    An infinite p_this (a delta light) takes the whole weight; an infinite p_other leaves none."""
    # Plain compares rather than math.isinf / isfinite (pdfs are >= 0 or NaN): LLVM's vectoriser
    # cannot widen the llvm.is.fpclass those become, and the fast path's light pass inlines this.
    if p_this == math.inf:
        return 1.0
    if p_other == math.inf:
        return 0.0
    if power:
        f = p_this * p_this
        den = f + p_other * p_other
    else:
        f = p_this
        den = f + p_other
    w = f / den if den > 0.0 else 0.0
    # w is in [0, 1] or NaN (f overflowed): here 'w <= 1' is isfinite(w).
    return w if w <= 1.0 else 0.0


@njit(cache=True, nogil=True)
def light_half_kernel(wo, s, t, ns, ng, wi, L, pdf_l, delta, pmf, power, beta, P, ta, tb, out_c):
    """The light half of continuation MIS at one vertex per row, times the path throughput.

    Per row: wi (world, unit, toward the light) into the shading frame (s, t, ns); the
    integrand f(wo, wi) |cos| L (0 below the shading or geometric horizon: wi.ng <= 0); the
    weight h(pmf p_l, p_b) against the BSDF pdf p_b of wi; divided by p_l (1 for delta lights,
    whose p_l counts as infinite) and by the pick pmf. out_c (n, 3) = beta times that: the
    radiance the vertex adds if the shadow ray is unblocked (0 where the sample is unusable).
    Exactly estimators.mis.mis_light_half(...).Ld * beta / pmf for lights with unit
    diffuse/specular multipliers (the only ones continuation MIS serves).

    wo: (n, 3) local; s, t, ns, ng, wi: (n, 3) world; L: (n, 3); pdf_l, pmf: (n,) solid-angle
    pdf and pick probability; delta, power: (n,) bool; beta: (n, 3).
    """
    for r in range(wo.shape[0]):
        wx = wi[r, 0] * s[r, 0] + wi[r, 1] * s[r, 1] + wi[r, 2] * s[r, 2]
        wy = wi[r, 0] * t[r, 0] + wi[r, 1] * t[r, 1] + wi[r, 2] * t[r, 2]
        wz = wi[r, 0] * ns[r, 0] + wi[r, 1] * ns[r, 1] + wi[r, 2] * ns[r, 2]
        above = wz > 0.0 and (wi[r, 0] * ng[r, 0] + wi[r, 1] * ng[r, 1] + wi[r, 2] * ng[r, 2]) > 0.0
        pl = pdf_l[r]
        pk = pmf[r]
        woz = wo[r, 2]
        out_c[r, 0] = 0.0
        out_c[r, 1] = 0.0
        out_c[r, 2] = 0.0
        if not (above and pl > 0.0 and pk > 0.0 and math.isfinite(pk) and woz > 0.0):
            continue
        ok, dv, w, pdf_s = _specular(wo[r, 0], wo[r, 1], woz, wx, wy, wz, P[r, ALPHA])
        if not ok:
            continue
        if P[r, COS_B] == woz:
            ao = P[r, AO_B]
            bo = P[r, BO_B]
            p_d = P[r, PD_B]
        else:
            ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
            p_d = _p_diffuse(
                P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
                P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
            )
        ai, bi = _lookup(wz, int(P[r, J0]), P[r, FY], ta, tb)
        p_b = p_d * wz * _INV_PI + (1.0 - p_d) * pdf_s
        if delta[r]:
            h = 1.0
            inv_pl = 1.0
        else:
            if not math.isfinite(pl):
                continue
            h = _mis_weight(pl * pk, p_b, power[r])
            inv_pl = 1.0 / pl
        k_all = wz * h * inv_pl / pk
        for k in range(3):
            fk = P[r, F0 + k]
            gk = P[r, F90 + k]
            c_o = 1.0 - (fk * ao + gk * bo)
            c_i = 1.0 - (fk * ai + gk * bi)
            f = P[r, KD + k] * c_o * c_i + (fk + (gk - fk) * w) * dv
            out_c[r, k] = beta[r, k] * f * L[r, k] * k_all


@njit(cache=True, nogil=True)
def scatter_kernel(wo, s, t, ns, ng, beta, u_lobe, u, u_rr, rr, P, ta, tb, out_wi, out_beta, out_pdf, out_ok):
    """sample_f at one vertex per row, fused with the path update that follows it.

    Per row: pick a lobe with u_lobe and sample it with u (as sample_kernel); wi to world
    (out_wi, (n, 3)); beta' = beta f |cos| / pdf (out_beta); out_ok = the path continues: the
    pdf is > 0, wi leaves on the side of the geometric normal ng, beta' is finite with a
    positive channel, and, where rr, it survives Russian roulette: with probability
    q = clip(1 - max(beta'), 0, 0.95) it ends, else beta' /= 1 - q. out_pdf: the BSDF pdf of wi.

    wo: (n, 3) local; s, t, ns, ng: (n, 3) world frame and geometric normal; beta: (n, 3);
    u_lobe, u_rr: (n,); u: (n, 2); rr: (n,) bool, roulette applies.
    """
    for r in range(wo.shape[0]):
        wox = wo[r, 0]
        woy = wo[r, 1]
        woz = wo[r, 2]
        a = P[r, ALPHA]
        if P[r, COS_B] == woz:
            ao = P[r, AO_B]
            bo = P[r, BO_B]
            p_d = P[r, PD_B]
        else:
            ao, bo = _lookup(woz, int(P[r, J0]), P[r, FY], ta, tb)
            p_d = _p_diffuse(
                P[r, RHO], P[r, RHO + 1], P[r, RHO + 2], P[r, F0], P[r, F0 + 1], P[r, F0 + 2],
                P[r, F90], P[r, F90 + 1], P[r, F90 + 2], ao, bo,
            )
        wix, wiy, wiz = _sample_dir(wox, woy, woz, a, u_lobe[r] < p_d, u[r, 0], u[r, 1])
        wx = wix * s[r, 0] + wiy * t[r, 0] + wiz * ns[r, 0]
        wy = wix * s[r, 1] + wiy * t[r, 1] + wiz * ns[r, 1]
        wz = wix * s[r, 2] + wiy * t[r, 2] + wiz * ns[r, 2]
        out_wi[r, 0] = wx
        out_wi[r, 1] = wy
        out_wi[r, 2] = wz
        ok, dv, w, pdf_s = _specular(wox, woy, woz, wix, wiy, wiz, a)
        pdf = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s if ok else 0.0
        out_pdf[r] = pdf
        ok = ok and pdf > 0.0 and math.isfinite(pdf) and (wx * ng[r, 0] + wy * ng[r, 1] + wz * ng[r, 2]) > 0.0
        if ok:
            ai, bi = _lookup(wiz, int(P[r, J0]), P[r, FY], ta, tb)
            k_all = abs(wiz) / pdf
            for k in range(3):
                fk = P[r, F0 + k]
                gk = P[r, F90 + k]
                c_o = 1.0 - (fk * ao + gk * bo)
                c_i = 1.0 - (fk * ai + gk * bi)
                out_beta[r, k] = beta[r, k] * (P[r, KD + k] * c_o * c_i + (fk + (gk - fk) * w) * dv) * k_all
            b0 = out_beta[r, 0]
            b1 = out_beta[r, 1]
            b2 = out_beta[r, 2]
            ok = (b0 > 0.0 or b1 > 0.0 or b2 > 0.0) and math.isfinite(b0 + b1 + b2)
            if ok and rr[r]:
                q = min(max(1.0 - max(b0, max(b1, b2)), 0.0), 0.95)
                if u_rr[r] < q:
                    ok = False
                else:
                    inv = 1.0 / (1.0 - q)
                    out_beta[r, 0] = b0 * inv
                    out_beta[r, 1] = b1 * inv
                    out_beta[r, 2] = b2 * inv
        if not ok:
            out_beta[r, 0] = 0.0
            out_beta[r, 1] = 0.0
            out_beta[r, 2] = 0.0
        out_ok[r] = ok


def as_rows(a: np.ndarray, k: int) -> np.ndarray:
    """C-contiguous float64 (n, k) view or copy of a."""
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1, k)


# _sample_dir inlines vmath.sincos: flush this file's cached kernels when vmath.py changes.
guard_cache(__name__, module_dispatchers(globals()), ["renderer/kernels/vmath.py"])
