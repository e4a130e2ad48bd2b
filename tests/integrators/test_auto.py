"""The pilot behind `illum:estimator = "auto"` (renderer/integrators/auto.py).

Each case is built so that one technique is far better or far worse than the others (by orders
of magnitude in variance, well beyond the pilot's timing noise), so the pick is certain.
"""

from pxr import Gf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.stage_builders import furnace_stage, quad_light_stage


def _pick(stage, **kw):
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"}, **kw))
    light = r.stats["lights"][0]
    assert light["auto"] is True
    return light["estimator"], light.get("auto_scores", {})


def test_unoccluded_rect_with_exact_F_picks_the_control_variate(tmp_path):
    """A floor under a rect light sees no occluder: with α = v̄ the control variate returns the
    diffuse lobe's F exactly (zero variance), leaving only the faint specular lobe to MIS."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=3.0, height=3.0)
    token, scores = _pick(stage, light_samples={"": 4})
    assert token == "controlVariate", scores


def test_constant_dome_over_a_convex_ball_picks_bsdf_sampling(tmp_path):
    """Under a constant dome the integrand is the BSDF times a constant, which BSDF sampling
    follows almost exactly."""
    stage = tmp_path / "f.usda"
    furnace_stage(stage, L=1.0, rho=0.5)
    token, scores = _pick(stage, light_samples={"": 4})
    assert token == "bsdfSampling", scores


def test_tiny_light_is_never_bsdf_sampled(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, light_kind="sphere", radius=0.01, intensity=1e4)
    token, scores = _pick(stage)
    assert token in ("lightSampling", "mis"), scores
    assert scores["bsdfSampling"] > 100 * scores[token]


def test_without_exact_F_or_with_one_sample_no_control_variate(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=2.0, height=2.0)
    _, scores = _pick(stage, light_samples={"": 1})
    assert set(scores) == {"lightSampling", "bsdfSampling", "mis"}


def test_point_light_is_light_sampled_without_a_pilot(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, light_kind="sphere", radius=0.1)
    from pxr import Usd

    s = Usd.Stage.Open(str(stage))
    UsdLux.SphereLight(s.GetPrimAtPath("/World/Light")).CreateTreatAsPointAttr(True)
    s.GetRootLayer().Save()
    token, scores = _pick(stage)
    assert token == "lightSampling" and scores == {}
