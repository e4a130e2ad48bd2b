"""MaterialX materials (renderer/usd/mtlx.py): inline UsdShade networks of MaterialX nodes and .mtlx
documents referenced from USD, read into the same MaterialDesc and rendered by the one BSDF.

Fixtures: tests/usd/data/mtlx/materials.usda (UsdPreviewSurface materials and their inline
MaterialX twins, references to library.mtlx), library.mtlx, albedo.png and normal.png. Each
render puts a quad under a constant dome, seen by a camera that it fills.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from renderer.errors import StageError
from renderer.film import read_exr
from renderer.render import RenderOptions, render, write_outputs
from renderer.textures import TextureCache
from renderer.usd import load_stage
from tests.stage_builders import textured_quad
from tests.stats import SIGNIFICANCE, z_test

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "mtlx")
MATERIALS = os.path.join(DATA, "materials.usda")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _scene(tmp_path, material: str, name: str = "scene.usda", extra=None) -> str:
    """A stage sublayering the fixture materials: camera, a 2x2 quad with st at z = 0 bound to
    ``material`` (a path; it need not exist, e.g. inside a referenced .mtlx document), a dome."""
    path = str(tmp_path / name)
    stage = Usd.Stage.CreateNew(path)
    stage.GetRootLayer().subLayerPaths.append(MATERIALS)
    UsdGeom.SetStageUpAxis(stage, "Y")
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    _bind(textured_quad(stage, "/Quad"), material)
    UsdLux.DomeLight.Define(stage, "/Sky").CreateIntensityAttr(1.0)
    if extra is not None:
        extra(stage)
    stage.GetRootLayer().Save()
    return path


def _bind(gprim, material: str) -> None:
    """material:binding to a path (which need not exist on the stage)."""
    UsdShade.MaterialBindingAPI.Apply(gprim.GetPrim())
    gprim.GetPrim().CreateRelationship("material:binding").SetTargets([Sdf.Path(material)])


def _material(desc, path: str):
    found = [m for m in desc.materials if m.path == path]
    assert len(found) == 1, [m.path for m in desc.materials]
    return found[0]


def _same_but_name(a, b) -> bool:
    """Equal descriptions apart from the material's path and source."""
    fields = {f: getattr(a, f) for f in a.__dataclass_fields__ if f not in ("path", "source")}
    return all(fields[f] == getattr(b, f) for f in fields)


OPTS = dict(threads=1, max_depth=2, resolution=(16, 16))


# ---- exact mappings -------------------------------------------------------------------
def test_nd_usd_preview_surface_network_renders_identically_to_usd_preview_surface(tmp_path):
    a = load_stage(_scene(tmp_path, "/Materials/Preview", "a.usda"))
    b = load_stage(_scene(tmp_path, "/Materials/NDPreview", "b.usda"))
    pa, pb = _material(a, "/Materials/Preview"), _material(b, "/Materials/NDPreview")
    # image (srgb_texture) * 0.5 folds into the texture's scale, exactly as UsdUVTexture's.
    assert pb.diffuse_color.texture.scale == (0.5, 0.5, 0.5, 1.0)
    assert pb.diffuse_color.texture.source_color_space == "sRGB"
    assert _same_but_name(pa, pb)
    assert (pa.source, pb.source) == ("UsdPreviewSurface", "mtlx:ND_UsdPreviewSurface_surfaceshader")
    assert a.warnings == b.warnings == []
    ia, ib = _render_exr(str(tmp_path / "a.usda"), seed=5, spp=4), _render_exr(str(tmp_path / "b.usda"), seed=5, spp=4)
    assert ia.max() > 0.0 and np.array_equal(ia, ib)


@pytest.mark.parametrize("holder", ["/Tiled", "/TiledPlain"])
def test_mtlx_document_reads_as_its_inline_twin(tmp_path, holder):
    """A .mtlx document referenced onto a Material prim, or onto a typeless prim bound directly
    (usd-core cannot compose either), gives the description of the same network written inline;
    tiledimage's uvtiling becomes the st transform through the library's own tiledimage graph."""
    doc = load_stage(_scene(tmp_path, holder, "a.usda"))
    inline = load_stage(_scene(tmp_path, "/TiledInline", "b.usda"))
    d, i = _material(doc, holder), _material(inline, "/TiledInline")
    assert d.diffuse_color.texture.st_transform == (2.0, 0.0, 0.0, 2.0, 0.0, 0.0)
    assert _same_but_name(d, i)
    assert d.source == "mtlx:ND_standard_surface_surfaceshader (library.mtlx)"
    # The arc usd-core cannot compose is no composition warning: illum reads the document.
    assert doc.warnings == inline.warnings == []


