"""UsdLux ShapingAPI, ShadowAPI and light linking on the compiled path (renderer/integrators/
fast_path.py) estimate what the general integrator estimates.

The room of test_fast_path.py (three rect lights, a sphere, a point and a disk light) gets cones,
focus and an IES profile on its lights; renders with the compiled path and with
``fast_path=False`` are z-tested as in test_fast_path.py (whole image and 16 blocks, each film's
own variance of the mean). Both routes call the same shaping factor (kernels/shaping.py), so the
tests check that the kernel applies it wherever the general path does: light samples of the
batched rect and sphere samplers and of the row samplers, the per-light estimators' light and
BSDF samples, and the emission that camera and continuation rays see.
"""

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_MAX, _block_z, _room
from tests.integrators.test_fast_path_materials import _card_stage, _check
from tests.stage_builders import add_quad, preview_material

IES = os.path.abspath("stages/ies/narrow_spot.ies")


def _shape(path):
    """Cones, focus and an IES profile on the room's lights (test_fast_path._room, more_kinds)."""
    stage = Usd.Stage.Open(str(path))
    for name, attrs in (
            ("Big", {"cone:angle": 35.0, "cone:softness": 0.3}),
            ("Sheared", {"focus": 3.0, "focusTint": Gf.Vec3f(0.2, 0.5, 1.0)}),
            ("Bulb", {"cone:angle": 60.0, "cone:softness": 0.5}),
            ("Point", {"ies:file": IES, "ies:normalize": True}),
            ("Disk", {"cone:angle": 25.0, "cone:softness": 0.0, "focus": 2.0})):
        prim = stage.GetPrimAtPath(f"/World/{name}")
        api = UsdLux.ShapingAPI.Apply(prim)
        for key, value in attrs.items():
            if key == "ies:file":
                api.GetShapingIesFileAttr().Set(Sdf.AssetPath(value))
            elif key == "ies:normalize":
                api.GetShapingIesNormalizeAttr().Set(value)
            elif key == "focusTint":
                api.GetShapingFocusTintAttr().Set(value)
            elif key == "focus":
                api.GetShapingFocusAttr().Set(value)
            elif key == "cone:angle":
                api.GetShapingConeAngleAttr().Set(value)
            else:
                api.GetShapingConeSoftnessAttr().Set(value)
    # The point light aims down at the floor (its axis is local -Z).
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Point")).AddRotateXOp().Set(-90.0)
    stage.GetRootLayer().Save()


def _pair(stage, max_depth, spp, **opt):
    common = dict(max_depth=max_depth, rr_depth=1, threads=1, spp=spp, pixel_filter_mode="importance")
    common.update(opt)
    fast = render(str(stage), RenderOptions(seed=1, **common))
    slow = render(str(stage), RenderOptions(seed=8, fast_path=False, **common))
    return fast, slow


@pytest.mark.parametrize("opt", [
    {"estimator": {"": "mis"}},                                # continuation MIS, batched samplers
    # the estimators' own samples at depth 0 (heavy: the N-sample rows run in the linking and
    # ShadowAPI tests by default)
    pytest.param({"estimator": {"": "mis"}, "light_samples": {"": 3}}, marks=pytest.mark.heavy),
    {"estimator": {"": "lightSampling"}},
    {"estimator": {"": "bsdfSampling"}},
    {"estimator": {"": "mis"}, "light_sampler": "bvh"},        # one picked light per vertex
])
def test_shaped_lights_on_the_compiled_path_match_the_general_path(tmp_path, opt):
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _shape(stage)
    fast, slow = _pair(stage, 4, 192, **opt)
    _check(fast, slow)


def _detect(monkeypatch, stage, edit, what):
    """A defect edit(fast_path) made to the compiled route after it is built must show in the
    z-test against the general path (the tests that compare the two can fail)."""
    from renderer.integrators import fast_path as fp_mod

    orig = fp_mod.FastPath.__init__

    def broken(self, integ):
        orig(self, integ)
        lux = self.lux
        edit(self)
        self.tables = tuple(self.lux if t is lux else t for t in self.tables)

    monkeypatch.setattr(fp_mod.FastPath, "__init__", broken)
    fast, slow = _pair(stage, 3, 64, estimator={"": "mis"})
    assert fast.stats["fast_path"] == "on"
    z, _ = _block_z(fast, slow)
    assert abs(z) > Z_MAX, f"{what} went unseen (z = {z:.2f})"


