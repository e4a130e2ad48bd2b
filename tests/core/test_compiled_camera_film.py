"""The compiled camera, film and pixel-sequence passes against their numpy formulations:
Camera.generate (_generate_kernel) vs Camera._generate_numpy, Film.add (_add_kernel) vs
fancy-index adds / np.add.at, pixel_sequence (_pixel_sequence_kernel) vs a splitmix64 written
here in numpy."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.camera import Camera
from renderer.description import CameraDesc
from renderer.film import Film
from renderer.sampling import _sobol2, pixel_sequence
from tests.simd import assembly, needs_avx2, uncached

_ROT_SCALE = np.array([[0.0, -2.0, 0.0, 1.0],    # rotate 90 deg about z, scale 2, translate
                       [2.0, 0.0, 0.0, -2.0],
                       [0.0, 0.0, 2.0, 3.5],
                       [0.0, 0.0, 0.0, 1.0]])
_SKEW = np.array([[1.3, 0.2, -0.4, 0.0],         # non-uniform scale and shear
                  [0.1, 0.7, 0.3, 5.0],
                  [0.5, -0.2, 1.9, -1.0],
                  [0.0, 0.0, 0.0, 1.0]])
_PLANES = ((0.0, 0.0, 1.0, 3.0), (0.3, 1.0, 0.0, 0.2), (-1.0, 0.0, -0.2, 0.0), (1.0, 0.0, 0.0, 0.0))

CASES = {
    "pinhole": dict(),
    "thin_lens": dict(f_stop=1.4, focus_distance=3.0),
    "orthographic": dict(projection="orthographic"),
    "scaled": dict(camera_to_world=_ROT_SCALE),
    "thin_lens_skewed": dict(camera_to_world=_SKEW, f_stop=2.0, focus_distance=7.0),
    "offsets": dict(horizontal_aperture_offset=0.4, vertical_aperture_offset=-0.25),
    "ortho_offsets_scaled": dict(projection="orthographic", horizontal_aperture_offset=-0.3,
                                 vertical_aperture_offset=0.2, camera_to_world=_ROT_SCALE),
    "planes": dict(clipping_planes=_PLANES),
    "planes_thin_lens_scaled": dict(clipping_planes=_PLANES, f_stop=1.4, focus_distance=3.0,
                                    camera_to_world=_ROT_SCALE),
    "planes_orthographic": dict(clipping_planes=_PLANES, projection="orthographic"),
}


def _camera(pixel_aspect=1.0, conform="expandAperture", **kw):
    desc = dict(path="/Cam", camera_to_world=np.eye(4), focal_length=1.3, horizontal_aperture=2.0,
                vertical_aperture=1.5, clipping_range=(0.1, 50.0))
    return Camera(CameraDesc(**{**desc, **kw}), 40, 30, pixel_aspect=pixel_aspect, conform=conform)


def _inputs(n=5000, seed=0):
    rng = np.random.default_rng(seed)
    px, py = rng.integers(0, 40, n), rng.integers(0, 30, n)
    u_filter, u_lens = rng.random((n, 2)), rng.random((n, 2))
    # the table's ends and the concentric map's branch points (a = 0, b = 0, |a| = |b|)
    u_filter[:6] = [[0.0, 0.0], [1.0, 1.0], [0.5, 0.5], [0.0, 1.0], [1.0, 0.0], [np.nextafter(1.0, 0.0), 1e-300]]
    u_lens[:6] = [[0.5, 0.5], [0.5, 0.2], [0.2, 0.2], [0.8, 0.2], [0.0, 0.5], [1.0, 0.0]]
    return px, py, u_filter, u_lens


def _assert_rays_match(a, b):
    for name in ("o", "d", "tmin", "tmax"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.dtype == np.float64, name
        assert np.array_equal(np.isinf(x), np.isinf(y)), name
        fin = np.isfinite(y)
        scale = np.abs(y[fin]).max() if fin.any() else 1.0
        np.testing.assert_allclose(x[fin], y[fin], rtol=1e-12, atol=1e-12 * scale, err_msg=name)


@pytest.mark.parametrize("case", sorted(CASES))
def test_generate_matches_the_numpy_formulation(case):
    cam = _camera(**CASES[case])
    args = _inputs()
    _assert_rays_match(cam.generate(*args), cam._generate_numpy(*args))


@pytest.mark.parametrize("conform", ["expandAperture", "cropAperture", "adjustApertureWidth",
                                     "adjustApertureHeight", "adjustPixelAspectRatio"])
def test_generate_matches_with_non_square_pixels_and_every_conform_policy(conform):
    cam = _camera(pixel_aspect=1.7, conform=conform, horizontal_aperture_offset=0.3, vertical_aperture_offset=-0.1,
                  f_stop=2.0, focus_distance=4.0)
    args = _inputs(seed=1)
    _assert_rays_match(cam.generate(*args), cam._generate_numpy(*args))


def test_generate_takes_other_pixel_dtypes_and_views():
    """int32 and float pixel coordinates and non-contiguous u give the same rays as int64."""
    cam = _camera(**CASES["planes_thin_lens_scaled"])
    px, py, u_filter, u_lens = _inputs(n=300, seed=2)
    ref = cam._generate_numpy(px, py, u_filter, u_lens)
    _assert_rays_match(cam.generate(px.astype(np.int32), py.astype(np.int32), u_filter, u_lens), ref)
    _assert_rays_match(cam.generate(px + 0.0, py + 0.0, u_filter, u_lens), ref)
    uf2 = np.stack([u_filter, u_filter], axis=2)[:, :, 0]  # a strided view
    _assert_rays_match(cam.generate(px, py, uf2, np.asfortranarray(u_lens)), ref)
    empty = cam.generate(px[:0], py[:0], u_filter[:0], u_lens[:0])
    assert empty.o.shape == (0, 3) and empty.tmin.shape == (0,)


def test_generate_comparison_detects_a_filter_offset_error():
    """Power check: a camera whose filter table is off by a small fraction of a pixel fails
    the comparison the tests above use."""
    cam = _camera()
    args = _inputs(n=500)
    ref = cam._generate_numpy(*args)
    cam.filter._inv = cam.filter._inv + 1e-6
    with pytest.raises(AssertionError):
        _assert_rays_match(cam.generate(*args), ref)


# ---------------------------------------------------------------------------------- film
def _reference_add(shape, rows, L, unique):
    """Film.add's numpy formulation: fancy-index adds (unique) or np.add.at, non-finite rows dropped."""
    h, w = shape
    s, sq, n = np.zeros((h * w, 3)), np.zeros((h * w, 3)), np.zeros(h * w, dtype=np.int64)
    ok = np.all(np.isfinite(L), axis=1)
    rows, L = rows[ok], L[ok]
    if unique:
        s[rows] += L
        sq[rows] += L * L
        n[rows] += 1
    else:
        np.add.at(s, rows, L)
        np.add.at(sq, rows, L * L)
        np.add.at(n, rows, 1)
    return s.reshape(h, w, 3), sq.reshape(h, w, 3), n.reshape(h, w), int((~ok).sum()), int(np.any(L < 0.0, axis=1).sum())


