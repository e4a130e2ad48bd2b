"""UsdPrimvarReader_* nodes on UsdPreviewSurface inputs: the primvar is interpolated per hit like st
(vertex, faceVarying, uniform, constant), through NodeGraphs, with the reader's fallback where
the gprim lacks it. Checked at known hit points: the primvars are linear functions of position,
so the exact per-hit value is known from the hit point alone."""

from __future__ import annotations

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

from renderer.geometry import surface_interaction
from renderer.materials import MaterialTable
from renderer.scene import build_geometry
from renderer.textures import TextureCache

from .helpers import add_mesh, bind, grid, new_stage, read

TEXTURE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "stages", "textures", "checker.png")


def _material(stage, path, wiring, nodegraph=False):
    """A UsdPreviewSurface whose inputs come from primvar readers.
    wiring: {input name: (sdf type of the input, reader id, varname, fallback or None)}."""
    mat = UsdShade.Material.Define(stage, path)
    pbr = UsdShade.Shader.Define(stage, f"{path}/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    parent = f"{path}/NG" if nodegraph else path
    ng = UsdShade.NodeGraph.Define(stage, parent) if nodegraph else None
    for name, (vtype, reader_id, varname, fallback) in wiring.items():
        reader = UsdShade.Shader.Define(stage, f"{parent}/Read_{name}")
        reader.CreateIdAttr(reader_id)
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set(varname)
        if fallback is not None:
            reader.CreateInput("fallback", fallback[0]).Set(fallback[1])
        out = reader.CreateOutput("result", vtype)
        if ng is not None:
            ng_out = ng.CreateOutput(name, vtype)
            ng_out.ConnectToSource(out)
            out = ng_out
        pbr.CreateInput(name, vtype).ConnectToSource(out)
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    return mat


def _hits(desc, n=400, seed=3):
    """Random hits on every triangle: (material ids, per-hit coordinates, hit points)."""
    g = build_geometry(desc)
    rng = np.random.default_rng(seed)
    prim = rng.integers(0, g.count, n)
    b = rng.random((n, 2))
    b = np.where(b.sum(axis=1, keepdims=True) > 1.0, 1.0 - b, b)
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    p, _ng, _ns, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, prim, b[:, 0], b[:, 1], d)
    return g.material[prim], st, p


def _grid_mesh(stage, path, n=4):
    pts, counts, idx = grid(n)
    return add_mesh(stage, path, pts, counts, idx), pts, counts, idx


@pytest.mark.parametrize("interpolation", ["vertex", "faceVarying"])
@pytest.mark.parametrize("nodegraph", [False, True])
def test_vertex_and_face_varying_primvars_are_interpolated_per_hit(interpolation, nodegraph):
    stage = new_stage()
    m, pts, _counts, idx = _grid_mesh(stage, "/G")
    colour = lambda q: np.c_[q[:, 0] / 3.0, q[:, 1] / 3.0, np.full(len(q), 0.25)]  # noqa: E731
    rough = lambda q: 0.1 + 0.2 * q[:, 0]  # noqa: E731
    api = UsdGeom.PrimvarsAPI(m)
    where = pts if interpolation == "vertex" else pts[idx]
    api.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, interpolation).Set(
        Vt.Vec3fArray.FromNumpy(colour(where).astype(np.float32)))
    api.CreatePrimvar("rough", Sdf.ValueTypeNames.FloatArray, interpolation).Set(
        Vt.FloatArray.FromNumpy(rough(where).astype(np.float32)))
    bind(m, _material(stage, "/M", {
        "diffuseColor": (Sdf.ValueTypeNames.Color3f, "UsdPrimvarReader_float3", "displayColor", None),
        "roughness": (Sdf.ValueTypeNames.Float, "UsdPrimvarReader_float", "primvars:rough", None)},
        nodegraph=nodegraph))
    d = read(stage)
    assert [w for w in d.warnings if "no lights" not in w] == []  # the stage has no light
    mat, st, p = _hits(d)
    params = MaterialTable.build(d.materials, TextureCache()).evaluate(mat, st)
    np.testing.assert_allclose(params.diffuse, colour(p), atol=1e-6)
    np.testing.assert_allclose(params.roughness, rough(p), atol=1e-6)


