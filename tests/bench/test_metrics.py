"""The bench's error metrics and configuration parsing, against hand-computed values."""

import math

import numpy as np
import pytest

from renderer.bench import (EPS, BenchConfig, efficiency, parse_budgets, parse_configs, reference_key, relmse,
                            relmse_floor, rmse)
from renderer.errors import SettingsError


def test_rmse_by_hand():
    ref = np.zeros((1, 2, 3))
    img = np.zeros((1, 2, 3))
    img[0, 0] = [1.0, 2.0, 2.0]   # squared errors 1, 4, 4; the other pixel is exact
    # mean over 6 values = 9 / 6 = 1.5
    assert rmse(img, ref) == pytest.approx(math.sqrt(1.5))


def test_relmse_by_hand():
    ref = np.array([[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]])
    img = np.array([[[2.0, 1.0, 0.5], [0.1, 0.0, 0.0]]])
    # pixel 0: (1^2 + 0 + 0.5^2) / (1 + 0.01); pixel 1: 0.1^2 / (0 + 0.01) = 1 in one channel.
    want = ((1.0 + 0.25) / 1.01 + 0.01 / 0.01) / 6.0
    assert relmse(img, ref) == pytest.approx(want)
    assert EPS == 1e-2


def test_relmse_is_relative_and_rmse_is_absolute():
    ref = np.full((2, 2, 3), 10.0)
    assert relmse(ref * 1.1, ref) == pytest.approx(0.01 * 100 / (100 + EPS))
    assert rmse(ref * 1.1, ref) == pytest.approx(1.0)
    assert relmse(ref, ref) == 0.0 and rmse(ref, ref) == 0.0


def test_metrics_reject_mismatched_sizes():
    with pytest.raises(SettingsError):
        relmse(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(SettingsError):
        rmse(np.zeros((2, 2, 3)), np.zeros((3, 2, 3)))


def test_floor_and_efficiency():
    ref = np.full((1, 1, 3), 1.0)
    var = np.full((1, 1, 3), 0.0202)
    assert relmse_floor(ref, var) == pytest.approx(0.02)
    assert efficiency(0.01, 4.0) == pytest.approx(25.0)
    assert efficiency(0.0, 4.0) == math.inf


def test_parse_configs_tokens_alphas_and_samplers():
    cfgs = parse_configs("mis,controlVariate:averageVisibilityUnbiased,stage")
    assert [c.label for c in cfgs] == ["mis", "controlVariate:averageVisibilityUnbiased", "stage"]
    assert cfgs[1] == BenchConfig("controlVariate", "averageVisibilityUnbiased", None)
    assert cfgs[2] == BenchConfig(None, None, None)
    crossed = parse_configs("mis,ratio", "uniform,power")
    assert [c.label for c in crossed] == ["mis@uniform", "mis@power", "ratio@uniform", "ratio@power"]


@pytest.mark.parametrize("bad", ["nope", "controlVariate:half", "mis:one", "mis,mis"])
def test_parse_configs_rejects(bad):
    with pytest.raises(SettingsError):
        parse_configs(bad)


def test_parse_configs_rejects_unknown_sampler():
    with pytest.raises(SettingsError):
        parse_configs("mis", "closest")


def test_parse_budgets():
    assert parse_budgets("4, 1,16,1") == [1.0, 4.0, 16.0]
    for bad in ("", "0", "-1", "x", "inf"):
        with pytest.raises(SettingsError):
            parse_budgets(bad)


def test_reference_key_depends_on_every_input():
    base = reference_key("abc", (16, 12), 1, {"spp": 64})
    assert base == reference_key("abc", (16, 12), 1, {"spp": 64})
    assert len({base, reference_key("abd", (16, 12), 1, {"spp": 64}), reference_key("abc", (16, 13), 1, {"spp": 64}),
                reference_key("abc", (16, 12), 2, {"spp": 64}), reference_key("abc", (16, 12), 1, {"spp": 65})}) == 5


def test_split_half_floor_measures_the_reference_error():
    """Two independent halves of heavy-tailed noise: on average the floor equals the merged
    reference's actual relMSE against the truth (z-test over many synthetic references), and a
    floor 20 % off is caught."""
    import numpy as np

    from renderer.bench import split_half_floor
    from tests.stats import SIGNIFICANCE, z_test

    rng = np.random.default_rng(3)
    truth = rng.uniform(1.0, 2.0, (16, 16, 3))
    floors, actual = [], []
    for _ in range(400):
        # Student-t noise with 3 degrees of freedom: mostly small, sometimes large.
        a = truth + rng.standard_t(3, truth.shape) * 0.05
        b = truth + rng.standard_t(3, truth.shape) * 0.05
        ref = (a + b) / 2.0
        actual.append(float(np.mean((ref - truth) ** 2 / (ref * ref + 0.01))))
        floors.append(split_half_floor(a, b, ref))
    floors, actual = np.array(floors), np.array(actual)
    assert z_test(floors - actual, 0.0) > SIGNIFICANCE, (floors.mean(), actual.mean())
    assert z_test(1.2 * floors - actual, 0.0) < SIGNIFICANCE
