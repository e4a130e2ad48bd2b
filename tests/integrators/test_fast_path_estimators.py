"""The compiled path's per-light estimators (renderer/estimators/compiled.py, drawn by
_vertex_kernels._direct_pair) estimate what the general path's numpy estimators estimate.

Each talk stage (stages/talk) is rendered with one estimator forced on every light, by the fast
path and by the general path (``fast_path=False``) with independent seeds, and the image means
are z-tested over the whole image and in 16 blocks, each film's per-pixel variance of the mean
giving the error (test_fast_path._block_z). The biased estimators (averageVisibility, ratio) have
the same bias in both paths (same N, same formula: kernels/direct.diffuse_combine_row), so their
expectations agree too. Depth 3 with roulette from depth 1 covers the first-vertex rule (N =
illum:samples) and the deeper one (N = 1, the control variate on alpha = 1). The rect-lit room of
test_fast_path with a sphere, a point (delta), an elliptical disk (no exact F: MIS fallback), a
sky, a sun and a delta distant light covers the other light kinds. A 5 % error in the
control variate's diffuse combination must fail the same comparison.
"""

import inspect

import numpy as np
import pytest
from numba import njit
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

import renderer.integrators._vertex_kernels as vk
from renderer.integrators import fast_path as fp_mod
from renderer.lights.base import ShadingContext
from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_BLOCK, Z_MAX, _block_z, _room

CASES = [
    ("penumbra", "controlVariate", "averageVisibilityUnbiased", 4),
    ("penumbra", "ratio", "one", 4),
    ("penumbra", "mis", "one", 4),
    ("disks", "controlVariate", "averageVisibility", 4),
    ("dome", "controlVariate", "averageVisibilityUnbiased", 4),
    ("dome", "ratio", "one", 2),
    ("furnace", "controlVariate", "averageVisibility", 4),
    ("sphere_occluder", "lightSampling", "one", 2),
    ("sphere_occluder", "bsdfSampling", "one", 1),
    ("large_rect", "controlVariate", "one", 3),
]


def _pair(stage, estimator, alpha, N, seeds=(1, 8), spp=96, res=(40, 30)):
    common = dict(max_depth=3, rr_depth=1, threads=1, estimator={"": estimator}, cv_alpha={"": alpha},
                  light_samples={"": N}, spp=spp, resolution=res, pixel_filter_mode="importance")
    fast = render(str(stage), RenderOptions(seed=seeds[0], **common))
    slow = render(str(stage), RenderOptions(seed=seeds[1], fast_path=False, **common))
    assert fast.stats["fast_path"] == "on"
    assert slow.stats["fast_path"].startswith("disabled")
    return fast, slow


def _check(fast, slow):
    z, zs = _block_z(fast, slow)
    assert abs(z) < Z_MAX, f"whole image: fast - general = {z:.2f} sigma"
    assert max(abs(x) for x in zs) < Z_BLOCK, f"blocks: {np.round(zs, 2)}"
    assert fast.film.nonfinite_dropped == 0 and fast.film.mean().sum() > 0.0
    # The same rules apply (own samples at the first vertex, alpha = 1 deeper, continuation MIS).
    for k in ("own_samples", "alpha_one_fallback", "continuation_mis"):
        assert (fast.stats["direct_rule"][k] > 0) == (slow.stats["direct_rule"][k] > 0), k


@pytest.mark.parametrize("name,estimator,alpha,N", CASES)
def test_talk_stage_estimator_matches_the_general_path(name, estimator, alpha, N):
    fast, slow = _pair(f"stages/talk/{name}.usda", estimator, alpha, N)
    _check(fast, slow)
    # Continuation MIS only for mis lights at deeper vertices (N = 1 there).
    assert (fast.stats["direct_rule"]["continuation_mis"] > 0) == (estimator == "mis")


def test_balance_heuristic_mis_with_samples_matches_the_general_path(tmp_path):
    stage = Usd.Stage.Open("stages/talk/sphere_occluder.usda")
    stage.GetPrimAtPath("/World/Lights/Key").CreateAttribute(
        "illum:mis:heuristic", Sdf.ValueTypeNames.Token, variability=Sdf.VariabilityUniform).Set("balance")
    path = tmp_path / "balance.usda"
    stage.Export(str(path))
    _check(*_pair(path, "mis", "one", 3))


@pytest.mark.parametrize("kw,estimator,alpha,N", [
    ({"more_kinds": True}, "controlVariate", "averageVisibilityUnbiased", 3),
    ({"more_kinds": True}, "mis", "one", 2),
    ({"infinite": True, "sky_texture": True}, "controlVariate", "averageVisibilityUnbiased", 3),
    ({"infinite": True, "sky_texture": True}, "lightSampling", "one", 2),
    ({"infinite": True}, "ratio", "one", 2),
])
def test_every_light_kind_matches_the_general_path(tmp_path, kw, estimator, alpha, N):
    stage = tmp_path / "room.usda"
    _room(stage, **kw)
    _check(*_pair(stage, estimator, alpha, N, spp=64, res=(48, 36)))


