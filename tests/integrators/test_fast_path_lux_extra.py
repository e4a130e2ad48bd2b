"""The compiled vertex kernel (renderer/integrators/fast_path.py) on the UsdLux kinds it serves
through their own row functions: CylinderLights (treatAsLine included; renderer/kernels/cylinder.py).

The rect-lit room of test_fast_path.py gets a ceiling tube the camera and the continuation rays
see, a sheared, non-uniformly scaled tube (an oblique elliptic cylinder) and a line light; the
fast path and the general path (``fast_path=False``) render it and the image means are z-tested
over the whole image and in 16 blocks, under every lighting service and with the per-light
estimators (a light sample, the BSDF sample, the control variate's MIS fallback), so a wrong
sample, pdf or crossing test fails.
"""

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_BLOCK, Z_MAX, _block_z, _pair, _room
from tests.integrators.test_fast_path_estimators import _pair as _pair_est


def _add_cylinders(path):
    """Three cylinder lights added to the room stage at path (saved in place)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    tube = UsdLux.CylinderLight.Define(stage, "/World/Tube")
    tube.CreateRadiusAttr(0.08)
    tube.CreateLengthAttr(2.2)
    tube.CreateIntensityAttr(6.0)
    tube.CreateColorAttr(Gf.Vec3f(0.8, 0.9, 1.0))
    xf = UsdGeom.Xformable(tube)
    xf.AddTranslateOp().Set(Gf.Vec3d(0.3, 2.6, -0.6))
    xf.AddRotateYOp().Set(20.0)
    oblique = UsdLux.CylinderLight.Define(stage, "/World/Oblique")
    oblique.CreateRadiusAttr(0.15)
    oblique.CreateLengthAttr(1.0)
    oblique.CreateIntensityAttr(4.0)
    oblique.CreateNormalizeAttr(True)
    oblique.CreateColorAttr(Gf.Vec3f(1.0, 0.6, 0.4))
    xf = UsdGeom.Xformable(oblique)
    xf.AddTranslateOp().Set(Gf.Vec3d(-1.6, 1.3, 0.6))
    xf.AddRotateZOp().Set(60.0)
    xf.AddScaleOp().Set(Gf.Vec3f(1.0, 1.8, 0.7))
    xf.AddTransformOp(opSuffix="shear").Set(Gf.Matrix4d(1, 0.3, 0, 0, 0, 1, 0, 0, 0, 0.2, 1, 0, 0, 0, 0, 1))
    line = UsdLux.CylinderLight.Define(stage, "/World/Line")
    line.CreateRadiusAttr(0.02)
    line.CreateLengthAttr(1.5)
    line.CreateTreatAsLineAttr(True)
    line.CreateIntensityAttr(20.0)
    xf = UsdGeom.Xformable(line)
    xf.AddTranslateOp().Set(Gf.Vec3d(1.8, 1.6, 1.0))
    xf.AddRotateXOp().Set(50.0)
    stage.GetRootLayer().Save()


@pytest.fixture
def cylinder_room(tmp_path):
    stage = tmp_path / "room.usda"
    _room(stage)
    _add_cylinders(stage)
    return stage


def _check(fast, slow, n_lights=6):
    assert fast.stats["fast_path"] == "on", fast.stats["fast_path"]
    assert slow.stats["fast_path"].startswith("disabled")
    z, zs = _block_z(fast, slow)
    assert abs(z) < Z_MAX, f"whole image: fast - general = {z:.2f} sigma"
    assert max(abs(x) for x in zs) < Z_BLOCK, f"blocks: {np.round(zs, 2)}"
    assert fast.film.nonfinite_dropped == 0 and fast.film.mean().sum() > 0.0


@pytest.mark.parametrize("max_depth", [2, 5])
def test_cylinder_lights_on_the_fast_path(cylinder_room, max_depth):
    fast, slow = _pair(cylinder_room, max_depth, spp=256, rr_depth=1)
    _check(fast, slow)
    assert fast.stats["rays"]["light_probe"] == 0


@pytest.mark.parametrize("sampler", ["uniform", "power", "bvh"])
def test_cylinder_lights_under_each_lighting_service(cylinder_room, sampler):
    fast, slow = _pair(cylinder_room, 4, spp=256, rr_depth=1, light_sampler=sampler)
    assert fast.stats["light_sampler"] == sampler
    _check(fast, slow)


@pytest.mark.parametrize("estimator,samples", [("lightSampling", 2), ("bsdfSampling", 1), ("controlVariate", 3),
                                               ("mis", 3)])
def test_cylinder_lights_with_each_estimator(cylinder_room, estimator, samples):
    fast, slow = _pair_est(cylinder_room, estimator, "one", samples, spp=192, res=(48, 36))
    _check(fast, slow)


def test_the_comparison_sees_a_wrong_cylinder_emission(cylinder_room, monkeypatch):
    """The comparison can fail: the tubes' radiance doubled where the fast path's rays meet them
    (their samples unchanged)."""
    from renderer.integrators import fast_path as fp_mod

    orig = fp_mod.FastPath.__init__

    def doubled(self, integ):
        orig(self, integ)
        packed, L, light = self.cyl
        self.tables = (*self.tables[:-1], (packed, 2.0 * L, light))
    monkeypatch.setattr(fp_mod.FastPath, "__init__", doubled)
    fast, slow = _pair(cylinder_room, 3, spp=192, rr_depth=1)
    z, _ = _block_z(fast, slow)
    assert abs(z) > Z_MAX, f"doubled tube emission went unseen (z = {z:.2f})"
