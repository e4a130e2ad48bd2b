"""BVHLightSampler: exact replay, normalisation, conservative bounds, chi-square, the fixed
d^2 clamp and a 100k-light build."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from renderer.light_samplers.bvh import BVHLightSampler, LightBounds, importance, light_bounds
from renderer.lights.base import ShadingContext
from tests.light_samplers.conftest import light_set, mixed_descs, placed, random_context, repeat_context
from tests.stats import chi2_sf


def all_pmfs(sampler, ctx: ShadingContext, i: int, count: int) -> np.ndarray:
    """pmf of every light (count,) at row i of ctx."""
    return sampler.pmf(repeat_context(ctx, i, count), np.arange(count))


def synthetic_bounds(m: int, seed: int, extent: float = 10.0, omni_fraction: float = 0.5) -> LightBounds:
    rng = np.random.default_rng(seed)
    c = rng.uniform(-extent, extent, (m, 3))
    r = rng.uniform(0.01, 0.1, m)[:, None] * extent / 10.0
    w = rng.normal(size=(m, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    omni = rng.random(m) < omni_fraction
    return LightBounds(np.arange(m), c - r, c + r, rng.uniform(0.1, 10.0, m), w,
                       np.where(omni, np.pi, 0.0), np.full(m, np.pi / 2))


# ----------------------------------------------------------------------------------------
def test_pmfs_sum_to_one_where_every_light_counts(finite_only):
    """No normal at the point and only omni lights: no importance is 0, so nothing is lost."""
    descs = [d for d in mixed_descs(80, seed=5) if d.kind in ("sphere", "dome", "distant")]
    lights = light_set(descs)
    s = BVHLightSampler(lights)
    ctx = random_context(12, seed=9, with_normals=False)
    for i in range(12):
        total = all_pmfs(s, ctx, i, lights.count).sum()
        assert abs(total - 1.0) < 1e-12


def test_pmfs_sum_to_one_at_random_points(mixed):
    """At random points with random normals, some one-sided lights face away. pbrt's traversal
    may then reach a node whose children both have importance 0: that sample is "no light".
    The pmfs sum to the probability of not ending there, which must match the fraction of
    samples that pick a light, and never exceed 1. (Where the whole tree is dark, the infinite
    lights take all the probability, so nothing is lost there.)"""
    s = BVHLightSampler(mixed)
    ctx = random_context(10, seed=12)
    n = 40_000
    for i in range(10):
        total = all_pmfs(s, ctx, i, mixed.count).sum()
        assert total <= 1.0 + 1e-12
        _, pmf = s.sample(repeat_context(ctx, i, n), np.random.default_rng(i).random(n))
        hit = (pmf > 0).mean()
        assert abs(hit - total) < 5.0 * np.sqrt(max(total * (1 - total), 1e-4) / n) + 1e-9


def test_pmfs_sum_to_one_on_a_lit_ground():
    """Points on a ground plane facing up, every light above it (down-facing rects and disks,
    spheres, points) and a sky: no light's importance is 0, so the pmfs sum to exactly 1."""
    descs = []
    for d in mixed_descs(120, seed=13):
        if d.kind in ("rect", "disk", "sphere"):
            pos = d.light_to_world[:3, 3].copy()
            pos[1] = 1.0 + abs(pos[1])
            d = dataclasses.replace(d, light_to_world=placed(pos, (0.0, -1.0, 0.0)))
        descs.append(d)
    lights = light_set(descs)
    s = BVHLightSampler(lights)
    rng = np.random.default_rng(14)
    p = np.column_stack((rng.uniform(-8, 8, 15), np.zeros(15), rng.uniform(-8, 8, 15)))
    up = np.tile([0.0, 1.0, 0.0], (15, 1))
    ctx = ShadingContext(p, up, up.copy())
    for i in range(15):
        total = all_pmfs(s, ctx, i, lights.count).sum()
        assert abs(total - 1.0) < 1e-12


