"""No shadow acne on large tilted triangles near the origin.

embree's float32 hit distance errs in proportion to the triangle's vertex coordinates, so shadow
rays from a point near the origin on a tilted plane whose vertices lie 50 units out must start
further off the surface than |p| alone suggests (Accel.ray_epsilon(p, prim)). The plane is
rendered once as two big triangles and once tessellated into a 40 x 40 grid (small triangles
near the origin, no such error), lit by a delta distant light: with the same seed every sample
is the same deterministic NEE evaluation (the extension rays escape to a black sky), so the two
images must agree to rounding on both integrator paths. Before the fix the big-triangle image lost 10-30 % of its
shadow rays in the centre.
"""

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material


def _plane_stage(path, cells: int):
    stage = new_stage(path)
    add_camera(stage, pos=(0, 0, 6))
    add_settings(stage, (24, 24))
    half = 50.0
    xs = np.linspace(-half, half, cells + 1)
    pts = [(float(x), float(y), 0.0) for y in xs for x in xs]
    counts, idx = [], []
    for j in range(cells):
        for i in range(cells):
            a = j * (cells + 1) + i
            counts.append(4)
            idx += [a, a + 1, a + cells + 2, a + cells + 1]
    mesh = UsdGeom.Mesh.Define(stage, "/World/Plane")
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(idx)
    mesh.CreateSubdivisionSchemeAttr("none")
    mesh.AddRotateXOp().Set(-17.0)  # tilted, through the origin
    bind(mesh.GetPrim(), preview_material(stage, "/World/Looks/Grey", diffuse=(0.6, 0.6, 0.6), roughness=1.0))
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateAngleAttr(0.0)
    sun.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-20.0)
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("fast_path", [True, False])
def test_large_tilted_triangles_do_not_shadow_themselves(tmp_path, fast_path):
    big, fine = tmp_path / "big.usda", tmp_path / "fine.usda"
    _plane_stage(big, 1)
    _plane_stage(fine, 40)
    opt = dict(spp=4, max_depth=2, threads=1, seed=3, estimator={"": "mis"}, fast_path=fast_path)
    ra = render(str(big), RenderOptions(**opt))
    assert (ra.stats["fast_path"] == "on") == fast_path
    a = ra.film.mean()
    b = render(str(fine), RenderOptions(**opt)).film.mean()
    assert b.min() > 0.0  # every pixel sees the lit plane
    np.testing.assert_allclose(a, b, rtol=1e-4)