def test_binding_into_a_referenced_document_reads_normal_map_and_remap(tmp_path):
    """``def "MaterialX" (references = @library.mtlx@</MaterialX>)`` bound at
    /MaterialX/Materials/Bumpy: normalmap(image) is the UsdPreviewSurface normal map (2 n - 1,
    scale 2 and bias -1) and remap(image.r, 0..1 -> 0.2..0.6) folds into roughness."""
    desc = load_stage(_scene(tmp_path, "/MaterialX/Materials/Bumpy"))
    assert desc.warnings == []
    m = _material(desc, "/MaterialX/Materials/Bumpy")
    n = m.normal.texture
    assert (n.output, n.scale, n.bias, n.source_color_space) == ("rgb", (2.0, 2.0, 2.0, 1.0),
                                                                 (-1.0, -1.0, -1.0, 0.0), "raw")
    r = m.roughness.texture
    assert (r.output, r.scale[0], r.bias[0]) == ("r", pytest.approx(0.4), pytest.approx(0.2))
    # The folded texture reads what the MaterialX network computes, texel by texel.
    st = np.random.default_rng(2).random((300, 2)) * 3.0 - 1.0
    raw = TextureCache().lookup(type(r)(file=r.file, source_color_space="raw", wrap_s="repeat", wrap_t="repeat",
                                        output="r"), st)
    assert np.allclose(TextureCache().lookup(r, st)[:, 0], 0.2 + 0.4 * raw[:, 0], atol=1e-6)


# ---- the documented approximation: standard_surface onto the UsdPreviewSurface BSDF --------
def _render_exr(stage: str, seed: int, spp: int = 16) -> np.ndarray:
    """Render ``stage``, write the EXR, and read it back with OpenImageIO: (H, W, 3)."""
    out = stage.replace(".usda", ".exr")
    write_outputs(render(stage, RenderOptions(spp=spp, seed=seed, **OPTS)), exr=out)
    img, _attrs = read_exr(out)
    return img[:, :, :3]


def _difference_p(tmp_path, mat_a: str, mat_b: str, extra=None) -> float:
    """z-test p-value that two materials render the same: per-pixel differences of two
    independent renders (seeds 1 and 2) of the evenly lit quad have mean 0."""
    a = _render_exr(_scene(tmp_path, mat_a, "a.usda"), seed=1)
    b = _render_exr(_scene(tmp_path, mat_b, "b.usda", extra=extra), seed=2)
    assert a.max() > 0.0
    return z_test((a - b).ravel(), 0.0)


def test_standard_surface_renders_as_preview_surface_with_base_times_base_color(tmp_path):
    assert _difference_p(tmp_path, "/Materials/Standard", "/Materials/StandardAsPreview") > SIGNIFICANCE


def test_the_z_test_tells_base_color_alone_from_base_times_base_color(tmp_path):
    """Control: without the base weight (diffuseColor = base_color) the renders differ."""
    def alone(stage):
        mat = UsdShade.Material.Define(stage, "/Alone")
        pbr = UsdShade.Shader.Define(stage, "/Alone/PBR")
        pbr.CreateIdAttr("UsdPreviewSurface")
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set((0.8, 0.3, 0.1))
        pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.4)
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")

    assert _difference_p(tmp_path, "/Materials/Standard", "/Alone", extra=alone) < SIGNIFICANCE


def _inline_surface(stage, node_id: str, **inputs):
    """/Inline: a Material whose mtlx surface is ``node_id`` with inputs name=(type, value)."""
    mat = UsdShade.Material.Define(stage, "/Inline")
    sh = UsdShade.Shader.Define(stage, "/Inline/Surface")
    sh.CreateIdAttr(node_id)
    for name, (vtype, value) in inputs.items():
        sh.CreateInput(name, vtype).Set(value)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.ConnectableAPI(), "surface")


