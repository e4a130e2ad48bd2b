"""Dome portals and textured RectLights on the compiled path (renderer/integrators/fast_path.py)
estimate what the general integrator estimates.

Both routes call the same compiled rows: kernels/portal.py for a dome's sampling through its
portals and the pdf of a direction (DomeLight.sample_li and pdf_li run them row by row, the
vertex kernel inside its bounce), kernels/lights.py's rect_texel_* rows for a textured rect's
texel sampling, texel pdf and the texel colour a sample or a ray sees. The tests check that the
kernel applies them wherever the general path does: the light half of continuation MIS, the
per-light estimators' light and BSDF samples, and the MIS weight of a continuation ray that
escapes to the dome or crosses the rect. Renders with the compiled path and with
``fast_path=False`` (independent seeds) are z-tested over the whole image and in 16 blocks with
each film's own variance of the mean (test_fast_path._block_z). A wrong texel colour and a wrong
portal density must fail the same comparison.
"""

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, Usd, UsdLux

from renderer.integrators import fast_path as fp_mod
from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_MAX, _block_z, _room
from tests.integrators.test_fast_path_estimators import _check

WINDOW = "stages/lux_extra/window_portal.usda"


def _pair(stage, estimator, N=1, spp=64, res=(48, 36), seeds=(1, 8), **opt):
    common = dict(max_depth=3, rr_depth=1, threads=1, estimator={"": estimator}, light_samples={"": N}, spp=spp,
                  resolution=res, pixel_filter_mode="importance", **opt)
    fast = render(str(stage), RenderOptions(seed=seeds[0], **common))
    slow = render(str(stage), RenderOptions(seed=seeds[1], fast_path=False, **common))
    assert fast.stats["fast_path"] == "on"
    assert slow.stats["fast_path"].startswith("disabled")
    return fast, slow


@pytest.mark.parametrize("estimator,N", [("mis", 1), ("lightSampling", 2), ("bsdfSampling", 1),
                                         ("controlVariate", 3)])
def test_window_portal_on_the_compiled_path_matches_the_general_path(estimator, N):
    """stages/lux_extra/window_portal.usda: a textured sky with a sun, seen through one portal
    (the windowed luminance table, three quarters of the samples). The control variate has no
    exact F through a portal (irradiance.has_exact_integral), so both routes fall back to MIS."""
    _check(*_pair(WINDOW, estimator, N))


@pytest.mark.parametrize("kw,estimator,N", [
    ({"portal": True}, "mis", 1),                                # constant sky: the spherical rectangle
    ({"portal": True, "sky_texture": True}, "controlVariate", 3),
    ({"portal": True}, "lightSampling", 1),
])
def test_portal_rooms_on_the_compiled_path(tmp_path, kw, estimator, N):
    """test_fast_path's room with its sky's portal (a constant sky: every portal sample uniform
    in the window's solid angle; a lat-long one: the table) among rect lights and two distant
    lights."""
    stage = tmp_path / "room.usda"
    _room(stage, **kw)
    _check(*_pair(stage, estimator, N))


def _write_exr(path, px) -> str:
    buf = oiio.ImageBuf(np.ascontiguousarray(px, dtype=np.float32))
    assert buf.write(str(path), oiio.FLOAT), oiio.geterror()
    return str(path)


def _textured_rects(path, tmp_path, sky=False):
    """The room of test_fast_path (three rects, a sphere, a point and a disk light) with colour
    ramps and one bright texel on the big tilted rect and on the one behind the ball: the texel
    pick, the colour at a sample and the colour a ray crossing the rect sees all matter. sky: with
    the lat-long sky and the distant lights too (the rects' images then follow the dome's in the
    kernel's image set)."""
    _room(path, more_kinds=True, infinite=sky, sky_texture=sky)
    h, w = 6, 8
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([0.2 + x / w, 0.3 + y / h, 1.2 - x / w], axis=-1)
    img[1, 6] = (6.0, 4.0, 1.0)
    tex = _write_exr(tmp_path / "ramp.exr", img)
    stage = Usd.Stage.Open(str(path))
    for name in ("Big", "Back"):
        UsdLux.RectLight(stage.GetPrimAtPath(f"/World/{name}")).CreateTextureFileAttr(Sdf.AssetPath(tex))
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("estimator,N,opt,sky", [
    ("mis", 1, {}, False),                           # continuation MIS, the textured rects off the batch
    ("controlVariate", 3, {}, True),                 # no exact F: MIS with its own samples
    ("mis", 1, {"light_sampler": "bvh"}, False),     # one picked light per vertex
])
def test_textured_rects_on_the_compiled_path_match_the_general_path(tmp_path, estimator, N, opt, sky):
    stage = tmp_path / "room.usda"
    _textured_rects(stage, tmp_path, sky)
    _check(*_pair(stage, estimator, N, **opt))


def _broken(monkeypatch, edit):
    """FastPath with edit(fast_path) applied to its records after it is built."""
    orig = fp_mod.FastPath.__init__

    def broken(self, integ):
        orig(self, integ)
        old = (self.portal, self.texrect)
        edit(self)
        swap = {id(old[0]): self.portal, id(old[1]): self.texrect}
        self.tables = tuple(swap.get(id(t), t) for t in self.tables)

    monkeypatch.setattr(fp_mod.FastPath, "__init__", broken)


def test_the_comparison_detects_an_untextured_rect(tmp_path, monkeypatch):
    """With the rects' textures dropped from the kernel's record (their plain L at every sample
    and on every ray), the comparison fails."""
    stage = tmp_path / "room.usda"
    _textured_rects(stage, tmp_path)

    def untextured(fp):
        fp.texrect = np.full_like(fp.texrect, -1)

    _broken(monkeypatch, untextured)
    z, _ = _block_z(*_pair(stage, "mis"))
    assert abs(z) > Z_MAX, f"untextured rects went unseen (z = {z:.2f})"


def test_the_comparison_detects_a_wrong_portal_density(monkeypatch):
    """With the portal table's density tripled in the kernel's record (the samples still follow
    the prefix tables), the light samples through the window are weighed wrongly and the
    comparison fails."""

    def wrong(fp):
        PP, PT, start, count = fp.portal
        PT = PT.copy()
        PT[0::3] *= 3.0  # the f tables (kernels/portal.py: f of table t at 3 t)
        fp.portal = (PP, PT, start, count)

    _broken(monkeypatch, wrong)
    z, _ = _block_z(*_pair(WINDOW, "lightSampling"))
    assert abs(z) > Z_MAX, f"a wrong portal density went unseen (z = {z:.2f})"


def test_portal_and_textured_rect_stages_run_as_one_compiled_call(tmp_path):
    """Neither feature needs numpy work between bounces: the whole bounce loop is one
    trace_kernel call (FastPath.kernel_reason() == '')."""
    from renderer.camera import Camera
    from renderer.integrators.path import IntegratorOptions, PathIntegrator
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    stage = tmp_path / "room.usda"
    _textured_rects(stage, tmp_path, sky=True)
    for path in (WINDOW, stage):
        scene = build_scene(load_stage(str(path)), threads=1)
        try:
            integ = PathIntegrator(scene, Camera(scene.desc.camera, 8, 8), IntegratorOptions(threads=1))
            assert integ.fast is not None and integ.fast.kernel_reason() == "", path
        finally:
            scene.close()
