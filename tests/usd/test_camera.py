"""UsdGeom.Camera -> CameraDesc, checked against Gf.Camera; camera selection and errors."""

import math

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdRender

from renderer.errors import StageError

from .helpers import new_stage, read


def _camera(stage, path="/Shot/Cam"):
    cam = UsdGeom.Camera.Define(stage, path)
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    cam.CreateHorizontalApertureOffsetAttr(2.0)
    cam.CreateVerticalApertureOffsetAttr(-1.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.1, 500.0))
    cam.CreateFStopAttr(2.8)
    cam.CreateFocusDistanceAttr(12.0)
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(1, 2, 30))
    xf.AddRotateYOp().Set(20.0)
    return cam


def test_camera_matches_gf_camera_frustum():
    stage = new_stage(camera=False)
    cam = _camera(stage)
    d = read(stage).camera
    gf = cam.GetCamera(Usd.TimeCode.Default())
    window = gf.frustum.GetWindow()
    # Gf's frustum window (at unit distance) = (+-aperture/2 + offset) / focal length
    assert (d.horizontal_aperture / 2 + d.horizontal_aperture_offset) / d.focal_length == pytest.approx(
        window.GetMax()[0])
    assert (-d.horizontal_aperture / 2 + d.horizontal_aperture_offset) / d.focal_length == pytest.approx(
        window.GetMin()[0])
    assert (d.vertical_aperture / 2 + d.vertical_aperture_offset) / d.focal_length == pytest.approx(
        window.GetMax()[1])
    fov = 2 * math.degrees(math.atan(d.horizontal_aperture / 2 / d.focal_length))
    assert fov == pytest.approx(gf.GetFieldOfView(Gf.Camera.FOVHorizontal), rel=1e-6)
    # tenths of a scene unit -> scene units
    assert d.focal_length == pytest.approx(3.5) and d.horizontal_aperture == pytest.approx(3.6)
    assert d.horizontal_aperture_offset == pytest.approx(0.2) and d.vertical_aperture_offset == pytest.approx(-0.1)
    # column-vector transform = transpose of Gf's row-vector matrix
    assert np.allclose(d.camera_to_world, np.array(gf.transform).T)
    assert np.allclose(d.camera_to_world @ [0, 0, 0, 1], [1, 2, 30, 1])
    assert d.clipping_range == pytest.approx((0.1, 500.0))
    assert (d.f_stop, d.focus_distance) == pytest.approx((gf.fStop, gf.focusDistance))
    assert d.projection == "perspective" and d.path == "/Shot/Cam"


def test_camera_exposure_scale():
    stage = new_stage(camera=False)
    cam = _camera(stage)
    cam.CreateExposureAttr(1.0)
    cam.GetPrim().GetAttribute("exposure:iso").Set(200.0)
    d = read(stage).camera
    assert d.exposure_scale == pytest.approx(cam.ComputeLinearExposureScale())
    assert d.exposure_scale == pytest.approx(4.0)  # 2^1 * 200/100
    cam.CreateExposureAttr(-2.0)  # negative exposure is fine
    cam.GetPrim().GetAttribute("exposure:iso").Set(100.0)
    assert read(stage).camera.exposure_scale == pytest.approx(0.25)


def test_orthographic(stage):
    cam = UsdGeom.Camera.Get(stage, "/Cam")
    cam.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    assert read(stage).camera.projection == "orthographic"


def test_camera_choice_order():
    stage = new_stage(camera=False)
    for name in ("A", "B", "C"):
        UsdGeom.Camera.Define(stage, f"/Cams/{name}")
    assert read(stage).camera.path == "/Cams/A"  # first in traversal
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateCameraRel().AddTarget("/Cams/B")
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    assert read(stage).camera.path == "/Cams/B"  # RenderSettings camera
    assert read(stage, camera="/Cams/C").camera.path == "/Cams/C"  # explicit argument
    assert read(stage, camera="C").camera.path == "/Cams/C"  # bare name


def test_camera_under_invisible_scope_is_still_found():
    stage = new_stage(camera=False)
    UsdGeom.Scope.Define(stage, "/Hidden").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    UsdGeom.Camera.Define(stage, "/Hidden/Cam")
    assert read(stage).camera.path == "/Hidden/Cam"