def test_standard_surface_mapping_formulas(tmp_path):
    """docs/materials.md: metalness -> metallic, specular weight and colour (dielectric) ->
    specular workflow with F0 = specular * specular_color * ((ior - 1) / (ior + 1))^2, emission
    * emission_color, opacity's mean, coat tinting the base by lerp(1, coat_color, coat); the
    inputs with no counterpart are named in one warning."""
    f = Sdf.ValueTypeNames
    path = _scene(tmp_path, "/Inline", extra=lambda s: _inline_surface(
        s, "ND_standard_surface_surfaceshader", base_color=(f.Color3f, (0.5, 0.5, 0.5)),
        specular=(f.Float, 0.5), specular_color=(f.Color3f, (1.0, 0.5, 0.25)), specular_IOR=(f.Float, 2.0),
        emission=(f.Float, 2.0), emission_color=(f.Color3f, (0.5, 0.25, 1.0)),
        opacity=(f.Color3f, (0.9, 0.6, 0.3)), coat=(f.Float, 0.5), coat_color=(f.Color3f, (1.0, 0.5, 0.0)),
        transmission=(f.Float, 0.3)))
    desc = load_stage(path)
    m = _material(desc, "/Inline")
    f0 = ((2.0 - 1.0) / (2.0 + 1.0)) ** 2
    assert m.use_specular_workflow and m.ior == 2.0
    assert m.specular_color.value == pytest.approx((0.5 * f0, 0.25 * f0, 0.125 * f0))
    assert m.emissive_color.value == pytest.approx((1.0, 0.5, 2.0))
    assert m.opacity.value == pytest.approx(0.6)
    assert m.diffuse_color.value == pytest.approx((0.5, 0.375, 0.25))
    lost = [w for w in desc.warnings if "no counterpart" in w]
    assert len(lost) == 1 and "transmission" in lost[0] and "coat" in lost[0] and "/Inline" in lost[0]


def test_open_pbr_metal(tmp_path):
    f = Sdf.ValueTypeNames
    path = _scene(tmp_path, "/Inline", extra=lambda s: _inline_surface(
        s, "ND_open_pbr_surface_surfaceshader", base_color=(f.Color3f, (0.9, 0.6, 0.2)),
        base_metalness=(f.Float, 1.0), specular_roughness=(f.Float, 0.25), emission_luminance=(f.Float, 3.0),
        geometry_opacity=(f.Float, 0.5)))
    m = _material(load_stage(path), "/Inline")
    assert (m.metallic.value, m.roughness.value, m.use_specular_workflow) == (1.0, 0.25, False)
    assert m.diffuse_color.value == pytest.approx((0.9, 0.6, 0.2))
    assert m.emissive_color.value == pytest.approx((3.0, 3.0, 3.0))
    assert m.opacity.value == 0.5


# ---- folding math nodes into the texture lookup --------------------------------------------
def _graph(stage, nodes, surface_input: str, source: str):
    """/Inline: standard_surface whose ``surface_input`` is fed by node ``source`` of ``nodes``
    {name: (node id, {input: ('value', type, v) | ('node', type, other name)})}."""
    mat = UsdShade.Material.Define(stage, "/Inline")
    shaders = {}
    for name, (node_id, _inputs) in nodes.items():
        sh = UsdShade.Shader.Define(stage, f"/Inline/{name}")
        sh.CreateIdAttr(node_id)
        sh.CreateOutput("out", Sdf.ValueTypeNames.Color3f)
        shaders[name] = sh
    for name, (_node_id, inputs) in nodes.items():
        for inp, (kind, vtype, v) in inputs.items():
            i = shaders[name].CreateInput(inp, vtype)
            if kind == "value":
                i.Set(v)
            else:
                i.ConnectToSource(shaders[v].ConnectableAPI(), "out")
    surface = UsdShade.Shader.Define(stage, "/Inline/Surface")
    surface.CreateIdAttr("ND_standard_surface_surfaceshader")
    surface.CreateInput(surface_input, Sdf.ValueTypeNames.Color3f).ConnectToSource(
        shaders[source].ConnectableAPI(), "out")
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(surface.ConnectableAPI(), "surface")


