"""`illum preconvolve --stage --light`: authoring illum:dome:irradiance through Sdf (issue #6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdLux

from renderer.cli import main
from renderer.errors import StageError
from renderer.usd import load_stage
from renderer.usd.preconvolve_author import author_dome_irradiance

from .conftest import write_image


def env(tmp_path, name="env.exr") -> str:
    img = np.ones((16, 32, 3), np.float32)
    img[3, 5] = 40.0
    return write_image(tmp_path / name, img)


def make_stage(path, texture="./env.exr") -> str:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    dome = UsdLux.DomeLight.Define(stage, "/World/Env")
    dome.CreateTextureFileAttr(texture)
    dome.CreateIntensityAttr(2.0)
    dome.AddRotateYOp().Set(30.0)
    UsdGeom.Sphere.Define(stage, "/World/Ball").CreateRadiusAttr(0.5)
    UsdLux.RectLight.Define(stage, "/World/Key").CreateWidthAttr(3.0)
    UsdGeom.Camera.Define(stage, "/Cam")
    stage.GetRootLayer().Save()
    return str(path)


def without_line(text: str, needle: str) -> list[str]:
    """text's lines minus the one line holding needle (asserted unique)."""
    lines = text.splitlines()
    hits = [ln for ln in lines if needle in ln]
    assert len(hits) == 1, hits
    return [ln for ln in lines if needle not in ln]


def test_cli_authors_relative_asset_and_leaves_the_rest(tmp_path, capsys):
    src = env(tmp_path)
    stage_path = make_stage(tmp_path / "scene.usda")
    before = Path(stage_path).read_text()
    out = tmp_path / "maps" / "env_irr.exr"
    argv = ["preconvolve", src, "-o", str(out), "--size", "8", "--stage", stage_path, "--light", "/World/Env"]
    assert main(argv) == 0
    assert "authored illum:dome:irradiance" in capsys.readouterr().err
    after = Path(stage_path).read_text()
    assert "asset illum:dome:irradiance = @./maps/env_irr.exr@" in after
    assert without_line(after, "illum:dome:irradiance") == before.splitlines()
    # The reader resolves it (anchored to the layer) for the renderer.
    desc = load_stage(stage_path)
    dome = next(d for d in desc.lights if d.path == "/World/Env")
    assert dome.estimator.dome_irradiance == str(out)
    # Re-running replaces the value in place (one attribute line, still).
    author_dome_irradiance(stage_path, "/World/Env", str(tmp_path / "other.exr"))
    text = Path(stage_path).read_text()
    assert without_line(text, "illum:dome:irradiance") == before.splitlines()
    assert "@./other.exr@" in text


def test_authors_in_the_defining_sublayer(tmp_path):
    sub = Sdf.Layer.CreateNew(str(tmp_path / "lights.usda"))
    root = Sdf.Layer.CreateNew(str(tmp_path / "shot.usda"))
    root.subLayerPaths.append("./lights.usda")
    root.Save()
    stage = Usd.Stage.Open(root)
    stage.SetEditTarget(sub)
    UsdLux.DomeLight.Define(stage, "/Env").CreateTextureFileAttr("./env.exr")
    stage.SetEditTarget(root)
    stage.OverridePrim("/Env").CreateAttribute("inputs:intensity", Sdf.ValueTypeNames.Float).Set(3.0)
    sub.Save()
    root.Save()
    root_before, sub_before = Path(root.realPath).read_text(), Path(sub.realPath).read_text()
    res = author_dome_irradiance(root.realPath, "/Env", str(tmp_path / "env_irr.exr"))
    assert res["layer"] == sub.realPath and res["value"] == "./env_irr.exr" and not res["warnings"]
    assert Path(root.realPath).read_text() == root_before
    assert without_line(Path(sub.realPath).read_text(), "illum:dome:irradiance") == sub_before.splitlines()


def test_referenced_dome_gets_an_over_in_the_root_layer(tmp_path):
    asset = Usd.Stage.CreateNew(str(tmp_path / "rig.usda"))
    UsdLux.DomeLight.Define(asset, "/Rig").CreateTextureFileAttr("./env.exr")
    asset.SetDefaultPrim(asset.GetPrimAtPath("/Rig"))
    asset.GetRootLayer().Save()
    shot = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    shot.DefinePrim("/Env").GetReferences().AddReference("./rig.usda")
    shot.GetRootLayer().Save()
    rig_before = Path(tmp_path / "rig.usda").read_text()
    res = author_dome_irradiance(str(tmp_path / "shot.usda"), "/Env", str(tmp_path / "irr.exr"))
    assert res["layer"] == str(tmp_path / "shot.usda")
    assert Path(tmp_path / "rig.usda").read_text() == rig_before  # the referenced asset is untouched
    assert Usd.Stage.Open(str(tmp_path / "shot.usda")).GetPrimAtPath("/Env").GetAttribute(
        "illum:dome:irradiance").Get().path == "./irr.exr"


def test_not_a_dome_or_missing_prim(tmp_path, capsys):
    src = env(tmp_path)
    stage_path = make_stage(tmp_path / "scene.usda")
    before = Path(stage_path).read_text()
    with pytest.raises(StageError, match="not a DomeLight"):
        author_dome_irradiance(stage_path, "/World/Key", str(tmp_path / "x.exr"))
    with pytest.raises(StageError, match="no such prim"):
        author_dome_irradiance(stage_path, "/World/Nope", str(tmp_path / "x.exr"))
    out = tmp_path / "irr.exr"
    assert main(["preconvolve", src, "-o", str(out), "--stage", stage_path, "--light", "/World/Ball"]) == 2
    err = capsys.readouterr().err
    assert "/World/Ball" in err and "not a DomeLight" in err
    assert not out.exists()  # checked before computing anything
    assert Path(stage_path).read_text() == before


def test_warns_when_the_dome_uses_another_texture(tmp_path):
    src = env(tmp_path, "other.exr")  # the map that was convolved
    write_image(tmp_path / "env.exr", np.full((16, 32, 3), 2.0))  # the dome's own ./env.exr differs
    stage_path = make_stage(tmp_path / "scene.usda")
    from renderer.preconvolve import file_sha256

    res = author_dome_irradiance(stage_path, "/World/Env", str(tmp_path / "irr.exr"), source_hash=file_sha256(src))
    assert len(res["warnings"]) == 1 and "stale" in res["warnings"][0]
    assert "illum:dome:irradiance" in Path(stage_path).read_text()  # authored all the same
