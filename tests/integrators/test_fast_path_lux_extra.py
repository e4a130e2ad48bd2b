"""The compiled vertex kernel (renderer/integrators/fast_path.py) on the UsdLux kinds it serves
through their own row functions: CylinderLights (treatAsLine included; renderer/kernels/cylinder.py)
and mesh lights (MeshLightAPI; renderer/kernels/mesh_light.py).

The rect-lit room of test_fast_path.py gets a ceiling tube the camera and the continuation rays
see, a sheared, non-uniformly scaled tube (an oblique elliptic cylinder) and a line light; the
fast path and the general path (``fast_path=False``) render it and the image means are z-tested
over the whole image and in 16 blocks, under every lighting service and with the per-light
estimators (a light sample, the BSDF sample, the control variate's MIS fallback), so a wrong
sample, pdf or crossing test fails.
"""

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_BLOCK, Z_MAX, _block_z, _pair, _room
from tests.integrators.test_fast_path_estimators import _pair as _pair_est
from tests.integrators.test_fast_path_materials import _check


def _add_cylinders(path):
    """Three cylinder lights added to the room stage at path (saved in place)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    tube = UsdLux.CylinderLight.Define(stage, "/World/Tube")
    tube.CreateRadiusAttr(0.08)
    tube.CreateLengthAttr(2.2)
    tube.CreateIntensityAttr(6.0)
    tube.CreateColorAttr(Gf.Vec3f(0.8, 0.9, 1.0))
    xf = UsdGeom.Xformable(tube)
    xf.AddTranslateOp().Set(Gf.Vec3d(0.3, 2.6, -0.6))
    xf.AddRotateYOp().Set(20.0)
    oblique = UsdLux.CylinderLight.Define(stage, "/World/Oblique")
    oblique.CreateRadiusAttr(0.15)
    oblique.CreateLengthAttr(1.0)
    oblique.CreateIntensityAttr(4.0)
    oblique.CreateNormalizeAttr(True)
    oblique.CreateColorAttr(Gf.Vec3f(1.0, 0.6, 0.4))
    xf = UsdGeom.Xformable(oblique)
    xf.AddTranslateOp().Set(Gf.Vec3d(-1.6, 1.3, 0.6))
    xf.AddRotateZOp().Set(60.0)
    xf.AddScaleOp().Set(Gf.Vec3f(1.0, 1.8, 0.7))
    xf.AddTransformOp(opSuffix="shear").Set(Gf.Matrix4d(1, 0.3, 0, 0, 0, 1, 0, 0, 0, 0.2, 1, 0, 0, 0, 0, 1))
    line = UsdLux.CylinderLight.Define(stage, "/World/Line")
    line.CreateRadiusAttr(0.02)
    line.CreateLengthAttr(1.5)
    line.CreateTreatAsLineAttr(True)
    line.CreateIntensityAttr(20.0)
    xf = UsdGeom.Xformable(line)
    xf.AddTranslateOp().Set(Gf.Vec3d(1.8, 1.6, 1.0))
    xf.AddRotateXOp().Set(50.0)
    stage.GetRootLayer().Save()


def _room_with(tmp_path, add):
    """test_fast_path's room with the lights ``add`` writes into it."""
    stage = tmp_path / "room.usda"
    _room(stage)
    add(stage)
    return stage


@pytest.fixture
def cylinder_room(tmp_path):
    return _room_with(tmp_path, _add_cylinders)


@pytest.mark.parametrize("max_depth", [2, 5])
def test_cylinder_lights_on_the_fast_path(cylinder_room, max_depth):
    fast, slow = _pair(cylinder_room, max_depth, spp=256, rr_depth=1)
    _check(fast, slow)
    assert fast.stats["rays"]["light_probe"] == 0


@pytest.mark.parametrize("sampler", ["uniform", "power", "bvh"])
def test_cylinder_lights_under_each_lighting_service(cylinder_room, sampler):
    fast, slow = _pair(cylinder_room, 4, spp=256, rr_depth=1, light_sampler=sampler)
    assert fast.stats["light_sampler"] == sampler
    _check(fast, slow)


@pytest.mark.parametrize("estimator,samples", [("lightSampling", 2), ("bsdfSampling", 1), ("controlVariate", 3),
                                               ("mis", 3)])
def test_cylinder_lights_with_each_estimator(cylinder_room, estimator, samples):
    fast, slow = _pair_est(cylinder_room, estimator, "one", samples, spp=192, res=(48, 36))
    _check(fast, slow)


def test_the_comparison_sees_a_wrong_cylinder_emission(cylinder_room, monkeypatch):
    """The comparison can fail: the tubes' radiance doubled where the fast path's rays meet them
    (their samples unchanged)."""
    from renderer.integrators import fast_path as fp_mod

    orig = fp_mod.FastPath.__init__

    def doubled(self, integ):
        orig(self, integ)
        packed, L, light = self.cyl
        # (FastPath.tables ends with the cyl, mesh, portal, texrect and tex records.)
        self.tables = (*self.tables[:-5], (packed, 2.0 * L, light), *self.tables[-4:])
    monkeypatch.setattr(fp_mod.FastPath, "__init__", doubled)
    fast, slow = _pair(cylinder_room, 3, spp=192, rr_depth=1)
    z, _ = _block_z(fast, slow)
    assert abs(z) > Z_MAX, f"doubled tube emission went unseen (z = {z:.2f})"


# ---- mesh lights ---------------------------------------------------------------------------
MESH_STAGE = "stages/lux_extra/mesh_light_room.usda"


