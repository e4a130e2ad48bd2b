"""UsdGeomCamera / UsdRender conformance found by the spec audit: clippingPlanes, data window
overscan, RenderSettings selection."""

from __future__ import annotations

import pytest
from pxr import Gf, UsdGeom, UsdRender, Vt

from renderer.errors import StageError

from .helpers import add_quad, read


def test_clipping_planes_are_read_in_camera_space(stage):
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Cam"))
    cam.CreateClippingPlanesAttr(Vt.Vec4fArray([Gf.Vec4f(0, 0, 1, 3), Gf.Vec4f(1, 0, 0, -0.5)]))
    add_quad(stage, "/Q")
    assert read(stage).camera.clipping_planes == ((0, 0, 1, 3), (1, 0, 0, -0.5))


def test_no_clipping_planes_by_default(stage):
    assert read(stage).camera.clipping_planes == ()


@pytest.mark.parametrize("plane", [(0, 0, 0, 1), (float("nan"), 0, 1, 0)])
def test_bad_clipping_plane_names_prim_and_attribute(stage, plane):
    UsdGeom.Camera(stage.GetPrimAtPath("/Cam")).CreateClippingPlanesAttr(Vt.Vec4fArray([Gf.Vec4f(*plane)]))
    with pytest.raises(StageError) as e:
        read(stage)
    assert "/Cam" in str(e.value) and "clippingPlanes" in str(e.value)


def _settings(stage, path="/Render/Settings", **attrs):
    s = UsdRender.Settings.Define(stage, path)
    for name, value in attrs.items():
        s.GetPrim().GetAttribute(name).Set(value)
    return s


def test_overscan_data_window_is_reported(stage):
    _settings(stage, dataWindowNDC=Gf.Vec4f(-0.1, 0, 1.1, 1))
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    d = read(stage)
    assert d.settings.data_window_ndc == pytest.approx((-0.1, 0, 1.1, 1))
    assert any("overscan" in w for w in d.warnings)
    stage.GetPrimAtPath("/Render/Settings").GetAttribute("dataWindowNDC").Set(Gf.Vec4f(0.25, 0, 1, 1))
    assert not any("overscan" in w for w in read(stage).warnings)


def test_unselected_render_settings_are_reported_and_metadata_picks_among_several(stage):
    _settings(stage, "/Render/A", resolution=Gf.Vec2i(40, 30))
    _settings(stage, "/Render/B", resolution=Gf.Vec2i(20, 10))
    d = read(stage)
    assert d.settings.path == "" and any("/Render/A" in w and "ignored" in w for w in d.warnings)
    stage.SetMetadata("renderSettingsPrimPath", "/Render/B")
    d = read(stage)
    assert d.settings.path == "/Render/B" and d.settings.resolution == (20, 10)
    assert not any("ignored" in w for w in d.warnings)


def test_orthographic_camera_may_have_zero_focal_length(stage):
    """focalLength is the *perspective* focal length: an orthographic camera ignores it."""
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Cam"))
    cam.CreateProjectionAttr("orthographic")
    cam.CreateFocalLengthAttr(0.0)
    add_quad(stage, "/Q")
    assert read(stage).camera.projection == "orthographic"
    cam.CreateProjectionAttr("perspective")
    with pytest.raises(StageError, match="focalLength"):
        read(stage)
