"""The path tracer end to end on real stages: white furnace, depth conventions, determinism."""

import numpy as np
import pytest

from renderer.render import RenderOptions, render
from tests.stage_builders import furnace_stage, quad_light_stage
from tests.stats import SIGNIFICANCE, z_test


def test_white_furnace_converges_to_dome_radiance(tmp_path):
    """A white sphere (albedo 1, energy-conserving UsdPreviewSurface) in a constant dome of
    radiance L: every pixel's expected value is exactly L, through any number of bounces."""
    L = 2.0
    stage = tmp_path / "furnace.usda"
    furnace_stage(stage, L=L, rho=1.0)
    r = render(str(stage), RenderOptions(spp=64, seed=1, max_depth=8, threads=1))
    img = r.film.mean()
    assert r.stats["nonfinite_dropped"] == 0
    # Per-pixel means are iid estimates of L (different pixels see the sphere at different wo).
    ball = img[6:18, 6:18, 1].ravel()  # the centre of the image is on the sphere
    p = z_test(ball, L)
    assert p > SIGNIFICANCE, f"sphere pixels average {ball.mean():.5f}, expected {L}"
    assert abs(ball.mean() / L - 1) < 0.01
    # Background pixels see the dome directly: exactly L with no noise.
    np.testing.assert_allclose(img[0, 0], L, rtol=1e-6)


def test_furnace_catches_energy_loss(tmp_path):
    """The same check must fail for a grey sphere (albedo 0.5 loses energy)."""
    stage = tmp_path / "grey.usda"
    furnace_stage(stage, L=2.0, rho=0.5)
    r = render(str(stage), RenderOptions(spp=16, seed=1, threads=1))
    ball = r.film.mean()[6:18, 6:18, 1].ravel()
    assert z_test(ball, 2.0) < SIGNIFICANCE


def test_max_depth_zero_shows_only_emitters(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage)
    r = render(str(stage), RenderOptions(spp=2, max_depth=0, threads=1))
    img = r.film.mean()
    # The floor is black, only the light (seen from above it emits downward: its back) ...
    # the camera looks down at the light's back, so nothing at all is visible.
    assert img.max() == 0.0
    assert r.stats["rays"]["shadow"] == 0 and r.stats["rays"]["extension"] == 0


@pytest.mark.parametrize("opt", [{"fast_path": False}, {"estimator": {"": "lightSampling"}}])
def test_max_depth_one_traces_no_extension_rays(tmp_path, opt):
    """The general path at max depth 1, and the compiled route where no light is on continuation
    MIS (it traces them for mis lights with one sample: their BSDF half rides on them)."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage)
    r = render(str(stage), RenderOptions(spp=2, max_depth=1, threads=1, **opt))
    assert r.stats["fast_path"] == ("on" if "estimator" in opt else "disabled (--no-fast-path)")
    assert r.stats["rays"]["extension"] == 0
    assert r.stats["rays"]["shadow"] > 0
    assert r.film.mean().max() > 0.0
    assert any("no extension rays" in s for s in r.stats["skipped"])


def test_max_depth_one_on_the_compiled_route_says_nothing_of_skipped_extension_rays(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage)
    r = render(str(stage), RenderOptions(spp=2, max_depth=1, threads=1))
    assert r.stats["fast_path"] == "on" and r.stats["rays"]["extension"] > 0
    assert not any("no extension rays" in s for s in r.stats["skipped"])


def test_images_do_not_depend_on_thread_count(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, res=(160, 120))
    a = render(str(stage), RenderOptions(spp=2, threads=1, seed=3)).film.mean()
    b = render(str(stage), RenderOptions(spp=2, threads=2, seed=3)).film.mean()
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("estimator", ["mis", "lightSampling", "controlVariate"])
def test_direct_lighting_matches_across_estimators(tmp_path, estimator):
    """Direct lighting (max depth 1) of a floor under a rect light: the image mean agrees
    between estimators (each is unbiased), z-tested against a long MIS render."""
    stage = tmp_path / "q.usda"
    quad_light_stage(stage, res=(12, 12), width=2.0, height=2.0)
    ref = render(str(stage), RenderOptions(spp=256, max_depth=1, threads=1, seed=99)).film.mean()
    r = render(str(stage), RenderOptions(spp=64, max_depth=1, threads=1, seed=5,
                                         estimator={"": estimator}, light_samples={"": 2}))
    img = r.film
    # Pixelwise z-scores against the reference mean (whose own error is 2x smaller).
    var = img.variance_of_mean()[..., 1]
    diff = img.mean()[..., 1] - ref[..., 1]
    lit = var > 0
    z = diff[lit] / np.sqrt(var[lit] * 1.25)
    assert abs(z.mean()) * np.sqrt(z.size) < 4.0
    assert r.stats["lights"][0]["estimator"] == estimator