def test_math_nodes_fold_into_the_texture_lookup(tmp_path):
    """mix(fg = image * (1, 0.5, 2), bg = (0.1, 0.2, 0.3), mix = 0.25) + 0.05, then invert
    (1 - x): looked up through the folded TextureDesc, it equals the MaterialX formula applied
    to the raw texels (spec inputs: mix's fg/bg/mix, multiply/add in1/in2, invert amount/in)."""
    f = Sdf.ValueTypeNames
    albedo = Sdf.AssetPath(os.path.join(DATA, "albedo.png"))
    nodes = {
        "Img": ("ND_image_color3", {"file": ("value", f.Asset, albedo)}),
        "Mul": ("ND_multiply_color3", {"in1": ("node", f.Color3f, "Img"), "in2": ("value", f.Color3f, (1, 0.5, 2))}),
        "Mix": ("ND_mix_color3", {"fg": ("node", f.Color3f, "Mul"), "bg": ("value", f.Color3f, (0.1, 0.2, 0.3)),
                                  "mix": ("value", f.Float, 0.25)}),
        "Add": ("ND_add_color3FA", {"in1": ("node", f.Color3f, "Mix"), "in2": ("value", f.Float, 0.05)}),
        "Inv": ("ND_invert_color3", {"in": ("node", f.Color3f, "Add")}),
    }
    desc = load_stage(_scene(tmp_path, "/Inline", extra=lambda s: _graph(s, nodes, "base_color", "Inv")))
    assert desc.warnings == []
    tex = _material(desc, "/Inline").diffuse_color.texture
    st = np.random.default_rng(4).random((400, 2)) * 2.0
    raw = TextureCache().lookup(type(tex)(file=tex.file, source_color_space="raw", wrap_s="repeat",
                                          wrap_t="repeat"), st)[:, :3]
    expected = 1.0 - ((0.25 * raw * np.array([1, 0.5, 2]) + 0.75 * np.array([0.1, 0.2, 0.3])) + 0.05)
    assert np.allclose(TextureCache().lookup(tex, st)[:, :3], expected, atol=1e-6)


def test_unsupported_node_warns_once_naming_node_and_material_in_stats(tmp_path):
    """Noise feeds base_color directly and specular_roughness through extract, and the material
    is bound to two prims: one warning, naming the node and the material, listed in --stats;
    a material with both render contexts is read from MaterialX, and --stats says so."""
    def second(stage):
        other = UsdGeom.Sphere.Define(stage, "/Ball")
        _bind(other, "/Materials/Noisy")
        both = UsdGeom.Sphere.Define(stage, "/Both")
        both.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5))
        _bind(both, "/Materials/Both")

    stage = _scene(tmp_path, "/Materials/Noisy", extra=second)
    out, stats = tmp_path / "o.exr", tmp_path / "s.json"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", stage, "-o", str(out), "--res", "8", "8",
                        "--spp", "1", "--stats", str(stats)], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr
    s = json.loads(stats.read_text())
    noisy = [w for w in s["warnings"] if "Noise" in w]
    assert len(noisy) == 1, s["warnings"]
    assert "/Materials/Noisy/Noise " in noisy[0] and noisy[0].startswith("/Materials/Noisy:")
    assert "more like it" not in noisy[0]
    assert sum("/Materials/Noisy/Noise " in line for line in r.stderr.splitlines()) == 1
    sources = {m["path"]: m["source"] for m in s["materials"]}
    assert sources["/Materials/Noisy"] == "mtlx:ND_standard_surface_surfaceshader"
    assert sources["/Materials/Both"] == "mtlx:ND_open_pbr_surface_surfaceshader"
    img, _attrs = read_exr(str(out))
    assert np.all(np.isfinite(img))


def test_both_contexts_prefer_materialx(tmp_path):
    m = _material(load_stage(_scene(tmp_path, "/Materials/Both")), "/Materials/Both")
    assert m.diffuse_color.value == pytest.approx((0.0, 0.8, 0.0))


# ---- missing documents: the missing-asset policy ---------------------------------------------
def _missing_doc(stage):
    UsdShade.Material.Define(stage, "/Gone").GetPrim().GetReferences().AddReference(
        "./nowhere.mtlx", "/MaterialX/Materials/Gone")


def test_missing_mtlx_document_warns_and_strict_fails(tmp_path):
    path = _scene(tmp_path, "/Gone", extra=_missing_doc)
    desc = load_stage(path)
    assert len([w for w in desc.warnings if "nowhere.mtlx" in w]) == 1
    assert _material(desc, "").source == "default"
    with pytest.raises(StageError, match="nowhere.mtlx"):
        load_stage(path, strict=True)


