"""The fused path-vertex kernels of PreviewSurfaceBSDF (path_scatter, path_light_half) against
the unfused route the path tracer takes for other BSDFs: sample_f / f_pdf plus the numpy
arithmetic of integrators/path.py and estimators/mis.mis_light_half, row by row, on random
inputs that include the edge cases (wo or wi below the surface, wi behind the geometric normal,
zero and infinite pdfs, delta lights, Russian roulette, both heuristics)."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.geometry import coordinate_frame, dot, to_local, to_world
from renderer.sampling import balance_heuristic, power_heuristic, safe_div
from tests.bsdfs.test_preview_surface import _random_bsdf, _random_unit

N = 4000


def _vertex(rng, n):
    """Random shading frames, geometric normals near the shading normal, wo (local), beta."""
    ns = _random_unit(rng, n)
    ng = ns + 0.3 * rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    s, t = coordinate_frame(ns)
    wo = _random_unit(rng, n)
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])  # most rows above, some below the surface
    beta = rng.random((n, 3)) * np.where(rng.random((n, 1)) < 0.1, 0.01, 1.0)
    return ns, ng, s, t, wo, beta


def test_path_scatter_matches_sample_f():
    rng = np.random.default_rng(11)
    bsdf = _random_bsdf(rng, N)
    ns, ng, s, t, wo, beta = _vertex(rng, N)
    bsdf.bind_wo(wo)
    u_lobe, u, u_rr = rng.random(N), rng.random((N, 2)), rng.random(N)
    rr = rng.random(N) < 0.5
    wi, beta_f, pdf_f, ok_f = bsdf.path_scatter(wo, s, t, ns, ng, beta, u_lobe, u, u_rr, rr)

    bs = bsdf.sample_f(wo, u_lobe, u)
    wi_ref = to_world(bs.wi, s, t, ns)
    ok = (bs.pdf > 0.0) & (dot(wi_ref, ng) > 0.0)
    b = beta * safe_div(bs.f * np.abs(bs.wi[:, 2])[:, None], bs.pdf)
    ok &= np.any(b > 0.0, axis=1) & np.all(np.isfinite(b), axis=1)
    q = np.where(rr, np.clip(1.0 - b.max(axis=1), 0.0, 0.95), 0.0)
    ok &= u_rr >= q
    b = b / (1.0 - q)[:, None]

    assert 0.2 < ok.mean() < 0.9  # the cases are all exercised
    np.testing.assert_array_equal(ok_f, ok)
    np.testing.assert_allclose(pdf_f, bs.pdf, rtol=1e-12, atol=0)
    np.testing.assert_allclose(wi[ok], wi_ref[ok], rtol=0, atol=1e-12)
    np.testing.assert_allclose(beta_f[ok], b[ok], rtol=1e-12, atol=0)
    assert np.all(beta_f[~ok] == 0.0)


@pytest.mark.parametrize("heuristic", ["power", "balance"])
def test_path_light_half_matches_numpy(heuristic):
    rng = np.random.default_rng(12 if heuristic == "power" else 13)
    bsdf = _random_bsdf(rng, N)
    ns, ng, s, t, wo, beta = _vertex(rng, N)
    bsdf.bind_wo(wo)
    wi = _random_unit(rng, N)
    L = rng.random((N, 3)) * 5.0
    pdf_l = rng.random(N) * 3.0
    pdf_l[rng.random(N) < 0.05] = 0.0           # failed light samples
    delta = rng.random(N) < 0.1                  # point / distant lights
    pmf = rng.random(N)
    pmf[rng.random(N) < 0.05] = 0.0
    power = np.full(N, heuristic == "power")
    c = bsdf.path_light_half(wo, s, t, ns, ng, wi, L, pdf_l, delta, pmf, power, beta)

    # The unfused route: light_samples' masks, f_pdf, mis_light_half's weight and ratio, then
    # the integrator's beta / pmf.
    wi_l = to_local(wi, s, t, ns)
    above = (wi_l[:, 2] > 0.0) & (dot(wi, ng) > 0.0)
    f, p_b = bsdf.f_pdf(wo, wi_l)
    integrand = f * (np.abs(wi_l[:, 2]) * above)[:, None] * L * (pdf_l > 0.0)[:, None]
    p_l = np.where(delta, np.inf, pdf_l)
    h = power_heuristic if heuristic == "power" else balance_heuristic
    with np.errstate(invalid="ignore"):  # inf * 0 on delta rows with pmf 0: their result is 0 anyway
        w = h(1, p_l * pmf, 1, p_b)
    Ld = safe_div(integrand * w[:, None], np.where(np.isinf(p_l), 1.0, p_l))
    ref = beta * safe_div(Ld, pmf)

    live = np.any(ref > 0.0, axis=1)
    assert 0.1 < live.mean() < 0.7
    assert np.any(live & delta)
    np.testing.assert_allclose(c, ref, rtol=1e-11, atol=1e-300)


def test_delta_light_takes_the_whole_weight_under_both_heuristics():
    """A delta light cannot be reached by a BSDF sample: its light sample's MIS weight is 1.
    (balance_heuristic gave inf/inf -> 0 before, which would have blacked out a point light
    rendered with MIS and the balance heuristic.)"""
    inf, p = np.array([np.inf, np.inf]), np.array([0.0, 2.0])
    for h in (power_heuristic, balance_heuristic):
        np.testing.assert_array_equal(h(1, inf, 1, p), [1.0, 1.0])
        np.testing.assert_array_equal(h(1, p, 1, inf), [0.0, 0.0])
