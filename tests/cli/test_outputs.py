"""The files `illum render` writes, read back with OpenImageIO: modes that follow the umask,
display-referred PNG/JPEG/TIFF (sRGB, or the $OCIO display), EXR compression and half floats,
the camera matrices and render metadata, and no partial or temporary file ever left behind."""

import os
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.film import Film, read_exr
from renderer.output import srgb_encode, write_image
from renderer.render import RenderResult, write_outputs
from tests.stage_builders import quad_light_stage

from .test_cli import ROOT, _error, illum

# The camera of quad_light_stage: at (0, 6, 0) looking down -Y, image up = world -Z; the 36 mm
# aperture at 35 mm focal length spans +-6 * 18 / 35 on the floor (y = 0).
HALF = 6.0 * 18.0 / 35.0


def run(*args, umask=None, env=None):
    """`illum ARGS`: in this process (test_cli.illum) unless a umask or environment is asked for."""
    if umask is None and env is None:
        return illum(*args)
    return subprocess.run([sys.executable, "-m", "renderer.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=600, env={**os.environ, **(env or {})},
                          preexec_fn=(lambda: os.umask(umask)) if umask is not None else None)


@pytest.fixture
def stage(tmp_path):
    p = tmp_path / "q.usda"
    quad_light_stage(p, res=(24, 16))
    return p


def _pixels(path, fmt=oiio.FLOAT):
    """(spec, pixels) as stored: OpenImageIO would premultiply straight alpha on reading."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    spec, data = inp.spec(), inp.read_image(fmt)
    inp.close()
    return spec, data


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640)])
def test_file_modes_follow_the_umask(tmp_path, stage, umask, mode):
    out = tmp_path / "out"
    r = run("render", stage, "-o", out / "o.exr", "--preview", out / "p.png", "--stats", out / "s.json", "--spp", 1,
            "--quiet", "--make-output-path", umask=umask)
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(out)) == ["o.exr", "p.png", "s.json"]  # no temporaries left
    for name in ("o.exr", "p.png", "s.json"):
        assert oct(os.stat(out / name).st_mode & 0o777) == oct(mode), name


def test_display_formats_are_srgb_encoded(tmp_path, stage):
    """-o x.png / .tif / .jpg hold the sRGB encoding of the EXR the same render (same seed, one
    thread) writes: PNG to the 8-bit level, TIFF to the 16-bit level, JPEG (lossy) on average."""
    common = ("--spp", 2, "--seed", 3, "-j", 1, "--quiet")
    for ext in ("exr", "png", "tif", "jpg"):
        r = run("render", stage, "-o", tmp_path / f"o.{ext}", *common)
        assert r.returncode == 0, r.stderr
    linear, _ = read_exr(str(tmp_path / "o.exr"))
    assert 0.02 < linear.mean() < 0.9 and linear.max() > 0.1  # a real image with mid-tones
    expect = srgb_encode(linear)
    spec, png = _pixels(tmp_path / "o.png", oiio.UINT8)
    assert spec.nchannels == 3 and spec.format == oiio.UINT8
    np.testing.assert_array_equal(png.astype(int), np.round(expect * 255).astype(int))
    spec, tif = _pixels(tmp_path / "o.tif", oiio.UINT16)
    assert spec.format == oiio.UINT16
    assert np.abs(tif.astype(int) - np.round(expect * 65535).astype(int)).max() <= 1
    _, jpg = _pixels(tmp_path / "o.jpg", oiio.UINT8)
    assert abs(jpg.astype(float).mean() - expect.mean() * 255) < 2.0
    assert abs(png.astype(float).mean() - linear.mean() * 255) > 10  # linear would be far darker


def test_alpha_is_written_straight_where_the_format_has_alpha(tmp_path):
    """Premultiplied RGBA in: PNG and TIFF get straight alpha with the colour sRGB-encoded after
    the division; JPEG has no alpha and keeps the premultiplied colour (over black)."""
    rgba = np.zeros((1, 3, 4), np.float32)
    rgba[0, 0] = (0.1, 0.1, 0.1, 0.5)   # half-covered mid grey 0.2
    rgba[0, 1] = (0.0, 0.0, 0.0, 0.0)   # empty
    rgba[0, 2] = (0.8, 0.4, 0.2, 1.0)
    for ext in ("png", "tif", "jpg"):
        write_image(str(tmp_path / f"a.{ext}"), rgba)
    spec, png = _pixels(tmp_path / "a.png", oiio.UINT8)
    assert spec.nchannels == 4 and spec.alpha_channel == 3
    straight = np.array([[0.2] * 3, [0.0] * 3, [0.8, 0.4, 0.2]])
    np.testing.assert_array_equal(png[0, :, :3], np.round(srgb_encode(straight) * 255))
    np.testing.assert_array_equal(png[0, :, 3], [128, 0, 255])
    spec, tif = _pixels(tmp_path / "a.tif", oiio.UINT16)
    assert spec.nchannels == 4
    assert np.abs(tif[0, :, :3].astype(int) - np.round(srgb_encode(straight) * 65535)).max() <= 1
    spec, _ = _pixels(tmp_path / "a.jpg")
    assert spec.nchannels == 3


OCIO_CONFIG = """ocio_profile_version: 2
roles:
  default: linear
  scene_linear: linear
file_rules:
  - !<Rule> {name: Default, colorspace: default}
displays:
  Square:
    - !<View> {name: Root, colorspace: root}
active_displays: [Square]
active_views: [Root]
colorspaces:
  - !<ColorSpace>
    name: linear
  - !<ColorSpace>
    name: root
    from_scene_reference: !<ExponentTransform> {value: 2, direction: inverse}
"""


def test_ocio_display_transform_when_ocio_is_set(tmp_path, stage):
    """With $OCIO naming a config whose default view is a square root, the PNG holds sqrt(x)."""
    cfg = tmp_path / "config.ocio"
    cfg.write_text(OCIO_CONFIG)
    common = ("--spp", 2, "--seed", 3, "-j", 1, "--quiet")
    r = run("render", stage, "-o", tmp_path / "o.exr", "--preview", tmp_path / "p.png", *common,
            env={"OCIO": str(cfg)})
    assert r.returncode == 0, r.stderr
    linear, _ = read_exr(str(tmp_path / "o.exr"))
    _, png = _pixels(tmp_path / "p.png", oiio.UINT8)
    expect = np.round(np.sqrt(np.clip(linear, 0, 1)) * 255)
    assert np.abs(png.astype(int) - expect.astype(int)).max() <= 1
    assert np.abs(png.astype(int) - np.round(srgb_encode(linear) * 255).astype(int)).max() > 3
    # a config OCIO cannot read is refused before rendering, and nothing is written
    r = run("render", stage, "-o", tmp_path / "b.exr", "--preview", tmp_path / "b.png", *common,
            env={"OCIO": str(tmp_path / "missing.ocio")})
    _error(r, "OCIO", "missing.ocio")
    assert not (tmp_path / "b.exr").exists() and not (tmp_path / "b.png").exists()


@pytest.mark.parametrize("compression", ["zip", "piz", "dwaa", "none"])
def test_exr_compression_and_half(tmp_path, stage, compression):
    common = ("--spp", 2, "--seed", 3, "-j", 1, "--quiet")
    r = run("render", stage, "-o", tmp_path / "f.exr", "--exr-compression", compression, *common)
    assert r.returncode == 0, r.stderr
    r = run("render", stage, "-o", tmp_path / "h.exr", "--exr-compression", compression, "--half", *common)
    assert r.returncode == 0, r.stderr
    fspec, full = _pixels(tmp_path / "f.exr")
    hspec, half = _pixels(tmp_path / "h.exr")
    assert fspec.format == oiio.FLOAT and hspec.format == oiio.HALF
    assert fspec.get_string_attribute("compression").startswith(compression)
    assert hspec.get_string_attribute("compression").startswith(compression)
    if compression != "dwaa":  # lossless: exactly the float image, rounded to half
        np.testing.assert_array_equal(half, full.astype(np.float16).astype(np.float32))
    else:
        assert np.abs(half - full).max() < 0.05 * max(full.max(), 1e-6)


def test_exr_metadata_camera_matrices_and_render_facts(tmp_path, stage):
    r = run("render", stage, "-o", tmp_path / "o.exr", "--spp", 3, "--frame", 7, "--quiet")
    assert r.returncode == 0, r.stderr
    _, attrs = read_exr(str(tmp_path / "o.exr"))
    assert attrs["illum:spp"] == 3 and attrs["illum:sppRange"] == "3 3"
    assert attrs["illum:frame"] == 7.0 and attrs["illum:renderSeconds"] > 0.0
    # Imath row-vector matrices: p_row @ M
    w2c = np.array(attrs["worldToCamera"], dtype=np.float64).reshape(4, 4)
    w2ndc = np.array(attrs["worldToNDC"], dtype=np.float64).reshape(4, 4)
    # OpenEXR camera space is left-handed, +z along the view: the floor's centre is 6 ahead.
    np.testing.assert_allclose(np.array([0, 0, 0, 1.0]) @ w2c, [0, 0, 6, 1], atol=1e-5)
    np.testing.assert_allclose(np.array([1, 0, 0, 1.0]) @ w2c, [1, 0, 6, 1], atol=1e-5)  # x right
    np.testing.assert_allclose(np.array([0, 0, -1, 1.0]) @ w2c, [0, 1, 6, 1], atol=1e-5)  # image up

    def ndc(p):
        h = np.array([*p, 1.0]) @ w2ndc
        return h[:2] / h[3]

    # The 24 x 16 image conforms the square aperture by expanding it horizontally (expandAperture).
    np.testing.assert_allclose(ndc((0, 0, 0)), [0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(ndc((-HALF * 1.5, 0, -HALF)), [0.0, 0.0], atol=1e-5)   # top-left
    np.testing.assert_allclose(ndc((HALF * 1.5, 0, HALF)), [1.0, 1.0], atol=1e-5)     # bottom-right


def test_a_failed_write_leaves_no_file_at_all(tmp_path):
    """The preview fails after the EXR is complete: neither final name nor any temporary exists."""
    film = Film(4, 3)
    film.add(np.arange(12), np.ones((12, 3)))
    result = RenderResult(film=film, stats={"seconds": {}}, metadata={"illum:spp": 1}, camera=None, warnings=[])
    (tmp_path / "blocker").write_text("a file where a directory should be")
    with pytest.raises(OSError):
        write_outputs(result, exr=str(tmp_path / "o.exr"), png=str(tmp_path / "blocker" / "p.png"))
    assert sorted(os.listdir(tmp_path)) == ["blocker"]
    write_outputs(result, exr=str(tmp_path / "o.exr"), png=str(tmp_path / "p.png"))
    assert sorted(os.listdir(tmp_path)) == ["blocker", "o.exr", "p.png"]
