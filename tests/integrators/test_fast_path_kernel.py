"""The fast path's bounce loop as one compiled call (renderer/integrators/_trace_kernel.py) gives
the image of the Python bounce loop (FastPath.trace_loop) for the same seed, bit for bit, with
the same counters; and chunks traced by parallel threads give the image of one thread.

Stages: the Cornell box (plain), a card cut out by a constant opacity over a lit floor (the
cut-out walks of camera, bounce and shadow rays), the plant (per-hit textured surfaces, normal
maps and textured cut-outs), and test_fast_path's room under per-light
estimators with N samples and a picking lighting service (the estimators' shadow rays and
groups, their own stream). The image comparisons are exact: both routes make the same calls
with the same keys, so any difference (a key, a buffer, a counter off by one bounce) shows.
"""

import numpy as np
import pytest

from renderer.integrators import fast_path as fp_mod
from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import _room
from tests.integrators.test_fast_path_lux import linked_card
from tests.integrators.test_fast_path_materials import _card_stage


def _render(stage, loop: bool, monkeypatch, **opt):
    """render() of stage through the compiled loop, or (loop) the Python one; with the scene's
    own BVH counters (Accel.rays_traced)."""
    calls = {"compiled": 0, "loop": 0}
    orig_c, orig_l = fp_mod.FastPath.trace_compiled, fp_mod.FastPath.trace_loop

    def compiled(self, *a, **kw):
        calls["compiled"] += 1
        return orig_c(self, *a, **kw)

    def looped(self, *a, **kw):
        calls["loop"] += 1
        return orig_l(self, *a, **kw)

    with monkeypatch.context() as mp:
        mp.setattr(fp_mod.FastPath, "trace_compiled", compiled)
        mp.setattr(fp_mod.FastPath, "trace_loop", looped)
        if loop:
            mp.setattr(fp_mod.FastPath, "kernel_reason", lambda self: "forced by the test")
        cache: dict = {}
        kw = dict(spp=3, max_depth=5, rr_depth=1, seed=4)
        kw.update(opt)
        r = render(str(stage), RenderOptions(**kw), scene_cache=cache)
        (_, scene), = cache.values()
        traced = dict(scene.accel.rays_traced)
        scene.close()
    assert r.stats["fast_path"] == "on"
    assert calls["loop" if loop else "compiled"] > 0 and calls["compiled" if loop else "loop"] == 0, calls
    return r, traced


def _same(a, b):
    (ra, ta), (rb, tb) = a, b
    assert np.array_equal(ra.film.mean(), rb.film.mean())
    assert ra.film.mean().sum() > 0.0
    assert ra.stats["rays"] == rb.stats["rays"]
    assert ra.stats["direct_rule"] == rb.stats["direct_rule"]
    assert ta == tb and ta["intersect"] > 0


def _card(tmp_path):
    return _card_stage(tmp_path / "card.usda", tmp_path, textured=False)


def _estimator_room(tmp_path):
    stage = tmp_path / "room.usda"
    _room(stage, more_kinds=True, infinite=True)
    return stage


STAGES = {
    "cornell": (lambda tmp_path: "stages/cornell_box.usda", dict(resolution=(40, 40))),
    "cutout": (_card, {}),
    "shadows": (lambda tmp_path: "stages/shaping/shadows.usda", dict(resolution=(48, 24))),
    "shadow_links_cutout": (linked_card, {}),
    # Textures, normal maps and textured cut-outs, evaluated per hit inside the vertex kernel.
    "plant": (lambda tmp_path: "stages/plant/plant.usda", dict(resolution=(32, 24))),
    "estimators": (_estimator_room, dict(estimator={"": "lightSampling", "/World/Big": "mis"},
                                         light_samples={"": 2})),
    "estimators_bvh": (_estimator_room, dict(estimator={"": "bsdfSampling", "/World/Bulb": "mis"},
                                             light_samples={"": 3}, light_sampler="bvh")),
}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_compiled_loop_gives_the_python_loops_image(tmp_path, monkeypatch, name):
    make, opt = STAGES[name]
    stage = make(tmp_path)
    compiled = _render(stage, False, monkeypatch, threads=2, **opt)
    _same(compiled, _render(stage, True, monkeypatch, threads=2, **opt))


