"""Camera-ray conformance found by the spec audit: UsdGeomCamera clippingPlanes and the
UsdRender dataWindowNDC pixel-centre rule."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.camera import Camera
from renderer.description import CameraDesc
from renderer.render import _data_window


def _camera(planes=(), projection="perspective", f_stop=0.0, clip=(0.1, 100.0)):
    desc = CameraDesc(path="/Cam", camera_to_world=np.diag([2.0, 2.0, 2.0, 1.0]), projection=projection,
                      focal_length=1.0, horizontal_aperture=2.0, vertical_aperture=2.0,
                      clipping_range=clip, f_stop=f_stop, focus_distance=5.0 if f_stop else 0.0,
                      clipping_planes=tuple(planes))
    return Camera(desc, 16, 16)


def _rays(cam, n=4000, seed=3):
    rng = np.random.default_rng(seed)
    px, py = rng.integers(0, 16, n), rng.integers(0, 16, n)
    return cam.generate(px, py, rng.random((n, 2)), rng.random((n, 2)))


@pytest.mark.parametrize("projection,f_stop", [("perspective", 0.0), ("perspective", 2.0), ("orthographic", 0.0)])
def test_clipping_planes_keep_exactly_the_points_on_their_positive_side(projection, f_stop):
    """Sample points along each camera ray: a point is inside [tmin, tmax] iff it is within
    the clipping range and a x + b y + c z + d >= 0 for every plane (camera space)."""
    planes = [(0.0, 0.0, 1.0, 3.0), (0.3, 1.0, 0.0, 0.2), (-1.0, 0.0, -0.2, 0.0)]
    cam = _camera(planes, projection, f_stop)
    base = _rays(_camera((), projection, f_stop))
    rays = _rays(cam)
    assert np.allclose(rays.o, base.o) and np.allclose(rays.d, base.d)
    inv = np.linalg.inv(cam.camera_to_world)
    t = np.linspace(0.0, 30.0, 601)
    p_world = rays.o[:, None, :] + rays.d[:, None, :] * t[None, :, None]  # (n, S, 3)
    p_cam = p_world @ inv[:3, :3].T + inv[:3, 3]
    kept = np.ones(p_cam.shape[:2], dtype=bool)
    for a, b, c, d in planes:
        kept &= a * p_cam[..., 0] + b * p_cam[..., 1] + c * p_cam[..., 2] + d >= 0.0
    kept &= (t >= base.tmin[:, None]) & (t <= base.tmax[:, None])
    inside = (t >= rays.tmin[:, None] - 1e-9) & (t <= rays.tmax[:, None] + 1e-9)
    assert np.all(rays.tmax >= rays.tmin)
    # the grid step is 0.05: disagreements only within a step of a boundary
    step = t[1] - t[0]
    near_edge = (np.abs(t[None, :] - rays.tmin[:, None]) < step) | (np.abs(t[None, :] - rays.tmax[:, None]) < step)
    assert np.all((kept == inside) | near_edge)
    assert 0.05 < kept.any(axis=1).mean() < 0.95  # the planes do clip some rays and keep others


def test_no_planes_leaves_rays_unchanged():
    a, b = _rays(_camera()), _rays(_camera(planes=()))
    assert np.array_equal(a.tmin, b.tmin) and np.array_equal(a.tmax, b.tmax)


def _brute_window(ndc, w, h):
    """Pixels whose centre lies in [xmin, xmax) x [ymin, ymax) (NDC, y up)."""
    xs = (np.arange(w) + 0.5) / w
    ys = 1.0 - (np.arange(h) + 0.5) / h
    cols = np.nonzero((xs >= ndc[0]) & (xs < ndc[2]))[0]
    rows = np.nonzero((ys >= ndc[1]) & (ys < ndc[3]))[0]
    return int(cols.min()), int(rows.min()), int(cols.max()) + 1, int(rows.max()) + 1


def test_data_window_includes_pixels_by_their_centre():
    # 0.26 * 10 = 2.6 > 2.5, the centre of column 2: column 2 is out, and 7 (centre 7.5 > 7.4)
    assert _data_window((0.26, 0.0, 0.74, 1.0), 10, 10) == (3, 0, 7, 10)
    assert _data_window((0.0, 0.26, 1.0, 0.74), 10, 10) == (0, 3, 10, 7)
    rng = np.random.default_rng(7)
    for _ in range(300):
        w, h = (int(v) for v in rng.integers(1, 40, 2))
        x = np.sort(rng.random(2))
        y = np.sort(rng.random(2))
        ndc = (x[0], y[0], x[1], y[1])
        try:
            expected = _brute_window(ndc, w, h)
        except ValueError:  # no pixel centre inside
            continue
        assert _data_window(ndc, w, h) == expected, (ndc, w, h)


def test_adjacent_data_windows_tile_the_image():
    left = _data_window((0.0, 0.0, 0.5, 1.0), 9, 9)
    right = _data_window((0.5, 0.0, 1.0, 1.0), 9, 9)
    assert left[2] == right[0] and left[0] == 0 and right[2] == 9
    top = _data_window((0.0, 0.5, 1.0, 1.0), 9, 9)
    bottom = _data_window((0.0, 0.0, 1.0, 0.5), 9, 9)
    assert top[3] == bottom[1] and top[1] == 0 and bottom[3] == 9


@pytest.mark.parametrize("policy,expected", [
    ("expandAperture", (4.0, 2.0)),        # image (2:1) wider than the aperture (3:2): widen
    ("cropAperture", (3.0, 1.5)),          # ... or crop its height
    ("adjustApertureWidth", (4.0, 2.0)),
    ("adjustApertureHeight", (3.0, 1.5)),
    ("adjustPixelAspectRatio", (3.0, 2.0)),  # aperture kept, pixels stretch
])
def test_every_conform_policy_with_a_non_square_pixel_aspect(policy, expected):
    """UsdRender aspectRatioConformPolicy against image aspect = width * pixelAspectRatio / height
    (here 100 * 2 / 100 = 2); the aperture offset stays the window centre."""
    desc = CameraDesc(path="/Cam", camera_to_world=np.eye(4), focal_length=2.0, horizontal_aperture=3.0,
                      vertical_aperture=2.0, horizontal_aperture_offset=0.4, vertical_aperture_offset=-0.2)
    cam = Camera(desc, 100, 100, pixel_aspect=2.0, conform=policy)
    assert (cam.horizontal_aperture, cam.vertical_aperture) == pytest.approx(expected)
    wx0, wx1, wy0, wy1 = cam.window
    assert (wx1 - wx0, wy1 - wy0) == pytest.approx((expected[0] / 2.0, expected[1] / 2.0))
    assert (0.5 * (wx0 + wx1), 0.5 * (wy0 + wy1)) == pytest.approx((0.2, -0.1))
