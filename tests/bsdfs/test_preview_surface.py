"""UsdPreviewSurface BSDF: sampling vs pdf (chi-square), sample-record consistency, reciprocity,
energy conservation, agreement of the Monte Carlo albedo with quadrature, parameter mapping."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.bsdfs.microfacet import ALPHA_MIN, compute_albedo_tables
from renderer.bsdfs.preview_surface import LOBE_DIFFUSE, LOBE_SPECULAR, PreviewSurfaceBSDF
from tests.bsdfs.helpers import direction, preview, reflect_z, tile
from tests.stats import SIGNIFICANCE, chi2_directions, z_test

ROUGHNESS = [0.05, 0.3, 0.8]
ANGLES = [0.0, 45.0, 85.0]
N_CHI2 = 200_000


def _glossy_chi2(sample, pdf, wo1: np.ndarray, roughness: float):
    """chi2_directions about the mirror direction, in a cos-theta band that resolves the peak.

    At normal incidence the reflected lobe falls off on the scale 1 - cos ~ 2 alpha^2; toward
    grazing it is compressed across the plane of incidence by ~cos(theta_o), so the band is
    1 - cos < 40 alpha^2 cos^2(theta_o): ~20 bins across the narrow direction, the rest of the
    mass goes to the overflow bin. A finer integration grid keeps the expected counts of the
    peak bins accurate.
    """
    alpha = max(roughness * roughness, ALPHA_MIN)
    width = 40.0 * alpha * alpha * max(wo1[2] * wo1[2], 1e-4)
    return chi2_directions(
        sample,
        pdf,
        n_samples=N_CHI2,
        axis=reflect_z(wo1),
        cos_range=(max(-1.0, 1.0 - width), 1.0),
        integration_res=24,
    )


def _random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _random_bsdf(rng, n) -> PreviewSurfaceBSDF:
    """Random UsdPreviewSurface inputs per row, both workflows, roughness down to 0."""
    rough = rng.random(n)
    rough[: n // 10] = 0.0
    return PreviewSurfaceBSDF.from_inputs(
        rng.random((n, 3)),
        rng.random((n, 3)),
        rng.random(n) < 0.3,
        np.where(rng.random(n) < 0.3, 1.0, rng.random(n)),
        rough,
        1.0 + rng.random(n) * 2.0,
    )


# --------------------------------------------------------------------------------------
# Chi-square: each lobe alone and the mixture
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_diffuse_lobe(theta):
    wo1 = direction(theta, 10.0)

    def sample(u):
        n = u.shape[0]
        wi, pdf = preview(n).sample_diffuse(tile(wo1, n), u)
        return wi, pdf > 0.0

    def pdf(wi):
        m = wi.shape[0]
        return preview(m).pdf_diffuse(tile(wo1, m), wi)

    p, d = chi2_directions(sample, pdf, n_samples=N_CHI2)
    assert p > SIGNIFICANCE, d["chi2"]


def _metal(n, roughness):
    # Metallic: rho_d = 0, so sample_f always picks the specular lobe.
    return preview(n, diffuse=(0.9, 0.6, 0.3), metallic=1.0, roughness=roughness)


@pytest.mark.parametrize("roughness", ROUGHNESS)
@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_specular_lobe_alone(roughness, theta):
    wo1 = direction(theta, 30.0)
    probe = _metal(1, roughness)
    assert probe.lobe_probabilities(wo1[None])[1][0] == 1.0

    def sample(u):
        n = u.shape[0]
        s = _metal(n, roughness).sample_f(tile(wo1, n), np.full(n, 0.5), u)
        assert np.all(s.lobe == LOBE_SPECULAR)
        return s.wi, s.pdf > 0.0

    def pdf(wi):
        m = wi.shape[0]
        return _metal(m, roughness).pdf(tile(wo1, m), wi)

    p, d = _glossy_chi2(sample, pdf, wo1, roughness)
    assert p > SIGNIFICANCE, d["chi2"]


def _plastic(n, roughness):
    return preview(n, diffuse=(0.6, 0.4, 0.2), roughness=roughness)


@pytest.mark.parametrize("roughness", ROUGHNESS)
@pytest.mark.parametrize("theta", ANGLES)
def test_chi2_mixture(roughness, theta):
    wo1 = direction(theta, 30.0)
    u_lobe = np.random.default_rng(5).random(N_CHI2)

    def sample(u):
        n = u.shape[0]
        s = _plastic(n, roughness).sample_f(tile(wo1, n), u_lobe[:n], u)
        return s.wi, s.pdf > 0.0

    def pdf(wi):
        m = wi.shape[0]
        return _plastic(m, roughness).pdf(tile(wo1, m), wi)

    # About the mirror direction, resolving the glossy peak ...
    p, d = _glossy_chi2(sample, pdf, wo1, roughness)
    assert p > SIGNIFICANCE, d["chi2"]
    if roughness >= 0.8:
        # ... and, for the broad lobe, over the whole sphere about the normal, where the diffuse
        # part is resolved too. (For narrower lobes the 0.1-wide cos bins of this layout put the
        # peak inside one bin, whose expected count the midpoint rule cannot integrate.)
        p, d = chi2_directions(sample, pdf, n_samples=N_CHI2, integration_res=24)
        assert p > SIGNIFICANCE, d["chi2"]


# --------------------------------------------------------------------------------------
# The sample record, the lobe sum, reciprocity, hemispheres
# --------------------------------------------------------------------------------------
def test_sample_record_is_consistent(rng):
    n = 20_000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wo[:, 2] = np.abs(wo[:, 2])
    s = b.sample_f(wo, rng.random(n), rng.random((n, 2)))
    np.testing.assert_allclose(s.pdf, b.pdf(wo, s.wi), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(s.f, b.f(wo, s.wi), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(np.linalg.norm(s.wi, axis=1), 1.0, atol=1e-12)
    assert s.lobe.dtype == np.int8
    assert set(np.unique(s.lobe)) <= {LOBE_DIFFUSE, LOBE_SPECULAR}
    assert np.all(np.isfinite(s.f)) and np.all(np.isfinite(s.pdf))
    # Failed samples (below the horizon) have pdf 0 and f 0; valid ones have pdf > 0.
    below = s.wi[:, 2] <= 0.0
    assert np.all(s.pdf[below] == 0.0) and np.all(s.f[below] == 0.0)
    assert np.all(s.pdf[~below] > 0.0)
    # The lobe actually chosen follows the lobe probabilities.
    p_d, p_s = b.lobe_probabilities(wo)
    np.testing.assert_allclose(p_d + p_s, 1.0)
    assert abs((s.lobe == LOBE_DIFFUSE).mean() - p_d.mean()) < 5.0 * np.sqrt(0.25 / n)


def test_f_is_sum_of_lobes_and_pdf_is_the_mixture(rng):
    n = 5000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    np.testing.assert_allclose(b.f(wo, wi), b.f_diffuse(wo, wi) + b.f_specular(wo, wi), rtol=1e-12)
    p_d, p_s = b.lobe_probabilities(wo)
    mix = p_d * b.pdf_diffuse(wo, wi) + p_s * b.pdf_specular(wo, wi)
    np.testing.assert_allclose(b.pdf(wo, wi), mix, rtol=1e-12)
    # f_diffuse factors into a constant-in-wi part and a wi part (the control-variate contract).
    np.testing.assert_allclose(
        b.f_diffuse(wo, wi), b.diffuse_constant(wo) * b.diffuse_factor_wi(wi), rtol=1e-12, atol=1e-300
    )


def test_reciprocity(rng):
    n = 20_000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    wo[:, 2] = np.abs(wo[:, 2])
    wi[:, 2] = np.abs(wi[:, 2])
    np.testing.assert_allclose(b.f(wo, wi), b.f(wi, wo), rtol=1e-10, atol=0.0)
    np.testing.assert_allclose(b.f_diffuse(wo, wi), b.f_diffuse(wi, wo), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(b.f_specular(wo, wi), b.f_specular(wi, wo), rtol=1e-10, atol=0.0)


def test_reflection_only(rng):
    n = 4000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    below = (wo[:, 2] <= 0.0) | (wi[:, 2] <= 0.0)
    for arr in (b.f(wo, wi), b.f_diffuse(wo, wi), b.f_specular(wo, wi)):
        assert np.all(arr[below] == 0.0)
    assert np.all(b.pdf(wo, wi)[below] == 0.0)
    s = b.sample_f(wo, rng.random(n), rng.random((n, 2)))
    down = wo[:, 2] <= 0.0
    assert np.all(s.pdf[down] == 0.0) and np.all(s.f[down] == 0.0)
    assert np.all(b.diffuse_constant(wo)[down] == 0.0)
    assert np.all(b.specular_albedo(wo)[down] == 0.0)


# --------------------------------------------------------------------------------------
# Energy
# --------------------------------------------------------------------------------------
def _mc_albedo(b: PreviewSurfaceBSDF, wo1: np.ndarray, n: int, rng) -> np.ndarray:
    """Per-sample estimates (n, 3) of integral f cos dwi with the BSDF's own sampler."""
    s = b.sample_f(tile(wo1, n), rng.random(n), rng.random((n, 2)))
    ok = s.pdf > 0.0
    w = np.zeros((n, 3))
    w[ok] = s.f[ok] * s.wi[ok, 2:3] / s.pdf[ok, None]
    return w


