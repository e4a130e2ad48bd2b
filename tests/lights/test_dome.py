"""DomeLight: orientation, importance sampling, constant domes, texture checks."""

from __future__ import annotations

import math

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.description import LightDesc
from renderer.errors import StageError
from renderer.lights.dome import DomeLight
from tests.lights.helpers import ctx, irradiance_samples, rotate, sampler_for
from tests.stats import SIGNIFICANCE, chi2_directions, z_test


def dome(m=np.eye(4), **kw) -> LightDesc:
    return LightDesc("/Dome", "dome", np.asarray(m, dtype=np.float64), **kw)


def write_exr(path, img) -> str:
    assert oiio.ImageBuf(np.ascontiguousarray(img, dtype=np.float32)).write(str(path))
    return str(path)


def direction(lon, lat):
    """USD-NOTES section 1, written out independently of the module under test."""
    return np.array([math.sin(lon) * math.cos(lat), math.sin(lat), math.cos(lon) * math.cos(lat)])


def id_image(h=8, w=16):
    img = np.zeros((h, w, 3))
    img[..., 0] = np.arange(h * w).reshape(h, w) + 1.0  # texel id + 1, row 0 = top of the file
    return img


@pytest.fixture
def id_dome(tmp_path):
    return write_exr(tmp_path / "ids.exr", id_image())


def texel_seen(light, d):
    v = light.le_escaped(np.zeros(1, dtype=np.int64), np.asarray(d, float)[None])[0, 0] - 1.0
    return int(v) // 16, int(v) % 16  # (row, col)


def test_orientation_axes(id_dome):
    light = DomeLight.build([dome(texture_file=id_dome)])
    e = 1e-3  # nudge off texel boundaries toward +lon, +lat
    assert texel_seen(light, direction(0 + e, e)) == (3, 7)  # +Z: image centre (u = 1/2)
    assert texel_seen(light, direction(math.pi / 2 + e, e)) == (3, 3)  # +X: u = 1/4
    assert texel_seen(light, direction(-math.pi / 2 + e, e)) == (3, 11)  # -X: u = 3/4
    assert texel_seen(light, direction(math.pi - e, e)) == (3, 0)  # -Z, just west: left edge
    assert texel_seen(light, direction(-math.pi + e, e)) == (3, 15)  # -Z, just east: right edge
    assert texel_seen(light, (0, 1.0, 0))[0] == 0  # +Y: top row
    assert texel_seen(light, (0, -1.0, 0))[0] == 7  # -Y: bottom row
    assert texel_seen(light, direction(e, -e)) == (4, 7)  # just below the horizon


def test_every_texel_centre_maps_back(id_dome):
    light = DomeLight.build([dome(texture_file=id_dome)])
    h, w = 8, 16
    y, x = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    u, v = (x.ravel() + 0.5) / w, (y.ravel() + 0.5) / h
    lon, lat = math.pi - 2 * math.pi * u, math.pi / 2 - math.pi * v
    d = np.stack([np.sin(lon) * np.cos(lat), np.sin(lat), np.cos(lon) * np.cos(lat)], axis=1)
    le = light.le_escaped(np.zeros(h * w, dtype=np.int64), d)[:, 0]
    np.testing.assert_array_equal(le, np.arange(h * w) + 1.0)


def test_rotation_z_up(id_dome):
    """A Z-up stage: the reader folds rotateX(90) into light_to_world, so the top row is world +Z."""
    light = DomeLight.build([dome(rotate((1, 0, 0), 90), texture_file=id_dome)])
    assert texel_seen(light, (0, 0, 1.0))[0] == 0
    e = 1e-3
    # local +Z (image centre) goes to world -Y
    assert texel_seen(light, (math.sin(e), -math.cos(e), math.sin(e))) == (3, 7)


def spot_image(h=32, w=64):
    img = np.full((h, w, 3), 0.2)
    img[:, :, 2] = 0.3
    img[8:11, 40:44] = (60.0, 50.0, 40.0)  # a bright sun-like spot
    img[20, 5] = 0.0  # a black texel
    img[h - 1, :] = 0.0  # a black bottom row
    return img


@pytest.fixture
def spot_dome(tmp_path):
    return write_exr(tmp_path / "spot.exr", spot_image())


def spot_direction(light):
    h, w = 32, 64
    u, v = 42.0 / w, 9.5 / h
    return light.rot[0] @ direction(math.pi - 2 * math.pi * u, math.pi / 2 - math.pi * v)


@pytest.mark.parametrize("m", [np.eye(4), rotate((0.3, 1, 0.2), 70)])
def test_textured_chi2(spot_dome, m):
    light = DomeLight.build([dome(m, texture_file=spot_dome)])
    sample, pdf = sampler_for(light, 0, (0, 0, 0))
    # Around the spot (fine bins) ...
    pval, details = chi2_directions(sample, pdf, axis=spot_direction(light), cos_range=(0.9, 1.0), n_samples=200_000, integration_res=12)
    assert pval > SIGNIFICANCE, details["chi2"]


def test_textured_chi2_whole_sphere(tmp_path):
    """A smooth sky with a dark ground (a 300x spot's sharp edges are too much for the coarse
    whole-sphere bins' quadrature; the spot is tested with fine bins above)."""
    h, w = 16, 32
    y, x = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    sky = 0.3 + 2.0 * (1 + np.sin(2 * np.pi * x / w)) * (h - y) / h
    img = np.repeat(sky[..., None], 3, axis=2)
    img[h - 2 :, :] = 0.0  # black ground rows
    f = write_exr(tmp_path / "sky.exr", img)
    light = DomeLight.build([dome(rotate((0.3, 1, 0.2), 70), texture_file=f)])
    sample, pdf = sampler_for(light, 0, (0, 0, 0))
    pval, details = chi2_directions(sample, pdf, axis=(0.2, 0.3, 0.9), n_samples=200_000, integration_res=12)
    assert pval > SIGNIFICANCE, details["chi2"]


