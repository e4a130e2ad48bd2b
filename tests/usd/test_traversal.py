"""Traversal: pruning (visibility, purpose, inactive, class), instancing, time, performance."""

import time

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdRender, Vt

from renderer.usd import load_stage

from .helpers import add_mesh, add_quad, grid, mesh, new_stage, read, translate


# --------------------------------------------------------------------------------------
# Pruning
# --------------------------------------------------------------------------------------
def test_invisible_million_triangle_mesh_is_never_read(stage):
    pts, counts, idx = grid(708)  # 499,849 quads = 999,698 triangles
    hidden = UsdGeom.Xform.Define(stage, "/Hidden")
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    add_mesh(stage, "/Hidden/Big", pts, counts, idx)
    add_quad(stage, "/Small")
    start = time.perf_counter()
    d = read(stage)
    assert time.perf_counter() - start < 1.0
    assert [m.path for m in d.meshes] == ["/Small"]
    assert d.stats["points_read"] == 4
    assert d.stats["prims_pruned"] >= 1
    assert d.stats["triangles"] == 2


def test_million_triangle_mesh_loads_in_seconds(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "big.usdc"))
    UsdGeom.Camera.Define(stage, "/Cam")
    pts, counts, idx = grid(708)
    m = add_mesh(stage, "/Big", pts, counts, idx)
    m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.tile(np.float32([0, 0, 1]), (len(pts), 1))))
    m.SetNormalsInterpolation("vertex")
    UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set(
        Vt.Vec2fArray.FromNumpy(pts[:, :2].copy()))
    stage.Save()
    start = time.perf_counter()
    d = load_stage(str(tmp_path / "big.usdc"))
    elapsed = time.perf_counter() - start
    assert d.stats["triangles"] == 999_698 and d.stats["points_read"] == len(pts)
    assert mesh(d, "/Big").normals.shape == (999_698, 3, 3)
    assert elapsed < 5.0, f"{elapsed:.2f} s"


def test_visibility_at_render_time_prunes_subtree(stage):
    grp = UsdGeom.Xform.Define(stage, "/G")
    vis = grp.CreateVisibilityAttr()
    vis.Set(UsdGeom.Tokens.inherited, 1)
    vis.Set(UsdGeom.Tokens.invisible, 2)
    add_quad(stage, "/G/Q")
    assert [m.path for m in read(stage, frame=1).meshes] == ["/G/Q"]
    d = read(stage, frame=2)
    assert d.meshes == [] and d.stats["points_read"] == 0


def test_guide_and_proxy_pruned_by_default(stage):
    add_quad(stage, "/Default")
    add_quad(stage, "/Render").CreatePurposeAttr(UsdGeom.Tokens.render)
    g = UsdGeom.Xform.Define(stage, "/Guide")
    g.CreatePurposeAttr(UsdGeom.Tokens.guide)
    add_quad(stage, "/Guide/Child")  # inherits guide
    add_quad(stage, "/Proxy").CreatePurposeAttr(UsdGeom.Tokens.proxy)
    d = read(stage)
    assert sorted(m.path for m in d.meshes) == ["/Default", "/Render"]
    assert d.stats["points_read"] == 8


def test_included_purposes_from_settings_and_cli_override(stage):
    add_quad(stage, "/Default")
    add_quad(stage, "/Render").CreatePurposeAttr(UsdGeom.Tokens.render)
    add_quad(stage, "/Proxy").CreatePurposeAttr(UsdGeom.Tokens.proxy)
    settings = UsdRender.Settings.Define(stage, "/Render/S")  # not imageable geometry
    settings.CreateIncludedPurposesAttr(["default", "proxy"])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/S")
    assert sorted(m.path for m in read(stage).meshes) == ["/Default", "/Proxy"]
    assert sorted(m.path for m in read(stage, purposes=("render",)).meshes) == ["/Render"]


def test_render_child_under_default_parent_when_default_excluded(stage):
    UsdGeom.Xform.Define(stage, "/Asset")
    add_quad(stage, "/Asset/Plain")
    add_quad(stage, "/Asset/Hi").CreatePurposeAttr(UsdGeom.Tokens.render)
    assert [m.path for m in read(stage, purposes=("render",)).meshes] == ["/Asset/Hi"]


