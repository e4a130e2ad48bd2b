"""The compiled fast path serves normal-mapped and cut-out materials, estimating what the general
integrator estimates (renderer/integrators/fast_path.py).

Three stages, each rendered with the fast path and with ``fast_path=False`` and z-tested over the
whole image and in 16 blocks (test_fast_path's _pair and _block_z): a floor with a bumpy
tangent-space normal map seen at oblique angles (where the bent normals are corrected toward a
valid reflection); a cut-out card over a lit floor, once with a texture's alpha against an
opacityThreshold and once with a stochastic constant opacity (camera and bounce rays pass through
the card, shadow rays see it as the general path does); and stages/plant/plant.usda. Each test
can fail: without the bent normals or without the pass-through the same comparison fails.
"""

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.integrators import fast_path as fp_mod
from renderer.materials import MaterialTable
from tests.integrators.test_fast_path import Z_BLOCK, Z_MAX, _block_z, _pair
from tests.materials.test_normal_map import _add_normal_map, _floor
from tests.stage_builders import add_camera, add_floor, add_settings, bind, new_stage, preview_material


def _write_image(path, px) -> str:
    """A float EXR or 8-bit PNG (by extension) of px (H, W, C), row 0 at the top."""
    px = np.ascontiguousarray(px, dtype=np.float32)
    buf = oiio.ImageBuf(px)
    assert buf.write(str(path), oiio.UINT8 if str(path).endswith(".png") else oiio.FLOAT), oiio.geterror()
    return str(path)


def _bumps(n=32, strength=0.9):
    """A tangent-space normal map of egg-crate bumps, up to ~50 degrees from +z."""
    u, v = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    gx = strength * np.cos(2 * np.pi * 3 * u) * np.sin(2 * np.pi * 2 * v)
    gy = strength * np.sin(2 * np.pi * 3 * u) * np.cos(2 * np.pi * 2 * v)
    nrm = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
    return nrm / np.linalg.norm(nrm, axis=-1, keepdims=True)


def _bumpy_floor_stage(path, tmp_path):
    stage = new_stage(path)
    add_camera(stage, pos=(0.0, 0.35, 1.1), tilt_x=-20.0)
    add_settings(stage, (32, 24))
    floor = _floor(stage, "plain")
    look = preview_material(stage, "/World/Looks/Grey", diffuse=(0.6, 0.5, 0.4), roughness=0.3)
    _add_normal_map(stage, "/World/Looks/Grey", _write_image(tmp_path / "bumps.exr", _bumps()), encoded=False)
    bind(floor.GetPrim(), look)
    light = UsdLux.RectLight.Define(stage, "/World/Light")
    light.CreateIntensityAttr(6.0)
    xf = UsdGeom.Xformable(light)
    xf.AddTranslateOp().Set(Gf.Vec3d(0.0, 1.5, -1.0))
    xf.AddRotateXOp().Set(-45.0)
    sky = UsdLux.DomeLight.Define(stage, "/World/Sky")
    sky.CreateIntensityAttr(0.3)
    stage.GetRootLayer().Save()
    return str(path)


def _card_stage(path, tmp_path, textured, primvar=False):
    """A floor lit by a rect light and a dim sky through a 2 x 2 m card at y = 1: its alpha (a
    4 x 4 checker, threshold 0.5), a constant opacity 0.4 (threshold 0, stochastic) or (primvar)
    a UsdPrimvarReader_float's per-vertex opacity from 0.1 to 0.9 across it cuts it."""
    stage = new_stage(path)
    add_camera(stage, pos=(0, 2.5, 4.0), tilt_x=-30)
    add_settings(stage, (32, 24))
    add_floor(stage, diffuse=(0.6, 0.6, 0.6))
    card = UsdGeom.Mesh.Define(stage, "/World/Card")
    card.CreatePointsAttr([(-1, 1, -1), (1, 1, -1), (1, 1, 1), (-1, 1, 1)])
    card.CreateFaceVertexCountsAttr([4])
    card.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    card.CreateSubdivisionSchemeAttr("none")
    UsdGeom.PrimvarsAPI(card).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (0, 1), (1, 1), (1, 0)])
    look = preview_material(stage, "/World/Looks/Card", diffuse=(0.2, 0.5, 0.2), roughness=0.5)
    pbr = UsdShade.Shader.Get(stage, "/World/Looks/Card/PBR")
    if textured:
        yy, xx = np.mgrid[0:16, 0:16]
        alpha = ((xx // 4 + yy // 4) % 2).astype(float)
        rgba = np.stack([0.2 + 0.6 * alpha, np.full_like(alpha, 0.5), 0.8 - 0.6 * alpha, alpha], axis=-1)
        reader = UsdShade.Shader.Define(stage, "/World/Looks/Card/St")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        tex = UsdShade.Shader.Define(stage, "/World/Looks/Card/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(_write_image(tmp_path / "alpha.png", rgba))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
            reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            tex.ConnectableAPI(), "rgb")
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        tex.CreateOutput("a", Sdf.ValueTypeNames.Float)
        pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "a")
        pbr.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    elif primvar:
        UsdGeom.PrimvarsAPI(card).CreatePrimvar("cut", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex).Set(
            [0.1, 0.9, 0.9, 0.1])
        reader = UsdShade.Shader.Define(stage, "/World/Looks/Card/Cut")
        reader.CreateIdAttr("UsdPrimvarReader_float")
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("cut")
        pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(
            reader.CreateOutput("result", Sdf.ValueTypeNames.Float))
    else:
        pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.4)
    bind(card.GetPrim(), look)
    light = UsdLux.RectLight.Define(stage, "/World/Light")
    light.CreateWidthAttr(1.0)
    light.CreateHeightAttr(1.0)
    light.CreateIntensityAttr(15.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0.3, 3.0, 0.2))
    UsdGeom.Xformable(light).AddRotateXOp().Set(-90.0)
    sky = UsdLux.DomeLight.Define(stage, "/World/Sky")
    sky.CreateIntensityAttr(0.2)
    stage.GetRootLayer().Save()
    return str(path)