# Tolerance of the tabulated specular albedo the diffuse coupling relies on (quadrature plus
# interpolation error; test_microfacet checks the table to this level).
TABLE_TOL = 2e-3


@pytest.mark.parametrize(
    "config", ["white_metal", "white_dielectric", "white_coated_mirror", "white_base_f90_half", "tinted_half_metal"]
)
def test_energy_conservation(config, rng):
    """Albedo <= 1 over roughness x angle for F0 = 1, for a white base under a coat and with edge
    reflectivity F90 < 1; a white diffuse base under any coat is energy *preserving* (furnace
    == 1), which holds only if E(wo) and E_avg use the same F90."""
    n = 100_000
    for roughness in (0.0, 0.05, 0.3, 0.8, 1.0):
        if config == "white_base_f90_half":
            alpha = np.full(n, max(roughness * roughness, ALPHA_MIN))
            b = PreviewSurfaceBSDF(np.ones((n, 3)), np.full((n, 3), 0.04), alpha, np.full((n, 3), 0.5))
        elif config == "tinted_half_metal":  # channel 1: F0 0.196, F90 0.58, rho_d 0.12
            b = preview(n, diffuse=(1.0, 0.3, 1.0), metallic=0.6, roughness=roughness)
        elif config == "white_metal":
            b = preview(n, diffuse=(1, 1, 1), metallic=1.0, roughness=roughness)
        elif config == "white_dielectric":
            b = preview(n, diffuse=(1, 1, 1), roughness=roughness)
        else:  # specular workflow, F0 = 1 over a white diffuse base
            b = preview(n, diffuse=(1, 1, 1), specular=(1, 1, 1), specular_workflow=True, roughness=roughness)
        for theta in (0.0, 45.0, 75.0, 85.0, 89.0):
            w = _mc_albedo(b, direction(theta), n, rng)[:, 1]
            mean, se = w.mean(), w.std(ddof=1) / np.sqrt(n)
            assert mean <= 1.0 + 4.0 * se + TABLE_TOL, (roughness, theta, mean, se)
            if config in ("white_dielectric", "white_base_f90_half"):
                assert mean >= 1.0 - 4.0 * se - TABLE_TOL, (roughness, theta, mean, se)