def test_every_contributing_light_has_positive_pmf(mixed):
    """The bounds are conservative: a light that sends light to the point (some sampled point
    on it is in front of its emitting side and above the shading normal's horizon) is never
    given pmf 0 -- that would be bias."""
    s = BVHLightSampler(mixed)
    ctx = random_context(300, seed=21, extent=8.0)
    rng = np.random.default_rng(22)
    finite = np.nonzero(~mixed.is_infinite)[0]
    for light in finite:
        n = 300
        li = np.full(n, light, np.int64)
        smp = mixed.sample_li(li, ctx, rng.random((n, 2)))
        contributes = (smp.pdf > 0) & np.any(smp.L > 0, axis=1) & (np.einsum("ij,ij->i", smp.wi, ctx.ns) > 0)
        if mixed.delta[light]:
            contributes = np.any(smp.L > 0, axis=1) & (np.einsum("ij,ij->i", smp.wi, ctx.ns) > 0)
        pm = s.pmf(ctx, li)
        assert np.all(pm[contributes] > 0.0), mixed.paths[light]


def test_chi_square_pick_frequencies(mixed):
    s = BVHLightSampler(mixed)
    ctx = random_context(3, seed=31)
    n = 200_000
    for i in range(3):
        c = repeat_context(ctx, i, n)
        index, pmf = s.sample(c, np.random.default_rng(40 + i).random(n))
        expected_p = all_pmfs(s, ctx, i, mixed.count)
        observed = np.bincount(index[pmf > 0], minlength=mixed.count).astype(float)
        expected = expected_p * n
        assert np.all(observed[expected_p == 0] == 0)
        # Pool cells with small expectations into one, as usual for the chi-square test.
        big = expected >= 5
        obs = np.append(observed[big], observed[~big].sum() + (n - observed.sum()))
        exp = np.append(expected[big], expected[~big].sum() + (n - expected.sum()))
        keep = exp > 0
        chi2 = float((((obs - exp) ** 2)[keep] / exp[keep]).sum())
        dof = int(keep.sum()) - 1
        assert chi2_sf(chi2, dof) > 1e-4, (i, chi2, dof)


def test_d2_clamp_is_unit_free():
    """Scaling the whole scene (by a power of two, so floats scale exactly) must not change the
    pmfs. pbrt-v4 clamps d^2 with |diagonal|/2, a length, which breaks this for points inside
    a node's bounding sphere; the clamp here is (|diagonal|/2)^2."""
    b = synthetic_bounds(500, seed=3)
    k = 1024.0
    bk = LightBounds(b.light, b.lo * k, b.hi * k, b.phi, b.w, b.theta_o, b.theta_e)
    s1 = BVHLightSampler(bounds=b, count=500)
    s2 = BVHLightSampler(bounds=bk, count=500)
    np.testing.assert_array_equal(s1.child, s2.child)
    ctx = random_context(50, seed=4, extent=10.0)
    ctx_k = ShadingContext(ctx.p * k, ctx.n, ctx.ns)
    idx = np.random.default_rng(5).integers(0, 500, 50)
    np.testing.assert_allclose(s2.pmf(ctx_k, idx), s1.pmf(ctx, idx), rtol=1e-12)
    # Inside a node's bounding sphere the clamp is what decides the importance.
    node = s1.nodes[:1]
    p = node[:, 0:3] + 0.01
    i1 = importance(p, np.zeros((1, 3)), np.zeros(1, bool), node)
    nk = node.copy()
    nk[:, 0:3] *= k
    nk[:, 3] *= k * k
    ik = importance(p * k, np.zeros((1, 3)), np.zeros(1, bool), nk)
    np.testing.assert_allclose(ik * k * k, i1, rtol=1e-12)


def test_single_light_and_infinite_only():
    one = light_set(mixed_descs(1, infinite=False))
    s = BVHLightSampler(one)
    ctx = random_context(200, seed=2)
    index, pmf = s.sample(ctx, np.random.default_rng(0).random(200))
    assert set(np.unique(pmf)) <= {0.0, 1.0}
    np.testing.assert_array_equal(s.pmf(ctx, index)[pmf > 0], 1.0)
    inf_only = light_set([d for d in mixed_descs(0)])
    s = BVHLightSampler(inf_only)
    index, pmf = s.sample(ctx, np.random.default_rng(1).random(200))
    np.testing.assert_array_equal(pmf, 0.5)
    assert set(index.tolist()) == {0, 1}


