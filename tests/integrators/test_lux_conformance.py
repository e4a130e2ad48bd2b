"""UsdLux radiometry end to end (stage -> render -> film) against analytic answers.

Each test authors a tiny stage with pxr, renders it through ``renderer.render`` and checks pixels
against the clarified UsdLux formulas (USD-NOTES section 1), not against illum's own code:

* a directly visible light (max depth 0) shows exactly L = intensity 2^exposure color
  [/ world-space area incl. xform scale when normalize] ("a directly visible light with
  intensity 1 and exposure 0 ... will generate a pixel value of [1, 1, 1]");
* a distant light seen along its axis shows L = intensity / sizeFactor(angle) with the doc's
  three-case sizeFactor, and lights a floor with that radiance over its cone;
* camera exposure (2^exposure time iso/100 / fStop^2), metersPerUnit and 6500 K do what the
  docs say (and metersPerUnit does nothing).

Depth-0 pixels are deterministic (every filter sample of a central pixel lands on the light), so
they are compared to 1e-6; the lit-floor test is a z-test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_floor, add_settings, new_stage

COLOR = (1.0, 0.5, 0.25)
_SCHEMAS = {"rect": UsdLux.RectLight, "disk": UsdLux.DiskLight, "sphere": UsdLux.SphereLight,
            "cylinder": UsdLux.CylinderLight}


def _centre(img: np.ndarray) -> np.ndarray:
    """(n, 3) the central 4x4 pixels of an 8x8 image."""
    return img[2:6, 2:6].reshape(-1, 3)


def _render(path, spp=2, depth=0, seed=1):
    return render(str(path), RenderOptions(spp=spp, max_depth=depth, seed=seed, threads=1))


def _narrow_camera(stage, pos=(0, 0, 0), **kw):
    """8x8 pixels over a ~2.3 degree field of view looking down -Z (then rotated by kw ops)."""
    cam = add_camera(stage, pos=pos, focal=50.0, aperture=2.0, **kw)
    add_settings(stage, (8, 8))
    return cam


# ----------------------------------------------------------------------------------------
# Directly visible area lights
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind,attrs,scale,normalize,area", [
    ("rect", {"width": 1.0, "height": 1.0}, (2.0, 3.0, 1.0), False, 6.0),
    ("rect", {"width": 1.0, "height": 1.0}, (2.0, 3.0, 1.0), True, 6.0),
    ("rect", {"width": 2.0, "height": 0.5}, (1.0, 1.0, 7.0), True, 1.0),       # Z scale: no area
    ("disk", {"radius": 0.5}, (2.0, 1.0, 1.0), True, math.pi * 0.25 * 2.0),  # an ellipse
    ("sphere", {"radius": 0.5}, (2.0, 2.0, 2.0), True, 4.0 * math.pi),
    ("sphere", {"radius": 0.5}, (1.0, 1.0, 1.0), False, math.pi),
    ("cylinder", {"radius": 0.5, "length": 1.0}, (1.0, 1.0, 1.0), True, math.pi),  # no end caps
])
def test_visible_light_radiance(tmp_path, kind, attrs, scale, normalize, area):
    """Camera at the origin looking down -Z at a light 10 units away whose emitting side faces
    it (rotateY 180: the light's -Z points to +Z): pixels = 3 * 2^1 * color [/ world area]."""
    path = tmp_path / f"{kind}.usda"
    stage = new_stage(path)
    _narrow_camera(stage)
    light = _SCHEMAS[kind].Define(stage, "/World/L")
    for name, value in attrs.items():
        light.GetPrim().CreateAttribute(f"inputs:{name}", Sdf.ValueTypeNames.Float).Set(value)
    light.CreateIntensityAttr(3.0)
    light.CreateExposureAttr(1.0)
    light.CreateColorAttr(Gf.Vec3f(*COLOR))
    light.CreateNormalizeAttr(normalize)
    xf = UsdGeom.Xformable(light)
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 0, -10))
    xf.AddRotateYOp().Set(180.0)
    xf.AddScaleOp().Set(Gf.Vec3f(*scale))
    stage.GetRootLayer().Save()
    expected = 6.0 / (area if normalize else 1.0) * np.array(COLOR)
    np.testing.assert_allclose(_centre(_render(path).film.mean()), np.tile(expected, (16, 1)), rtol=1e-6)


@pytest.mark.parametrize("kind", ["rect", "disk"])
def test_planar_lights_emit_along_minus_z_only(tmp_path, kind):
    """Unrotated, the light's -Z points away from the camera: its back is black."""
    path = tmp_path / f"{kind}_back.usda"
    stage = new_stage(path)
    _narrow_camera(stage)
    light = _SCHEMAS[kind].Define(stage, "/World/L")
    light.CreateIntensityAttr(5.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 0, -10))
    stage.GetRootLayer().Save()
    assert np.all(_render(path).film.mean() == 0.0)