def test_textured_pdf_is_proportional_to_luminance(spot_dome):
    light = DomeLight.build([dome(texture_file=spot_dome, intensity=3.0)])
    n = 5000
    c = ctx((0, 0, 0), count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(3).random((n, 2)))
    assert np.all(s.pdf > 0)
    np.testing.assert_allclose(light.pdf_li(idx, c, s.wi), s.pdf, rtol=1e-9)
    lum = s.L @ np.array([0.2126, 0.7152, 0.0722])
    ratio = lum / s.pdf  # constant: the integral of lum(Le) over the sphere
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    np.testing.assert_allclose(ratio[0], light.phi()[0] / math.pi, rtol=1e-9)  # scene radius 1
    # Black texels are never sampled and have pdf 0.
    h, w = 32, 64
    black = light.rot[0] @ direction(math.pi - 2 * math.pi * 5.5 / w, math.pi / 2 - math.pi * 20.5 / h)
    assert light.pdf_li(idx[:1], c.take(np.array([0])), black[None])[0] == 0.0


def _dome_quadrature(img, n_normal, res_sub=8):
    h, w = img.shape[:2]
    y = (np.arange(h * res_sub) + 0.5) / (h * res_sub)
    x = (np.arange(w * res_sub) + 0.5) / (w * res_sub)
    V, U = np.meshgrid(y, x, indexing="ij")
    lon, lat = math.pi - 2 * math.pi * U, math.pi / 2 - math.pi * V
    d = np.stack([np.sin(lon) * np.cos(lat), np.sin(lat), np.cos(lon) * np.cos(lat)], axis=-1)
    tex = img[(V * h).astype(int), (U * w).astype(int), 0]
    d_omega = np.cos(lat) * (2 * math.pi / (w * res_sub)) * (math.pi / (h * res_sub))
    return float((tex * np.maximum(0.0, d @ n_normal) * d_omega).sum())


@pytest.mark.parametrize("n_normal", [(0, 1.0, 0), (0.4, 0.5, -0.7), (0, -1.0, 0.1)])
def test_textured_irradiance(spot_dome, n_normal):
    light = DomeLight.build([dome(texture_file=spot_dome)])
    n_normal = np.asarray(n_normal) / np.linalg.norm(n_normal)
    ref = _dome_quadrature(spot_image(), n_normal)
    est = irradiance_samples(light, 0, (0, 0, 0), n_normal, n=100_000)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)


def test_constant_dome():
    light = DomeLight.build([dome(rotate((0, 0, 1), 20), intensity=2.0, color=(1.0, 0.5, 0.25), normalize=True)])
    np.testing.assert_allclose(light.L[0], [2.0, 1.0, 0.5])  # normalize is ignored for domes
    sample, pdf = sampler_for(light, 0, (0, 0, 0))
    pval, details = chi2_directions(sample, pdf, n_samples=50_000, integration_res=4)
    assert pval > SIGNIFICANCE
    n_normal = np.array([0.0, 0.6, 0.8])
    est = irradiance_samples(light, 0, (0, 0, 0), n_normal, n=50_000)
    assert z_test(est, math.pi * 2.0) > SIGNIFICANCE
    d = np.random.default_rng(0).normal(size=(10, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(light.le_escaped(np.zeros(10, dtype=np.int64), d), np.tile([2.0, 1.0, 0.5], (10, 1)))
    assert light.phi()[0] == pytest.approx(4 * math.pi**2 * (0.2126 * 2 + 0.7152 + 0.0722 * 0.5))


def test_texture_format_checks(tmp_path):
    square = write_exr(tmp_path / "square.exr", np.ones((8, 8, 3)))
    with pytest.raises(StageError) as err:
        DomeLight.build([dome(texture_file=square)])
    assert err.value.prim == "/Dome" and err.value.attribute == "inputs:texture:file"
    assert "square.exr" in str(err.value)
    light = DomeLight.build([dome(texture_file=square, texture_format="latlong")])  # explicit: accepted
    assert light.images.width[0] == 8
    with pytest.raises(StageError, match="mirroredBall"):
        DomeLight.build([dome(texture_file=square, texture_format="mirroredBall")])
    bad = np.ones((4, 8, 3))
    bad[1, 1] = np.inf
    bad[2, 3, 2] = np.nan
    bad[3, 3, 0] = -0.5
    f = write_exr(tmp_path / "bad.exr", bad)
    with pytest.raises(StageError, match=r"bad\.exr.*3 texel"):
        DomeLight.build([dome(texture_file=f)])


def test_two_domes_vectorised(tmp_path, spot_dome, id_dome):
    """Rows for different textured and constant domes are handled in one call."""
    light = DomeLight.build([dome(texture_file=spot_dome), dome(intensity=0.5), dome(texture_file=id_dome)])
    n = 3000
    idx = np.arange(n, dtype=np.int64) % 3
    c = ctx((0, 0, 0), count=n)
    s = light.sample_li(idx, c, np.random.default_rng(8).random((n, 2)))
    np.testing.assert_allclose(light.pdf_li(idx, c, s.wi), s.pdf, rtol=1e-9)
    np.testing.assert_allclose(light.le_escaped(idx, s.wi), s.L, rtol=1e-12)
    assert np.all(s.pdf[idx == 1] == pytest.approx(1 / (4 * math.pi)))
