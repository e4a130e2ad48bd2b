"""Render passes (renderer/aov.py) and the beauty's alpha, read back from the EXR with
OpenImageIO: RenderVar channel names, coverage on a known silhouette, first-hit values on a
plane whose answers are exact, one warning per unsupported RenderVar, the transparent dome, and
OIDN lowering the error where the answer is known (a white furnace)."""

import math
import sys

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, UsdRender

from renderer.errors import SettingsError
from renderer.render import RenderOptions, render, write_outputs
from tests.stage_builders import add_camera, add_settings, bind, furnace_stage, new_stage, preview_material, \
    quad_light_stage

from .test_cli import _error
from .test_outputs import run


def _exr(path) -> dict:
    """{channel name: (H, W) float32} of an EXR, as OpenImageIO reads it."""
    inp = oiio.ImageInput.open(str(path))
    spec, data = inp.spec(), inp.read_image(oiio.FLOAT)
    inp.close()
    return {name: data[:, :, k] for k, name in enumerate(spec.channelnames)}, spec


def _add_vars(stage, specs, product_name="out.exr"):
    """A RenderProduct on /Render/Settings with orderedVars (name, sourceName, sourceType, dataType)."""
    prod = UsdRender.Product.Define(stage, "/Render/Product")
    prod.CreateProductNameAttr(product_name)
    paths = []
    for name, src, kind, dtype in specs:
        v = UsdRender.Var.Define(stage, f"/Render/Vars/{name}")
        v.CreateSourceNameAttr(src)
        v.CreateSourceTypeAttr(kind)
        v.CreateDataTypeAttr(dtype)
        paths.append(v.GetPath())
    prod.CreateOrderedVarsRel().SetTargets(paths)
    UsdRender.Settings(stage.GetPrimAtPath("/Render/Settings")).CreateProductsRel().SetTargets([prod.GetPath()])
    stage.GetRootLayer().Save()


def _render(stage_path, out, **opts):
    result = render(str(stage_path), RenderOptions(**opts))
    write_outputs(result, exr=str(out))
    return result, _exr(out)


# The furnace stage's camera: focal 35 mm, aperture 36 mm, 4 units from a unit sphere on its axis.
def _disk_radius_px(res: int) -> float:
    return 35.0 / math.sqrt(4.0 ** 2 - 1.0) / 36.0 * res


def test_render_vars_become_named_channels_and_lpes_warn_once(tmp_path):
    p = tmp_path / "f.usda"
    stage = furnace_stage(p, L=1.0, rho=0.8, res=(16, 16))
    _add_vars(stage, [("beauty", "Ci", "raw", "color3f"), ("a", "a", "raw", "float"),
                      ("albedo", "albedo", "raw", "color3f"), ("N", "N", "raw", "normal3f"),
                      ("Nc", "Nc", "raw", "normal3f"), ("depth", "Pz", "raw", "float"), ("P", "P", "raw", "point3f"),
                      ("primId", "primId", "raw", "int"), ("matId", "materialId", "raw", "int"),
                      ("spp", "sampleCount", "raw", "int"), ("diffuse", "C<RD>L", "lpe", "color3f"),
                      ("specular", "C<RS>L", "lpe", "color3f"), ("uv", "st", "primvar", "float2")])
    result, (ch, spec) = _render(p, tmp_path / "o.exr", spp=2)
    assert set(ch) == {"R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z", "Nc.X", "Nc.Y",
                       "Nc.Z", "depth", "P.X", "P.Y", "P.Z", "primId", "matId", "spp"}
    assert spec.channelnames[spec.alpha_channel] == "A"
    assert np.all(ch["spp"] == 2)
    for var in ("/Render/Vars/diffuse", "/Render/Vars/specular", "/Render/Vars/uv"):
        said = [w for w in result.stats["warnings"] if var + ":" in w]
        assert len(said) == 1, (var, result.stats["warnings"])
    assert not any("/Render/Vars/albedo" in w for w in result.stats["warnings"])
    # ids: the sphere is gprim 0 and material 0 where the pixel's nearest sample hits it
    centre = ch["primId"][8, 8], ch["matId"][8, 8], ch["primId"][0, 0]
    assert centre == (0.0, 0.0, -1.0)
    assert '"/World/Ball"' in str(result.metadata["illum:primPaths"]) or \
        list(result.metadata["illum:primPaths"]) == ["/World/Ball"]


def test_data_type_that_does_not_fit_the_source_is_an_error(tmp_path):
    p = tmp_path / "f.usda"
    stage = furnace_stage(p, res=(8, 8))
    _add_vars(stage, [("albedo", "albedo", "raw", "float")])
    with pytest.raises(Exception, match=r"dataType float has 1 components.*albedo"):
        render(str(p), RenderOptions(spp=1))


