"""ShapingAPI: the emission factor against the UsdLux doc's equations (re-derived here), the
shaped power, sampling (chi-square, pdf consistency), unbiasedness and the light BVH bounds."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from renderer.description import LightDesc, ShapingDesc
from renderer.light_samplers.bvh import BVHLightSampler, light_bounds
from renderer.lights.base import ShadingContext
from renderer.lights.ies import load_ies
from renderer.lights.light_set import LightSet
from tests.lights.helpers import ctx, look_down, rotate, scale, translate
from tests.stats import SIGNIFICANCE, chi2_directions, z_test

IES_DIR = os.path.join(os.path.dirname(__file__), "..", "..", "stages", "ies")


# ------------------------------------------------------------------ the doc's equations
def doc_smoothstep(x, e0, e1):
    if e1 == e0:
        return np.where(x <= e0, 0.0, 1.0)
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return 3 * t**2 - 2 * t**3


def doc_theta_ies(theta, s):
    if s > 0:
        out = theta / s
    elif s == 0:
        out = theta
    else:
        out = (theta - math.pi) / -s + math.pi
    return np.clip(out, 0.0, math.pi)


def doc_factor(e_local, sh: ShapingDesc, profile=None):
    """(n, 3) multiplier of L_Color for unit emission directions in light space (axis -Z)."""
    axis = np.array([0.0, 0.0, -1.0])
    cos = e_local @ axis
    theta_off = np.arccos(np.clip(cos, -1.0, 1.0))
    out = np.ones((e_local.shape[0], 3))
    if sh.focus > 0:  # "Values < 0 are ignored"
        ff = np.abs(cos) ** sh.focus
        out *= np.asarray(sh.focus_tint)[None, :] + ff[:, None] * (1.0 - np.asarray(sh.focus_tint))[None, :]
    cut = math.radians(sh.cone_angle)
    start = cut + sh.cone_softness * (0.0 - cut)  # lerp(softness, cut, 0)
    out *= (1.0 - doc_smoothstep(theta_off, start, cut))[:, None]   # 1 - smoothStep(θoff, θsmoothStart, θcutoff)
    if profile is not None:
        phi = np.arctan2(-e_local[:, 1], -e_local[:, 0])   # hdEmbree: phi of the direction to the light
        val = profile.eval(doc_theta_ies(theta_off, sh.ies_angle_scale), phi)
        if sh.ies_normalize:
            val = val / profile.power()
        out *= val[:, None]
    return out


def random_dirs(n, seed, hemisphere_axis=None):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if hemisphere_axis is not None:
        v *= np.sign(v @ np.asarray(hemisphere_axis))[:, None]
    return v


def one(desc) -> LightSet:
    return LightSet.build([desc], (0.0, 0.0, 0.0), 10.0)


PROFILE = os.path.join(IES_DIR, "wallwash.ies")
CONFIGS = {
    "disk_cone_soft": ("disk", ShapingDesc(cone_angle=40.0, cone_softness=0.5)),
    "disk_cone_hard": ("disk", ShapingDesc(cone_angle=25.0)),
    "disk_focus_tint": ("disk", ShapingDesc(focus=3.5, focus_tint=(0.6, 0.2, 0.0))),
    "sphere_everything": ("sphere", ShapingDesc(focus=2.0, focus_tint=(0.1, 0.3, 0.5), cone_angle=120.0,
                                                cone_softness=0.7, ies_file=PROFILE, ies_angle_scale=0.8,
                                                ies_normalize=True)),
    "sphere_fallback_cone": ("sphere", ShapingDesc(focus=1.0)),   # cone 90: the +Z half is dark
    "disk_ies_negative_scale": ("disk", ShapingDesc(ies_file=PROFILE, ies_angle_scale=-0.6)),
    "point_ies_big_scale": ("point", ShapingDesc(ies_file=PROFILE, ies_angle_scale=1.7, ies_normalize=True)),
}
M = translate(0.3, -0.2, 1.0) @ rotate((1.0, 2.0, 0.5), 37.0)


def make(kind, sh, m=M, **kw):
    if kind == "point":
        return LightDesc("/L", "sphere", m, radius=0.2, treat_as_point=True, intensity=3.0, shaping=sh, **kw)
    return LightDesc("/L", kind, m, radius=0.25, intensity=3.0, color=(1.0, 0.5, 0.25), shaping=sh, **kw)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_emission_factor_matches_the_doc(name):
    kind, sh = CONFIGS[name]
    desc = make(kind, sh)
    shaped = one(desc)
    plain = one(make(kind, None))
    R = M[:3, :3]
    n = 2000
    # Emission directions in light space (the front hemisphere for disks), mapped to world.
    e_local = random_dirs(n, 11, hemisphere_axis=(0, 0, -1) if kind == "disk" else None)
    e_world = e_local @ R.T
    c = M[:3, 3]
    light = np.zeros(n, dtype=np.int64)
    if kind == "point":
        # Point lights are sampled only: the sample toward a receiver along e carries the factor.
        p = c + 2.0 * e_world
        zero = np.zeros((n, 3))
        got = shaped.sample_li(light, ShadingContext(p, zero, zero), np.zeros((n, 2))).L
        base = plain.sample_li(light, ShadingContext(p, zero, zero), np.zeros((n, 2))).L
    else:
        p_light = c + (0.25 * e_world if kind == "sphere" else 0.0)
        wi = -e_world
        got = shaped.le(light, np.broadcast_to(p_light, (n, 3)).copy(), wi)
        base = plain.le(light, np.broadcast_to(p_light, (n, 3)).copy(), wi)
    profile = load_ies(sh.ies_file) if sh.ies_file else None
    expect = base * doc_factor(e_local, sh, profile)
    np.testing.assert_allclose(got, expect, rtol=1e-9, atol=1e-12)
    if name == "sphere_fallback_cone":
        assert np.all(got[e_local[:, 2] > 1e-9] == 0.0)   # the doc's fallback cone: 90 degrees
    assert np.any(got > 0.0)


def test_sample_li_carries_the_same_factor_as_le():
    desc = make("disk", CONFIGS["disk_cone_soft"][1])
    ls = one(desc)
    n = 4000
    rng = np.random.default_rng(3)
    p = M[:3, 3] + (rng.normal(size=(n, 3)) * 1.5) @ M[:3, :3].T + 2.0 * (M[:3, :3] @ [0, 0, -1])
    s = ls.sample_li(np.zeros(n, np.int64), ShadingContext(p, np.zeros((n, 3)), np.zeros((n, 3))), rng.random((n, 2)))
    ok = s.pdf > 0
    assert ok.sum() > n // 2
    np.testing.assert_allclose(s.L[ok], ls.le(np.zeros(ok.sum(), np.int64), s.p_light[ok], s.wi[ok]), rtol=1e-12)
    # Outside the 40 degree cone nothing arrives, so no shadow ray would be traced there.
    e = -s.wi[ok] @ M[:3, :3]
    off = np.degrees(np.arccos(np.clip(-e[:, 2], -1, 1)))
    assert np.all(s.L[ok][off > 40.0 + 1e-9] == 0.0)
    assert np.any(s.L[ok][off < 20.0] > 0.0)


def test_focus_below_zero_and_white_tint_change_nothing():
    for sh in (ShapingDesc(focus=-2.0), ShapingDesc(focus=5.0, focus_tint=(1.0, 1.0, 1.0))):
        ls = one(make("disk", sh))
        assert ls.shaping is None and not ls.shaped.any() and ls.has_exact_integral.all()


def test_non_uniform_scale_measures_angles_in_light_space():
    m = translate(0, 0, 2) @ rotate((0, 1, 0), 20) @ scale(3.0, 1.0, 0.5)
    sh = ShapingDesc(cone_angle=30.0, cone_softness=1.0)
    ls, plain = one(make("disk", sh, m)), one(make("disk", None, m))
    e_local = random_dirs(500, 5, hemisphere_axis=(0, 0, -1))
    e_world = e_local @ m[:3, :3].T
    e_world /= np.linalg.norm(e_world, axis=1, keepdims=True)
    # Back to light space with M^-1 (hdEmbree's xformWorldToLight), renormalised.
    back = e_world @ np.linalg.inv(m[:3, :3]).T
    back /= np.linalg.norm(back, axis=1, keepdims=True)
    p_light = np.broadcast_to(m[:3, 3], (500, 3)).copy()
    got = ls.le(np.zeros(500, np.int64), p_light, -e_world)
    base = plain.le(np.zeros(500, np.int64), p_light, -e_world)
    np.testing.assert_allclose(got, base * doc_factor(back, sh), rtol=1e-9, atol=1e-12)
    assert not ls.shaping.similarity[0]   # the light BVH keeps the unshaped cone bounds


# ------------------------------------------------------------------ power
@pytest.mark.parametrize("kind, sh, ratio", [
    ("disk", ShapingDesc(cone_angle=30.0), math.sin(math.radians(30.0)) ** 2),
    ("sphere", ShapingDesc(cone_angle=50.0), (1.0 - math.cos(math.radians(50.0))) / 2.0),
    ("point", ShapingDesc(cone_angle=180.0, focus=3.0), 1.0 / 4.0),        # (1/4pi) ∫ |cos|^3 = 1/(f+1)
    ("disk", ShapingDesc(focus=4.0), 2.0 / 6.0),                           # (1/pi) ∫ cos^4 cos = 2/(f+2)
])
def test_shaped_power_is_the_integral_of_the_factor(kind, sh, ratio):
    ls = one(make(kind, sh))
    plain = one(make(kind, None))
    assert ls.phi()[0] == pytest.approx(plain.phi()[0] * ratio, rel=1e-9)


def test_normalized_isotropic_ies_keeps_the_power(tmp_path):
    f = tmp_path / "iso.ies"
    f.write_text("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 0\n0 90 180\n0\n250 250 250\n")
    ls = one(make("point", ShapingDesc(cone_angle=180.0, ies_file=str(f), ies_normalize=True)))
    plain = one(make("point", None))
    assert ls.phi()[0] == pytest.approx(plain.phi()[0], rel=1e-12)


# ------------------------------------------------------------------ sampling
def _dispatch_sampler(ls, p):
    def sample(u):
        n = u.shape[0]
        s = ls.sample_li(np.zeros(n, np.int64), ctx(p, count=n), u)
        return s.wi, s.pdf > 0.0

    def pdf(wi):
        n = wi.shape[0]
        return ls.pdf_li(np.zeros(n, np.int64), ctx(p, count=n), wi)

    return sample, pdf


@pytest.mark.parametrize("kind", ["disk", "sphere"])
def test_chi2_sample_matches_pdf_for_shaped_lights(kind):
    sh = ShapingDesc(cone_angle=35.0, cone_softness=0.3, focus=2.0)
    ls = one(make(kind, sh, translate(0, 0, 1.5)))  # local -Z points down at p
    p = (0.4, 0.1, 0.0)
    axis = np.array([0.0, 0.0, 1.0])
    sample, pdf = _dispatch_sampler(ls, p)
    w_c = (np.array([0, 0, 1.5]) - p) / np.linalg.norm(np.array([0, 0, 1.5]) - p)
    pval, details = chi2_directions(sample, pdf, axis=w_c, cos_range=(0.96, 1.0), n_samples=100_000, seed=4,
                                    integration_res=16)
    assert pval > SIGNIFICANCE, details["chi2"]
    assert details["observed"].sum() > 50_000   # the light is in front: most samples are valid
    # pdf(sample) is the sample's pdf.
    n = 2000
    s = ls.sample_li(np.zeros(n, np.int64), ctx(p, count=n), np.random.default_rng(8).random((n, 2)))
    ok = s.pdf > 0
    np.testing.assert_allclose(ls.pdf_li(np.zeros(ok.sum(), np.int64), ctx(p, count=ok.sum()), s.wi[ok]), s.pdf[ok],
                               rtol=1e-9)
    # Inside the cone (p is 15 degrees off the axis) the shaped radiance is there.
    assert np.any(s.L[ok] > 0.0) and axis is not None


def _disk_irradiance_quadrature(desc: LightDesc, sh: ShapingDesc, p, n_normal, n_rho=1500, n_alpha=1000):
    """∫ L f(e) cos_p cos_l / d^2 dA over the disk (midpoint rule in rho and alpha; f is C1)."""
    m = np.asarray(desc.light_to_world)
    R, c, r = m[:3, :3], m[:3, 3], desc.radius
    rho = (np.arange(n_rho) + 0.5) / n_rho
    alpha = (np.arange(n_alpha) + 0.5) / n_alpha * 2 * math.pi
    Rho, A = np.meshgrid(rho, alpha, indexing="ij")
    local = np.stack([r * Rho * np.cos(A), r * Rho * np.sin(A), np.zeros_like(Rho)], -1).reshape(-1, 3)
    x = c + local @ R.T
    v = np.asarray(p) - x
    d2 = np.einsum("ij,ij->i", v, v)
    e = v / np.sqrt(d2)[:, None]
    normal = R @ [0.0, 0.0, -1.0]
    cos_l = np.maximum(0.0, e @ normal)
    cos_p = np.maximum(0.0, -(e @ np.asarray(n_normal)))
    f = doc_factor(e @ R, sh)[:, 0]
    dA = r * r * Rho.ravel() * (1.0 / n_rho) * (2 * math.pi / n_alpha)
    return float(desc.intensity * (f * cos_l * cos_p / d2 * dA).sum())


def test_unbiased_irradiance_of_a_disk_spot():
    """MC mean of L cos / pdf through LightSet.sample_li against a quadrature of the shaped
    emission: the receiver sits near the cone's soft edge, where part of the disk is cut."""
    sh = ShapingDesc(cone_angle=30.0, cone_softness=0.6, focus=1.5, focus_tint=(0.0, 0.0, 0.0))
    desc = LightDesc("/L", "disk", translate(0, 0, 1.2), radius=0.4, intensity=2.0,
                     shaping=sh)
    ls = one(desc)
    p, n_normal = (0.55, 0.1, 0.0), (0.0, 0.0, 1.0)
    ref = _disk_irradiance_quadrature(desc, sh, p, n_normal)
    n = 300_000
    rng = np.random.default_rng(17)
    s = ls.sample_li(np.zeros(n, np.int64), ctx(p, n_normal, count=n), rng.random((n, 2)))
    cos = np.maximum(0.0, s.wi @ np.asarray(n_normal))
    ok = s.pdf > 0
    est = np.where(ok, s.L[:, 0] * cos / np.where(ok, s.pdf, 1.0), 0.0)
    assert 0.0 < ref
    assert z_test(est, ref) > SIGNIFICANCE, (est.mean(), ref)
    # And the shaping matters here: the unshaped disk gives clearly more.
    plain = one(LightDesc("/L", "disk", desc.light_to_world, radius=0.4, intensity=2.0))
    s0 = plain.sample_li(np.zeros(n, np.int64), ctx(p, n_normal, count=n), rng.random((n, 2)))
    e0 = np.where(s0.pdf > 0, s0.L[:, 0] * np.maximum(0.0, s0.wi @ n_normal) / np.where(s0.pdf > 0, s0.pdf, 1.0), 0)
    assert e0.mean() > 1.3 * ref


