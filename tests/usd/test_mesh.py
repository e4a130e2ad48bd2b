"""UsdGeom.Mesh topology: triangulation, holes, orientation, validation, subdivision warnings."""

import math

import numpy as np
import pytest
from pxr import Gf, UsdGeom, Vt

from renderer.errors import StageError
from renderer.usd.mesh import triangulate

from .helpers import add_mesh, add_quad, face_normals, mesh, read


def _shoelace(p2: np.ndarray) -> float:
    return 0.5 * float(np.sum(p2[:, 0] * np.roll(p2[:, 1], -1) - np.roll(p2[:, 0], -1) * p2[:, 1]))


def _inside(q: np.ndarray, poly: np.ndarray) -> bool:
    """Even-odd point-in-polygon test in 2D."""
    x, y = q
    inside = False
    for (x0, y0), (x1, y1) in zip(poly, np.roll(poly, -1, axis=0)):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


CONCAVE = {
    "L": [(0, 0), (3, 0), (3, 1), (1, 1), (1, 3), (0, 3)],
    "star": [((1.0 if k % 2 == 0 else 0.35) * math.cos(k * math.pi / 6),
              (1.0 if k % 2 == 0 else 0.35) * math.sin(k * math.pi / 6)) for k in range(12)],
    "comb": [(0, 0), (7, 0), (7, 3), (6, 3), (6, 1), (5, 1), (5, 3), (4, 3), (4, 1), (3, 1), (3, 3),
             (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)],
    "reflex_at_1": [(0, 0), (1, 1), (2, 0), (2, 2), (0, 2)],  # a fan from vertex 0 would fold over
}


@pytest.mark.parametrize("name", sorted(CONCAVE))
def test_concave_ngon_area_preserved_and_triangles_inside(name):
    poly = np.asarray(CONCAVE[name], dtype=float)
    # tilt the polygon out of any coordinate plane to exercise the projection
    rot = np.asarray(Gf.Matrix3d(Gf.Rotation(Gf.Vec3d(1, 2, 3).GetNormalized(), 37.0)))
    pts3 = np.c_[poly, np.zeros(len(poly))] @ rot
    tri_c, tri_f = triangulate(pts3, np.array([len(poly)]), np.arange(len(poly)))
    assert tri_c.shape == (len(poly) - 2, 3) and (tri_f == 0).all()
    t2 = poly[tri_c]
    e1, e2 = t2[:, 1] - t2[:, 0], t2[:, 2] - t2[:, 0]
    signed = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (signed > 0).all(), "every triangle keeps the polygon's (CCW) winding"
    assert signed.sum() == pytest.approx(_shoelace(poly), rel=1e-12)
    for tri in t2:
        assert _inside(tri.mean(axis=0), poly)


def test_concave_quad_uses_the_valid_diagonal():
    # reflex corner at vertex 1: the fan from 0 would create an overlapping, flipped triangle
    pts = np.array([(0, 0, 0), (1, 0.8, 0), (2, 0, 0), (1, 2, 0)], float)
    tri_c, _ = triangulate(pts, np.array([4]), np.arange(4))
    t = pts[tri_c]
    z = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, 2]
    assert (z > 0).all()
    assert 0.5 * z.sum() == pytest.approx(_shoelace(pts[:, :2]))


def test_convex_ngons_fan_vectorised_and_face_order_kept():
    hexagon = [(math.cos(a), math.sin(a), 0.0) for a in np.linspace(0, 2 * math.pi, 7)[:-1]]
    pts = np.array(hexagon + [(5, 0, 0), (6, 0, 0), (6, 1, 0)], float)
    counts = np.array([6, 3, 6])
    indices = np.r_[np.arange(6), [6, 7, 8], np.arange(6)]
    tri_c, tri_f = triangulate(pts, counts, indices)
    assert list(tri_f) == [0] * 4 + [1] + [2] * 4


