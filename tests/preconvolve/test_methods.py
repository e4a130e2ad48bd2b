"""The two preconvolution methods against analytic values and brute force (issue #6).

E(n) = Σ_t L_t ∫_t max(0, n·ω) dω (the nearest-texel radiance the DomeLight samples). References:
* constant map: E = π L exactly;
* one texel: L ∫_t n·ω dω = L n·M_t (first moment, analytic) where the texel is fully lit, and
  the issue's L Ω max(0, n·ω_t) up to the texel's size;
* brute force: K x K midpoint sub-samples in every texel (numpy, independent of the kernels),
  and the midpoint sum over texel centres Σ L_t Ω_t max(0, n·ω_t) for large maps.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer import preconvolve as pc
from renderer.lights.dome import latlong_texel_solid_angles

from .conftest import random_normals


def supersampled(img: np.ndarray, normals: np.ndarray, K: int = 32) -> np.ndarray:
    """Brute force E (N, 3): K x K equal-solid-angle midpoint sub-samples per texel."""
    h, w = img.shape[:2]
    omega = latlong_texel_solid_angles(h, w)
    out = np.zeros((normals.shape[0], 3))
    j = (np.arange(K) + 0.5) / K
    for r in range(h):
        zt, zb = math.cos(math.pi * r / h), math.cos(math.pi * (r + 1) / h)
        z = zt - j * (zt - zb)
        s = np.sqrt(1.0 - z * z)
        lon = np.pi - 2.0 * np.pi * (np.arange(w)[:, None] + j[None, :]) / w  # (w, K)
        d = np.stack([s[None, :, None] * np.sin(lon)[:, None, :], np.broadcast_to(z[None, :, None], (w, K, K)),
                      s[None, :, None] * np.cos(lon)[:, None, :]], axis=-1).reshape(w, K * K, 3)
        cos = np.maximum(0.0, np.einsum("nk,wsk->nws", normals, d)).mean(axis=2)  # (N, w)
        out += omega[r] * cos @ img[r]
    return out


def first_moment(h, w, r, c) -> np.ndarray:
    """∫_texel ω dω of texel (r, c), by dense quadrature (independent of the module's formula)."""
    K = 400
    j = (np.arange(K) + 0.5) / K
    zt, zb = math.cos(math.pi * r / h), math.cos(math.pi * (r + 1) / h)
    z = zt - j * (zt - zb)
    lon = np.pi - 2.0 * np.pi * (c + j) / w
    s = np.sqrt(1 - z * z)[:, None]
    d = np.stack([s * np.sin(lon)[None], np.broadcast_to(z[:, None], (K, K)), s * np.cos(lon)[None]], -1)
    return d.reshape(-1, 3).mean(axis=0) * latlong_texel_solid_angles(h, w)[r]


@pytest.mark.parametrize("shape, rtol", [((8, 16), 2e-5), ((32, 64), 2e-5), ((33, 50), 2e-5),
                                         ((2, 4), 5e-3), ((1, 2), 5e-3)])
def test_constant_map_is_pi_L(shape, rtol):
    """Tiny maps have cells of ~90°, whose straddling integral (K_MAX² sub-samples) is coarser."""
    L = np.array([1.0, 2.0, 0.25])
    img = np.broadcast_to(L, shape + (3,)).copy()
    n = random_normals(300)
    assert np.allclose(pc.exact_irradiance(img, n), np.pi * L, rtol=rtol, atol=0)
    assert np.allclose(pc.sh_irradiance(img, n), np.pi * L, rtol=1e-12, atol=0)


def test_single_texel_analytic():
    h, w, r, c = 32, 64, 9, 21
    Lt = 50.0
    img = np.zeros((h, w, 3))
    img[r, c] = Lt
    n = random_normals(2000, seed=1)
    E = pc.exact_irradiance(img, n)[:, 0]
    d = pc.latlong_directions(h, w)[r, c]
    omega = latlong_texel_solid_angles(h, w)[r]
    M = first_moment(h, w, r, c)
    # Where the whole texel is above the horizon E is exactly L n·M (the clamp is inactive).
    half = math.radians(6.0)  # > the texel's angular radius
    lit = n @ d > math.sin(half)
    assert lit.sum() > 500
    assert np.allclose(E[lit], Lt * n[lit] @ M, rtol=1e-5, atol=0)
    dark = n @ d < -math.sin(half)
    assert np.all(E[dark] == 0.0)
    # The midpoint form L Ω max(0, n·ω): equal up to the texel size (angular size² / 8
    # relative where lit, and L Ω · size absolute across the horizon band).
    mid = Lt * omega * np.maximum(0.0, n @ d)
    size = math.pi / h * math.sqrt(2)
    assert np.all(np.abs(E - mid) <= Lt * omega * size), np.abs(E - mid).max()
    assert np.all(np.abs(E[lit] - mid[lit]) <= Lt * omega * size**2 / 8)
    # texel_cos_integral exposes the same integral (its straddling sub-sampling may be coarser:
    # the sample count of a bright texel depends on its share of the map's power).
    one = pc.texel_cos_integral(h, w, r, c, n) * Lt
    assert np.allclose(one[lit | dark], E[lit | dark], rtol=1e-12, atol=0)
    assert np.abs(one - E).max() < 1e-3 * Lt * omega


@pytest.mark.parametrize("shape", [(8, 16), (12, 20)])
def test_exact_vs_brute_force_random_map(shape):
    rng = np.random.default_rng(sum(shape))
    img = rng.random(shape + (3,)) ** 3 * 4.0
    n = random_normals(60, seed=2)
    E = pc.exact_irradiance(img, n)
    ref = supersampled(img, n, K=40)
    assert np.abs(E / ref - 1).max() < 1e-4
    # The plain midpoint sum over texel centres is the same integral only to second order.
    mid = pc.midpoint_irradiance(img, n)
    assert np.abs(mid / ref - 1).max() < 0.05


def dense_texel_integral(h, w, r, c, normals, K=160) -> np.ndarray:
    """(N,) ∫_texel max(0, n·ω) dω by K x K midpoint sub-samples."""
    j = (np.arange(K) + 0.5) / K
    zt, zb = math.cos(math.pi * r / h), math.cos(math.pi * (r + 1) / h)
    z = zt - j * (zt - zb)
    lon = np.pi - 2.0 * np.pi * (c + j) / w
    s = np.sqrt(1 - z * z)[:, None]
    d = np.stack([s * np.sin(lon)[None], np.broadcast_to(z[:, None], (K, K)), s * np.cos(lon)[None]], -1)
    return np.maximum(0.0, normals @ d.reshape(-1, 3).T).mean(axis=1) * latlong_texel_solid_angles(h, w)[r]


def test_exact_vs_brute_force_sun_map():
    """A sky plus a 1e5 sun over 2x2 texels, every normal of a 32x16 output grid. Brute force:
    the texel-centre sum for the sky plus dense sub-sampling of the sun texels (a centre sample
    is too coarse for a sun cut by the horizon). Required 0.5 %; achieved far better."""
    h, w = 128, 256
    d = pc.latlong_directions(h, w)
    sky = 1.0 + 0.6 * np.clip(d[..., 1:2], 0, None) * np.array([0.6, 0.8, 1.2])
    sky = sky + 0.2 * np.random.default_rng(3).random((h, w, 3))
    img = sky.copy()
    sun_texels = [(35, 90), (35, 91), (36, 90), (36, 91)]
    sun_L = np.array([1e5, 0.9e5, 0.8e5])
    for r, c in sun_texels:
        img[r, c] = sun_L
        sky[r, c] = 0.0
    n = pc.latlong_directions(16, 32).reshape(-1, 3)
    E = pc.exact_irradiance(img, n)
    E_sun = sum(dense_texel_integral(h, w, r, c, n) for r, c in sun_texels)[:, None] * sun_L
    ref = pc.midpoint_irradiance(sky, n) + E_sun
    rel = np.abs(E / ref - 1)
    assert rel.max() < 5e-3
    assert rel.max() < 2e-4  # what the method actually achieves here
    assert (E_sun[:, 0] / E[:, 0]).max() > 0.5  # the sun matters
    # The plain texel-centre sum everywhere is the coarse one: a sun texel cut by the horizon is
    # all-or-nothing for it (here ~6 % off for normals whose horizon crosses the sun).
    assert np.abs(pc.midpoint_irradiance(img, n) / ref - 1).max() > 10 * rel.max()


@pytest.mark.parametrize("shape", [(4, 8), (16, 32), (20, 33), (64, 128), (128, 256)])
def test_row_kernel_matches_per_texel_integration(shape):
    """The row kernel (prefix sums of lit runs, corner classification) against integrating every
    texel on its own (_texel_list, bounding-cone classification): two independent paths."""
    h, w = shape
    rng = np.random.default_rng(h * w)
    img = rng.random((h, w, 3)) ** 4 * 5.0
    img[rng.integers(h), rng.integers(w)] = 1e4
    n = random_normals(400, seed=4)
    E = pc.exact_irradiance(img, n)
    rows, cols = np.divmod(np.arange(h * w), w)
    m = img.reshape(-1, 3).max(axis=1)
    L_ref = pc._mean_max_radiance(img)
    rp = pc._row_params(h, w, L_ref)
    Ks = np.array([pc._texel_k_py(int(rp.K[r]), float(rp.kb[r]), float(v)) for r, v in zip(rows, m)])
    slon, clon = pc._col_params(w)
    ref = np.zeros_like(E)
    pc._texel_list(n, rows.astype(np.int64), cols.astype(np.int64), np.ascontiguousarray(img.reshape(-1, 3)), Ks,
                   rp.cz, rp.sz, rp.zt, rp.zb, rp.omega, rp.S, rp.Y, rp.sinb, slon, clon, w, pc.K_MAX, ref)
    assert np.abs(E / ref - 1).max() < 2e-4


def test_orientation_bright_texel_at_plus_x():
    """USD-NOTES §1: +X is the column at u = 1/4 on the equator. Normals toward +X see it."""
    h, w = 32, 64
    img = np.full((h, w, 3), 1e-3)
    img[h // 2 - 1: h // 2 + 1, w // 4 - 1: w // 4 + 1] = 1e3  # the four texels around +X
    tilt = math.radians(60.0)  # normals 60° away from +X see the texels at cos 60° at most
    n = np.array([[1.0, 0, 0], [-1, 0, 0], [math.cos(tilt), 0, math.sin(tilt)], [math.cos(tilt), math.sin(tilt), 0]])
    E = pc.exact_irradiance(img, n)[:, 0]
    assert E[0] > 1e4 * E[1]
    assert 0.45 * E[0] < E[2] < 0.55 * E[0] and 0.45 * E[0] < E[3] < 0.55 * E[0]
    # On the output grid too: the brightest output texel is the one whose normal is +X.
    n = pc.latlong_directions(16, 32).reshape(-1, 3)
    grid = pc.exact_irradiance(img, n)[:, 0].reshape(16, 32)
    r, c = np.unravel_index(np.argmax(grid), grid.shape)
    assert r in (7, 8) and c in (7, 8)
    assert np.allclose(pc.latlong_directions(16, 32)[r, c], [1, 0, 0], atol=0.15)


def test_sh_exact_for_order_two_radiance_and_close_on_smooth_maps():
    h, w = 64, 128
    d = pc.latlong_directions(h, w)
    x, y, z = d[..., 0:1], d[..., 1:2], d[..., 2:3]
    n = random_normals(500, seed=5)
    # Radiance with only l <= 2 content: R&H's 9 terms are exact (up to texel discretisation).
    low = 1.0 + 0.5 * y * np.array([1.0, 0.5, 0.2]) + 0.3 * x * z + 0.2 * (3 * y * y - 1)
    assert np.abs(pc.sh_irradiance(low, n) / pc.exact_irradiance(low, n) - 1).max() < 1e-5
    # A smooth sky (clamped gradient: l >= 3 content): approximate. Documented tolerance 1 %.
    sky = 1.0 + 0.8 * np.clip(y, 0, None) * np.array([0.6, 0.8, 1.2]) + 0.1 * x
    rel = np.abs(pc.sh_irradiance(sky, n) / pc.exact_irradiance(sky, n) - 1)
    assert rel.max() < 1e-2
    assert rel.max() > 1e-4  # ... and it is an approximation
    # A sun is not smooth: SH is badly off near the sun's horizon (why the hook uses exact).
    sun = sky.copy()
    sun[20:22, 40:42] = 1e4
    rel = np.abs(pc.sh_irradiance(sun, n) / pc.exact_irradiance(sun, n) - 1)
    assert rel.max() > 0.05