def test_usd_nodes_inside_a_materialx_network_read_as_in_a_preview_network(tmp_path):
    """UsdUVTexture <- UsdTransform2d <- UsdPrimvarReader_float2 feeding a standard_surface
    (through MaterialX's own definitions of those nodes, USD's defaults for their unauthored
    inputs) look up what they look up under a UsdPreviewSurface; rendered with the same seed
    the two agree to float rounding (the st transforms differ in the last bits: MaterialX's
    graph composes scale, -rotation and translation node by node)."""
    def uv2(stage):
        quad = UsdGeom.Mesh(stage.GetPrimAtPath("/Quad"))
        UsdGeom.PrimvarsAPI(quad).CreatePrimvar("uv2", Sdf.ValueTypeNames.TexCoord2fArray,
                                                UsdGeom.Tokens.vertex).Set(
            Vt.Vec2fArray([(0.1, 0.2), (0.9, 0.1), (1.3, 0.8), (0.0, 1.1)]))

    a = load_stage(_scene(tmp_path, "/Mixed", "a.usda", extra=uv2))
    b = load_stage(_scene(tmp_path, "/MixedPreview", "b.usda", extra=uv2))
    assert a.warnings == b.warnings == []
    ma, mb = _material(a, "/Mixed"), _material(b, "/MixedPreview")
    st = np.random.default_rng(7).random((500, 2)) * 3.0 - 1.0
    for field, channels in (("diffuse_color", slice(0, 3)), ("roughness", slice(3, 4))):
        ta, tb = getattr(ma, field).texture, getattr(mb, field).texture
        assert ta.st_primvar == tb.st_primvar == "uv2"
        assert ta.st_transform == pytest.approx(tb.st_transform, abs=1e-12)
        assert (ta.wrap_s, ta.wrap_t, ta.source_color_space) == ("mirror", "useMetadata", "auto")
        assert np.allclose(TextureCache().lookup(ta, st)[:, channels], TextureCache().lookup(tb, st)[:, channels],
                           atol=1e-6)
    ia = render(str(tmp_path / "a.usda"), RenderOptions(spp=4, seed=5, **OPTS)).film.image()
    ib = render(str(tmp_path / "b.usda"), RenderOptions(spp=4, seed=5, **OPTS)).film.image()
    assert ia.max() > 0.0 and np.allclose(ia, ib, rtol=1e-6, atol=0.0)


def test_geompropvalue_reads_the_primvar_per_hit_as_a_primvar_reader_does(tmp_path):
    """geompropvalue(displayColor) into standard_surface base_color is the
    UsdPrimvarReader_float3 the UsdPreviewSurface path reads per hit; a multiply after it
    cannot be evaluated per hit and warns (naming the node) instead."""
    f = Sdf.ValueTypeNames

    def build(stage):
        for name, scale in (("/Inline", None), ("/Scaled", 0.5)):
            mat = UsdShade.Material.Define(stage, name)
            read = UsdShade.Shader.Define(stage, f"{name}/Read")
            read.CreateIdAttr("ND_geompropvalue_color3")
            read.CreateInput("geomprop", f.String).Set("displayColor")
            src = read.CreateOutput("out", f.Color3f)
            if scale is not None:
                mul = UsdShade.Shader.Define(stage, f"{name}/Mul")
                mul.CreateIdAttr("ND_multiply_color3FA")
                mul.CreateInput("in1", f.Color3f).ConnectToSource(src)
                mul.CreateInput("in2", f.Float).Set(scale)
                src = mul.CreateOutput("out", f.Color3f)
            sh = UsdShade.Shader.Define(stage, f"{name}/Surface")
            sh.CreateIdAttr("ND_standard_surface_surfaceshader")
            sh.CreateInput("base_color", f.Color3f).ConnectToSource(src)
            mat.CreateSurfaceOutput("mtlx").ConnectToSource(sh.ConnectableAPI(), "surface")
        mat = UsdShade.Material.Define(stage, "/Reader")
        pbr = UsdShade.Shader.Define(stage, "/Reader/PBR")
        pbr.CreateIdAttr("UsdPreviewSurface")
        read = UsdShade.Shader.Define(stage, "/Reader/Read")
        read.CreateIdAttr("UsdPrimvarReader_float3")
        read.CreateInput("varname", f.Token).Set("displayColor")
        pbr.CreateInput("diffuseColor", f.Color3f).ConnectToSource(read.CreateOutput("result", f.Float3))
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        for i, target in enumerate(("/Reader", "/Scaled")):
            ball = UsdGeom.Sphere.Define(stage, f"/Ball{i}")
            ball.AddTranslateOp().Set(Gf.Vec3d(0, 0, -5 - i))
            _bind(ball, target)

    desc = load_stage(_scene(tmp_path, "/Inline", extra=build))
    inline, reader = _material(desc, "/Inline"), _material(desc, "/Reader")
    assert inline.diffuse_color.primvar is not None
    assert inline.diffuse_color == reader.diffuse_color
    warned = [w for w in desc.warnings if "/Scaled/Read" in w]
    assert len(warned) == 1 and warned[0].startswith("/Scaled:")
    assert _material(desc, "/Scaled").diffuse_color.value == pytest.approx((0.8, 0.8, 0.8))


