"""TextureCache: orientation, bilinear filtering, wrap modes, colour decoding, channels, errors."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer import textures as textures_mod
from renderer.description import TextureDesc
from renderer.errors import StageError
from renderer.textures import TextureCache, srgb_to_linear


_FORMATS = {
    np.dtype(np.uint8): oiio.UINT8,
    np.dtype(np.uint16): oiio.UINT16,
    np.dtype(np.float32): oiio.FLOAT,
}


def write_image(path, pixels: np.ndarray) -> str:
    """Write (H, W, C) pixels (row 0 = top, OIIO order) to path, values stored as given
    (unassociated alpha: OIIO must not un-premultiply them on write)."""
    px = np.ascontiguousarray(pixels)
    h, w, c = px.shape
    spec = oiio.ImageSpec(w, h, c, _FORMATS[px.dtype])
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None, oiio.geterror()
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(px), out.geterror()
    out.close()
    return str(path)


# A 2x2 image, OIIO rows top to bottom: top = (red, green), bottom = (blue, white).
RED, GREEN, BLUE, WHITE = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 1.0)


@pytest.fixture
def quad_exr(tmp_path):
    px = np.array([[RED, GREEN], [BLUE, WHITE]], dtype=np.float32)
    return write_image(tmp_path / "quad.exr", px)


def tex(path, **kw) -> TextureDesc:
    kw.setdefault("wrap_s", "clamp")
    kw.setdefault("wrap_t", "clamp")
    return TextureDesc(file=path, **kw)


def test_st_origin_is_bottom_left(quad_exr):
    cache = TextureCache()
    t = tex(quad_exr)
    st = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])
    out = cache.lookup(t, st)
    assert out.shape == (4, 4) and out.dtype == np.float64
    np.testing.assert_allclose(out[:, :3], [BLUE, WHITE, RED, GREEN])
    np.testing.assert_allclose(out[:, 3], 1.0)  # 3-channel file: alpha = 1


def test_bilinear_between_texel_centres(quad_exr):
    cache = TextureCache()
    t = tex(quad_exr)
    out = cache.lookup(t, np.array([[0.5, 0.5], [0.5, 0.25], [0.375, 0.25]]))
    np.testing.assert_allclose(out[0, :3], np.mean([RED, GREEN, BLUE, WHITE], axis=0))
    np.testing.assert_allclose(out[1, :3], np.mean([BLUE, WHITE], axis=0))
    # s = 0.375 is a quarter of the way from the centre of texel 0 (0.25) to texel 1 (0.75).
    np.testing.assert_allclose(out[2, :3], 0.75 * np.array(BLUE) + 0.25 * np.array(WHITE))


@pytest.fixture
def ramp_exr(tmp_path):
    """A 4x1 image with values 0, 1, 2, 3 (one channel): texel centres at s = 1/8, 3/8, 5/8, 7/8."""
    px = np.array([[[0.0], [1.0], [2.0], [3.0]]], dtype=np.float32)
    return write_image(tmp_path / "ramp.exr", px)


def _s(cache, t, s):
    st = np.stack([np.asarray(s, dtype=np.float64), np.full(len(s), 0.5)], axis=1)
    return cache.lookup(t, st)[:, 0]


def test_wrap_repeat(ramp_exr):
    c = TextureCache()
    t = tex(ramp_exr, wrap_s="repeat")
    s = np.array([1 / 8, 3 / 8, 5 / 8, 7 / 8])
    np.testing.assert_allclose(_s(c, t, s + 1.0), [0, 1, 2, 3])
    np.testing.assert_allclose(_s(c, t, s - 3.0), [0, 1, 2, 3])
    # Between the last and the first texel across the seam.
    np.testing.assert_allclose(_s(c, t, [1.0, 0.0]), [1.5, 1.5])


def test_wrap_clamp(ramp_exr):
    c = TextureCache()
    t = tex(ramp_exr, wrap_s="clamp")
    np.testing.assert_allclose(_s(c, t, [-5.0, 0.0, 1 / 8, 1.0, 7.5]), [0, 0, 0, 3, 3])


def test_wrap_mirror(ramp_exr):
    c = TextureCache()
    t = tex(ramp_exr, wrap_s="mirror")
    # [1, 2) is the image reversed; [-1, 0) too.
    np.testing.assert_allclose(_s(c, t, [1 + 1 / 8, 1 + 7 / 8, -1 / 8, 2 + 3 / 8]), [3, 0, 0, 1])
    # At s = 1 the two texels on either side of the edge are the same texel.
    np.testing.assert_allclose(_s(c, t, [1.0, 0.0]), [3.0, 0.0])


def test_wrap_black(ramp_exr):
    c = TextureCache()
    t = tex(ramp_exr, wrap_s="black")
    np.testing.assert_allclose(_s(c, t, [-0.5, 1.5, 7 / 8]), [0.0, 0.0, 3.0])
    # At the right edge: half texel 3, half black.
    np.testing.assert_allclose(_s(c, t, [1.0]), [1.5])
    # Alpha is black too outside the image.
    out = c.lookup(t, np.array([[-0.5, 0.5]]))
    np.testing.assert_allclose(out, [[0.0, 0.0, 0.0, 0.0]])


def test_wrap_modes_are_per_axis(tmp_path):
    px = np.array([[[1.0], [2.0]], [[3.0], [4.0]]], dtype=np.float32)  # top row 1 2, bottom 3 4
    path = write_image(tmp_path / "a.exr", px)
    c = TextureCache()
    t = tex(path, wrap_s="repeat", wrap_t="black")
    out = c.lookup(t, np.array([[1.25, 0.25], [0.25, 1.5]]))[:, 0]
    np.testing.assert_allclose(out, [3.0, 0.0])


def test_scale_bias_and_output_channels(quad_exr):
    c = TextureCache()
    t = tex(quad_exr, scale=(2.0, 3.0, 4.0, 0.5), bias=(0.1, 0.2, 0.3, 0.4), output="g")
    out = c.lookup(t, np.array([[0.75, 0.75]]))  # green texel
    np.testing.assert_allclose(out, [[0.1, 3.2, 0.3, 0.9]])
    np.testing.assert_allclose(c.lookup_output(t, np.array([[0.75, 0.75]])), [[3.2]])


def test_srgb_decoding_rules(tmp_path):
    v8 = np.array([[[0, 128, 255, 128]]], dtype=np.uint8)  # RGBA, one texel
    png = write_image(tmp_path / "c.png", v8)
    vf = np.array([[[0.0, 0.5, 1.0, 0.5]]], dtype=np.float32)
    exr = write_image(tmp_path / "c.exr", vf)
    v16 = (np.array([[[0, 32768, 65535]]], dtype=np.uint16))
    png16 = write_image(tmp_path / "c16.png", v16)
    c = TextureCache()
    st = np.array([[0.5, 0.5]])
    half = 128.0 / 255.0
    auto8 = c.lookup(tex(png), st)[0]
    np.testing.assert_allclose(auto8, [0.0, srgb_to_linear(half), 1.0, half], rtol=1e-6)
    raw8 = c.lookup(tex(png, source_color_space="raw"), st)[0]
    np.testing.assert_allclose(raw8, [0.0, half, 1.0, half], rtol=1e-6)
    np.testing.assert_allclose(c.lookup(tex(exr), st)[0], [0.0, 0.5, 1.0, 0.5])  # float: linear
    srgb_f = c.lookup(tex(exr, source_color_space="sRGB"), st)[0]
    np.testing.assert_allclose(srgb_f, [0.0, srgb_to_linear(0.5), 1.0, 0.5], rtol=1e-6)
    # UsdPreviewSurface spec, 'auto' without metadata: sRGB only for 8-bit files with 3 or 4
    # channels, so a 16-bit file is read as stored (it used to be decoded).
    auto16 = c.lookup(tex(png16), st)[0]
    np.testing.assert_allclose(auto16[:3], [0.0, 32768 / 65535, 1.0], rtol=1e-5)
    # One file, read once, however many colour-space variants use it.
    assert len(c._files) == 3


@pytest.mark.parametrize("channels", [1, 2])
def test_auto_reads_one_and_two_channel_8bit_files_raw(tmp_path, channels):
    """An 8-bit grey roughness/metallic map (or grey + alpha) is data, not colour: under 'auto'
    the spec decodes only 3- and 4-channel 8-bit files, so 128 stays 128/255 (sRGB-decoding
    it would give 0.216 and turn roughness 0.5 into 0.2). 'sRGB' still decodes when asked."""
    v8 = np.full((1, 1, channels), 128, dtype=np.uint8)
    path = write_image(tmp_path / f"grey{channels}.png", v8)
    c = TextureCache()
    st = np.array([[0.5, 0.5]])
    half = 128.0 / 255.0
    np.testing.assert_allclose(c.lookup(tex(path), st)[0, :3], [half] * 3, rtol=1e-6)
    forced = c.lookup(tex(path, source_color_space="sRGB"), st)[0, :3]
    np.testing.assert_allclose(forced, [srgb_to_linear(half)] * 3, rtol=1e-6)


def test_use_metadata_reads_the_file_else_black(tmp_path):
    """UsdUVTexture wrap 'useMetadata' (the fallback): the file's wrap metadata, and "if the
    texture contains no such metadata, then fall back to black" (UsdPreviewSurface spec)."""
    px = np.array([[[1.0], [2.0]], [[3.0], [4.0]]], dtype=np.float32)  # top row 1 2, bottom 3 4
    plain = write_image(tmp_path / "plain.exr", px)
    spec = oiio.ImageSpec(2, 2, 1, oiio.FLOAT)
    spec.attribute("wrapmodes", "periodic,clamp")
    tagged = str(tmp_path / "tagged.exr")
    out = oiio.ImageOutput.create(tagged)
    assert out.open(tagged, spec)
    assert out.write_image(px)
    out.close()
    c = TextureCache()
    st = np.array([[1.25, 0.25], [0.25, 1.75]])  # s past the right edge; t past the top
    meta = tex(plain, wrap_s="useMetadata", wrap_t="useMetadata")
    np.testing.assert_allclose(c.lookup(meta, st)[:, 0], [0.0, 0.0])  # no metadata: black
    meta = tex(tagged, wrap_s="useMetadata", wrap_t="useMetadata")
    np.testing.assert_allclose(c.lookup(meta, st)[:, 0], [3.0, 1.0])  # s periodic, t clamped
    assert c.wrap_modes(meta) == ("repeat", "clamp")


