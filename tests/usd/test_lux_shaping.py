"""UsdLux ShapingAPI / ShadowAPI reading: values, fallbacks, validation errors and warnings."""

import os

import pytest
from pxr import Gf, Sdf, UsdLux

from renderer.errors import StageError
from renderer.usd import load_stage

from .helpers import new_stage, read

IES = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "stages", "ies", "narrow_spot.ies"))


def _light(d, path):
    found = [light for light in d.lights if light.path == path]
    assert len(found) == 1, [light.path for light in d.lights]
    return found[0]


def _spot(stage, path="/Spot"):
    light = UsdLux.DiskLight.Define(stage, path)
    return light, UsdLux.ShapingAPI.Apply(light.GetPrim())


def test_shaping_values_and_fallbacks(stage):
    _, api = _spot(stage)
    api.CreateShapingFocusAttr(3.0)
    api.CreateShapingFocusTintAttr(Gf.Vec3f(0.5, 0.25, 0.0))
    api.CreateShapingConeSoftnessAttr(0.4)
    api.CreateShapingIesFileAttr(Sdf.AssetPath(IES))
    api.CreateShapingIesAngleScaleAttr(-0.5)
    api.CreateShapingIesNormalizeAttr(True)
    sh = _light(read(stage), "/Spot").shaping
    assert (sh.focus, sh.focus_tint, sh.cone_softness) == (3.0, (0.5, 0.25, 0.0), pytest.approx(0.4))
    assert sh.cone_angle == 90.0                               # the schema's fallback
    assert sh.ies_file == IES and sh.ies_angle_scale == -0.5 and sh.ies_normalize
    assert sh.ies_profile is not None and sh.ies_profile.version == "LM-63-2002"


def test_no_api_no_shaping_but_authored_inputs_count(stage):
    UsdLux.DiskLight.Define(stage, "/Plain")
    light = UsdLux.SphereLight.Define(stage, "/Authored")
    # The UsdLux user doc's CylinderLight example authors a shaping input without the API.
    light.GetPrim().CreateAttribute("inputs:shaping:cone:angle", Sdf.ValueTypeNames.Float).Set(45.0)
    d = read(stage)
    assert _light(d, "/Plain").shaping is None and _light(d, "/Plain").shadow is None
    sh = _light(d, "/Authored").shaping
    assert sh.cone_angle == 45.0 and sh.focus == 0.0 and sh.cone_softness == 0.0


@pytest.mark.parametrize("attr, value, fragment", [
    ("inputs:shaping:cone:angle", 200.0, "outside [0, 180]"),
    ("inputs:shaping:cone:angle", -1.0, "outside [0, 180]"),
    ("inputs:shaping:focus", float("nan"), "must be finite"),
    ("inputs:shaping:cone:softness", float("inf"), "must be finite"),
    ("inputs:shaping:ies:angleScale", float("nan"), "must be finite"),
])
def test_bad_shaping_values_are_errors(stage, attr, value, fragment):
    light, api = _spot(stage)
    light.GetPrim().GetAttribute(attr).Set(value) if light.GetPrim().GetAttribute(attr) else \
        light.GetPrim().CreateAttribute(attr, Sdf.ValueTypeNames.Float).Set(value)
    with pytest.raises(StageError) as exc:
        read(stage)
    msg = str(exc.value)
    assert f"/Spot.{attr}" in msg and fragment in msg


def test_negative_focus_tint_is_an_error(stage):
    _, api = _spot(stage)
    api.CreateShapingFocusTintAttr(Gf.Vec3f(0.5, -0.1, 0.0))
    with pytest.raises(StageError, match=r"/Spot\.inputs:shaping:focusTint"):
        read(stage)


def test_softness_clamped_and_negative_focus_ignored_with_warnings(stage):
    _, api = _spot(stage)
    api.CreateShapingConeSoftnessAttr(1.7)
    api.CreateShapingFocusAttr(-2.0)
    d = read(stage)
    sh = _light(d, "/Spot").shaping
    assert sh.cone_softness == 1.0 and sh.focus == -2.0        # the renderer ignores focus < 0
    assert any("softness 1.7 is clamped to 1" in w for w in d.warnings)
    assert any("shaping:focus -2 < 0 is ignored" in w for w in d.warnings)


def test_missing_ies_file_warns_or_fails_under_strict(stage):
    """The missing-asset policy: by default one warning and an unshaped light; --strict: an error
    naming the layer, the prim and the attribute."""
    _, api = _spot(stage)
    api.CreateShapingIesFileAttr(Sdf.AssetPath("/nonexistent/profile.ies"))
    d = read(stage)
    assert _light(d, "/Spot").shaping.ies_profile is None and _light(d, "/Spot").shaping.ies_file == ""
    hits = [w for w in d.warnings if "profile.ies" in w]
    assert len(hits) == 1 and "/Spot.inputs:shaping:ies:file: file not found" in hits[0]
    layer = stage.GetRootLayer().identifier
    with pytest.raises(StageError, match=r"/Spot\.inputs:shaping:ies:file: file not found") as exc:
        read(stage, strict=True)
    assert exc.value.file == layer


