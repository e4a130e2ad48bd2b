"""The lighting-service protocol, for every sampler that picks: pmf(ctx, sample(ctx, u)) equals
the pmf that sample reported, picks are never zero-power lights, and the factory's choices."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.description import LightDesc
from renderer.errors import SettingsError
from renderer.light_samplers import (
    EXHAUSTIVE_MAX_LIGHTS,
    SAMPLERS,
    BVHLightSampler,
    ExhaustiveLightSampler,
    default_sampler_name,
    make_light_sampler,
)
from tests.light_samplers.conftest import light_set, mixed_descs, placed, random_context

PICKING = ["uniform", "power", "bvh"]


@pytest.mark.parametrize("name", PICKING)
@pytest.mark.parametrize("fixture", ["mixed", "finite_only"])
def test_pmf_of_sample_matches_reported(name, fixture, request):
    lights = request.getfixturevalue(fixture)
    sampler = make_light_sampler(name, lights)
    ctx = random_context(20_000, seed=1)
    u = np.random.default_rng(2).random(20_000)
    index, pmf = sampler.sample(ctx, u)
    assert index.dtype == np.int64 and index.shape == (20_000,) and pmf.shape == (20_000,)
    picked = pmf > 0.0
    assert picked.mean() > 0.5
    assert np.all((index >= 0) & (index < lights.count))
    # Exactly equal, not approximately: MIS weights combine both numbers.
    rows = np.nonzero(picked)[0]
    np.testing.assert_array_equal(sampler.pmf(ctx.take(rows), index[rows]), pmf[rows])
    assert np.all(pmf <= 1.0)


@pytest.mark.parametrize("name", PICKING)
def test_infinite_lights_are_picked(name, mixed):
    sampler = make_light_sampler(name, mixed)
    ctx = random_context(5_000, seed=4)
    for light in mixed.infinite:
        assert np.all(sampler.pmf(ctx, np.full(5_000, light)) > 0.0)
    if name != "power":  # the sun's power is tiny next to the others'
        index, pmf = sampler.sample(ctx, np.random.default_rng(5).random(5_000))
        assert set(mixed.infinite.tolist()) <= set(index[pmf > 0].tolist())


@pytest.mark.parametrize("name", PICKING)
def test_zero_power_lights_are_never_picked(name):
    # Power vector with zeros, as a sampler would see it if LightSet kept such lights.
    phi = np.array([0.0, 2.0, 0.0, 1.0, 0.0])
    if name == "bvh":
        from renderer.light_samplers.bvh import LightBounds

        c = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0]], float)
        b = LightBounds(np.arange(5), c - 0.1, c + 0.1, phi, np.tile([0.0, 0.0, 1.0], (5, 1)),
                        np.full(5, np.pi), np.full(5, np.pi / 2))
        sampler = BVHLightSampler(bounds=b, count=5)
    else:
        sampler = SAMPLERS[name](phi)
    ctx = random_context(4_000, seed=6)
    index, pmf = sampler.sample(ctx, np.random.default_rng(7).random(4_000))
    assert np.all(phi[index[pmf > 0]] > 0)
    for zero in (0, 2, 4):
        np.testing.assert_array_equal(sampler.pmf(ctx, np.full(4_000, zero)), 0.0)


@pytest.mark.parametrize("name", PICKING)
def test_all_zero_power_gives_no_light(name):
    phi = np.zeros(3)
    if name == "bvh":
        from renderer.light_samplers.bvh import LightBounds

        c = np.zeros((3, 3))
        sampler = BVHLightSampler(bounds=LightBounds(np.arange(3), c, c + 1, phi, np.tile([0.0, 0.0, 1.0], (3, 1)),
                                                     np.full(3, np.pi), np.full(3, np.pi / 2)), count=3)
    else:
        sampler = SAMPLERS[name](phi)
    ctx = random_context(10, seed=8)
    _, pmf = sampler.sample(ctx, np.linspace(0, 0.99, 10))
    np.testing.assert_array_equal(pmf, 0.0)


def test_dark_light_dropped_before_the_sampler():
    descs = mixed_descs(12, infinite=False)
    descs.append(LightDesc("/L/Off", "sphere", placed((0, 0, 0)), intensity=0.0, radius=0.3))
    lights = light_set(descs)
    assert "/L/Off" in lights.dropped and lights.count == 12
    sampler = make_light_sampler("bvh", lights)
    assert np.all(sampler.slot >= 0)


def test_factory_registry_and_auto_rule(mixed):
    assert set(SAMPLERS) == {"exhaustive", "uniform", "power", "bvh"}
    assert default_sampler_name(0) == "exhaustive"
    assert default_sampler_name(EXHAUSTIVE_MAX_LIGHTS) == "exhaustive"
    assert default_sampler_name(EXHAUSTIVE_MAX_LIGHTS + 1) == "bvh"
    assert make_light_sampler("auto", mixed).name == "bvh"
    assert make_light_sampler("", mixed).name == "bvh"
    few = light_set(mixed_descs(4, infinite=False))
    assert isinstance(make_light_sampler("auto", few), ExhaustiveLightSampler)
    assert make_light_sampler("auto", None).name == "exhaustive"
    with pytest.raises(SettingsError):
        make_light_sampler("nearest", mixed)
    for name in ("uniform", "power", "bvh"):
        s = make_light_sampler(name, None)
        _, pmf = s.sample(random_context(3), np.array([0.1, 0.5, 0.9]))
        np.testing.assert_array_equal(pmf, 0.0)
