"""load_stage: the public entry point, whole-file behaviour and file-level errors."""

import numpy as np
import pytest

import renderer.usd
from renderer.description import SceneDescription
from renderer.errors import StageError
from renderer.usd import load_stage

STAGE = """#usda 1.0
(
    upAxis = "Z"
    metersPerUnit = 1
    renderSettingsPrimPath = "/Render/Settings"
)

def Scope "Render"
{
    def RenderSettings "Settings" (
        prepend apiSchemas = ["IllumRenderSettingsAPI"]
    )
    {
        rel camera = </World/Cam>
        int2 resolution = (320, 240)
        uniform token illum:lightSampler = "power"
    }
}

def Xform "World"
{
    def Camera "Cam"
    {
        float focalLength = 35
        double3 xformOp:translate = (0, -10, 2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }

    def Mesh "Floor"
    {
        point3f[] points = [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        uniform token subdivisionScheme = "none"
    }

    def Sphere "Ball"
    {
        color3f[] primvars:displayColor = [(0.8, 0.2, 0.2)]
        double3 xformOp:translate = (0, 0, 1)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }

    def RectLight "Key" (
        prepend apiSchemas = ["IllumLightAPI"]
    )
    {
        float inputs:intensity = 10
        uniform token illum:estimator = "lightSampling"
    }

    def DomeLight_1 "Sky"
    {
    }
}
"""


def test_public_api():
    assert renderer.usd.__all__ == ["load_stage", "read_stage"]


def test_load_stage_file(tmp_path):
    path = tmp_path / "scene.usda"
    path.write_text(STAGE)
    d = load_stage(str(path))
    assert isinstance(d, SceneDescription) and d.source == str(path)
    assert d.up_axis == "Z" and d.meters_per_unit == 1.0
    assert sorted(m.path for m in d.meshes) == ["/World/Ball", "/World/Floor"]
    assert d.camera.path == "/World/Cam" and d.settings.resolution == (320, 240)
    assert d.settings.light_sampler == "power"
    assert {light.path: light.estimator.estimator for light in d.lights} == {
        "/World/Key": "lightSampling", "/World/Sky": "mis"}
    sky = [light for light in d.lights if light.kind == "dome"][0]
    assert np.allclose(sky.light_to_world @ [0, 1, 0, 0], [0, 0, 1, 0])  # Z-up scene pole
    assert d.warnings == []
    assert d.stats["meshes"] == 2 and d.stats["lights"] == 2 and d.stats["points_read"] == 4
    for m in d.meshes:
        assert m.points.dtype == np.float64 and m.triangles.dtype == np.int32
        assert 0 <= m.material < len(d.materials)


def test_missing_file():
    with pytest.raises(StageError) as err:
        load_stage("/no/such/dir/shot.usda")
    assert err.value.file == "/no/such/dir/shot.usda" and "not found" in str(err.value)


def test_malformed_file_is_one_line(tmp_path):
    path = tmp_path / "broken.usda"
    path.write_text(STAGE.replace("float focalLength = 35", "float focalLength = = 35"))
    with pytest.raises(StageError) as err:
        load_stage(str(path))
    text = str(err.value)
    assert text.startswith(f"{path}: cannot open stage: ") and "\n" not in text
    assert "stage.cpp" not in text  # C++ source locations are stripped


def test_not_a_usd_file(tmp_path):
    path = tmp_path / "image.usda"
    path.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(StageError) as err:
        load_stage(str(path))
    assert str(path) in str(err.value)


def test_frame_must_be_finite(tmp_path):
    path = tmp_path / "scene.usda"
    path.write_text(STAGE)
    with pytest.raises(StageError):
        load_stage(str(path), frame=float("nan"))


def test_composition_errors_become_warnings(tmp_path):
    path = tmp_path / "shot.usda"
    path.write_text(STAGE.replace('def Xform "World"', 'def Xform "World" (references = @./missing_asset.usda@</X>)'))
    d = load_stage(str(path))
    assert any("composition error" in w and "missing_asset.usda" in w for w in d.warnings)


BAD_TYPE = """#usda 1.0
def Camera "C" {}
def Mesh "M"
{
    %s
    int[] faceVertexIndices = [0, 1, 2]
    uniform token subdivisionScheme = "none"
}
"""


@pytest.mark.parametrize("line, attribute, words", [
    ("float2[] points = [(0, 0), (1, 0), (1, 1)]\n    int[] faceVertexCounts = [3]", "points",
     "authored as float2[]"),
    ("point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]\n    int faceVertexCounts = 3",
     "faceVertexCounts", "authored as int"),
])
def test_wrongly_typed_attribute_names_it(tmp_path, line, attribute, words):
    """A schema attribute authored with another value type is a StageError (exit 2) naming the
    prim and attribute, not an internal error deep in the mesh code."""
    path = tmp_path / "bad.usda"
    path.write_text(BAD_TYPE % line)
    with pytest.raises(StageError) as err:
        load_stage(str(path))
    assert (err.value.prim, err.value.attribute) == ("/M", attribute)
    assert words in err.value.message and "schema declares" in err.value.message


def test_other_precision_or_role_of_the_same_shape_is_read(tmp_path):
    """double for float, float3[] for point3f[], float[] for int[]: the values convert."""
    path = tmp_path / "ok.usda"
    path.write_text(BAD_TYPE % "float3[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0)]\n"
                                "    float[] faceVertexCounts = [3]\n    double doubleSided = 1")
    d = load_stage(str(path))
    assert len(d.meshes) == 1 and d.meshes[0].triangles.shape == (1, 3)


def test_stage_without_lights_warns_and_the_stats_say_so(tmp_path):
    from pxr import Gf, UsdGeom

    from renderer.render import RenderOptions, render
    from tests.stage_builders import add_camera, add_floor, add_settings, new_stage

    path = str(tmp_path / "dark.usda")
    stage = new_stage(path)
    add_camera(stage, pos=(0, 6, 0), tilt_x=-90.0)
    add_settings(stage, (8, 8))
    add_floor(stage)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Floor")).AddTranslateOp().Set(Gf.Vec3d(0, 0, 0))
    stage.GetRootLayer().Save()
    result = render(path, RenderOptions(spp=1, threads=1, resolution=(8, 8)))
    hits = [w for w in result.stats["warnings"] if "no lights" in w]
    assert len(hits) == 1 and hits[0] in result.warnings
    assert float(result.film.image().max()) == 0.0