def test_alpha_on_a_sphere_silhouette(tmp_path):
    """A unit sphere over nothing, box filter, filter importance sampling: each pixel's alpha is
    the mean of hit indicators at points uniform in the pixel, so it is exactly 1 where the pixel
    lies inside the projected disk, exactly 0 outside, in between on the edge, and the alphas sum
    to the disk's area in pixels (z-test against the Bernoulli variance of each pixel)."""
    res, spp = 32, 64
    p = tmp_path / "s.usda"
    stage = new_stage(p)
    add_camera(stage, pos=(0, 0, 4))
    add_settings(stage, (res, res))
    from pxr import UsdGeom

    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(1.0)
    bind(ball.GetPrim(), preview_material(stage, "/World/Looks/Grey"))
    stage.GetRootLayer().Save()
    _, (ch, _) = _render(p, tmp_path / "o.exr", spp=spp, alpha=True, pixel_filter="box",
                         pixel_filter_mode="importance")
    a = ch["A"]
    R = _disk_radius_px(res)
    y, x = np.mgrid[0:res, 0:res] + 0.5
    r = np.hypot(x - res / 2, y - res / 2)
    half_diag = math.sqrt(0.5)
    assert np.all(a[r < R - half_diag - 0.05] == 1.0)
    assert np.all(a[r > R + half_diag + 0.05] == 0.0)
    edge = (r > R - 0.3) & (r < R + 0.3)
    assert np.all((a[edge] > 0.0) & (a[edge] < 1.0))
    var = a * (1.0 - a) / spp
    z = (a.sum() - math.pi * R * R) / math.sqrt(var.sum())
    assert abs(z) < 4.0, z


def test_first_hit_values_on_a_plane(tmp_path):
    """quad_light_stage: the camera 6 above a 0.5-grey floor, looking straight down; the rect
    light between them is crossed by the camera rays (lights add no coverage)."""
    p = tmp_path / "q.usda"
    quad_light_stage(p, res=(16, 12))
    _, (ch, _) = _render(p, tmp_path / "o.exr", spp=3, alpha=True,
                         aov=("albedo", "N", "normalCamera", "Z", "P", "materialId"))
    assert np.all(ch["A"] == 1.0)
    for c in "RGB":
        np.testing.assert_allclose(ch[f"albedo.{c}"], 0.5, rtol=1e-6)
    np.testing.assert_allclose(np.stack([ch["N.X"], ch["N.Y"], ch["N.Z"]], -1), np.broadcast_to([0, 1, 0], (12, 16, 3)),
                               atol=1e-6)
    np.testing.assert_allclose(np.stack([ch[f"normalCamera.{c}"] for c in "XYZ"], -1),
                               np.broadcast_to([0, 0, 1], (12, 16, 3)), atol=1e-6)
    np.testing.assert_allclose(ch["Z"], 6.0, rtol=1e-6)
    np.testing.assert_allclose(ch["P.Y"], 0.0, atol=1e-6)
    # P is the mean hit point of the pixel's samples: inside the visible floor (the aperture is
    # expanded to the 4:3 image), growing along the image's x (world +X) and y (world +Z)
    half = 6.0 * 18.0 / 35.0
    assert np.all(np.abs(ch["P.X"]) < half * 16 / 12) and np.all(np.abs(ch["P.Z"]) < half)
    assert np.all(np.diff(ch["P.X"].mean(axis=0)) > 0.0) and np.all(np.diff(ch["P.Z"].mean(axis=1)) > 0.0)
    assert np.all(ch["materialId"] == 0.0)


@pytest.mark.parametrize("how", ["flag", "schema"])
def test_transparent_dome(tmp_path, how):
    """Furnace (sphere in a dome of radiance 1): with the dome transparent, pixels that see only
    the dome are exactly (0, 0, 0, 0), and inside the sphere RGB and alpha are what they are with
    the dome opaque (the same samples: seed and passes equal)."""
    p = tmp_path / "f.usda"
    stage = furnace_stage(p, L=1.0, rho=0.5, res=(24, 24))
    opts = dict(spp=4, alpha=True)
    if how == "schema":
        attr = stage.GetPrimAtPath("/Render/Settings").CreateAttribute("illum:alpha:domeTransparent",
                                                                        Sdf.ValueTypeNames.Bool)
        attr.Set(True)
        stage.GetRootLayer().Save()
    else:
        opts["alpha_dome_transparent"] = True
    _, (clear, _) = _render(p, tmp_path / "c.exr", **opts)
    opaque = dict(opts, alpha_dome_transparent=False)
    _, (solid, _) = _render(p, tmp_path / "s.exr", **opaque)
    corner = (slice(0, 3), slice(0, 3))
    for c in "RGBA":
        assert np.all(clear[c][corner] == 0.0)
    np.testing.assert_allclose(solid["R"][corner], 1.0, rtol=1e-6)
    inside = (slice(10, 14), slice(10, 14))
    assert np.all(clear["A"][inside] == 1.0)
    for c in "RGB":
        np.testing.assert_allclose(clear[c][inside], solid[c][inside], rtol=1e-5)


