"""UsdLux radiometry: intensity, exposure, colour, temperature, normalize and sizeFactor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.color import blackbody_rgb
from renderer.description import LightDesc
from renderer.errors import StageError
from renderer.lights.disk import DiskLight
from renderer.lights.radiometry import distant_size_factor, emitted_radiance
from renderer.lights.rect import RectLight
from renderer.lights.sphere import SphereLight
from tests.lights.helpers import rotate, scale, translate


def desc(kind, m=np.eye(4), **kw):
    return LightDesc("/L", kind, np.asarray(m, dtype=np.float64), **kw)


def test_intensity_exposure_color():
    d = desc("rect", intensity=2.0, exposure=1.5, color=(1.0, 0.5, 0.25))
    np.testing.assert_allclose(emitted_radiance(d, 1.0), 2.0 * 2**1.5 * np.array([1.0, 0.5, 0.25]))


def test_color_temperature():
    d = desc("rect", color=(0.5, 1.0, 1.0), enable_color_temperature=True, color_temperature=6500.0)
    np.testing.assert_array_equal(emitted_radiance(d, 1.0), [0.5, 1.0, 1.0])
    d = desc("rect", color=(0.5, 1.0, 1.0), enable_color_temperature=True, color_temperature=3000.0)
    np.testing.assert_allclose(emitted_radiance(d, 1.0), np.array([0.5, 1.0, 1.0]) * blackbody_rgb(3000.0))
    # Disabled: the temperature is ignored.
    d = desc("rect", enable_color_temperature=False, color_temperature=3000.0)
    np.testing.assert_array_equal(emitted_radiance(d, 1.0), [1.0, 1.0, 1.0])


def test_normalize_rect_with_scaled_xform():
    """USD-NOTES example: width 2, height 0.5, scale (2, 2, 1): world area 4; 10 * 2^1 / 4 = 5."""
    m = translate(0, 0, 5) @ scale(2, 2, 1)
    d = desc("rect", m, width=2.0, height=0.5, intensity=10.0, exposure=1.0, normalize=True)
    assert RectLight.world_area(d) == pytest.approx(4.0)
    np.testing.assert_allclose(RectLight.build([d]).L[0], 5.0)
    # A rotation does not change the area; a shear does (parallelogram).
    assert RectLight.world_area(desc("rect", rotate((1, 2, 3), 40) @ scale(3, 1, 1))) == pytest.approx(3.0)
    shear = np.eye(4)
    shear[0, 1] = 0.7
    assert RectLight.world_area(desc("rect", shear @ scale(1, 2, 1))) == pytest.approx(2.0)


def test_normalize_disk_and_sphere():
    d = desc("disk", scale(2, 3, 7), radius=0.5, intensity=6.0, normalize=True)
    assert DiskLight.world_area(d) == pytest.approx(math.pi * 0.25 * 6.0)
    np.testing.assert_allclose(DiskLight.build([d]).L[0], 6.0 / (math.pi * 1.5))
    s = desc("sphere", rotate((0, 1, 0), 30) @ scale(2, 2, 2), radius=0.5, intensity=1.0, normalize=True)
    assert SphereLight.world_area(s) == pytest.approx(4 * math.pi)
    np.testing.assert_allclose(SphereLight.build([s]).L[0], 1.0 / (4 * math.pi))
    # Not normalized: the area does not matter.
    np.testing.assert_allclose(emitted_radiance(desc("disk", scale(5, 5, 5), intensity=3.0), 99.0), 3.0)


def test_distant_size_factor():
    assert distant_size_factor(0.0) == 1.0
    assert distant_size_factor(1.0) == pytest.approx(math.pi * math.sin(math.radians(0.5)) ** 2)
    assert distant_size_factor(180.0) == pytest.approx(math.pi)
    assert distant_size_factor(270.0) == pytest.approx(math.pi * (2 - math.sin(math.radians(135)) ** 2))
    assert distant_size_factor(400.0) == pytest.approx(2 * math.pi)  # theta_max clamped to pi
    d = desc("distant", angle=10.0, intensity=3.0, normalize=True)
    np.testing.assert_allclose(emitted_radiance(d, 1.0), 3.0 / distant_size_factor(10.0))


def test_dome_ignores_normalize():
    np.testing.assert_allclose(emitted_radiance(desc("dome", intensity=2.0, normalize=True), 0.0), 2.0)


def test_non_finite_inputs_raise():
    with pytest.raises(StageError, match="not finite"):
        emitted_radiance(desc("rect", intensity=float("nan")), 1.0)
    with pytest.raises(StageError):
        emitted_radiance(desc("rect", color=(1.0, float("inf"), 0.0)), 1.0)


def test_zero_area_normalized_is_black():
    np.testing.assert_array_equal(emitted_radiance(desc("rect", width=0.0, normalize=True), 0.0), 0.0)
