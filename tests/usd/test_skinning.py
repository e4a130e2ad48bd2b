"""UsdSkel skinning and animated points at the render time, against usd-core's own
UsdSkel.BakeSkinning on a rig authored here: a two-joint arm (shoulder and elbow) bending a
cylinder, with a blend shape that bulges one ring, animated over three time samples."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

from .helpers import add_mesh, mesh, new_stage, read

RINGS, SEG = 9, 8
TIMES = (1.0, 5.0, 10.0)


def _arm(stage: Usd.Stage, scheme: str = "none") -> UsdGeom.Mesh:
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(10)
    root = UsdSkel.Root.Define(stage, "/Arm")
    UsdGeom.Xformable(root).AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    skel = UsdSkel.Skeleton.Define(stage, "/Arm/Skel")
    joints = ["Shoulder", "Shoulder/Elbow"]
    skel.CreateJointsAttr(joints)
    elbow = Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 2, 0))
    skel.CreateBindTransformsAttr([Gf.Matrix4d(1), elbow])
    skel.CreateRestTransformsAttr([Gf.Matrix4d(1), elbow])
    anim = UsdSkel.Animation.Define(stage, "/Arm/Skel/Anim")
    anim.CreateJointsAttr(joints)
    anim.CreateTranslationsAttr([Gf.Vec3f(0, 0, 0), Gf.Vec3f(0, 2, 0)])
    anim.CreateScalesAttr([Gf.Vec3h(1, 1, 1)] * 2)
    anim.CreateBlendShapesAttr(["bulge"])
    rot, weights = anim.CreateRotationsAttr(), anim.CreateBlendShapeWeightsAttr()
    for t, f in zip(TIMES, (0.0, 0.4, 1.0)):
        rot.Set([Gf.Quatf(Gf.Rotation(Gf.Vec3d(1, 0, 0), 30 * f).GetQuat()),
                 Gf.Quatf(Gf.Rotation(Gf.Vec3d(0, 0, 1), 90 * f).GetQuat())], t)
        weights.Set([f], t)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    a = 2 * np.pi * np.arange(SEG) / SEG
    pts = [(0.3 * np.cos(x), 4.0 * r / (RINGS - 1), 0.3 * np.sin(x)) for r in range(RINGS) for x in a]
    quads = [[r * SEG + s, (r + 1) * SEG + s, (r + 1) * SEG + (s + 1) % SEG, r * SEG + (s + 1) % SEG]
             for r in range(RINGS - 1) for s in range(SEG)]
    m = add_mesh(stage, "/Arm/Skin", pts, [4] * len(quads), np.ravel(quads))
    m.CreateSubdivisionSchemeAttr(scheme)
    if scheme == "none":
        m.CreateNormalsAttr([Gf.Vec3f(p[0], 0, p[2]).GetNormalized() for p in pts])
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(5, 0, 0))  # ignored once skinned (UsdSkel)
    binding = UsdSkel.BindingAPI.Apply(m.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    y = np.array([p[1] for p in pts])
    w_elbow = np.clip(y - 1.5, 0.0, 1.0)
    binding.CreateJointIndicesPrimvar(False, 2).Set(Vt.IntArray([0, 1] * len(pts)))
    binding.CreateJointWeightsPrimvar(False, 2).Set(Vt.FloatArray(np.c_[1 - w_elbow, w_elbow].ravel().tolist()))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1))
    shape = UsdSkel.BlendShape.Define(stage, "/Arm/Skin/Bulge")
    shape.CreateOffsetsAttr([Gf.Vec3f(0.2, 0, 0)] * SEG)
    shape.CreatePointIndicesAttr(list(range(4 * SEG, 5 * SEG)))
    binding.CreateBlendShapesAttr(["bulge"])
    binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
    return m


def _baked(stage, tmp_path):
    path = str(tmp_path / "rig.usda")
    stage.GetRootLayer().Export(path)
    baked = Usd.Stage.Open(path)
    assert UsdSkel.BakeSkinning(baked.Traverse(), Gf.Interval(TIMES[0], TIMES[-1]))
    return baked


@pytest.mark.parametrize("frame", [5.0, 10.0])
def test_skinned_points_and_normals_match_bake_skinning(tmp_path, frame):
    stage = new_stage()
    _arm(stage)
    baked = _baked(stage, tmp_path)
    ours = read(stage, frame=frame)
    ref = read(baked, frame=frame)
    assert ours.stats["skinned_meshes"] == 1 and ref.stats["skinned_meshes"] == 0
    a, b = mesh(ours, "/Arm/Skin"), mesh(ref, "/Arm/Skin")
    np.testing.assert_allclose(a.points, b.points, atol=2e-6)
    np.testing.assert_allclose(a.normals, b.normals, atol=2e-6)
    rest = mesh(read(stage, frame=1.0), "/Arm/Skin").points
    assert np.abs(a.points - rest).max() > 0.5  # it did move: the bent elbow


def test_skinned_subdivision_cage_is_refined_after_skinning(tmp_path):
    stage = new_stage()
    _arm(stage, scheme="catmullClark")
    baked = _baked(stage, tmp_path)
    a = mesh(read(stage, frame=10.0, subdiv_level=1), "/Arm/Skin")
    b = mesh(read(baked, frame=10.0, subdiv_level=1), "/Arm/Skin")
    np.testing.assert_allclose(a.points, b.points, atol=2e-6)
    np.testing.assert_allclose(a.normals, b.normals, atol=2e-5)


def test_time_sampled_points_are_read_at_the_frame(stage):
    m = add_mesh(stage, "/Q", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [4], [0, 1, 2, 3])
    attr = m.GetPointsAttr()
    attr.Clear()
    for t, z in ((1.0, 0.0), (3.0, 2.0)):
        attr.Set(Vt.Vec3fArray([(0, 0, z), (1, 0, z), (1, 1, z), (0, 1, z)]), t)
    stage.SetStartTimeCode(1)
    for frame, z in ((1.0, 0.0), (2.0, 1.0), (3.0, 2.0), (None, 0.0)):
        np.testing.assert_allclose(mesh(read(stage, frame=frame), "/Q").points[:, 2], z)


def test_skinned_implicit_prim_warns(stage):
    _arm(stage)
    ball = UsdGeom.Sphere.Define(stage, "/Arm/Ball")
    b = UsdSkel.BindingAPI.Apply(ball.GetPrim())
    b.CreateSkeletonRel().SetTargets(["/Arm/Skel"])
    b.CreateJointIndicesPrimvar(True, 1).Set(Vt.IntArray([1]))
    b.CreateJointWeightsPrimvar(True, 1).Set(Vt.FloatArray([1.0]))
    d = read(stage, frame=10.0)
    assert "/Arm/Ball: skinning of a Sphere is not supported (only Mesh points); rendered unskinned" in d.warnings


def test_binding_to_a_missing_skeleton_warns(stage):
    m = _arm(stage)
    UsdSkel.BindingAPI(m.GetPrim()).GetSkeletonRel().SetTargets(["/Arm/Nope"])
    d = read(stage, frame=10.0)
    assert any(w.startswith("/Arm/Skin: skel binding without a valid Skeleton") for w in d.warnings)
    np.testing.assert_allclose(mesh(d, "/Arm/Skin").points[:, 1].max(), 4.0 + 2.0, atol=1e-6)  # rest pose
