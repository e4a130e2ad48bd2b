"""DistantLight: cone sampling, delta lights, escaped rays, radiometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.description import LightDesc
from renderer.lights.distant import DistantLight
from tests.lights.helpers import cone_quadrature_irradiance, ctx, irradiance_samples, rotate, sampler_for
from tests.stats import SIGNIFICANCE, chi2_directions, z_test


def distant(m=np.eye(4), angle=0.53, intensity=1.0, **kw) -> LightDesc:
    return LightDesc("/Sun", "distant", np.asarray(m, dtype=np.float64), angle=angle, intensity=intensity, **kw)


TILT = rotate((1, 0.3, 0), 35)  # the light's +Z (toward the light) tilted away from world +Z


@pytest.mark.parametrize("angle", [0.53, 10.0, 200.0])
def test_chi2_sample_matches_pdf(angle):
    light = DistantLight.build([distant(TILT, angle)])
    axis = light.axis[0]
    omc = light.omc[0]
    lo = max(-1.0, 1.0 - omc * 20.0 / 18.5)
    sample, pdf = sampler_for(light, 0, (0, 0, 0))
    pval, details = chi2_directions(sample, pdf, axis=axis, cos_range=(lo, 1.0), n_samples=100_000, integration_res=8)
    assert pval > SIGNIFICANCE, details["chi2"]


def test_axis_and_round_trip():
    light = DistantLight.build([distant(TILT, 3.0)])
    np.testing.assert_allclose(light.axis[0], TILT[:3, 2])  # toward the light = local +Z
    n = 2000
    c = ctx((1, 2, 3), count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(0).random((n, 2)))
    np.testing.assert_allclose(light.pdf_li(idx, c, s.wi), s.pdf, rtol=1e-9)
    assert np.all(np.isinf(s.dist))
    assert np.all(np.linalg.norm(s.p_light - c.p, axis=1) > 2.0)  # beyond the scene (radius 1)
    np.testing.assert_allclose(light.le_escaped(idx, s.wi), light.L[idx])
    assert np.all(light.le_escaped(idx, -s.wi) == 0.0)
    assert np.all(light.pdf_li(idx, c, -s.wi) == 0.0)


@pytest.mark.parametrize(
    "angle,n_normal",
    [(0.53, (0, 0, 1.0)), (30.0, (0, 0, 1.0)), (120.0, (0, 0, 1.0)), (60.0, (1.0, 0, 0.2))],
)
def test_irradiance(angle, n_normal):
    light = DistantLight.build([distant(TILT, angle, intensity=2.0)])
    n_normal = np.asarray(n_normal) / np.linalg.norm(n_normal)
    ref = cone_quadrature_irradiance(light.axis[0], math.cos(light.theta_max[0]), n_normal, 2.0)
    cos_axis = float(light.axis[0] @ n_normal)
    s2 = math.sin(light.theta_max[0]) ** 2
    if light.theta_max[0] < math.pi / 2 and cos_axis**2 > s2 and cos_axis > 0:
        np.testing.assert_allclose(ref, 2.0 * math.pi * s2 * cos_axis, rtol=1e-5)
    est = irradiance_samples(light, 0, (0, 0, 0), n_normal, n=100_000)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)


@pytest.mark.parametrize("angle", [0.53, 30.0, 180.0, 300.0])
def test_normalize_makes_intensity_the_illuminance(angle):
    light = DistantLight.build([distant(np.eye(4), angle, intensity=5.0, normalize=True)])
    e_perp = light.irradiance_normal()[0, 0]
    if angle <= 180.0:
        np.testing.assert_allclose(e_perp, 5.0, rtol=1e-12)
    else:  # the cone reaches behind: the facing hemisphere gets L pi, sizeFactor pi (2 - sin^2)
        s2 = math.sin(math.radians(angle / 2)) ** 2
        np.testing.assert_allclose(e_perp, 5.0 * math.pi / (math.pi * (2 - s2)), rtol=1e-12)
    ref = cone_quadrature_irradiance((0, 0, 1.0), math.cos(light.theta_max[0]), np.array([0, 0, 1.0]), light.L[0, 0])
    np.testing.assert_allclose(ref, e_perp, rtol=1e-5)


def test_angle_zero_is_delta():
    light = DistantLight.build([distant(rotate((1, 0, 0), -90), 0.0, intensity=7.0, color=(1.0, 0.5, 0.25))])
    assert light.delta[0]
    n = 4
    c = ctx((0, 0, 0), count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(0).random((n, 2)))
    np.testing.assert_allclose(s.wi, np.tile([0, 1.0, 0], (n, 1)), atol=1e-15)  # local +Z -> world +Y
    np.testing.assert_array_equal(s.pdf, 1.0)
    np.testing.assert_allclose(s.L, np.tile([7.0, 3.5, 1.75], (n, 1)))  # irradiance at normal incidence
    assert np.all(light.pdf_li(idx, c, s.wi) == 0.0)
    assert np.all(light.le_escaped(idx, s.wi) == 0.0)
    assert light.phi()[0] == pytest.approx(math.pi * 1.0 * (0.2126 * 7 + 0.7152 * 3.5 + 0.0722 * 1.75))
