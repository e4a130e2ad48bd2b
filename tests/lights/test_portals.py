"""Dome portals: sampling through PortalLights vs pdf, the per-point fallback, and unbiased direct
lighting inside a closed box lit through a window (analytic projected solid angle)."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.accel import Accel
from renderer.bsdfs.lambert import LambertBSDF
from renderer.description import LightDesc
from renderer.estimators import REGISTRY, DirectQuery, DirectRandom
from renderer.geometry import coordinate_frame, offset_origin, to_local
from renderer.lights.analytic import projected_solid_angle_rect
from renderer.lights.base import ShadingContext
from renderer.lights.dome import TEXTURED_PORTAL_FRACTION, DomeLight
from renderer.lights.light_set import LightSet
from tests.lights.helpers import ctx, rotate, sampler_for, translate
from tests.stats import SIGNIFICANCE, chi2_directions, z_test

# The window: x in [-0.3, 0.4], y in [-0.2, 0.3] in the top face (z = 1) of the box [-1, 1]^3.
WIN_C = np.array([0.05, 0.05, 1.0])
WIN_W, WIN_H = 0.7, 0.5


def portal_frame(center, w, h, m=np.eye(4)) -> np.ndarray:
    """World frame of a PortalLight (width/height folded in): local -Z is m's image of -Z."""
    return translate(*center) @ m @ np.diag([w, h, 1.0, 1.0])


def dome_desc(portals=(), texture_file="", intensity=2.0) -> LightDesc:
    frames = np.stack(portals) if len(portals) else None
    return LightDesc("/Sky", "dome", np.eye(4), intensity=intensity, texture_file=texture_file,
                     portals=frames, portal_paths=tuple(f"/P{k}" for k in range(len(portals))))


@pytest.fixture
def sky_exr(tmp_path):
    """A small lat-long sky: a gradient and one bright texel block (a 'sun')."""
    h, w = 16, 32
    img = np.ones((h, w, 3), np.float32) * np.linspace(2.0, 0.5, h)[:, None, None]
    img[3:5, 14:16] = 60.0
    path = str(tmp_path / "sky.exr")
    assert oiio.ImageBuf(img).write(path)
    return path


def test_chi2_through_two_portals():
    """A constant dome: directions uniform over the union of the usable portals' solid angles;
    a portal whose interior side is away from p is not used."""
    up = portal_frame(WIN_C, WIN_W, WIN_H)
    side = portal_frame((1.0, 0.1, 0.2), 0.6, 0.8, rotate((0, 1, 0), 90))  # interior toward -X
    away = portal_frame((0.0, 0.0, -1.0), 0.5, 0.5)                        # interior toward -Z: p is above it
    light = DomeLight.build([dome_desc([up, side, away])], np.zeros(3), 5.0)
    np.testing.assert_allclose(light.portal_n, [[0, 0, -1], [-1, 0, 0], [0, 0, -1]], atol=1e-12)
    p = (0.1, 0.0, -0.5)
    sample, pdf = sampler_for(light, 0, p)
    pval, details = chi2_directions(sample, pdf, axis=(0.5, 0.1, 0.86), cos_range=(0.0, 1.0), n_samples=100_000,
                                    res_theta=8, res_phi=16, integration_res=64)
    assert pval > SIGNIFICANCE, details["chi2"]


def test_chi2_textured_mixture(sky_exr):
    light = DomeLight.build([dome_desc([portal_frame(WIN_C, WIN_W, WIN_H)], texture_file=sky_exr)], np.zeros(3), 5.0)
    assert light.portal_fraction[0] == TEXTURED_PORTAL_FRACTION < 1.0
    sample, pdf = sampler_for(light, 0, (0.1, 0.0, -0.5))
    # The density jumps along texel and portal-table cell edges: a fine sub-grid integrates them.
    pval, details = chi2_directions(sample, pdf, n_samples=200_000, res_theta=16, res_phi=32, integration_res=64)
    assert pval > SIGNIFICANCE, details["chi2"]


def test_round_trip_support_and_fallback():
    light = DomeLight.build([dome_desc([portal_frame(WIN_C, WIN_W, WIN_H)])], np.zeros(3), 5.0)
    n = 4000
    rng = np.random.default_rng(2)
    idx = np.zeros(n, dtype=np.int64)
    inside = ctx((0.1, 0.0, -0.5), count=n)
    s = light.sample_li(idx, inside, rng.random((n, 2)))
    assert np.all(s.pdf > 0)
    np.testing.assert_allclose(light.pdf_li(idx, inside, s.wi), s.pdf, rtol=1e-12)
    G = projected_solid_angle_rect(inside.p[:1], [0, 0, 1.0], WIN_C, [WIN_W, 0, 0], [0, WIN_H, 0], [0, 0, -1.0])
    # Every sample crosses the window; outside it the light pdf is 0 (BSDF sampling covers it).
    t = (WIN_C[2] - inside.p[:, 2]) / s.wi[:, 2]
    x = inside.p + s.wi * t[:, None]
    assert np.all(np.abs(x[:, 0] - WIN_C[0]) <= WIN_W / 2 + 1e-12) and np.all(np.abs(x[:, 1] - WIN_C[1]) <= WIN_H / 2 + 1e-12)
    assert light.pdf_li(idx[:1], inside.take(np.array([0])), np.array([[0.0, 1.0, 0.0]]))[0] == 0.0
    assert G[0] > 0
    # Above the window (on its exterior side) no portal is usable: the ordinary dome sampling.
    outside = ctx((0.0, 0.0, 2.0), count=n)
    s2 = light.sample_li(idx, outside, rng.random((n, 2)))
    np.testing.assert_allclose(s2.pdf, 1 / (4 * np.pi))
    np.testing.assert_allclose(light.pdf_li(idx, outside, s2.wi), 1 / (4 * np.pi))