def test_inactive_and_class_prims_not_rendered(stage):
    add_quad(stage, "/Off").GetPrim().SetActive(False)
    add_quad(stage, "/Abstract/Q")
    stage.GetPrimAtPath("/Abstract").SetSpecifier(Sdf.SpecifierClass)
    add_quad(stage, "/On")
    d = read(stage)
    assert [m.path for m in d.meshes] == ["/On"] and d.stats["points_read"] == 4


# --------------------------------------------------------------------------------------
# Instancing
# --------------------------------------------------------------------------------------
def test_instanceable_references_flattened_with_proxy_paths(stage):
    add_quad(stage, "/Proto/Q")
    stage.GetPrimAtPath("/Proto").SetSpecifier(Sdf.SpecifierClass)
    for name, x in (("A", 5.0), ("B", -5.0)):
        inst = UsdGeom.Xform.Define(stage, f"/W/{name}")
        translate(inst, x=x)
        inst.GetPrim().GetReferences().AddInternalReference("/Proto")
        inst.GetPrim().SetInstanceable(True)
    d = read(stage)
    assert sorted(m.path for m in d.meshes) == ["/W/A/Q", "/W/B/Q"]
    assert mesh(d, "/W/A/Q").points[:, 0].min() == pytest.approx(5.0)
    assert mesh(d, "/W/B/Q").points[:, 0].min() == pytest.approx(-5.0)


def _instancer(stage, path="/W/PI"):
    pi = UsdGeom.PointInstancer.Define(stage, path)
    UsdGeom.Sphere.Define(stage, f"{path}/Protos/Ball").CreateRadiusAttr(0.5)
    UsdGeom.Cube.Define(stage, f"{path}/Protos/Box").CreateSizeAttr(1.0)
    rel = pi.CreatePrototypesRel()
    rel.AddTarget(f"{path}/Protos/Ball")
    rel.AddTarget(f"{path}/Protos/Box")
    pi.CreateProtoIndicesAttr([0, 1, 0, 1])
    pi.CreatePositionsAttr([(10, 0, 0), (20, 0, 0), (30, 0, 0), (40, 0, 0)])
    return pi


def test_point_instancer_flattens_prototypes_and_prunes_its_children(stage):
    pi = _instancer(stage)
    pi.CreateScalesAttr([(1, 1, 1), (2, 2, 2), (1, 1, 1), (1, 1, 1)])
    pi.CreateOrientationsAttr([Gf.Quath(1, 0, 0, 0)] * 4)
    d = read(stage)
    assert sorted(m.path for m in d.meshes) == ["/W/PI/Protos/Ball", "/W/PI/Protos/Box"]
    box = mesh(d, "/W/PI/Protos/Box")
    assert len(box.triangles) == 24  # two instances merged
    centres = box.points.reshape(2, -1, 3).mean(axis=1)
    assert np.allclose(centres, [(20, 0, 0), (40, 0, 0)])
    assert np.ptp(box.points.reshape(2, -1, 3)[0][:, 0]) == pytest.approx(2.0)  # scaled instance
    ball = mesh(d, "/W/PI/Protos/Ball")
    per = ball.points.reshape(2, -1, 3)
    assert np.allclose(0.5 * (per.min(axis=1) + per.max(axis=1)), [(10, 0, 0), (30, 0, 0)], atol=1e-6)
    assert d.stats["instances"] == 4 and d.stats["instancers"] == 1
    # no stand-alone copy of a prototype at the origin
    assert all(m.points[:, 0].min() > 5 for m in d.meshes)


def test_point_instancer_invisible_ids(stage):
    pi = _instancer(stage)
    pi.CreateIdsAttr([100, 101, 102, 103])
    pi.InvisIds([101, 103], Usd.TimeCode.Default())
    d = read(stage)
    assert [m.path for m in d.meshes] == ["/W/PI/Protos/Ball"]
    assert d.stats["instances"] == 2