# ----------------------------------------------------------------------------------------
# Camera exposure, metersPerUnit, colour temperature
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("camera_attrs,mpu,temperature,factor", [
    ({"exposure": 1.0}, 1.0, None, 2.0),
    ({"exposure:iso": 200.0, "exposure:fStop": 2.0, "exposure:time": 0.5}, 1.0, None, 0.25),
    ({}, 0.01, None, 1.0),        # centimetre stage: radiometry is unit-free
    ({}, 1.0, 6500.0, 1.0),       # "the fallback value of 6500 will always result in white"
])
def test_camera_exposure_units_and_white_point(tmp_path, camera_attrs, mpu, temperature, factor):
    path = tmp_path / "cam.usda"
    stage = new_stage(path)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    cam = _narrow_camera(stage)
    for name, value in camera_attrs.items():
        cam.GetPrim().GetAttribute(name).Set(value)
    light = UsdLux.RectLight.Define(stage, "/World/L")
    light.CreateIntensityAttr(3.0)
    if temperature is not None:
        light.CreateEnableColorTemperatureAttr(True)
        light.CreateColorTemperatureAttr(temperature)
    xf = UsdGeom.Xformable(light)
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 0, -10))
    xf.AddRotateYOp().Set(180.0)
    stage.GetRootLayer().Save()
    np.testing.assert_allclose(_centre(_render(path).film.mean()), 3.0 * factor, rtol=1e-6)


# ----------------------------------------------------------------------------------------
# Distant lights
# ----------------------------------------------------------------------------------------
def _size_factor(angle_deg: float) -> float:
    """The UsdLux doc's sizeFactor, written out independently of renderer/lights/radiometry.py."""
    t = min(max(math.radians(angle_deg) / 2.0, 0.0), math.pi)
    if t == 0.0:
        return 1.0
    return math.pi * math.sin(t) ** 2 if t <= math.pi / 2 else math.pi * (2.0 - math.sin(t) ** 2)


@pytest.mark.parametrize("angle,normalize", [(10.0, False), (10.0, True), (120.0, True), (200.0, True)])
def test_distant_light_seen_along_its_axis(tmp_path, angle, normalize):
    """Looking into the light (the camera's -Z against the light's -Z): L = intensity /
    sizeFactor when normalize is on, intensity otherwise."""
    path = tmp_path / "sun.usda"
    stage = new_stage(path)
    _narrow_camera(stage)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(4.0)
    sun.CreateAngleAttr(angle)
    sun.CreateNormalizeAttr(normalize)
    UsdGeom.Xformable(sun).AddRotateYOp().Set(180.0)  # shines along +Z, toward the camera
    stage.GetRootLayer().Save()
    expected = 4.0 / (_size_factor(angle) if normalize else 1.0)
    np.testing.assert_allclose(_centre(_render(path).film.mean()), expected, rtol=1e-6)


def _cone_integral(bsdf: PreviewSurfaceBSDF, theta_max: float, n: int = 4000) -> float:
    """int over the cone theta <= theta_max about the normal of f(n, wi) cos(theta) d omega (green),
    by the midpoint rule in theta (f is isotropic for wo = n, so phi integrates to 2 pi)."""
    theta = (np.arange(n) + 0.5) * (theta_max / n)
    wi = np.stack([np.sin(theta), np.zeros(n), np.cos(theta)], axis=1)
    wo = np.tile([0.0, 0.0, 1.0], (n, 1))
    f = bsdf.take(np.zeros(n, dtype=np.int64)).f(wo, wi)[:, 1]
    return float(np.sum(f * np.cos(theta) * np.sin(theta)) * 2.0 * np.pi * theta_max / n)


@pytest.mark.parametrize("angle,normalize", [(0.0, False), (120.0, True), (120.0, False)])
def test_distant_light_lights_a_floor_with_its_cone(tmp_path, angle, normalize):
    """A floor straight below the light, seen from straight above: the pixel is
    (intensity / sizeFactor) * integral over the cone of f cos, the BSDF integrated by
    quadrature (a delta light: intensity * f(n, n), intensity being the illuminance)."""
    path = tmp_path / "floor.usda"
    stage = new_stage(path)
    _narrow_camera(stage, pos=(0, 5, 0), tilt_x=-90.0)
    add_floor(stage, half=50.0, diffuse=(0.6, 0.6, 0.6), roughness=0.7)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateAngleAttr(angle)
    sun.CreateNormalizeAttr(normalize)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-90.0)  # -Z -> -Y: shines straight down
    stage.GetRootLayer().Save()

    bsdf = PreviewSurfaceBSDF.from_inputs(np.full((1, 3), 0.6), np.zeros((1, 3)), np.zeros(1, bool),
                                          np.zeros(1), np.full(1, 0.7), np.full(1, 1.5))
    L = 2.0 / (_size_factor(angle) if normalize else 1.0)
    if angle == 0.0:
        up = np.array([[0.0, 0.0, 1.0]])
        expected = 2.0 * float(bsdf.f(up, up)[0, 1])
    else:
        expected = L * _cone_integral(bsdf, math.radians(angle) / 2.0)
    film = _render(path, spp=64, depth=1, seed=7).film
    mean = film.mean()[2:6, 2:6, 1].astype(np.float64)
    var = film.variance_of_mean()[2:6, 2:6, 1]
    if angle == 0.0:  # no sampling noise: only wo's ~1 degree spread across the pixels
        np.testing.assert_allclose(mean, expected, rtol=1e-3)
        return
    z = (mean.mean() - expected) / math.sqrt(var.sum() / var.size**2)
    assert abs(z) < 4.0, (mean.mean(), expected, z)
