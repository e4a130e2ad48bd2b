"""UsdShade: binding purposes, UsdPreviewSurface values and defaults, textures, fallbacks."""

import os

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, UsdGeom, UsdRender, UsdShade

from renderer.description import MaterialDesc, MaterialInput
from renderer.errors import StageError
from renderer.usd import load_stage

from .helpers import COLOR3, FLOAT, add_quad, bind, mesh, new_stage, preview_material, read


def _material_of(d, path):
    return d.materials[mesh(d, path).material]


def test_preview_surface_values_and_sdr_defaults(stage):
    mat, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (0.8, 0.1, 0.1)),
                              roughness=(FLOAT, 0.25), metallic=(FLOAT, 1.0),
                              useSpecularWorkflow=(Sdf.ValueTypeNames.Int, 1),
                              specularColor=(COLOR3, (0.5, 0.5, 0.5)), ior=(FLOAT, 1.33),
                              emissiveColor=(COLOR3, (2, 2, 2)), opacity=(FLOAT, 0.5),
                              opacityThreshold=(FLOAT, 0.1), opacityMode=(Sdf.ValueTypeNames.Token, "presence"))
    bind(add_quad(stage, "/A"), mat)
    bare, _ = preview_material(stage, "/Looks/Bare")
    bind(add_quad(stage, "/B"), bare)
    d = read(stage)
    red = _material_of(d, "/A")
    assert red.path == "/Looks/Red"
    assert red.diffuse_color.value == pytest.approx((0.8, 0.1, 0.1))
    assert red.roughness.value == pytest.approx(0.25) and red.metallic.value == 1.0
    assert red.use_specular_workflow is True and red.specular_color.value == pytest.approx((0.5,) * 3)
    assert red.ior == pytest.approx(1.33) and red.emissive_color.value == (2.0, 2.0, 2.0)
    assert red.opacity.value == 0.5 and red.opacity_threshold == pytest.approx(0.1)
    assert red.opacity_mode == "presence"
    # unauthored inputs take UsdPreviewSurface's Sdr defaults
    b = _material_of(d, "/B")
    assert b == MaterialDesc(path="/Looks/Bare", diffuse_color=MaterialInput(b.diffuse_color.value))
    assert b.diffuse_color.value == pytest.approx((0.18, 0.18, 0.18))
    assert (b.roughness.value, b.ior, b.opacity.value, b.metallic.value) == pytest.approx((0.5, 1.5, 1.0, 0.0))


def test_binding_purpose_order(stage):
    q = add_quad(stage, "/Q")
    for name, purpose in (("Full", "full"), ("Preview", "preview"), ("All", "")):
        m, _ = preview_material(stage, f"/Looks/{name}")
        bind(q, m, purpose)
    settings = UsdRender.Settings.Define(stage, "/Render/S")
    stage.SetMetadata("renderSettingsPrimPath", "/Render/S")
    assert _material_of(read(stage), "/Q").path == "/Looks/Full"  # fallback ["full", ""]
    settings.CreateMaterialBindingPurposesAttr(["preview", ""])
    assert _material_of(read(stage), "/Q").path == "/Looks/Preview"
    settings.CreateMaterialBindingPurposesAttr([""])
    assert _material_of(read(stage), "/Q").path == "/Looks/All"


def test_binding_inherited_from_ancestor(stage):
    m, _ = preview_material(stage, "/Looks/M")
    grp = UsdGeom.Xform.Define(stage, "/G")
    bind(grp, m)
    add_quad(stage, "/G/Q")
    assert _material_of(read(stage), "/G/Q").path == "/Looks/M"


