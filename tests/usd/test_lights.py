"""UsdLux -> LightDesc: raw inputs, frames, dome pole axis, linking, validation, unsupported types."""

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from renderer.errors import StageError
from renderer.usd import load_stage

from .helpers import add_quad, new_stage, read


def _light(d, path):
    found = [light for light in d.lights if light.path == path]
    assert len(found) == 1, [light.path for light in d.lights]
    return found[0]


def test_common_raw_inputs(stage):
    L = UsdLux.RectLight.Define(stage, "/Key")
    L.CreateIntensityAttr(12.0)
    L.CreateExposureAttr(-1.5)
    L.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    L.CreateEnableColorTemperatureAttr(True)
    L.CreateColorTemperatureAttr(3200.0)
    L.CreateNormalizeAttr(True)
    L.CreateDiffuseAttr(0.5)
    L.CreateSpecularAttr(0.0)
    L.CreateWidthAttr(2.0)
    L.CreateHeightAttr(0.5)
    d = _light(read(stage), "/Key")
    assert d.kind == "rect"
    assert (d.intensity, d.exposure, d.color) == (12.0, -1.5, (1.0, 0.5, 0.25))
    assert d.enable_color_temperature and d.color_temperature == 3200.0
    assert d.normalize and (d.diffuse, d.specular) == (0.5, 0.0)
    assert (d.width, d.height) == (2.0, 0.5)
    assert np.allclose(d.light_to_world, np.eye(4))
    assert d.light_link_excludes is None and d.shadow_link_excludes is None


def test_each_kind_and_its_own_inputs(stage):
    UsdLux.DiskLight.Define(stage, "/Disk").CreateRadiusAttr(0.2)
    s = UsdLux.SphereLight.Define(stage, "/Sphere")
    s.CreateRadiusAttr(0.0)
    s.CreateTreatAsPointAttr(True)
    c = UsdLux.CylinderLight.Define(stage, "/Cyl")
    c.CreateLengthAttr(3.0)
    c.CreateRadiusAttr(0.1)
    c.CreateTreatAsLineAttr(True)
    UsdLux.DistantLight.Define(stage, "/Sun").CreateAngleAttr(1.0)
    UsdLux.DomeLight.Define(stage, "/Dome")
    d = read(stage)
    assert {light.path: light.kind for light in d.lights} == {
        "/Disk": "disk", "/Sphere": "sphere", "/Cyl": "cylinder", "/Sun": "distant", "/Dome": "dome"}
    assert _light(d, "/Disk").radius == pytest.approx(0.2)
    assert _light(d, "/Sphere").treat_as_point and _light(d, "/Sphere").radius == 0.0
    cyl = _light(d, "/Cyl")
    assert (cyl.length, cyl.treat_as_line) == (3.0, True) and cyl.radius == pytest.approx(0.1)
    sun = _light(d, "/Sun")
    assert sun.angle == 1.0 and sun.intensity == 50000.0  # DistantLight's own fallback
    assert _light(d, "/Dome").texture_format == "automatic"


def test_light_frame_is_the_world_matrix(stage):
    UsdGeom.Xform.Define(stage, "/Rig").AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    L = UsdLux.RectLight.Define(stage, "/Rig/Key")
    UsdGeom.Xformable(L).AddRotateXOp().Set(90.0)
    d = _light(read(stage), "/Rig/Key")
    emit = d.light_to_world @ [0, 0, -1, 0]  # lights emit along local -Z
    assert np.allclose(emit[:3], [0, 1, 0], atol=1e-12)
    assert np.allclose(d.light_to_world @ [0, 0, 0, 1], [0, 0, 5, 1])


