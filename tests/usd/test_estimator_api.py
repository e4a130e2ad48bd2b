"""IllumLightAPI attributes on lights: values, fallbacks, and every error class."""

import os
import subprocess
import sys
import textwrap

import pytest
from pxr import Sdf, UsdGeom, UsdLux

from renderer.description import EstimatorSettings
from renderer.errors import StageError
from renderer.usd import load_stage

from .helpers import new_stage, read

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _light_with_api(stage, path="/Key", schema=UsdLux.RectLight):
    prim = schema.Define(stage, path).GetPrim()
    prim.ApplyAPI("IllumLightAPI")
    return prim


def test_unauthored_attributes_take_schema_fallbacks(stage):
    _light_with_api(stage)
    UsdLux.SphereLight.Define(stage, "/NoApi")
    d = read(stage)
    assert all(light.estimator == EstimatorSettings() for light in d.lights)
    assert EstimatorSettings() == EstimatorSettings("mis", "averageVisibilityUnbiased", 1, "power", "")


def test_authored_attributes(stage):
    prim = _light_with_api(stage)
    prim.GetAttribute("illum:estimator").Set("controlVariate")
    prim.GetAttribute("illum:cv:alpha").Set("averageVisibility")
    prim.GetAttribute("illum:samples").Set(4)
    prim.GetAttribute("illum:mis:heuristic").Set("balance")
    d = read(stage)
    assert d.lights[0].estimator == EstimatorSettings("controlVariate", "averageVisibility", 4, "balance", "",
                                                      estimator_authored=True)
    assert not d.warnings


@pytest.mark.parametrize("attr,value", [
    ("illum:estimator", "guess"),
    ("illum:cv:alpha", "optimal"),
    ("illum:mis:heuristic", "maximum"),
])
def test_token_outside_allowed_list(stage, attr, value):
    _light_with_api(stage).GetAttribute(attr).Set(value)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Key", attr)
    assert value in str(err.value)


@pytest.mark.parametrize("samples", [0, -3])
def test_samples_below_one(stage, samples):
    _light_with_api(stage).GetAttribute("illum:samples").Set(samples)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Key", "illum:samples")


def test_light_api_on_a_non_light(stage):
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball").GetPrim()
    ball.AddAppliedSchema("IllumLightAPI")  # ApplyAPI would refuse: apiSchemaCanOnlyApplyTo
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/World/Ball", "apiSchemas")
    assert "IllumLightAPI" in str(err.value)


def test_average_visibility_alpha_with_one_sample_warns_once(stage):
    for k in range(3):
        _light_with_api(stage, f"/L{k}").GetAttribute("illum:estimator").Set("controlVariate")
    d = read(stage)
    assert all(light.estimator.cv_alpha == "averageVisibilityUnbiased" for light in d.lights)  # kept
    warns = [w for w in d.warnings if "illum:samples >= 2" in w]
    assert len(warns) == 1 and "2 more" in warns[0]


def test_no_alpha_warning_for_other_estimators_or_enough_samples(stage):
    _light_with_api(stage, "/Mis")  # estimator mis with fallback alpha: no warning
    cv = _light_with_api(stage, "/Cv")
    cv.GetAttribute("illum:estimator").Set("controlVariate")
    cv.GetAttribute("illum:samples").Set(2)
    assert not read(stage).warnings


def test_dome_irradiance_resolved(tmp_path):
    (tmp_path / "irr.exr").write_bytes(b"x")
    stage = new_stage()
    prim = _light_with_api(stage, "/Dome", UsdLux.DomeLight_1)
    prim.GetAttribute("illum:dome:irradiance").Set(Sdf.AssetPath("irr.exr"))
    path = tmp_path / "dome.usda"
    stage.GetRootLayer().Export(str(path))
    d = load_stage(str(path))
    assert d.lights[0].estimator.dome_irradiance == os.path.join(str(tmp_path), "irr.exr")


def test_dome_irradiance_missing_file(stage):
    prim = _light_with_api(stage, "/Dome", UsdLux.DomeLight)
    prim.GetAttribute("illum:dome:irradiance").Set(Sdf.AssetPath("/nowhere/irr.exr"))
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Dome", "illum:dome:irradiance")


