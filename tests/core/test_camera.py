"""Camera rays against pxr's own Gf.Camera frustum."""

import numpy as np
import pytest
from pxr import Gf

from renderer.camera import Camera, check_resolution
from renderer.description import CameraDesc
from renderer.errors import SettingsError


def _gf_camera(focal=50.0, ha=36.0, va=24.0, ho=0.0, vo=0.0, proj=Gf.Camera.Perspective, xform=None):
    cam = Gf.Camera()
    cam.projection = proj
    cam.focalLength = focal
    cam.horizontalAperture = ha
    cam.verticalAperture = va
    cam.horizontalApertureOffset = ho
    cam.verticalApertureOffset = vo
    if xform is not None:
        cam.transform = xform
    return cam


def _desc_from_gf(cam: Gf.Camera) -> CameraDesc:
    # USD apertures/focal length are in tenths of a scene unit; the reader multiplies by 0.1.
    m = np.array(cam.transform, dtype=np.float64).T
    return CameraDesc(
        path="/cam",
        camera_to_world=m,
        projection="orthographic" if cam.projection == Gf.Camera.Orthographic else "perspective",
        focal_length=cam.focalLength * 0.1,
        horizontal_aperture=cam.horizontalAperture * 0.1,
        vertical_aperture=cam.verticalAperture * 0.1,
        horizontal_aperture_offset=cam.horizontalApertureOffset * 0.1,
        vertical_aperture_offset=cam.verticalApertureOffset * 0.1,
    )


@pytest.mark.parametrize("ho,vo", [(0.0, 0.0), (3.0, -2.0)])
def test_window_matches_gf_frustum(ho, vo):
    gf = _gf_camera(ho=ho, vo=vo)
    cam = Camera(_desc_from_gf(gf), 360, 240)  # same aspect as the aperture: no conform
    win = gf.frustum.window
    np.testing.assert_allclose(cam.window, (win.min[0], win.max[0], win.min[1], win.max[1]), rtol=1e-9, atol=1e-12)


def test_corner_rays_match_frustum_rays():
    xf = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0, 1, 0), 30.0)) * Gf.Matrix4d().SetTranslate(Gf.Vec3d(1, 2, 3))
    gf = _gf_camera(xform=xf)
    cam = Camera(_desc_from_gf(gf), 360, 240)
    fr = gf.frustum
    # Raster (0,0) is the top-left image corner; NDC (-1, +1) in Gf.
    for (rx, ry), ndc in (((0, 0), (-1, 1)), ((360, 240), (1, -1)), ((180, 120), (0, 0))):
        q = cam.raster_to_camera(np.array([float(rx)]), np.array([float(ry)]))
        from renderer.geometry import normalize, transform_vectors

        d = normalize(transform_vectors(cam.camera_to_world, normalize(q)))[0]
        ray = fr.ComputePickRay(Gf.Vec2d(*ndc))
        expect = np.array(ray.direction)
        expect /= np.linalg.norm(expect)
        np.testing.assert_allclose(d, expect, atol=1e-9)
        # Gf's pick ray starts on the near plane: it must lie on our ray from the eye.
        v = np.array(ray.startPoint) - cam.camera_to_world[:3, 3]
        np.testing.assert_allclose(np.cross(v, d), 0.0, atol=1e-9)


def test_expand_aperture_conform_keeps_vertical_when_image_is_wider():
    gf = _gf_camera(ha=24.0, va=24.0)
    cam = Camera(_desc_from_gf(gf), 400, 200)  # image 2:1, aperture 1:1 -> expand width
    assert cam.vertical_aperture == pytest.approx(2.4)
    assert cam.horizontal_aperture == pytest.approx(4.8)
    cam = Camera(_desc_from_gf(gf), 200, 400)  # taller -> expand height
    assert cam.horizontal_aperture == pytest.approx(2.4)
    assert cam.vertical_aperture == pytest.approx(4.8)


def test_orthographic_rays_are_parallel_and_span_aperture():
    gf = _gf_camera(proj=Gf.Camera.Orthographic, ha=200.0, va=100.0)
    cam = Camera(_desc_from_gf(gf), 200, 100)
    n = 5
    r = cam.generate(np.array([0, 199, 100, 0, 199]), np.array([0, 0, 50, 99, 99]),
                     np.full((n, 2), 0.5), np.full((n, 2), 0.5))
    np.testing.assert_allclose(r.d, np.tile([0, 0, -1.0], (n, 1)), atol=1e-12)
    assert r.o[:, 0].min() > -10.0 and r.o[:, 0].max() < 10.0  # 20 scene units wide
    assert r.o[1, 0] > 9.5 and r.o[0, 0] < -9.5


