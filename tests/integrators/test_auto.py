"""The pilot behind `illum:estimator = "auto"` (renderer/integrators/auto.py).

Each case is built so that one technique is far better or far worse than the others (by orders
of magnitude in variance, well beyond the pilot's timing noise), so the pick is certain.
"""

import time

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from renderer.integrators import auto
from renderer.render import RenderOptions, render
from tests.stage_builders import furnace_stage, quad_light_stage


def _pick(stage, **kw):
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"}, **kw))
    light = r.stats["lights"][0]
    assert light["auto"] is True
    return light["estimator"], light.get("auto_scores", {})


def test_unoccluded_rect_with_exact_F_picks_the_control_variate(tmp_path):
    """A floor under a rect light sees no occluder: with α = v̄ the control variate returns the
    diffuse lobe's F exactly (zero variance), leaving only the faint specular lobe to MIS.

    At 16x16 pixels the lighting varies a lot across a pixel; the render's low-discrepancy pixel
    samples make that part of the error small, and the control variate is 1.5x as efficient as
    light sampling here (measured). A pilot that re-jittered its hits every round charged that
    variation as noise common to all candidates and picked light sampling: this catches it."""
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
    # The unoccluded floor makes the α = 1 control variate exact for the diffuse lobe, so it
    # may win too; what matters is that BSDF sampling, which rarely finds the light, loses.
    assert token in ("lightSampling", "mis", "controlVariate"), scores
    assert scores["bsdfSampling"] > 100 * min(scores.values())


def test_candidates_are_every_unbiased_form(tmp_path):
    """With one sample α = v̄ is undefined, so the control variate competes with α = 1 only;
    with N >= 2 its leave-one-out α = v̄ joins. The biased forms (ratio, α = v̄ over N) never do."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=2.0, height=2.0)
    _, scores = _pick(stage, light_samples={"": 1})
    assert set(scores) == {"lightSampling", "bsdfSampling", "mis", "controlVariate:one"}
    _, scores = _pick(stage, light_samples={"": 2})
    assert set(scores) == {"lightSampling", "bsdfSampling", "mis", "controlVariate:one",
                           "controlVariate:averageVisibilityUnbiased"}


def test_a_picked_control_variate_keeps_its_alpha(tmp_path):
    """The pick carries the α it was scored with into the render (the stats' cv_alpha)."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=3.0, height=3.0)
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"},
                                         light_samples={"": 4}, cv_alpha={"": "averageVisibility"}))
    light = r.stats["lights"][0]
    assert light["estimator"] == "controlVariate", light
    best = min(light["auto_scores"], key=light["auto_scores"].get)
    assert best == f"controlVariate:{light['cv_alpha']}", light


def test_point_light_is_light_sampled_without_a_pilot(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, light_kind="sphere", radius=0.1)
    from pxr import Usd

    s = Usd.Stage.Open(str(stage))
    UsdLux.SphereLight(s.GetPrimAtPath("/World/Light")).CreateTreatAsPointAttr(True)
    s.GetRootLayer().Save()
    token, scores = _pick(stage)
    assert token == "lightSampling" and scores == {}


# ---------------------------------------------------------------------------------------------
# The pilot's rules: CPU-time cost, racing, the cached decision.


def _before_each_call(monkeypatch, token: str, before) -> None:
    """Make the pilot's estimator ``token`` call before() ahead of each real estimate."""
    real = auto.REGISTRY[token]

    class Wrapped:
        def estimate(self, *a, **kw):
            before()
            return real.estimate(*a, **kw)

    Wrapped.token = token
    monkeypatch.setitem(auto.REGISTRY, token, Wrapped())


def test_a_candidate_that_waits_is_not_charged_for_the_wait(tmp_path, monkeypatch):
    """The pilot charges process CPU seconds, so a call that sits descheduled (here: sleeps, as
    under another job's load) costs what it computes, not what the wall clock shows."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=2.0, height=2.0)
    sleeps = []

    def sleep():
        time.sleep(0.05)
        sleeps.append(1)

    _before_each_call(monkeypatch, "mis", sleep)
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"},
                                         light_samples={"": 2}))
    pilot = r.stats["lights"][0]["auto_pilot"]
    # Each MIS call slept 50 ms (MIS may be dropped from the race before the last round); its
    # CPU cost per round stays a few ms.
    assert len(sleeps) >= 2
    assert pilot["cpu_seconds_per_round"]["mis"] < 0.025, pilot
    assert pilot["wall_seconds"] > 0.05 * len(sleeps) * 0.9, pilot



def test_one_off_costs_of_the_first_round_are_not_charged(tmp_path, monkeypatch):
    """In a fresh process the first call of each technique loads kernels and builds tables (up to
    40x a later call); whichever candidate runs first would be charged for it. The pilot's cost is
    the median over the rounds after the first. Here light sampling burns 0.1 CPU s in its first
    call only."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=2.0, height=2.0)
    calls = []

    def cold_start():
        if not calls:
            t0 = time.process_time()
            while time.process_time() - t0 < 0.1:
                pass
        calls.append(1)

    _before_each_call(monkeypatch, "lightSampling", cold_start)
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"},
                                         light_samples={"": 2}))
    pilot = r.stats["lights"][0]["auto_pilot"]
    assert len(calls) >= auto.MIN_ROUNDS
    # Charged per round as a mean over 4 rounds, the 0.1 s would add 25 ms to a few ms.
    assert pilot["cpu_seconds_per_round"]["lightSampling"] < 0.015, pilot

