"""RectLight: sampling vs pdf (chi-square), pdf round trip, irradiance, intersection, texture."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.description import LightDesc
from renderer.errors import StageError
from renderer.lights.rect import RectLight
from renderer.lights.spherical_rect import MIN_SOLID_ANGLE
from tests.lights.helpers import (
    area_quadrature_irradiance,
    chi2_on_surface,
    ctx,
    irradiance_samples,
    look_down,
    planar_axis_setup,
    polygon_outline,
    ray_triangle,
    rotate,
    sampler_for,
    scale,
    translate,
)
from tests.stats import SIGNIFICANCE, chi2_directions, z_test


SHEAR = np.array([[1, 0.6, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def rect(m, width=1.0, height=1.0, **kw) -> LightDesc:
    return LightDesc("/Rect", "rect", np.asarray(m, dtype=np.float64), width=width, height=height, **kw)


def corners(light: RectLight, i: int = 0) -> np.ndarray:
    c, hx, hy = light.center[i], 0.5 * light.ex[i], 0.5 * light.ey[i]
    return np.array([c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy])


def cone_setup(light: RectLight, p):
    return planar_axis_setup(light, 0, p, polygon_outline(corners(light)), light.n[0])


def solid_angle_of(light, p):
    from renderer.lights import spherical_rect

    k = corners(light)
    sr = spherical_rect.setup(np.asarray(p, float)[None], k[0][None], light.ex[:1], light.ey[:1])
    return float(sr.solid_angle[0]), bool(sr.usable[0])


# Lights facing down (-Z) seen from points below, one per sampling regime.
CONFIGS = {
    # name: (desc, point, spherical-rectangle sampling expected)
    "small_far": (rect(translate(0, 0, 10), 0.01, 0.01), (0.0, 0.0, 0.0), False),
    "just_above_threshold": (rect(translate(3, 1, 60), 1.0, 0.8), (0.0, 0.0, 0.0), True),
    "large_near": (rect(translate(0, 0, 1), 4.0, 2.0), (0.3, 0.2, 0.0), True),
    "oblique": (rect(translate(0, 0, 0.6), 1.0, 1.0), (2.5, 0.3, 0.0), True),
    "edge_on": (rect(translate(0, 0, 0.05), 1.0, 1.0), (2.5, 0.3, 0.0), True),
    "grazing": (rect(translate(0, 0, 0.0005), 1.0, 1.0), (3.0, 0.0, 0.0), False),
    "rotated_scaled": (rect(translate(1, -1, 2) @ rotate((1, 1, 0), 30) @ scale(2, 0.5, 1), 1.0, 1.0), (0.0, 0.0, 0.0), True),
    "sheared": (rect(translate(0, 0, 1.5) @ SHEAR, 2.0, 1.0), (0.2, 0.1, 0.0), False),
}
# Seen almost edge-on the light is a band a fraction of a degree thick, which the direction
# bins of chi2_directions cannot integrate accurately; those are tested on the surface instead.
EDGE_ON = ("edge_on", "grazing")


@pytest.mark.parametrize("name", list(CONFIGS))
def test_strategy(name):
    desc, p, spherical = CONFIGS[name]
    light = RectLight.build([desc])
    omega, usable = solid_angle_of(light, p)
    if name == "just_above_threshold":
        assert MIN_SOLID_ANGLE < omega < 3 * MIN_SOLID_ANGLE
    if name == "sheared":
        assert not light.is_rectangle[0]
    else:
        assert light.is_rectangle[0] and usable == spherical


@pytest.mark.parametrize("name", [n for n in CONFIGS if n not in EDGE_ON])
def test_chi2_sample_matches_pdf(name):
    desc, p, _ = CONFIGS[name]
    light = RectLight.build([desc])
    axis, cos_range = cone_setup(light, p)
    sample, pdf = sampler_for(light, 0, p)
    pval, details = chi2_directions(
        sample, pdf, axis=axis, cos_range=cos_range, n_samples=100_000, seed=3, integration_res=24, res_phi=60
    )
    assert pval > SIGNIFICANCE, details["chi2"]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_chi2_on_surface(name):
    """The sampled points' density on the light equals pdf_li * |cos theta_l| / d^2."""
    desc, p, _ = CONFIGS[name]
    light = RectLight.build([desc])
    n = 200_000
    c = ctx(p, count=n)
    idx = np.zeros(n, dtype=np.int64)
    s = light.sample_li(idx, c, np.random.default_rng(4).random((n, 2)))
    assert np.all(s.pdf > 0.0)
    to_ab = lambda x: light._ab(np.zeros(len(x), dtype=np.int64), x)  # noqa: E731

    def density(ab):
        x = light.center[0] + ab[:, :1] * light.ex[0] + ab[:, 1:] * light.ey[0]
        v = x - np.asarray(p)
        d = np.linalg.norm(v, axis=1)
        wi = v / d[:, None]
        pw = light.pdf_li(np.zeros(len(x), dtype=np.int64), ctx(p, count=len(x)), wi)
        return pw * np.abs(wi @ light.n[0]) / d**2 * light.area[0]

    assert chi2_on_surface(to_ab, density, s.p_light, n) > SIGNIFICANCE


