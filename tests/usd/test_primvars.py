"""Normals (every interpolation, primvars:normals precedence, transforms) and st."""

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

from .helpers import add_mesh, add_quad, mesh, preview_material, bind, read

# Two quads side by side: 6 points, 2 faces, 8 corners, 4 triangles.
PTS = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (2, 1, 0)]
COUNTS = [4, 4]
INDICES = [0, 1, 4, 3, 1, 2, 5, 4]


def _dirs(n: int) -> np.ndarray:
    """n distinct unit directions, all with positive z."""
    k = np.arange(n, dtype=float)
    v = np.stack([np.cos(k), np.sin(k), np.full(n, 2.0)], axis=1)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _two_quads(stage, path="/M"):
    return add_mesh(stage, path, PTS, COUNTS, INDICES)


def _corner_ids(m):
    """For each output triangle corner: (point id, face id, corner id) recovered from positions."""
    pts = np.asarray(PTS, float)
    point_id = np.array([[int(np.argmin(np.linalg.norm(pts - m.points[v], axis=1))) for v in tri]
                         for tri in m.triangles])
    face_id = (m.points[m.triangles].mean(axis=1)[:, 0] > 1.0).astype(int)
    corner_id = np.zeros_like(point_id)
    for t in range(len(point_id)):
        f = face_id[t]
        face_pts = INDICES[4 * f: 4 * f + 4]
        corner_id[t] = [4 * f + face_pts.index(p) for p in point_id[t]]
    return point_id, face_id, corner_id


@pytest.mark.parametrize("interp", ["constant", "uniform", "vertex", "varying", "faceVarying"])
def test_normals_every_interpolation(stage, interp):
    m = _two_quads(stage)
    n = {"constant": 1, "uniform": 2, "vertex": 6, "varying": 6, "faceVarying": 8}[interp]
    values = _dirs(n)
    m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
    m.SetNormalsInterpolation(interp)
    d = mesh(read(stage), "/M")
    assert d.normals.shape == (4, 3, 3) and d.normals.dtype == np.float32
    point_id, face_id, corner_id = _corner_ids(d)
    elem = {"constant": np.zeros_like(point_id), "uniform": np.repeat(face_id[:, None], 3, 1),
            "vertex": point_id, "varying": point_id, "faceVarying": corner_id}[interp]
    assert np.allclose(d.normals, values[elem], atol=1e-6)


def test_primvars_normals_win_over_normals_and_may_be_indexed(stage):
    m = _two_quads(stage)
    m.CreateNormalsAttr([(0, 0, 1)] * 6)
    m.SetNormalsInterpolation("vertex")
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, "faceVarying")
    pv.Set([(1, 0, 0), (0, 1, 0)])
    pv.SetIndices(Vt.IntArray([0, 0, 0, 0, 1, 1, 1, 1]))
    d = mesh(read(stage), "/M")
    _, face_id, _ = _corner_ids(d)
    expect = np.where(face_id[:, None, None] == 0, [1, 0, 0], [0, 1, 0])
    assert np.allclose(d.normals, np.broadcast_to(expect, d.normals.shape))


def test_no_authored_normals_gives_none(stage):
    _two_quads(stage)
    assert mesh(read(stage), "/M").normals is None


def test_wrong_sized_normals_are_dropped_with_warning(stage):
    m = _two_quads(stage)
    m.CreateNormalsAttr([(0, 0, 1)] * 3)
    m.SetNormalsInterpolation("vertex")
    d = read(stage)
    assert mesh(d, "/M").normals is None
    assert any("normals" in w and "3 elements" in w for w in d.warnings)


def test_normals_use_inverse_transpose_and_stay_unit(stage):
    m = add_quad(stage, "/M")
    m.CreateNormalsAttr([(1, 0, 1)] * 4)
    m.SetNormalsInterpolation("vertex")
    UsdGeom.Xformable(m).AddScaleOp().Set(Gf.Vec3f(4, 1, 1))
    d = mesh(read(stage), "/M")
    expect = np.array([0.25, 0.0, 1.0]) / np.linalg.norm([0.25, 0.0, 1.0])
    assert np.allclose(d.normals, expect, atol=1e-6)
    assert np.allclose(d.points[:, 0].max(), 4.0)


