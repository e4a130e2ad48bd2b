"""Blackbody colour and luminance."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from renderer import color


def test_6500_is_exactly_white():
    np.testing.assert_array_equal(color.blackbody_rgb(6500.0), [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(color.blackbody_rgb(6500), [1.0, 1.0, 1.0])


def test_known_values_and_clamping():
    np.testing.assert_allclose(color.blackbody_rgb(3000.0), [1.6974, 0.8585, 0.2629], atol=2e-4)
    low = color.blackbody_rgb(1000.0)
    assert low[2] == 0.0 and np.all(low >= 0.0)  # the spectral blue is negative at 1000 K: clamped
    np.testing.assert_array_equal(color.blackbody_rgb(500.0), low)
    np.testing.assert_array_equal(color.blackbody_rgb(25000.0), color.blackbody_rgb(10000.0))
    assert color.blackbody_rgb(2000.0)[0] > color.blackbody_rgb(4000.0)[0] > 1.0  # warmer = redder
    assert color.blackbody_rgb(9000.0)[2] > 1.0


def test_close_to_openusd():
    UsdLux = pytest.importorskip("pxr.UsdLux")
    for T in (2000.0, 2700.0, 3200.0, 4000.0, 5600.0, 6500.0, 8000.0, 10000.0):
        ours = color.blackbody_rgb(T)
        usd = np.array(UsdLux.BlackbodyTemperatureAsRgb(T))
        assert np.all(np.abs(ours / usd - 1.0) <= 0.044), (T, ours, usd)


def test_no_warnings_escape():
    color._spectral_rgb.cache_clear()
    color._blackbody_cached.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        color.blackbody_rgb(4321.0)
    assert caught == []


def test_luminance():
    assert color.luminance(np.ones(3)) == pytest.approx(1.0)
    x = np.random.default_rng(0).random((4, 5, 3))
    lum = color.luminance(x)
    assert lum.shape == (4, 5)
    np.testing.assert_allclose(lum, 0.2126 * x[..., 0] + 0.7152 * x[..., 1] + 0.0722 * x[..., 2])
