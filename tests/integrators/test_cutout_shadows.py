"""Shadow rays see cut-out surfaces as camera and BSDF rays do.

A card between a rect light and a floor: with opacity 0 (absent everywhere) the image must be
the image without the card, for every estimator (before the fix the card blocked every shadow
ray and the image was black); with opacity 0.5 (present half the time) light sampling, BSDF
sampling and MIS must agree, which needs the shadow rays and the continuation rays to pass
through the card with the same probability.
"""

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.render import RenderOptions, render
from tests.stats import film_difference_z
from tests.stage_builders import add_camera, add_floor, add_settings, bind, new_stage, preview_material

Z_MAX = 4.0


def _stage(path, opacity=None, threshold=0.0, light_size=2.0, shadow_link=False):
    stage = new_stage(str(path))
    add_camera(stage, pos=(0, 3, 6), tilt_x=-25)
    add_settings(stage, (16, 16))
    add_floor(stage)
    light = UsdLux.RectLight.Define(stage, "/World/Light")
    light.CreateWidthAttr(light_size)
    light.CreateHeightAttr(light_size)
    light.CreateIntensityAttr(20.0 / light_size ** 2)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 4, 0))
    UsdGeom.Xformable(light).AddRotateXOp().Set(-90.0)
    if shadow_link:
        # The floor casts no shadow for this light: its shadow rays use a BVH of the other
        # meshes (a subset of the scene's triangles, with their own numbering).
        api = UsdLux.LightAPI(light.GetPrim())
        api.GetShadowLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/Floor")
    if opacity is not None:
        card = UsdGeom.Mesh.Define(stage, "/World/Card")
        card.CreatePointsAttr([(-3, 2, -3), (3, 2, -3), (3, 2, 3), (-3, 2, 3)])
        card.CreateFaceVertexCountsAttr([4])
        card.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        card.CreateSubdivisionSchemeAttr("none")
        mat = preview_material(stage, "/World/Looks/Card", diffuse=(0.3, 0.3, 0.3))
        shader = UsdShade.Shader.Get(stage, "/World/Looks/Card/PBR")
        shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(opacity)
        shader.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(threshold)
        bind(card.GetPrim(), mat)
    stage.GetRootLayer().Save()
    return str(path)


def _z(a, b):
    """z of the whole image's difference, per channel (tests.stats.film_difference_z)."""
    return film_difference_z(a.film, b.film, blocks=1)[0]


@pytest.mark.parametrize("estimator", ["mis", "lightSampling", "bsdfSampling"])
@pytest.mark.parametrize("opacity,threshold,shadow_link", [(0.0, 0.0, False), (0.2, 0.5, False), (0.0, 0.0, True)])
def test_an_absent_card_casts_no_shadow(tmp_path, estimator, opacity, threshold, shadow_link):
    plain = _stage(tmp_path / "plain.usda", shadow_link=shadow_link)
    card = _stage(tmp_path / "card.usda", opacity, threshold, shadow_link=shadow_link)
    opt = dict(spp=32, max_depth=1, threads=1, estimator={"": estimator})
    a = render(plain, RenderOptions(seed=1, **opt))
    b = render(card, RenderOptions(seed=2, **opt))
    assert b.film.mean().mean() > 0.5 * a.film.mean().mean()
    z = _z(a, b)
    assert abs(z) < Z_MAX, f"{estimator}: card (absent) vs no card: {z:.2f} sigma"


def test_estimators_agree_under_a_half_present_card(tmp_path):
    # A large light, so the BSDF half of MIS (the continuation ray through the card) carries
    # much of the weight: with opaque shadow rays MIS would exceed light sampling.
    card = _stage(tmp_path / "card.usda", 0.5, light_size=8.0)
    opt = dict(spp=64, max_depth=2, threads=1)
    ls = render(card, RenderOptions(seed=1, estimator={"": "lightSampling"}, **opt))
    for k, est in enumerate(("mis", "bsdfSampling")):
        # The general path's shadow rays (MIS would take the fast path, whose cut-outs
        # tests/integrators/test_fast_path_materials.py z-tests against this path).
        r = render(card, RenderOptions(seed=2 + k, estimator={"": est}, fast_path=False, **opt))
        z = _z(r, ls)
        assert abs(z) < Z_MAX, f"{est} vs lightSampling under a half-present card: {z:.2f} sigma"