def test_malformed_ies_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.ies"
    bad.write_text("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 0\n0 45 90\n0\n100 5O 0\n")
    stage_path = tmp_path / "s.usda"
    stage = new_stage()
    _, api = _spot(stage)
    api.CreateShapingIesFileAttr(Sdf.AssetPath("bad.ies"))
    stage.GetRootLayer().Export(str(stage_path))
    with pytest.raises(StageError) as exc:
        load_stage(str(stage_path), strict=True)
    msg = str(exc.value)
    assert "/Spot.inputs:shaping:ies:file" in msg and str(bad) in msg and "line 7" in msg and "'5O'" in msg
    assert exc.value.file == str(stage_path)
    # By default: the same words as one warning, and the light unshaped by IES.
    d = load_stage(str(stage_path))
    assert _light(d, "/Spot").shaping.ies_profile is None
    hits = [w for w in d.warnings if str(bad) in w]
    assert len(hits) == 1 and "line 7" in hits[0] and "'5O'" in hits[0]


def test_shaping_on_distant_light_warns(stage):
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    UsdLux.ShapingAPI.Apply(sun.GetPrim()).CreateShapingConeAngleAttr(10.0)
    d = read(stage)
    assert _light(d, "/Sun").shaping is None
    assert any("ShapingAPI on a distant light is ignored" in w for w in d.warnings)


# ------------------------------------------------------------------ ShadowAPI
def test_shadow_values(stage):
    light = UsdLux.SphereLight.Define(stage, "/Key")
    api = UsdLux.ShadowAPI.Apply(light.GetPrim())
    api.CreateShadowColorAttr(Gf.Vec3f(0.1, 0.2, 0.3))
    api.CreateShadowDistanceAttr(2.0)
    api.CreateShadowFalloffAttr(0.5)
    api.CreateShadowFalloffGammaAttr(2.0)
    sd = _light(read(stage), "/Key").shadow
    assert sd.enable and sd.color == pytest.approx((0.1, 0.2, 0.3))
    assert (sd.distance, sd.falloff, sd.falloff_gamma) == (2.0, 0.5, 2.0)


def test_default_shadow_api_reads_as_none(stage):
    light = UsdLux.SphereLight.Define(stage, "/Key")
    UsdLux.ShadowAPI.Apply(light.GetPrim())
    assert _light(read(stage), "/Key").shadow is None


def test_shadow_falloff_clamped_and_ignored_without_distance(stage):
    a = UsdLux.ShadowAPI.Apply(UsdLux.SphereLight.Define(stage, "/A").GetPrim())
    a.CreateShadowDistanceAttr(1.0)
    a.CreateShadowFalloffAttr(3.0)
    b = UsdLux.ShadowAPI.Apply(UsdLux.SphereLight.Define(stage, "/B").GetPrim())
    b.CreateShadowFalloffAttr(0.5)
    b.CreateShadowEnableAttr(False)
    d = read(stage)
    assert _light(d, "/A").shadow.falloff == 1.0
    assert _light(d, "/B").shadow.falloff == -1.0 and not _light(d, "/B").shadow.enable
    assert any("exceeds shadow:distance" in w for w in d.warnings)
    assert any("no effect without a shadow:distance" in w for w in d.warnings)


@pytest.mark.parametrize("attr, value, fragment", [
    ("inputs:shadow:falloffGamma", -1.0, "negative"),
    ("inputs:shadow:distance", float("nan"), "must be finite"),
])
def test_bad_shadow_values(stage, attr, value, fragment):
    light = UsdLux.SphereLight.Define(stage, "/Key")
    UsdLux.ShadowAPI.Apply(light.GetPrim())
    light.GetPrim().GetAttribute(attr).Set(value)
    with pytest.raises(StageError) as exc:
        read(stage)
    assert f"/Key.{attr}" in str(exc.value) and fragment in str(exc.value)


def test_light_filters_warn_once_per_light(stage):
    UsdLux.LightFilter.Define(stage, "/Filter")
    for path in ("/A", "/B"):
        UsdLux.SphereLight.Define(stage, path).GetPrim().CreateRelationship("light:filters").AddTarget("/Filter")
    d = read(stage)
    msgs = [w for w in d.warnings if "light filters" in w]
    assert len(msgs) == 2 and any(m.startswith("/A") for m in msgs) and any(m.startswith("/B") for m in msgs)