@pytest.mark.parametrize("up", ["Y", "Z"])
def test_no_camera_frames_the_bounding_box_as_usdrecord(up):
    """usdrecord's free camera: GfCamera defaults, looking along the horizontal axis that is not
    up, at the box centre; a point on the box's front face at the in-plane half-diagonal from the
    centre lies exactly on the edge of the horizontal field of view."""
    stage = new_stage(up=up, camera=False)
    cube = UsdGeom.Cube.Define(stage, "/Box")
    cube.CreateSizeAttr(2.0)
    UsdGeom.Xformable(cube).AddScaleOp().Set(Gf.Vec3f(1.0, 0.5, 1.5))
    UsdGeom.Xformable(cube).AddTranslateOp().Set(Gf.Vec3d(3.0, 1.0, -2.0))  # after scale: centre (3, .5, -3)
    d = read(stage)
    assert sum("no camera" in w and "usdrecord" in w for w in d.warnings) == 1
    cam = d.camera
    assert (cam.focal_length, cam.horizontal_aperture) == pytest.approx((5.0, 2.0955), rel=1e-6)
    m = cam.camera_to_world
    centre, half = np.array([3.0, 0.5, -3.0]), np.array([1.0, 0.5, 1.5])
    depth_axis, image_axes = (1, (0, 2)) if up == "Z" else (2, (0, 1))
    forward = -m[:3, 2]  # the camera looks down its local -Z
    expected_forward = np.zeros(3)
    expected_forward[depth_axis] = 1.0 if up == "Z" else -1.0
    np.testing.assert_allclose(forward, expected_forward, atol=1e-12)
    eye = m[:3, 3]
    np.testing.assert_allclose(eye[list(image_axes)], centre[list(image_axes)], atol=1e-9)
    front = centre[depth_axis] - expected_forward[depth_axis] * half[depth_axis]
    radius = np.hypot(*half[list(image_axes)])
    tan_half_fov = (cam.horizontal_aperture / 2.0) / cam.focal_length
    assert radius / abs(front - eye[depth_axis]) == pytest.approx(tan_half_fov, rel=1e-6)


def test_missing_or_wrong_camera_argument(stage):
    UsdGeom.Xform.Define(stage, "/NotACam")
    with pytest.raises(StageError) as err:
        read(stage, camera="/Nope")
    assert err.value.prim == "/Nope" and "mem.usda" in str(err.value)
    with pytest.raises(StageError) as err:
        read(stage, camera="/NotACam")
    assert err.value.prim == "/NotACam" and "not a Camera" in str(err.value)


def test_settings_camera_target_must_be_a_camera(stage):
    settings = UsdRender.Settings.Define(stage, "/Render/S")
    settings.CreateCameraRel().AddTarget("/Gone")
    with pytest.raises(StageError) as err:
        read(stage, settings="/Render/S")
    assert err.value.prim == "/Render/S" and err.value.attribute == "camera"


@pytest.mark.parametrize("attr,value", [
    ("focalLength", 0.0), ("focalLength", -5.0), ("focalLength", float("nan")),
    ("horizontalAperture", 0.0), ("verticalAperture", -1.0), ("fStop", -1.0),
    ("focusDistance", float("inf")),
])
def test_invalid_camera_values(stage, attr, value):
    stage.GetPrimAtPath("/Cam").GetAttribute(attr).Set(value)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Cam", attr)


def test_invalid_clipping_range(stage):
    UsdGeom.Camera.Get(stage, "/Cam").CreateClippingRangeAttr(Gf.Vec2f(10, 1))
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.attribute == "clippingRange"


def test_disable_depth_of_field_zeroes_f_stop():
    stage = new_stage(camera=False)
    _camera(stage)
    settings = UsdRender.Settings.Define(stage, "/Render/S")
    settings.CreateDisableDepthOfFieldAttr(True)
    assert read(stage).camera.f_stop == pytest.approx(2.8)
    assert read(stage, settings="/Render/S").camera.f_stop == 0.0
