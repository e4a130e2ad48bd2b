"""renderer.usd.confine: every file a stage makes the reader open must lie under the allowed
directories (the render service's stage root), whatever kind of asset path leads there."""

from __future__ import annotations

import os
import shutil
import zipfile

import pytest

from renderer.errors import StageError
from renderer.usd import load_stage
from renderer.usd.confine import find_escapes

STAGES = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "stages")

TEX_SHADER = """def Shader "Tex" {{
    uniform token info:id = "UsdUVTexture"
    {decl}
}}"""


@pytest.fixture
def tree(tmp_path):
    """root/ (allowed) with shots/ and a texture; outside/ next to it with a layer, a texture
    and an IES file."""
    root = tmp_path / "root"
    (root / "shots").mkdir(parents=True)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.usda").write_text('#usda 1.0\ndef Xform "Secret" {}\n')
    shutil.copy(os.path.join(STAGES, "textures", "checker.png"), outside / "secret.png")
    shutil.copy(os.path.join(STAGES, "textures", "checker.png"), root / "ok.png")
    (root / "inside.usda").write_text('#usda 1.0\ndef Xform "Inside" {}\n')
    return root, outside


def _stage(root, body: str, header: str = "", name: str = "shots/s.usda") -> str:
    path = root / name
    path.write_text(f"#usda 1.0\n{header}\n{body}\n")
    return str(path)


def _escapes(path, root):
    return [(e.prim, e.field, e.asset) for e in find_escapes(path, [str(root)]).escapes]


@pytest.mark.parametrize("header, body, expected", [
    ('(\n subLayers = [@../../outside/secret.usda@]\n)', "", ("", "subLayers", "../../outside/secret.usda")),
    ("", 'def "R" ( references = @{outside}/secret.usda@ ) {}', ("/R", "references", "{outside}/secret.usda")),
    ("", 'def "P" ( prepend payload = @../../outside/secret.usda@ ) {}',
     ("/P", "payload", "../../outside/secret.usda")),
    # an arc in a variant that is not selected still counts: the check does not depend on selections
    ("", 'def "V" (\n variants = { string v = "a" }\n prepend variantSets = "v"\n) {\n variantSet "v" = {\n'
         ' "a" { }\n "b" ( references = @../../outside/secret.usda@ ) { }\n }\n}',
     ("/V", "references", "../../outside/secret.usda")),
    # a variable expression is judged by its value
    ('(\n expressionVariables = { string DIR = "../../outside" }\n)',
     'def "E" ( references = @`"${DIR}/secret.usda"`@ ) {}', ("/E", "references", "../../outside/secret.usda")),
    ("", TEX_SHADER.format(decl="asset inputs:file = @../../outside/secret.png@"),
     ("/Tex", "inputs:file", "../../outside/secret.png")),
    ("", TEX_SHADER.format(decl="asset inputs:file.timeSamples = { 1: @../ok.png@, 2: @/etc/hostname@ }"),
     ("/Tex", "inputs:file", "/etc/hostname")),
    ("", 'def SphereLight "L" ( prepend apiSchemas = ["ShapingAPI"] ) {\n'
         ' asset inputs:shaping:ies:file = @{outside}/spot.ies@\n}', ("/L", "inputs:shaping:ies:file",
                                                                      "{outside}/spot.ies")),
    ("", 'def DomeLight "D" {\n asset illum:dome:irradiance = @../../outside/irr.exr@\n}',
     ("/D", "illum:dome:irradiance", "../../outside/irr.exr")),
    ("", 'def Xform "A" {\n asset[] files = [@../ok.png@, @../../outside/secret.png@]\n}',
     ("/A", "files", "../../outside/secret.png")),
    # the reader opens a plain string that names an existing file: absolute string inputs count
    ("", TEX_SHADER.format(decl='string inputs:file = "{outside}/secret.png"'),
     ("/Tex", "inputs:file", "{outside}/secret.png")),
    ("", 'def Material "M" {\n token inputs:tex = "/etc/passwd"\n}', ("/M", "inputs:tex", "/etc/passwd")),
    # a string primvar can become a texture's file (UsdPrimvarReader_string), anchored to its layer
    ("", 'def Mesh "G" {\n string primvars:texFile = "../../outside/secret.png"\n}',
     ("/G", "primvars:texFile", "../../outside/secret.png")),
    ("", 'def Mesh "G" {\n string[] primvars:maps = ["../ok.png", "{outside}/secret.png"]\n}',
     ("/G", "primvars:maps", "{outside}/secret.png")),
])
def test_escapes_are_found_and_located(tree, header, body, expected):
    root, outside = tree
    path = _stage(root, body.replace("{outside}", str(outside)), header.replace("{outside}", str(outside)))
    found = _escapes(path, root)
    expected = tuple(x.replace("{outside}", str(outside)) for x in expected)
    assert expected in found, found
    err = find_escapes(path, [str(root)]).escapes[0].error(where="the stage root")
    assert isinstance(err, StageError) and "outside the stage root" in str(err) and "\n" not in str(err)