@pytest.mark.parametrize("name", list(CONFIGS))
def test_pdf_round_trip(name):
    desc, p, _ = CONFIGS[name]
    light = RectLight.build([desc])
    n = 4000
    u = np.random.default_rng(11).random((n, 2))
    c = ctx(p, count=n)
    s = light.sample_li(np.zeros(n, dtype=np.int64), c, u)
    assert np.all(s.pdf > 0.0)
    assert np.allclose(np.linalg.norm(s.wi, axis=1), 1.0)
    pdf = light.pdf_li(np.zeros(n, dtype=np.int64), c, s.wi)
    np.testing.assert_allclose(pdf, s.pdf, rtol=1e-6)
    # The sampled point lies on the light, at the returned distance along wi.
    np.testing.assert_allclose(c.p + s.wi * s.dist[:, None], s.p_light, atol=1e-9 * max(1.0, s.dist.max()))
    t = light.intersect(np.zeros(n, dtype=np.int64), c.p, s.wi)
    np.testing.assert_allclose(t, s.dist, rtol=1e-7)


def _rect_quadrature(light: RectLight, p, n_normal, res=800):
    a = (np.arange(res) + 0.5) / res - 0.5
    A, B = np.meshgrid(a, a, indexing="ij")
    pts = light.center[0] + A.reshape(-1, 1) * light.ex[0] + B.reshape(-1, 1) * light.ey[0]
    normals = np.tile(light.n[0], (pts.shape[0], 1))
    return area_quadrature_irradiance(pts, normals, light.area[0] / res**2, p, n_normal, light.L[0, 0])


IRRADIANCE = {
    "large_near_facing": (rect(translate(0, 0, 1), 4.0, 2.0), (0.3, 0.2, 0.0), (0.0, 0.0, 1.0)),
    "partly_below_horizon": (rect(translate(0, 0, 1), 4.0, 2.0), (0.3, 0.2, 0.0), (0.8, 0.0, 0.6)),
    "tilted_partly_below": (rect(translate(1, 0, 0.5) @ rotate((0, 1, 0), 60), 2.0, 2.0), (0, 0, 0), (0.0, 0.0, 1.0)),
    "tiny": (rect(translate(0.5, 0, 3), 3e-3, 3e-3), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "far": (rect(translate(30, 10, 100) @ look_down((-30, -10, -100)), 2.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.6, 0.8)),
}


@pytest.mark.parametrize("name", list(IRRADIANCE))
def test_irradiance_matches_quadrature(name):
    desc, p, n_normal = IRRADIANCE[name]
    n_normal = np.asarray(n_normal) / np.linalg.norm(n_normal)
    light = RectLight.build([desc])
    ref = _rect_quadrature(light, p, n_normal)
    est = irradiance_samples(light, 0, p, n_normal, n=100_000)
    assert ref > 0.0
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    assert abs(est.mean() / ref - 1.0) < 0.02


def test_lambert_polygon_cross_check():
    """Independent closed form for a rect fully above the horizon (Lambert's polygon formula)."""
    light = RectLight.build([rect(translate(0, 0, 1), 4.0, 2.0)])
    p = np.array([0.3, 0.2, 0.0])
    n = np.array([0.0, 0.0, 1.0])
    v = corners(light) - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    total = 0.0
    for i in range(4):
        a, b = v[i], v[(i + 1) % 4]
        c = np.cross(a, b)
        total += np.arccos(np.clip(a @ b, -1, 1)) * (c @ n) / np.linalg.norm(c)
    lambert = abs(0.5 * total)
    np.testing.assert_allclose(_rect_quadrature(light, p, n), lambert, rtol=1e-5)


def test_behind_and_in_plane_fail():
    light = RectLight.build([rect(translate(0, 0, 1), 1.0, 1.0)])
    for p in [(0.0, 0.0, 2.0), (0.2, 0.1, 1.0), (5.0, 0.0, 1.0)]:
        c = ctx(p, count=16)
        s = light.sample_li(np.zeros(16, dtype=np.int64), c, np.random.default_rng(0).random((16, 2)))
        assert np.all(s.pdf == 0.0) and np.all(s.L == 0.0)
        wi = np.tile([0.0, 0.0, -1.0 if p[2] > 1 else 1.0], (16, 1))
        assert np.all(light.pdf_li(np.zeros(16, dtype=np.int64), c, wi) == 0.0)


def test_intersect_and_le_one_sided():
    light = RectLight.build([rect(translate(0, 0, 1), 2.0, 1.0, intensity=3.0)])
    idx = np.zeros(6, dtype=np.int64)
    o = np.array([[0, 0, 0], [0.9, 0.45, 0], [1.1, 0, 0], [0, 0, 2], [0, 0, 0], [0, 0, 0.0]])
    d = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0, -1.0]])
    t = light.intersect(idx, o, d)
    np.testing.assert_allclose(t[:2], 1.0)
    assert np.isinf(t[2]) and np.isinf(t[4]) and np.isinf(t[5])
    np.testing.assert_allclose(t[3], 1.0)  # geometric hit from behind ...
    p_hit = o[:4] + np.where(np.isfinite(t[:4]), t[:4], 0.0)[:, None] * d[:4]
    le = light.le(idx[:4], p_hit, d[:4])
    np.testing.assert_allclose(le[:2], 3.0)
    assert np.all(le[3] == 0.0)  # ... but no emission toward +Z