def _quadrature_albedo(b1, wo1: np.ndarray, axis: np.ndarray, c_lo: float, res: int = 800):
    """Midpoint-rule integral (3,) of f cos over the cap {cos(angle to axis) >= c_lo}, on a
    (cos, phi) grid about ``axis`` (pick the cap to hold the whole lobe; c_lo = -1: everything)."""
    ax = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(ax[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, ax)
    s /= np.linalg.norm(s)
    t = np.cross(ax, s)
    dc = (1.0 - c_lo) / res
    dp = 2.0 * np.pi / (2 * res)
    c = c_lo + (np.arange(res) + 0.5) * dc
    p = (np.arange(2 * res) + 0.5) * dp
    C, P = np.meshgrid(c, p, indexing="ij")
    S = np.sqrt(1.0 - C * C)
    local = np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1).reshape(-1, 3)
    wi = local @ np.stack([s, t, ax])
    m = wi.shape[0]
    b = b1.take(np.zeros(m, dtype=np.int64))
    f = b.f(tile(wo1, m), wi)
    return (f * np.maximum(wi[:, 2:3], 0.0)).sum(axis=0) * dc * dp


@pytest.mark.parametrize(
    "roughness,theta,metal",
    [(0.3, 30.0, False), (0.8, 60.0, False), (0.5, 80.0, True), (1.0, 0.0, True)],
)
def test_mc_albedo_matches_quadrature(roughness, theta, metal, rng):
    kw = dict(diffuse=(0.9, 0.5, 0.2), roughness=roughness, metallic=1.0 if metal else 0.0)
    wo1 = direction(theta, 45.0)
    ref = _quadrature_albedo(preview(1, **kw), wo1, np.array([0.0, 0.0, 1.0]), -1.0)
    n = 200_000
    w = _mc_albedo(preview(n, **kw), wo1, n, rng)
    for k in range(3):
        assert z_test(w[:, k], ref[k]) > SIGNIFICANCE, (k, w[:, k].mean(), ref[k])