def _samples(rows, seed):
    rng = np.random.default_rng(seed)
    L = rng.normal(0.5, 1.0, (rows.size, 3))
    bad = rng.random(rows.size) < 0.05
    L[bad, rng.integers(0, 3, bad.sum())] = rng.choice([np.nan, np.inf, -np.inf], bad.sum())
    return L


@pytest.mark.parametrize("unique", [True, False])
def test_film_add_matches_fancy_index_and_add_at(unique):
    h, w = 9, 13
    rng = np.random.default_rng(4)
    rows = rng.permutation(h * w)[:100] if unique else rng.integers(0, h * w, 400)
    L = _samples(rows, 5)
    film = Film(w, h)
    film.add(rows, L, unique=unique)
    s, sq, n, dropped, negative = _reference_add((h, w), rows, L, unique)
    assert dropped > 0 and negative > 0  # the data exercise both counters
    assert np.array_equal(film.sum, s) and np.array_equal(film.sum_sq, sq) and np.array_equal(film.count, n)
    assert (film.nonfinite_dropped, film.negative_samples) == (dropped, negative)
    assert np.all(np.isfinite(film.sum)) and np.all(np.isfinite(film.sum_sq))


def test_film_add_indexes_like_numpy():
    """Negative rows count from the end; an out-of-range row raises and adds nothing."""
    film = Film(4, 3)
    film.add(np.array([-1, 0]), np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]))
    assert film.count[2, 3] == 1 and film.sum[2, 3, 2] == 3.0 and film.sum[0, 0, 0] == 4.0
    before = (film.sum.copy(), film.count.copy())
    for bad in (12, -13):
        with pytest.raises(IndexError):
            film.add(np.array([1, bad]), np.ones((2, 3)))
    assert np.array_equal(film.sum, before[0]) and np.array_equal(film.count, before[1])