def test_uniform_and_constant_primvars_and_the_fallback():
    stage = new_stage()
    m, _pts, counts, _idx = _grid_mesh(stage, "/G")  # 9 faces
    api = UsdGeom.PrimvarsAPI(m)
    face_metal = np.linspace(0.0, 0.8, len(counts))
    api.CreatePrimvar("metal", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform).Set(
        Vt.FloatArray.FromNumpy(face_metal.astype(np.float32)))
    api.CreatePrimvar("glow", Sdf.ValueTypeNames.Float4Array, UsdGeom.Tokens.constant).Set([(0.5, 0.25, 0.125, 9.0)])
    api.CreatePrimvar("layer", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.constant).Set([1])
    bind(m, _material(stage, "/M", {
        "metallic": (Sdf.ValueTypeNames.Float, "UsdPrimvarReader_float", "metal", None),
        "emissiveColor": (Sdf.ValueTypeNames.Color3f, "UsdPrimvarReader_float4", "glow", None),
        "opacity": (Sdf.ValueTypeNames.Float, "UsdPrimvarReader_int", "layer", None),
        # absent on the gprim: the reader's authored fallback, broadcast to RGB
        "diffuseColor": (Sdf.ValueTypeNames.Color3f, "UsdPrimvarReader_float", "nowhere",
                         (Sdf.ValueTypeNames.Float, 0.7))}))
    d = read(stage)
    mat, st, p = _hits(d)
    table = MaterialTable.build(d.materials, TextureCache())
    params = table.evaluate(mat, st)
    # grid(4): face f covers x in [f // 3, f // 3 + 1], y in [f % 3, f % 3 + 1]
    face = (np.floor(np.clip(p[:, 0], 0, 2.999)) * 3 + np.floor(np.clip(p[:, 1], 0, 2.999))).astype(int)
    np.testing.assert_allclose(params.metallic, face_metal[face], atol=1e-6)
    np.testing.assert_allclose(params.emission, np.tile([0.5, 0.25, 0.125], (len(mat), 1)), atol=1e-7)
    np.testing.assert_allclose(params.opacity, 1.0)
    np.testing.assert_allclose(params.diffuse, 0.7, atol=1e-7)
    assert table.has_emission and not table.bsdf_is_constant
    # No per-hit coordinates at all (st None): every primvar input takes its fallback.
    bare = table.evaluate(mat, None)
    np.testing.assert_allclose(bare.metallic, 0.0) and np.testing.assert_allclose(bare.diffuse, 0.7, atol=1e-7)


