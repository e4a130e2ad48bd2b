"""UsdLux ShadowAPI end to end on tiny .usda stages: shadow:enable, shadow:color,
shadow:distance and falloff; plus the exact fractional visibility of one shadow ray."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.accel import Accel
from renderer.integrators.shadow_api import ShadowParams, shadow_params, visibility
from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material

RES = 40
OCC_CENTER = np.array([1.0, 2.0, 0.0])
OCC_RADIUS = 0.5


def _stage(path, shadow=None, hide=False, point=True):
    """A floor lit by one light 4 m up; a sphere 2 m up casts a shadow at x ~ 2 on the floor.
    shadow: dict of ShadowAPI inputs (enable, color, distance, falloff, gamma) or None."""
    stage = new_stage(path)
    cam = add_camera(stage, pos=(2.0, 6, 0), focal=50.0)
    UsdGeom.Xformable(cam).AddRotateXOp().Set(-90.0)
    add_settings(stage, res=(RES, RES))
    grey = preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5), roughness=1.0,
                            specular_workflow=True)
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-10, 0, -10), (10, 0, -10), (10, 0, 10), (-10, 0, 10)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    floor.CreateSubdivisionSchemeAttr("none")
    bind(floor.GetPrim(), grey)
    occ = UsdGeom.Sphere.Define(stage, "/World/Occluder")
    occ.CreateRadiusAttr(OCC_RADIUS)
    occ.AddTranslateOp().Set(Gf.Vec3d(*OCC_CENTER))
    bind(occ.GetPrim(), grey)
    if hide:
        occ.CreateVisibilityAttr("invisible")
    light = UsdLux.SphereLight.Define(stage, "/World/Key")
    light.CreateRadiusAttr(0.05 if point else 0.3)
    light.CreateTreatAsPointAttr(point)
    light.CreateIntensityAttr(4000.0 if point else 120.0)
    light.AddTranslateOp().Set(Gf.Vec3d(0, 4, 0))
    if shadow is not None:
        api = UsdLux.ShadowAPI.Apply(light.GetPrim())
        if "enable" in shadow:
            api.CreateShadowEnableAttr(shadow["enable"])
        if "color" in shadow:
            api.CreateShadowColorAttr(Gf.Vec3f(*shadow["color"]))
        if "distance" in shadow:
            api.CreateShadowDistanceAttr(shadow["distance"])
        if "falloff" in shadow:
            api.CreateShadowFalloffAttr(shadow["falloff"])
        if "gamma" in shadow:
            api.CreateShadowFalloffGammaAttr(shadow["gamma"])
    stage.GetRootLayer().Save()
    return str(path)


def _render(path, **kw):
    res = render(path, RenderOptions(spp=4, max_depth=1, seed=7, threads=1, **kw))
    return res.film.mean(), res


def _floor_mask(res) -> np.ndarray:
    """(H, W) True for pixels whose every filter sample sees the floor: the occluder's projected
    silhouette, dilated by the filter radius (1.5 px) plus a margin, is excluded."""
    cam = res.camera
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20000, 3))
    # (the camera is the traced one, re-centred by res.origin)
    pts = OCC_CENTER + OCC_RADIUS * d / np.linalg.norm(d, axis=1, keepdims=True) - res.origin
    pc = (cam.world_to_camera() @ np.c_[pts, np.ones(len(pts))].T).T
    wx0, wx1, wy0, wy1 = cam.window
    sx, sy = pc[:, 0] / -pc[:, 2], pc[:, 1] / -pc[:, 2]
    rx = (sx - wx0) / (wx1 - wx0) * cam.width
    ry = (wy1 - sy) / (wy1 - wy0) * cam.height
    mask = np.ones((cam.height, cam.width), dtype=bool)
    for x, y in zip(rx, ry):
        x0, x1 = int(np.floor(x - 2.5)), int(np.ceil(x + 2.5))
        y0, y1 = int(np.floor(y - 2.5)), int(np.ceil(y + 2.5))
        mask[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = False
    return mask


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("shadow_api")
    plain, res = _render(_stage(d / "plain.usda"))
    hidden, _ = _render(_stage(d / "hidden.usda", hide=True))
    mask = _floor_mask(res)
    shadowed = mask & (plain[..., 1] < 0.3 * hidden[..., 1])
    assert shadowed.sum() >= 10, "the occluder must cast a visible umbra on floor pixels"
    return d, plain, hidden, mask, shadowed


def test_enable_off_gives_the_unshadowed_image_exactly(base):
    d, plain, hidden, mask, shadowed = base
    off, res = _render(_stage(d / "off.usda", {"enable": False}))
    np.testing.assert_array_equal(off[mask], hidden[mask])
    assert res.stats["rays"]["shadow"] == 0   # no shadow ray is traced for that light
    # The occluder itself is still there and lit.
    assert np.any(off[~mask] != hidden[~mask])


def test_color_tints_the_shadowed_fraction(base):
    d, plain, hidden, mask, shadowed = base
    c = np.array([0.2, 0.5, 0.9])
    tint, res = _render(_stage(d / "tint.usda", {"color": tuple(c)}))
    # Each sample: f L (v + (1 - v) c) = plain + c (unshadowed - plain), channel by channel.
    np.testing.assert_allclose(tint[mask], plain[mask] + c * (hidden[mask] - plain[mask]), rtol=2e-6, atol=1e-9)  # the film accumulates in float32
    assert np.all(tint[shadowed][:, 2] > 0.8 * hidden[shadowed][:, 2])
    light = res.stats["lights"][0]
    assert light["exact_integral"] is False and "shadow:color" in light["no_exact_integral_because"]


def test_color_with_an_area_light_and_mis_on_the_general_path(base):
    """Sample by sample on the general path: there plain, hidden and tinted lights all take the
    two-sample MIS estimator, so the three renders draw the same numbers."""
    d, _, _, _, _ = base
    c = np.array([0.7, 0.1, 0.3])
    kw = dict(estimator={"": "mis"}, fast_path=False)
    plain, res = _render(_stage(d / "a_plain.usda", point=False), **kw)
    hidden, _ = _render(_stage(d / "a_hidden.usda", point=False, hide=True), **kw)
    tint, _ = _render(_stage(d / "a_tint.usda", {"color": tuple(c)}, point=False), **kw)
    mask = _floor_mask(res)
    np.testing.assert_allclose(tint[mask], plain[mask] + c * (hidden[mask] - plain[mask]), rtol=2e-6, atol=1e-9)


def test_color_with_an_area_light_and_mis_compiled(base):
    """The compiled route in expectation. A tinted light cannot take continuation MIS (its BSDF
    ray must find the light behind the occluder), while the plain one does: the renders draw
    different numbers, so the identity holds for the means. 16 seeds: the floor mean of
    tint - (plain + c (hidden - plain)) per seed, a t-test per channel (15 dof; |t| < 5 has
    p < 2e-4). Black shadows (the colour ignored) shift that mean by ~10 standard errors."""
    d, _, _, _, _ = base
    c = np.array([0.7, 0.1, 0.3])
    paths = (_stage(d / "c_plain.usda", point=False), _stage(d / "c_hidden.usda", point=False, hide=True),
             _stage(d / "c_tint.usda", {"color": tuple(c)}, point=False))
    diffs, gaps = [], []
    for seed in range(16):
        opts = RenderOptions(spp=4, max_depth=1, seed=100 + seed, threads=1, estimator={"": "mis"})
        runs = [render(p, opts) for p in paths]
        assert all(r.stats["fast_path"] == "on" for r in runs)
        plain, hidden, tint = (r.film.mean() for r in runs)
        mask = _floor_mask(runs[0])
        diffs.append((tint[mask] - plain[mask] - c * (hidden[mask] - plain[mask])).mean(axis=0))
        gaps.append((c * (hidden[mask] - plain[mask])).mean(axis=0))
    diffs = np.array(diffs)
    se = diffs.std(axis=0, ddof=1) / np.sqrt(len(diffs))
    t = diffs.mean(axis=0) / se
    assert np.all(np.abs(t) < 5.0), (t, diffs.mean(axis=0), se)
    # The test has power: the colour's share of the image is far above the noise.
    assert np.all(np.mean(gaps, axis=0) > 8 * se), (np.mean(gaps, axis=0), se)


def test_distance_limits_which_occluders_cast_shadow(base):
    d, plain, hidden, mask, shadowed = base
    # The occluder is >= 1.5 m from the floor under it: a 1 m limit removes its shadow ...
    near, _ = _render(_stage(d / "near.usda", {"distance": 1.0}))
    np.testing.assert_array_equal(near[mask], hidden[mask])
    # ... and a 3.5 m limit (past the occluder, short of the 4 m light) keeps it all.
    far, _ = _render(_stage(d / "far.usda", {"distance": 3.5}))
    np.testing.assert_array_equal(far[mask], plain[mask])


def test_falloff_fades_the_shadow(base):
    d, plain, hidden, mask, shadowed = base
    # Occluder 1.5 .. 2.5 m from the umbra: zone [1.5, 2.5] with gamma 1 gives a partial shadow.
    fade, _ = _render(_stage(d / "fade.usda", {"distance": 2.5, "falloff": 1.0, "gamma": 1.0}))
    soft, _ = _render(_stage(d / "soft.usda", {"distance": 2.5, "falloff": 1.0, "gamma": 3.0}))
    g = shadowed
    assert np.all(fade[g] >= plain[g]) and np.all(fade[g] <= hidden[g] * (1 + 1e-12))
    frac = 1.0 - (fade[g][:, 1] - plain[g][:, 1]) / (hidden[g][:, 1] - plain[g][:, 1])  # shadow strength
    assert 0.1 < frac.mean() < 0.9
    frac3 = 1.0 - (soft[g][:, 1] - plain[g][:, 1]) / (hidden[g][:, 1] - plain[g][:, 1])
    assert frac3.mean() < frac.mean()   # a larger gamma fades faster (x^3 < x for x in (0, 1))


# ------------------------------------------------------------------ one shadow ray, exactly
def test_fractional_visibility_of_single_rays():
    # An occluding triangle at z = 2 above rays shot straight up from z = 0.
    tri = np.array([[[-5.0, -5.0, 2.0], [5.0, -5.0, 2.0], [0.0, 5.0, 2.0]]])
    accel = Accel(tri, threads=1)
    o = np.zeros((1, 3))
    up = np.array([[0.0, 0.0, 1.0]])
    t_max = np.array([10.0])
    for d, f, g, expect in [
        (np.inf, 0.0, 1.0, 0.0),          # plain: blocked
        (1.5, 0.0, 1.0, 1.0),             # beyond the distance limit: unshadowed
        (2.5, 0.0, 1.0, 0.0),             # inside it: full shadow
        (2.5, 1.0, 1.0, 1.0 - 0.5),       # zone [1.5, 2.5]: strength (2.5 - 2)/1
        (2.5, 1.0, 2.0, 1.0 - 0.25),      # gamma 2
        (3.5, 1.0, 2.0, 0.0),             # zone [2.5, 3.5]: the occluder is nearer, full shadow
    ]:
        v, rays = visibility(accel, o, up, t_max, ShadowParams(True, d, f, g))
        assert v[0] == pytest.approx(expect, abs=1e-6), (d, f, g)
        assert rays == 1
    v, rays = visibility(accel, o, up, t_max, ShadowParams(enable=False))
    assert v[0] == 1.0 and rays == 0
    accel.close()


def test_shadow_params_of_descs():
    from renderer.description import ShadowDesc

    assert shadow_params(None) is None
    assert shadow_params(ShadowDesc(color=(1.0, 0.0, 0.0))) is None        # colour alone: plain rays
    assert shadow_params(ShadowDesc(enable=False)) == ShadowParams(enable=False)
    assert shadow_params(ShadowDesc(distance=2.0, falloff=5.0)) == ShadowParams(True, 2.0, 2.0, 1.0)