def test_srgb_curve():
    np.testing.assert_allclose(srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0])),
                               [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-6)


def test_channel_expansion(tmp_path):
    g = write_image(tmp_path / "g.exr", np.array([[[0.3]]], dtype=np.float32))
    ga = write_image(tmp_path / "ga.exr", np.array([[[0.3, 0.6]]], dtype=np.float32))
    c = TextureCache()
    st = np.array([[0.5, 0.5]])
    np.testing.assert_allclose(c.lookup(tex(g), st), [[0.3, 0.3, 0.3, 1.0]], rtol=1e-6)
    np.testing.assert_allclose(c.lookup(tex(ga), st), [[0.3, 0.3, 0.3, 0.6]], rtol=1e-6)


def test_missing_file_raises_stage_error_naming_it(tmp_path):
    path = str(tmp_path / "nope.png")
    with pytest.raises(StageError, match="nope.png"):
        TextureCache().add(tex(path))


def test_missing_file_fallback_mode(tmp_path):
    c = TextureCache(missing="fallback")
    t = tex(str(tmp_path / "nope.png"), fallback=(0.1, 0.2, 0.3, 0.4), scale=(9, 9, 9, 9))
    out = c.lookup(t, np.zeros((3, 2)))
    np.testing.assert_allclose(out, np.tile([0.1, 0.2, 0.3, 0.4], (3, 1)))
    assert any("nope.png" in w for w in c.warnings)


