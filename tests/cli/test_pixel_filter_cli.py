"""`illum render --pixel-filter* ` and IllumRenderSettingsAPI's illum:pixelFilter attributes: each
filter renders through the CLI (EXR read back with OpenImageIO), the stage's opinion applies
unless a flag overrides it, and bad values exit 2 naming the flag or attribute."""

import json
import os

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, Usd

from renderer.cli import main
from tests.stage_builders import quad_light_stage

from .test_cli import illum

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _stage(tmp_path, **attrs):
    path = tmp_path / "q.usda"
    quad_light_stage(path, res=(24, 16))
    if attrs:
        stage = Usd.Stage.Open(str(path))
        prim = stage.GetPrimAtPath("/Render/Settings")
        assert prim, "quad_light_stage's RenderSettings moved"
        prim.AddAppliedSchema("IllumRenderSettingsAPI")
        for name, (type_name, value) in attrs.items():
            prim.CreateAttribute(name, type_name, variability=Sdf.VariabilityUniform).Set(value)
        stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("name,width,mode", [("gaussian", None, "splat"), ("box", "1.0", "importance"),
                                             ("blackman-harris", "2", "splat")])
def test_each_filter_renders_through_the_cli(tmp_path, name, width, mode):
    stage = _stage(tmp_path)
    out, stats = tmp_path / "o.exr", tmp_path / "s.json"
    args = ["render", stage, "-o", out, "--spp", 4, "--stats", stats, "--quiet", "--pixel-filter", name,
            "--pixel-filter-mode", mode] + (["--pixel-filter-width", width] if width else [])
    r = illum(*args)
    assert r.returncode == 0, r.stderr
    inp = oiio.ImageInput.open(str(out))
    spec = inp.spec()
    img = inp.read_image(oiio.FLOAT)
    inp.close()
    assert (spec.width, spec.height) == (24, 16)
    assert np.all(np.isfinite(img)) and img.max() > 0.0
    radius = float(width) if width else 1.5
    assert spec.getattribute("illum:pixelFilter") == f"{name} {radius:g} {mode}"
    s = json.loads(stats.read_text())
    assert s["pixel_filter"] == {"name": name, "radius": radius, "mode": mode}
    assert s["spp"] == 4 and s["nonfinite_dropped"] == 0


def test_render_settings_choose_the_filter_and_flags_override(tmp_path):
    from renderer.render import RenderOptions, render

    stage = str(_stage(tmp_path, **{"illum:pixelFilter": (Sdf.ValueTypeNames.Token, "box"),
                                   "illum:pixelFilter:width": (Sdf.ValueTypeNames.Float, 1.25),
                                   "illum:pixelFilter:mode": (Sdf.ValueTypeNames.Token, "importance")}))
    r = render(stage, RenderOptions(spp=1, threads=1))
    assert r.stats["pixel_filter"] == {"name": "box", "radius": 1.25, "mode": "importance"}
    assert r.film.mode == "importance"
    # A flag's filter drops the stage's width (it belongs to the stage's filter); its mode wins.
    r = render(stage, RenderOptions(spp=1, threads=1, pixel_filter="gaussian", pixel_filter_mode="splat"))
    assert r.stats["pixel_filter"] == {"name": "gaussian", "radius": 1.5, "mode": "splat"}
    assert r.film.mode == "splat"


@pytest.mark.parametrize("flags,named", [
    (["--pixel-filter", "mitchell"], "pixel_filter: must be one of gaussian, box, blackman-harris, got 'mitchell'"),
    (["--pixel-filter-width", "0.2"], "pixel_filter_width: must be a number in [0.5, 8], got 0.2"),
    (["--pixel-filter-width", "nan"], "pixel_filter_width: must be finite"),
    (["--pixel-filter-mode", "both"], "pixel_filter_mode: must be one of splat, importance, got 'both'"),
])
def test_bad_flags_exit_2_naming_the_flag(tmp_path, capsys, flags, named):
    stage = _stage(tmp_path)
    assert main(["render", str(stage), "-o", str(tmp_path / "o.exr"), "--spp", "1", "--quiet", *flags]) == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("attr,type_name,value,named", [
    ("illum:pixelFilter", Sdf.ValueTypeNames.Token, "sinc", "/Render/Settings.illum:pixelFilter: 'sinc'"),
    ("illum:pixelFilter:width", Sdf.ValueTypeNames.Float, 20.0,
     "/Render/Settings.illum:pixelFilter:width: radius 20.0 px is outside [0.5, 8]"),
    ("illum:pixelFilter:mode", Sdf.ValueTypeNames.Token, "gather", "/Render/Settings.illum:pixelFilter:mode"),
])
def test_bad_render_settings_exit_2_naming_the_attribute(tmp_path, capsys, attr, type_name, value, named):
    stage = _stage(tmp_path, **{attr: (type_name, value)})
    assert main(["render", str(stage), "-o", str(tmp_path / "o.exr"), "--spp", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert named in err and "q.usda" in err
