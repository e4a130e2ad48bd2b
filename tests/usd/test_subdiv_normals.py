"""At ``--subdiv-level 0`` subdivision meshes (catmullClark, the fallback, and loop) without
authored normals are rendered as their control cage with smooth (area-weighted vertex) normals, as
Hydra's delegates do at refine level 0: UsdGeom defines their normals by the subdivision, not by
the cage's facets. ``none`` and ``bilinear`` stay faceted; authored normals win at level 0.
(Refinement itself: tests/usd/test_subdiv_mesh.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import UsdGeom

from .helpers import add_mesh, mesh, read

# A tent: two unit-wide slopes meeting at a ridge along Y, each tilted 45 degrees.
_PTS = [(-1, 0, 0), (-1, 1, 0), (0, 0, 1), (0, 1, 1), (1, 0, 0), (1, 1, 0)]
_IDX = [0, 2, 3, 1, 2, 4, 5, 3]  # counter-clockwise seen from above (+Z front)


def _tent(stage, scheme):
    m = add_mesh(stage, "/Tent", _PTS, [4, 4], _IDX)
    if scheme is None:
        m.GetSubdivisionSchemeAttr().Clear()  # fallback: catmullClark
    else:
        m.CreateSubdivisionSchemeAttr(scheme)
    return m


@pytest.mark.parametrize("scheme", [None, "catmullClark", "loop"])
def test_subdivision_cage_gets_smooth_vertex_normals(stage, scheme):
    _tent(stage, scheme)
    m = mesh(read(stage, subdiv_level=0), "/Tent")
    assert m.normals is not None
    s = 1.0 / math.sqrt(2.0)
    for tri, nrm in zip(m.triangles, m.normals):
        for v, n in zip(tri, nrm):
            x = m.points[v][0]
            # ridge vertices (x = 0): the mean of the two slopes' normals, straight up
            expected = (0.0, 0.0, 1.0) if x == 0 else (np.sign(-x) * -s, 0.0, s)
            np.testing.assert_allclose(n, expected, atol=1e-6)


@pytest.mark.parametrize("scheme", ["none", "bilinear"])
def test_polygonal_schemes_stay_faceted(stage, scheme):
    _tent(stage, scheme)
    assert mesh(read(stage, subdiv_level=0), "/Tent").normals is None


def test_authored_normals_win_over_smoothing(stage):
    m = _tent(stage, None)
    m.CreateNormalsAttr([(0, 0, 1)] * 6)
    m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    d = mesh(read(stage, subdiv_level=0), "/Tent")
    np.testing.assert_allclose(d.normals.reshape(-1, 3), [(0, 0, 1)] * (3 * len(d.triangles)), atol=1e-6)


def test_left_handed_cage_normals_face_its_front(stage):
    m = _tent(stage, None)
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)  # front is now -Z
    d = mesh(read(stage, subdiv_level=0), "/Tent")
    assert np.all(d.normals[..., 2] < 0.0)