def _add_mesh_lights(path):
    """Two mesh lights added to the room stage at path: a one-sided panel of two triangles
    (exact F for the control variate, the per-point triangle pick) and a box of twelve that
    ends paths (materialSyncMode noMaterialResponse)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    panel = UsdGeom.Mesh.Define(stage, "/World/Panel")
    panel.CreatePointsAttr([(-2.2, 0.6, -1.0), (-1.4, 0.6, -1.4), (-1.4, 1.6, -1.4), (-2.2, 1.6, -1.0)])
    panel.CreateFaceVertexCountsAttr([4])
    panel.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    panel.CreateSubdivisionSchemeAttr("none")
    box = UsdGeom.Mesh.Define(stage, "/World/Box")
    c, h = np.array([1.7, 0.35, 1.2]), 0.25
    corners = [tuple(c + h * np.array([x, y, z])) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    box.CreatePointsAttr(corners)
    box.CreateFaceVertexCountsAttr([4] * 6)
    box.CreateFaceVertexIndicesAttr([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])
    box.CreateSubdivisionSchemeAttr("none")
    for prim, intensity, color in ((panel, 3.0, (1.0, 0.7, 0.4)), (box, 2.0, (0.5, 0.8, 1.0))):
        UsdLux.MeshLightAPI.Apply(prim.GetPrim())
        prim.GetPrim().GetAttribute("inputs:intensity").Set(intensity)
        prim.GetPrim().GetAttribute("inputs:color").Set(Gf.Vec3f(*color))
    UsdLux.LightAPI(box.GetPrim()).GetMaterialSyncModeAttr().Set("noMaterialResponse")
    stage.GetRootLayer().Save()


@pytest.fixture
def mesh_room(tmp_path):
    return _room_with(tmp_path, _add_mesh_lights)


def _pair_res(stage, res, **kw):
    common = dict(max_depth=4, rr_depth=1, threads=1, estimator={"": "mis"}, spp=256, resolution=res,
                  pixel_filter_mode="importance", **kw)
    return (render(str(stage), RenderOptions(seed=1, **common)),
            render(str(stage), RenderOptions(seed=8, fast_path=False, **common)))


@pytest.mark.parametrize("sampler", ["exhaustive", "uniform", "power", "bvh"])
def test_mesh_light_room_under_each_lighting_service(sampler):
    """The neon ring (768 triangles: its triangle BVH), the two-sided lampshade and the tube."""
    fast, slow = _pair_res(MESH_STAGE, (48, 36), light_sampler=sampler)
    _check(fast, slow)


@pytest.mark.parametrize("max_depth", [2, 5])
def test_mesh_lights_on_the_fast_path(mesh_room, max_depth):
    fast, slow = _pair(mesh_room, max_depth, spp=256, rr_depth=1)
    _check(fast, slow)


@pytest.mark.parametrize("estimator,samples", [("lightSampling", 2), ("bsdfSampling", 1), ("controlVariate", 3)])
def test_mesh_lights_with_each_estimator(mesh_room, estimator, samples):
    fast, slow = _pair_est(mesh_room, estimator, "one", samples, spp=192, res=(48, 36))
    _check(fast, slow)


def test_the_comparison_sees_a_wrong_mesh_light_sample(mesh_room, monkeypatch):
    """The comparison can fail: the mesh lights' radiance doubled in the kernel's record (their
    samples and the emission rays meet), which moves the image by a few per cent."""
    from renderer.integrators import fast_path as fp_mod

    orig = fp_mod.FastPath._mesh_record

    def doubled(self, ml):
        MS, light, prim_light, prim_tri, absorb = orig(self, ml)
        return (MS[:6] + (2.0 * MS[6],) + MS[7:], light, prim_light, prim_tri, absorb)
    monkeypatch.setattr(fp_mod.FastPath, "_mesh_record", doubled)
    fast, slow = _pair(mesh_room, 3, spp=192, rr_depth=1)
    z, _ = _block_z(fast, slow)
    assert abs(z) > Z_MAX, f"doubled mesh-light samples went unseen (z = {z:.2f})"


# ---- inside the compiled bounce loop -------------------------------------------------------
def _both_kinds(path):
    _add_cylinders(path)
    _add_mesh_lights(path)


@pytest.mark.parametrize("opt", [{}, dict(estimator={"": "controlVariate", "/World/Line": "lightSampling"},
                                          light_samples={"": 2}, light_sampler="bvh")])
def test_cylinder_and_mesh_lights_inside_the_compiled_loop(tmp_path, monkeypatch, opt):
    """The room with both kinds (and the neon stage) runs as one trace_kernel call, which gives the
    Python bounce loop's image bit for bit: continuation MIS, and per-light estimators (the
    mesh panel's exact F taken in the kernel) under the bvh service."""
    from tests.integrators.test_fast_path_kernel import _render, _same

    stage = _room_with(tmp_path, _both_kinds)
    _same(_render(stage, False, monkeypatch, **opt), _render(stage, True, monkeypatch, **opt))


@pytest.mark.parametrize("stage", [MESH_STAGE, None])
def test_one_compiled_call_serves_them(tmp_path, stage):
    """FastPath.kernel_reason is '' for the neon stage (its lampshade's constant glow is read per
    material, no per-hit rows) and the room with both kinds."""
    from renderer.camera import Camera
    from renderer.integrators.path import IntegratorOptions, PathIntegrator
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    scene = build_scene(load_stage(str(stage or _room_with(tmp_path, _both_kinds))), threads=1)
    try:
        integ = PathIntegrator(scene, Camera(scene.desc.camera, 8, 8), IntegratorOptions(threads=1))
        assert integ.fast is not None and integ.fast.kernel_reason() == ""
    finally:
        scene.close()