def test_constant_primvar_on_an_implicit_prim_and_inherited():
    stage = new_stage()
    UsdGeom.PrimvarsAPI(UsdGeom.Xform.Define(stage, "/Parent")).CreatePrimvar(
        "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(0.2, 0.4, 0.6)])
    ball = UsdGeom.Sphere.Define(stage, "/Parent/Ball")
    bind(ball, _material(stage, "/M", {
        "diffuseColor": (Sdf.ValueTypeNames.Color3f, "UsdPrimvarReader_float3", "displayColor", None)}))
    d = read(stage)
    mat, st, _p = _hits(d, 50)
    params = MaterialTable.build(d.materials, TextureCache()).evaluate(mat, st)
    np.testing.assert_allclose(params.diffuse, np.tile([0.2, 0.4, 0.6], (50, 1)), atol=1e-7)


def test_float2_into_a_colour_warns_and_keeps_the_default():
    stage = new_stage()
    m, *_ = _grid_mesh(stage, "/G")
    bind(m, _material(stage, "/M", {
        "diffuseColor": (Sdf.ValueTypeNames.Float2, "UsdPrimvarReader_float2", "st", None)}))
    d = read(stage)
    assert d.materials[0].diffuse_color.primvar is None
    assert d.materials[0].diffuse_color.value == pytest.approx((0.18, 0.18, 0.18))
    assert sum("UsdPrimvarReader_float2 (2 components) cannot feed" in w for w in d.warnings) == 1


def test_render_with_display_color_reader_matches_the_authored_colour(tmp_path):
    """End to end: a floor whose diffuseColor reads a constant displayColor renders as the same
    floor with that colour authored on diffuseColor (same seed: the same samples)."""
    from renderer.render import RenderOptions, render
    from tests.stage_builders import quad_light_stage

    images = []
    for through_reader in (False, True):
        path = str(tmp_path / f"floor{int(through_reader)}.usda")
        stage = quad_light_stage(path)
        floor = stage.GetPrimAtPath("/World/Floor")
        if through_reader:
            UsdGeom.PrimvarsAPI(floor).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                      UsdGeom.Tokens.constant).Set([(0.8, 0.3, 0.1)])
            mat = _material(stage, "/World/Looks/FromPrimvar", {
                "diffuseColor": (Sdf.ValueTypeNames.Color3f, "UsdPrimvarReader_float3", "displayColor", None)})
        else:
            mat = UsdShade.Material.Define(stage, "/World/Looks/Authored")
            pbr = UsdShade.Shader.Define(stage, "/World/Looks/Authored/PBR")
            pbr.CreateIdAttr("UsdPreviewSurface")
            pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.8, 0.3, 0.1))
            mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        bind(floor, mat)
        stage.GetRootLayer().Save()
        result = render(path, RenderOptions(spp=4, threads=1, seed=2, max_depth=2, resolution=(12, 12)))
        assert not any("Reader" in w for w in result.warnings)
        images.append(result.film.image())
    assert images[0].max() > 0.0 and images[0][..., 0].mean() > 2.0 * images[0][..., 2].mean()
    np.testing.assert_allclose(images[1], images[0], rtol=1e-6, atol=1e-9)


def test_unknown_node_on_a_texture_constant_input_warns_once():
    """UsdUVTexture inputs illum reads as constants (scale here) fed by a node it does not
    evaluate: one warning naming the node and the input, and the input's default."""
    stage = new_stage()
    mats = []
    for k in range(2):
        mat = UsdShade.Material.Define(stage, f"/M{k}")
        pbr = UsdShade.Shader.Define(stage, f"/M{k}/PBR")
        pbr.CreateIdAttr("UsdPreviewSurface")
        tex = UsdShade.Shader.Define(stage, f"/M{k}/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(TEXTURE)
        reader = UsdShade.Shader.Define(stage, f"/M{k}/Scale")
        reader.CreateIdAttr("StudioNoise")
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).ConnectToSource(
            reader.CreateOutput("result", Sdf.ValueTypeNames.Float4))
        tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.1 * (k + 1), 0, 0, 1))
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        m, *_ = _grid_mesh(stage, f"/G{k}")
        bind(m, mat)
        mats.append(mat)
    d = read(stage)
    hits = [w for w in d.warnings if "feeding" in w and "inputs:scale" in w]
    assert len(hits) == 1 and "'StudioNoise'" in hits[0] and "(and 1 more like it)" in hits[0]
    assert all(m.diffuse_color.texture.scale == (1, 1, 1, 1) for m in d.materials if m.path)


