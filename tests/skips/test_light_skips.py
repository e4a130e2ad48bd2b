"""Skip proofs for lights (issue #8 item 3), by counting.

* Lights that emit nothing (intensity 0, black colour) are dropped before the lighting services:
  ``LightSet.dropped`` lists them, the stats JSON's ``lights`` list excludes them, its
  ``skipped`` list names them, and no light sample is ever drawn for them (the light set's
  count excludes them, so the estimators are never called with them).
* With a single light no light BVH is built: the scene's ``light_accel`` (the proxy BVH for
  ray/light hits) is None, the lighting service is ``exhaustive``, and neither the BVH light
  sampler nor the proxy triangles are ever constructed (call counter). With 20 lights they are.

Already proven elsewhere: tests/light_samplers/test_protocol.py::test_dark_light_dropped_before_the_sampler
(at the LightSet, for the BVH sampler) and ::test_factory_registry_and_auto_rule (the auto rule).
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.accel import Accel
from renderer.light_samplers.bvh import BVHLightSampler
from renderer.lights.light_set import LightSet
from renderer.render import RenderOptions, render
from tests.skips.counting import CallCounter
from tests.stage_builders import quad_light_stage


def _add_sphere(stage, path, pos, **attrs):
    light = UsdLux.SphereLight.Define(stage, path)
    light.CreateRadiusAttr(0.1)
    for name, value in attrs.items():
        light.GetPrim().GetAttribute(name).Set(value)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(*pos))
    return light


def _render_keep_scene(path, **opt):
    cache: dict = {}
    kw = dict(spp=1, threads=1, max_depth=1)
    kw.update(opt)
    r = render(str(path), RenderOptions(**kw), scene_cache=cache)
    (desc, scene), = cache.values()
    return r, scene


@pytest.mark.parametrize("dark", [{"inputs:intensity": 0.0}, {"inputs:color": Gf.Vec3f(0, 0, 0)},
                                  {"inputs:intensity": 5.0, "inputs:color": Gf.Vec3f(0, 0, 0)}])
def test_lights_that_emit_nothing_are_dropped_before_the_lighting_services(tmp_path, dark):
    path = tmp_path / "s.usda"
    stage = quad_light_stage(path, res=(8, 8))
    for k in range(3):
        _add_sphere(stage, f"/World/Off{k}", (k - 1.0, 2.0, 0.0), **dark)
    stage.GetRootLayer().Save()
    counter = CallCounter(LightSet.sample_li, capture={LightSet.sample_li: "light"})
    with counter as calls:
        # The general path: its light samples are LightSet.sample_li calls the counter sees (the
        # compiled route draws them in its kernel).
        r, scene = _render_keep_scene(path, fast_path=False)
    try:
        off = [f"/World/Off{k}" for k in range(3)]
        assert scene.lights.dropped == off
        assert scene.lights.paths == ["/World/Light"]
        assert [li["path"] for li in r.stats["lights"]] == ["/World/Light"]
        for p in off:
            assert any(p in s and "dropped before the lighting services" in s for s in r.stats["skipped"]), p
        # The lighting service only knows the light that emits ...
        assert scene.light_sampler.count == 1
        # ... so every light sample ever drawn is of that light (global index 0).
        assert calls[LightSet.sample_li] > 0
        drawn = np.concatenate([np.asarray(x).ravel() for x in counter.captured[LightSet.sample_li]])
        assert drawn.size > 0 and np.all(drawn == 0)
        assert not any("/World/Off" in w for w in r.warnings)  # dark lights are dropped silently
    finally:
        scene.close()


def test_a_single_light_builds_no_light_bvh(tmp_path):
    path = tmp_path / "s.usda"
    quad_light_stage(path, res=(8, 8))
    with CallCounter(BVHLightSampler.__init__, LightSet.proxy_triangles, Accel.__init__) as calls:
        r, scene = _render_keep_scene(path, max_depth=3)
    try:
        assert scene.lights.count == 1
        assert scene.light_accel is None and scene.light_owner is None
        assert scene.light_sampler.name == "exhaustive" and r.stats["light_sampler"] == "exhaustive"
        assert calls[BVHLightSampler.__init__] == 0
        assert calls[LightSet.proxy_triangles] == 0
        assert calls[Accel.__init__] == 1  # the scene's geometry BVH only
    finally:
        scene.close()


def test_twenty_lights_do_build_them(tmp_path):
    """Control: above the thresholds (8 lights for the exhaustive service, 16 finite lights for
    brute-force light hits) both structures are built, and the counters see it."""
    path = tmp_path / "s.usda"
    stage = quad_light_stage(path, res=(8, 8))
    for k in range(19):
        _add_sphere(stage, f"/World/L{k}", (0.2 * k - 2.0, 2.0, 0.0), **{"inputs:intensity": 3.0})
    stage.GetRootLayer().Save()
    with CallCounter(BVHLightSampler.__init__, LightSet.proxy_triangles, Accel.__init__) as calls:
        r, scene = _render_keep_scene(path)
    try:
        assert scene.lights.count == 20
        assert scene.light_accel is not None and r.stats["light_sampler"] == "bvh"
        assert calls[BVHLightSampler.__init__] == 1 and calls[LightSet.proxy_triangles] == 1
        assert calls[Accel.__init__] == 2
        assert np.all(np.isfinite(r.film.mean()))
    finally:
        scene.close()
