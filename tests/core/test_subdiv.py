"""renderer/subdiv.py against known limits and counts.

Closed forms used (a cube of edge 2 centred on the origin, Catmull-Clark):
* level 1 by hand: a corner's vertex point is (Q + 2R + (n-3)v)/n with n = 3, Q = -1/3, R = -2/3
  per axis: -5/9; a face centre stays at -1 on its axis; an edge point is -3/4.
* the limit mask (n^2 v + 4 sum(e) + sum(f)) / (n (n + 5)) on that level-1 ring gives the corner
  limit (9 (-5/9) + 4 (-3/2) - 1) / 24 = -1/2 per axis and the face-centre limit
  (16 (-1) + 16 (-3/4) + 4 (-5/9)) / 36 = -68/81 on its axis.
"""

from __future__ import annotations

import numpy as np
import pytest

from renderer import subdiv

CUBE_P = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
CUBE_F = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])


def _grid(n, m):
    """(points, counts, indices) of an n x m vertex grid of unit quads in z = 0, CCW from +Z."""
    pts = np.array([[i, j, 0.0] for j in range(m) for i in range(n)])
    quads = [[j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i]
             for j in range(m - 1) for i in range(n - 1)]
    return pts, np.full(len(quads), 4), np.array(quads).ravel()


def _edge_count(counts, indices):
    starts = np.cumsum(counts) - counts
    face = np.repeat(np.arange(len(counts)), counts)
    nxt = starts[face] + (np.arange(len(indices)) - starts[face] + 1) % counts[face]
    a, b = indices, indices[nxt]
    return len(np.unique(np.minimum(a, b) * 10**9 + np.maximum(a, b)))


@pytest.mark.parametrize("scheme", ["catmullClark", "bilinear"])
def test_plane_stays_planar(scheme):
    pts, counts, idx = _grid(5, 4)
    for level in (1, 2, 3):
        r = subdiv.refine(pts, counts, idx, scheme, level)
        np.testing.assert_array_equal(r.points[:, 2], 0.0)
        assert r.points[:, 0].min() == 0.0 and r.points[:, 0].max() == 4.0  # the boundary stays put
        if r.normals is not None:
            np.testing.assert_allclose(r.normals, np.tile([0.0, 0.0, 1.0], (len(r.normals), 1)), atol=1e-12)


def test_plane_face_varying_st_is_linear():
    pts, counts, idx = _grid(4, 4)
    r = subdiv.refine(pts, counts, idx, "catmullClark", 2)
    st = subdiv.refine_face_varying(r, pts[idx, :2])
    # On a uniform plane the limit reproduces linear functions, so st = (x, y) at every corner.
    np.testing.assert_allclose(st, r.points[r.indices, :2], atol=1e-12)


def test_cube_corner_and_face_limits_match_the_closed_form():
    for level in range(1, 5):
        r = subdiv.refine(CUBE_P, np.full(6, 4), CUBE_F.ravel(), "catmullClark", level)
        np.testing.assert_allclose(r.points[0], [-0.5, -0.5, -0.5], atol=1e-12)
        np.testing.assert_allclose(r.normals[0], -np.ones(3) / np.sqrt(3.0), atol=1e-12)
        assert r.points[:, 0].min() == pytest.approx(-68.0 / 81.0, abs=1e-12)
        # every limit normal points out of this convex, centred shape
        assert np.all(np.einsum("ij,ij->i", r.normals, r.points) > 0.0)


def test_cube_refined_vertices_converge_to_the_limit():
    errors = []
    for level in range(1, 7):
        r = subdiv.refine(CUBE_P, np.full(6, 4), CUBE_F.ravel(), "catmullClark", level, project=False)
        errors.append(abs(r.points[0, 0] + 0.5))
    assert errors[0] == pytest.approx(abs(-5.0 / 9.0 + 0.5), abs=1e-12)  # level 1 by hand
    assert all(b < a for a, b in zip(errors, errors[1:]))
    assert errors[-1] < 1e-2 * errors[0]


@pytest.mark.parametrize("sharpness, expect", [(10.0, "straight"), (1.5, "between"), (0.0, "round")])
def test_crease_keeps_its_edge(sharpness, expect):
    # A tent: two slopes meeting at the ridge x = 2 (z = 2), creased along the ridge.
    pts, counts, idx = _grid(5, 5)
    pts[:, 2] = 2.0 - np.abs(pts[:, 0] - 2.0)
    ridge = np.array([2 + 5 * j for j in range(5)])
    creases = subdiv.Creases(np.stack([ridge[:-1], ridge[1:]], 1), np.full(4, sharpness))
    r = subdiv.refine(pts, counts, idx, "catmullClark", 4, creases)
    on_ridge = np.abs(r.points[:, 0] - 2.0) < 1e-12
    inner = on_ridge & (r.points[:, 1] > 0.0) & (r.points[:, 1] < 4.0)
    top = r.points[:, 2].max()
    if expect == "straight":
        assert inner.sum() > 10
        np.testing.assert_allclose(r.points[inner, 2], 2.0, atol=1e-12)
    elif expect == "between":
        smooth = subdiv.refine(pts, counts, idx, "catmullClark", 4).points[:, 2].max()
        assert smooth < top < 2.0 - 1e-6
    else:
        assert top < 2.0 - 0.1