@pytest.mark.parametrize("interpolation", ["uniform", "vertex"])
def test_unbound_mesh_shows_its_display_color_per_hit(interpolation):
    """No material: displayColor is the diffuse colour at each hit, per face or per vertex (not
    its first value for the whole mesh)."""
    stage = new_stage()
    m, pts, counts, _idx = _grid_mesh(stage, "/G")
    if interpolation == "vertex":
        colours = np.c_[pts[:, 0] / 3.0, pts[:, 1] / 3.0, np.full(len(pts), 0.5)]
    else:
        colours = np.c_[np.linspace(0.1, 0.9, len(counts)), np.zeros(len(counts)), np.full(len(counts), 0.5)]
    UsdGeom.PrimvarsAPI(m).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, interpolation).Set(
        Vt.Vec3fArray.FromNumpy(colours.astype(np.float32)))
    d = read(stage)
    mat, st, p = _hits(d)
    params = MaterialTable.build(d.materials, TextureCache()).evaluate(mat, st)
    if interpolation == "vertex":
        expected = np.c_[p[:, 0] / 3.0, p[:, 1] / 3.0, np.full(len(p), 0.5)]
    else:
        face = (np.floor(np.clip(p[:, 0], 0, 2.999)) * 3 + np.floor(np.clip(p[:, 1], 0, 2.999))).astype(int)
        expected = colours[face]
    np.testing.assert_allclose(params.diffuse, expected, atol=1e-6)


def test_string_reader_picks_each_gprims_texture_and_numeric_readers_its_scale(tmp_path):
    """UsdUVTexture.file from a UsdPrimvarReader_string and its scale from a
    UsdPrimvarReader_float4, evaluated per gprim from constant primvars: one material per
    distinct value; a gprim without the primvar gets the reader's fallback (no file: the
    texture's fallback, with a warning)."""
    import OpenImageIO as oiio

    (tmp_path / "maps").mkdir()
    for name, rgb in (("red.png", (1, 0, 0)), ("blue.png", (0, 0, 1))):
        pixels = np.tile(np.array(rgb, np.float32), (2, 2, 1))
        assert oiio.ImageBuf(pixels).write(str(tmp_path / "maps" / name), oiio.UINT8)
    stage = new_stage()
    mat = UsdShade.Material.Define(stage, "/Shared")
    pbr = UsdShade.Shader.Define(stage, "/Shared/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    tex = UsdShade.Shader.Define(stage, "/Shared/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.5, 0.5, 0.5, 1))
    name_reader = UsdShade.Shader.Define(stage, "/Shared/FileName")
    name_reader.CreateIdAttr("UsdPrimvarReader_string")
    name_reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("texFile")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).ConnectToSource(
        name_reader.CreateOutput("result", Sdf.ValueTypeNames.String))
    gain = UsdShade.Shader.Define(stage, "/Shared/Gain")
    gain.CreateIdAttr("UsdPrimvarReader_float4")
    gain.CreateInput("varname", Sdf.ValueTypeNames.String).Set("gain")
    gain.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(1, 1, 1, 1))
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).ConnectToSource(
        gain.CreateOutput("result", Sdf.ValueTypeNames.Float4))
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    for k, (file, gain_value) in enumerate([("./maps/red.png", (2, 2, 2, 1)), ("./maps/blue.png", None),
                                            ("./maps/red.png", (2, 2, 2, 1)), (None, None)]):
        m, *_ = _grid_mesh(stage, f"/G{k}")
        api = UsdGeom.PrimvarsAPI(m)
        if file is not None:
            api.CreatePrimvar("texFile", Sdf.ValueTypeNames.String, UsdGeom.Tokens.constant).Set(file)
        if gain_value is not None:
            api.CreatePrimvar("gain", Sdf.ValueTypeNames.Float4, UsdGeom.Tokens.constant).Set(Gf.Vec4f(*gain_value))
        bind(m, mat)
    layer = tmp_path / "s.usda"
    stage.GetRootLayer().Export(str(layer))
    from renderer.usd import load_stage

    d = load_stage(str(layer))
    inputs = [d.materials[next(m for m in d.meshes if m.path == f"/G{k}").material].diffuse_color for k in range(4)]
    assert inputs[0] == inputs[2] and len({id(d.materials[m.material]) for m in d.meshes}) == 3
    assert inputs[0].texture.file == str(tmp_path / "maps" / "red.png") and inputs[0].texture.scale == (2, 2, 2, 1)
    assert inputs[1].texture.file == str(tmp_path / "maps" / "blue.png") and inputs[1].texture.scale == (1, 1, 1, 1)
    assert inputs[3].texture is None and inputs[3].value == pytest.approx((0.5, 0.5, 0.5))
    assert sum("gives no path" in w for w in d.warnings) == 1