# ------------------------------------------------------------------ exactness and the light BVH
def test_shaped_lights_have_no_exact_integral_and_cost_nothing_when_identity():
    descs = [make("disk", ShapingDesc(cone_angle=30.0)),
             make("disk", ShapingDesc(cone_angle=90.0)),          # identity for a one-sided light
             LightDesc("/R", "rect", translate(2, 0, 1), width=1.0, height=1.0, shaping=ShapingDesc()),
             make("sphere", ShapingDesc(cone_angle=180.0))]       # identity for a sphere
    descs = [LightDesc(f"/L{i}", d.kind, d.light_to_world, radius=d.radius, intensity=1.0, shaping=d.shaping)
             for i, d in enumerate(descs)]
    ls = LightSet.build(descs, (0, 0, 0), 10.0)
    assert ls.shaped.tolist() == [True, False, False, False]
    assert ls.has_exact_integral.tolist() == [False, True, True, True]
    assert ls.shaping.row_of.tolist() == [0, -1, -1, -1]
    c = ctx((0.0, 0.0, -2.0), (0.0, 0.0, 1.0), count=4)
    _, exact = ls.irradiance(np.arange(4), c)
    assert exact.tolist() == [False, True, True, True]
    assert "ShapingAPI" in ls.inexact_reason[0]