@pytest.mark.parametrize("roughness,theta", [(0.1, 0.0), (0.3, 70.0), (0.8, 85.0), (0.05, 89.0)])
def test_specular_albedo_table_matches_the_lobe(roughness, theta, rng):
    """specular_albedo(wo) (tabulated) equals the Monte Carlo albedo of the specular lobe."""
    kw = dict(diffuse=(0.9, 0.5, 0.05), roughness=roughness, metallic=1.0)
    wo1 = direction(theta)
    n = 200_000
    b = preview(n, **kw)
    w = _mc_albedo(b, wo1, n, rng)
    e = b.specular_albedo(tile(wo1, 1))[0]
    for k in range(3):
        mean, se = w[:, k].mean(), w[:, k].std(ddof=1) / np.sqrt(n)
        assert abs(mean - e[k]) <= 4.0 * se + TABLE_TOL, (k, mean, e[k], se)


# --------------------------------------------------------------------------------------
# Edge reflectivity F90 (spec: "If metallic is 1, then both F0 [...] and edge F90 reflectivity
# will simply be the Albedo"; F90 is white for metallic 0 and in the specular workflow)
# --------------------------------------------------------------------------------------
ALBEDO = np.array([0.9, 0.5, 0.2])


@pytest.mark.parametrize("theta", [30.0, 60.0, 80.0, 89.0])
def test_metal_reflection_keeps_the_albedo_tint_at_grazing(theta):
    """metallic = 1: F0 = F90 = diffuseColor, so Fresnel is the albedo at every angle and the
    channels of f (and of the specular albedo) keep the albedo's ratios. With F90 = 1 the
    grazing reflection would whiten (at 80 degrees the blue/red ratio of f at the mirror
    direction would be 0.54 instead of 0.22)."""
    wo1 = direction(theta, 30.0)
    wi = np.stack([reflect_z(wo1), direction(max(theta - 25.0, 0.0), 150.0)])  # mirror, off-mirror
    for roughness in (0.05, 0.3, 0.8):
        b = preview(2, diffuse=tuple(ALBEDO), metallic=1.0, roughness=roughness)
        f = b.f(tile(wo1, 2), wi)
        assert np.all(f > 0.0)
        np.testing.assert_allclose(f / ALBEDO, np.repeat(f[:, 1:2] / ALBEDO[1], 3, axis=1), rtol=1e-12)
        e = b.specular_albedo(tile(wo1, 1))[0]
        np.testing.assert_allclose(e / ALBEDO, e[1] / ALBEDO[1], rtol=1e-12)