def test_display_color_then_grey_fallback_and_dedupe(stage):
    for k in range(3):
        q = add_quad(stage, f"/Red{k}")
        UsdGeom.Gprim(q).CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(1, 0, 0)])
    u = add_quad(stage, "/Uniform")
    UsdGeom.Gprim(u).CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set([(0, 1, 0)])
    add_quad(stage, "/Plain1")
    UsdGeom.Sphere.Define(stage, "/Plain2")
    shared, _ = preview_material(stage, "/Looks/Shared")
    bind(add_quad(stage, "/S1"), shared)
    bind(add_quad(stage, "/S2"), shared)
    d = read(stage)
    assert _material_of(d, "/Red0").diffuse_color.value == (1.0, 0.0, 0.0)
    assert _material_of(d, "/Red0").path == ""
    assert _material_of(d, "/Uniform").diffuse_color.value == (0.0, 1.0, 0.0)
    assert _material_of(d, "/Plain1") == MaterialDesc(path="")  # 0.18 grey
    assert _material_of(d, "/Plain2").diffuse_color.value == pytest.approx((0.18,) * 3)
    # red, green, grey, shared: duplicates share one table entry
    assert len(d.materials) == 4
    assert {mesh(d, f"/Red{k}").material for k in range(3)} == {mesh(d, "/Red0").material}
    assert mesh(d, "/S1").material == mesh(d, "/S2").material