def test_point_instancer_transform_and_prototype_xform(stage):
    pi = _instancer(stage)
    translate(pi, y=100)
    translate(stage.GetPrimAtPath("/W/PI/Protos/Box"), z=7)  # prototype root's own xform applies
    d = read(stage)
    box = mesh(d, "/W/PI/Protos/Box")
    assert np.allclose(box.points.reshape(2, -1, 3).mean(axis=1), [(20, 100, 7), (40, 100, 7)])


def test_nested_point_instancers(stage):
    inner = UsdGeom.PointInstancer.Define(stage, "/W/Outer/Protos/Inner")
    UsdGeom.Cube.Define(stage, "/W/Outer/Protos/Inner/Protos/C").CreateSizeAttr(1.0)
    inner.CreatePrototypesRel().AddTarget("/W/Outer/Protos/Inner/Protos/C")
    inner.CreateProtoIndicesAttr([0, 0])
    inner.CreatePositionsAttr([(0, 0, 0), (0, 3, 0)])
    outer = UsdGeom.PointInstancer.Define(stage, "/W/Outer")
    outer.CreatePrototypesRel().AddTarget("/W/Outer/Protos/Inner")
    outer.CreateProtoIndicesAttr([0, 0, 0])
    outer.CreatePositionsAttr([(10, 0, 0), (20, 0, 0), (30, 0, 0)])
    d = read(stage)
    c = mesh(d, "/W/Outer/Protos/Inner/Protos/C")
    centres = c.points.reshape(6, -1, 3).mean(axis=1)
    assert sorted(map(tuple, np.round(centres, 6))) == sorted(
        (x, y, 0.0) for x in (10.0, 20.0, 30.0) for y in (0.0, 3.0))


def test_point_instancer_bad_proto_indices(stage):
    pi = _instancer(stage)
    pi.GetProtoIndicesAttr().Set([0, 1, 2, 0])
    from renderer.errors import StageError

    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.prim == "/W/PI" and err.value.attribute == "protoIndices"


# --------------------------------------------------------------------------------------
# Time
# --------------------------------------------------------------------------------------
def _animated_quad(stage):
    q = add_quad(stage, "/Q")
    pts = q.GetPointsAttr()
    pts.Clear()
    for t, z in ((1, 0.0), (2, 1.0)):
        pts.Set([(0, 0, z), (1, 0, z), (1, 1, z), (0, 1, z)], t)
    return q


def test_time_sampled_points_at_frame(stage):
    _animated_quad(stage)
    d = read(stage, frame=1.5)
    assert d.time_code == 1.5
    assert np.allclose(mesh(d, "/Q").points[:, 2], 0.5)


def test_default_time_is_start_time_code_when_authored(tmp_path):
    stage = new_stage()
    _animated_quad(stage)
    stage.SetStartTimeCode(2)
    path = tmp_path / "anim.usda"
    stage.GetRootLayer().Export(str(path))
    d = load_stage(str(path))
    assert d.time_code == 2.0 and np.allclose(mesh(d, "/Q").points[:, 2], 1.0)


def test_default_time_without_start_time_code(stage):
    add_quad(stage, "/Q", z=3.0)
    d = read(stage)
    assert d.time_code == 0.0  # stage.GetStartTimeCode()'s fallback, as usdrecord reads
    assert np.allclose(mesh(d, "/Q").points[:, 2], 3.0)


def test_stage_metrics(stage):
    stage2 = new_stage(up="Z")
    UsdGeom.SetStageMetersPerUnit(stage2, 1.0)
    d = read(stage2)
    assert d.up_axis == "Z" and d.meters_per_unit == 1.0
    d = read(stage)
    assert d.up_axis == "Y" and d.meters_per_unit == pytest.approx(0.01)


def test_default_time_with_time_samples_warns(stage):
    _animated_quad(stage)
    d = read(stage)
    assert np.allclose(mesh(d, "/Q").points[:, 2], 0.0)  # time 0 holds the first sample (t=1)
    assert any("no startTimeCode" in w for w in d.warnings)
    assert not any("no startTimeCode" in w for w in read(stage, frame=1).warnings)