def test_missing_files_are_judged_by_where_they_point(tree):
    """Existence never changes the verdict (no oracle for files outside): a missing file
    outside escapes, a missing file below the layer does not."""
    root, outside = tree
    body = "\n".join([
        TEX_SHADER.format(decl="asset inputs:file = @../../outside/nothere.png@").replace('"Tex"', '"A"'),
        TEX_SHADER.format(decl="asset inputs:file = @/nonexistent/dir/x.png@").replace('"Tex"', '"B"'),
        TEX_SHADER.format(decl="asset inputs:file = @textures/missing.png@").replace('"Tex"', '"C"'),
        'def "R" ( references = @../../outside/nothere.usda@ ) {}',
        'def "S" ( references = @./missing_inside.usda@ ) {}',
    ])
    found = _escapes(_stage(root, body), root)
    assert set(found) == {("/A", "inputs:file", "../../outside/nothere.png"),
                          ("/B", "inputs:file", "/nonexistent/dir/x.png"),
                          ("/R", "references", "../../outside/nothere.usda")}


def test_symlinks_out_of_the_root_escape(tree):
    root, outside = tree
    os.symlink(outside / "secret.png", root / "link.png")
    os.symlink(outside, root / "linkdir")
    body = "\n".join([TEX_SHADER.format(decl="asset inputs:file = @../link.png@"),
                      'def "R" ( references = @../linkdir/secret.usda@ ) {}'])
    found = _escapes(_stage(root, body), root)
    assert ("/Tex", "inputs:file", "../link.png") in found
    assert ("/R", "references", "../linkdir/secret.usda") in found


def test_nested_layers_and_instances_are_followed(tree):
    """A layer inside the root that itself reaches out is named as the culprit, and a texture
    inside an instance prototype is reported at its authored spec, not at /__Prototype_N."""
    root, outside = tree
    (root / "asset.usda").write_text(
        '#usda 1.0\ndef Xform "Asset" {\n' + TEX_SHADER.format(decl=f"asset inputs:file = @{outside}/secret.png@")
        + '\n def "Deep" ( references = @../outside/secret.usda@ ) {}\n}\n')
    body = ('def "I1" (\n instanceable = true\n references = @../asset.usda@</Asset>\n) {}\n'
            'def "I2" (\n instanceable = true\n references = @../asset.usda@</Asset>\n) {}')
    report = find_escapes(_stage(root, body), [str(root)])
    got = {(os.path.basename(e.layer), e.prim, e.field) for e in report.escapes}
    assert ("asset.usda", "/Asset/Deep", "references") in got
    assert ("asset.usda", "/Asset/Tex", "inputs:file") in got
    assert str(root / "asset.usda") in report.layers


def test_value_clips_are_checked(tree):
    root, outside = tree
    (outside / "clip.usda").write_text('#usda 1.0\ndef Xform "C" { double x.timeSamples = { 1: 1 } }\n')
    body = ('def Xform "C" (\n clips = {\n  dictionary default = {\n   asset[] assetPaths = [@../../outside/clip.usda@]\n'
            '   asset manifestAssetPath = @../inside.usda@\n   string primPath = "/C"\n   double2[] times = [(1, 1)]\n'
            '   double2[] active = [(1, 0)]\n  }\n }\n) {}')
    found = _escapes(_stage(root, body), root)
    assert ("/C", "clips", "../../outside/clip.usda") in found