def test_light_bounds_of_each_kind(mixed):
    b = light_bounds(mixed)
    assert b.count == int((~mixed.is_infinite).sum())
    assert np.all(b.hi >= b.lo) and np.all(b.phi > 0)
    kinds = mixed.kind_of[b.light]
    from renderer.lights.light_set import KIND_NAMES

    one_sided = np.isin(kinds, [KIND_NAMES.index("rect"), KIND_NAMES.index("disk")])
    np.testing.assert_array_equal(b.theta_o[one_sided], 0.0)
    np.testing.assert_array_equal(b.theta_o[~one_sided], np.pi)
    np.testing.assert_allclose(b.theta_e, np.pi / 2)
    # Every sampled point of a light lies in its AABB.
    rng = np.random.default_rng(3)
    n = 64
    for j, light in enumerate(b.light):
        li = np.full(n, light, np.int64)
        smp = mixed.sample_li(li, random_context(n, seed=j, extent=8.0), rng.random((n, 2)))
        ok = smp.pdf > 0
        q = smp.p_light[ok]
        assert np.all(q >= b.lo[j] - 1e-9) and np.all(q <= b.hi[j] + 1e-9)


def test_build_100k_lights():
    """A 100k-light build completes and the tree is sound (timing is in the benchmark)."""
    m = 100_000
    s = BVHLightSampler(bounds=synthetic_bounds(m, seed=8), count=m)
    assert s.child.size == 2 * m - 1
    leaves = s.leaf_light[s.leaf_light >= 0]
    assert leaves.size == m and np.unique(leaves).size == m
    assert s.max_depth <= 64
    ctx = random_context(5_000, seed=9)
    index, pmf = s.sample(ctx, np.random.default_rng(10).random(5_000))
    ok = np.nonzero(pmf > 0)[0]
    np.testing.assert_array_equal(s.pmf(ctx.take(ok), index[ok]), pmf[ok])
    assert s.memory_bytes() < 400 * m


@pytest.mark.parametrize("m", [2, 3, 7, 64])
def test_small_trees_and_coincident_lights(m):
    """Coincident centroids cannot be split by cost: the build halves the range instead."""
    c = np.zeros((m, 3))
    b = LightBounds(np.arange(m), c - 0.1, c + 0.1, np.ones(m), np.tile([0.0, 0.0, 1.0], (m, 1)),
                    np.full(m, np.pi), np.full(m, np.pi / 2))
    s = BVHLightSampler(bounds=b, count=m)
    ctx = random_context(20, seed=1, with_normals=False)
    for i in range(20):
        p = all_pmfs(s, ctx, i, m)
        np.testing.assert_allclose(p, 1.0 / m, rtol=1e-6)  # float32 importances
    assert s.max_depth == int(np.ceil(np.log2(m)))


def test_sphere_leaf_importance_follows_inverse_square_down_to_its_surface():
    """The d^2 clamp is a third of the squared AABB half-diagonal, which for a sphere light's
    leaf (half-diagonal sqrt(3) rho) is rho^2: from any point outside the sphere, two sphere
    lights are then picked in exact proportion to phi / d^2, the ratio of their unoccluded
    irradiances. With the full squared half-diagonal (3 rho^2) the near light would lose up to
    a factor 3 within sqrt(3) rho of its centre."""
    rho = np.array([0.02, 0.05])
    c = np.array([[0.0, 0.0, 0.0], [0.3, 0.1, 0.0]])
    phi = np.array([2.0, 7.0])
    b = LightBounds(np.arange(2), c - rho[:, None], c + rho[:, None], phi, np.tile([0.0, 0.0, 1.0], (2, 1)),
                    np.full(2, np.pi), np.full(2, np.pi / 2))
    s = BVHLightSampler(bounds=b, count=2)
    rng = np.random.default_rng(6)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    d = rho[0] * rng.uniform(1.01, 4.0, 200)
    p = c[0] + dirs * d[:, None]
    ctx = ShadingContext(p, np.zeros_like(p), np.zeros_like(p))     # no normal: no incidence factor
    e = phi / np.sum((p[:, None, :] - c[None]) ** 2, axis=2)
    np.testing.assert_allclose(s.pmf(ctx, np.zeros(200, np.int64)), e[:, 0] / e.sum(axis=1), rtol=1e-6)