@pytest.mark.parametrize("desc", [rect(translate(0, 0, 1) @ rotate((1, 2, 0), 40), 2.0, 0.5),
                                  rect(translate(0, 0, 1) @ SHEAR)])
def test_proxy_triangles_are_exact(desc):
    light = RectLight.build([desc])
    tris, owner = light.proxy_triangles()
    assert tris.shape == (2, 3, 3) and np.all(owner == 0)
    rng = np.random.default_rng(5)
    n = 3000
    o = rng.normal(size=(n, 3)) * 3.0
    target = light.center[0] + (rng.random((n, 1)) - 0.5) * 1.4 * light.ex[0] + (rng.random((n, 1)) - 0.5) * 1.4 * light.ey[0]
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = light.intersect(np.zeros(n, dtype=np.int64), o, d)
    tp = ray_triangle(o, d, tris).min(axis=1)
    hit = np.isfinite(t)
    assert 0.2 < hit.mean() < 0.9
    np.testing.assert_allclose(tp[hit], t[hit], rtol=1e-9)
    assert np.all(np.isinf(tp[~hit]))


# --------------------------------------------------------------------------------------
# Texture
# --------------------------------------------------------------------------------------
def write_exr(path, img):
    assert oiio.ImageBuf(np.ascontiguousarray(img, dtype=np.float32)).write(str(path))
    return str(path)


def test_texture_orientation(tmp_path):
    """uv (0,0) (the image's bottom-left texel) at local (+X,+Y); top-right texel at (-X,-Y)."""
    h, w = 2, 4
    img = np.zeros((h, w, 3))
    img[..., 0] = np.arange(h * w).reshape(h, w) + 1.0  # texel id + 1 in red, row 0 = top
    f = write_exr(tmp_path / "t.exr", img)
    light = RectLight.build([rect(np.eye(4), 2.0, 1.0, texture_file=f)])
    q = np.array([[0.9, 0.45, 0.0], [-0.9, -0.45, 0.0], [0.9, -0.45, 0.0], [-0.9, 0.45, 0.0], [0.1, 0.2, 0.0]])
    wi = np.tile([0.0, 0.0, 1.0], (5, 1))  # arriving at the -Z side: the emitting side
    le = light.le(np.zeros(5, dtype=np.int64), q, wi)[:, 0]
    ids = lambda row, col: row * w + col + 1.0  # noqa: E731
    np.testing.assert_array_equal(le, [ids(1, 0), ids(0, 3), ids(0, 0), ids(1, 3), ids(1, 1)])


def textured_light(tmp_path, m=None):
    h, w = 12, 16
    img = np.full((h, w, 3), 0.05)
    img[2:4, 10:13] = (20.0, 10.0, 5.0)  # a bright patch
    img[9, 1] = (0.0, 0.0, 3.0)  # a blue texel
    img[:, 5] = 0.0  # a black column: never sampled
    f = write_exr(tmp_path / "patch.exr", img)
    desc = rect(translate(0.2, 0.1, 1.0) if m is None else m, 2.0, 1.5, texture_file=f)
    return RectLight.build([desc]), img


