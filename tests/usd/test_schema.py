"""usd_schemas: the committed generated files are up to date, and the registered schema is right."""

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

import usd_schemas
from renderer.adaptive import DEFAULT_MIN_SPP
from renderer.usd import estimator_api

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _types(plug_info_path: str) -> dict:
    with open(plug_info_path) as f:
        text = f.read()
    # plugInfo.json allows '#' comment lines (the generator writes a header); JSON does not
    body = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    (plugin,) = json.loads(body)["Plugins"]
    return plugin


def test_generated_files_are_up_to_date(tmp_path):
    pytest.importorskip("jinja2")
    shutil.copy(os.path.join(usd_schemas.PLUGIN_DIR, "schema.usda"), tmp_path / "schema.usda")
    out = subprocess.run([sys.executable, "-m", "pxr.Usd.usdGenSchema", str(tmp_path / "schema.usda"),
                          str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    fresh = (tmp_path / "generatedSchema.usda").read_text()
    with open(os.path.join(usd_schemas.PLUGIN_DIR, "generatedSchema.usda")) as f:
        committed = f.read()
    assert fresh == committed, "regenerate: python -m pxr.Usd.usdGenSchema usd_schemas/schema.usda usd_schemas"
    new, old = _types(str(tmp_path / "plugInfo.json")), _types(os.path.join(usd_schemas.PLUGIN_DIR, "plugInfo.json"))
    assert new["Info"]["Types"] == old["Info"]["Types"]
    # the committed plugInfo carries the path edits that make a codeless plugin loadable
    assert "LibraryPath" not in old and old["ResourcePath"] == "." and old["Root"] == "."
    assert old["Name"] == "illum" and old["Type"] == "resource"


def test_registered_schema_matches_the_reader_fallbacks():
    # fresh interpreter: registration must precede the first schema-registry use
    script = textwrap.dedent("""
        import json
        import usd_schemas
        from pxr import Usd, UsdGeom, UsdLux, Tf
        reg = Usd.SchemaRegistry()
        out = {}
        for name in ("IllumLightAPI", "IllumRenderSettingsAPI"):
            pd = reg.FindAppliedAPIPrimDefinition(name)
            out[name] = {p: [str(pd.GetAttributeFallbackValue(p)),
                             [str(t) for t in (pd.GetPropertyMetadata(p, "allowedTokens") or [])],
                             str(pd.GetSchemaAttributeSpec(p).typeName)]
                         for p in pd.GetPropertyNames()}
        stage = Usd.Stage.CreateInMemory()
        light = UsdLux.RectLight.Define(stage, "/L").GetPrim()
        ball = UsdGeom.Sphere.Define(stage, "/B").GetPrim()
        out["can_apply"] = [bool(light.CanApplyAPI("IllumLightAPI")), bool(ball.CanApplyAPI("IllumLightAPI"))]
        out["tftype"] = str(Tf.Type.FindByName("IllumIllumLightAPI"))
        print(json.dumps(out))
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    light = got["IllumLightAPI"]
    assert set(light) == {"illum:estimator", "illum:cv:alpha", "illum:samples", "illum:mis:heuristic",
                          "illum:dome:irradiance"}
    assert light["illum:estimator"] == ["mis", list(estimator_api.ESTIMATORS), "token"]
    assert light["illum:cv:alpha"] == ["averageVisibilityUnbiased", list(estimator_api.CV_ALPHAS), "token"]
    assert light["illum:mis:heuristic"] == ["power", list(estimator_api.MIS_HEURISTICS), "token"]
    assert light["illum:samples"][0] == "1" and light["illum:samples"][2] == "int"
    assert light["illum:dome:irradiance"][2] == "asset"
    rs = got["IllumRenderSettingsAPI"]
    assert rs == {"illum:lightSampler": ["auto", list(estimator_api.LIGHT_SAMPLERS), "token"],
                  "illum:estimator": ["mis", list(estimator_api.ESTIMATORS), "token"],
                  "illum:pixelFilter": ["gaussian", ["gaussian", "box", "blackman-harris"], "token"],
                  "illum:pixelFilter:width": ["None", [], "float"],
                  "illum:pixelFilter:mode": ["splat", ["splat", "importance"], "token"],
                  "illum:alpha:domeTransparent": ["False", [], "bool"],
                  "illum:adaptive:noiseThreshold": ["0.0", [], "float"],
                  "illum:adaptive:minSpp": [str(DEFAULT_MIN_SPP), [], "int"]}
    assert got["can_apply"] == [True, False]
    assert "IllumIllumLightAPI" in got["tftype"]


def test_register_is_idempotent():
    usd_schemas.register()
    usd_schemas.register()
    assert os.path.isfile(os.path.join(usd_schemas.PLUGIN_DIR, "plugInfo.json"))


@pytest.mark.parametrize("pxr_first", [False, True])
def test_import_renderer_registers_the_schemas(pxr_first):
    """`import renderer` alone (not renderer.usd) makes USD know the schemas, whether pxr is
    loaded before it or after; without it (the control) USD does not."""
    probe = ("from pxr import Usd\n"
             "print(Usd.SchemaRegistry().FindAppliedAPIPrimDefinition('IllumLightAPI') is not None)\n")
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    for imports, expected in ((["import renderer"], "True"), ([], "False")):
        lines = (["from pxr import Usd"] if pxr_first else []) + imports
        proc = subprocess.run([sys.executable, "-c", "\n".join(lines) + "\n" + probe], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip().splitlines()[-1] == expected
