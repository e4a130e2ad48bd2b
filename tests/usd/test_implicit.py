"""Implicit prims: extents, axis, analytic unit normals facing outward, caps, Plane defaults."""

import numpy as np
import pytest
from pxr import Gf, UsdGeom

from renderer.errors import StageError

from .helpers import face_normals, mesh, read

AXES = {"X": 0, "Y": 1, "Z": 2}


def _check_surface(m, center=np.zeros(3), star_shaped=True):
    """Unit corner normals that agree with the winding; outward from center when star-shaped."""
    assert m.normals.shape == (len(m.triangles), 3, 3)
    assert np.allclose(np.linalg.norm(m.normals, axis=-1), 1.0, atol=1e-5)
    fn = face_normals(m)
    assert (np.einsum("ij,ikj->ik", fn, m.normals) > 0.9).all(), "corner normals agree with the winding"
    if star_shaped:
        c = m.points[m.triangles].mean(axis=1) - center
        assert (np.einsum("ij,ij->i", fn, c) > 0).all(), "faces point away from the centre"


def _extent(m):
    return m.points.min(axis=0), m.points.max(axis=0)


def test_sphere(stage):
    s = UsdGeom.Sphere.Define(stage, "/S")
    s.CreateRadiusAttr(2.5)
    UsdGeom.Xformable(s).AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    m = mesh(read(stage), "/S")
    lo, hi = _extent(m)
    assert np.allclose(lo, [-1.5, -0.5, 0.5], atol=1e-3) and np.allclose(hi, [3.5, 4.5, 5.5], atol=1e-3)
    assert len(m.triangles) >= 96 * 46 * 2  # fine enough for smooth shading
    _check_surface(m, center=np.array([1, 2, 3]))
    # analytic normals: exactly radial at every vertex
    radial = (m.points[m.triangles] - [1, 2, 3]) / 2.5
    assert np.allclose(m.normals, radial, atol=1e-5)


def test_cube_size_is_edge_length(stage):
    UsdGeom.Cube.Define(stage, "/C").CreateSizeAttr(3.0)
    m = mesh(read(stage), "/C")
    lo, hi = _extent(m)
    assert np.allclose(lo, -1.5) and np.allclose(hi, 1.5)
    assert len(m.triangles) == 12
    _check_surface(m)
    areas = 0.5 * np.linalg.norm(np.cross(*(m.points[m.triangles][:, k] - m.points[m.triangles][:, 0]
                                            for k in (1, 2))), axis=1)
    assert areas.sum() == pytest.approx(6 * 9.0)


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
def test_cylinder_axis_and_caps(stage, axis):
    c = UsdGeom.Cylinder.Define(stage, "/C")
    c.CreateRadiusAttr(0.5)
    c.CreateHeightAttr(4.0)
    c.CreateAxisAttr(axis)
    m = mesh(read(stage), "/C")
    lo, hi = _extent(m)
    k = AXES[axis]
    assert lo[k] == pytest.approx(-2.0) and hi[k] == pytest.approx(2.0)
    others = [i for i in range(3) if i != k]
    assert np.allclose(lo[others], -0.5, atol=1e-6) and np.allclose(hi[others], 0.5, atol=1e-6)
    _check_surface(m)
    # both end caps exist: some faces point along +axis and some along -axis
    fn = face_normals(m)
    assert (fn[:, k] > 0.999).any() and (fn[:, k] < -0.999).any()