def test_texture_files_resolved(tmp_path):
    # Real images: the reader opens each texture's header (the missing-asset policy covers
    # unreadable files too).
    import OpenImageIO as oiio

    for name, fmt in (("env.exr", oiio.HALF), ("gobo.png", oiio.UINT8)):
        assert oiio.ImageBuf(np.full((2, 4, 3), 0.5, np.float32)).write(str(tmp_path / name), fmt)
    stage = new_stage()
    dome = UsdLux.DomeLight.Define(stage, "/Dome")
    dome.CreateTextureFileAttr(Sdf.AssetPath("./env.exr"))
    dome.CreateTextureFormatAttr("latlong")
    UsdLux.RectLight.Define(stage, "/Rect").CreateTextureFileAttr(Sdf.AssetPath("gobo.png"))
    path = tmp_path / "lights.usda"
    stage.GetRootLayer().Export(str(path))
    d = load_stage(str(path))
    assert _light(d, "/Dome").texture_file == os.path.join(str(tmp_path), "env.exr")
    assert _light(d, "/Dome").texture_format == "latlong"
    assert _light(d, "/Rect").texture_file == os.path.join(str(tmp_path), "gobo.png")


def test_missing_light_texture(stage):
    """The missing-asset policy: a warning and an untextured dome; --strict: an error."""
    UsdLux.DomeLight.Define(stage, "/Dome").CreateTextureFileAttr(Sdf.AssetPath("/no/such/env.exr"))
    d = read(stage)
    assert _light(d, "/Dome").texture_file == ""
    assert sum("/Dome.inputs:texture:file: file not found" in w for w in d.warnings) == 1
    with pytest.raises(StageError) as err:
        read(stage, strict=True)
    assert (err.value.prim, err.value.attribute) == ("/Dome", "inputs:texture:file")


# --------------------------------------------------------------------------------------
# Dome pole axis
# --------------------------------------------------------------------------------------
R_POLE = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)


@pytest.mark.parametrize("up,schema,pole,rotated", [
    ("Z", "DomeLight_1", "scene", True),
    ("Z", "DomeLight_1", None, True),  # poleAxis fallback is 'scene'
    ("Y", "DomeLight_1", "scene", False),
    ("Y", "DomeLight_1", "Z", True),
    ("Z", "DomeLight_1", "Y", False),
    ("Z", "DomeLight", None, False),  # the old DomeLight always keeps +Y as its pole
])
def test_dome_pole(up, schema, pole, rotated):
    stage = new_stage(up=up)
    dome = getattr(UsdLux, schema).Define(stage, "/Dome")
    if pole is not None:
        dome.CreatePoleAxisAttr(pole)
    d = _light(read(stage), "/Dome")
    assert np.allclose(d.light_to_world, R_POLE if rotated else np.eye(4))
    if rotated:
        assert np.allclose(d.light_to_world @ [0, 1, 0, 0], [0, 0, 1, 0])  # top pole -> world +Z
        assert np.allclose(d.light_to_world @ [0, 0, 1, 0], [0, -1, 0, 0])  # lat0/lon0 -> world -Y


def test_dome_pole_composes_after_the_lights_own_transform():
    stage = new_stage(up="Z")
    dome = UsdLux.DomeLight_1.Define(stage, "/Dome")
    UsdGeom.Xformable(dome).AddRotateZOp().Set(90.0)
    d = _light(read(stage), "/Dome")
    own = np.array(Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0, 0, 1), 90))).T
    assert np.allclose(d.light_to_world, own @ R_POLE)


# --------------------------------------------------------------------------------------
# Linking
# --------------------------------------------------------------------------------------
def test_light_and_shadow_linking(stage):
    for name in ("A", "B", "C"):
        add_quad(stage, f"/World/{name}")
    key = UsdLux.RectLight.Define(stage, "/Key")
    api = UsdLux.LightAPI(key)
    link = api.GetLightLinkCollectionAPI()
    link.CreateIncludeRootAttr(False)
    link.CreateIncludesRel().AddTarget("/World/A")
    api.GetShadowLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/B")
    UsdLux.SphereLight.Define(stage, "/Fill")
    d = read(stage)
    key_d = _light(d, "/Key")
    assert key_d.light_link_excludes == frozenset({"/World/B", "/World/C"})
    assert key_d.shadow_link_excludes == frozenset({"/World/B"})
    fill = _light(d, "/Fill")
    assert fill.light_link_excludes is None and fill.shadow_link_excludes is None


