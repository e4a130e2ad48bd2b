"""Small real stages for the stress renders, written with pxr (see tests/stage_builders.py).

``penumbra_stage``: a grey floor (y = 0) lit by one rect light 3 units above it, facing down, a
small occluding card halfway between them (so the floor has umbra, penumbra and full light),
and a camera 6 units up looking down. Everything lives under /World, whose translate op can
move the whole stage (``offset``) without changing anything relative.
"""

from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade, Vt

from tests.stage_builders import add_quad, add_settings, new_stage, preview_material


def _quad(stage, path, corners, material=None):
    return add_quad(stage, path, corners, material, double_sided=True)


def penumbra_stage(path, *, res=(24, 24), offset=(0.0, 0.0, 0.0), intensity=4.0, light_kind="rect",
                   light_size=2.0, occluder=True, diffuse=(0.5, 0.5, 0.5), roughness=0.5, metallic=0.0,
                   camera_exposure=None, light_exposure=None, specular_workflow=False):
    stage = new_stage(path)
    world = UsdGeom.Xform.Define(stage, "/World")
    world.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*offset))
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(20.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(36.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.1, 1000.0))
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 6, 0))
    xf.AddRotateXOp().Set(-90.0)
    if camera_exposure is not None:
        cam.CreateExposureAttr(float(camera_exposure))
    add_settings(stage, res, camera="/World/Camera")
    grey = preview_material(stage, "/World/Looks/Floor", diffuse=diffuse, roughness=roughness, metallic=metallic,
                            specular_workflow=specular_workflow)
    _quad(stage, "/World/Floor", [(-5, 0, -5), (-5, 0, 5), (5, 0, 5), (5, 0, -5)], grey)
    if occluder:
        _quad(stage, "/World/Card", [(-0.3, 1.5, -3), (-0.3, 1.5, 3), (3, 1.5, 3), (3, 1.5, -3)], grey)
    if light_kind == "rect":
        light = UsdLux.RectLight.Define(stage, "/World/Light")
        light.CreateWidthAttr(light_size)
        light.CreateHeightAttr(light_size)
    elif light_kind == "disk":
        light = UsdLux.DiskLight.Define(stage, "/World/Light")
        light.CreateRadiusAttr(0.5 * light_size)
    elif light_kind == "sphere":
        light = UsdLux.SphereLight.Define(stage, "/World/Light")
        light.CreateRadiusAttr(0.5 * light_size)
    else:
        raise ValueError(light_kind)
    light.CreateIntensityAttr(float(intensity))
    if light_exposure is not None:
        light.CreateExposureAttr(float(light_exposure))
    lx = UsdGeom.Xformable(light)
    lx.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    lx.AddRotateXOp().Set(-90.0)
    stage.GetRootLayer().Save()
    return stage


def textured_material(stage, path, texture_file):
    """A UsdPreviewSurface whose diffuseColor reads ``texture_file`` through st."""
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/PBR")
    sh.CreateIdAttr("UsdPreviewSurface")
    tex = UsdShade.Shader.Define(stage, path + "/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(str(texture_file)))
    reader = UsdShade.Shader.Define(stage, path + "/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def add_st(mesh, values):
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set(Vt.Vec2fArray([Gf.Vec2f(*v) for v in values]))


def write_image(path, img) -> str:
    import OpenImageIO as oiio

    assert oiio.ImageBuf(np.ascontiguousarray(img, dtype=np.float32)).write(str(path))
    return str(path)