def _check(fast, slow):
    assert fast.stats["fast_path"] == "on", fast.stats["fast_path"]
    assert slow.stats["fast_path"].startswith("disabled")
    z, zs = _block_z(fast, slow)
    assert abs(z) < Z_MAX, f"whole image: fast - general = {z:.2f} sigma"
    assert max(abs(x) for x in zs) < Z_BLOCK, f"blocks: {np.round(zs, 2)}"
    assert fast.film.nonfinite_dropped == 0 and fast.film.mean().sum() > 0.0


@pytest.mark.parametrize("max_depth", [2, 4])
def test_normal_mapped_floor_matches_general_path(tmp_path, max_depth):
    stage = _bumpy_floor_stage(tmp_path / "bumps.usda", tmp_path)
    _check(*_pair(stage, max_depth, spp=256, rr_depth=1))


@pytest.mark.parametrize("textured", [True, False])
def test_cutout_card_matches_general_path(tmp_path, textured):
    stage = _card_stage(tmp_path / "card.usda", tmp_path, textured)
    _check(*_pair(stage, 4, spp=256, rr_depth=1))


def test_primvar_fed_cutout_matches_general_path(tmp_path):
    """Opacity from a primvar reader: the compiled walks read it per hit (materials.presence_hit)."""
    stage = _card_stage(tmp_path / "card.usda", tmp_path, False, primvar=True)
    _check(*_pair(stage, 4, spp=256, rr_depth=1))


def test_plant_stage_matches_general_path():
    # The stage at 40 x 30 (its own 320 x 240 would take minutes on the general path).
    _check(*_pair("stages/plant/plant.usda", 5, spp=128, rr_depth=2, resolution=(40, 30)))


@pytest.mark.parametrize("which", ["normals", "cutouts"])
def test_the_comparison_sees_a_missing_material_feature(tmp_path, monkeypatch, which):
    """Unbent normals, or cut-outs left solid for camera and bounce rays, fail the same test."""
    if which == "normals":
        stage = _bumpy_floor_stage(tmp_path / "bumps.usda", tmp_path)
        # The fast path's hit record without the normal maps' tangent frames: normals unbent.
        orig = MaterialTable.hit_record
        monkeypatch.setattr(MaterialTable, "hit_record",
                            lambda self, g: orig(self, g)[:2] + (np.zeros((0, 3)), np.zeros(0)) + orig(self, g)[4:])
    else:
        stage = _card_stage(tmp_path / "card.usda", tmp_path, True)
        # (On the Python bounce loop, whose walk can be switched off.)
        monkeypatch.setattr(fp_mod.FastPath, "kernel_reason", lambda self: "forced by the test")
        monkeypatch.setattr(fp_mod.FastPath, "_through_cutouts", lambda self, *a: None)
    z, zs = _block_z(*_pair(stage, 4, spp=256, rr_depth=1))
    assert max(abs(x) for x in zs) > Z_BLOCK, f"a missing {which} went unseen (blocks {np.round(zs, 2)})"


def test_numpy_cutout_walk_matches_general_path(tmp_path, monkeypatch):
    """Without native Embree calls the fast path walks cut-outs with numpy loops (FastPath.walk
    None): the same estimate."""
    orig = fp_mod.FastPath.__init__

    def no_native(self, integ):
        orig(self, integ)
        assert self.walk is not None  # this machine has native Embree: the compiled walks ran above
        self.walk = None

    monkeypatch.setattr(fp_mod.FastPath, "__init__", no_native)
    stage = _card_stage(tmp_path / "card.usda", tmp_path, True)
    _check(*_pair(stage, 4, spp=256, rr_depth=1))
