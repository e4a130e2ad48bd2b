"""UsdGeom conformance found by the spec audit: default read time, primvar inheritance."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom

from .helpers import add_quad, mesh, read


def _quad_with_samples(stage, samples):
    q = add_quad(stage, "/Q")
    pts = q.GetPointsAttr()
    pts.Clear()
    for t, z in samples:
        pts.Set([(0, 0, z), (1, 0, z), (1, 1, z), (0, 1, z)], t)
    return q


def test_unauthored_start_time_code_reads_at_zero_like_usdrecord(stage):
    """usdrecord/usdview render at stage.GetStartTimeCode() (0.0 when unauthored), a numeric
    time: time samples win over the default value, and before the first sample it is held."""
    q = _quad_with_samples(stage, [(-1, 4.0), (1, 8.0)])
    q.GetPointsAttr().Set([(0, 0, 99), (1, 0, 99), (1, 1, 99), (0, 1, 99)])  # a default opinion too
    d = read(stage)
    assert d.time_code == 0.0
    assert np.allclose(mesh(d, "/Q").points[:, 2], 6.0)  # linear between -1 and 1, not the default 99


def test_animated_camera_without_start_time_code_is_at_time_zero(stage):
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Cam"))
    op = cam.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 2), 0.0)
    op.Set(Gf.Vec3d(0, 0, 6), 10.0)
    add_quad(stage, "/Q")
    d = read(stage)
    assert np.allclose(d.camera.camera_to_world[:3, 3], (0, 0, 2))


def _constant_color(prim, rgb, interpolation=UsdGeom.Tokens.constant):
    UsdGeom.PrimvarsAPI(prim).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                            interpolation).Set([rgb])


@pytest.mark.parametrize("depth", [1, 2])
def test_display_color_is_inherited_from_an_ancestor(stage, depth):
    """UsdGeom primvar inheritance: a constant primvar on an ancestor applies to descendants
    that do not author their own (FindPrimvarWithInheritance)."""
    parent = "/G" + "/X" * (depth - 1)
    UsdGeom.Xform.Define(stage, "/G")
    if depth > 1:
        UsdGeom.Xform.Define(stage, parent)
    _constant_color(stage.GetPrimAtPath("/G"), (1, 0, 0))
    UsdGeom.Sphere.Define(stage, parent + "/Inherits")
    own = UsdGeom.Sphere.Define(stage, parent + "/Own")
    own.CreateDisplayColorAttr([(0, 0, 1)])
    d = read(stage)
    assert d.materials[mesh(d, parent + "/Inherits").material].diffuse_color.value == pytest.approx((1, 0, 0))
    assert d.materials[mesh(d, parent + "/Own").material].diffuse_color.value == pytest.approx((0, 0, 1))


def test_only_constant_display_color_is_inherited(stage):
    UsdGeom.Xform.Define(stage, "/G")
    _constant_color(stage.GetPrimAtPath("/G"), (1, 0, 0), UsdGeom.Tokens.vertex)
    UsdGeom.Sphere.Define(stage, "/G/S")
    d = read(stage)
    assert d.materials[mesh(d, "/G/S").material].diffuse_color.value == pytest.approx((0.18, 0.18, 0.18))