def test_aov_flag_rejects_unknown_names(tmp_path):
    p = tmp_path / "q.usda"
    quad_light_stage(p, res=(8, 8))
    r = run("render", p, "-o", tmp_path / "o.exr", "--aov", "albedo,C<RD>L", "--spp", 1)
    assert r.returncode == 2 and "aov" in _error(r) and "C<RD>L" in _error(r)
    assert not (tmp_path / "o.exr").exists()


def test_cli_aov_flag_writes_layers(tmp_path):
    p = tmp_path / "q.usda"
    quad_light_stage(p, res=(8, 8))
    r = run("render", p, "-o", tmp_path / "o.exr", "--aov", "albedo", "--aov", "Z", "--spp", 1, "--quiet")
    assert r.returncode == 0, r.stderr
    ch, _ = _exr(tmp_path / "o.exr")
    assert set(ch) == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "Z"}


def test_denoise_without_oidn_is_refused_before_rendering(tmp_path, monkeypatch):
    """pyoidn missing (an import that fails, as on a machine without the extra): a SettingsError
    naming --denoise and the package, raised before the stage is loaded."""
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    with pytest.raises(SettingsError, match="pyoidn") as e:
        render(str(tmp_path / "never-read.usda"), RenderOptions(denoise=True, spp=1))
    assert e.value.attribute == "denoise"


def test_denoiser_lowers_the_error_in_a_white_furnace(tmp_path):
    """A white sphere in a constant dome of radiance L: every pixel converges to L, so the
    error of the raw and the denoised beauty is known without a reference render."""
    pytest.importorskip("pyoidn", reason="pyoidn (illum[denoise]) is not installed")
    p = tmp_path / "f.usda"
    furnace_stage(p, L=1.0, rho=1.0, res=(48, 48))
    # Filter importance sampling: each pixel's noise its own, as OIDN expects (a splatted film's
    # noise is correlated across neighbours, which OIDN keeps as detail; bench/bench_denoise.py)
    result, (ch, _) = _render(p, tmp_path / "o.exr", spp=2, denoise=True, pixel_filter_mode="importance")
    raw = np.stack([ch[c] for c in "RGB"], -1)
    den = np.stack([ch[f"denoised.{c}"] for c in "RGB"], -1)
    err_raw = np.mean((raw - 1.0) ** 2)
    err_den = np.mean((den - 1.0) ** 2)
    assert err_raw > 1e-4  # there is noise to remove
    assert err_den < 0.3 * err_raw, (err_raw, err_den)
    assert result.stats["seconds"]["denoise"] > 0.0


@pytest.mark.parametrize("threshold, expected", [(0.0, 0.3), (0.2, 1.0), (0.5, 0.0)])
def test_cut_outs_are_transparent(tmp_path, threshold, expected):
    """The floor that fills the image with opacity 0.3: a cut-out (opacityThreshold 0.2: present,
    0.5: absent) gives alpha exactly 1 or 0; without threshold each camera ray passes with
    probability 0.7, so with a box filter and filter importance sampling every pixel's alpha is a
    mean of independent Bernoulli(0.3) draws (z-test on the image mean)."""
    p = tmp_path / "q.usda"
    stage = quad_light_stage(p, res=(16, 16))
    shader = stage.GetPrimAtPath("/World/Looks/Grey/PBR")
    shader.CreateAttribute("inputs:opacity", Sdf.ValueTypeNames.Float).Set(0.3)
    shader.CreateAttribute("inputs:opacityThreshold", Sdf.ValueTypeNames.Float).Set(threshold)
    stage.GetRootLayer().Save()
    spp = 8
    _, (ch, _) = _render(p, tmp_path / "o.exr", spp=spp, alpha=True, pixel_filter="box",
                         pixel_filter_mode="importance")
    a = ch["A"]
    if expected in (0.0, 1.0):
        assert np.all(a == expected)
        return
    z = (a.mean() - expected) / math.sqrt(expected * (1 - expected) / (spp * a.size))
    assert abs(z) < 4.0, (a.mean(), z)
