"""Film accumulation, non-finite policy and EXR/PNG output read back with OpenImageIO."""

import os

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.film import Film, read_exr, srgb_encode, write_exr, write_png


def test_nonfinite_samples_are_dropped_and_counted():
    film = Film(2, 1)
    film.add(np.array([0, 1]), np.array([[1.0, 1.0, 1.0], [np.nan, 0.0, 0.0]]))
    film.add(np.array([0, 1]), np.array([[3.0, 3.0, 3.0], [np.inf, 1.0, 1.0]]))
    assert film.nonfinite_dropped == 2
    img = film.mean()
    assert np.all(np.isfinite(img))
    np.testing.assert_allclose(img[0, 0], [2.0, 2.0, 2.0])
    np.testing.assert_allclose(img[0, 1], [0.0, 0.0, 0.0])


def test_negative_samples_are_kept_and_counted():
    film = Film(1, 1)
    film.add(np.array([0]), np.array([[-1.0, 0.5, 0.5]]))
    film.add(np.array([0]), np.array([[3.0, 0.5, 0.5]]))
    assert film.negative_samples == 1
    np.testing.assert_allclose(film.mean()[0, 0], [1.0, 0.5, 0.5])


def test_variance_estimate_matches_numpy():
    rng = np.random.default_rng(1)
    film = Film(3, 2)
    xs = rng.random((50, 6, 3))
    for k in range(50):
        film.add(np.arange(6), xs[k])
    expect = xs.var(axis=0, ddof=1) / 50
    np.testing.assert_allclose(film.variance_of_mean().reshape(6, 3), expect, rtol=1e-9)


def test_exr_round_trip_keeps_pixels_window_and_metadata(tmp_path):
    film = Film(8, 6, window=(2, 1, 7, 5))
    h, w = film.shape
    vals = np.random.default_rng(2).random((h * w, 3)) * 10
    film.add(np.arange(h * w), vals)
    m = np.arange(16, dtype=np.float64).reshape(4, 4)
    path = str(tmp_path / "sub" / "out.exr")
    write_exr(path, film, {"illum:spp": 1, "illum:renderSeconds": 1.5, "illum:seed": 7,
                           "illum:version": "0.1.0", "worldToCamera": m,
                           "illum:estimators": {"/Key": "mis"}})
    img, attrs = read_exr(path)
    assert img.shape == (6, 8, 3)
    np.testing.assert_allclose(img[1:5, 2:7].reshape(-1, 3), vals, rtol=1e-6)
    assert np.all(img[0] == 0)
    assert attrs["illum:spp"] == 1 and attrs["illum:seed"] == 7
    assert attrs["illum:renderSeconds"] == pytest.approx(1.5)
    assert attrs["illum:version"] == "0.1.0"
    assert '"/Key": "mis"' in attrs["illum:estimators"]
    np.testing.assert_allclose(np.array(attrs["worldToCamera"]).reshape(4, 4), m.T)
    inp = oiio.ImageInput.open(path)
    spec = inp.spec()
    inp.close()
    assert (spec.x, spec.y, spec.width, spec.height) == (2, 1, 5, 4)
    assert (spec.full_width, spec.full_height) == (8, 6)
    assert spec.format == oiio.FLOAT
    # No temporary files are left behind.
    assert os.listdir(tmp_path / "sub") == ["out.exr"]


def test_png_preview_is_srgb_encoded(tmp_path):
    img = np.zeros((1, 3, 3), np.float32)
    img[0, 1] = 0.214041  # sRGB 0.5
    img[0, 2] = 7.0        # clamps to white
    path = str(tmp_path / "p.png")
    write_png(path, img)
    back = oiio.ImageBuf(path).get_pixels(oiio.UINT8)
    assert back[0, 0, 0] == 0 and back[0, 2, 0] == 255
    assert abs(int(back[0, 1, 0]) - 128) <= 1
    assert srgb_encode(np.array([0.0031308]))[0] == pytest.approx(0.04045, rel=1e-4)


def test_checkpoint_round_trip(tmp_path):
    film = Film(4, 3)
    film.add(np.arange(12), np.ones((12, 3)))
    film.nonfinite_dropped = 3
    p = str(tmp_path / "ck.npz")
    film.save_state(p)
    back = Film.load_state(p)
    np.testing.assert_array_equal(back.sum, film.sum)
    assert back.count.max() == 1 and back.nonfinite_dropped == 3 and back.window == film.window