@pytest.mark.parametrize("interp,indexed", [("vertex", False), ("faceVarying", True), ("faceVarying", False),
                                            ("uniform", False), ("constant", False)])
def test_st_any_interpolation(stage, interp, indexed):
    m = _two_quads(stage)
    n = {"constant": 1, "uniform": 2, "vertex": 6, "faceVarying": 8}[interp]
    values = np.stack([np.arange(n) * 0.1, np.arange(n) * 0.01 + 0.5], axis=1).astype(np.float32)
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    if indexed:
        # store the values reversed and point at them through indices
        pv.Set(Vt.Vec2fArray.FromNumpy(values[::-1].copy()))
        pv.SetIndices(Vt.IntArray.FromNumpy(np.arange(n - 1, -1, -1).astype(np.int32)))
    else:
        pv.Set(Vt.Vec2fArray.FromNumpy(values))
    d = mesh(read(stage), "/M")
    point_id, face_id, corner_id = _corner_ids(d)
    elem = {"constant": np.zeros_like(point_id), "uniform": np.repeat(face_id[:, None], 3, 1),
            "vertex": point_id, "faceVarying": corner_id}[interp]
    assert d.st.shape == (4, 3, 2) and d.st.dtype == np.float32
    assert np.allclose(d.st, values[elem])


@pytest.mark.parametrize("varname", ["uv", "primvars:uv"])
def test_texture_without_file_gives_its_fallback_and_default_st(stage, varname):
    m = _two_quads(stage)
    api = UsdGeom.PrimvarsAPI(m)
    api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set([(9, 9)] * 6)
    api.CreatePrimvar("uv", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set([(k, 0) for k in range(6)])
    mat, shader = preview_material(stage, "/Mat")
    reader = UsdShade.Shader.Define(stage, "/Mat/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(varname)
    tex = UsdShade.Shader.Define(stage, "/Mat/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    # no file: the texture outputs its fallback, but the mesh still reads the named primvar
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(""))
    bind(m, mat)
    d = read(stage)
    # a texture without file carries no TextureDesc, so the mesh keeps the default 'st' name
    assert np.allclose(mesh(d, "/M").st, 9.0)
    diffuse = d.materials[mesh(d, "/M").material].diffuse_color
    assert diffuse.texture is None and diffuse.value == (0.0, 0.0, 0.0)  # UsdUVTexture fallback rgb
    assert any("no inputs:file" in w for w in d.warnings)


@pytest.mark.parametrize("varname", ["uv", "primvars:uv"])
def test_st_primvar_name_from_textured_material(tmp_path, varname):
    from .helpers import new_stage

    import OpenImageIO as oiio

    assert oiio.ImageBuf(np.full((2, 2, 3), 0.5, np.float32)).write(str(tmp_path / "t.png"), oiio.UINT8)
    stage = new_stage()
    m = _two_quads(stage)
    api = UsdGeom.PrimvarsAPI(m)
    api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set([(9, 9)] * 6)
    api.CreatePrimvar("uv", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set([(k, 0) for k in range(6)])
    mat, shader = preview_material(stage, "/Mat")
    reader = UsdShade.Shader.Define(stage, "/Mat/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(varname)
    tex = UsdShade.Shader.Define(stage, "/Mat/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(tmp_path / "t.png"))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    bind(m, mat)
    d = read(stage)
    assert d.materials[mesh(d, "/M").material].diffuse_color.texture.st_primvar == "uv"
    st = mesh(d, "/M").st
    point_id, _, _ = _corner_ids(mesh(d, "/M"))
    assert np.allclose(st[..., 0], point_id) and np.allclose(st[..., 1], 0.0)


def test_left_handed_keeps_attributes_on_their_corners(stage):
    m = add_quad(stage, "/L")
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex").Set(
        [(0, 0), (1, 0), (1, 1), (0, 1)])
    d = mesh(read(stage), "/L")
    # st still equals the xy of the corner's point after the winding flip
    assert np.allclose(d.st, d.points[d.triangles][..., :2])
