"""Statistical test harness shared by every test package.

* ``chi2_directions``: Mitsuba-style chi-square goodness-of-fit test of a direction sampler
  against its pdf. Directions are binned on a (cos theta, phi) grid about a chosen axis; expected
  counts come from integrating the pdf over each bin with a dense midpoint rule; bins with tiny
  expectation are pooled (the standard rule: expected >= 5) before the test.
* ``z_test``: two-sided z-test of a Monte Carlo mean against a reference value.

Both return p-values; tests assert p > a small significance level (1e-4 for chi-square, 1e-4 for
z-tests), which a correct sampler passes with overwhelming probability under a fixed seed, while
a wrong pdf (off by a constant, a cosine or a Jacobian) fails at the sample counts used.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

SIGNIFICANCE = 1e-4


def _frame(axis: np.ndarray) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, axis)
    s /= np.linalg.norm(s)
    t = np.cross(axis, s)
    return np.stack([s, t, axis])  # rows: local x, y, z


def chi2_sf(x: float, dof: int) -> float:
    """Upper tail of the chi-square distribution (Wilson-Hilferty for large dof, exact series otherwise)."""
    if dof <= 0:
        return 1.0
    if x <= 0:
        return 1.0
    # Regularised upper incomplete gamma Q(dof/2, x/2) via continued fraction / series.
    a = dof / 2.0
    xx = x / 2.0
    if xx < a + 1.0:
        term = 1.0 / a
        total = term
        n = 1
        while n < 10000:
            term *= xx / (a + n)
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
            n += 1
        p = total * math.exp(-xx + a * math.log(xx) - math.lgamma(a))
        return max(0.0, 1.0 - p)
    # Lentz continued fraction for Q.
    b = xx + 1.0 - a
    c = 1.0 / 1e-300
    d = 1.0 / b
    h = d
    for i in range(1, 10000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = 1e-300 if abs(d) < 1e-300 else d
        c = b + an / c
        c = 1e-300 if abs(c) < 1e-300 else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h * math.exp(-xx + a * math.log(xx) - math.lgamma(a))


def chi2_directions(
    sample: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    pdf: Callable[[np.ndarray], np.ndarray],
    *,
    n_samples: int = 400_000,
    axis=(0.0, 0.0, 1.0),
    res_theta: int = 20,
    res_phi: int = 40,
    cos_range: tuple[float, float] = (-1.0, 1.0),
    integration_res: int = 12,
    seed: int = 1,
) -> tuple[float, dict]:
    """Chi-square test that directions from ``sample`` follow ``pdf``.

    sample(u (n, 2)) -> (wi (n, 3) unit world directions, valid (n,) bool).
    pdf(wi (m, 3)) -> (m,) solid-angle density of the sampler (failed samples carry the
        missing probability mass; valid samples must integrate to <= 1).
    axis: bins are laid out in (cos theta, phi) about this axis; pick it to put the
        distribution's detail into many bins (e.g. toward a light).
    cos_range: restrict binning to this cos-theta band (e.g. the cone of a small light) so
        the bins resolve the distribution; samples outside count in an overflow bin whose
        expectation is the pdf mass outside the band.
    Returns (p_value, details) where details has 'observed', 'expected' and 'chi2'.
    """
    rng = np.random.default_rng(seed)
    u = rng.random((n_samples, 2))
    wi, valid = sample(u)
    frame = _frame(np.asarray(axis))
    c_lo, c_hi = cos_range
    loc = wi[valid] @ frame.T
    cos_t = np.clip(loc[:, 2], -1.0, 1.0)
    phi = np.mod(np.arctan2(loc[:, 1], loc[:, 0]), 2.0 * np.pi)
    inside = (cos_t >= c_lo) & (cos_t <= c_hi)
    it = np.clip(((cos_t[inside] - c_lo) / (c_hi - c_lo) * res_theta).astype(int), 0, res_theta - 1)
    ip = np.clip((phi[inside] / (2.0 * np.pi) * res_phi).astype(int), 0, res_phi - 1)
    observed = np.zeros((res_theta, res_phi))
    np.add.at(observed, (it, ip), 1.0)
    n_outside = float((~inside).sum())

    # Expected counts: midpoint rule on a sub-grid of every bin (area element dcos dphi).
    k = integration_res
    dc = (c_hi - c_lo) / (res_theta * k)
    dp = 2.0 * np.pi / (res_phi * k)
    cs = c_lo + (np.arange(res_theta * k) + 0.5) * dc
    ps = (np.arange(res_phi * k) + 0.5) * dp
    C, P = np.meshgrid(cs, ps, indexing="ij")
    S = np.sqrt(np.maximum(0.0, 1.0 - C * C))
    local = np.stack([S * np.cos(P), S * np.sin(P), C], axis=-1).reshape(-1, 3)
    dens = pdf(local @ frame).reshape(res_theta * k, res_phi * k)
    expected = dens.reshape(res_theta, k, res_phi, k).sum(axis=(1, 3)) * dc * dp * n_samples
    inside_mass = expected.sum() / n_samples
    valid_mass = valid.mean()
    expected_outside = max(0.0, valid_mass - inside_mass) * n_samples

    obs = np.concatenate([observed.ravel(), [n_outside]])
    exp = np.concatenate([expected.ravel(), [expected_outside]])
    # Pool bins with small expectations into one, as chi-square requires.
    order = np.argsort(exp)
    obs, exp = obs[order], exp[order]
    small = exp < 5.0
    pooled_obs = obs[~small].tolist()
    pooled_exp = exp[~small].tolist()
    if small.any():
        pooled_obs.append(obs[small].sum())
        pooled_exp.append(exp[small].sum())
    obs_a = np.array(pooled_obs)
    exp_a = np.array(pooled_exp)
    # A sample observed where the pdf claims no mass at all is a hard failure.
    if np.any((exp_a <= 0.0) & (obs_a > 0.0)):
        return 0.0, {"observed": observed, "expected": expected, "chi2": math.inf}
    keep = exp_a > 0.0
    chi2 = float((((obs_a - exp_a) ** 2)[keep] / exp_a[keep]).sum())
    dof = int(keep.sum()) - 1
    return chi2_sf(chi2, dof), {"observed": observed, "expected": expected, "chi2": chi2, "dof": dof}


def z_test(samples: np.ndarray, reference: float) -> float:
    """Two-sided p-value that the mean of iid ``samples`` equals ``reference``.

    Degenerate case: zero sample variance passes only if the mean equals the reference to
    within 1e-12 relative (so a deterministic estimator cannot fake a pass).
    """
    x = np.asarray(samples, dtype=np.float64).ravel()
    mean = x.mean()
    se = x.std(ddof=1) / math.sqrt(x.size)
    if se == 0.0:
        return 1.0 if abs(mean - reference) <= 1e-12 * max(1.0, abs(reference)) else 0.0
    z = (mean - reference) / se
    return math.erfc(abs(z) / math.sqrt(2.0))


def _signed_max(z: np.ndarray) -> float:
    """The entry of z (3,) with the largest magnitude, sign kept."""
    return float(z[np.argmax(np.abs(z))])


def film_difference_z(a, b, blocks: int = 4) -> tuple[float, list[float]]:
    """z of the difference of two films' means (renderer.film.Film a and b, independent renders
    of one expectation): over the whole image and over blocks x blocks blocks, each the channel
    with the largest |z|. Per channel, because the film's variances are: a sample's three
    channels move together, so the variance of their sum is up to three times the sum of their
    variances (summed, z came out up to 1.7x too large). Pixels' errors must be independent
    (filter importance sampling, not a splatting film)."""
    d = a.mean().astype(np.float64) - b.mean()
    var = a.variance_of_mean() + b.variance_of_mean()
    h, w = d.shape[:2]

    def z(sl) -> float:
        s = d[sl].sum(axis=(0, 1))
        v = var[sl].sum(axis=(0, 1))
        return _signed_max(np.where(v > 0.0, s / np.sqrt(np.where(v > 0.0, v, 1.0)), 0.0))

    zs = [z((slice(i * h // blocks, (i + 1) * h // blocks), slice(j * w // blocks, (j + 1) * w // blocks)))
          for i in range(blocks) for j in range(blocks)]
    return z((slice(None), slice(None))), zs