@pytest.mark.parametrize("roughness,theta,metallic", [(0.5, 80.0, 1.0), (0.3, 85.0, 1.0), (0.5, 80.0, 0.5)])
def test_albedo_matches_closed_form_with_f90(roughness, theta, metallic, rng):
    """The directional albedo, by quadrature and by Monte Carlo, equals E + rho_d (1 - E) with
    E = F0 A + F90 B, F0 = lerp(((ior - 1) / (ior + 1))^2, albedo, metallic),
    F90 = lerp(1, albedo, metallic), and A, B computed afresh by VNDF quadrature at this
    (mu, alpha) rather than read from the stored tables."""
    kw = dict(diffuse=tuple(ALBEDO), roughness=roughness, metallic=metallic, ior=1.5)
    wo1 = direction(theta, 45.0)
    a_tab, b_tab = compute_albedo_tables(256, mu=[wo1[2]], alpha=[max(roughness * roughness, ALPHA_MIN)])
    f0 = 0.04 * (1.0 - metallic) + ALBEDO * metallic
    f90 = (1.0 - metallic) + ALBEDO * metallic
    e = f0 * a_tab[0, 0] + f90 * b_tab[0, 0]
    expected = e + ALBEDO * (1.0 - metallic) * (1.0 - e)
    ref = _quadrature_albedo(preview(1, **kw), wo1, np.array([0.0, 0.0, 1.0]), -1.0)
    np.testing.assert_allclose(ref, expected, rtol=0.0, atol=TABLE_TOL)
    n = 200_000
    w = _mc_albedo(preview(n, **kw), wo1, n, rng)
    for k in range(3):
        mean, se = w[:, k].mean(), w[:, k].std(ddof=1) / np.sqrt(n)
        assert abs(mean - expected[k]) <= 4.0 * se + TABLE_TOL, (k, mean, expected[k], se)


@pytest.mark.parametrize("roughness,theta", [(0.05, 0.0), (0.5, 60.0), (1.0, 85.0)])
def test_diffuse_lobe_albedo(roughness, theta):
    """integral f_diffuse cos dwi == pi * diffuse_constant(wo) == rho_d (1 - E(wo))."""
    b1 = preview(1, diffuse=(0.9, 0.5, 0.2), roughness=roughness)
    wo1 = direction(theta)
    res = 400
    c = (np.arange(res) + 0.5) / res
    p = (np.arange(2 * res) + 0.5) * (np.pi / res)
    C, P = np.meshgrid(c, p, indexing="ij")
    S = np.sqrt(1.0 - C * C)
    wi = np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1).reshape(-1, 3)
    m = wi.shape[0]
    b = b1.take(np.zeros(m, dtype=np.int64))
    integral = (b.f_diffuse(tile(wo1, m), wi) * wi[:, 2:3]).sum(axis=0) * (1.0 / res) * (np.pi / res)
    expected = np.pi * b1.diffuse_constant(wo1[None])[0]
    np.testing.assert_allclose(integral, expected, rtol=2e-4)
    e = b1.specular_albedo(wo1[None])[0]
    np.testing.assert_allclose(expected, b1.diffuse_albedo()[0] * (1.0 - e), rtol=1e-12)