def test_linking_by_ancestor_and_instancer_paths(stage):
    add_quad(stage, "/World/Set/Wall")
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Trees")
    UsdGeom.Cube.Define(stage, "/World/Trees/Protos/Tree")
    pi.CreatePrototypesRel().AddTarget("/World/Trees/Protos/Tree")
    pi.CreateProtoIndicesAttr([0, 0])
    pi.CreatePositionsAttr([(0, 0, 0), (5, 0, 0)])
    key = UsdLux.RectLight.Define(stage, "/Key")
    UsdLux.LightAPI(key).GetLightLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/Trees")
    d = read(stage)
    assert _light(d, "/Key").light_link_excludes == frozenset({"/World/Trees/Protos/Tree"})


# --------------------------------------------------------------------------------------
# Skipped lights and validation
# --------------------------------------------------------------------------------------
def test_invisible_light_is_skipped(stage):
    UsdLux.RectLight.Define(stage, "/Off").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    UsdLux.RectLight.Define(stage, "/On")
    assert [light.path for light in read(stage).lights] == ["/On"]


@pytest.mark.parametrize("make", [
    lambda s: UsdLux.RectLight.Define(s, "/L").CreateWidthAttr(0.0),
    lambda s: UsdLux.DiskLight.Define(s, "/L").CreateRadiusAttr(0.0),
    lambda s: UsdLux.SphereLight.Define(s, "/L").CreateRadiusAttr(0.0),
    lambda s: UsdLux.CylinderLight.Define(s, "/L").CreateLengthAttr(0.0),
])
def test_degenerate_lights_skipped_with_warning(stage, make):
    make(stage)
    d = read(stage)
    assert d.lights == [] and any("/L" in w and "skipped" in w for w in d.warnings)


@pytest.mark.parametrize("schema,attr,value", [
    (UsdLux.RectLight, "inputs:intensity", float("nan")),
    (UsdLux.RectLight, "inputs:intensity", -1.0),
    (UsdLux.RectLight, "inputs:intensity", float("inf")),
    (UsdLux.RectLight, "inputs:width", -2.0),
    (UsdLux.RectLight, "inputs:height", float("nan")),
    (UsdLux.SphereLight, "inputs:radius", -0.5),
    (UsdLux.DiskLight, "inputs:radius", -0.1),
    (UsdLux.CylinderLight, "inputs:radius", -0.2),
    (UsdLux.CylinderLight, "inputs:length", -1.0),
    (UsdLux.DistantLight, "inputs:angle", -0.1),
    (UsdLux.DiskLight, "inputs:colorTemperature", float("nan")),
    (UsdLux.DiskLight, "inputs:exposure", float("nan")),
])
def test_invalid_light_values(stage, schema, attr, value):
    schema.Define(stage, "/World/L").GetPrim().GetAttribute(attr).Set(value)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/World/L", attr)
    assert str(err.value).startswith(f"mem.usda: /World/L.{attr}: ")


def test_negative_exposure_is_fine(stage):
    UsdLux.RectLight.Define(stage, "/L").CreateExposureAttr(-4.0)
    assert read(stage).lights[0].exposure == -4.0


def test_unsupported_texture_format(stage):
    UsdLux.DomeLight_1.Define(stage, "/Dome").CreateTextureFormatAttr("mirroredBall")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Dome", "inputs:texture:format")


def test_unsupported_light_types_warn_and_skip(stage):
    UsdLux.PluginLight.Define(stage, "/Plugin")
    UsdLux.GeometryLight.Define(stage, "/Geo")
    d = read(stage)
    assert d.lights == []
    text = " ".join(d.warnings)
    assert all(k in text for k in ("PluginLight", "GeometryLight"))


def test_mesh_light_and_unused_portal(stage):
    # MeshLightAPI makes the mesh a light as well (tests/usd/test_mesh_lights.py has the details);
    # a PortalLight no dome targets is no light and says it has no effect.
    UsdLux.PortalLight.Define(stage, "/Portal")
    glow = add_quad(stage, "/Glow")
    UsdLux.MeshLightAPI.Apply(glow.GetPrim())
    d = read(stage)
    assert [(light.path, light.kind) for light in d.lights] == [("/Glow", "mesh")]
    assert [m.path for m in d.meshes] == ["/Glow"]  # the mesh itself still renders
    assert [w for w in d.warnings if "/Portal" in w and "not a target" in w]
