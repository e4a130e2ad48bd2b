"""`.usdz` packages: every asset (UsdUVTexture, DomeLight and RectLight textures, IES profiles) is
resolved through USD's asset resolver and read from inside the package, and a packaged stage
reads and renders exactly as the same stage unpacked."""

from __future__ import annotations

import os
import shutil

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade, UsdUtils

from renderer.lights.texture import load_texture_rgb
from renderer.render import RenderOptions, render
from renderer.textures import TextureCache
from renderer.usd import load_stage
from tests.stage_builders import add_camera, add_settings, bind, new_stage, textured_quad, uv_texture

IES = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", "stages", "ies", "narrow_spot.ies"))


def _write_image(path, pixels, fmt=oiio.UINT8):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    assert oiio.ImageBuf(np.ascontiguousarray(pixels, dtype=np.float32)).write(str(path), fmt)


def _textured_stage(src) -> str:
    """A textured quad lit by a textured dome and an IES-shaped textured rect light, its assets
    in subdirectories next to the layer. Returns the layer's path."""
    rng = np.random.default_rng(7)
    _write_image(src / "maps" / "albedo.png", rng.random((8, 16, 3)))
    sky = np.ones((8, 16, 3)) * 0.2
    sky[:4] = (0.9, 0.6, 0.3)
    _write_image(src / "env" / "sky.exr", sky, oiio.HALF)
    _write_image(src / "maps" / "panel.png", rng.random((4, 4, 3)))
    os.makedirs(src / "ies", exist_ok=True)
    shutil.copy(IES, src / "ies" / "spot.ies")

    path = str(src / "scene.usda")
    stage = new_stage(path)
    add_camera(stage, pos=(0, 0, 4))
    add_settings(stage, (16, 16))
    quad = textured_quad(stage, "/World/Quad")
    mat = UsdShade.Material.Define(stage, "/World/Looks/Tex")
    pbr = UsdShade.Shader.Define(stage, "/World/Looks/Tex/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    tex = uv_texture(stage, "/World/Looks/Tex", "Albedo", "./maps/albedo.png", (1, 0, 1, 1))
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
    bind(quad.GetPrim(), mat)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateTextureFileAttr("./env/sky.exr")
    dome.CreateTextureFormatAttr("latlong")
    rect = UsdLux.RectLight.Define(stage, "/World/Panel")
    rect.CreateTextureFileAttr("./maps/panel.png")
    rect.CreateIntensityAttr(4.0)
    UsdGeom.Xformable(rect).AddTranslateOp().Set(Gf.Vec3d(0, 0, 2))
    shaping = UsdLux.ShapingAPI.Apply(rect.GetPrim())
    shaping.CreateShapingIesFileAttr("./ies/spot.ies")
    stage.GetRootLayer().Save()
    return path


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """(unpacked layer, the same stage packaged as a .usdz)."""
    root = tmp_path_factory.mktemp("usdz")
    src = _textured_stage(root / "src")
    pkg = str(root / "scene.usdz")
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(src), pkg)
    return src, pkg


def test_assets_are_read_from_inside_the_package(pair):
    src, pkg = pair
    plain, packed = load_stage(src), load_stage(pkg)
    assert packed.warnings == plain.warnings == []
    tex_plain = plain.materials[0].diffuse_color.texture
    tex_packed = packed.materials[0].diffuse_color.texture
    # Package-relative identifiers, with the bytes read through Ar; files on disk keep no bytes.
    assert tex_packed.file.startswith(pkg + "[") and tex_packed.data is not None
    assert tex_plain.data is None and os.path.isfile(tex_plain.file)
    with open(tex_plain.file, "rb") as fh:
        assert fh.read() == tex_packed.data
    # OpenImageIO decodes the packaged texture to the very texels of the unpacked one.
    st = np.random.default_rng(1).random((500, 2))
    assert np.array_equal(TextureCache().lookup(tex_packed, st), TextureCache().lookup(tex_plain, st))
    lights = {(l.path, l.kind): l for l in packed.lights}
    plain_lights = {(l.path, l.kind): l for l in plain.lights}
    for key in (("/World/Sky", "dome"), ("/World/Panel", "rect")):
        a, b = lights[key], plain_lights[key]
        assert a.texture_file.startswith(pkg + "[") and a.texture_data is not None
        assert np.array_equal(load_texture_rgb(a.texture_file, a.path, data=a.texture_data),
                              load_texture_rgb(b.texture_file, b.path))
    ies_a = lights[("/World/Panel", "rect")].shaping
    ies_b = plain_lights[("/World/Panel", "rect")].shaping
    assert ies_a.ies_file.startswith(pkg + "[")
    assert np.array_equal(ies_a.ies_profile.candela, ies_b.ies_profile.candela)


def test_packaged_stage_renders_as_unpacked(pair):
    src, pkg = pair
    opts = RenderOptions(spp=2, threads=1, seed=3, max_depth=2, resolution=(12, 12))
    a = render(src, opts).film.image()
    b = render(pkg, opts).film.image()
    assert np.all(np.isfinite(a)) and a.max() > 0.0
    assert np.array_equal(a, b)


def package_without_albedo(tmp_path) -> str:
    """The textured stage packaged, then repackaged with its albedo texture left out of the zip
    (the material's path still points inside the package). Returns the broken package."""
    import zipfile

    src = _textured_stage(tmp_path / "src")
    pkg = str(tmp_path / "scene.usdz")
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(src), pkg)
    broken = str(tmp_path / "broken.usdz")
    with zipfile.ZipFile(pkg) as zin, zipfile.ZipFile(broken, "w", zipfile.ZIP_STORED) as zout:
        for item in zin.infolist():
            if not item.filename.endswith("albedo.png"):
                zout.writestr(item, zin.read(item.filename))
    return broken


def test_missing_file_inside_a_package_uses_the_fallback(tmp_path):
    desc = load_stage(package_without_albedo(tmp_path))
    diffuse = desc.materials[0].diffuse_color
    assert diffuse.texture is None and diffuse.value == (1.0, 0.0, 1.0)
    hits = [w for w in desc.warnings if "albedo.png" in w]
    assert len(hits) == 1 and "file not found" in hits[0] and "/World/Looks/Tex/Albedo.inputs:file" in hits[0]