def test_film_add_other_dtypes_take_the_numpy_path():
    """float32 radiance and unsigned rows give what the numpy formulation gives."""
    film = Film(3, 2)
    L = np.array([[0.1, -0.2, 0.3], [np.nan, 1.0, 1.0], [1.0, 2.0, 3.0]], dtype=np.float32)
    film.add(np.array([0, 1, 5], dtype=np.uint32), L)
    s, sq, n, dropped, negative = _reference_add((2, 3), np.array([0, 1, 5]), L, True)
    assert np.array_equal(film.sum, s) and np.array_equal(film.sum_sq, sq) and np.array_equal(film.count, n)
    assert (film.nonfinite_dropped, film.negative_samples) == (dropped, negative) == (1, 1)


# ---------------------------------------------------------------------------------- pixel_sequence
def _splitmix_reference(seed, pixel, index):
    """pixel_sequence written out in numpy uint64 arrays (array arithmetic wraps silently)."""
    mask = (1 << 64) - 1
    keys = np.asarray(pixel).astype(np.uint64) * np.uint64(4) + np.uint64(((seed & 0xFFFFFFFF) * 0x100000001B3) & mask)
    out = []
    for stream, bits in enumerate(_sobol2(index)):
        z = keys + np.uint64((0x9E3779B97F4A7C15 * (stream + 1)) & mask)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
        out.append(((z >> np.uint64(32)) ^ np.uint64(bits)).astype(np.float64) / 4294967296.0)
    return np.stack(out, axis=-1)


@pytest.mark.parametrize("seed", [0, 7, 0xFFFFFFFF, (1 << 40) + 3])
def test_pixel_sequence_matches_the_numpy_hash_exactly(seed):
    rng = np.random.default_rng(6)
    pix = np.concatenate([rng.integers(0, 1 << 40, 2000), [0, 1, -1, (1 << 63) - 1]])
    for index in (0, 1, 17, 1000, (1 << 31) + 5):
        ref = _splitmix_reference(seed, pix, index)
        assert np.array_equal(pixel_sequence(seed, pix, index), ref)
        small = np.arange(-50, 50)
        assert np.array_equal(pixel_sequence(seed, small.astype(np.int32), index), _splitmix_reference(seed, small, index))
    grid = np.arange(12).reshape(3, 4)  # any shape keeps working (numpy path)
    assert np.array_equal(pixel_sequence(seed, grid, 3), _splitmix_reference(seed, grid, 3))


@pytest.mark.parametrize("case", ["pinhole", "scaled", "offsets"])
def test_pinhole_kernel_is_the_general_kernel_bit_for_bit(case):
    """Camera.generate's vectorised kernel for perspective cameras without a lens or clipping
    planes gives exactly what the general kernel gives (out-of-range and NaN filter numbers too)."""
    from renderer.camera import _generate_kernel, _raster_index

    cam = _camera(**CASES[case])
    px, py, u_filter, u_lens = _inputs(seed=3)
    u_filter[6:9] = [[-0.5, 2.0], [np.nan, 0.5], [0.5, np.inf]]
    fast = cam.generate(px, py, u_filter, u_lens)
    n = px.size
    o, d, tmin, tmax = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n)
    _generate_kernel(_raster_index(px), _raster_index(py), u_filter, u_lens, cam.filter._inv,
                     np.array(cam.window, dtype=np.float64), float(cam.width), float(cam.height), False, 0.0,
                     float(cam.focus_distance), float(cam.near), float(cam.far), np.zeros((0, 4)),
                     np.ascontiguousarray(cam.camera_to_world, dtype=np.float64), o, d, tmin, tmax)
    for got, ref in ((fast.o, o), (fast.d, d), (fast.tmin, tmin), (fast.tmax, tmax)):
        np.testing.assert_array_equal(got, ref)


@needs_avx2
def test_pinhole_kernel_loop_is_vectorised():
    """The pinhole camera kernel runs packed (its square roots on ymm/zmm registers): a 2-D
    array's runtime stride or a branch around work would turn it scalar, ~2x slower a ray."""
    import re

    from renderer.camera import _generate_pinhole_kernel
    from renderer.kernels import NoAliasCompiler

    kernel = uncached(_generate_pinhole_kernel, pipeline_class=NoAliasCompiler)
    n = 16
    kernel(np.arange(n), np.arange(n), np.full(2 * n, 0.5), np.linspace(-1.0, 1.0, 65),
           np.array([-1.0, 1.0, -1.0, 1.0]), 16.0, 16.0, 0.1, 10.0, np.eye(4), np.empty(3 * n), np.empty(3 * n),
           np.empty(n), np.empty(n))
    assert re.search(r"vsqrtpd\s+%[yz]mm", assembly(kernel)), "the pinhole camera loop is no longer vectorised"