def test_unreadable_file_uses_fallback(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"this is not a png")
    c = TextureCache()
    t = tex(str(bad), fallback=(0.5, 0.5, 0.5, 1.0))
    out = c.lookup(t, np.zeros((2, 2)))
    np.testing.assert_allclose(out, [[0.5, 0.5, 0.5, 1.0]] * 2)
    assert len(c.warnings) == 1 and "bad.png" in c.warnings[0]


def test_nan_texels_are_zeroed_and_counted(tmp_path):
    px = np.array([[[np.nan, 1.0, 1.0], [1.0, 1.0, 1.0]], [[1.0, np.inf, 1.0], [1.0, 1.0, 1.0]]],
                  dtype=np.float32)
    path = write_image(tmp_path / "nan.exr", px)
    c = TextureCache()
    t = tex(path)
    out = c.lookup(t, np.array([[0.25, 0.75], [0.25, 0.25], [0.5, 0.5]]))
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[0, :3], [0.0, 1.0, 1.0])
    np.testing.assert_allclose(out[1, :3], [1.0, 0.0, 1.0])
    assert len(c.warnings) == 1 and "2 texel" in c.warnings[0]


def test_each_file_is_loaded_once(quad_exr, monkeypatch):
    calls = []
    real = textures_mod.load_image

    def counting(path, data=None):
        calls.append(path)
        return real(path, data)

    monkeypatch.setattr(textures_mod, "load_image", counting)
    c = TextureCache()
    for t in (tex(quad_exr), tex(quad_exr, wrap_s="repeat"), tex(quad_exr, source_color_space="sRGB")):
        c.add(t)
        c.lookup(t, np.zeros((1, 2)))
    assert calls == [quad_exr]


def test_non_finite_st_gets_fallback(quad_exr):
    c = TextureCache()
    t = tex(quad_exr, fallback=(7.0, 7.0, 7.0, 7.0))
    out = c.lookup(t, np.array([[np.nan, 0.5], [0.25, 0.25], [np.inf, 0.0]]))
    np.testing.assert_allclose(out[[0, 2]], 7.0)
    np.testing.assert_allclose(out[1, :3], BLUE)


def test_bad_tokens_raise(quad_exr):
    with pytest.raises(StageError):
        TextureCache().add(tex(quad_exr, wrap_s="periodic"))  # OIIO's name, not a USD token
    with pytest.raises(StageError):
        TextureCache().add(tex(quad_exr, source_color_space="linear"))
    with pytest.raises(StageError):
        TextureCache().add(tex(quad_exr, output="rgbx"))


def test_empty_lookup(quad_exr):
    assert TextureCache().lookup(tex(quad_exr), np.zeros((0, 2))).shape == (0, 4)