def test_cylinder_1_radius_top_bottom(stage):
    c = UsdGeom.Cylinder_1.Define(stage, "/C")
    c.CreateRadiusTopAttr(0.25)
    c.CreateRadiusBottomAttr(1.0)
    c.CreateHeightAttr(2.0)
    m = mesh(read(stage), "/C")
    top = m.points[np.isclose(m.points[:, 2], 1.0)]
    bottom = m.points[np.isclose(m.points[:, 2], -1.0)]
    assert np.linalg.norm(top[:, :2], axis=1).max() == pytest.approx(0.25)
    assert np.linalg.norm(bottom[:, :2], axis=1).max() == pytest.approx(1.0)
    _check_surface(m)


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
def test_cone_apex_on_positive_axis(stage, axis):
    c = UsdGeom.Cone.Define(stage, "/C")
    c.CreateRadiusAttr(1.0)
    c.CreateHeightAttr(2.0)
    c.CreateAxisAttr(axis)
    m = mesh(read(stage), "/C")
    k = AXES[axis]
    apex = m.points[np.isclose(m.points[:, k], 1.0)]
    others = [i for i in range(3) if i != k]
    assert np.allclose(apex[:, others], 0.0), "the apex is a point on +axis"
    base = m.points[np.isclose(m.points[:, k], -1.0)]
    assert np.linalg.norm(base[:, others], axis=1).max() == pytest.approx(1.0)
    _check_surface(m)
    assert (face_normals(m)[:, k] < -0.999).any(), "the base is capped"


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
def test_capsule(stage, axis):
    c = UsdGeom.Capsule.Define(stage, "/C")
    c.CreateRadiusAttr(0.5)
    c.CreateHeightAttr(2.0)
    c.CreateAxisAttr(axis)
    m = mesh(read(stage), "/C")
    lo, hi = _extent(m)
    k = AXES[axis]
    assert lo[k] == pytest.approx(-1.5) and hi[k] == pytest.approx(1.5)  # spine + two half spheres
    _check_surface(m)
    # hemispherical ends: the normal at a cap point points from its sphere centre
    p = m.points[m.triangles]
    cap = p[..., k] > 1.0 + 1e-9
    centre = np.zeros(3)
    centre[k] = 1.0
    assert np.allclose(m.normals[cap], (p[cap] - centre) / 0.5, atol=1e-5)


def test_capsule_1_different_radii_is_smooth(stage):
    c = UsdGeom.Capsule_1.Define(stage, "/C")
    c.CreateRadiusBottomAttr(1.0)
    c.CreateRadiusTopAttr(0.5)
    c.CreateHeightAttr(1.5)
    m = mesh(read(stage), "/C")
    lo, hi = _extent(m)
    assert lo[2] == pytest.approx(-0.75 - 1.0) and hi[2] == pytest.approx(0.75 + 0.5)
    assert hi[0] == pytest.approx(1.0, abs=2e-3)
    _check_surface(m)


@pytest.mark.parametrize("axis,width_axis,length_axis", [("Z", 0, 1), ("Y", 0, 2), ("X", 2, 1)])
def test_plane_axis_and_double_sided_default(stage, axis, width_axis, length_axis):
    p = UsdGeom.Plane.Define(stage, "/P")
    p.CreateWidthAttr(4.0)
    p.CreateLengthAttr(6.0)
    p.CreateAxisAttr(axis)
    m = mesh(read(stage), "/P")
    assert m.double_sided is True  # Plane's schema fallback
    lo, hi = _extent(m)
    assert hi[width_axis] - lo[width_axis] == pytest.approx(4.0)
    assert hi[length_axis] - lo[length_axis] == pytest.approx(6.0)
    k = AXES[axis]
    assert np.allclose(face_normals(m)[:, k], 1.0) and np.allclose(m.normals[..., k], 1.0)


def test_other_gprims_are_single_sided_by_default(stage):
    UsdGeom.Sphere.Define(stage, "/S")
    assert mesh(read(stage), "/S").double_sided is False


def test_left_handed_implicit_faces_inward(stage):
    s = UsdGeom.Sphere.Define(stage, "/S")
    s.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    m = mesh(read(stage), "/S")
    c = m.points[m.triangles].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normals(m), c) < 0).all()
    assert (np.einsum("ikj,ij->ik", m.normals, c) < 0).all()


@pytest.mark.parametrize("value", [-1.0, float("nan")])
def test_invalid_implicit_size(stage, value):
    UsdGeom.Sphere.Define(stage, "/S").CreateRadiusAttr(value)
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.prim == "/S" and err.value.attribute == "radius"


def test_zero_size_implicit_has_no_mesh(stage):
    UsdGeom.Sphere.Define(stage, "/S").CreateRadiusAttr(0.0)
    UsdGeom.Cube.Define(stage, "/C").CreateSizeAttr(0.0)
    assert read(stage).meshes == []