def test_holes_drop_faces(stage):
    pts = [(x, y, 0) for y in (0, 1) for x in (0, 1, 2, 3)]
    add_mesh(stage, "/M", pts, [4, 4, 4], [0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6],
             holeIndices=Vt.IntArray([1]))
    m = mesh(read(stage), "/M")
    assert len(m.triangles) == 4
    centroids = m.points[m.triangles].mean(axis=1)
    assert not ((centroids[:, 0] > 1) & (centroids[:, 0] < 2)).any()


def test_left_handed_flips_winding(stage):
    add_quad(stage, "/R")
    add_quad(stage, "/L").CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    d = read(stage)
    assert np.allclose(face_normals(mesh(d, "/R")), [0, 0, 1])
    assert np.allclose(face_normals(mesh(d, "/L")), [0, 0, -1])


def test_mirroring_transform_keeps_front_facing(stage):
    q = add_quad(stage, "/M")
    UsdGeom.Xformable(q).AddScaleOp().Set(Gf.Vec3f(1, 1, -1))
    q.CreateNormalsAttr([(0, 0, 1)] * 4)
    q.SetNormalsInterpolation("vertex")
    m = mesh(read(stage), "/M")
    # mirrored in z: the front (authored +Z side) now faces -Z; winding and normals agree
    assert np.allclose(face_normals(m), [0, 0, -1])
    assert np.allclose(m.normals, [0, 0, -1])


def test_small_faces_skipped_with_warning(stage):
    add_mesh(stage, "/M", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [2, 3], [0, 1, 0, 1, 2])
    d = read(stage)
    assert len(mesh(d, "/M").triangles) == 1
    assert any("fewer than 3" in w for w in d.warnings)


@pytest.mark.parametrize("attr,counts,indices,points", [
    ("faceVertexIndices", [3], [0, 1, 5], [(0, 0, 0), (1, 0, 0), (1, 1, 0)]),
    ("faceVertexIndices", [3], [0, 1, -1], [(0, 0, 0), (1, 0, 0), (1, 1, 0)]),
    ("faceVertexCounts", [4], [0, 1, 2], [(0, 0, 0), (1, 0, 0), (1, 1, 0)]),
    ("faceVertexCounts", [-3], [], [(0, 0, 0), (1, 0, 0), (1, 1, 0)]),
    ("points", [3], [0, 1, 2], [(0, 0, 0), (1, float("nan"), 0), (1, 1, 0)]),
    ("points", [3], [0, 1, 2], [(0, 0, 0), (1, 0, float("inf")), (1, 1, 0)]),
])
def test_invalid_topology_names_prim_and_attribute(stage, attr, counts, indices, points):
    add_mesh(stage, "/World/Bad", points, counts, indices)
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.prim == "/World/Bad" and err.value.attribute == attr
    assert f"mem.usda: /World/Bad.{attr}:" in str(err.value)


def test_subdivision_meshes_are_refined_not_warned_about(stage):
    for k in range(3):
        m = add_quad(stage, f"/Sub{k}")
        m.GetSubdivisionSchemeAttr().Clear()  # fallback: catmullClark
    add_quad(stage, "/Loop").CreateSubdivisionSchemeAttr("loop")
    d = read(stage, subdiv_level=1)
    assert not [w for w in d.warnings if "control cage" in w]
    # loop on a quad: one warning naming the prim, then Catmull-Clark
    assert [w for w in d.warnings if "loop" in w] == [
        "/Loop: subdivisionScheme 'loop' needs triangles only; this mesh has other polygons and is "
        "subdivided with catmullClark instead"]
    assert len(d.meshes) == 4 and all(len(m.triangles) == 8 for m in d.meshes)
    assert d.stats["subdivided_meshes"] == 4


def test_no_subdivision_warning_for_scheme_none(stage):
    add_quad(stage, "/Q")
    assert [w for w in read(stage).warnings if "no lights" not in w] == []