def test_zero_size_and_sheared_portals_are_dropped_with_a_warning():
    shear = np.eye(4)
    shear[0, 1] = 0.5
    light = DomeLight.build([dome_desc([portal_frame(WIN_C, 0.0, 1.0), portal_frame(WIN_C, 1.0, 1.0, shear)])],
                            np.zeros(3), 5.0)
    assert not light.has_portals[0]
    assert any("/P0" in w and "zero width" in w for w in light.warnings)
    assert any("/P1" in w and "sheared" in w for w in light.warnings)


def test_portal_domes_have_no_exact_integral():
    ls = LightSet.build([dome_desc([portal_frame(WIN_C, WIN_W, WIN_H)]), dome_desc()], np.zeros(3), 5.0)
    np.testing.assert_array_equal(ls.has_exact_integral, [False, True])
    E, exact = ls.irradiance(np.array([0, 1]), ctx((0, 0, 0), (0, 0, 1.0), count=2))
    np.testing.assert_array_equal(exact, [False, True])


# ----------------------------------------------------------------------------------------
# Unbiased direct lighting through a window
# ----------------------------------------------------------------------------------------
def box_with_window() -> Accel:
    """The box [-1, 1]^3 (two triangles per face) with the window cut out of its top face."""
    def rect(x0, x1, y0, y1, z):
        a, b, c, d = [x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]
        return [[a, b, c], [a, c, d]]
    tris = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            if axis == 2 and sign > 0:
                continue
            q = np.array(rect(-1, 1, -1, 1, sign))
            tris += np.roll(q, axis + 1, axis=2).tolist() if axis != 2 else q.tolist()
    wx0, wx1 = WIN_C[0] - WIN_W / 2, WIN_C[0] + WIN_W / 2
    wy0, wy1 = WIN_C[1] - WIN_H / 2, WIN_C[1] + WIN_H / 2
    tris += rect(-1, 1, -1, wy0, 1.0) + rect(-1, 1, wy1, 1, 1.0) + rect(-1, wx0, wy0, wy1, 1.0) + rect(wx1, 1, wy0, wy1, 1.0)
    return Accel(np.array(tris, float), threads=1)


class Room:
    """n shading points at p (normal +z) inside the box, one dome light, a Lambert BSDF."""

    def __init__(self, desc: LightDesc, p=(0.1, 0.0, -0.5), n=20000, rho=0.5):
        self.lights = LightSet.build([desc], np.zeros(3), 2.0)
        self.accel = box_with_window()
        self.n, self.rho, self.p = n, rho, np.asarray(p, float)
        nz = np.tile([0.0, 0.0, 1.0], (n, 1))
        self.ctx = ShadingContext(np.tile(self.p, (n, 1)), nz, nz)
        self.s, self.t = coordinate_frame(nz)
        self.wo_l = to_local(nz, self.s, self.t, nz)
        self.bsdf = LambertBSDF(np.full((n, 3), rho))

    def trace(self, p, ng, wi, dist, eps):
        o = offset_origin(p, ng, wi, eps)
        t_max = np.where(np.isfinite(dist), dist * (1 - 1e-6) - eps, np.inf)
        return ~self.accel.occluded(o, wi, t_max)

    def estimate(self, token: str, seed: int = 0) -> np.ndarray:
        q = DirectQuery(self.ctx, self.s, self.t, self.wo_l, self.bsdf, np.zeros(self.n, dtype=np.int64),
                        np.full(self.n, 1e-7), self.bsdf.diffuse_constant(self.wo_l))
        res = REGISTRY[token].estimate(q, self.lights, self.trace, 1, DirectRandom.draw(np.random.default_rng(seed),
                                                                                      self.n, 1), "one", "power")
        return res.Ld[:, 0]

    def window_reference(self, L: float) -> float:
        """rho / pi * L * (projected solid angle of the window seen from p)."""
        G = projected_solid_angle_rect(self.p[None], [0, 0, 1.0], WIN_C, [WIN_W, 0, 0], [0, WIN_H, 0], [0, 0, -1.0])[0]
        return self.rho / np.pi * L * G


