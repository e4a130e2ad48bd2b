"""One policy for missing or unreadable assets: by default a warning per file and the fallback
(the arc skipped, for composition arcs); under --strict an error (exit 2) naming the layer, the
prim and the attribute -- for sublayers, references, payloads, a sublayer cycle, textures and
IES files alike."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from pxr import Sdf, UsdLux

from renderer.errors import StageError
from renderer.usd import load_stage
from tests.stage_builders import quad_light_stage

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _write(path, text):
    path.write_text("#usda 1.0\n" + text)
    return str(path)


@pytest.fixture
def arcs(tmp_path):
    """A renderable stage (camera, floor, light) whose root layer sublayers the given text."""
    base = str(tmp_path / "base.usda")
    quad_light_stage(base)

    def make(extra_layer_meta: str = "", body: str = "") -> str:
        subs = ", ".join(f"@{s}@" for s in ["./base.usda", *filter(None, [extra_layer_meta])])
        return _write(tmp_path / "root.usda", f'(\n    renderSettingsPrimPath = "/Render/Settings"\n'
                                              f"    subLayers = [{subs}]\n)\n{body}")

    return tmp_path, make


CASES = [
    # (sublayer entry, prim text, expected (layer file name, prim, attribute), words)
    ("./missing_sub.usda", "", ("root.usda", "", "subLayers"), "missing_sub.usda"),
    ("", 'def Xform "A" ( references = @./missing_ref.usda@ ) {}\n', ("root.usda", "/A", "references"),
     "missing_ref.usda"),
    ("", 'def Xform "B" ( payload = @./missing_pay.usda@ ) {}\n', ("root.usda", "/B", "payload"),
     "missing_pay.usda"),
    ("", 'def Xform "C" ( references = @./garbage.usda@ ) {}\n', ("root.usda", "/C", "references"),
     "garbage.usda"),
]


@pytest.mark.parametrize("sub, body, where, words", CASES)
def test_composition_arcs(arcs, sub, body, where, words):
    tmp, make = arcs
    (tmp / "garbage.usda").write_text("this is not a USD layer\n")
    stage = make(sub, body)
    d = load_stage(stage)  # default: the arc is skipped, with one warning naming where it is
    hits = [w for w in d.warnings if words in w]
    prim_attr = f"{where[1]}.{where[2]}" if where[1] else where[2]
    assert len(hits) == 1 and str(tmp / where[0]) in hits[0] and prim_attr in hits[0], d.warnings
    with pytest.raises(StageError, match=words) as err:
        load_stage(stage, strict=True)
    assert (err.value.file, err.value.prim, err.value.attribute) == (str(tmp / where[0]), where[1], where[2])


def test_sublayer_cycle_names_the_layer_closing_it(arcs):
    tmp, make = arcs
    _write(tmp / "cyc_a.usda", "(\n    subLayers = [@./cyc_b.usda@]\n)\n")
    _write(tmp / "cyc_b.usda", "(\n    subLayers = [@./cyc_a.usda@]\n)\n")
    stage = make("./cyc_a.usda")
    d = load_stage(stage)
    assert any("cycle" in w for w in d.warnings)
    with pytest.raises(StageError, match="cycle") as err:
        load_stage(stage, strict=True)
    assert (err.value.file, err.value.attribute) == (str(tmp / "cyc_b.usda"), "subLayers")


def test_clean_stage_is_clean_under_strict(arcs):
    _tmp, make = arcs
    d = load_stage(make(), strict=True)
    assert d.warnings == [] and d.strict


def test_light_texture_policy(tmp_path):
    stage_path = str(tmp_path / "s.usda")
    stage = quad_light_stage(stage_path)
    UsdLux.RectLight(stage.GetPrimAtPath("/World/Light")).CreateTextureFileAttr(Sdf.AssetPath("./gone.exr"))
    stage.GetRootLayer().Save()
    d = load_stage(stage_path)
    light = next(l for l in d.lights if l.path == "/World/Light")
    assert light.texture_file == "" and light.texture_data is None
    hits = [w for w in d.warnings if "gone.exr" in w]
    assert len(hits) == 1 and "untextured" in hits[0] and "/World/Light.inputs:texture:file" in hits[0]
    with pytest.raises(StageError) as err:
        load_stage(stage_path, strict=True)
    assert (err.value.file, err.value.prim, err.value.attribute) == (stage_path, "/World/Light",
                                                                    "inputs:texture:file")


def test_cli_strict_exits_2_and_default_renders(tmp_path):
    stage_path = str(tmp_path / "s.usda")
    quad_light_stage(stage_path)
    root = _write(tmp_path / "root.usda", '(\n    subLayers = [@./s.usda@, @./nowhere.usda@]\n)\n')

    def illum(*args):
        return subprocess.run([sys.executable, "-m", "renderer.cli", "render", root, "-o", tmp_path / "o.exr",
                               "--res", "8", "8", "--spp", "1", *args], capture_output=True, text=True, cwd=ROOT,
                              timeout=600)

    r = illum("--strict")
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"illum: error: {root}: subLayers: composition error")
    assert "nowhere.usda" in r.stderr
    r = illum()
    assert r.returncode == 0, r.stderr
    assert "nowhere.usda" in r.stderr and "warning" in r.stderr