def test_reader_does_not_depend_on_plugin_registration(tmp_path):
    """A process whose schema registry started before the plugin was registered reads the same."""
    stage = new_stage()
    prim = _light_with_api(stage)
    prim.GetAttribute("illum:estimator").Set("ratio")
    prim.GetAttribute("illum:samples").Set(3)
    _light_with_api(stage, "/Plain")
    path = tmp_path / "est.usda"
    stage.GetRootLayer().Export(str(path))
    script = textwrap.dedent(f"""
        from pxr import Usd
        # the schema registry is initialised before illum's plugin gets registered
        assert Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("LightAPI") is not None
        from renderer.usd import load_stage
        # (Where the plugin is found at start-up, as in some installs, the registry knows the
        # schema anyway; the reading below must match in either case.)
        d = load_stage({str(path)!r})
        print(sorted((l.path, l.estimator.estimator, l.estimator.samples, l.estimator.cv_alpha) for l in d.lights))
    """)
    out = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    expect = sorted((light.path, light.estimator.estimator, light.estimator.samples, light.estimator.cv_alpha)
                    for light in load_stage(str(path)).lights)
    assert out.stdout.strip() == str(expect)


# ---------------------------------------------------------------------------------------------
# The stage-wide default estimator (IllumRenderSettingsAPI illum:estimator, --estimator TOKEN)


def _two_light_stage(path, default: str | None):
    """A floor under two rect lights: /World/Authored says lightSampling, /World/Plain says nothing."""
    from pxr import Usd
    from tests.stage_builders import quad_light_stage

    quad_light_stage(path)
    stage = Usd.Stage.Open(str(path))
    authored = UsdLux.RectLight.Define(stage, "/World/Authored")
    UsdGeom.Xformable(authored).AddTranslateOp().Set((0.5, 2.0, 0.0))
    UsdGeom.Xformable(authored).AddRotateXOp().Set(-90.0)
    authored.GetPrim().ApplyAPI("IllumLightAPI")
    authored.GetPrim().GetAttribute("illum:estimator").Set("lightSampling")
    if default is not None:
        rs = stage.GetPrimAtPath("/Render/Settings")
        rs.ApplyAPI("IllumRenderSettingsAPI")
        rs.GetAttribute("illum:estimator").Set(default)
    stage.GetRootLayer().Save()


def _estimators(stats):
    return {li["path"]: li["estimator"] for li in stats["lights"]}


@pytest.mark.parametrize("default", [None, "bsdfSampling"])
def test_render_settings_default_applies_to_unauthored_lights_only(tmp_path, default):
    from renderer.render import RenderOptions, render

    path = tmp_path / "two.usda"
    _two_light_stage(path, default)
    r = render(str(path), RenderOptions(spp=1, max_depth=1, threads=1))
    assert _estimators(r.stats) == {"/World/Light": default or "mis", "/World/Authored": "lightSampling"}
    assert r.stats["default_estimator"] == (default or "mis")


def test_cli_estimator_token_is_the_default_and_star_forces_every_light(tmp_path):
    path = tmp_path / "two.usda"
    _two_light_stage(path, "bsdfSampling")
    out = {}
    for name, flags in (("plain", ["--estimator", "controlVariate"]), ("star", ["--estimator", "*=controlVariate"]),
                        ("one", ["--estimator", "/World/Authored=mis"])):
        stats = tmp_path / f"{name}.json"
        proc = subprocess.run([sys.executable, "-m", "renderer.cli", "render", str(path), "-o", str(tmp_path / f"{name}.exr"),
                               "--spp", "1", "--max-depth", "1", "--res", "8", "8", "--stats", str(stats), *flags],
                              cwd=REPO, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        import json

        out[name] = _estimators(json.loads(stats.read_text()))
    assert out["plain"] == {"/World/Light": "controlVariate", "/World/Authored": "lightSampling"}
    assert out["star"] == {"/World/Light": "controlVariate", "/World/Authored": "controlVariate"}
    assert out["one"] == {"/World/Light": "bsdfSampling", "/World/Authored": "mis"}


def test_bad_render_settings_default_names_the_attribute(tmp_path):
    path = tmp_path / "two.usda"
    _two_light_stage(path, "guess")
    proc = subprocess.run([sys.executable, "-m", "renderer.cli", "render", str(path), "-o", str(tmp_path / "x.exr"),
                           "--spp", "1"], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 2
    assert "/Render/Settings" in proc.stderr and "illum:estimator" in proc.stderr and "guess" in proc.stderr
    assert not (tmp_path / "x.exr").exists()