# --------------------------------------------------------------------------------------
# Parameter mapping
# --------------------------------------------------------------------------------------
def test_metallic_workflow_mapping():
    b = PreviewSurfaceBSDF.from_inputs(
        np.array([[0.8, 0.4, 0.2], [0.8, 0.4, 0.2], [0.8, 0.4, 0.2]]),
        np.array([[1.0, 1.0, 1.0]] * 3),  # ignored in the metallic workflow
        np.array([False, False, False]),
        np.array([0.0, 1.0, 0.5]),
        np.array([0.5, 0.0, 2.0]),
        np.array([1.5, 1.5, 2.0]),
    )
    f0_d = ((1.5 - 1.0) / (1.5 + 1.0)) ** 2
    np.testing.assert_allclose(b.f0[0], [f0_d] * 3)
    np.testing.assert_allclose(b.f90[0], [1.0] * 3)  # spec: "If metallic is 0 [...] F90 is white"
    np.testing.assert_allclose(b.diffuse_albedo()[0], [0.8, 0.4, 0.2])
    np.testing.assert_allclose(b.f0[1], [0.8, 0.4, 0.2])
    np.testing.assert_allclose(b.f90[1], [0.8, 0.4, 0.2])  # "both F0 and edge F90 [...] the Albedo"
    np.testing.assert_allclose(b.diffuse_albedo()[1], [0.0, 0.0, 0.0])
    f0_2 = (1.0 / 3.0) ** 2
    np.testing.assert_allclose(b.f0[2], 0.5 * f0_2 + 0.5 * np.array([0.8, 0.4, 0.2]))
    np.testing.assert_allclose(b.f90[2], 0.5 + 0.5 * np.array([0.8, 0.4, 0.2]))
    np.testing.assert_allclose(b.diffuse_albedo()[2], [0.4, 0.2, 0.1])
    np.testing.assert_allclose(b.alpha, [0.25, ALPHA_MIN, 1.0])  # roughness clamped to [0, 1]


def test_specular_workflow_mapping_and_clamps():
    b = PreviewSurfaceBSDF.from_inputs(
        np.array([[1.5, 0.5, -0.2]]),
        np.array([[0.2, 0.9, 1.7]]),
        np.array([True]),
        np.array([1.0]),  # ignored in the specular workflow
        np.array([0.3]),
        np.array([1.5]),
    )
    np.testing.assert_allclose(b.f0[0], [0.2, 0.9, 1.0])
    np.testing.assert_allclose(b.f90[0], [1.0, 1.0, 1.0])  # "color at 90 is assumed white"
    np.testing.assert_allclose(b.diffuse_albedo()[0], [1.0, 0.5, 0.0])
    np.testing.assert_allclose(b.alpha, [0.09])


def test_take_subsets_rows(rng):
    n = 100
    b = _random_bsdf(rng, n)
    rows = np.array([5, 7, 7, 99])
    sub = b.take(rows)
    wo = _random_unit(rng, rows.size)
    wi = _random_unit(rng, rows.size)
    wo[:, 2] = np.abs(wo[:, 2])
    wi[:, 2] = np.abs(wi[:, 2])
    assert np.any(b.f90[rows] < 1.0)  # metallic rows: F90 must come along too
    ref = PreviewSurfaceBSDF(b.rho_d[rows], b.f0[rows], b.alpha[rows], b.f90[rows])
    np.testing.assert_array_equal(sub.f(wo, wi), ref.f(wo, wi))
    np.testing.assert_array_equal(sub.pdf(wo, wi), ref.pdf(wo, wi))
    assert len(sub) == 4


