"""numba kernels for the hot paths of PreviewSurfaceBSDF (f + pdf, and sample_f).

One loop over rows with scalar math: no (n,)-sized temporaries, about 20x faster than the
equivalent numpy expression. The formulas are exactly those of ``preview_surface.py`` and
``microfacet.py`` (the numpy versions there are the reference the tests compare against).

Kernels are compiled with ``nogil=True`` (render threads can run them concurrently) and
``cache=True`` (compiled once per machine, into __pycache__), and are *not* ``parallel``: numba's
default threading layer is not safe to enter from several Python threads at once, and the
integrator already parallelises over threads.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.bsdfs.microfacet import ALPHA_MIN, LUMINANCE, N_A, N_MU

_LOG_ALPHA_MIN = math.log(ALPHA_MIN)
_INV_PI = 1.0 / math.pi
_LUM_R, _LUM_G, _LUM_B = (float(v) for v in LUMINANCE)


@njit(cache=True, nogil=True, inline="always")
def _lookup(mu, alpha, ta, tb):
    """Bilinear (A, B) at (mu, alpha); same coordinates as AlbedoTables.lookup."""
    m = min(max(mu, 0.0), 1.0)
    x = math.sqrt(m) * (N_MU - 1)
    i0 = min(int(x), N_MU - 2)
    fx = x - i0
    la = math.log(min(max(alpha, ALPHA_MIN), 1.0))
    y = (1.0 - la / _LOG_ALPHA_MIN) * (N_A - 1)
    j0 = min(max(int(y), 0), N_A - 2)
    fy = min(max(y - j0, 0.0), 1.0)
    w00 = (1.0 - fx) * (1.0 - fy)
    w10 = fx * (1.0 - fy)
    w01 = (1.0 - fx) * fy
    w11 = fx * fy
    a = ta[i0, j0] * w00 + ta[i0 + 1, j0] * w10 + ta[i0, j0 + 1] * w01 + ta[i0 + 1, j0 + 1] * w11
    b = tb[i0, j0] * w00 + tb[i0 + 1, j0] * w10 + tb[i0, j0 + 1] * w01 + tb[i0 + 1, j0 + 1] * w11
    return a, b


@njit(cache=True, nogil=True, inline="always")
def _p_diffuse(r, rho_d, f0, ao, bo):
    """Probability of picking the diffuse lobe: lum(rho_d (1 - E_o)) / (that + lum(E_o))."""
    e0 = f0[r, 0] * ao + bo
    e1 = f0[r, 1] * ao + bo
    e2 = f0[r, 2] * ao + bo
    wd = (
        _LUM_R * rho_d[r, 0] * (1.0 - e0)
        + _LUM_G * rho_d[r, 1] * (1.0 - e1)
        + _LUM_B * rho_d[r, 2] * (1.0 - e2)
    )
    ws = _LUM_R * e0 + _LUM_G * e1 + _LUM_B * e2
    tot = wd + ws
    if tot > 0.0:
        return wd / tot
    return 0.5


@njit(cache=True, nogil=True, inline="always")
def _eval_row(r, wox, woy, woz, wix, wiy, wiz, rho_d, f0, alpha, k_d, ta, tb, p_d, ao, bo, out_f, out_pdf):
    """Write f (3 values) and the mixture pdf of row r; zeros when below the surface."""
    out_f[r, 0] = 0.0
    out_f[r, 1] = 0.0
    out_f[r, 2] = 0.0
    out_pdf[r] = 0.0
    if woz <= 0.0 or wiz <= 0.0:
        return
    hx = wox + wix
    hy = woy + wiy
    hz = woz + wiz
    hl = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not hl > 1e-12:
        return
    hx /= hl
    hy /= hl
    hz /= hl
    a = alpha[r]
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
    ai, bi = _lookup(wiz, a, ta, tb)
    for k in range(3):
        fk = f0[r, k]
        c_o = 1.0 - (fk * ao + bo)
        c_i = 1.0 - (fk * ai + bi)
        out_f[r, k] = k_d[r, k] * c_o * c_i + (fk + (1.0 - fk) * w) * dv
    pden = 2.0 * (woz + s_o)
    pdf_s = d / pden if pden > 0.0 else 0.0
    out_pdf[r] = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s


@njit(cache=True, nogil=True)
def f_pdf_kernel(wo, wi, rho_d, f0, alpha, k_d, ta, tb, out_f, out_pdf):
    """out_f (n, 3) = f(wo, wi), out_pdf (n,) = mixture pdf(wo, wi)."""
    for r in range(wo.shape[0]):
        woz = wo[r, 2]
        ao, bo = _lookup(woz, alpha[r], ta, tb)
        p_d = _p_diffuse(r, rho_d, f0, ao, bo)
        _eval_row(
            r, wo[r, 0], wo[r, 1], woz, wi[r, 0], wi[r, 1], wi[r, 2],
            rho_d, f0, alpha, k_d, ta, tb, p_d, ao, bo, out_f, out_pdf,
        )


@njit(cache=True, nogil=True)
def sample_kernel(wo, u_lobe, u, rho_d, f0, alpha, k_d, ta, tb, out_wi, out_f, out_pdf, out_lobe):
    """Lobe choice with u_lobe, cosine or VNDF sampling with u, then f and pdf at the sample."""
    for r in range(wo.shape[0]):
        wox = wo[r, 0]
        woy = wo[r, 1]
        woz = wo[r, 2]
        a = alpha[r]
        ao, bo = _lookup(woz, a, ta, tb)
        p_d = _p_diffuse(r, rho_d, f0, ao, bo)
        wix = 0.0
        wiy = 0.0
        wiz = 1.0
        if u_lobe[r] < p_d:
            out_lobe[r] = 0
            if woz > 0.0:
                # Cosine-weighted hemisphere via the concentric disk map (sampling.py's warp).
                sa = 2.0 * u[r, 0] - 1.0
                sb = 2.0 * u[r, 1] - 1.0
                if abs(sa) > abs(sb):
                    rad = sa
                    th = (math.pi / 4.0) * (sb / sa)
                else:
                    rad = sb
                    th = (math.pi / 2.0) - (math.pi / 4.0) * (sa / sb if sb != 0.0 else 0.0)
                wix = rad * math.cos(th)
                wiy = rad * math.sin(th)
                wiz = math.sqrt(max(0.0, 1.0 - wix * wix - wiy * wiy))
        else:
            out_lobe[r] = 1
            if woz > 0.0:
                # GGX visible normal, spherical caps (Dupuy & Benyoub 2023), then reflect.
                vx = wox * a
                vy = woy * a
                vz = woz
                vl = math.sqrt(vx * vx + vy * vy + vz * vz)
                if vl > 0.0:
                    vx /= vl
                    vy /= vl
                    vz /= vl
                phi = 2.0 * math.pi * u[r, 0]
                z = (1.0 - u[r, 1]) * (1.0 + vz) - vz
                st = math.sqrt(min(max(1.0 - z * z, 0.0), 1.0))
                hx = (st * math.cos(phi) + vx) * a
                hy = (st * math.sin(phi) + vy) * a
                hz = max(z + vz, 0.0)
                hl = math.sqrt(hx * hx + hy * hy + hz * hz)
                if hl > 0.0:
                    hx /= hl
                    hy /= hl
                    hz /= hl
                else:
                    hx = 0.0
                    hy = 0.0
                    hz = 1.0
                dd = wox * hx + woy * hy + woz * hz
                wix = 2.0 * dd * hx - wox
                wiy = 2.0 * dd * hy - woy
                wiz = 2.0 * dd * hz - woz
                wl = math.sqrt(wix * wix + wiy * wiy + wiz * wiz)
                if wl > 0.0:
                    wix /= wl
                    wiy /= wl
                    wiz /= wl
        out_wi[r, 0] = wix
        out_wi[r, 1] = wiy
        out_wi[r, 2] = wiz
        _eval_row(r, wox, woy, woz, wix, wiy, wiz, rho_d, f0, alpha, k_d, ta, tb, p_d, ao, bo, out_f, out_pdf)


def as_rows(a: np.ndarray, k: int) -> np.ndarray:
    """C-contiguous float64 (n, k) view or copy of a."""
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1, k)
