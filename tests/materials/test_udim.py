"""UDIM textures (a ``<UDIM>`` file path: tiles 1001 + u + 10 v) and the useMetadata wrap warning."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade

from renderer.render import RenderOptions, render
from renderer.textures import TextureCache
from renderer.usd import load_stage
from tests.stage_builders import add_camera, add_settings, bind, new_stage, uv_texture

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FALLBACK = (1.0, 0.0, 1.0, 1.0)
TILES = {1001: (0.8, 0.1, 0.1), 1002: (0.1, 0.7, 0.2), 1012: (0.2, 0.3, 0.9)}


def _write(path, rgb, size=(4, 4)):
    px = np.broadcast_to(np.asarray(rgb, dtype=np.float32), (*size, 3))
    assert oiio.ImageBuf(np.ascontiguousarray(px)).write(str(path), oiio.FLOAT)


def _emissive_quad_stage(path, file, st, wrap="repeat", res=(40, 20), extent=(2.0, 1.0)):
    """A quad filling the frame whose emissiveColor (black diffuse, no lights) reads ``file``:
    each pixel shows the texture's value exactly."""
    stage = new_stage(str(path))
    w, h = extent
    cam = add_camera(stage, pos=(0, 0, 10), focal=50.0, aperture=9.0 * w)  # sees 90 % of the quad
    cam.GetVerticalApertureAttr().Set(9.0 * h)
    add_settings(stage, res)
    quad = UsdGeom.Mesh.Define(stage, "/World/Quad")
    quad.CreatePointsAttr([(-w, -h, 0), (w, -h, 0), (w, h, 0), (-w, h, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr("none")
    pv = UsdGeom.PrimvarsAPI(quad).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set([Gf.Vec2f(*p) for p in st])
    mat = UsdShade.Material.Define(stage, "/World/Looks/Glow")
    pbr = UsdShade.Shader.Define(stage, "/World/Looks/Glow/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    tex = uv_texture(stage, "/World/Looks/Glow", "Tex", file, FALLBACK, wrap)
    pbr.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    bind(quad.GetPrim(), mat)
    stage.GetRootLayer().Save()
    return str(path)


@pytest.fixture
def udim_dir(tmp_path):
    os.makedirs(tmp_path / "maps")
    for tile, rgb in TILES.items():
        _write(tmp_path / "maps" / f"paint.{tile}.exr", rgb)
    return tmp_path


def test_reader_finds_every_tile(udim_dir):
    path = _emissive_quad_stage(udim_dir / "s.usda", "./maps/paint.<UDIM>.exr", [(0, 0), (2, 0), (2, 1), (0, 1)])
    desc = load_stage(path)
    (tex,) = [m.emissive_color.texture for m in desc.materials if m.emissive_color.texture is not None]
    assert tex.file.endswith("paint.<UDIM>.exr")
    assert [t for t, _ in tex.udim_tiles] == sorted(TILES)
    assert all(f.endswith(f"paint.{t}.exr") for t, f in tex.udim_tiles)
    assert not any("UDIM" in w for w in desc.warnings), desc.warnings


def test_lookup_picks_the_tile_and_falls_back_off_the_tiles(udim_dir):
    path = _emissive_quad_stage(udim_dir / "s.usda", "./maps/paint.<UDIM>.exr", [(0, 0), (2, 0), (2, 1), (0, 1)])
    (tex,) = [m.emissive_color.texture for m in load_stage(path).materials if m.emissive_color.texture is not None]
    cache = TextureCache()
    cache.add(tex)
    st = np.array([[0.5, 0.5], [1.5, 0.5], [1.25, 1.75], [0.5, 1.5], [10.5, 0.5], [-0.5, 0.5], [np.nan, 0.2],
                   [0.999, 0.999], [1.001, 0.001]])
    out = cache.lookup(tex, st)
    want = [TILES[1001], TILES[1002], TILES[1012], FALLBACK[:3], FALLBACK[:3], FALLBACK[:3], FALLBACK[:3],
            TILES[1001], TILES[1002]]
    np.testing.assert_allclose(out[:, :3], want, rtol=1e-6)
    # Tiles do not filter into each other: each is clamped at its own edges.
    assert np.all(out[:, 3] == 1.0)


def test_render_shows_each_tile_where_its_st_lands(udim_dir):
    path = _emissive_quad_stage(udim_dir / "s.usda", "./maps/paint.<UDIM>.exr", [(0, 0), (2, 0), (2, 1), (0, 1)])
    img = render(path, RenderOptions(spp=1, max_depth=1, threads=1, seed=1, pixel_filter="box",
                                     pixel_filter_width=0.5)).film.image()
    h, w = img.shape[:2]
    # The quad fills the frame: left half tile 1001 (s in [0, 1)), right half 1002.
    left, right = img[2:h - 2, 2:w // 2 - 2, :3], img[2:h - 2, w // 2 + 2:w - 2, :3]
    np.testing.assert_allclose(left.reshape(-1, 3), np.broadcast_to(TILES[1001], (left.size // 3, 3)), rtol=1e-5)
    np.testing.assert_allclose(right.reshape(-1, 3), np.broadcast_to(TILES[1002], (right.size // 3, 3)), rtol=1e-5)


def test_no_tile_follows_the_missing_asset_policy(tmp_path):
    path = _emissive_quad_stage(tmp_path / "s.usda", "./maps/none.<UDIM>.exr", [(0, 0), (1, 0), (1, 1), (0, 1)])
    desc = load_stage(path)
    assert all(m.emissive_color.texture is None for m in desc.materials)
    (w,) = [w for w in desc.warnings if "UDIM" in w]
    assert "no UDIM tile found (1001-1100)" in w and "/World/Looks/Glow/Tex" in w and "inputs:file" in w
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", path, "-o", str(tmp_path / "o.exr"),
                        "--strict", "--spp", "1"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    assert "no UDIM tile found" in r.stderr and "inputs:file" in r.stderr
    assert not (tmp_path / "o.exr").exists()


def test_use_metadata_without_metadata_warns_once_when_st_leaves_the_unit_square(tmp_path):
    _write(tmp_path / "plain.exr", (0.5, 0.5, 0.5))
    inside = _emissive_quad_stage(tmp_path / "in.usda", "./plain.exr", [(0, 0), (1, 0), (1, 1), (0, 1)],
                                  wrap="useMetadata")
    tiled = _emissive_quad_stage(tmp_path / "out.usda", "./plain.exr", [(0, 0), (3, 0), (3, 1), (0, 1)],
                                 wrap="useMetadata")
    repeat = _emissive_quad_stage(tmp_path / "rep.usda", "./plain.exr", [(0, 0), (3, 0), (3, 1), (0, 1)])
    opts = RenderOptions(spp=1, max_depth=1, threads=1, seed=1, resolution=(8, 4))
    assert not [w for w in render(inside, opts).warnings if "useMetadata" in w]
    assert not [w for w in render(repeat, opts).warnings if "useMetadata" in w]
    res = render(tiled, opts)
    (w,) = [w for w in res.warnings if "useMetadata" in w]
    assert "/World/Quad" in w and "inputs:wrapS" in w and "plain.exr" in w and "[0, 3]" in w
    # The spec's black, as warned: the right two thirds of the quad are black.
    img = res.film.image()
    assert img[:, -1, :3].max() == 0.0 and img[:, 0, :3].min() > 0.0


_MTLX = """<?xml version="1.0"?>
<materialx version="1.39">
  <image name="paint" type="color3">
    <input name="file" type="filename" value="maps/paint.&lt;UDIM&gt;.exr" colorspace="lin_rec709" />
  </image>
  <standard_surface name="surf" type="surfaceshader">
    <input name="base_color" type="color3" nodename="paint" />
  </standard_surface>
  <surfacematerial name="Paint" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="surf" />
  </surfacematerial>
</materialx>
"""


@pytest.mark.parametrize("where", ["document", "inline"])
def test_materialx_image_nodes_read_udim_tiles(udim_dir, where):
    """A MaterialX image node whose file holds <UDIM> (in a referenced .mtlx document, or as an
    inline ND_image_color3 shader) reads the same tiles as UsdUVTexture, and looks up the same."""
    stage = new_stage(str(udim_dir / "m.usda"))
    quad = UsdGeom.Mesh.Define(stage, "/World/Quad")
    quad.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if where == "document":
        (udim_dir / "looks.mtlx").write_text(_MTLX)
        stage.DefinePrim("/MaterialX").GetReferences().AddReference("./looks.mtlx", "/MaterialX")
        material = "/MaterialX/Materials/Paint"
    else:
        mat = UsdShade.Material.Define(stage, "/World/Looks/Paint")
        img = UsdShade.Shader.Define(stage, "/World/Looks/Paint/Image")
        img.CreateIdAttr("ND_image_color3")
        img.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./maps/paint.<UDIM>.exr")
        surf = UsdShade.Shader.Define(stage, "/World/Looks/Paint/Surf")
        surf.CreateIdAttr("ND_standard_surface_surfaceshader")
        surf.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).ConnectToSource(img.ConnectableAPI(), "out")
        mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf.ConnectableAPI(), "out")
        material = "/World/Looks/Paint"
    UsdShade.MaterialBindingAPI.Apply(quad.GetPrim())
    quad.GetPrim().CreateRelationship("material:binding").SetTargets([Sdf.Path(material)])
    stage.GetRootLayer().Save()
    desc = load_stage(str(udim_dir / "m.usda"))
    (mat,) = [m for m in desc.materials if m.path == material]
    tex = mat.diffuse_color.texture
    assert tex is not None, desc.warnings
    assert tex.file.endswith("paint.<UDIM>.exr")
    assert [t for t, _ in tex.udim_tiles] == sorted(TILES)
    assert not any("UDIM" in w for w in desc.warnings), desc.warnings
    cache = TextureCache()
    cache.add(tex)
    st = np.array([[0.5, 0.5], [1.5, 0.5], [1.25, 1.75], [10.5, 0.5]])
    out = cache.lookup(tex, st)[:, :3]
    np.testing.assert_allclose(out[:3], [TILES[1001], TILES[1002], TILES[1012]], rtol=1e-6)
    # Off the tiles: the image node's default (black), not a tile.
    assert np.all(out[3] == 0.0)
