"""SphereLight: cone sampling (incl. the small-angle branch), inside, treatAsPoint, geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.description import LightDesc
from renderer.lights.sphere import SphereLight, ellipsoid_area
from renderer.sampling import SMALL_CONE_SIN2
from tests.lights.helpers import (
    cone_quadrature_irradiance,
    ctx,
    irradiance_samples,
    ray_triangle,
    sampler_for,
    scale,
    translate,
)
from tests.stats import SIGNIFICANCE, chi2_directions, z_test


def sphere(m, radius=0.5, **kw) -> LightDesc:
    return LightDesc("/Sphere", "sphere", np.asarray(m, dtype=np.float64), radius=radius, **kw)


CONFIGS = {
    # name: (desc, point)
    "far": (sphere(translate(0, 0, 5), 1.0), (0.0, 0.0, 0.0)),
    "near": (sphere(translate(0.3, 0.2, 1.2), 1.0), (0.3, 0.2, 0.0)),
    "small_angle": (sphere(translate(1, 2, 10), 0.2), (0.0, 0.0, 0.0)),
    "tiny": (sphere(translate(0, 3, 4), 1e-4), (0.0, 0.0, 0.0)),
}


def cone(light: SphereLight, p):
    v = light.center[0] - np.asarray(p, float)
    d = np.linalg.norm(v)
    sin2 = (light.radius[0] / d) ** 2
    return v / d, sin2


@pytest.mark.parametrize("name", list(CONFIGS))
def test_chi2_sample_matches_pdf(name):
    desc, p = CONFIGS[name]
    light = SphereLight.build([desc])
    axis, sin2 = cone(light, p)
    if name in ("small_angle", "tiny"):
        assert sin2 < SMALL_CONE_SIN2
    else:
        assert sin2 > SMALL_CONE_SIN2
    omc = sin2 / (1.0 + math.sqrt(1.0 - sin2))
    # Put the cone's edge in the middle of the second cos bin (a sub-grid cell boundary).
    lo = 1.0 - omc * 20.0 / 18.5
    sample, pdf = sampler_for(light, 0, p)
    pval, details = chi2_directions(sample, pdf, axis=axis, cos_range=(lo, 1.0), n_samples=100_000, integration_res=8)
    assert pval > SIGNIFICANCE, details["chi2"]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_pdf_round_trip_and_points_on_sphere(name):
    desc, p = CONFIGS[name]
    light = SphereLight.build([desc])
    n = 4000
    c = ctx(p, count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(1).random((n, 2)))
    assert np.all(s.pdf > 0)
    np.testing.assert_allclose(light.pdf_li(idx, c, s.wi), s.pdf, rtol=1e-12)
    r = light.radius[0]
    np.testing.assert_allclose(np.linalg.norm(s.p_light - light.center[0], axis=1), r, rtol=1e-9)
    # The sampled point is the *visible* one: the first hit along wi.
    t = light.intersect(idx, c.p, s.wi)
    np.testing.assert_allclose(t, s.dist, rtol=1e-6, atol=1e-9 * r)
    # Outward normal faces p: the emission reaches p.
    assert np.all(np.einsum("ij,ij->i", s.p_light - light.center[0], -s.wi) >= -1e-9 * r)


def test_small_angle_pdf_is_accurate():
    light = SphereLight.build([sphere(translate(0, 0, 1000), 1e-3)])
    pdf = light.pdf_li(np.zeros(1, dtype=np.int64), ctx((0, 0, 0)), np.array([[0, 0, 1.0]]))[0]
    sin2 = (1e-3 / 1000) ** 2
    np.testing.assert_allclose(pdf, 1.0 / (np.pi * sin2), rtol=1e-9)  # 1 / (2 pi sin^2 / 2)


IRRADIANCE = {
    "above_horizon": (sphere(translate(0.5, 0, 3), 1.0), (0, 0, 0), (0, 0, 1.0)),
    "partly_below": (sphere(translate(0.5, 0, 1.5), 1.0), (0, 0, 0), (0.9, 0.0, -0.436)),
    "near": (sphere(translate(0, 0, 1.05), 1.0), (0, 0, 0), (0.3, 0, 0.954)),
    "small_angle": (sphere(translate(1, 2, 10), 0.2), (0, 0, 0), (0, 0, 1.0)),
    "tiny_far": (sphere(translate(30, 0, 100), 1e-3), (0, 0, 0), (0, 0.6, 0.8)),
}


@pytest.mark.parametrize("name", list(IRRADIANCE))
def test_irradiance(name):
    desc, p, n_normal = IRRADIANCE[name]
    n_normal = np.asarray(n_normal) / np.linalg.norm(n_normal)
    light = SphereLight.build([desc])
    axis, sin2 = cone(light, p)
    cos_axis = float(axis @ n_normal)
    if cos_axis**2 > sin2 and cos_axis > 0:  # fully above the horizon: exact closed form
        ref = np.pi * sin2 * cos_axis * light.L[0, 0]
    else:
        ref = cone_quadrature_irradiance(axis, math.sqrt(1 - sin2), n_normal, light.L[0, 0])
    est = irradiance_samples(light, 0, p, n_normal, n=100_000)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    assert abs(est.mean() / ref - 1.0) < 0.02


def test_closed_form_matches_quadrature():
    axis = np.array([0.0, 0.6, 0.8])
    n = np.array([0.0, 0.0, 1.0])
    sin2 = 0.2
    np.testing.assert_allclose(
        cone_quadrature_irradiance(axis, math.sqrt(1 - sin2), n, 1.0), np.pi * sin2 * 0.8, rtol=1e-6
    )


def test_inside_sees_nothing():
    light = SphereLight.build([sphere(translate(0, 0, 0), 1.0)])
    n = 64
    c = ctx((0.2, 0.3, -0.1), count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(0).random((n, 2)))
    assert np.all(s.pdf == 0) and np.all(s.L == 0)
    wi = np.random.default_rng(1).normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    assert np.all(light.pdf_li(idx, c, wi) == 0)
    t = light.intersect(idx, c.p, wi)  # the inner wall is hit ...
    assert np.all(np.isfinite(t) & (t > 0))
    assert np.all(light.le(idx, c.p + t[:, None] * wi, wi) == 0)  # ... but emits nothing inward


def test_intersect_and_le_from_outside():
    light = SphereLight.build([sphere(translate(0, 0, 5), 1.0, intensity=4.0)])
    idx = np.zeros(3, dtype=np.int64)
    o = np.zeros((3, 3))
    d = np.array([[0, 0, 1.0], [0, 0.15, 0.989], [1.0, 0, 0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = light.intersect(idx, o, d)
    np.testing.assert_allclose(t[0], 4.0)
    assert np.isfinite(t[1]) and np.isinf(t[2])
    le = light.le(idx[:2], o[:2] + t[:2, None] * d[:2], d[:2])
    np.testing.assert_allclose(le, 4.0)


def test_treat_as_point_is_delta():
    light = SphereLight.build([sphere(translate(0, 0, 4), 0.5, intensity=3.0, treat_as_point=True)])
    assert light.delta[0]
    n = 5
    c = ctx((0, 0, 0), count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(0).random((n, 2)))
    np.testing.assert_array_equal(s.pdf, 1.0)
    np.testing.assert_allclose(s.wi, np.tile([0, 0, 1.0], (n, 1)))
    np.testing.assert_allclose(s.dist, 4.0)
    np.testing.assert_allclose(s.L, 3.0 * np.pi * 0.25 / 16.0)  # L pi r^2 / d^2
    assert np.all(light.pdf_li(idx, c, s.wi) == 0)
    assert np.all(np.isinf(light.intersect(idx, c.p, s.wi)))
    assert light.proxy_triangles()[0].shape == (0, 3, 3)
    # Far away the point light and the sphere it replaces give the same irradiance.
    full = SphereLight.build([sphere(translate(0, 0, 4), 0.5, intensity=3.0)])
    e_sphere = np.pi * (0.5 / 4.0) ** 2 * 3.0
    np.testing.assert_allclose(s.L[0, 0], e_sphere, rtol=1e-12)
    np.testing.assert_allclose(light.phi(), full.phi())


@pytest.mark.parametrize("radius", [0.0, 1e-3, 0.5])
def test_normalized_point_light_of_any_radius_has_intensity_base_over_4(radius):
    """UsdLux: treatAsPoint is "effectively a zero-radius sphere" (Maya-USD writes point lights as
    radius 0). A normalized sphere has L = base / (4 pi r^2), intensity L pi r^2 = base / 4 at
    every radius, so radius 0 is that limit -- not a black light (the sizeFactor would be 0)."""
    from renderer.lights.light_set import LightSet

    d = sphere(translate(0, 0, 4), radius, intensity=3.0, exposure=1.0, color=(1.0, 0.5, 0.25),
               treat_as_point=True, normalize=True)
    ls = LightSet.build([d])
    assert ls.count == 1 and not ls.warnings
    s = SphereLight.build([d]).sample_li(np.zeros(1, dtype=np.int64), ctx((0, 0, 0)), np.full((1, 2), 0.5))
    np.testing.assert_allclose(s.L[0], 6.0 / 4.0 / 16.0 * np.array([1.0, 0.5, 0.25]), rtol=1e-12)


def test_zero_radius_point_without_normalize_is_dropped_with_a_warning():
    from renderer.lights.light_set import LightSet

    ls = LightSet.build([sphere(translate(0, 0, 4), 0.0, intensity=3.0, treat_as_point=True)])
    assert ls.count == 0 and any("/Sphere" in w for w in ls.warnings)


def test_ellipsoid_area_and_warning():
    # Knud-Thomsen vs a dense quadrature of the ellipsoid's surface.
    a, b, c = 2.0, 1.0, 0.5
    th = (np.arange(1000) + 0.5) / 1000 * np.pi
    ph = (np.arange(2000) + 0.5) / 2000 * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    st, ct, sp, cp = np.sin(T), np.cos(T), np.sin(P), np.cos(P)
    # |dr/dtheta x dr/dphi| for r = (a st cp, b st sp, c ct)
    nx, ny, nz = b * c * st**2 * cp, a * c * st**2 * sp, a * b * st * ct
    area = float(np.sqrt(nx**2 + ny**2 + nz**2).sum() * (np.pi / 1000) * (2 * np.pi / 2000))
    assert ellipsoid_area(a, b, c) == pytest.approx(area, rel=0.015)
    assert ellipsoid_area(1.5, 1.5, 1.5) == pytest.approx(4 * np.pi * 2.25)
    desc = sphere(scale(2.0, 1.0, 0.5), 1.0, normalize=True)
    light = SphereLight.build([desc])
    assert light.radius[0] == pytest.approx(2.0)
    assert len(light.warnings) == 1 and "/Sphere" in light.warnings[0]
    np.testing.assert_allclose(light.L[0], 1.0 / ellipsoid_area(2.0, 1.0, 0.5))


def _outside_proxy(o, tris):
    """True where o is outside the convex proxy (in front of some face)."""
    v0 = tris[:, 0]
    nrm = np.cross(tris[:, 1] - v0, tris[:, 2] - v0)
    centre = tris.reshape(-1, 3).mean(0)
    nrm *= np.sign(np.einsum("ij,ij->i", nrm, v0 - centre))[:, None]  # outward
    return (np.einsum("ntk,tk->nt", o[:, None, :] - v0[None], nrm) > 0).any(axis=1)


def test_proxy_icosahedron_is_conservative():
    light = SphereLight.build([sphere(translate(1, 2, 3), 0.8)])
    tris, owner = light.proxy_triangles()
    assert tris.shape == (20, 3, 3) and np.all(owner == 0)
    rng = np.random.default_rng(3)
    n = 6000
    o = light.center[0] + rng.normal(size=(n, 3)) * np.where(rng.random((n, 1)) < 0.3, 0.6, 3.0)
    target = light.center[0] + rng.normal(size=(n, 3)) * 0.6
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = light.intersect(np.zeros(n, dtype=np.int64), o, d)
    tp_all = ray_triangle(o, d, tris)
    hit = np.isfinite(t)
    outside = _outside_proxy(o, tris)
    inside_sphere = np.linalg.norm(o - light.center[0], axis=1) < light.radius[0]
    assert hit.mean() > 0.3 and (~outside & ~inside_sphere).sum() > 50
    # From outside the proxy: some proxy triangle is hit at or before the exact hit.
    m = hit & outside
    assert np.all(tp_all[m].min(axis=1) <= t[m])
    # From inside the proxy (between it and the sphere, or inside the sphere): the exit face is hit.
    m = hit & ~outside
    assert np.all(np.isfinite(tp_all[m]).any(axis=1))