def test_importance_matches_the_angle_formula():
    """The kernel carries every cosine and sine multiplied by the distance and tests angles
    through those products; this checks it against pbrt's formula written with the angles
    themselves: phi cos(theta') / max(d^2, r^2 / 3) * cos(max(theta_i - theta_b, 0)), with
    theta' = max(theta_w - theta_o - theta_b, 0) and 0 where theta' >= theta_e. Random nodes
    (every cone from a one-sided panel to a sphere, points inside and outside the bounding
    sphere, with and without a normal); rows within rounding of a cut-off are left out."""
    rng = np.random.default_rng(17)
    k = 20_000
    f32 = np.float32
    c = rng.uniform(-2.0, 2.0, (k, 3)).astype(f32).astype(float)
    r = rng.uniform(0.01, 1.5, k).astype(f32).astype(float)
    w = rng.normal(size=(k, 3))
    w = (w / np.linalg.norm(w, axis=1)[:, None]).astype(f32).astype(float)
    theta_o = np.where(rng.random(k) < 0.3, np.pi, rng.uniform(0.0, np.pi, k))
    theta_e = np.where(rng.random(k) < 0.5, np.pi / 2, rng.uniform(0.05, np.pi / 2, k))
    cos_o, sin_o = np.cos(theta_o).astype(f32).astype(float), np.sin(theta_o).astype(f32).astype(float)
    cos_e = np.cos(theta_e).astype(f32).astype(float)
    phi = rng.uniform(0.1, 10.0, k).astype(f32).astype(float)
    node = np.column_stack((c, r * r, w, phi, cos_o, sin_o, cos_e))
    p = c + rng.normal(size=(k, 3)) * rng.uniform(0.05, 3.0, k)[:, None] * r[:, None] * 2.0
    nrm = rng.normal(size=(k, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    has_n = rng.random(k) < 0.7
    got = importance(p, nrm, has_n, node)

    v = p - c
    d2 = np.sum(v * v, axis=1)
    d = np.sqrt(d2)
    wi = v / d[:, None]
    theta_w = np.arccos(np.clip(np.sum(w * wi, axis=1), -1.0, 1.0))
    theta_b = np.where(d2 < r * r, np.pi, np.arcsin(np.minimum(r / d, 1.0)))
    to = np.arctan2(sin_o, cos_o)
    theta_p = np.maximum(theta_w - to - theta_b, 0.0)
    te = np.arccos(cos_e)
    theta_i = np.arccos(np.clip(-np.sum(nrm * wi, axis=1), -1.0, 1.0))
    cos_ib = np.cos(np.maximum(theta_i - theta_b, 0.0))
    inc = np.where(has_n, np.clip(cos_ib + 1e-6, 0.0, 1.0), 1.0)
    ref = np.where(theta_p < te, phi * np.cos(theta_p) / np.maximum(d2, r * r / 3.0) * inc, 0.0)
    # Away from the cut-offs (theta' = theta_e, a grazing incidence bound) by more than rounding
    # of the float32 bounds and of arccos near 0 and pi.
    clear = (np.abs(theta_p - te) > 1e-3) & (~has_n | (np.abs(cos_ib) > 1e-3))
    assert clear.mean() > 0.95
    assert (ref[clear] == 0).mean() > 0.05 and (ref[clear] > 0).mean() > 0.5    # both cases occur
    np.testing.assert_allclose(got[clear], ref[clear], rtol=2e-5, atol=0.0)