def test_the_shaping_comparison_detects_a_missing_factor(tmp_path, monkeypatch):
    """With the kernel's shaping factor dropped, the compiled route lights the room as if the
    cones were not there."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _shape(stage)

    def unshaped(fp):
        fp.lux = (np.full_like(fp.lux[0], -1),) + tuple(fp.lux[1:])

    _detect(monkeypatch, stage, unshaped, "an unshaped kernel")


@pytest.mark.parametrize("stage", ["stages/shaping/spotlights.usda"])
def test_shaping_stages_on_the_compiled_path(stage):
    """The shaping stage (42 small sphere spots, cones and three IES profiles) with its own
    lighting service."""
    fast, slow = _pair(stage, 3, 48, resolution=(64, 36), emitter_samples=1)
    _check(fast, slow)


def _link(path, light_link=(), shadow_link=()):
    """lightLink and shadowLink exclusions on the room's lights: (light, excluded prim) pairs."""
    stage = Usd.Stage.Open(str(path))
    for pairs, get in ((light_link, "GetLightLinkCollectionAPI"), (shadow_link, "GetShadowLinkCollectionAPI")):
        for light, prim in pairs:
            api = UsdLux.LightAPI(stage.GetPrimAtPath(f"/World/{light}"))
            getattr(api, get)().CreateExcludesRel().AddTarget(f"/World/{prim}")
    stage.GetRootLayer().Save()


LINKS = dict(light_link=(("Big", "Ball"), ("Disk", "Floor"), ("Bulb", "Wall")),
             shadow_link=(("Big", "Chrome"), ("Point", "Ball")))


@pytest.mark.parametrize("opt", [
    {"estimator": {"": "mis"}},
    # Heavy: the control variate's groups over shadow groups run in the ShadowAPI test by default.
    pytest.param({"estimator": {"": "mis"}, "light_samples": {"": 3}}, marks=pytest.mark.heavy),
    pytest.param({"estimator": {"": "controlVariate"}, "light_samples": {"": 4}}, marks=pytest.mark.heavy),
    {"estimator": {"": "mis"}, "light_sampler": "power"},
])
def test_light_linking_on_the_compiled_path_matches_the_general_path(tmp_path, opt):
    """lightLink (a light skips the excluded meshes at every vertex, and a continuation ray that
    left an excluded mesh adds none of that light's emission) and shadowLink (the excluded meshes
    cast no shadow from that light: its own BVH, scene.shadow_accels)."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _link(stage, **LINKS)
    fast, slow = _pair(stage, 4, 192, **opt)
    _check(fast, slow)


def test_the_linking_comparison_detects_ignored_links(tmp_path, monkeypatch):
    """A kernel that ignores lightLink lights the excluded meshes."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _link(stage, light_link=LINKS["light_link"])

    def unlinked(fp):
        fp.lux = tuple(fp.lux[:3]) + (np.zeros((0, 0), dtype=bool),) + tuple(fp.lux[4:])

    _detect(monkeypatch, stage, unlinked, "ignored light links")


def _shadow_api(path, settings):
    """ShadowAPI inputs on the room's lights: {light: {enable, color, distance, falloff, gamma}}."""
    stage = Usd.Stage.Open(str(path))
    for light, attrs in settings.items():
        api = UsdLux.ShadowAPI.Apply(stage.GetPrimAtPath(f"/World/{light}"))
        for key, value in attrs.items():
            {"enable": api.CreateShadowEnableAttr, "color": api.CreateShadowColorAttr,
             "distance": api.CreateShadowDistanceAttr, "falloff": api.CreateShadowFalloffAttr,
             "gamma": api.CreateShadowFalloffGammaAttr}[key](Gf.Vec3f(*value) if key == "color" else value)
    stage.GetRootLayer().Save()


