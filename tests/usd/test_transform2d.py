"""UsdTransform2d between the primvar reader and a UsdUVTexture (UsdPreviewSurface spec:
"result = in * scale * rotate + translation", rotation counter-clockwise in degrees)."""

from __future__ import annotations

import math

import numpy as np
from pxr import Gf, Sdf, UsdShade

from renderer.textures import TextureCache

from .helpers import add_quad, bind, mesh, preview_material, read


def _chain(stage, tmp_path, transforms):
    """Material whose diffuse texture reads st through the given UsdTransform2d nodes
    (listed from the reader toward the texture)."""
    import OpenImageIO as oiio

    img = np.zeros((4, 4, 3), dtype=np.float32)
    img[..., 0] = np.arange(4)[None, :]        # red = column
    img[..., 1] = np.arange(4)[::-1, None]     # green = row counted from the bottom (t)
    path = str(tmp_path / "ramp.exr")
    oiio.ImageBuf(img).write(path)
    mat, shader = preview_material(stage, "/Mat")
    reader = UsdShade.Shader.Define(stage, "/Mat/Reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    src = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for k, (scale, rotation, translation) in enumerate(transforms):
        node = UsdShade.Shader.Define(stage, f"/Mat/T{k}")
        node.CreateIdAttr("UsdTransform2d")
        node.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(src)
        node.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*scale))
        node.CreateInput("rotation", Sdf.ValueTypeNames.Float).Set(rotation)
        node.CreateInput("translation", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(*translation))
        src = node.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, "/Mat/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(path)
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(src)
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    return mat


def _expected(transforms, st):
    for scale, rotation, translation in transforms:  # reader -> texture order
        x, y = st[:, 0] * scale[0], st[:, 1] * scale[1]
        c, s = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
        st = np.stack([c * x - s * y + translation[0], s * x + c * y + translation[1]], axis=1)
    return st


def test_transform2d_chain_is_applied_to_st(stage, tmp_path):
    transforms = [((2.0, 0.5), 90.0, (0.25, 0.0)), ((1.0, 1.0), 0.0, (0.0, 0.125))]
    q = add_quad(stage, "/Q")
    bind(q, _chain(stage, tmp_path, transforms))
    d = read(stage)
    desc = d.materials[mesh(d, "/Q").material].diffuse_color.texture
    assert desc.st_primvar == "st" and len(desc.st_transform) == 6
    st = np.array([[0.1, 0.2], [0.3, 0.05], [0.6, 0.7]])
    want = _expected(transforms, st)
    cache = TextureCache()
    untransformed = type(desc)(**{**desc.__dict__, "st_transform": ()})
    np.testing.assert_allclose(cache.lookup(desc, st), cache.lookup(untransformed, want), atol=1e-12)
    assert not any("Transform2d" in w for w in d.warnings)


def test_no_transform_node_gives_identity(stage, tmp_path):
    q = add_quad(stage, "/Q")
    bind(q, _chain(stage, tmp_path, []))
    d = read(stage)
    assert d.materials[mesh(d, "/Q").material].diffuse_color.texture.st_transform == ()
