"""Skip proof: invisible, guide, proxy and inactive subtrees are never loaded (issue #8 item 3).

Proof by counting: a stage holding a 1M-triangle mesh under a pruned prim reads exactly as many
points, meshes and triangles as the same stage without it (the reader's counters
``desc.stats``), and the render's stats JSON reports the same triangle count. The mesh lives in
a separate .usdc layer that the stage references, so "never loaded" means its points array is
never fetched.

Where the skip is listed: the reader counts pruned subtree roots in ``desc.stats["prims_pruned"]``
(invisible, guide, proxy; inactive prims are not even traversed, so they are not counted).
The render's stats JSON does not carry the reader's counters, only ``triangles``.

Already proven elsewhere: tests/usd/test_traversal.py::test_invisible_million_triangle_mesh_is_never_read
(invisible, absolute counts and a time bound), ::test_guide_and_proxy_pruned_by_default and
::test_inactive_and_class_prims_not_rendered (small quads).
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdLux, Vt

from renderer.render import RenderOptions, render
from renderer.usd import load_stage
from tests.stage_builders import add_camera, add_settings, new_stage

BIG_N = 708            # 708 x 708 vertex grid: 999,698 triangles


@pytest.fixture(scope="module")
def big_layer(tmp_path_factory) -> str:
    """A .usdc holding one 1M-triangle mesh at /Big."""
    path = str(tmp_path_factory.mktemp("big") / "big.usdc")
    stage = Usd.Stage.CreateNew(path)
    n = BIG_N
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    pts = np.c_[g * 0.01, np.zeros(len(g))].astype(np.float32)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij"))
    quads = np.stack([i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1], 1).astype(np.int32)
    mesh = UsdGeom.Mesh.Define(stage, "/Big")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel()))
    mesh.CreateSubdivisionSchemeAttr("none")
    stage.SetDefaultPrim(mesh.GetPrim())
    stage.Save()
    return path


def _stage(path, big_layer=None, how=None):
    """A small lit quad; with big_layer, the 1M-triangle mesh referenced under /World/Hidden/Big
    and /World/Hidden pruned by ``how``."""
    stage = new_stage(path)
    add_camera(stage, "/World/Camera", pos=(0, 0, 5))
    add_settings(stage, (8, 8), camera="/World/Camera")
    quad = UsdGeom.Mesh.Define(stage, "/World/Quad")
    quad.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr("none")
    light = UsdLux.SphereLight.Define(stage, "/World/Light")
    light.CreateRadiusAttr(0.2)
    light.CreateIntensityAttr(10.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 0, 2))
    if big_layer is not None:
        hidden = UsdGeom.Xform.Define(stage, "/World/Hidden")
        big = stage.DefinePrim("/World/Hidden/Big")
        big.GetReferences().AddReference(big_layer)
        if how == "invisible":
            hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        elif how in ("guide", "proxy"):
            hidden.CreatePurposeAttr(how)
        elif how == "inactive":
            hidden.GetPrim().SetActive(False)
        elif how == "invisible-mesh":
            UsdGeom.Imageable(big).CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        else:
            raise ValueError(how)
    stage.GetRootLayer().Save()
    return str(path)


@pytest.mark.parametrize("how", ["invisible", "guide", "proxy", "inactive", "invisible-mesh"])
def test_pruned_million_triangle_mesh_reads_nothing(tmp_path, big_layer, how):
    plain = load_stage(_stage(tmp_path / "plain.usda"))
    pruned = load_stage(_stage(tmp_path / "pruned.usda", big_layer, how))
    for key in ("points_read", "meshes", "triangles", "implicit_prims", "instances"):
        assert pruned.stats[key] == plain.stats[key], (key, pruned.stats[key], plain.stats[key])
    assert [m.path for m in pruned.meshes] == ["/World/Quad"]
    if how == "inactive":
        # not traversed at all: nothing to prune
        assert pruned.stats["prims_pruned"] == plain.stats["prims_pruned"]
        assert pruned.stats["prims_visited"] == plain.stats["prims_visited"]
    else:
        assert pruned.stats["prims_pruned"] == plain.stats["prims_pruned"] + 1
        # the walk stopped at the pruned root: its child was never visited
        assert pruned.stats["prims_visited"] == plain.stats["prims_visited"] + (1 if how != "invisible-mesh" else 2)


def test_the_same_mesh_when_visible_is_read(tmp_path, big_layer):
    """Control: the counters do see the mesh when nothing prunes it."""
    path = tmp_path / "visible.usda"
    stage = Usd.Stage.Open(_stage(tmp_path / "base.usda", big_layer, "invisible"))
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Hidden")).GetVisibilityAttr().Set(UsdGeom.Tokens.inherited)
    stage.GetRootLayer().Export(str(path))
    d = load_stage(str(path))
    assert d.stats["points_read"] == 4 + BIG_N * BIG_N
    assert d.stats["triangles"] == 2 + 2 * (BIG_N - 1) ** 2


@pytest.mark.parametrize("how", ["invisible", "guide", "inactive"])
def test_render_stats_count_only_the_visible_triangles(tmp_path, big_layer, how):
    r = render(_stage(tmp_path / "pruned.usda", big_layer, how), RenderOptions(spp=1, threads=1, max_depth=1))
    assert r.stats["triangles"] == 2
