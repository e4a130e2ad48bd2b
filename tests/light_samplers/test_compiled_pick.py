"""The lighting services per row (renderer/kernels/light_pick.py), as the fast path's vertex
kernel runs them: the compiled pick has the numpy sampler's pmf (chi-square of its picks at
fixed points), reports the pmf the sampler's own pmf() gives (bit for bit), replays it in
pick_pmf_row, and the light BVH walk finds every light a ray crosses while visiting few."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from renderer.kernels.light_pick import EXHAUSTIVE, crossed_row, pick_pmf_row, pick_row
from renderer.light_samplers import make_light_sampler, pick_tables
from renderer.light_samplers.bvh import light_bounds
from tests.light_samplers.conftest import random_context, repeat_context
from tests.stats import chi2_sf

PICKING = ["uniform", "power", "bvh"]


@njit(cache=False)
def _picks(sp, u, p, nrm, out_light, out_pmf, out_replay):
    """pick_row for each u at the point p with normal nrm (3,), and pick_pmf_row of each pick."""
    for i in range(u.shape[0]):
        li, pmf = pick_row(sp, u[i], p[0], p[1], p[2], nrm[0], nrm[1], nrm[2])
        out_light[i] = li
        out_pmf[i] = pmf
        out_replay[i] = pick_pmf_row(sp, li, p[0], p[1], p[2], nrm[0], nrm[1], nrm[2]) if pmf > 0.0 else 0.0


@njit(cache=False)
def _pmfs(sp, count, p, nrm, out):
    for li in range(count):
        out[li] = pick_pmf_row(sp, li, p[0], p[1], p[2], nrm[0], nrm[1], nrm[2])


def _chi2_p(observed: np.ndarray, expected_p: np.ndarray, n: int) -> float:
    """Chi-square p-value of pick counts against a pmf (cells expecting < 5 pooled with 'no
    light'); 0 when a light of pmf 0 was picked."""
    if np.any(observed[expected_p == 0] > 0):
        return 0.0
    expected = expected_p * n
    big = expected >= 5
    obs = np.append(observed[big], observed[~big].sum() + (n - observed.sum()))
    exp = np.append(expected[big], expected[~big].sum() + (n - expected.sum()))
    keep = exp > 0
    chi2 = float((((obs - exp) ** 2)[keep] / exp[keep]).sum())
    return chi2_sf(chi2, int(keep.sum()) - 1)


@pytest.mark.parametrize("name", PICKING)
def test_compiled_pick_has_the_samplers_pmf(name, mixed):
    sampler = make_light_sampler(name, mixed)
    sp = pick_tables(sampler, mixed)
    assert sp[0] != EXHAUSTIVE
    ctx = random_context(4, seed=57)
    n = 100_000
    for i in range(4):
        p, nrm = ctx.p[i].copy(), ctx.ns[i].copy()
        expected_p = sampler.pmf(repeat_context(ctx, i, mixed.count), np.arange(mixed.count))
        # The per-row pmf is the sampler's, bit for bit (MIS weights combine both numbers).
        replayed = np.empty(mixed.count)
        _pmfs(sp, mixed.count, p, nrm, replayed)
        np.testing.assert_array_equal(replayed, expected_p)
        light, pmf, again = np.empty(n, np.int64), np.empty(n), np.empty(n)
        _picks(sp, np.random.default_rng(90 + i).random(n), p, nrm, light, pmf, again)
        picked = pmf > 0.0
        # Each pick reports its light's pmf, and pick_pmf_row replays it.
        np.testing.assert_array_equal(pmf[picked], expected_p[light[picked]])
        np.testing.assert_array_equal(again, pmf)
        observed = np.bincount(light[picked], minlength=mixed.count).astype(float)
        assert _chi2_p(observed, expected_p, n) > 1e-4, (name, i)
        # The same test sees a pick that favours half the lights by 10 %.
        if name != "uniform":
            continue
        biased = expected_p.copy()
        biased[: mixed.count // 2] *= 1.1
        biased *= expected_p.sum() / biased.sum()
        assert _chi2_p(observed, biased, n) < 1e-4


@pytest.mark.parametrize("name", PICKING)
def test_compiled_pick_matches_the_batch_pick(name, mixed):
    """The same u at the same point picks the same light in both forms (the numpy samplers'
    batch formulas and the per-row ones)."""
    sampler = make_light_sampler(name, mixed)
    sp = pick_tables(sampler, mixed)
    ctx = random_context(1, seed=8)
    u = np.random.default_rng(9).random(5_000)
    index, pmf = sampler.sample(repeat_context(ctx, 0, u.size), u)
    light, pmf_c, _ = np.empty(u.size, np.int64), np.empty(u.size), np.empty(u.size)
    _picks(sp, u, ctx.p[0].copy(), ctx.ns[0].copy(), light, pmf_c, np.empty(u.size))
    np.testing.assert_array_equal(pmf_c, pmf)
    np.testing.assert_array_equal(light[pmf > 0], index[pmf > 0])


@njit(cache=False)
def _crossings(sp, o, d, t_max, out_count, out_first):
    stack = np.empty(64, np.int64)
    found = np.empty(out_first.shape[1], np.int64)
    for r in range(o.shape[0]):
        k = crossed_row(sp, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2], t_max[r], stack, found)
        out_count[r] = k
        for c in range(k):
            out_first[r, found[c]] = True


@pytest.mark.parametrize("name", PICKING)
def test_the_light_bvh_walk_finds_every_light_a_ray_crosses(name, mixed):
    sampler = make_light_sampler(name, mixed)
    sp = pick_tables(sampler, mixed)
    rng = np.random.default_rng(12)
    m = 4_000
    o = rng.uniform(-7.0, 7.0, (m, 3))
    finite = np.nonzero(~mixed.is_infinite)[0]
    # Half the rays aimed near a light's centre (many crossings), half in random directions.
    d = rng.normal(size=(m, 3))
    aim = rng.random(m) < 0.5
    b = light_bounds(mixed)
    centres = 0.5 * (b.lo + b.hi)
    d[aim] = centres[rng.integers(0, b.count, int(aim.sum()))] + rng.normal(
        scale=0.05, size=(int(aim.sum()), 3)) - o[aim]
    d /= np.linalg.norm(d, axis=1)[:, None]
    t_max = np.where(rng.random(m) < 0.5, np.inf, rng.uniform(0.5, 12.0, m))
    count = np.zeros(m, np.int64)
    found = np.zeros((m, mixed.count), bool)
    _crossings(sp, o, d, t_max, count, found)
    hits = 0
    for li in finite:
        t = mixed.intersect(np.full(m, li), o, d)
        crossed = t < t_max
        hits += int(crossed.sum())
        assert np.all(found[crossed, li]), mixed.paths[li]
    assert hits > 500  # the rays do cross lights
    # Infinite lights are never candidates, and the walk prunes: far fewer candidates than lights.
    assert not found[:, mixed.infinite].any()
    assert count.mean() < 0.2 * finite.size, count.mean()
