"""bench/bench_mitsuba.py compares illum with Mitsuba on Lambertian stages by swapping illum's
BSDF for Lambert inside its own process. The swap patches the integrator's BSDF entry point; when
that entry point moved (MaterialTable.bsdf), the swap broke without any test noticing. These
tests pin it: inside the context every hit gets LambertBSDF(diffuse), the render uses it, and
the original is restored afterwards."""

from __future__ import annotations

import importlib.util
import os

import numpy as np

from renderer.bsdfs.lambert import LambertBSDF
from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.description import MaterialDesc, MaterialInput
from renderer.materials import MaterialTable
from renderer.render import RenderOptions, render
from renderer.textures import TextureCache

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _bench_mitsuba():
    spec = importlib.util.spec_from_file_location("bench_mitsuba", os.path.join(ROOT, "bench", "bench_mitsuba.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_lambert_swap_replaces_the_bsdf_at_every_hit_and_restores_it():
    bm = _bench_mitsuba()
    table = MaterialTable.build([MaterialDesc("/A", diffuse_color=MaterialInput((0.9, 0.2, 1.4))),
                                 MaterialDesc("/B", metallic=MaterialInput(1.0))], TextureCache())
    mat = np.array([0, 1, 1, 0])
    with bm.lambert_materials():
        b = table.bsdf(mat)
        assert isinstance(b, LambertBSDF)
        np.testing.assert_array_equal(b.albedo, np.clip(table.evaluate(mat).diffuse, 0.0, 1.0))
    assert isinstance(table.bsdf(mat), PreviewSurfaceBSDF)


def test_lambert_swap_changes_the_render_and_only_inside_the_context():
    bm = _bench_mitsuba()
    stage = os.path.join(ROOT, "stages", "cornell_box.usda")
    opts = dict(resolution=(12, 12), spp=4, seed=3, threads=1, max_depth=1)
    plain = render(stage, RenderOptions(**opts)).film.image()
    with bm.lambert_materials():
        lam = render(stage, RenderOptions(**opts)).film.image()
    again = render(stage, RenderOptions(**opts)).film.image()
    np.testing.assert_array_equal(plain, again)  # restored, and renders are deterministic
    assert not np.array_equal(plain, lam)  # the swap reached the integrator