def test_unmapped_materialx_surface_falls_back_to_the_preview_surface(tmp_path):
    desc = load_stage(_scene(tmp_path, "/Unmapped"))
    m = _material(desc, "/Unmapped")
    assert m.source == "UsdPreviewSurface" and m.diffuse_color.value == pytest.approx((0.8, 0.0, 0.0))
    assert len([w for w in desc.warnings if "ND_disney_principled" in w and "/Unmapped" in w]) == 1


def test_gltf_pbr_mask_mode(tmp_path):
    f = Sdf.ValueTypeNames
    path = _scene(tmp_path, "/Inline", extra=lambda s: _inline_surface(
        s, "ND_gltf_pbr_surfaceshader", base_color=(f.Color3f, (0.2, 0.4, 0.6)), metallic=(f.Float, 0.5),
        roughness=(f.Float, 0.3), alpha=(f.Float, 0.2), alpha_mode=(f.Int, 1), alpha_cutoff=(f.Float, 0.4),
        emissive=(f.Color3f, (1.0, 0.5, 0.0)), emissive_strength=(f.Float, 2.0)))
    m = _material(load_stage(path), "/Inline")
    assert m.diffuse_color.value == pytest.approx((0.2, 0.4, 0.6))
    assert (m.metallic.value, m.roughness.value) == pytest.approx((0.5, 0.3))
    assert (m.opacity.value, m.opacity_threshold) == pytest.approx((0.2, 0.4))
    assert m.emissive_color.value == pytest.approx((2.0, 1.0, 0.0))


def test_mtlx_document_inside_a_usdz_package(tmp_path):
    """A .usdz holding the stage, a .mtlx document and its textures: the document and its
    images are read from the package through Ar, as the unpacked files are."""
    scene = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(scene))
    stage.DefinePrim("/MaterialX").GetReferences().AddReference("looks/library.mtlx", "/MaterialX")
    UsdGeom.Camera.Define(stage, "/Cam").AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    UsdLux.DomeLight.Define(stage, "/Sky")
    _bind(textured_quad(stage, "/Quad"), "/MaterialX/Materials/Tiled")
    stage.GetRootLayer().Save()
    package = str(tmp_path / "pkg.usdz")
    writer = Sdf.ZipFileWriter.CreateNew(package)
    writer.AddFile(str(scene), "scene.usda")
    for name in ("library.mtlx", "albedo.png", "normal.png"):
        writer.AddFile(os.path.join(DATA, name), f"looks/{name}")
    writer.Save()
    packed = load_stage(package)
    assert packed.warnings == []
    tex = _material(packed, "/MaterialX/Materials/Tiled").diffuse_color.texture
    assert tex.file == f"{package}[looks/albedo.png]" and tex.data is not None
    plain = _material(load_stage(_scene(tmp_path, "/Tiled", "plain.usda")), "/Tiled").diffuse_color.texture
    st = np.random.default_rng(3).random((200, 2))
    assert tex.st_transform == plain.st_transform
    assert np.array_equal(TextureCache().lookup(tex, st), TextureCache().lookup(plain, st))