def _textured_stage(tmp_path, file_value="tex/wood.png", through_nodegraph=False):
    (tmp_path / "tex").mkdir(exist_ok=True)
    # A real image: the reader opens each texture's header (an unreadable one is the
    # missing-asset policy's, like a missing one).
    assert oiio.ImageBuf(np.full((2, 2, 3), 0.5, np.float32)).write(str(tmp_path / "tex" / "wood.png"), oiio.UINT8)
    stage = new_stage()
    mat, pbr = preview_material(stage, "/Looks/Wood")
    parent = "/Looks/Wood/NG" if through_nodegraph else "/Looks/Wood"
    if through_nodegraph:
        UsdShade.NodeGraph.Define(stage, parent)
    reader = UsdShade.Shader.Define(stage, f"{parent}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("uvSet1")
    tex = UsdShade.Shader.Define(stage, f"{parent}/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file_value)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set((2, 2, 2, 1))
    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set((0.1, 0, 0, 0))
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set((0.3, 0.4, 0.5, 1))
    rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    g = tex.CreateOutput("g", Sdf.ValueTypeNames.Float)
    if through_nodegraph:
        ng = UsdShade.NodeGraph.Get(stage, parent)
        ng_rgb = ng.CreateOutput("color", Sdf.ValueTypeNames.Float3)
        ng_rgb.ConnectToSource(rgb)
        ng_g = ng.CreateOutput("rough", Sdf.ValueTypeNames.Float)
        ng_g.ConnectToSource(g)
        rgb, g = ng_rgb, ng_g
    pbr.CreateInput("diffuseColor", COLOR3).ConnectToSource(rgb)
    pbr.CreateInput("roughness", FLOAT).ConnectToSource(g)
    # metallic through a Material interface input
    iface = mat.CreateInput("metalness", FLOAT)
    iface.Set(0.75)
    pbr.CreateInput("metallic", FLOAT).ConnectToSource(iface)
    bind(add_quad(stage, "/Q"), mat)
    layer_path = tmp_path / "scene.usda"
    stage.GetRootLayer().Export(str(layer_path))
    return str(layer_path)


@pytest.mark.parametrize("through_nodegraph", [False, True])
def test_texture_desc(tmp_path, through_nodegraph):
    d = load_stage(_textured_stage(tmp_path, through_nodegraph=through_nodegraph))
    m = _material_of(d, "/Q")
    tex = m.diffuse_color.texture
    assert tex is not None
    assert tex.file == os.path.join(str(tmp_path), "tex", "wood.png") and os.path.isabs(tex.file)
    assert tex.source_color_space == "sRGB"
    assert (tex.wrap_s, tex.wrap_t) == ("clamp", "useMetadata")  # resolved from the file at load
    assert tex.scale == (2.0, 2.0, 2.0, 1.0) and tex.bias == pytest.approx((0.1, 0, 0, 0))
    assert tex.fallback == pytest.approx((0.3, 0.4, 0.5, 1.0))
    assert tex.output == "rgb" and tex.st_primvar == "uvSet1"
    assert m.diffuse_color.value == pytest.approx((0.3, 0.4, 0.5))  # the texture's fallback
    rough = m.roughness
    assert rough.texture is not None and rough.texture.output == "g"
    assert rough.value == pytest.approx(0.4)
    assert m.metallic == MaterialInput(0.75)  # interface input value
    assert m.emissive_color.texture is None


def test_missing_texture_uses_fallback_or_fails_under_strict(tmp_path):
    """The missing-asset policy: by default the UsdUVTexture's fallback with one warning per
    file (two inputs read the same texture); --strict: an error naming layer, prim, attribute."""
    path = _textured_stage(tmp_path, file_value="tex/missing.png")
    d = load_stage(path)
    m = _material_of(d, "/Q")
    assert m.diffuse_color.texture is None and m.diffuse_color.value == pytest.approx((0.3, 0.4, 0.5))
    assert m.roughness.texture is None and m.roughness.value == pytest.approx(0.4)
    hits = [w for w in d.warnings if "missing.png" in w]
    assert len(hits) == 1 and "/Looks/Wood/Tex.inputs:file: file not found" in hits[0] and path in hits[0]
    with pytest.raises(StageError) as err:
        load_stage(path, strict=True)
    assert err.value.prim == "/Looks/Wood/Tex" and err.value.attribute == "inputs:file"
    assert "missing.png" in str(err.value) and err.value.file == path


def test_unreadable_texture_uses_fallback_or_fails_under_strict(tmp_path):
    path = _textured_stage(tmp_path)
    (tmp_path / "tex" / "wood.png").write_bytes(b"\x89PNG but truncated")
    d = load_stage(path)
    diffuse = _material_of(d, "/Q").diffuse_color
    assert diffuse.texture is None and diffuse.value == pytest.approx((0.3, 0.4, 0.5))
    hits = [w for w in d.warnings if "wood.png" in w]
    assert len(hits) == 1 and "cannot read image" in hits[0]
    with pytest.raises(StageError, match="cannot read image") as err:
        load_stage(path, strict=True)
    assert (err.value.file, err.value.prim, err.value.attribute) == (path, "/Looks/Wood/Tex", "inputs:file")


def test_unsupported_surface_shader_warns_and_falls_back(stage):
    mat = UsdShade.Material.Define(stage, "/Looks/Custom")
    sh = UsdShade.Shader.Define(stage, "/Looks/Custom/S")
    sh.CreateIdAttr("MyStudioShader")
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    q = add_quad(stage, "/Q")
    UsdGeom.Gprim(q).CreateDisplayColorPrimvar().Set([(0, 0, 1)])
    bind(q, mat)
    d = read(stage)
    assert _material_of(d, "/Q").diffuse_color.value == (0.0, 0.0, 1.0)
    assert any("MyStudioShader" in w for w in d.warnings)


def test_non_finite_input_is_an_error(stage):
    mat, _ = preview_material(stage, "/Looks/Bad", roughness=(FLOAT, float("nan")))
    bind(add_quad(stage, "/Q"), mat)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Looks/Bad/PBR", "inputs:roughness")


def test_nodegraph_interface_inputs_are_followed(stage):
    mat, pbr = preview_material(stage, "/Looks/M")
    ng = UsdShade.NodeGraph.Define(stage, "/Looks/M/Tint")
    # Material input -> NodeGraph interface input -> constant shader input inside the graph
    m_in = mat.CreateInput("tint", COLOR3)
    m_in.Set((0.1, 0.2, 0.3))
    ng_in = ng.CreateInput("tint", COLOR3)
    ng_in.ConnectToSource(m_in)
    ng_out = ng.CreateOutput("out", COLOR3)
    ng_out.ConnectToSource(ng_in)
    pbr.CreateInput("diffuseColor", COLOR3).ConnectToSource(ng_out)
    bind(add_quad(stage, "/Q"), mat)
    diffuse = _material_of(read(stage), "/Q").diffuse_color
    assert diffuse.texture is None and diffuse.value == pytest.approx((0.1, 0.2, 0.3))


def test_unusable_material_warns_once_per_material(stage):
    mat = UsdShade.Material.Define(stage, "/Looks/Empty")  # no surface output at all
    for k in range(5):
        bind(add_quad(stage, f"/Q{k}"), mat)
    d = read(stage)
    assert [w for w in d.warnings if "/Looks/Empty" in w] == [
        "/Looks/Empty: material has no universal surface output; using displayColor/grey"]
    assert len(d.materials) == 1
