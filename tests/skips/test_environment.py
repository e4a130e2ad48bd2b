"""Skip proof: with no dome (or distant) light, rays that miss do no environment work.

Proof by counting, not timing: a stage where half of the camera rays miss everything is
rendered under a call counter (tests/skips/counting.py, a profile hook: nothing is replaced).
Without an infinite light, the integrator's escaped-ray path (PathIntegrator._add_escaped) and
the light set's environment lookups (LightSet.le_escaped / le_escaped_all) are never called,
and the stats JSON lists the skip ("no dome or distant light: escaped rays do no environment
work"). The same stage with a dome calls them, and the skip is not listed.
"""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.integrators.path import PathIntegrator
from renderer.lights.light_set import LightSet
from renderer.render import RenderOptions, render
from tests.skips.counting import CallCounter
from tests.stage_builders import add_settings, new_stage

SKIP = "no dome or distant light: escaped rays do no environment work"
WATCHED = (PathIntegrator._add_escaped, LightSet.le_escaped, LightSet.le_escaped_all)


def _horizon_stage(path, infinite=None):
    """A floor seen at a grazing angle, so the upper half of the image is empty sky."""
    stage = new_stage(path)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(20.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(36.0)
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 1, 8))
    add_settings(stage, (16, 16), camera="/World/Camera")
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-50, 0, -50), (-50, 0, 50), (50, 0, 50), (50, 0, -50)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    floor.CreateSubdivisionSchemeAttr("none")
    light = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    light.CreateRadiusAttr(0.3)
    light.CreateIntensityAttr(50.0)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    if infinite == "dome":
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.5)
    elif infinite == "distant":
        UsdLux.DistantLight.Define(stage, "/World/Sun").CreateIntensityAttr(2.0)
    stage.GetRootLayer().Save()
    return str(path)


@pytest.mark.parametrize("max_depth", [1, 4])
def test_no_environment_work_without_an_infinite_light(tmp_path, max_depth):
    path = _horizon_stage(tmp_path / "s.usda")
    with CallCounter(*WATCHED) as calls:
        # The general path (the fast path's kernel loops over no infinite lights, unseen here).
        r = render(path, RenderOptions(spp=2, threads=1, max_depth=max_depth, fast_path=False))
    img = r.film.mean()
    sky = (img == 0.0).all(axis=2)
    assert sky.sum() >= 0.3 * sky.size, "the stage must have escaping camera rays for this proof"
    assert calls == {f: 0 for f in WATCHED}, calls
    assert SKIP in r.stats["skipped"]


@pytest.mark.parametrize("infinite", ["dome", "distant"])
def test_the_environment_work_happens_with_an_infinite_light(tmp_path, infinite):
    """Control: the counter does see the calls when there is an environment to look up."""
    path = _horizon_stage(tmp_path / "s.usda", infinite)
    with CallCounter(*WATCHED) as calls:
        r = render(path, RenderOptions(spp=2, threads=1, max_depth=2, fast_path=False))
    assert calls[PathIntegrator._add_escaped] > 0 and calls[LightSet.le_escaped] > 0
    assert SKIP not in r.stats["skipped"]
    if infinite == "dome":
        assert np.all(r.film.mean() > 0.0)