def test_shaping_on_distant_lights_is_ignored_with_a_warning():
    d = LightDesc("/Sun", "distant", rotate((1, 0, 0), -90.0), angle=1.0, shaping=ShapingDesc(cone_angle=10.0))
    ls = one(d)
    assert ls.shaping is None and any("ignored" in w for w in ls.warnings)


def _spots(shaping_aware: bool):
    descs = []
    for i, x in enumerate((-4.0, 0.0, 4.0)):
        descs.append(LightDesc(f"/S{i}", "sphere", translate(x, 3.0, 0.0) @ look_down((0, -1, 0)), radius=0.05,
                               treat_as_point=True,
                               intensity=100.0, shaping=ShapingDesc(cone_angle=20.0, cone_softness=0.5)))
        descs.append(LightDesc(f"/D{i}", "disk", translate(x, 3.0, 2.0) @ look_down((0, -1, 0)), radius=0.1,
                               intensity=50.0, shaping=ShapingDesc(cone_angle=15.0)))
    ls = LightSet.build(descs, (0, 0, 0), 10.0)
    ls.shaping_aware = shaping_aware
    return ls


def test_bvh_bounds_follow_the_cones_without_losing_any_light():
    ls = _spots(True)
    b = light_bounds(ls)
    order = np.argsort(b.light)
    total = b.theta_o[order] + b.theta_e[order]
    np.testing.assert_allclose(total, math.radians(20.0) * np.array([1, 0, 1, 0, 1, 0]) +
                               math.radians(15.0) * np.array([0, 1, 0, 1, 0, 1]), rtol=1e-12)
    np.testing.assert_allclose(b.phi[order], ls.phi(), rtol=1e-12)
    sampler = BVHLightSampler(ls)
    loose = _spots(False)
    loose_sampler = BVHLightSampler(loose)
    rng = np.random.default_rng(5)
    m = 4000
    pts = np.c_[rng.uniform(-6, 6, m), np.zeros(m), rng.uniform(-2, 4, m)]
    nrm = np.tile([0.0, 1.0, 0.0], (m, 1))
    c = ShadingContext(pts, nrm, nrm)
    light_ids = np.repeat(np.arange(ls.count), m)
    big = ShadingContext(np.tile(pts, (ls.count, 1)), np.tile(nrm, (ls.count, 1)), np.tile(nrm, (ls.count, 1)))
    pmf = sampler.pmf(big, light_ids).reshape(ls.count, m)
    pmf_loose = loose_sampler.pmf(big, light_ids).reshape(ls.count, m)
    # Where a light reaches the point at all (some emission toward it), its pmf is positive: no bias.
    for i in range(ls.count):
        e = ls.sample_li(np.full(m, i), c, rng.random((m, 2)))
        reach = np.any(e.L > 0.0, axis=1)
        assert np.all(pmf[i][reach] > 0.0), ls.paths[i]
    # The cones let the BVH skip lights that cannot reach the point; without them it cannot.
    outside = pmf == 0.0
    assert outside.mean() > 0.5
    assert (pmf_loose == 0.0).mean() < 0.05
    # pbrt's traversal may end where both children have importance 0 ("no light"): sums <= 1.
    assert np.all(pmf.sum(axis=0) <= 1.0 + 1e-12)
