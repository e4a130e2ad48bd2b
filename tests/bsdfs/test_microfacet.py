"""GGX building blocks: normalisation of D and of the visible-normal density, the stored albedo
tables against fresh quadrature, and the exactness of the cosine-weighted averages."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.bsdfs import microfacet as mf


def _hemisphere_grid(res: int):
    """Midpoint grid over the upper hemisphere in (cos theta, phi): directions (m, 3), dOmega."""
    c = (np.arange(res) + 0.5) / res
    p = (np.arange(2 * res) + 0.5) * (np.pi / res)
    C, P = np.meshgrid(c, p, indexing="ij")
    S = np.sqrt(1.0 - C * C)
    w = np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1).reshape(-1, 3)
    return w, (1.0 / res) * (np.pi / res)


@pytest.mark.parametrize("alpha", [mf.ALPHA_MIN, 0.05, 0.3, 1.0])
def test_d_projected_area_is_one(alpha):
    """integral D(h) cos(theta_h) dh = 1 (1-D in theta_h: D is isotropic; the grid resolves the
    peak, whose width is ~alpha radians)."""
    k = 400_000
    theta = (np.arange(k) + 0.5) * (0.5 * np.pi / k)
    c = np.cos(theta)
    d = mf.ggx_d(c, np.full(k, alpha))
    total = 2.0 * np.pi * (d * c * np.sin(theta)).sum() * (0.5 * np.pi / k)
    assert abs(total - 1.0) < 1e-4


@pytest.mark.parametrize("alpha,theta", [(0.2, 0.0), (0.5, 60.0), (1.0, 85.0)])
def test_visible_normal_density_is_normalised(alpha, theta):
    """integral G1(wo) max(0, wo.h) D(h) / cos_o dh = 1."""
    h, dw = _hemisphere_grid(1200)
    m = h.shape[0]
    t = np.radians(theta)
    wo = np.array([np.sin(t), 0.0, np.cos(t)])
    a = np.full(m, alpha)
    g1 = mf.ggx_g1(np.full(m, wo[2]), a)
    dens = g1 * np.maximum(h @ wo, 0.0) * mf.ggx_d(h[:, 2], a) / wo[2]
    assert abs(dens.sum() * dw - 1.0) < 2e-3


def test_vndf_samples_are_visible_and_unit():
    rng = np.random.default_rng(3)
    n = 10_000
    t = np.radians(80.0)
    wo = np.tile([np.sin(t), 0.0, np.cos(t)], (n, 1))
    h = mf.sample_ggx_vndf(wo, np.full(n, 0.4), rng.random((n, 2)))
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), 1.0, atol=1e-12)
    assert np.all(h[:, 2] >= 0.0)
    assert np.all(np.einsum("ij,ij->i", h, wo) >= -1e-12)


def test_stored_tables_match_fresh_quadrature():
    """Spot-check nodes of the stored A, B tables against a new (coarser) quadrature."""
    mu, alpha = mf.table_nodes()
    tables = mf.albedo_tables()
    rng = np.random.default_rng(11)
    for i, j in zip(rng.integers(0, mf.N_MU, 6), rng.integers(0, mf.N_A, 6)):
        a, b = mf.compute_albedo_tables(128, [mu[i]], [alpha[j]])
        assert abs(a[0, 0] - tables.a[i, j]) < 2e-3
        assert abs(b[0, 0] - tables.b[i, j]) < 2e-3


@pytest.mark.parametrize(
    "mu,alpha", [(np.cos(np.radians(89.0)), 0.0025), (0.003, 0.01), (0.37, 0.2), (0.93, 0.55)]
)
def test_interpolated_albedo_between_nodes(mu, alpha):
    """Bilinear interpolation in (sqrt mu, log alpha) stays within the table tolerance off-node."""
    a, b = mf.compute_albedo_tables(256, [mu], [alpha])
    ta, tb = mf.albedo_tables().lookup(np.array([mu]), np.array([alpha]))
    assert abs(a[0, 0] - ta[0]) < 2e-3
    assert abs(b[0, 0] - tb[0]) < 2e-3


def test_table_invariants():
    t = mf.albedo_tables()
    assert np.all(t.a >= 0.0) and np.all(t.b >= 0.0) and np.all(t.a + t.b <= 1.0)


@pytest.mark.parametrize("alpha", [mf.ALPHA_MIN, 0.0025, 0.2, 0.77, 1.0])
def test_cosine_weighted_average_is_exact(alpha):
    """albedo_avg equals 2 integral E(mu) mu dmu of the *interpolated* E (what makes the diffuse
    coupling integrate to exactly rho_d (1 - E(wo)))."""
    t = mf.albedo_tables()
    k = 200_000
    mu = (np.arange(k) + 0.5) / k
    f0 = np.tile([0.04, 0.5, 1.0], (k, 1))
    for f90 in (None, np.tile([1.0, 0.7, 0.2], (k, 1))):
        e = t.albedo(f0, mu, np.full(k, alpha), f90)
        brute = 2.0 * (e * mu[:, None]).sum(axis=0) / k
        avg = t.albedo_avg(f0[:1], np.array([alpha]), None if f90 is None else f90[:1])[0]
        np.testing.assert_allclose(avg, brute, rtol=0, atol=2e-6)


def test_fresnel_schlick_limits():
    f0 = np.array([[0.04, 0.5, 1.0]])
    np.testing.assert_allclose(mf.fresnel_schlick(f0, np.array([1.0])), f0)
    np.testing.assert_allclose(mf.fresnel_schlick(f0, np.array([0.0])), [[1.0, 1.0, 1.0]])
    f90 = np.array([[1.0, 0.7, 0.2]])
    np.testing.assert_allclose(mf.fresnel_schlick(f0, np.array([1.0]), f90), f0)
    np.testing.assert_allclose(mf.fresnel_schlick(f0, np.array([0.0]), f90), f90)
    w = 0.5**5
    np.testing.assert_allclose(mf.fresnel_schlick(f0, np.array([0.5]), f90), f0 * (1.0 - w) + f90 * w)
