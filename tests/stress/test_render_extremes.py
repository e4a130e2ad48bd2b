"""Whole renders of extreme stages (issue #8, stress item): invariants of the image.

* Geometry 1e5 units from the origin renders like the same stage at the origin (means agree
  within noise, no dark speckle).
* Light intensities 1e-20..1e20 with light and camera exposures in [-60, 60]: no NaN or Inf
  pixel, and the image scales exactly linearly while it stays within float32's range; above
  it (~3.4e38) the film must not hold or write Inf.
* colorTemperature outside [1000, 10000] K: a warning, the clamped value is used, it renders.
* Degenerate lights (zero width, height or radius, zero scale) are skipped with a warning and
  the stage still renders.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from pxr import Gf, UsdGeom, UsdLux

from renderer.description import LightDesc
from renderer.errors import IllumError, StageError
from renderer.lights.light_set import LightSet
from renderer.render import RenderOptions, render, write_outputs
from tests.stress.budget import examples
from tests.stress.record import note
from tests.stress.stages import penumbra_stage

pytestmark = pytest.mark.slow

F32_MAX = float(np.finfo(np.float32).max)


def _render(path, **opt):
    kw = dict(spp=8, threads=1, max_depth=2, seed=3)
    kw.update(opt)
    return render(str(path), RenderOptions(**kw))


def _assert_clean(film, label=""):
    img = film.mean()
    assert np.all(np.isfinite(img)), f"NaN/Inf pixel {label}"
    assert film.nonfinite_dropped == 0, f"{film.nonfinite_dropped} non-finite samples dropped {label}"
    return img


# --------------------------------------------------------------------------------------
# Far from the origin
# --------------------------------------------------------------------------------------


def _compare_to_origin(tmp_path, offset, estimator, spp=32):
    a = tmp_path / "origin.usda"
    b = tmp_path / "far.usda"
    penumbra_stage(a)
    penumbra_stage(b, offset=offset)
    # Filter importance sampling: each sample lands in one pixel, so pixels are independent and
    # their variances add up to the image mean's (a splatting film shares samples between
    # neighbours, whose errors then correlate).
    opt = dict(spp=spp, max_depth=2, seed=11, estimator={"": estimator}, pixel_filter_mode="importance")
    ra, rb = _render(a, **opt), _render(b, **opt)
    ia, ib = _assert_clean(ra.film)[..., 1], _assert_clean(rb.film, "far from the origin")[..., 1]
    # z-test of the image means (each pixel's variance estimated by the film).
    va = ra.film.variance_of_mean()[..., 1].sum() / ia.size ** 2
    vb = rb.film.variance_of_mean()[..., 1].sum() / ib.size ** 2
    z = (ib.mean() - ia.mean()) / math.sqrt(va + vb)
    # Dark speckle (acne): pixels much darker far away than at the origin where the origin
    # render is clearly lit, by more than Monte Carlo noise explains (4 sigma of the pixel
    # difference): acne is a systematic loss, while a noisy estimator (BSDF sampling at 32
    # spp) halves single pixels by chance.
    lit = ia > 0.25 * ia.max()
    sigma = np.sqrt(ra.film.variance_of_mean()[..., 1] + rb.film.variance_of_mean()[..., 1])
    dark = float(((ib < 0.5 * ia) & (ia - ib > 4.0 * sigma) & lit).sum() / max(lit.sum(), 1))
    note(f"far from origin |z| of image mean ({estimator})", abs(z), f"offset {offset}")
    note(f"far from origin dark-pixel fraction ({estimator})", dark, f"offset {offset}")
    return z, dark, ia.mean(), ib.mean()


@pytest.mark.parametrize("estimator", ["lightSampling", "mis", "bsdfSampling"])
def test_stage_1e5_from_the_origin_renders_like_at_the_origin(tmp_path, estimator):
    z, dark, ma, mb = _compare_to_origin(tmp_path, (1e5, 7e4, -3e4), estimator)
    assert abs(z) < 5.0, f"image mean {mb:.5f} far from the origin vs {ma:.5f} at it (z = {z:.1f})"
    assert dark < 0.01, f"{dark:.1%} of the lit pixels are dark speckle far from the origin"


@examples(default=3, long=30)
@given(exponent=st.floats(min_value=2.0, max_value=5.0),
       direction=st.tuples(*[st.floats(min_value=-1.0, max_value=1.0)] * 3).filter(lambda v: sum(x * x for x in v) > 0.1),
       estimator=st.sampled_from(["lightSampling", "mis"]))
@example(exponent=math.log10(math.sqrt(1e10 + 4.9e9 + 9e8)), direction=(1.0, 0.7, -0.3), estimator="lightSampling")
def test_random_offsets_render_like_at_the_origin(tmp_path_factory, exponent, direction, estimator):
    tmp_path = tmp_path_factory.mktemp("far")
    n = math.sqrt(sum(x * x for x in direction))
    offset = tuple(10.0 ** exponent * x / n for x in direction)
    z, dark, ma, mb = _compare_to_origin(tmp_path, offset, estimator, spp=16)
    assert abs(z) < 5.3, f"offset {offset}: image mean {mb:.5f} vs {ma:.5f} (z = {z:.1f})"
    assert dark < 0.01, f"offset {offset}: {dark:.1%} dark speckle"


@examples(default=3, long=40)
@given(exponent=st.floats(min_value=0.0, max_value=3.0),
       direction=st.tuples(*[st.floats(min_value=-1.0, max_value=1.0)] * 3).filter(lambda v: sum(x * x for x in v) > 0.1))
def test_moderate_offsets_light_sampling(tmp_path_factory, exponent, direction):
    """Up to 1e3 units away light sampling (no BSDF-sampled light hits) is still exact."""
    tmp_path = tmp_path_factory.mktemp("near")
    n = math.sqrt(sum(x * x for x in direction))
    offset = tuple(10.0 ** exponent * x / n for x in direction)
    z, dark, ma, mb = _compare_to_origin(tmp_path, offset, "lightSampling", spp=16)
    assert abs(z) < 5.3, f"offset {offset}: image mean {mb:.5f} vs {ma:.5f} (z = {z:.1f})"
    assert dark < 0.01, f"offset {offset}: {dark:.1%} dark speckle"


# --------------------------------------------------------------------------------------
# Intensity and exposure
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def unit_image(tmp_path_factory):
    """The reference render at intensity 1, exposures 0 (every scaled render uses the same seed,
    so its paths, and hence its image, differ only by the scale)."""
    path = tmp_path_factory.mktemp("unit") / "unit.usda"
    penumbra_stage(path, intensity=1.0)
    img = _assert_clean(_render(path).film)
    assert img.max() > 0.1
    return img


@examples(default=8, long=200)
@given(log_intensity=st.floats(min_value=-20.0, max_value=20.0),
       light_exposure=st.floats(min_value=-60.0, max_value=60.0),
       camera_exposure=st.floats(min_value=-60.0, max_value=60.0))
def test_image_scales_linearly_with_intensity_and_exposure(tmp_path_factory, unit_image, log_intensity,
                                                           light_exposure, camera_exposure):
    # UsdLux intensity/exposure and UsdGeomCamera exposure are float attributes: the stage holds
    # the float32-rounded values, so the expected scale is computed from those.
    f32 = lambda v: float(np.float32(v))  # noqa: E731
    intensity = f32(10.0 ** log_intensity)
    light_exposure, camera_exposure = f32(light_exposure), f32(camera_exposure)
    scale = intensity * 2.0 ** light_exposure * 2.0 ** camera_exposure
    peak = scale * float(unit_image.max())
    if peak > 0.5 * F32_MAX:
        return  # beyond float32: test_film_beyond_float32_range
    path = tmp_path_factory.mktemp("scale") / "s.usda"
    penumbra_stage(path, intensity=intensity, light_exposure=light_exposure, camera_exposure=camera_exposure)
    img = _assert_clean(_render(path).film, f"at scale {scale:.3g}")
    assert np.all(img >= 0.0)
    label = f"intensity {intensity:.3g}, exposures {light_exposure:.3g} / {camera_exposure:.3g}"
    tiny = float(np.finfo(np.float32).tiny)
    if peak * 1e-6 >= tiny:
        # Every pixel value above float32's normal range: exact scaling to float32 rounding
        # (pixels below 1e-6 of the peak may sit in the subnormal range and are skipped).
        mask = unit_image * scale >= tiny / np.finfo(np.float32).eps
        rel = np.abs(img[mask] / (unit_image[mask] * scale) - 1.0)
        err = float(rel.max()) if rel.size else 0.0
        note("intensity/exposure scaling, max rel error", err, label)
        assert err < 1e-6, f"image does not scale linearly (rel error {err:.3g}): {label}"
    else:
        # Underflow: float32 cannot hold these values; they must come out as 0 or tiny, never NaN.
        note("intensity/exposure below float32 normals (finite only)", 0.0, label)
        assert float(img.max()) <= 2.0 * peak + tiny


def test_film_beyond_float32_range(tmp_path):
    path = tmp_path / "hot.usda"
    penumbra_stage(path, intensity=1e20, light_exposure=60.0, camera_exposure=60.0)
    r = _render(path, spp=2)
    assert r.film.nonfinite_dropped == 0
    try:
        write_outputs(r, exr=str(tmp_path / "hot.exr"))
    except IllumError:
        return  # a clear, user-facing refusal is acceptable
    from renderer.film import read_exr

    img, _ = read_exr(str(tmp_path / "hot.exr"))
    assert np.all(np.isfinite(img)), "the EXR holds Inf"
    assert np.all(np.isfinite(r.film.mean())), "the film's mean holds Inf"


@pytest.mark.parametrize("exposure", [1100.0, 2000.0])
def test_huge_finite_light_exposure_is_a_stage_error(tmp_path, exposure):
    path = tmp_path / "e.usda"
    penumbra_stage(path, light_exposure=exposure)
    with pytest.raises(StageError) as err:
        _render(path, spp=1)
    assert err.value.prim == "/World/Light"


# --------------------------------------------------------------------------------------
# colorTemperature
# --------------------------------------------------------------------------------------
@examples(default=4, long=60)
@given(temperature=st.one_of(st.floats(min_value=0.0, max_value=999.0),
                             st.floats(min_value=10001.0, max_value=1e7)))
def test_color_temperature_out_of_range_is_clamped_with_a_warning(tmp_path_factory, temperature):
    tmp_path = tmp_path_factory.mktemp("ct")
    images = {}
    for name, T in (("out", temperature), ("clamped", 1000.0 if temperature < 1000.0 else 10000.0)):
        path = tmp_path / f"{name}.usda"
        stage = penumbra_stage(path)
        light = UsdLux.RectLight(stage.GetPrimAtPath("/World/Light"))
        light.CreateEnableColorTemperatureAttr(True)
        light.CreateColorTemperatureAttr(float(T))
        stage.GetRootLayer().Save()
        r = _render(path, spp=2)
        images[name] = _assert_clean(r.film)
        if name == "out":
            assert any("/World/Light" in w and "colorTemperature" in w and "clamp" in w for w in r.warnings), r.warnings
            assert any("colorTemperature" in w for w in r.stats["warnings"])
    np.testing.assert_array_equal(images["out"], images["clamped"])
    note("colorTemperature out of range (renders, clamped)", 0.0, f"T = {temperature:g}")


# --------------------------------------------------------------------------------------
# Degenerate lights
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind,attrs", [
    ("rect", dict(width=0.0)), ("rect", dict(height=0.0)), ("disk", dict(radius=0.0)),
    ("sphere", dict(radius=0.0)),
])
def test_degenerate_light_descs_are_dropped_with_a_warning(kind, attrs):
    """At the LightSet (descriptions that did not come through the USD reader)."""
    good = LightDesc("/Good", "sphere", np.eye(4), radius=0.5)
    bad = LightDesc("/Bad", kind, np.eye(4), **attrs)
    lights = LightSet.build([bad, good], np.zeros(3), 1.0)
    assert lights.dropped == ["/Bad"] and lights.paths == ["/Good"]
    assert any("/Bad" in w and "degenerate" in w for w in lights.warnings)


@pytest.mark.parametrize("kind", ["rect", "disk", "sphere"])
def test_zero_scale_light_is_dropped_with_a_warning(kind):
    m = np.diag([0.0, 1.0, 1.0, 1.0]) if kind != "sphere" else np.diag([0.0, 0.0, 0.0, 1.0])
    lights = LightSet.build([LightDesc("/Flat", kind, m)], np.zeros(3), 1.0)
    assert lights.count == 0 and lights.dropped == ["/Flat"]
    assert any("/Flat" in w for w in lights.warnings)


@pytest.mark.parametrize("kind,attr", [
    ("rect", "inputs:width"), ("rect", "inputs:height"), ("disk", "inputs:radius"), ("sphere", "inputs:radius"),
    ("rect", "scale"), ("sphere", "scale"),
])
def test_stage_with_a_degenerate_light_renders(tmp_path, kind, attr):
    """The degenerate light is skipped with a warning naming it, the other light still lights
    the floor, and nothing non-finite appears."""
    path = tmp_path / "d.usda"
    stage = penumbra_stage(path, occluder=False)
    schema = {"rect": UsdLux.RectLight, "disk": UsdLux.DiskLight, "sphere": UsdLux.SphereLight}[kind]
    bad = schema.Define(stage, "/World/Bad")
    bad.CreateIntensityAttr(100.0)
    if attr == "scale":
        UsdGeom.Xformable(bad).AddScaleOp().Set(Gf.Vec3f(0.0, 0.0, 0.0))
    else:
        bad.GetPrim().GetAttribute(attr).Set(0.0)
    UsdGeom.Xformable(bad).AddTranslateOp().Set(Gf.Vec3d(1, 2, 0))
    stage.GetRootLayer().Save()
    r = _render(path, spp=2)
    img = _assert_clean(r.film)
    assert img.max() > 0.0
    assert [li["path"] for li in r.stats["lights"]] == ["/World/Light"]
    assert any("/World/Bad" in w for w in r.warnings), r.warnings
    note("degenerate light stages rendered", 0.0)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_zero_size_is_a_skip_but_a_non_finite_size_is_an_error(tmp_path, value):
    """Zero size: skipped with a warning (above); a non-finite size: an error naming the attribute."""
    path = tmp_path / "n.usda"
    stage = penumbra_stage(path, occluder=False)
    UsdLux.RectLight(stage.GetPrimAtPath("/World/Light")).GetWidthAttr().Set(value)
    stage.GetRootLayer().Save()
    with pytest.raises(StageError) as err:
        _render(path, spp=1)
    assert (err.value.prim, err.value.attribute) == ("/World/Light", "inputs:width")
