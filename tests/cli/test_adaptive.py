"""Adaptive sampling (renderer/adaptive.py) on a stage that mixes easy and hard pixels: a grey
room lit by a sky it opens onto (tests/stage_builders.py sky_room_stage). The image is compared
with an independent uniform render by a z-test; the same test applied to the samples that
decided when to stop (the textbook rule's estimate) finds their bias, so it has the power to
see one. The sample-count pass is read back from the EXR with OpenImageIO."""

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf

from renderer.adaptive import DEFAULT_MIN_SPP, decisions
from renderer.errors import SettingsError
from renderer.render import RenderOptions, render, write_outputs
from tests.stage_builders import sky_room_stage
from tests.stats import SIGNIFICANCE

from .test_cli import _error
from .test_outputs import run

CAP, MIN_SPP, T = 128, 16, 0.1


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    p = tmp_path_factory.mktemp("adaptive") / "room.usda"
    sky_room_stage(p, res=(32, 32))
    return p


@pytest.fixture(scope="module")
def reference(room):
    """An independent uniform render (another seed) of the same film mode."""
    return render(str(room), RenderOptions(spp=256, seed=7, pixel_filter_mode="importance")).film


def _z(film, ref, pixels) -> np.ndarray:
    """(3,) z of the summed differences between film's and ref's pixel means over the flat
    pixels, per channel, against the sum of both films' variance estimates."""
    def means(f):
        return (f.sum / np.maximum(f.count[:, :, None], 1)).reshape(-1, 3)[pixels]

    var = film.variance_of_mean().reshape(-1, 3)[pixels] + ref.variance_of_mean().reshape(-1, 3)[pixels]
    return (means(film) - means(ref)).sum(axis=0) / np.sqrt(var.sum(axis=0))


def _p(z) -> np.ndarray:
    return np.array([math.erfc(abs(v) / math.sqrt(2.0)) for v in z])


def _exr(path) -> dict:
    inp = oiio.ImageInput.open(str(path))
    spec, data = inp.spec(), inp.read_image(oiio.FLOAT)
    inp.close()
    return {name: data[:, :, k] for k, name in enumerate(spec.channelnames)}, spec


@pytest.mark.parametrize("sampler", ["sobol", "independent"])
def test_adaptive_image_is_unbiased_and_the_sample_count_shows_where_samples_went(room, reference, tmp_path, sampler):
    result = render(str(room), RenderOptions(spp=CAP, seed=1, noise_threshold=T, adaptive_min_spp=MIN_SPP,
                                             aov=("sampleCount",), sampler=sampler))
    out = tmp_path / "a.exr"
    write_outputs(result, exr=str(out))
    ch, spec = _exr(out)
    ad = result.adaptive
    count = ch["sampleCount"]
    # The pass is both streams' samples per pixel; the image holds the image stream's.
    np.testing.assert_array_equal(count, ad.count(result.film))
    np.testing.assert_array_equal(result.film.count + ad.decision.count, count)
    assert spec.get_string_attribute("illum:sppRange") == f"{int(count.min())} {int(count.max())}"
    # Premise: easy and hard pixels. The sky (top right) agrees with itself and stops at the
    # minimum; some of the room never gets below the threshold and runs to the cap.
    assert np.all(count[:4, -4:] == MIN_SPP)
    assert (count == CAP).sum() >= 50 and (count == MIN_SPP).sum() >= 200
    assert result.stats["adaptive"]["pixels_stopped"] == int((ad.stopped_at > 0).sum())
    assert result.stats["rays"]["camera"] == int(count.sum())   # only active pixels were traced
    for c, name in enumerate("RGB"):
        np.testing.assert_array_equal(ch[name], result.film.mean()[:, :, c])

    every = np.ones(count.size, dtype=bool)
    early = ((ad.stopped_at > 0) & (ad.stopped_at < CAP))
    hard = early & (ad.stopped_at > MIN_SPP)
    assert early.sum() >= 500 and hard.sum() >= 100
    for pixels in (every, early, hard):
        p = _p(_z(result.film, reference, pixels))
        assert np.all(p > SIGNIFICANCE), p
    # The samples the rule decided from, as the textbook rule would keep them: a pixel stops
    # when its relative error happens to be small, i.e. its mean high -- biased, and seen with
    # independent numbers (the default sampler's stratified passes vary less, and so does that
    # selection bias: too little to see at this size).
    if sampler == "independent":
        assert np.all(_p(_z(ad.decision, reference, early)) < SIGNIFICANCE)


