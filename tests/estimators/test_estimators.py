"""Statistical proofs for the per-light estimators (issue: estimators chosen by our schema).

Each test compares a Monte Carlo mean against an analytic reference with a z-test under a fixed
seed, or checks an exact property (zero variance, exact zeros).
"""

import numpy as np
import pytest

from tests.estimators.helpers import Setup, reference, unshadowed_F
from tests.stats import SIGNIFICANCE, z_test

UNBIASED = [
    ("mis:balance", "one", 1), ("mis:balance", "one", 4),
    ("lightSampling", "one", 1), ("lightSampling", "one", 4),
    ("bsdfSampling", "one", 1), ("bsdfSampling", "one", 4),
    ("mis", "one", 1), ("mis", "one", 4),
    ("controlVariate", "one", 1), ("controlVariate", "one", 4),
    ("controlVariate", "averageVisibilityUnbiased", 2), ("controlVariate", "averageVisibilityUnbiased", 4),
    ("controlVariate", "averageVisibilityUnbiased", 8),
]


@pytest.mark.parametrize("token,alpha,N", UNBIASED)
def test_unbiased_estimators_match_analytic_penumbra(token, alpha, N):
    token, _, heuristic = token.partition(":")
    heuristic = heuristic or "power"
    s = Setup("half", n=20000)
    Ld = s.estimate(token, N, alpha, heuristic, seed=11)
    ref = reference("half")
    assert ref > 0.05
    p = z_test(Ld[:, 0], ref)
    assert p > SIGNIFICANCE, f"{token}/{alpha}/N={N}: mean {Ld[:, 0].mean():.6f} vs {ref:.6f} (p={p:.2e})"


def test_z_test_detects_a_wrong_reference():
    # The harness must be able to fail: a 2% error is caught at this sample count.
    s = Setup("half", n=20000)
    Ld = s.estimate("controlVariate", 4, "averageVisibilityUnbiased", seed=3)
    assert z_test(Ld[:, 0], reference("half") * 1.02) < SIGNIFICANCE


@pytest.mark.parametrize("N", [2, 4, 8])
def test_biased_average_visibility_matches_the_talks_derivation(N):
    """E = (1/N) E[V] E[F] + ((N-1)/N) E[FV], each term estimated separately.

    A low, wide light with an off-centre occluder makes visibility correlate with f/p (the
    visible part holds the light's centre), so the bias is large enough to measure.
    """
    from renderer.estimators import DirectRandom
    from renderer.estimators.base import light_samples

    h = 0.6
    s = Setup("offset", n=40000, height=h)
    biased = s.estimate("controlVariate", N, "averageVisibility", seed=100 + N)[:, 0]
    # E[V]: the probability that one light sample is visible (an independent run);
    # E[F]: the unshadowed integral and E[FV]: the shadowed one, both analytic.
    ls, _ = light_samples(s.query(), s.lights, s.trace, 1, DirectRandom.draw(np.random.default_rng(7), s.n, 1))
    EV = ls.v.mean()
    EF = unshadowed_F(h)
    EFV = reference("offset", h)
    predicted = EV * EF / N + (N - 1) / N * EFV
    se_biased = biased.std(ddof=1) / np.sqrt(biased.size)
    # The bias is large enough to see ...
    assert abs(predicted - EFV) > 6 * se_biased, (predicted, EFV, se_biased)
    assert z_test(biased, EFV) < SIGNIFICANCE
    # ... and the derivation explains it (E[V]'s own sampling error folded into the z-test).
    se = np.hypot(se_biased, EF / N * np.sqrt(EV * (1 - EV) / s.n))
    z = (biased.mean() - predicted) / se
    assert abs(z) < 4.0, f"N={N}: mean {biased.mean():.6f}, predicted {predicted:.6f}, unbiased {EFV:.6f}"


@pytest.mark.parametrize("N", [2, 4])
def test_unbiased_rescaling_removes_that_bias(N):
    h = 0.6
    s = Setup("offset", n=40000, height=h)
    Ld = s.estimate("controlVariate", N, "averageVisibilityUnbiased", seed=200 + N)[:, 0]
    assert z_test(Ld, reference("offset", h)) > SIGNIFICANCE


@pytest.mark.parametrize("alpha", ["averageVisibility", "averageVisibilityUnbiased"])
def test_fully_lit_point_gives_exactly_F(alpha):
    s = Setup("none", n=500)
    Ld = s.estimate("controlVariate", 4, alpha, seed=5)
    np.testing.assert_allclose(Ld[:, 0], unshadowed_F(), rtol=1e-12)
    assert Ld[:, 0].std() == 0.0 or Ld[:, 0].std() < 1e-15 * unshadowed_F()


@pytest.mark.parametrize("alpha", ["averageVisibility", "averageVisibilityUnbiased"])
def test_fully_shadowed_point_gives_exactly_zero(alpha):
    s = Setup("full", n=500)
    Ld = s.estimate("controlVariate", 4, alpha, seed=6)
    assert np.all(Ld == 0.0)


def test_alpha_one_goes_negative_in_the_penumbra():
    s = Setup("half", n=5000)
    Ld = s.estimate("controlVariate", 1, "one", seed=8)[:, 0]
    assert (Ld < 0).sum() > 100, "alpha = 1 with N = 1 must produce negative samples in a penumbra"
    # ... and it stays unbiased.
    assert z_test(Ld, reference("half")) > SIGNIFICANCE


def test_ratio_estimator_is_consistent_and_exact_when_unshadowed():
    s = Setup("none", n=200)
    Ld = s.estimate("ratio", 4, seed=9)
    np.testing.assert_allclose(Ld[:, 0], unshadowed_F(), rtol=1e-12)
    # Biased at small N, but converges: at N = 64 per point the mean is within 1%.
    s = Setup("half", n=2000)
    Ld = s.estimate("ratio", 64, seed=10)[:, 0]
    assert abs(Ld.mean() / reference("half") - 1) < 0.01


def test_no_shadow_rays_when_the_light_is_below_the_horizon():
    s = Setup("none", n=1000)
    # Flip the shading points upside down: the light is entirely below their horizon, F = 0.
    from renderer.lights.base import ShadingContext
    from renderer.geometry import coordinate_frame, to_local

    down = np.tile([0.0, 0.0, -1.0], (s.n, 1))
    s.ctx = ShadingContext(s.ctx.p, down, down)
    s.s, s.t = coordinate_frame(down)
    s.wo_l = to_local(down, s.s, s.t, down)
    for token, alpha in (("controlVariate", "averageVisibilityUnbiased"), ("mis", "one"), ("lightSampling", "one")):
        s.rays = 0
        Ld = s.estimate(token, 4, alpha, seed=12)
        assert np.all(Ld == 0.0)
        assert s.rays == 0, f"{token} traced {s.rays} shadow rays toward a light below the horizon"