def test_textured_chi2_and_round_trip(tmp_path):
    light, _ = textured_light(tmp_path)
    p = (0.0, 0.0, 0.0)
    axis, cos_range = cone_setup(light, p)
    sample, pdf = sampler_for(light, 0, p)
    pval, details = chi2_directions(sample, pdf, axis=axis, cos_range=cos_range, res_theta=30, res_phi=60, n_samples=300_000)
    assert pval > SIGNIFICANCE, details["chi2"]
    n = 2000
    c = ctx(p, count=n)
    s = light.sample_li(np.zeros(n, dtype=np.int64), c, np.random.default_rng(2).random((n, 2)))
    assert np.all(s.pdf > 0.0)
    np.testing.assert_allclose(light.pdf_li(np.zeros(n, dtype=np.int64), c, s.wi), s.pdf, rtol=1e-6)


def test_textured_irradiance(tmp_path):
    light, img = textured_light(tmp_path)
    h, w = img.shape[:2]
    p = np.array([0.0, 0.0, 0.0])
    n_normal = np.array([0.0, 0.0, 1.0])
    res = 960
    a = (np.arange(res) + 0.5) / res - 0.5
    A, B = np.meshgrid(a, a, indexing="ij")
    # Independent texture lookup: u = 1/2 - a, v = 1/2 - b, v up (row 0 at the top).
    uu, vv = 0.5 - A.ravel(), 0.5 - B.ravel()
    col = np.floor(uu * w).astype(int)
    row = np.floor((1.0 - vv) * h).astype(int)
    tex = img[row, col, 0]
    pts = light.center[0] + A.reshape(-1, 1) * light.ex[0] + B.reshape(-1, 1) * light.ey[0]
    v = pts - p
    d2 = (v * v).sum(1)
    wdir = v / np.sqrt(d2)[:, None]
    ref = float((tex * np.maximum(0, wdir @ n_normal) * np.maximum(0, -(wdir @ light.n[0])) / d2).sum() * light.area[0] / res**2)
    est = irradiance_samples(light, 0, p, n_normal, n=100_000)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)


def test_texture_errors(tmp_path):
    img = np.ones((4, 4, 3))
    img[0, 0, 1] = np.nan
    img[1, 2, 0] = -1.0
    f = write_exr(tmp_path / "bad.exr", img)
    with pytest.raises(StageError, match="2 texel"):
        RectLight.build([rect(np.eye(4), texture_file=f)])
    with pytest.raises(StageError, match="missing.exr"):
        RectLight.build([rect(np.eye(4), texture_file=str(tmp_path / "missing.exr"))])


def test_mirrored_transform_flips_the_emitting_side():
    """scale(1, 1, -1) maps the local -Z half-space to world +Z: the light then emits upward."""
    light = RectLight.build([rect(scale(1, 1, -1))])
    np.testing.assert_allclose(light.n[0], [0, 0, 1.0])
    n = 8
    idx = np.zeros(n, dtype=np.int64)
    u = np.random.default_rng(0).random((n, 2))
    assert np.all(light.sample_li(idx, ctx((0, 0, 1.0), count=n), u).pdf > 0)
    assert np.all(light.sample_li(idx, ctx((0, 0, -1.0), count=n), u).pdf == 0)


def test_srgb_png_texture_is_linearised(tmp_path):
    img = np.zeros((2, 2, 3), dtype=np.uint8)
    img[...] = 128
    f = str(tmp_path / "grey.png")
    assert oiio.ImageBuf(img).write(f)
    light = RectLight.build([rect(np.eye(4), texture_file=f)])
    le = light.le(np.zeros(1, dtype=np.int64), np.zeros((1, 3)), np.array([[0, 0, 1.0]]))
    np.testing.assert_allclose(le[0], ((128 / 255 + 0.055) / 1.055) ** 2.4, rtol=1e-6)


def test_strategy_threshold_and_phi():
    light = RectLight.build([rect(translate(0, 0, 1), 2.0, 3.0, intensity=2.0)])
    assert light.phi()[0] == pytest.approx(np.pi * 6.0 * 2.0)
    omega, usable = solid_angle_of(light, (0, 0, -1000.0))
    assert omega < MIN_SOLID_ANGLE and not usable
