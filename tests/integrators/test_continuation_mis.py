"""Continuation MIS: the path's extension ray is the BSDF half of every MIS light.

The same multi-bounce stage is rendered with MIS (light half in the estimator, BSDF half on the
continuation ray, weighted with the lighting service's pmf) and with light sampling only (no
half rides on the continuation ray). Both are unbiased, so the difference of the two image
means is zero up to noise: z-tested with the per-pixel variance of each film. A deliberately
broken weight (the continuation adds the whole emission) must fail the same test.
"""

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux

from renderer.integrators import path as path_mod
from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material

Z_MAX = 4.0


def _room(path, n_lights: int):
    """A floor, a back wall and a glossy ball, lit by n_lights sphere and rect lights large enough
    that continuation rays often reach them (so a wrong BSDF-half weight shows)."""
    stage = new_stage(path)
    add_camera(stage, pos=(0, 1.2, 5))
    add_settings(stage, (20, 16))
    for name, pts in (("Floor", [(-3, 0, -3), (3, 0, -3), (3, 0, 3), (-3, 0, 3)]),
                      ("Wall", [(-3, 0, -2), (3, 0, -2), (3, 4, -2), (-3, 4, -2)])):
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreatePointsAttr(pts)
        m.CreateFaceVertexCountsAttr([4])
        m.CreateFaceVertexIndicesAttr([0, 3, 2, 1] if name == "Floor" else [0, 1, 2, 3])
        m.CreateSubdivisionSchemeAttr("none")
        bind(m.GetPrim(), preview_material(stage, f"/World/Looks/{name}", diffuse=(0.7, 0.6, 0.5)))
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(0.7)
    ball.AddTranslateOp().Set(Gf.Vec3d(0.3, 0.7, 0))
    bind(ball.GetPrim(), preview_material(stage, "/World/Looks/Gloss", diffuse=(0.3, 0.3, 0.6), roughness=0.25,
                                          metallic=0.5))
    rng = np.random.default_rng(7)
    big = UsdLux.RectLight.Define(stage, "/World/Big")  # the one continuation rays hit most
    big.CreateWidthAttr(4.0)
    big.CreateHeightAttr(3.0)
    big.CreateIntensityAttr(2.0)
    UsdGeom.Xformable(big).AddTranslateOp().Set(Gf.Vec3d(0, 2.2, 0))
    UsdGeom.Xformable(big).AddRotateXOp().Set(-90.0)
    for i in range(n_lights - 1):
        pos = Gf.Vec3d(float(rng.uniform(-2.5, 2.5)), float(rng.uniform(1.5, 3.5)), float(rng.uniform(-1.5, 1.5)))
        if i % 2 == 0:
            light = UsdLux.SphereLight.Define(stage, f"/World/L{i}")
            light.CreateRadiusAttr(float(rng.uniform(0.3, 0.6)))
        else:
            light = UsdLux.RectLight.Define(stage, f"/World/L{i}")
            light.CreateWidthAttr(float(rng.uniform(1.0, 2.5)))
            light.CreateHeightAttr(float(rng.uniform(1.0, 2.5)))
        light.CreateIntensityAttr(float(rng.uniform(2.0, 20.0)))
        xf = UsdGeom.Xformable(light)
        xf.AddTranslateOp().Set(pos)
        xf.AddRotateXOp().Set(-90.0)
    stage.GetRootLayer().Save()


def _z_of_difference(stage, sampler: str, fast_path: bool = True) -> float:
    common = dict(max_depth=4, threads=1, light_sampler=sampler)
    # With the exhaustive sampler the MIS render qualifies for the fast path (its own compiled
    # continuation MIS); fast_path=False tests the general integrator's.
    a = render(str(stage), RenderOptions(spp=48, seed=1, estimator={"": "mis"}, fast_path=fast_path, **common))
    b = render(str(stage), RenderOptions(spp=48, seed=2, estimator={"": "lightSampling"}, **common))
    assert a.stats["direct_rule"]["continuation_mis"] > 0
    assert b.stats["direct_rule"]["continuation_mis"] == 0
    # Pixels are independent, and each pixel's difference has mean 0 when both are unbiased.
    d = a.film.mean().sum(axis=-1) - b.film.mean().sum(axis=-1)
    return float(d.mean() / (d.std(ddof=1) / np.sqrt(d.size)))


@pytest.mark.parametrize("n_lights,sampler,fast_path", [(3, "exhaustive", True), (3, "exhaustive", False),
                                                        (12, "bvh", True), (12, "power", True)])
def test_continuation_mis_is_unbiased(tmp_path, n_lights, sampler, fast_path):
    stage = tmp_path / "room.usda"
    _room(stage, n_lights)
    z = _z_of_difference(stage, sampler, fast_path)
    assert abs(z) < Z_MAX, f"mean difference MIS - lightSampling is {z:.2f} sigma"


def test_broken_continuation_weight_is_detected(tmp_path, monkeypatch):
    """Counting the continuation's emission in full for MIS lights (forgetting the weight) double
    counts their BSDF half; the light-sampling render is untouched (no half rides on its rays)."""
    stage = tmp_path / "room.usda"
    _room(stage, 3)
    real = path_mod._Emission.weight

    def broken(self, rows, light):
        w = real(self, rows, light)
        return np.where((self.cont[rows] > 0) & self.integ.cont_ok[light], 1.0, w)

    monkeypatch.setattr(path_mod._Emission, "weight", broken)
    z = _z_of_difference(stage, "exhaustive", fast_path=False)
    assert z > Z_MAX, f"the broken weight went unnoticed (z = {z:.2f})"