@pytest.mark.parametrize("token", ["mis", "lightSampling", "bsdfSampling"])
def test_direct_light_through_window_is_unbiased(token):
    """A constant dome seen only through the window: every estimator equals rho/pi L G_window.
    With the portal on the window, light sampling alone is already unbiased (and far less noisy
    than BSDF sampling)."""
    room = Room(dome_desc([portal_frame(WIN_C, WIN_W, WIN_H)]))
    ref = room.window_reference(2.0)
    est = room.estimate(token, seed=3)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    if token == "lightSampling":
        bsdf = room.estimate("bsdfSampling", seed=4)
        assert est.var() < 0.2 * bsdf.var()


def test_portal_smaller_than_window_stays_unbiased_with_mis():
    """A portal covering only part of the window: light samples never reach the rest, but
    BSDF-sampled rays still see the dome there with weight 1, so MIS stays unbiased while
    light sampling alone misses light (a test that can fail)."""
    small = portal_frame(WIN_C + [0.1, 0.0, 0.0], WIN_W / 2, WIN_H)
    room = Room(dome_desc([small]))
    ref = room.window_reference(2.0)
    mis = room.estimate("mis", seed=5)
    assert z_test(mis, ref) > SIGNIFICANCE, (mis.mean(), ref)
    light_only = room.estimate("lightSampling", seed=6)
    assert z_test(light_only, ref) < SIGNIFICANCE


def test_textured_dome_through_window_is_unbiased(sky_exr):
    """Textured dome: the reference integrates the dome's radiance over the window (midpoint
    quadrature on the window plane, cos_p cos_w / d^2 dA)."""
    room = Room(dome_desc([portal_frame(WIN_C, WIN_W, WIN_H)], texture_file=sky_exr, intensity=1.0))
    dome = room.lights.kinds[room.lights.kind_of[0]]
    k = 800
    gx = (np.arange(k) + 0.5) / k - 0.5
    X, Y = np.meshgrid(gx * WIN_W, gx * WIN_H, indexing="ij")
    pts = np.stack([WIN_C[0] + X.ravel(), WIN_C[1] + Y.ravel(), np.full(X.size, WIN_C[2])], axis=1)
    v = pts - room.p
    d2 = np.einsum("ij,ij->i", v, v)
    w = v / np.sqrt(d2)[:, None]
    Le = dome.le_escaped(np.zeros(w.shape[0], dtype=np.int64), w)[:, 0]
    ref = room.rho / np.pi * float((Le * w[:, 2] * w[:, 2] / d2).sum() * (WIN_W * WIN_H) / (k * k))
    est = room.estimate("mis", seed=7)
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)


# ----------------------------------------------------------------------------------------
# The windowed luminance table (lights/portal.py)
# ----------------------------------------------------------------------------------------
def _tables(seed=0):
    from renderer.lights import portal as P

    rng = np.random.default_rng(seed)
    f = rng.random((2, P.N_CELLS, P.N_CELLS)) + 40.0 * (np.arange(P.N_CELLS) == 20)[None, :, None]
    sat, col = (np.array(x) for x in zip(*(P.prefix_tables(x) for x in f)))
    return P, f, sat, col


def test_window_kernels_match_the_numpy_statement():
    P, f, sat, col = _tables()
    rng = np.random.default_rng(1)
    n = 5000
    t = rng.integers(0, 2, n)
    a = np.sort(rng.uniform(-1.5, 1.5, (n, 2)), axis=1)
    b = np.sort(rng.uniform(-1.5, 1.5, (n, 2)), axis=1)
    u = rng.random((n, 2))
    args = (t, a[:, 0], a[:, 1], b[:, 0], b[:, 1])
    np.testing.assert_allclose(P.window_integral(sat, *args), P.window_integral_reference(sat, *args), rtol=1e-12)
    k = P.sample_window(sat, col, *args, u)
    r = P.sample_window_reference(sat, col, *args, u)
    np.testing.assert_allclose(k[0], r[0], atol=1e-9)
    np.testing.assert_allclose(k[1], r[1], atol=1e-9)


def test_windowed_sampling_follows_the_table():
    """Chi-square in (alpha, beta) of samples restricted to one window against f / W."""
    from tests.stats import chi2_sf

    P, f, sat, col = _tables(2)
    n = 200_000
    a0, a1, b0, b1 = -0.45, 0.3, -0.2, 0.7
    t = np.zeros(n, dtype=np.int64)
    alpha, beta = P.sample_window(sat, col, t, np.full(n, a0), np.full(n, a1), np.full(n, b0), np.full(n, b1),
                                  np.random.default_rng(3).random((n, 2)))
    assert alpha.min() >= a0 and alpha.max() <= a1 and beta.min() >= b0 and beta.max() <= b1
    bins = 12
    obs, ea, eb = np.histogram2d(alpha, beta, bins=bins, range=[[a0, a1], [b0, b1]])
    W = P.window_integral(sat, t[:1], np.array([a0]), np.array([a1]), np.array([b0]), np.array([b1]))[0]
    exp = np.array([[P.window_integral(sat, t[:1], ea[i:i + 1], ea[i + 1:i + 2], eb[j:j + 1], eb[j + 1:j + 2])[0]
                     for j in range(bins)] for i in range(bins)]) / W * n
    chi2 = float(((obs - exp) ** 2 / exp).sum())
    assert chi2_sf(chi2, bins * bins - 1) > SIGNIFICANCE, chi2
