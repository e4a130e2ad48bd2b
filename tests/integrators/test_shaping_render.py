"""UsdLux ShapingAPI end to end (render()): a shaped spot renders the same image whether it is
light-sampled, MIS-combined or only found by BSDF-sampled rays, so the factor on light samples
(LightSet.sample_li), on rays that hit the light (LightSet.le) and the pdfs all agree.

At this size (8 x 8 pixels, seconds) the pooled z-test catches a factor missing or misapplied on
one path, or a light-sampling error of ~15 % (checked by scaling the pdf); the light-level
chi-square and z-tests (tests/lights/test_shaping.py) are the fine-grained checks."""

from __future__ import annotations

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_floor, add_settings, new_stage

IES = os.path.join(os.path.dirname(__file__), "..", "..", "stages", "ies", "wallwash.ies")


def _spot_stage(path, ies: bool):
    """A grey floor under a large tilted disk spot (radius 0.9 m, 0.9 m up: it fills much of the
    floor's sky, so BSDF sampling is a sound reference) with focus, a soft cone and optionally
    an IES profile; the camera, just under the light, looks down at the pool of light."""
    stage = new_stage(path)
    add_camera(stage, pos=(0.0, 0.8, 0.0), focal=20.0, tilt_x=-90.0, clip=(0.01, 100.0))
    add_settings(stage, res=(8, 8))
    add_floor(stage, half=10.0, roughness=0.7)
    spot = UsdLux.DiskLight.Define(stage, "/World/Spot")
    spot.CreateRadiusAttr(0.9)
    spot.CreateIntensityAttr(6.0)
    lx = UsdGeom.Xformable(spot)
    lx.AddTranslateOp().Set(Gf.Vec3d(-0.7, 0.9, 0.0))
    lx.AddRotateZOp().Set(20.0)
    lx.AddRotateXOp().Set(-90.0)   # local -Z (the axis) -> world -Y, then tilted toward +X
    sh = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    sh.CreateShapingFocusAttr(1.5)
    sh.CreateShapingFocusTintAttr(Gf.Vec3f(0.2, 0.1, 0.4))
    sh.CreateShapingConeAngleAttr(30.0)
    sh.CreateShapingConeSoftnessAttr(0.5)
    if ies:
        sh.CreateShapingIesFileAttr(Sdf.AssetPath(os.path.abspath(IES)))
        sh.CreateShapingIesAngleScaleAttr(0.6)
        sh.CreateShapingIesNormalizeAttr(True)
    stage.GetRootLayer().Save()
    return str(path)


def _zdiff(img, ref):
    """Pixelwise z-scores of img's mean against ref's (both Films), pooled: |mean z| sqrt(n)."""
    var = img.variance_of_mean()[..., 1] + ref.variance_of_mean()[..., 1]
    lit = var > 0
    z = (img.mean()[..., 1] - ref.mean()[..., 1])[lit] / np.sqrt(var[lit])
    return abs(z.mean()) * np.sqrt(z.size), int(lit.sum())


@pytest.mark.parametrize("ies", [False, True])
def test_shaped_spot_light_sampling_and_mis_match_bsdf_sampling(tmp_path, ies):
    path = _spot_stage(tmp_path / f"spot_{ies}.usda", ies)
    ref = render(path, RenderOptions(spp=512, max_depth=1, threads=1, seed=21, estimator={"": "bsdfSampling"}))
    assert ref.stats["lights"][0]["exact_integral"] is False   # shaped: MIS, no exact F
    img = ref.film.mean()[..., 1]
    assert img.max() > 3 * max(img.min(), 1e-6)   # the cone's soft edge crosses the frame
    for k, est in enumerate(("lightSampling", "mis")):
        r = render(path, RenderOptions(spp=32, max_depth=1, threads=1, seed=22 + k, estimator={"": est}))
        z, lit = _zdiff(r.film, ref.film)
        assert lit > 40 and z < 4.0, (est, z)


def test_control_variate_on_a_shaped_light_falls_back_to_mis_and_says_so(tmp_path):
    """No exact F for a shaped light: controlVariate runs as MIS (the same image, seed for seed),
    the stats say why and one warning says what was requested."""
    path = _spot_stage(tmp_path / "cv.usda", False)
    # Two samples: mis with one would take continuation MIS on the compiled route, which draws
    # other numbers than the estimator the control variate falls back to.
    cv = render(path, RenderOptions(spp=2, max_depth=1, threads=1, seed=3, estimator={"": "controlVariate"},
                                    light_samples={"": 2}))
    mis = render(path, RenderOptions(spp=2, max_depth=1, threads=1, seed=3, estimator={"": "mis"},
                                     light_samples={"": 2}))
    light = cv.stats["lights"][0]
    assert light["exact_integral"] is False and "ShapingAPI" in light["no_exact_integral_because"]
    msgs = [w for w in cv.stats["warnings"] if w.startswith("/World/Spot") and "falls back to MIS" in w]
    assert len(msgs) == 1 and "controlVariate" in msgs[0]
    np.testing.assert_array_equal(cv.film.mean(), mis.film.mean())