# --------------------------------------------------------------------------------------
# The numba kernels against the numpy reference
# --------------------------------------------------------------------------------------
def test_kernels_match_numpy_reference(rng):
    n = 50_000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])
    f, pdf = b.f_pdf(wo, wi)
    f_ref, pdf_ref = b.reference_f_pdf(wo, wi)
    np.testing.assert_allclose(f, f_ref, rtol=1e-11, atol=1e-300)
    np.testing.assert_allclose(pdf, pdf_ref, rtol=1e-11, atol=1e-300)
    u_lobe, u = rng.random(n), rng.random((n, 2))
    s = b.sample_f(wo, u_lobe, u)
    r = b.reference_sample_f(wo, u_lobe, u)
    np.testing.assert_array_equal(s.lobe, r.lobe)
    up = wo[:, 2] > 0.0
    np.testing.assert_allclose(s.wi[up], r.wi[up], rtol=0, atol=1e-12)
    # The sampled pdf and f are those of the sampled half vector, in a narrow lobe very sensitive to
    # its rounding: at GGX alpha ~1e-3 a pdf near 1e6 moves ~1e-9 relative per ulp of h, so the
    # kernel and the reference (equal directions to 1e-12) agree to a few 1e-9, no better.
    np.testing.assert_allclose(s.pdf, r.pdf, rtol=5e-9, atol=1e-300)
    np.testing.assert_allclose(s.f, r.f, rtol=5e-9, atol=1e-300)


def test_non_contiguous_inputs(rng):
    n = 1000
    b = _random_bsdf(rng, n)
    big = _random_unit(rng, 2 * n)
    big[:, 2] = np.abs(big[:, 2])
    wo, wi = big[::2], big[1::2]  # strided views
    f, pdf = b.f_pdf(wo, wi)
    f2, pdf2 = b.f_pdf(wo.copy(), wi.copy())
    np.testing.assert_array_equal(f, f2)
    np.testing.assert_array_equal(pdf, pdf2)


def test_f_parts_matches_the_separate_methods(rng):
    n = 20_000
    b = _random_bsdf(rng, n)
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])
    f, fd, pdf = b.f_parts(wo, wi)
    np.testing.assert_array_equal(f, b.f(wo, wi))
    np.testing.assert_array_equal(fd, b.f_diffuse(wo, wi))
    np.testing.assert_array_equal(pdf, b.pdf(wo, wi))
    f2, pdf2 = b.f_pdf(wo, wi)
    np.testing.assert_array_equal(f, f2)
    np.testing.assert_array_equal(pdf, pdf2)


def test_bind_wo_only_saves_work(rng):
    """Bound wo terms give bit-identical results, travel with take(), and are ignored for rows
    whose wo differs from the bound one."""
    n = 5000
    wo = _random_unit(rng, n)
    wi = _random_unit(rng, n)
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])
    u_lobe, u = rng.random(n), rng.random((n, 2))
    plain = _random_bsdf(np.random.default_rng(9), n)
    bound = _random_bsdf(np.random.default_rng(9), n).bind_wo(wo)

    def everything(b, wo_, wi_, ul, uu):
        s = b.sample_f(wo_, ul, uu)
        return [*b.f_parts(wo_, wi_), b.f_specular(wo_, wi_), b.diffuse_constant(wo_),
                b.lobe_probabilities(wo_)[0], s.f, s.wi, s.pdf, s.lobe]

    for x, y in zip(everything(plain, wo, wi, u_lobe, u), everything(bound, wo, wi, u_lobe, u)):
        np.testing.assert_array_equal(x, y)
    rows = np.array([3, 3, 17, n - 1, 0])
    for x, y in zip(everything(plain.take(rows), wo[rows], wi[rows], u_lobe[rows], u[rows]),
                    everything(bound.take(rows), wo[rows], wi[rows], u_lobe[rows], u[rows])):
        np.testing.assert_array_equal(x, y)
    # A different wo (same array object mutated in place, and a fresh one) is not served stale terms.
    other = _random_unit(rng, n)
    other[:, 2] = np.abs(other[:, 2])
    for x, y in zip(everything(plain, other, wi, u_lobe, u), everything(bound, other, wi, u_lobe, u)):
        np.testing.assert_array_equal(x, y)
    wo[:] = other
    np.testing.assert_array_equal(bound.f_parts(wo, wi)[0], plain.f_parts(other, wi)[0])