def test_auto_matches_the_general_path():
    # auto's pilot runs on the general path before either renders (same seed: the same picks).
    fast, slow = _pair("stages/talk/penumbra.usda", "auto", "one", 4, seeds=(3, 3))
    _check(fast, slow)


def test_the_comparison_detects_a_five_percent_error(monkeypatch):
    orig = vk.resolve_groups_kernel

    def scaled(L, g_int, g_f, *a):
        g_f = g_f.copy()
        g_f[:, 3:6] *= 1.05
        orig(L, g_int, g_f, *a)

    monkeypatch.setattr(vk, "resolve_groups_kernel", scaled)
    # The Python bounce loop calls the module's resolve_groups_kernel, so the error reaches the
    # image (the compiled loop gives the same image, test_fast_path_kernel, but binds the kernel).
    from renderer.integrators.fast_path import FastPath

    monkeypatch.setattr(FastPath, "kernel_reason", lambda self: "the test patches a kernel the Python loop calls")
    fast, slow = _pair("stages/talk/penumbra.usda", "controlVariate", "averageVisibilityUnbiased", 4)
    z, _ = _block_z(fast, slow)
    assert abs(z) > Z_MAX, f"a 5% error went unseen (z = {z:.2f})"


@pytest.mark.parametrize("sampler,estimator,alpha,N", [
    ("bvh", {"": "controlVariate"}, "averageVisibilityUnbiased", {"": 3}),
    # Mixed: the bulb on continuation MIS at every vertex, the disk from the second vertex on
    # (N = 2 at the first), the other lights on the ratio estimator.
    ("power", {"": "ratio", "/World/Bulb": "mis", "/World/Disk": "mis"}, "one", {"": 2, "/World/Bulb": 1}),
])
def test_picking_service_with_per_light_estimators(tmp_path, sampler, estimator, alpha, N):
    """A lighting service that picks one light per vertex together with estimators other than
    continuation MIS (path.py _direct: the picked light's estimator, divided by the pmf; MIS
    lights with N = 1 by continuation MIS with the pmf replayed on the extension ray)."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True, infinite=True)
    common = dict(max_depth=3, rr_depth=1, threads=1, estimator=estimator, cv_alpha={"": alpha}, light_samples=N,
                  spp=96, resolution=(48, 36), pixel_filter_mode="importance", light_sampler=sampler)
    fast = render(str(stage), RenderOptions(seed=2, **common))
    slow = render(str(stage), RenderOptions(seed=9, fast_path=False, **common))
    assert fast.stats["fast_path"] == "on" and fast.stats["light_sampler"] == sampler
    assert slow.stats["fast_path"].startswith("disabled") and slow.stats["light_sampler"] == sampler
    _check(fast, slow)
    assert (fast.stats["direct_rule"]["continuation_mis"] > 0) == ("/World/Bulb" in estimator)
    # One light per vertex: at most 2 N shadow rays there, where the exhaustive service traces
    # them for all nine lights.
    n_max = 2 * max(N.values())
    assert fast.stats["rays"]["shadow"] <= n_max * (fast.stats["rays"]["camera"] + fast.stats["rays"]["extension"])


@njit(cache=True)
def _kernel_F(LP, g, p, ns, fcalc, IMG, E):
    """E[i] = the kernel's F of light g[i] at p[i] about ns[i], as vertex_kernel takes it:
    _vertex_kernels._dome_table_F where _table_F, else _light_F."""
    _exact, theta, far_ratio, kappa_max, PK = fcalc
    tbuf = np.empty(PK[-1])
    for i in range(p.shape[0]):
        gi = g[i]
        pi = (p[i, 0], p[i, 1], p[i, 2])
        ni = (ns[i, 0], ns[i, 1], ns[i, 2])
        if vk._table_F(LP, gi):
            e = vk._dome_table_F(LP, gi, ni, IMG[0][int(LP[gi, vk.LP_J])], PK, tbuf)
        else:
            e = vk._light_F(LP, gi, pi, ni, theta[gi], far_ratio, kappa_max)
        E[i, 0], E[i, 1], E[i, 2] = e


def test_kernel_F_is_the_irradiance_of_the_numpy_api(tmp_path, monkeypatch):
    """The F the vertex kernel takes per (vertex, light) pair (_light_F or _dome_table_F, from FastPath's tables)
    is LightSet.irradiance's E, and its exact flag irradiance's exact, for every light kind the
    fast path serves, at random points and shading normals: rects (a sheared one), a sphere, a
    point, a circular and an elliptical disk, a rotated textured dome (its preconvolved table), a
    5-degree sun, a delta and a too-wide distant light."""
    stage_path = tmp_path / "room.usda"
    _room(stage_path, more_kinds=True, infinite=True, sky_texture=True)
    stage = Usd.Stage.Open(str(stage_path))
    disk = UsdLux.DiskLight.Define(stage, "/World/Round")
    disk.CreateRadiusAttr(0.4)
    disk.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(disk).AddTranslateOp().Set(Gf.Vec3d(-1.5, 2.5, -0.5))
    UsdGeom.Xformable(disk).AddRotateXOp().Set(-80.0)
    wide = UsdLux.DistantLight.Define(stage, "/World/Wide")
    wide.CreateAngleAttr(200.0)
    wide.CreateIntensityAttr(0.1)
    stage.GetRootLayer().Save()
    made = []
    init = fp_mod.FastPath.__init__

    def keep(self, integ):
        init(self, integ)
        made.append(self)

    monkeypatch.setattr(fp_mod.FastPath, "__init__", keep)
    r = render(str(stage_path), RenderOptions(spp=1, resolution=(8, 6), threads=1, estimator={"": "controlVariate"}))
    assert r.stats["fast_path"] == "on" and made
    fast = made[0]
    lights = fast.integ.lights
    names = [p for p in inspect.signature(vk.vertex_kernel.py_func).parameters]
    tab = dict(zip(names[names.index("vertices"):], fast.tables))
    LP = vk._light_table(*(tab[a] for a in inspect.signature(vk._light_table.py_func).parameters))
    IMG = (tab["i_rot"], *(tab[a] for a in names if a.startswith("im_")))
    order = np.concatenate([fast.rect_light, fast.sphere_light, fast.disk_light, fast.inf_light])
    assert sorted(order) == list(range(lights.count)) and lights.count == 11
    rng = np.random.default_rng(5)
    n = 400
    lo, hi = fast.geo[0].reshape(-1, 3).min(axis=0), fast.geo[0].reshape(-1, 3).max(axis=0)
    exact_seen = []
    for g, gl in enumerate(order):
        p = lo + (hi - lo) * rng.random((n, 3))
        ns = rng.normal(size=(n, 3))
        ns /= np.linalg.norm(ns, axis=1, keepdims=True)
        E = np.empty((n, 3))
        _kernel_F(LP, np.full(n, g, dtype=np.int64), p, ns, fast.fcalc, IMG, E)
        E_ref, exact = lights.irradiance(np.full(n, gl, dtype=np.int64), ShadingContext(p, ns, ns))
        assert np.all(exact == fast.fcalc[0][g]), lights.paths[gl] if hasattr(lights, "paths") else gl
        exact_seen.append(bool(fast.fcalc[0][g]))
        if exact.any():
            assert np.count_nonzero(E_ref[exact] > 0.0) > n // 10
            np.testing.assert_allclose(E[exact], E_ref[exact], rtol=1e-12, atol=1e-300)
    # Inexact: the point, the ellipse, the delta and the too-wide distant lights.
    assert exact_seen.count(False) == 4, exact_seen


@pytest.mark.parametrize("estimator,alpha,N", [
    ("mis", "one", 1),
    ("controlVariate", "averageVisibilityUnbiased", 3),
])
def test_diffuse_and_specular_multipliers_match_the_general_path(tmp_path, estimator, alpha, N):
    """UsdLux inputs:diffuse / inputs:specular on the compiled path: such a light leaves
    continuation MIS (path.py cont_ok) and its estimator scales the BSDF's lobes
    (_vertex_kernels._split_at, kernels.direct.split_kernel's rule; F by the diffuse one)."""
    stage_path = tmp_path / "room.usda"
    _room(stage_path, more_kinds=True)
    stage = Usd.Stage.Open(str(stage_path))
    for path, diffuse, specular in (("/World/Big", 0.4, 1.8), ("/World/Bulb", 1.5, 0.0), ("/World/Back", 0.0, 2.0)):
        light = UsdLux.LightAPI(stage.GetPrimAtPath(path))
        light.CreateDiffuseAttr(diffuse)
        light.CreateSpecularAttr(specular)
    stage.GetRootLayer().Save()
    fast, slow = _pair(stage_path, estimator, alpha, N, spp=64, res=(48, 36))
    _check(fast, slow)
    # Continuation MIS still serves the plain mis lights.
    assert (fast.stats["direct_rule"]["continuation_mis"] > 0) == (estimator == "mis")

