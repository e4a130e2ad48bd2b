"""`illum preconvolve`: files, metadata, input formats, robustness, exit codes (issue #6)."""

from __future__ import annotations

import hashlib

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer import preconvolve as pc
from renderer.cli import main
from renderer.errors import IllumError

from .conftest import write_image


def sky_map(h=32, w=64, seed=0) -> np.ndarray:
    d = pc.latlong_directions(h, w)
    rng = np.random.default_rng(seed)
    img = 1.0 + 0.5 * np.clip(d[..., 1:2], 0, None) * np.array([0.5, 0.8, 1.2]) + 0.3 * rng.random((h, w, 3))
    img[h // 4, w // 3] = 500.0
    return img.astype(np.float32)


def read(path):
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    px = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    inp.close()
    return px, spec


def test_writes_float_exr_same_orientation_with_metadata(tmp_path):
    img = sky_map()
    src = write_image(tmp_path / "env.exr", img)
    out = tmp_path / "env_irradiance.exr"
    calls = []
    rep = pc.preconvolve(src, str(out), size=32, progress=lambda d, t: calls.append((d, t)))
    px, spec = read(out)
    assert (spec.width, spec.height, spec.nchannels) == (32, 16, 3)
    assert spec.format == oiio.FLOAT
    assert spec.getattribute("illum:source") == src
    with open(src, "rb") as f:
        assert spec.getattribute("illum:sourceHash") == hashlib.sha256(f.read()).hexdigest()
    assert spec.getattribute("illum:method") == "exact"
    assert spec.getattribute("illum:size") == "32x16"
    assert rep["source_hash"] == spec.getattribute("illum:sourceHash") and rep["size"] == (32, 16)
    # Texel (x, y) holds E for the direction of its centre (same convention as the source).
    n = pc.latlong_directions(16, 32).reshape(-1, 3)
    ref = pc.exact_irradiance(img.astype(np.float64), n).reshape(16, 32, 3)
    assert np.allclose(px, ref, rtol=1e-6)
    assert calls and calls[-1] == (32, 32)
    # read_irradiance gives the same pixels and metadata.
    E, meta = pc.read_irradiance(str(out))
    assert np.array_equal(E, px.astype(np.float64)) and meta["illum:method"] == "exact"


def test_sh_method_metadata_and_values(tmp_path):
    img = sky_map()
    src = write_image(tmp_path / "env.exr", img)
    out = tmp_path / "sh.exr"
    pc.preconvolve(src, str(out), size=16, method="sh")
    px, spec = read(out)
    assert spec.getattribute("illum:method") == "sh"
    n = pc.latlong_directions(8, 16).reshape(-1, 3)
    assert np.allclose(px.reshape(-1, 3), pc.sh_irradiance(img.astype(np.float64), n), rtol=1e-5)


@pytest.mark.parametrize("fmt", ["hdr", "tx", "png"])
def test_other_input_formats(tmp_path, fmt):
    """.hdr (RGBE), .tx (tiled, MIP-mapped: level 0 is read tile-row by tile-row) and 8-bit PNG
    (sRGB-decoded, as the renderer's DomeLight reads it)."""
    img = sky_map(64, 128)
    exr = write_image(tmp_path / "env.exr", img)
    if fmt == "tx":
        cfg = oiio.ImageSpec()
        cfg.attribute("tile_width", 16)
        cfg.attribute("tile_height", 16)
        assert oiio.ImageBufAlgo.make_texture(oiio.MakeTxEnvLatl, exr, str(tmp_path / "env.tx"), cfg)
        src = str(tmp_path / "env.tx")
    elif fmt == "hdr":
        src = write_image(tmp_path / "env.hdr", img)
    else:
        src = write_image(tmp_path / "env.png", np.clip(img / 600.0, 0, 1), "uint8")
    pc.preconvolve(src, str(tmp_path / "out.exr"), size=16)
    got, _ = read(tmp_path / "out.exr")
    from renderer.lights.texture import load_texture_rgb

    texels = load_texture_rgb(src, "/Dome")  # exactly what the renderer sees
    ref = pc.exact_irradiance(texels, pc.latlong_directions(8, 16).reshape(-1, 3)).reshape(8, 16, 3)
    assert np.allclose(got, ref, rtol=1e-6)


def test_bad_texels_error_with_count_and_sanitize(tmp_path, capsys):
    img = sky_map()
    img[3, 4, 0] = np.nan
    img[5, 6] = -1.0
    img[7, 8, 2] = np.inf
    img[9, 10, 1] = np.nan
    src = write_image(tmp_path / "bad.exr", img)
    out = str(tmp_path / "o.exr")
    with pytest.raises(IllumError) as e:
        pc.preconvolve(src, out)
    msg = str(e.value)
    assert src in msg and "4 texel(s)" in msg and "NaN (2)" in msg and "infinite (1)" in msg and "negative (1)" in msg
    assert main(["preconvolve", src, "-o", out, "--size", "16"]) == 2
    assert "4 texel(s)" in capsys.readouterr().err
    rep = pc.preconvolve(src, out, size=16, sanitize=True)
    assert rep["sanitized"] == {"nan": 2, "posinf": 1, "neginf": 0, "negative": 1}
    px, spec = read(out)
    assert np.all(np.isfinite(px)) and spec.getattribute("illum:sanitized") == 4
    clean = img.copy().astype(np.float64)
    clean[3, 4, 0] = clean[9, 10, 1] = 0.0
    clean[5, 6] = 0.0
    clean[7, 8, 2] = np.nanmax(np.where(np.isfinite(img), img, np.nan))  # +Inf -> largest finite value
    ref = pc.exact_irradiance(clean, pc.latlong_directions(8, 16).reshape(-1, 3)).reshape(8, 16, 3)
    assert np.allclose(px, ref, rtol=1e-6)
    assert main(["preconvolve", src, "-o", out, "--size", "16", "--sanitize"]) == 0
    assert "sanitized 4 texel(s)" in capsys.readouterr().err


def test_not_two_to_one_needs_force(tmp_path, capsys):
    img = sky_map(40, 64)
    src = write_image(tmp_path / "odd.exr", img)
    out = str(tmp_path / "o.exr")
    with pytest.raises(IllumError, match="not a 2:1 lat-long map"):
        pc.preconvolve(src, out, size=16)
    assert main(["preconvolve", src, "-o", out, "--size", "16"]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["preconvolve", src, "-o", out, "--size", "16", "--force", "--quiet"]) == 0
    px, _ = read(out)
    ref = pc.exact_irradiance(img.astype(np.float64), pc.latlong_directions(8, 16).reshape(-1, 3))
    assert np.allclose(px.reshape(-1, 3), ref, rtol=1e-6)


def test_cli_errors_exit_2(tmp_path, capsys):
    src = write_image(tmp_path / "env.exr", sky_map())
    assert main(["preconvolve", str(tmp_path / "missing.exr")]) == 2
    assert "missing.exr: file not found" in capsys.readouterr().err
    assert main(["preconvolve", src, "--size", "33"]) == 2
    assert main(["preconvolve", src, "--size", "0"]) == 2
    assert main(["preconvolve", src, "-o", src]) == 2  # would overwrite the source
    assert main(["preconvolve", src, "--stage", str(tmp_path / "x.usda")]) == 2  # --light missing
    not_image = tmp_path / "notes.exr"
    not_image.write_text("not an image")
    assert main(["preconvolve", str(not_image)]) == 2
    with pytest.raises(SystemExit) as e:
        main(["preconvolve", src, "--method", "bogus"])
    assert e.value.code == 2
    capsys.readouterr()


def test_default_output_name(tmp_path):
    src = write_image(tmp_path / "studio.exr", sky_map())
    assert main(["preconvolve", src, "--size", "8", "--quiet"]) == 0
    assert (tmp_path / "studio_irradiance.exr").exists()


def test_progress_bar_on_a_tty(tmp_path, capsys, monkeypatch):
    src = write_image(tmp_path / "env.exr", sky_map())
    import sys

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert main(["preconvolve", src, "--size", "8"]) == 0
    err = capsys.readouterr().err
    assert "preconvolve" in err and "32/32" in err and "row" in err  # tqdm's bar: rows done/total