def test_hopeless_candidates_are_dropped_after_the_first_rounds(tmp_path):
    """Racing: against a tiny light, BSDF sampling is clearly worse after MIN_ROUNDS rounds and
    runs no more; a clear decision stops well before MAX_ROUNDS."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, light_kind="sphere", radius=0.01, intensity=1e4)
    r = render(str(stage), RenderOptions(spp=1, max_depth=1, threads=1, estimator={"": "auto"}))
    pilot = r.stats["lights"][0]["auto_pilot"]
    assert pilot["dropped"].get("bsdfSampling") == auto.MIN_ROUNDS, pilot
    assert pilot["rounds"] < auto.MAX_ROUNDS, pilot


def _synthetic_pilot(rng, err_a, err_b, rounds, cpu_a=1e-3, cpu_b=1e-3, P=1200):
    """A two-candidate race filled with Gaussian values of the given per-point variances (mean 1)."""
    p = auto._LightPilot(0, ["a", "b"], {"samples": 4, "cv_alpha": "one", "mis_heuristic": "power"}, P)
    for c, var, cpu in (("a", err_a, cpu_a), ("b", err_b, cpu_b)):
        x = 1.0 + np.sqrt(var) * rng.standard_normal((rounds, P))
        p.sum[c] = x.sum(axis=0)
        p.sq[c] = (x * x).sum(axis=0)
        p.rounds[c] = rounds
        p.cpu[c] = list(cpu * (1.0 + 0.02 * rng.standard_normal(rounds)))
    p.base = [0.0] * rounds
    return p


def _decide(p, rounds):
    # The consensus of two candidates is their average; the denominator is (mean² + floor).
    den = p.consensus() ** 2 + auto.RELMSE_FLOOR
    p.decide(den, 1.0, rounds)
    return p


def test_racing_drops_a_clearly_worse_candidate():
    p = _decide(_synthetic_pilot(np.random.default_rng(1), 0.01, 0.04, auto.MIN_ROUNDS), auto.MIN_ROUNDS)
    assert p.active == ["a"] and p.dropped == {"b": auto.MIN_ROUNDS} and p.done


def test_racing_stops_on_a_resolved_tie_and_continues_on_an_unresolved_one():
    rng = np.random.default_rng(2)
    # Equal variances and costs, many rounds: the ratio is known to a few percent, either is fine.
    p = _decide(_synthetic_pilot(rng, 0.01, 0.01, 40), 40)
    assert p.done and len(p.active) == 2, p.dropped
    # The same pair seen through few, heavy-tailed pilot pixels: too uncertain to settle.
    p = auto._LightPilot(0, ["a", "b"], {"samples": 4, "cv_alpha": "one", "mis_heuristic": "power"}, 40)
    for c in ("a", "b"):
        x = 1.0 + 0.3 * rng.standard_t(2.5, (auto.MIN_ROUNDS, 40))
        p.sum[c], p.sq[c], p.rounds[c] = x.sum(axis=0), (x * x).sum(axis=0), auto.MIN_ROUNDS
        p.cpu[c] = [1e-3] * auto.MIN_ROUNDS
    p.base = [0.0] * auto.MIN_ROUNDS
    _decide(p, auto.MIN_ROUNDS)
    assert not p.done and len(p.active) == 2


def test_cost_decides_between_equally_noisy_candidates():
    p = _decide(_synthetic_pilot(np.random.default_rng(3), 0.01, 0.01, 12, cpu_a=1e-3, cpu_b=2e-3), 12)
    assert p.active == ["a"], p.dropped


def test_the_decision_is_kept_with_the_loaded_scene(tmp_path):
    """A re-render of a cached scene reuses the pilot's decision; another image size pilots again."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, width=2.0, height=2.0)
    cache: dict = {}
    opts = dict(spp=1, max_depth=1, threads=1, estimator={"": "auto"}, light_samples={"": 4})
    first = render(str(stage), RenderOptions(**opts), scene_cache=cache).stats["lights"][0]
    again = render(str(stage), RenderOptions(**opts), scene_cache=cache).stats["lights"][0]
    other = render(str(stage), RenderOptions(resolution=(12, 12), **opts), scene_cache=cache).stats["lights"][0]
    assert first["auto_pilot"]["cached"] is False
    assert again["auto_pilot"]["cached"] is True
    assert (again["estimator"], again["auto_scores"]) == (first["estimator"], first["auto_scores"])
    assert other["auto_pilot"]["cached"] is False