SHADOWS = {"Big": {"color": (0.1, 0.3, 0.9)}, "Bulb": {"distance": 1.2, "falloff": 0.6, "gamma": 2.0},
           "Point": {"enable": False}, "Disk": {"distance": 0.8}}


@pytest.mark.parametrize("opt", [
    {"estimator": {"": "mis"}},
    {"estimator": {"": "lightSampling"}, "light_samples": {"": 2}},
    {"estimator": {"": "controlVariate"}, "light_samples": {"": 4}},
    {"estimator": {"": "mis"}, "light_sampler": "bvh"},
])
def test_shadow_api_on_the_compiled_path_matches_the_general_path(tmp_path, opt):
    """shadow:color (the blocked fraction shows the colour), shadow:enable off (no ray), shadow
    distance with and without falloff (fractional visibility, also inside the control variate's
    diffuse combination), with the room's light links on top (a light with both a shadowLink and
    ShadowAPI settings gets one BVH and one set of settings, scene.build_linking)."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _link(stage, **LINKS)
    _shadow_api(stage, SHADOWS)
    fast, slow = _pair(stage, 4, 192, **opt)
    _check(fast, slow)


def test_disabled_shadows_trace_no_shadow_ray(tmp_path):
    """shadow:enable off on every light: the compiled path traces no shadow ray at all, and its
    image matches the general path's."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _shadow_api(stage, {k: {"enable": False} for k in ("Big", "Sheared", "Back", "Bulb", "Point", "Disk")})
    fast, slow = _pair(stage, 3, 128, estimator={"": "mis"})
    _check(fast, slow)
    assert fast.stats["rays"]["shadow"] == 0 and slow.stats["rays"]["shadow"] == 0


def test_the_shadow_comparison_detects_black_shadows(tmp_path, monkeypatch):
    """Dropping the shadow colour (black shadows) is seen."""
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True)
    _shadow_api(stage, {k: {"color": (0.9, 0.9, 0.9)} for k in ("Big", "Sheared", "Bulb", "Disk")})

    def black(fp):
        fp.shadow_tint = np.zeros_like(fp.shadow_tint)

    _detect(monkeypatch, stage, black, "black shadows")


def test_shadows_stage_on_the_compiled_path():
    """stages/shaping/shadows.usda: four shaped spots with plain, disabled, coloured and
    distance-limited shadows."""
    fast, slow = _pair("stages/shaping/shadows.usda", 3, 64, resolution=(64, 32), emitter_samples=1)
    _check(fast, slow)


def linked_card(tmp_path):
    """test_fast_path_materials' card (a constant opacity 0.4 cuts it) over a lit floor, with a
    grey board between card and floor that the rect light's shadowLink excludes: that light's
    shadow rays are traced against a BVH of floor and card alone, through the cut-out card; the
    dim sky's see the board."""
    path = _card_stage(tmp_path / "linked_card.usda", tmp_path, textured=False)
    stage = Usd.Stage.Open(path)
    add_quad(stage, "/World/Board", [(-0.5, 0.5, -0.5), (-0.5, 0.5, 0.5), (0.5, 0.5, 0.5), (0.5, 0.5, -0.5)],
             mat=preview_material(stage, "/World/Looks/Board", diffuse=(0.5, 0.5, 0.5)))
    UsdLux.LightAPI(stage.GetPrimAtPath("/World/Light")).GetShadowLinkCollectionAPI().CreateExcludesRel().AddTarget(
        "/World/Board")
    stage.GetRootLayer().Save()
    return path


def test_shadow_links_through_cutouts_on_the_compiled_path(tmp_path):
    """A shadowLink group in a scene with cut-outs: the kernel walks the group's own BVH through
    the cut-out card (its triangles' materials, in the group BVH's order)."""
    stage = linked_card(tmp_path)
    fast, slow = _pair(stage, 3, 128, estimator={"": "mis"})
    _check(fast, slow)
