"""Lambert: sampling matches pdf, consistency of the sample record, exact white furnace."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.bsdfs.lambert import LambertBSDF
from tests.bsdfs.helpers import direction, tile
from tests.stats import SIGNIFICANCE, chi2_directions


@pytest.mark.parametrize("theta", [0.0, 45.0, 85.0])
def test_chi2_sample_matches_pdf(theta):
    wo1 = direction(theta, 30.0)

    def sample(u):
        n = u.shape[0]
        s = LambertBSDF(tile((0.5, 0.5, 0.5), n)).sample_f(tile(wo1, n), np.zeros(n), u)
        return s.wi, s.pdf > 0.0

    def pdf(wi):
        m = wi.shape[0]
        return LambertBSDF(tile((0.5, 0.5, 0.5), m)).pdf(tile(wo1, m), wi)

    p, details = chi2_directions(sample, pdf, n_samples=200_000)
    assert p > SIGNIFICANCE, details["chi2"]


def test_sample_record_is_consistent(rng):
    n = 10_000
    albedo = rng.random((n, 3))
    b = LambertBSDF(albedo)
    wo = direction(40.0) * np.ones((n, 1))
    s = b.sample_f(wo, rng.random(n), rng.random((n, 2)))
    np.testing.assert_array_equal(s.pdf, b.pdf(wo, s.wi))
    np.testing.assert_array_equal(s.f, b.f(wo, s.wi))
    assert s.lobe.dtype == np.int8 and np.all(s.lobe == 0)
    np.testing.assert_allclose(np.linalg.norm(s.wi, axis=1), 1.0, atol=1e-12)


def test_white_furnace_is_exact(rng):
    """Cosine sampling makes f cos / pdf == rho for every sample: zero variance."""
    n = 50_000
    rho = np.array([0.9, 0.5, 0.1])
    b = LambertBSDF(tile(rho, n))
    wo = tile(direction(60.0), n)
    s = b.sample_f(wo, rng.random(n), rng.random((n, 2)))
    ok = s.pdf > 0.0
    assert ok.mean() > 0.999
    w = s.f[ok] * s.wi[ok, 2:3] / s.pdf[ok, None]
    np.testing.assert_allclose(w, np.broadcast_to(rho, w.shape), rtol=1e-12)
    assert np.all(np.ptp(w, axis=0) <= 1e-15)  # zero variance, up to rounding


def test_reciprocity_and_hemispheres(rng):
    n = 1000
    b = LambertBSDF(rng.random((n, 3)))
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    np.testing.assert_array_equal(b.f(wo, wi), b.f(wi, wo))
    below = (wo[:, 2] <= 0.0) | (wi[:, 2] <= 0.0)
    assert np.all(b.f(wo, wi)[below] == 0.0)
    assert np.all(b.pdf(wo, wi)[below] == 0.0)
    s = b.sample_f(wo, rng.random(n), rng.random((n, 2)))
    assert np.all(s.pdf[wo[:, 2] <= 0.0] == 0.0)
    assert np.all(s.f[wo[:, 2] <= 0.0] == 0.0)


def test_control_variate_decomposition(rng):
    n = 500
    b = LambertBSDF(rng.random((n, 3)))
    wo = tile(direction(20.0), n)
    wi = tile(direction(70.0, 100.0), n)
    np.testing.assert_array_equal(b.f_diffuse(wo, wi), b.diffuse_constant(wo) * b.diffuse_factor_wi(wi))
    np.testing.assert_array_equal(b.f(wo, wi), b.f_diffuse(wo, wi) + b.f_specular(wo, wi))
    np.testing.assert_allclose(b.diffuse_constant(wo), b.diffuse_albedo() / np.pi)
    assert len(b.take(np.arange(10))) == 10


def test_f_parts_and_bind_wo(rng):
    n = 1000
    b = LambertBSDF(rng.random((n, 3)))
    wo = rng.normal(size=(n, 3))
    wi = rng.normal(size=(n, 3))
    assert b.bind_wo(wo) is b
    f, fd, pdf = b.f_parts(wo, wi)
    np.testing.assert_array_equal(f, b.f(wo, wi))
    np.testing.assert_array_equal(fd, b.f_diffuse(wo, wi))
    np.testing.assert_array_equal(pdf, b.pdf(wo, wi))