def test_textures_read_their_own_st_sets(tmp_path):
    """Two textures of one material read different st primvars (st and uv2), and another mesh's
    material reads uv2 alone: every texture is looked up at its own coordinates."""
    import OpenImageIO as oiio

    ramp = np.random.default_rng(5).random((8, 8, 3)).astype(np.float32)
    for name in ("a.exr", "b.exr"):
        assert oiio.ImageBuf(ramp[:, ::-1] if name == "b.exr" else ramp).write(str(tmp_path / name), oiio.HALF)
    stage = new_stage()

    def textured(path, wiring):
        mat = UsdShade.Material.Define(stage, path)
        pbr = UsdShade.Shader.Define(stage, f"{path}/PBR")
        pbr.CreateIdAttr("UsdPreviewSurface")
        for inp, (vtype, out, file, varname) in wiring.items():
            reader = UsdShade.Shader.Define(stage, f"{path}/St_{inp}")
            reader.CreateIdAttr("UsdPrimvarReader_float2")
            reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set(varname)
            tex = UsdShade.Shader.Define(stage, f"{path}/Tex_{inp}")
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(tmp_path / file))
            tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
                reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
            pbr.CreateInput(inp, vtype).ConnectToSource(tex.CreateOutput(out, vtype))
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        return mat

    both = textured("/Both", {"diffuseColor": (Sdf.ValueTypeNames.Color3f, "rgb", "a.exr", "st"),
                              "roughness": (Sdf.ValueTypeNames.Float, "r", "b.exr", "uv2")})
    only = textured("/Only", {"diffuseColor": (Sdf.ValueTypeNames.Color3f, "rgb", "b.exr", "uv2")})
    st_of = {"st": lambda q: np.c_[q[:, 0] / 3.0, q[:, 1] / 3.0], "uv2": lambda q: np.c_[q[:, 1] / 3.0, 1 - q[:, 0] / 3.0]}
    for path, mat in (("/G0", both), ("/G1", only)):
        m, pts, *_ = _grid_mesh(stage, path)
        for name, f in st_of.items():
            UsdGeom.PrimvarsAPI(m).CreatePrimvar(name, Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set(
                Vt.Vec2fArray.FromNumpy(f(pts).astype(np.float32)))
        bind(m, mat)
    d = read(stage)
    assert not any("st primvar" in w for w in d.warnings), d.warnings
    mat, st, p = _hits(d, 600)
    table = MaterialTable.build(d.materials, TextureCache())
    params = table.evaluate(mat, st)
    cache = TextureCache()
    by_path = {d.materials[i].path: i for i in range(len(d.materials))}
    for path, checks in (("/Both", (("diffuse", "diffuse_color", "st"), ("roughness", "roughness", "uv2"))),
                         ("/Only", (("diffuse", "diffuse_color", "uv2"),))):
        rows = mat == by_path[path]
        assert rows.sum() > 50
        for field, attr, st_name in checks:
            tex = getattr(d.materials[by_path[path]], attr).texture
            assert tex.st_primvar == st_name
            expected = cache.lookup(tex, st_of[st_name](p[rows]))
            got = getattr(params, field)[rows]
            np.testing.assert_allclose(got, expected[:, :3] if got.ndim == 2 else expected[:, 0], atol=1e-5)
