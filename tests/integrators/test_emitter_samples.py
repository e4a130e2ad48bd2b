"""Emitter samples (integrators/path.py trace_paths): K camera rays per pixel and pass see the
emitters, one continues as the path. The image must stay unbiased, the anti-aliasing variance of
small lights on screen must fall, and the `auto` rule and the option's bounds must hold."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, UsdLux

from renderer.errors import SettingsError
from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_floor, add_settings, new_stage


def _small_lights_stage(path, n_lights=6, res=(24, 24), radius=0.05, dome=False):
    """A grey floor seen from above, with n_lights small bright sphere lights between camera
    and floor, each covering about one pixel: subpixel emitters on camera, like the fireflies."""
    stage = new_stage(path)
    add_camera(stage, pos=(0, 6, 0), tilt_x=-90.0)
    add_settings(stage, res)
    add_floor(stage)
    rng = np.random.default_rng(4)
    for i in range(n_lights):
        light = UsdLux.SphereLight.Define(stage, f"/World/L{i}")
        light.CreateRadiusAttr(radius)
        light.CreateIntensityAttr(float(rng.uniform(50.0, 200.0)))
        x, z = rng.uniform(-1.5, 1.5, size=2)
        light.AddTranslateOp().Set(Gf.Vec3d(float(x), 1.0, float(z)))
    if dome:  # an infinite light among them: it has no bounds
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.1)
    stage.GetRootLayer().Save()
    return str(path)


def _image_z(a, b) -> float:
    """z-score of the difference of two renders' image sums (pixels are independent)."""
    da = a.film.mean()[..., 1].sum() - b.film.mean()[..., 1].sum()
    var = a.film.variance_of_mean()[..., 1].sum() + b.film.variance_of_mean()[..., 1].sum()
    return float(da / np.sqrt(var))


@pytest.mark.parametrize("max_depth", [0, 2])
def test_emitter_samples_keep_the_image_unbiased(tmp_path, max_depth):
    stage = _small_lights_stage(tmp_path / "s.usda")
    base = dict(max_depth=max_depth, threads=1, light_sampler="uniform")
    one = render(stage, RenderOptions(spp=96, seed=1, emitter_samples=1, **base))
    four = render(stage, RenderOptions(spp=96, seed=2, emitter_samples=4, **base))
    assert one.stats["emitter_samples"] == 1 and four.stats["emitter_samples"] == 4
    assert four.stats["rays"]["camera"] == 4 * one.stats["rays"]["camera"]
    assert abs(_image_z(four, one)) < 4.0


def test_emitter_samples_cut_the_anti_aliasing_variance(tmp_path):
    """Directly seen emitters only (max depth 0): with K = 4 rays per pass the per-pixel variance
    of the mean, summed over the image, is about a quarter of K = 1's at equal passes or less
    (0.19 with these seeds; the K rays continue each pixel's stratified sequence), where rays
    that repeated the first one's position would give 1. A split that ignored the extra rays, or
    weighted them wrongly, fails the unbiasedness test above."""
    stage = _small_lights_stage(tmp_path / "s.usda")
    base = dict(max_depth=0, threads=1, spp=64)
    v1 = render(stage, RenderOptions(seed=1, emitter_samples=1, **base)).film.variance_of_mean()[..., 1].sum()
    v4 = render(stage, RenderOptions(seed=1, emitter_samples=4, **base)).film.variance_of_mean()[..., 1].sum()
    assert v4 < 0.4 * v1


def test_auto_uses_more_emitter_samples_only_where_subpixel_lights_touch_many_pixels(tmp_path):
    """auto: K = 2 when lights under a pixel on screen could touch >= 1 % of the pixels."""
    cases = {  # name: (lights, resolution, radius, dome, expected K); a pixel is ~0.64 units at the lights
        "few": (3, (64, 64), 0.05, False, 1),       # 12 of 4096 pixels
        "many": (64, (8, 8), 0.05, False, 2),       # every pixel
        "many+dome": (64, (8, 8), 0.05, True, 2),   # an unbounded light among them changes nothing
        "large": (64, (8, 8), 1.0, False, 1),       # as many lights, but each wider than a pixel
    }
    for name, (n, res, radius, dome, k) in cases.items():
        stage = _small_lights_stage(tmp_path / f"{name}.usda", n_lights=n, res=res, radius=radius, dome=dome)
        assert render(stage, RenderOptions(spp=1, threads=1)).stats["emitter_samples"] == k, name


@pytest.mark.parametrize("bad", [-1, 65, 2.5])
def test_emitter_samples_out_of_range_is_a_named_error(tmp_path, bad):
    stage = _small_lights_stage(tmp_path / "s.usda", n_lights=1, res=(4, 4))
    with pytest.raises(SettingsError, match="emitter_samples"):
        render(stage, RenderOptions(spp=1, emitter_samples=bad))
