"""Skip proofs for rays (issue #8 item 3), by counting.

* max depth 1: no extension ray is traced. The stats JSON's ray counter says 0 and ``skipped``
  lists it (tests/integrators/test_path.py::test_max_depth_one_traces_no_extension_rays proves
  that much); here the BVH's own counter (Accel.rays_traced, counted inside accel.py) confirms
  that the only closest-hit queries were the camera rays.
* Where F = 0 (the light is below the horizon, or the point is behind a one-sided light), no
  shadow ray is traced: by every estimator, for every light kind, counted through the ``trace``
  callback (as tests/estimators/test_estimators.py::test_no_shadow_rays_when_the_light_is_below_the_horizon
  does for a rect with three estimators), and at render level on a stage whose lights face
  away from everything: ``stats["rays"]["shadow"] == 0`` and the BVH's occlusion counter is 0.
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.stage_builders import quad_light_stage
from tests.stress.cases import LightCase
from tests.stress.estimator_cases import ALL, rig_for


def _render_keep_scene(path, **opt):
    cache: dict = {}
    kw = dict(spp=2, threads=1)
    kw.update(opt)
    r = render(str(path), RenderOptions(**kw), scene_cache=cache)
    (desc, scene), = cache.values()
    return r, scene


@pytest.mark.parametrize("estimator", ["mis", "controlVariate", "bsdfSampling"])
def test_max_depth_one_intersects_only_camera_rays(tmp_path, estimator):
    path = tmp_path / "q.usda"
    quad_light_stage(path, res=(12, 12))
    r, scene = _render_keep_scene(path, max_depth=1, estimator={"": estimator}, light_samples={"": 2})
    try:
        assert r.stats["rays"]["extension"] == 0
        assert scene.accel.rays_traced["intersect"] == r.stats["rays"]["camera"] == 2 * 12 * 12
        assert scene.accel.rays_traced["occluded"] == r.stats["rays"]["shadow"] > 0
        assert any("no extension rays" in s for s in r.stats["skipped"])
    finally:
        scene.close()


def test_control_depth_two_does_trace_extension_rays(tmp_path):
    path = tmp_path / "q.usda"
    quad_light_stage(path, res=(12, 12))
    r, scene = _render_keep_scene(path, max_depth=2)
    try:
        assert r.stats["rays"]["extension"] > 0
        assert scene.accel.rays_traced["intersect"] == r.stats["rays"]["camera"] + r.stats["rays"]["extension"]
        assert not any("no extension rays" in s for s in r.stats["skipped"])
    finally:
        scene.close()


# --------------------------------------------------------------------------------------
# F = 0: no shadow rays
# --------------------------------------------------------------------------------------
def _case(kind, placement, normal, nrm=(0.0, 0.0, 1.0)):
    """A unit light at the origin (rect/disk emit along -Z), the point 2 units away."""
    return LightCase(kind=kind, size=0.5, aspect=1.0, quat=(1, 0, 0, 0), offset=(0, 0, 0), placement=placement,
                     dist=2.0, where=(0.5, 0.5, 0.5), direction=(0, 0, -1), normal=normal, tilt=0.0, nrm=nrm)


ZERO_F = [
    # below the horizon: the point is in front of the light but its normal faces away
    ("rect", "free", "random", (0.0, 0.0, -1.0)),
    ("disk", "free", "random", (0.0, 0.0, -1.0)),
    ("sphere", "free", "random", (0.0, 0.0, -1.0)),
    # behind a one-sided light, facing it
    ("rect", "behind", "facing", (0.0, 0.0, 1.0)),
    ("disk", "behind", "facing", (0.0, 0.0, 1.0)),
    # inside a sphere light (it emits outward only)
    ("sphere", "inside", "random", (0.3, 0.2, 1.0)),
]


@pytest.mark.parametrize("bsdf", ["lambert", "preview"])
@pytest.mark.parametrize("kind,placement,normal,nrm", ZERO_F)
def test_no_shadow_rays_where_F_is_zero(kind, placement, normal, nrm, bsdf):
    case = _case(kind, placement, normal, nrm)
    rig = rig_for(case, 500, bsdf=bsdf)
    E, _ = rig.lights.irradiance(np.zeros(1, dtype=np.int64),
                                 rig.query().ctx.take(np.array([0])))
    assert np.all(E == 0.0), "the setup must have F = 0"
    for token, alpha, heuristic, n_min in ALL:
        for N in sorted({n_min, 4}):
            Ld, reported, traced = rig.estimate(token, N, alpha, heuristic, seed=N)
            assert np.all(Ld == 0.0), f"{token}/{alpha}: non-zero light where F = 0"
            assert traced == 0 and reported == 0, f"{token}/{alpha}/N={N} traced {traced} shadow rays"


def test_control_shadow_rays_are_traced_where_F_is_positive():
    case = _case("rect", "free", "facing")
    rig = rig_for(case, 100)
    Ld, reported, traced = rig.estimate("mis", 2, "one", "power", seed=1)
    assert np.all(Ld > 0.0) and traced == reported > 0


def test_render_with_lights_facing_away_traces_no_shadow_rays(tmp_path):
    """A floor with a rect light above it that faces up (away from it; the camera sees its
    front) and a sphere light under the floor (below every floor point's horizon, the floor
    being seen from above): every estimator finds F = 0 everywhere and the stats JSON counts
    no shadow ray."""
    path = tmp_path / "away.usda"
    stage = quad_light_stage(path, res=(12, 12))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Light")).GetOrderedXformOps()[1].Set(90.0)  # now emits +Y
    ball = UsdLux.SphereLight.Define(stage, "/World/Below")
    ball.CreateRadiusAttr(0.5)
    ball.CreateIntensityAttr(10.0)
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(0, -3, 0))
    stage.GetRootLayer().Save()
    for estimator in ("mis", "controlVariate", "lightSampling", "bsdfSampling", "auto"):
        r, scene = _render_keep_scene(path, max_depth=3, estimator={"": estimator}, light_samples={"": 2})
        try:
            assert r.stats["rays"]["shadow"] == 0, (estimator, r.stats["rays"])
            assert scene.accel.rays_traced["occluded"] == 0
            assert r.stats["rays"]["camera"] > 0 and len(r.stats["lights"]) == 2
        finally:
            scene.close()