@pytest.mark.parametrize("case", ["two textures", "rearranged channels", "nonlinear"])
def test_networks_that_cannot_fold_warn_naming_the_node(tmp_path, case):
    f = Sdf.ValueTypeNames
    albedo, normal = (Sdf.AssetPath(os.path.join(DATA, n)) for n in ("albedo.png", "normal.png"))
    img = lambda path: ("ND_image_color3", {"file": ("value", f.Asset, path)})  # noqa: E731
    nodes, culprit = {
        "two textures": ({"A": img(albedo), "B": img(normal),
                          "Out": ("ND_mix_color3", {"fg": ("node", f.Color3f, "A"), "bg": ("node", f.Color3f, "B"),
                                                    "mix": ("value", f.Float, 0.5)})}, "Out"),
        "rearranged channels": ({"A": img(albedo), **{
            ch: ("ND_extract_color3", {"in": ("node", f.Color3f, "A"), "index": ("value", f.Int, k)})
            for ch, k in (("R", 2), ("G", 1), ("B", 0))},
            "Out": ("ND_combine3_color3", {f"in{i + 1}": ("node", f.Float, ch) for i, ch in enumerate("RGB")})}, "A"),
        "nonlinear": ({"A": img(albedo),
                       "Out": ("ND_power_color3FA", {"in1": ("node", f.Color3f, "A"), "in2": ("value", f.Float, 2.2)})},
                      "Out"),
    }[case]
    desc = load_stage(_scene(tmp_path, "/Inline", extra=lambda s: _graph(s, nodes, "base_color", "Out")))
    warned = [w for w in desc.warnings if "MaterialX node" in w]
    assert len(warned) == 1 and warned[0].startswith(f"/Inline: MaterialX node /Inline/{culprit} is not supported")
    m = _material(desc, "/Inline")
    assert m.diffuse_color.texture is None and m.diffuse_color.value == pytest.approx((0.8, 0.8, 0.8))


def test_place2d_folds_into_the_st_transform(tmp_path):
    """place2d (through MaterialX's own graph of it: subtract, divide, rotate2d, add and a
    switch on operationorder) gives st' = R(rotate) diag(1 / scale) (st - pivot) - offset + pivot,
    R the rotation of mx_rotate_vector2."""
    f = Sdf.ValueTypeNames
    nodes = {
        "T": ("ND_texcoord_vector2", {}),
        "P": ("ND_place2d_vector2", {"texcoord": ("node", f.Float2, "T"), "scale": ("value", f.Float2, (2, 4)),
                                     "rotate": ("value", f.Float, 30.0), "offset": ("value", f.Float2, (0.1, 0.2)),
                                     "pivot": ("value", f.Float2, (0.5, 0.5))}),
        "I": ("ND_image_color3", {"file": ("value", f.Asset, Sdf.AssetPath(os.path.join(DATA, "albedo.png"))),
                                  "texcoord": ("node", f.Float2, "P")}),
    }
    desc = load_stage(_scene(tmp_path, "/Inline", extra=lambda s: _graph(s, nodes, "base_color", "I")))
    assert desc.warnings == []
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    A = np.array([[c, s], [-s, c]]) @ np.diag([0.5, 0.25])
    offset = np.array([0.1, 0.2], dtype=np.float32).astype(np.float64)  # as the float2 holds it
    t = -A @ np.array([0.5, 0.5]) - offset + np.array([0.5, 0.5])
    xf = _material(desc, "/Inline").diffuse_color.texture.st_transform
    assert xf == pytest.approx((*A.ravel(), *t), abs=1e-12)


def test_constant_networks_fold_through_nonlinear_nodes(tmp_path):
    """clamp(power(c, 2), 0, 1) and luminance on constants: evaluated at read time."""
    f = Sdf.ValueTypeNames
    nodes = {
        "Pow": ("ND_power_color3FA", {"in1": ("value", f.Color3f, (0.5, 0.25, 2.0)), "in2": ("value", f.Float, 2.0)}),
        "Clamp": ("ND_clamp_color3FA", {"in": ("node", f.Color3f, "Pow")}),
        "Lum": ("ND_luminance_color3", {"in": ("node", f.Color3f, "Clamp"),
                                        "lumacoeffs": ("value", f.Color3f, (0.25, 0.5, 0.25))}),
    }
    desc = load_stage(_scene(tmp_path, "/Inline", extra=lambda s: _graph(s, nodes, "base_color", "Lum")))
    assert desc.warnings == []
    y = 0.25 * 0.25 + 0.5 * 0.0625 + 0.25 * 1.0
    assert _material(desc, "/Inline").diffuse_color.value == pytest.approx((y, y, y))
