"""The issue #9 test stages (stages/shaping, stages/lux_extra): each loads with the UsdLux features
it exists to show, and renders lit and finite at a tiny size."""

from __future__ import annotations

import os

import numpy as np
import pytest

from renderer.render import RenderOptions, render
from renderer.usd import load_stage

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _spotlights(d):
    kinds = sorted({x.kind for x in d.lights})
    assert kinds == ["disk", "rect", "sphere"] and all(x.shaping is not None for x in d.lights)
    assert sum(bool(x.shaping.ies_file) for x in d.lights) >= 3          # the IES profiles of stages/ies
    assert any(x.shaping.cone_softness > 0 for x in d.lights) and any(x.shaping.focus > 0 for x in d.lights)


def _shadows(d):
    sh = [x.shadow for x in d.lights if x.shadow is not None]
    assert any(not s.enable for s in sh) and any(any(c > 0 for c in s.color) for s in sh)
    assert any(s.distance > 0 and s.falloff > 0 for s in sh)


def _mesh_room(d):
    assert sorted(x.kind for x in d.lights) == ["cylinder", "mesh", "mesh"]
    assert any(x.mesh_two_sided for x in d.lights if x.kind == "mesh")
    assert [w for w in d.warnings if "light filters" in w] and len(d.warnings) == 1


def _window(d):
    (dome,) = d.lights
    assert dome.kind == "dome" and dome.portals is not None and dome.portals.shape == (1, 4, 4)


STAGES = {
    "shaping/spotlights.usda": _spotlights,
    "shaping/shadows.usda": _shadows,
    "lux_extra/mesh_light_room.usda": _mesh_room,
    "lux_extra/window_portal.usda": _window,
}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_stage_has_its_features_and_renders_lit(name):
    path = os.path.join(ROOT, "stages", name)
    STAGES[name](load_stage(path))
    r = render(path, RenderOptions(spp=2, resolution=(32, 24), max_depth=2, seed=1, threads=1))
    img = r.film.mean()
    assert np.all(np.isfinite(img))
    assert np.mean(img[..., 1] > 0.0) > 0.1, "a test stage renders (mostly) black"
