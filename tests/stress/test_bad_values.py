"""NaN and Inf in a stage (issue #8, stress item): clear errors, never a silent black or NaN image.

* A non-finite value in a light, camera, mesh or material attribute is a StageError naming the
  prim and the attribute, raised by ``render()`` (the CLI prints it as one line, exit code 2).
* NaN texels: in a light texture (rect or dome) they are a StageError with their count; in a
  material texture they are replaced by 0 with a warning giving the count (the documented
  policy of renderer/lights/texture.py and renderer/textures.py), and the image stays finite.

The reader's unit tests (tests/usd/test_lights.py::test_invalid_light_values, test_camera.py,
test_materials.py::test_non_finite_input_is_an_error) cover several of these at the reader
level; here each goes through a whole render.
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.errors import StageError
from renderer.render import RenderOptions, render
from tests.stress.record import count
from tests.stress.stages import add_st, penumbra_stage, textured_material, write_image

pytestmark = pytest.mark.slow

NAN, INF = float("nan"), float("inf")
BAD = [NAN, INF, -INF]


def _render(path):
    return render(str(path), RenderOptions(spp=1, threads=1, max_depth=2))


def _light(stage, attr, value):
    stage.GetPrimAtPath("/World/Light").GetAttribute(attr).Set(value)


def _sphere(stage, attr, value):
    light = UsdLux.SphereLight.Define(stage, "/World/Ball")
    light.GetPrim().GetAttribute(attr).Set(value)


def _dome(stage, attr, value):
    UsdLux.DomeLight.Define(stage, "/World/Dome").GetPrim().GetAttribute(attr).Set(value)


def _distant(stage, attr, value):
    UsdLux.DistantLight.Define(stage, "/World/Sun").GetPrim().GetAttribute(attr).Set(value)


def _camera(stage, attr, value):
    stage.GetPrimAtPath("/World/Camera").GetAttribute(attr).Set(value)


def _shader(stage, attr, value):
    UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Floor/PBR")).GetInput(attr.split(":", 1)[1]).Set(value)


def _points(stage, attr, value):
    UsdGeom.Mesh(stage.GetPrimAtPath("/World/Card")).GetPointsAttr().Set(
        [Gf.Vec3f(-0.3, 1.5, -3), Gf.Vec3f(-0.3, value, 3), Gf.Vec3f(3, 1.5, 3), Gf.Vec3f(3, 1.5, -3)])


def _color_temperature(stage, attr, value):
    stage.GetPrimAtPath("/World/Light").GetAttribute("inputs:enableColorTemperature").Set(True)
    _light(stage, attr, value)


def _vec(v):
    return Gf.Vec3f(v, 1.0, 1.0)


# (setter, prim, attribute, value -> authored value)
CASES = [
    (_light, "/World/Light", "inputs:intensity", float),
    (_light, "/World/Light", "inputs:exposure", float),
    (_light, "/World/Light", "inputs:color", _vec),
    (_light, "/World/Light", "inputs:width", float),
    (_light, "/World/Light", "inputs:height", float),
    (_light, "/World/Light", "inputs:diffuse", float),
    (_color_temperature, "/World/Light", "inputs:colorTemperature", float),
    (_sphere, "/World/Ball", "inputs:radius", float),
    (_dome, "/World/Dome", "inputs:intensity", float),
    (_distant, "/World/Sun", "inputs:angle", float),
    (_camera, "/World/Camera", "focalLength", float),
    (_camera, "/World/Camera", "horizontalAperture", float),
    (_camera, "/World/Camera", "exposure", float),
    (_camera, "/World/Camera", "fStop", float),
    (_points, "/World/Card", "points", float),
    (_shader, "/World/Looks/Floor/PBR", "inputs:diffuseColor", _vec),
    (_shader, "/World/Looks/Floor/PBR", "inputs:roughness", float),
]


def _params():
    out = []
    for case in CASES:
        for value, vid in zip(BAD, ("nan", "inf", "-inf")):
            out.append(pytest.param(*case, value, id=f"{case[1]}.{case[2]}-{vid}"))
    return out


@pytest.mark.parametrize("setter,prim,attr,make,value", _params())
def test_non_finite_attribute_is_a_stage_error_naming_it(tmp_path, setter, prim, attr, make, value):
    path = tmp_path / "bad.usda"
    stage = penumbra_stage(path)
    setter(stage, attr, make(value))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    e = err.value
    assert e.prim == prim, str(e)
    # The camera's exposure is read through ComputeLinearExposureScale: the reader names
    # "exposure" either way.
    assert e.attribute == attr, str(e)
    assert str(e).startswith(f"{path}: {prim}.{attr}: "), str(e)
    count("non-finite attribute -> StageError", 1)


@pytest.mark.parametrize("value", BAD, ids=["nan", "inf", "-inf"])
def test_non_finite_light_transform_is_a_stage_error(tmp_path, value):
    path = tmp_path / "bad.usda"
    stage = penumbra_stage(path)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Light")).AddTranslateOp(opSuffix="bad").Set(Gf.Vec3d(value, 0, 0))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    assert err.value.prim == "/World/Light"


@pytest.mark.parametrize("value", BAD, ids=["nan", "inf", "-inf"])
def test_non_finite_camera_transform_is_a_stage_error(tmp_path, value):
    path = tmp_path / "bad.usda"
    stage = penumbra_stage(path)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Camera")).AddTranslateOp(opSuffix="bad").Set(Gf.Vec3d(value, 0, 0))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    assert err.value.prim == "/World/Camera"


def test_non_finite_mesh_transform_is_a_stage_error(tmp_path):
    """(The reference behaviour the two tests above ask of lights and cameras.)"""
    path = tmp_path / "bad.usda"
    stage = penumbra_stage(path)
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Card")).AddTranslateOp(opSuffix="bad").Set(Gf.Vec3d(NAN, 0, 0))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    assert err.value.prim == "/World/Card"


# --------------------------------------------------------------------------------------
# NaN texels
# --------------------------------------------------------------------------------------
def _bad_texture(tmp_path, shape=(8, 16), n_nan=3, n_inf=2):
    img = np.full(shape + (3,), 0.5)
    flat = img.reshape(-1, 3)
    flat[:n_nan, 1] = np.nan
    flat[n_nan:n_nan + n_inf, 0] = np.inf
    return write_image(tmp_path / "bad.exr", img), n_nan + n_inf


def test_nan_texels_in_a_rect_light_texture_are_an_error_with_their_count(tmp_path):
    tex, bad = _bad_texture(tmp_path)
    path = tmp_path / "rect.usda"
    stage = penumbra_stage(path)
    UsdLux.RectLight(stage.GetPrimAtPath("/World/Light")).CreateTextureFileAttr(Sdf.AssetPath(tex))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    assert (err.value.prim, err.value.attribute) == ("/World/Light", "inputs:texture:file")
    assert f"{bad} texel" in str(err.value) and "bad.exr" in str(err.value)


def test_nan_texels_in_a_dome_texture_are_an_error_with_their_count(tmp_path):
    tex, bad = _bad_texture(tmp_path)
    path = tmp_path / "dome.usda"
    stage = penumbra_stage(path)
    UsdLux.DomeLight.Define(stage, "/World/Dome").CreateTextureFileAttr(Sdf.AssetPath(tex))
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path)
    assert (err.value.prim, err.value.attribute) == ("/World/Dome", "inputs:texture:file")
    assert f"{bad} texel" in str(err.value)


def test_nan_texels_in_a_material_texture_become_zero_with_a_warning(tmp_path):
    """renderer/textures.py: non-finite texels are replaced by 0 at load, the count is reported
    once per file; the render goes on and stays finite."""
    tex, bad = _bad_texture(tmp_path)
    clean = write_image(tmp_path / "clean.exr", np.full((8, 16, 3), 0.5))
    images = {}
    for name, f in (("bad", tex), ("clean", clean)):
        path = tmp_path / f"{name}.usda"
        stage = penumbra_stage(path)
        mat = textured_material(stage, "/World/Looks/Tex", f)
        floor = stage.GetPrimAtPath("/World/Floor")
        UsdShade.MaterialBindingAPI(floor).Bind(mat)
        add_st(UsdGeom.Mesh(floor), [(0, 0), (0, 1), (1, 1), (1, 0)])
        stage.GetRootLayer().Save()
        r = _render(path)
        img = r.film.mean()
        assert np.all(np.isfinite(img)) and r.film.nonfinite_dropped == 0
        images[name] = img
        if name == "bad":
            assert any("bad.exr" in w and f"{bad} texel" in w for w in r.warnings), r.warnings
        else:
            assert not any("texel" in w for w in r.warnings)
    # The zeroed texels darken the floor somewhere but nowhere make it brighter or NaN.
    assert np.all(images["bad"] <= images["clean"] + 1e-6)