def test_clean_stages_pass(tree):
    root, _ = tree
    body = "\n".join([TEX_SHADER.format(decl="asset inputs:file = @../ok.png@"),
                      'def "R" ( references = @../inside.usda@ ) {}'])
    report = find_escapes(_stage(root, body, '(\n subLayers = [@../inside.usda@]\n)'), [str(root)])
    assert report.escapes == []
    assert str(root / "inside.usda") in report.layers and str(root / "ok.png") in report.assets
    # every stage shipped with illum is self-contained
    for dirpath, _dirs, files in os.walk(STAGES):
        for name in files:
            if name.endswith((".usda", ".usdc", ".usdz")):
                assert find_escapes(os.path.join(dirpath, name), [STAGES]).escapes == [], name


def test_usdz_packages(tree):
    """Paths inside a package stay inside it; the package is judged by its own location."""
    root, _ = tree
    pkg = root / "pkg.usdz"
    layer = '#usda 1.0\ndef Xform "W" {\n' + TEX_SHADER.format(decl="asset inputs:file = @tex.png@") + "\n}\n"
    with zipfile.ZipFile(pkg, "w", compression=zipfile.ZIP_STORED) as z:
        z.writestr("root.usda", layer)
        z.write(root / "ok.png", "tex.png")
    assert find_escapes(str(pkg), [str(root)]).escapes == []
    body = 'def "R" ( references = @../pkg.usdz@ ) {}'
    assert _escapes(_stage(root, body), root) == []
    assert _escapes(_stage(root, body), root / "shots") == [("/R", "references", "../pkg.usdz")]


def test_stage_outside_or_unreadable(tree):
    root, outside = tree
    assert _escapes(str(outside / "secret.usda"), root) == [("", "layer", str(outside / "secret.usda"))]
    bad = root / "bad.usda"
    bad.write_text("#usda 1.0\ndef {{{")
    with pytest.raises(StageError, match="bad.usda"):
        find_escapes(str(bad), [str(root)])


def test_the_reader_itself_is_not_confined(tree):
    """The CLI renders what it is pointed at: load_stage reads a texture outside any root."""
    root, outside = tree
    body = ('def Camera "Cam" {}\ndef Material "M" {\n token outputs:surface.connect = </M/S.outputs:surface>\n'
            ' def Shader "S" {\n  uniform token info:id = "UsdPreviewSurface"\n'
            '  color3f inputs:diffuseColor.connect = </M/T.outputs:rgb>\n  token outputs:surface\n }\n'
            f' def Shader "T" {{\n  uniform token info:id = "UsdUVTexture"\n  asset inputs:file = @{outside}/secret.png@\n'
            '  float3 outputs:rgb\n }\n}\n'
            'def Mesh "Quad" ( prepend apiSchemas = ["MaterialBindingAPI"] ) {\n rel material:binding = </M>\n'
            ' int[] faceVertexCounts = [4]\n int[] faceVertexIndices = [0, 1, 2, 3]\n'
            ' point3f[] points = [(-1, -1, -5), (1, -1, -5), (1, 1, -5), (-1, 1, -5)]\n}')
    path = _stage(root, body)
    assert _escapes(path, root) == [("/M/T", "inputs:file", f"{outside}/secret.png")]
    desc = load_stage(path)
    assert [t.file for m in desc.materials for t in _textures(m)] == [str(outside / "secret.png")]


def _textures(material):
    return [v.texture for v in vars(material).values() if getattr(v, "texture", None) is not None]


def test_files_named_inside_a_referenced_mtlx_document_are_judged(tree):
    """renderer/usd/mtlx.py reads referenced .mtlx documents itself: their filename inputs lead
    out of the root like any texture path."""
    root, outside = tree
    (root / "shots" / "look.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n'
        '  <image name="leak" type="color3"><input name="file" type="filename" value="../../outside/secret.png" />'
        '</image>\n  <image name="fine" type="color3"><input name="file" type="filename" value="../ok.png" /></image>\n'
        '</materialx>\n')
    path = _stage(root, 'def "MaterialX" (\n references = @look.mtlx@</MaterialX>\n) {}')
    report = find_escapes(path, [str(root)])
    assert [(e.layer, e.prim, e.field, e.asset) for e in report.escapes] == [
        (str(root / "shots" / "look.mtlx"), "leak/file", "file", "../../outside/secret.png")]
    assert str(root / "ok.png") in report.assets and str(root / "shots" / "look.mtlx") in report.assets