def test_corner_sharpness_pins_a_vertex():
    creases = subdiv.Creases(corners=np.array([0]), corner_sharpness=np.array([10.0]))
    r = subdiv.refine(CUBE_P, np.full(6, 4), CUBE_F.ravel(), "catmullClark", 3, creases)
    np.testing.assert_array_equal(r.points[0], CUBE_P[0])
    np.testing.assert_allclose(r.points[7], [0.5, 0.5, 0.5], atol=1e-12)  # the far corner is smooth


def test_catmull_clark_counts_per_level():
    # a pentagon, a quad and a triangle sharing edges: F quads become 4F after the first level
    pts = np.array([[0, 0, 0], [2, 0, 0], [3, 1, 0], [1, 2, 0], [-1, 1, 0], [3, -1, 0], [1, -1, 0]], float)
    counts = np.array([5, 4, 3])
    idx = np.array([0, 1, 2, 3, 4, 0, 6, 5, 1, 1, 5, 2])
    n_v, n_e, n_f = len(pts), _edge_count(counts, idx), len(counts)
    for level in (1, 2, 3):
        r = subdiv.refine(pts, counts, idx, "catmullClark", level)
        assert len(r.counts) == 12 * 4 ** (level - 1) and np.all(r.counts == 4)
        assert len(r.points) == n_v + n_e + n_f
        n_v, n_e, n_f = len(r.points), _edge_count(r.counts, r.indices), len(r.counts)
        np.testing.assert_array_equal(np.bincount(r.face_parent), [5, 4, 3] * np.array(4 ** (level - 1)))


def test_loop_counts_and_symmetric_limit():
    # the octahedron: every vertex has valence 4, so its limit is a symmetric shape
    pts = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    tris = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    n_v, n_e = 6, 12
    for level in (1, 2, 3):
        r = subdiv.refine(pts, np.full(8, 3), tris.ravel(), "loop", level)
        assert len(r.counts) == 8 * 4 ** level and np.all(r.counts == 3)
        assert len(r.points) == n_v + n_e
        n_v, n_e = len(r.points), _edge_count(r.counts, r.indices)
        radii = np.linalg.norm(r.points[:6], axis=1)
        np.testing.assert_allclose(radii, radii[0], atol=1e-12)
        assert 0.4 < radii[0] < 1.0  # pulled in from the cage's corners
        np.testing.assert_allclose(r.normals[:6], r.points[:6] / radii[:, None], atol=1e-12)


def test_boundary_none_drops_faces_touching_the_boundary():
    pts, counts, idx = _grid(4, 4)  # 3 x 3 faces: only the middle one has no boundary vertex
    r = subdiv.refine(pts, counts, idx, "catmullClark", 2, interpolate_boundary="none")
    assert set(r.face_parent[~r.drop].tolist()) == {4}
    kept = subdiv.refine(pts, counts, idx, "catmullClark", 2, interpolate_boundary="edgeOnly")
    assert not kept.drop.any()


def test_edge_and_corner_pins_boundary_corners_and_edge_only_rounds_them():
    pts, counts, idx = _grid(3, 3)
    pinned = subdiv.refine(pts, counts, idx, "catmullClark", 2, interpolate_boundary="edgeAndCorner")
    rounded = subdiv.refine(pts, counts, idx, "catmullClark", 2, interpolate_boundary="edgeOnly")
    np.testing.assert_array_equal(pinned.points[0], [0.0, 0.0, 0.0])
    assert np.linalg.norm(rounded.points[0]) > 0.1


def test_loop_crease_keeps_its_edge():
    # the tent as triangles: each quad split along its diagonal, the ridge x = 2 creased
    pts, counts, idx = _grid(5, 5)
    pts[:, 2] = 2.0 - np.abs(pts[:, 0] - 2.0)
    q = idx.reshape(-1, 4)
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    ridge = np.array([2 + 5 * j for j in range(5)])
    creases = subdiv.Creases(np.stack([ridge[:-1], ridge[1:]], 1), np.full(4, 10.0))
    r = subdiv.refine(pts, np.full(len(tris), 3), tris.ravel(), "loop", 3, creases)
    on_ridge = np.abs(r.points[:, 0] - 2.0) < 1e-12
    assert on_ridge.sum() > 10
    np.testing.assert_allclose(r.points[on_ridge, 2], 2.0, atol=1e-12)
    smooth = subdiv.refine(pts, np.full(len(tris), 3), tris.ravel(), "loop", 3)
    assert smooth.points[:, 2].max() < 2.0 - 0.1