def test_thin_lens_rays_converge_on_focus_plane():
    desc = _desc_from_gf(_gf_camera())
    desc = CameraDesc(**{**desc.__dict__, "f_stop": 2.0, "focus_distance": 7.0})
    cam = Camera(desc, 64, 64)
    assert cam.lens_radius == pytest.approx(5.0 / 4.0)
    rng = np.random.default_rng(3)
    n = 100
    px = np.full(n, 20)
    py = np.full(n, 40)
    r = cam.generate(px, py, np.full((n, 2), 0.5), rng.random((n, 2)))
    # Every ray through one film point meets the plane z = -7 at the same point.
    t = (-7.0 - r.o[:, 2]) / r.d[:, 2]
    hit = r.o + r.d * t[:, None]
    assert np.ptp(hit[:, 0]) < 1e-9 and np.ptp(hit[:, 1]) < 1e-9
    assert np.ptp(r.o[:, 0]) > 0.5  # the origins really spread over the lens


def test_pixel_filter_offsets_stay_within_radius_and_centered():
    cam = Camera(_desc_from_gf(_gf_camera()), 36, 24)
    u = np.random.default_rng(0).random((200000, 2))
    off = cam.filter.sample(u)
    assert np.abs(off).max() <= 1.5
    assert abs(off.mean()) < 0.01
    # Gaussian sigma 0.5 truncated at 1.5: standard deviation a little under 0.5.
    assert 0.4 < off.std() < 0.5


def _truncated_gaussian_cdf(x, radius=1.5, sigma=0.5):
    """Exact CDF of the filter's density g(x) - g(radius) on [-radius, radius]."""
    import math

    c = math.exp(-0.5 * (radius / sigma) ** 2)

    def antideriv(v):
        return sigma * math.sqrt(math.pi / 2.0) * math.erf(v / (sigma * math.sqrt(2.0))) - c * v

    lo = antideriv(-radius)
    return np.array([(antideriv(v) - lo) / (antideriv(radius) - lo) for v in np.atleast_1d(x)])


@pytest.mark.parametrize("seed", [0, 1])
def test_pixel_filter_samples_follow_the_truncated_gaussian_chi_square(seed):
    """Chi-square of filter offsets against the exact truncated-Gaussian CDF, on 60 bins; the
    tabulated inverse CDF must not distort the tails either (a plain uniform or an untruncated
    Gaussian fails this by orders of magnitude)."""
    from tests.stats import chi2_sf

    cam = Camera(_desc_from_gf(_gf_camera()), 36, 24)
    n = 400000
    off = cam.filter.sample(np.random.default_rng(seed).random((n, 2))).ravel()
    edges = np.linspace(-1.5, 1.5, 61)
    counts, _ = np.histogram(off, bins=edges)
    expected = np.diff(_truncated_gaussian_cdf(edges)) * off.size
    keep = expected > 5.0
    chi2 = float(np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep]))
    assert chi2_sf(chi2, int(keep.sum()) - 1) > 1e-3, chi2


def test_pixel_filter_chi_square_detects_a_wrong_sigma():
    """The same statistic rejects offsets drawn with sigma 0.52 instead of 0.5 (power check)."""
    from tests.stats import chi2_sf

    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 0.52, 1200000)
    x = x[np.abs(x) <= 1.5][:800000]
    edges = np.linspace(-1.5, 1.5, 61)
    counts, _ = np.histogram(x, bins=edges)
    expected = np.diff(_truncated_gaussian_cdf(edges)) * x.size
    keep = expected > 5.0
    chi2 = float(np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep]))
    assert chi2_sf(chi2, int(keep.sum()) - 1) < 1e-6


@pytest.mark.parametrize("w,h", [(0, 10), (10, -1), (16385, 10), (9000, 9000)])
def test_absurd_resolutions_are_rejected(w, h):
    with pytest.raises(SettingsError, match="resolution"):
        check_resolution(w, h)
