"""CylinderLight: emission and normalize, facing-band sampling vs pdf, intersection, line lights."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.description import LightDesc
from renderer.light_samplers.bvh import light_bounds
from renderer.lights.cylinder import CylinderLight, ellipse_perimeter
from renderer.lights.light_set import LightSet
from tests.lights.helpers import (
    ctx,
    irradiance_samples,
    offset_axis_setup,
    ray_triangle,
    rotate,
    sampler_for,
    scale,
    translate,
)
from tests.stats import SIGNIFICANCE, chi2_directions, z_test


def cyl(m, radius=0.5, length=2.0, **kw) -> LightDesc:
    return LightDesc("/Tube", "cylinder", np.asarray(m, dtype=np.float64), radius=radius, length=length, **kw)


CONFIGS = {
    # name: (desc, shading point)
    "far": (cyl(translate(0, 0, 3)), (0.3, 0.2, 0.0)),
    "near": (cyl(translate(0, 0, 0.7)), (0.5, 0.0, 0.0)),
    "beyond_end": (cyl(translate(0, 0, 1.0)), (2.5, 0.3, 0.0)),
    "oblique_elliptic": (cyl(translate(0, 0, 3) @ rotate((1, 1, 0), 30) @ scale(2, 0.5, 1.5)), (0.2, 0.1, 0.0)),
    "sheared": (cyl(translate(0, 0.5, 2.5) @ np.array([[1, 0.4, 0, 0], [0, 1, 0, 0], [0, 0.3, 1, 0], [0, 0, 0, 1.0]])),
                (0.0, 0.0, 0.0)),
}


def surface_grid(light: CylinderLight, ns: int = 400, nphi: int = 400):
    """Midpoint quadrature of the side: points (m, 3), outward normals (m, 3), world areas (m,)."""
    s = (np.arange(ns) + 0.5) / ns * 2 * light.half[0] - light.half[0]
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    S, P = np.meshgrid(s, phi, indexing="ij")
    S, P = S.ravel(), P.ravel()
    idx = np.zeros(S.size, dtype=np.int64)
    r = light.radius[0]
    x_l = np.stack([S, r * np.cos(P), r * np.sin(P)], axis=1)
    pts = light._to_world(idx, x_l)
    dA = light._jacobian(idx, P) * (2 * light.half[0] / ns) * (2 * np.pi / nphi)
    return pts, light._world_normal(idx, P), dA


def test_emission_and_normalize_follow_the_doc():
    """L = intensity 2^exposure color (and / world side area 2 pi r L when normalize)."""
    d = cyl(translate(0, 0, 2), radius=0.25, length=3.0, intensity=8.0, exposure=1.0, color=(1.0, 0.5, 0.25))
    light = CylinderLight.build([d])
    np.testing.assert_allclose(light.L[0], [16.0, 8.0, 4.0])
    np.testing.assert_allclose(CylinderLight.world_area(d), 2 * np.pi * 0.25 * 3.0, rtol=1e-12)
    n = CylinderLight.build([cyl(translate(0, 0, 2) @ scale(2, 2, 2), radius=0.25, length=3.0, intensity=8.0,
                                 normalize=True)])
    np.testing.assert_allclose(n.L[0], 8.0 / (2 * np.pi * 0.5 * 6.0), rtol=1e-12)
    # le: outward only; a ray from inside the tube sees nothing, from outside sees L.
    idx = np.zeros(2, dtype=np.int64)
    o = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]])  # below the tube / on its axis
    w = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    t = light.intersect(idx, o, w)
    np.testing.assert_allclose(t, [1.75, 0.25])
    Le = light.le(idx, o + w * t[:, None], w)
    np.testing.assert_allclose(Le, [light.L[0], [0.0, 0.0, 0.0]])


def test_non_uniform_scale_uses_ramanujan_perimeter():
    """hdEmbree's rule: cross-section perimeter by Ramanujan (pi (3(a+b) - sqrt((3a+b)(a+3b)))),
    times the world length; within 4e-4 of the exact ellipse perimeter."""
    d = cyl(scale(3.0, 1.0, 0.25), radius=1.0, length=1.0)
    a, b = 1.0, 0.25
    expected = math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b))) * 3.0
    np.testing.assert_allclose(CylinderLight.world_area(d), expected, rtol=1e-12)
    t = np.linspace(0, 2 * np.pi, 200001)
    exact = np.trapezoid(np.hypot(a * np.sin(t), b * np.cos(t)), t)
    assert abs(ellipse_perimeter(a, b) / exact - 1) < 4e-4
    # The sampler's exact area element integrates to the true (not Ramanujan) side area.
    light = CylinderLight.build([d])
    _, _, dA = surface_grid(light, 4, 4000)
    np.testing.assert_allclose(dA.sum(), exact * 3.0, rtol=1e-9)


# The fine integration grid makes each case a few seconds: two run by default, all with -m slow.
CHI2_CASES = [pytest.param(name, marks=() if name in ("near", "oblique_elliptic") else pytest.mark.slow)
              for name in CONFIGS]


@pytest.mark.parametrize("name", CHI2_CASES)
def test_chi2_sample_matches_pdf(name):
    desc, p = CONFIGS[name]
    light = CylinderLight.build([desc])
    pts, _, _ = surface_grid(light, 60, 120)
    axis, cos_range = offset_axis_setup(p, pts)
    sample, pdf = sampler_for(light, 0, p)
    # The tube's curved ends cut bins diagonally: a fine sub-grid keeps the expected counts exact.
    pval, details = chi2_directions(sample, pdf, axis=axis, cos_range=cos_range, n_samples=100_000,
                                    res_theta=8, res_phi=16, integration_res=128)
    assert pval > SIGNIFICANCE, details["chi2"]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_pdf_round_trip_visible_points(name):
    desc, p = CONFIGS[name]
    light = CylinderLight.build([desc])
    n = 4000
    c = ctx(p, count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(3).random((n, 2)))
    assert np.all(s.pdf > 0)
    np.testing.assert_allclose(light.pdf_li(idx, c, s.wi), s.pdf, rtol=1e-9)
    # The sampled point is the first hit along wi (never the hidden half) and emits toward p.
    np.testing.assert_allclose(light.intersect(idx, c.p, s.wi), s.dist, rtol=1e-9)
    np.testing.assert_allclose(light.le(idx, s.p_light, s.wi), s.L)


IRRADIANCE = {
    "above": (cyl(translate(0.4, 0, 2.0), radius=0.3), (0, 0, 0), (0, 0, 1.0)),
    "straddles_horizon": (cyl(translate(0.0, 0.6, 0.35), radius=0.3), (0, 0, 0), (0, 0.3, 0.954)),
    "close": (cyl(translate(0, 0, 0.32), radius=0.3, length=4.0), (0, 0, 0), (0, 0, 1.0)),
    "elliptic": (cyl(translate(0, 0, 2.0) @ rotate((0, 1, 1), 50) @ scale(1.5, 0.6, 0.2)), (0.1, 0, 0), (0, 0, 1.0)),
}


@pytest.mark.parametrize("name", list(IRRADIANCE))
def test_irradiance_matches_quadrature(name):
    """MC mean of L cos / pdf (unshadowed) vs a 160k-point midpoint quadrature of the side."""
    desc, p, nrm = IRRADIANCE[name]
    nrm = np.asarray(nrm) / np.linalg.norm(nrm)
    light = CylinderLight.build([desc])
    pts, nl, dA = surface_grid(light)
    v = pts - np.asarray(p, float)
    d2 = np.einsum("ij,ij->i", v, v)
    w = v / np.sqrt(d2)[:, None]
    ref = float((light.L[0, 0] * np.maximum(w @ nrm, 0) * np.maximum(-np.einsum("ij,ij->i", w, nl), 0) / d2 * dA).sum())
    est = irradiance_samples(light, 0, p, nrm, n=100_000)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    assert abs(est.mean() / ref - 1.0) < 0.02


def test_facing_band_sampling_beats_area_sampling():
    """Near a long tube the estimator's relative variance stays small (the 1/d^2 and cos_l
    factors cancel); uniform area sampling of the side would be several times worse."""
    desc, p, nrm = IRRADIANCE["close"]
    light = CylinderLight.build([desc])
    est = irradiance_samples(light, 0, p, np.asarray(nrm, float), n=50_000)
    rel_var = est.var() / est.mean() ** 2
    pts, nl, dA = surface_grid(light, 200, 200)
    v = pts - np.asarray(p, float)
    d2 = np.einsum("ij,ij->i", v, v)
    w = v / np.sqrt(d2)[:, None]
    f = np.maximum(w[:, 2], 0) * np.maximum(-np.einsum("ij,ij->i", w, nl), 0) / d2  # per unit area
    area = dA.sum()
    area_rel_var = (area * (f**2 * dA).sum()) / (f * dA).sum() ** 2 - 1.0
    assert rel_var < 0.25 * area_rel_var, (rel_var, area_rel_var)


def test_inside_and_behind_nothing_is_sampled():
    light = CylinderLight.build([cyl(translate(0, 0, 0))])
    n = 100
    c = ctx((0.3, 0.1, 0.1), count=n)
    s = light.sample_li(np.zeros(n, dtype=np.int64), c, np.random.default_rng(0).random((n, 2)))
    assert np.all(s.pdf == 0) and np.all(s.L == 0)
    assert np.all(light.pdf_li(np.zeros(n, dtype=np.int64), c, s.wi * 0 + [0, 0, 1.0]) == 0)


def test_proxies_are_conservative():
    light = CylinderLight.build([cyl(translate(0.2, -0.1, 0.5) @ rotate((0, 0, 1), 25) @ scale(1, 1.5, 0.7))])
    tris, owner = light.proxy_triangles()
    assert np.all(owner == 0)
    rng = np.random.default_rng(5)
    o = rng.normal(size=(3000, 3))
    o = light.center[0] + 3.0 * o / np.linalg.norm(o, axis=1, keepdims=True)  # outside the prism
    target = light.center[0] + rng.normal(size=(3000, 3)) * 0.5
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = light.intersect(np.zeros(3000, dtype=np.int64), o, d)
    hit = np.isfinite(t)
    assert hit.sum() > 500
    tp = ray_triangle(o[hit], d[hit], tris).min(axis=1)
    assert np.all(tp <= t[hit] * (1 + 1e-9))


def test_light_bvh_bounds_contain_the_side():
    desc = cyl(translate(1, 2, 3) @ rotate((1, 2, 0), 40) @ scale(1, 0.5, 2), radius=0.4, length=1.5)
    ls = LightSet.build([desc], np.zeros(3), 5.0)
    b = light_bounds(ls)
    pts, _, _ = surface_grid(ls.kinds[ls.kind_of[0]], 20, 200)
    assert np.all(pts >= b.lo[0] - 1e-12) and np.all(pts <= b.hi[0] + 1e-12)
    assert b.theta_o[0] == pytest.approx(np.pi)


# ----------------------------------------------------------------------------------------
# treatAsLine
# ----------------------------------------------------------------------------------------
def line_reference(light: CylinderLight, p, nrm, k: int = 200_001) -> float:
    """E = int I_lin sin(theta) cos_p / d^2 ds over the segment (trapezoid rule)."""
    a = light.a[0]
    la = np.linalg.norm(a)
    s = np.linspace(-light.half[0] * la, light.half[0] * la, k)
    x = light.center[0] + s[:, None] * a / la
    v = x - np.asarray(p, float)
    d = np.linalg.norm(v, axis=1)
    w = v / d[:, None]
    sin = np.linalg.norm(np.cross(w, a / la), axis=1)
    f = light.L[0, 0] * sin * np.maximum(w @ nrm, 0) / d**2
    return float(np.trapezoid(f, s))


def test_line_light_is_a_delta_light_matching_the_thin_tube():
    p, nrm = np.array([0.3, 0.1, 0.0]), np.array([0.0, 0.6, 0.8])
    m = translate(0, 0.5, 1.5) @ rotate((0, 0, 1), 20)
    line = CylinderLight.build([cyl(m, radius=0.0, length=2.0, intensity=5.0, normalize=True, treat_as_line=True)])
    assert line.delta[0]
    # normalize: I_lin = intensity / (pi * length), whatever the radius.
    np.testing.assert_allclose(line.L[0], 5.0 / (np.pi * 2.0))
    n = 50_000
    c = ctx(p, count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = line.sample_li(idx, c, np.random.default_rng(2).random((n, 2)))
    assert np.all(s.pdf == 1.0)
    assert np.all(line.pdf_li(idx, c, s.wi) == 0.0)
    assert np.all(np.isinf(line.intersect(idx, c.p, s.wi)))
    est = s.L[:, 0] * np.maximum(s.wi @ nrm, 0)
    ref = line_reference(line, p, nrm)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    # A thin normalized tube of the same intensity gives (almost) the same irradiance.
    tube = CylinderLight.build([cyl(m, radius=1e-3, length=2.0, intensity=5.0, normalize=True)])
    tube_est = irradiance_samples(tube, 0, p, nrm, n=50_000)
    assert abs(tube_est.mean() / ref - 1) < 0.01
    np.testing.assert_allclose(line.phi(), tube.phi(), rtol=1e-5)


def test_line_light_with_zero_radius_needs_normalize():
    """Without normalize a line's intensity is L times the tube's mean width: zero radius emits
    nothing (dropped), while a normalized one is kept."""
    ls = LightSet.build([cyl(np.eye(4), radius=0.0, treat_as_line=True, normalize=False),
                         cyl(np.eye(4), radius=0.0, treat_as_line=True, normalize=True)], np.zeros(3), 2.0)
    assert ls.count == 1 and ls.kinds[ls.kind_of[0]].delta[0]


def test_kernel_pdf_matches_the_numpy_statement():
    """The numba pdf equals the module's numpy densities (frame, band and equiangular pdfs, the
    area element and the cosine), evaluated at sampled points."""
    desc, p = CONFIGS["oblique_elliptic"]
    light = CylinderLight.build([desc])
    n = 3000
    c = ctx(p, count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(12).random((n, 2)))
    xl = np.einsum("nij,nj->ni", light.m3_inv[idx], s.p_light - light.center[idx])
    phi = np.arctan2(xl[:, 2], xl[:, 1])
    s_p, rho, phi_p, outside = light._frame(idx, c.p)
    assert outside.all()
    psi = np.angle(np.exp(1j * (phi - phi_p)))
    ref = light._to_solid_angle(idx, light._param_pdf(idx, xl[:, 0], psi, s_p, rho), phi, s.wi, s.dist)
    np.testing.assert_allclose(s.pdf, ref, rtol=1e-9)