def test_a_pass_traces_only_the_active_pixels_on_both_routes(room):
    rays = {}
    for fast in (True, False):
        r = render(str(room), RenderOptions(spp=24, seed=3, noise_threshold=T, adaptive_min_spp=8,
                                            resolution=(12, 12), fast_path=fast))
        assert (r.stats["fast_path"] == "on") == fast
        total = r.adaptive.count(r.film)
        assert total.min() == 8 and total.max() == 24
        assert r.stats["rays"]["camera"] == int(total.sum())
        # The decision passes follow the schedule: a pixel's decision share is that of its count.
        np.testing.assert_array_equal(r.adaptive.decision.count, decisions(total))
        rays[fast] = total
    assert rays[True].sum() < 24 * 144


def test_the_threshold_comes_from_the_render_settings_and_the_flag_wins(room, tmp_path):
    p = tmp_path / "s.usda"
    stage = sky_room_stage(p, res=(8, 8))
    rs = stage.GetPrimAtPath("/Render/Settings")
    rs.CreateAttribute("illum:adaptive:noiseThreshold", Sdf.ValueTypeNames.Float).Set(0.25)
    rs.CreateAttribute("illum:adaptive:minSpp", Sdf.ValueTypeNames.Int).Set(12)
    stage.GetRootLayer().Save()
    r = render(str(p), RenderOptions(spp=16))
    assert (r.stats["adaptive"]["noise_threshold"], r.stats["adaptive"]["min_spp"]) == (0.25, 12)
    assert r.stats["pixel_filter"]["mode"] == "importance"
    r = render(str(p), RenderOptions(spp=16, noise_threshold=0.0))
    assert r.stats["adaptive"] is None and r.adaptive is None
    r = render(str(p), RenderOptions(spp=16, noise_threshold=0.5))
    assert r.stats["adaptive"]["noise_threshold"] == 0.5 and r.stats["adaptive"]["min_spp"] == 12
    r = render(str(room), RenderOptions(spp=4, noise_threshold=0.5, resolution=(4, 4)))
    assert r.stats["adaptive"]["min_spp"] == DEFAULT_MIN_SPP


def test_bad_adaptive_input_is_refused_naming_it(room, tmp_path):
    with pytest.raises(SettingsError, match="importance"):
        render(str(room), RenderOptions(spp=4, noise_threshold=0.1, pixel_filter_mode="splat"))
    _error(run("render", room, "-o", tmp_path / "o.exr", "--noise-threshold", "0.1", "--pixel-filter-mode",
               "splat"), "pixel_filter_mode", "importance")
    _error(run("render", room, "-o", tmp_path / "o.exr", "--noise-threshold", "-0.1"), "noise_threshold")
    _error(run("render", room, "-o", tmp_path / "o.exr", "--adaptive-min-spp", "0"), "adaptive_min_spp")
    p = tmp_path / "bad.usda"
    stage = sky_room_stage(p, res=(8, 8))
    stage.GetPrimAtPath("/Render/Settings").CreateAttribute("illum:adaptive:noiseThreshold",
                                                            Sdf.ValueTypeNames.Float).Set(2.0)
    stage.GetRootLayer().Save()
    _error(run("render", p, "-o", tmp_path / "o.exr"), "illum:adaptive:noiseThreshold", "/Render/Settings")


def test_passes_follow_the_image_samples_of_an_adaptive_render(room, tmp_path):
    """The first-hit passes replay the image stream's camera rays over the same active pixels:
    the same sample count per pixel, and a transparent sky taken out of the beauty exactly."""
    r = render(str(room), RenderOptions(spp=24, seed=2, noise_threshold=T, adaptive_min_spp=8, resolution=(12, 12),
                                        alpha_dome_transparent=True, aov=("sampleCount", "depth")))
    total = r.adaptive.count(r.film)
    assert total.min() < total.max()   # premise: the pixels stopped at different counts
    np.testing.assert_array_equal(r.aovs.passes.weight, r.film.count)
    out = tmp_path / "p.exr"
    write_outputs(r, exr=str(out))
    ch, _ = _exr(out)
    np.testing.assert_array_equal(ch["sampleCount"], total)
    sky = ch["A"] == 0.0
    assert sky.sum() >= 10
    for c in "RGB":
        assert np.all(np.abs(ch[c][sky]) <= 1e-6)