@pytest.mark.parametrize("name", ["cornell", "cutout"])
def test_the_image_does_not_depend_on_the_thread_count(tmp_path, monkeypatch, name):
    make, opt = STAGES[name]
    stage = make(tmp_path)
    # 80 x 80: 6400 pixels, several chunks per pass (PathIntegrator.render_pass).
    opt = dict(opt, resolution=(80, 80))
    _same(_render(stage, False, monkeypatch, threads=1, **opt), _render(stage, False, monkeypatch, threads=2, **opt))


def test_the_comparison_sees_a_changed_key(tmp_path, monkeypatch):
    """The exact comparison above can fail: the pixels' sequences one pass ahead in the compiled
    route alone give another image."""
    make, opt = STAGES["cornell"]
    stage = make(tmp_path)
    orig = fp_mod.FastPath.trace_compiled

    def shifted(self, o, d, tmax, max_depth, keys, keys2, ckeys, lds=None):
        pix, index, roles = lds
        return orig(self, o, d, tmax, max_depth, keys, keys2, ckeys, lds=(pix, index + np.uint64(1), roles))

    loop = _render(stage, True, monkeypatch, threads=2, **opt)
    monkeypatch.setattr(fp_mod.FastPath, "trace_compiled", shifted)
    r, _ = _render(stage, False, monkeypatch, threads=2, **opt)
    assert not np.array_equal(r.film.mean(), loop[0].film.mean())


def test_scenes_with_numpy_work_per_bounce_keep_the_python_loop(tmp_path):
    """Shadow groups keep the Python loop, with the reason in kernel_reason; per-hit textured
    materials (the plant's leaves and normal maps) and the control variate's F do not."""
    from renderer.camera import Camera
    from renderer.integrators.path import IntegratorOptions, PathIntegrator
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    def reason(path, **opt):
        desc = load_stage(str(path))
        scene = build_scene(desc, threads=1)
        try:
            cam = Camera(scene.desc.camera, 8, 8)
            integ = PathIntegrator(scene, cam, IntegratorOptions(threads=1, **opt))
            assert integ.fast is not None
            return integ.fast.kernel_reason()
        finally:
            scene.close()

    # Per-hit surfaces (the plant's textures, normal maps and cut-outs) are evaluated in the kernel.
    assert reason("stages/plant/plant.usda") == ""
    # F is taken inside the vertex kernel: the control variate runs in the compiled loop too.
    assert reason("stages/cornell_box.usda", estimator={"": "controlVariate"}) == ""
    # Shadow groups (ShadowAPI settings, shadowLink, shadow colours) are traced inside the kernel:
    # the stage runs as one trace_kernel call.
    assert reason("stages/shaping/shadows.usda") == ""
    assert reason("stages/cornell_box.usda") == ""
    assert reason(_card(tmp_path)) == ""


def test_the_compiled_loop_releases_the_gil(monkeypatch):
    """While trace_kernel runs, another Python thread runs: it counts during most calls. (A call
    holding the GIL stops every Python thread until it returns: the counter could then only move
    through a GIL switch in the microseconds between its readings and the call.)"""
    import threading
    import time

    from renderer.integrators import _trace_kernel as tk

    ticks = [0]
    done = threading.Event()

    def count():
        while not done.is_set():
            ticks[0] += 1
            time.sleep(0)  # hands the GIL back at once

    moved = []
    orig = tk.trace_kernel

    def watched(*a):
        before = ticks[0]
        orig(*a)
        moved.append(ticks[0] - before)

    monkeypatch.setattr(tk, "trace_kernel", watched)
    counter = threading.Thread(target=count, daemon=True)
    counter.start()
    try:
        r = render("stages/cornell_box.usda", RenderOptions(spp=2, resolution=(128, 128), threads=1, max_depth=4))
    finally:
        done.set()
        counter.join()
    assert r.stats["fast_path"] == "on" and len(moved) == 8  # 2 passes of 4 chunks
    assert sum(m > 0 for m in moved) >= len(moved) // 2, moved
