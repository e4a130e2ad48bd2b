"""Subdivision meshes through the reader: the limit surface, its normals, creases, holes, boundary
rules, face-varying st, GeomSubsets, the level rule and the warnings (renderer/usd/subdiv_mesh.py).
The limits themselves are checked in tests/core/test_subdiv.py."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

from renderer import subdiv
from renderer.options import BY_NAME

from .helpers import add_mesh, grid, mesh, read, translate

CUBE_P = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
CUBE_F = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]


def _cube(stage, path="/Cube", scheme="catmullClark"):
    m = add_mesh(stage, path, CUBE_P, [4] * 6, CUBE_F)
    m.CreateSubdivisionSchemeAttr(scheme)
    return m


def _others(d):
    return [w for w in d.warnings if "no lights" not in w]


def test_cube_reads_as_its_limit_surface(stage):
    _cube(stage)
    d = read(stage, subdiv_level=2)
    m = mesh(d, "/Cube")
    assert len(m.triangles) == 2 * 6 * 4 ** 2
    assert m.points[:, 0].min() == pytest.approx(-68.0 / 81.0, abs=1e-9)  # face-centre limit
    corner = np.argmin(m.points.sum(axis=1))
    np.testing.assert_allclose(m.points[corner], [-0.5, -0.5, -0.5], atol=1e-9)
    centre_of_tri = m.points[m.triangles].mean(axis=1)
    assert np.all(np.einsum("tcj,tj->tc", m.normals, centre_of_tri) > 0.0)  # outward
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=2), 1.0, atol=1e-6)
    assert _others(d) == [] and d.stats["subdivided_faces"] == 96


def test_fallback_scheme_is_catmull_clark(stage):
    _cube(stage).GetSubdivisionSchemeAttr().Clear()
    assert len(mesh(read(stage, subdiv_level=1), "/Cube").triangles) == 48


def test_none_scheme_is_untouched(stage):
    _cube(stage, scheme="none")
    m = mesh(read(stage, subdiv_level=3), "/Cube")
    assert len(m.triangles) == 12 and m.normals is None
    np.testing.assert_array_equal(np.sort(m.points, axis=0), np.sort(np.asarray(CUBE_P, float), axis=0))


def test_bilinear_keeps_the_cage_shape_and_facets(stage):
    _cube(stage, scheme="bilinear")
    m = mesh(read(stage, subdiv_level=2), "/Cube")
    assert len(m.triangles) == 192 and m.normals is None
    np.testing.assert_allclose(np.abs(m.points).max(axis=1), 1.0)  # every point on the cube's faces


def test_left_handed_limit_normals_face_the_front(stage):
    _cube(stage).CreateOrientationAttr(UsdGeom.Tokens.leftHanded)  # the outside is now the back
    m = mesh(read(stage, subdiv_level=1), "/Cube")
    centre_of_tri = m.points[m.triangles].mean(axis=1)
    assert np.all(np.einsum("tcj,tj->tc", m.normals, centre_of_tri) < 0.0)
    # ... and the winding agrees with the normals
    p = m.points[m.triangles]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(np.einsum("tj,tj->t", face_n, m.normals[:, 0]) > 0.0)


def test_creases_and_corners_are_read(stage):
    pts, counts, idx = grid(5)
    pts[:, 2] = 2.0 - np.abs(pts[:, 0] - 2.0)
    m = add_mesh(stage, "/Tent", pts, counts, idx)
    m.CreateSubdivisionSchemeAttr("catmullClark")
    ridge = [2 * 5 + j for j in range(5)]  # x = 2
    m.CreateCreaseIndicesAttr(ridge)
    m.CreateCreaseLengthsAttr([5])
    m.CreateCreaseSharpnessesAttr([10.0])
    m.CreateCornerIndicesAttr([0])
    m.CreateCornerSharpnessesAttr([10.0])
    m.CreateInterpolateBoundaryAttr("edgeOnly")
    d = read(stage, subdiv_level=3)
    p = mesh(d, "/Tent").points
    on_ridge = np.abs(p[:, 0] - 2.0) < 1e-9
    assert on_ridge.sum() >= 30
    np.testing.assert_allclose(p[on_ridge, 2], 2.0, atol=1e-6)  # the crease stays straight
    assert np.any(np.all(np.abs(p - pts[0]) < 1e-9, axis=1))  # the corner stays pinned
    assert _others(d) == []


def test_malformed_creases_warn_and_are_ignored(stage):
    m = _cube(stage)
    m.CreateCreaseIndicesAttr([0, 1, 3])
    m.CreateCreaseLengthsAttr([2])
    m.CreateCreaseSharpnessesAttr([10.0])
    d = read(stage, subdiv_level=1)
    assert [w for w in _others(d) if "crease" in w] == [
        "/Cube: creaseIndices / creaseLengths / creaseSharpnesses do not agree (or index missing points); "
        "creases ignored"]


def test_boundary_none_renders_only_interior_faces(stage):
    pts, counts, idx = grid(4)  # 3 x 3 faces; only the middle one touches no boundary vertex
    m = add_mesh(stage, "/G", pts, counts, idx)
    m.CreateSubdivisionSchemeAttr("catmullClark")
    m.CreateInterpolateBoundaryAttr("none")
    g = mesh(read(stage, subdiv_level=2), "/G")
    assert len(g.triangles) == 2 * 16
    assert g.points[np.unique(g.triangles)].min(axis=0)[:2].min() > 0.9


def test_holes_drop_the_refined_faces_of_their_control_face(stage):
    _cube(stage).CreateHoleIndicesAttr([2])
    assert len(mesh(read(stage, subdiv_level=2), "/Cube").triangles) == 2 * 5 * 16


def test_face_varying_st_and_its_warning(stage):
    pts, counts, idx = grid(3)
    m = add_mesh(stage, "/G", pts, counts, idx)
    m.CreateSubdivisionSchemeAttr("catmullClark")
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray.FromNumpy(pts[idx, :2] / 2.0))
    d = read(stage, subdiv_level=2)
    g = mesh(d, "/G")
    # a uniform plane: the limit is the parametric position, so st = xy / 2 at every corner
    np.testing.assert_allclose(g.st, g.points[g.triangles][..., :2] / 2.0, atol=1e-6)
    assert [w for w in _others(d) if "faceVarying" in w] == [
        "/G: faceVaryingLinearInterpolation 'cornersPlus1' is approximated by linear interpolation of "
        "primvars:st (as 'all')"]
    m.CreateFaceVaryingLinearInterpolationAttr("all")
    assert not [w for w in _others(read(stage, subdiv_level=2)) if "faceVarying" in w]


def test_geom_subset_materials_follow_control_faces(stage):
    _cube(stage)
    for name, colour in (("Red", (1, 0, 0)), ("Blue", (0, 0, 1))):
        mat = UsdShade.Material.Define(stage, f"/M/{name}")
        sh = UsdShade.Shader.Define(stage, f"/M/{name}/S")
        sh.CreateIdAttr("UsdPreviewSurface")
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    cube = stage.GetPrimAtPath("/Cube")
    UsdShade.MaterialBindingAPI.Apply(cube).Bind(UsdShade.Material(stage.GetPrimAtPath("/M/Red")))
    sub = UsdGeom.Subset.Define(stage, "/Cube/Top")
    sub.CreateElementTypeAttr(UsdGeom.Tokens.face)
    sub.CreateIndicesAttr([3])
    sub.CreateFamilyNameAttr("materialBind")
    UsdShade.MaterialBindingAPI.Apply(sub.GetPrim()).Bind(UsdShade.Material(stage.GetPrimAtPath("/M/Blue")))
    parts = sorted(len(m.triangles) for m in read(stage, subdiv_level=2).meshes)
    assert parts == [2 * 16, 2 * 5 * 16]


def test_authored_normals_on_subdivided_mesh_warn(stage):
    m = _cube(stage)
    m.CreateNormalsAttr([(0, 1, 0)] * 8)
    m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    d = read(stage, subdiv_level=1)
    assert any(w.startswith("/Cube: normals are authored on a subdivided mesh") for w in d.warnings)
    assert mesh(d, "/Cube").normals[..., 1].min() < -0.5  # the limit's, not the authored +Y


def test_automatic_level_follows_the_projected_size(stage):
    _cube(stage)
    translate(stage.GetPrimAtPath("/Cam"), z=20.0)
    near = len(mesh(read(stage), "/Cube").triangles)
    stage.GetPrimAtPath("/Cam").GetAttribute("xformOp:translate").Set(Gf.Vec3d(0, 0, 2000.0))
    far = len(mesh(read(stage), "/Cube").triangles)
    assert far == 48  # a cube a few pixels wide: one level
    assert near > far
    # the rule itself: the level that brings the edge to TARGET_EDGE_PX pixels, within its bounds
    assert subdiv.choose_level(None, "catmullClark", 6, 4 * subdiv.TARGET_EDGE_PX) == 2
    assert subdiv.choose_level(None, "catmullClark", 6, 1e9) == subdiv.MAX_AUTO_LEVEL
    assert subdiv.choose_level(None, "catmullClark", 10**6, 1e9) == 1
    assert subdiv.choose_level(None, "catmullClark", 6, None) == 2
    assert subdiv.choose_level(3, "catmullClark", 10**6, None) == 3


def test_subdiv_level_is_a_render_option():
    o = BY_NAME["subdiv_level"]
    assert o.flags == ("--subdiv-level",) and o.lo == 0 and o.default is None
