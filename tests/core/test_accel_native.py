"""The native Embree route (renderer/accel.py): Embree's own rules, lifetime, and agreement with
the embreex route on the same rays."""

import gc
import os

import numpy as np
import pytest
from numba import njit

from renderer import accel as accel_mod
from renderer.accel import (HIT_GEOM, HIT_INST, HIT_INST_PRIM, HIT_NG, HIT_PRIM, HIT_U, HIT_V, PACKET_WIDTHS,
                            RAY_FLAGS, RAY_ID, RAY_MASK, RAY_TFAR, RAY_TIME, RAYHIT_WORDS, VERTEX_PAD_FLOATS,
                            Accel, aligned_record, rtc_intersect1, rtc_occluded1, set_ray)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SENTINEL = 0x5A5A5A5A

if accel_mod.native_embree() is None:  # pragma: no cover - the wheel ships the library
    pytest.skip("native Embree library not loadable", allow_module_level=True)


def _two_floors():
    """Two unit squares, z = 0 (triangles 0, 1) and z = -1 (triangles 2, 3)."""
    quads = []
    for z in (0.0, -1.0):
        a, b, c, d = [-1, -1, z], [1, -1, z], [1, 1, z], [-1, 1, z]
        quads += [[a, b, c], [a, c, d]]
    return np.array(quads, dtype=np.float64)


@njit
def _trace_one(fn, scene, occluded, ox, oy, oz, dx, dy, dz, tnear, tfar, mask):
    """One ray through rtcIntersect1 / rtcOccluded1; returns the whole record as float32 and
    int32, with the words after the documented fields preset to SENTINEL (to see what Embree
    writes)."""
    rec = aligned_record(RAYHIT_WORDS, 16)
    rec_i = rec.view(np.int32)
    set_ray(rec, rec_i, 0, 1, ox, oy, oz, dx, dy, dz, tnear, tfar, mask)
    if occluded:
        for k in range(12, RAYHIT_WORDS):
            rec_i[k] = SENTINEL
        rtc_occluded1(fn, scene, rec)
    else:
        for k in range(HIT_INST_PRIM + 1, RAYHIT_WORDS):
            rec_i[k] = SENTINEL
        rtc_intersect1(fn, scene, rec)
    return rec.copy(), rec_i.copy(), rec.ctypes.data


def _one(acc, occluded=False, o=(0.2, 0.3, 1.0), d=(0.0, 0.0, -1.0), tnear=0.0, tfar=1e30, mask=-1):
    h = acc.native_handles()
    fn = h.occluded1 if occluded else h.intersect1
    return _trace_one(fn, h.scene, occluded, *o, *d, np.float32(tnear), np.float32(tfar), mask)


def test_rayhit_record_layout_and_what_embree_writes():
    """RTCRayHit: 16-byte aligned; Ng, u, v, primID, geomID at the documented words, instID and
    (this 4.4 build has instance arrays) instPrimID invalid without instancing, nothing written
    past the 84 bytes of fields inside our 96-byte record."""
    acc = Accel(_two_floors(), threads=1, backend="native")
    f, i, addr = _one(acc)
    assert addr % 16 == 0
    assert f[RAY_TFAR] == pytest.approx(1.0)
    assert i[HIT_PRIM] in (0, 1) and i[HIT_GEOM] == 0
    assert i[HIT_INST] == -1 and i[HIT_INST_PRIM] == -1  # 0xFFFFFFFF
    assert np.all(i[HIT_INST_PRIM + 1:] == SENTINEL)
    # Unnormalised geometric normal: along z, |Ng| = twice the triangle's area (2 for these).
    assert f[HIT_NG] == 0 and f[HIT_NG + 1] == 0 and abs(f[HIT_NG + 2]) == pytest.approx(4.0)
    # Barycentrics reproduce the hit point.
    tri = _two_floors()[i[HIT_PRIM]]
    p = (1 - f[HIT_U] - f[HIT_V]) * tri[0] + f[HIT_U] * tri[1] + f[HIT_V] * tri[2]
    np.testing.assert_allclose(p, [0.2, 0.3, 0.0], atol=1e-6)
    # The ray words set_ray fills besides position and direction: time, mask, id, flags (Embree
    # requires flags = 0).
    assert f[RAY_TIME] == 0 and i[RAY_MASK] == -1 and i[RAY_ID] == 0 and i[RAY_FLAGS] == 0


@pytest.mark.parametrize("width", PACKET_WIDTHS)
def test_packet_records_are_aligned(width):
    # RTCRayHit4/8/16 need 16/32/64-byte alignment; the valid mask the same.
    align = 4 * max(width, 4)
    for words in (21 * width, 7, 1):
        assert aligned_record(words, align).ctypes.data % align == 0


def test_misses_keep_invalid_ids_and_tfar():
    acc = Accel(_two_floors(), threads=1, backend="native")
    f, i, _ = _one(acc, o=(5.0, 5.0, 1.0), tfar=7.5)
    assert i[HIT_GEOM] == -1 and i[HIT_PRIM] == -1 and i[HIT_INST] == -1
    assert np.uint32(i[HIT_GEOM]) == 0xFFFFFFFF
    assert f[RAY_TFAR] == np.float32(7.5)


def test_tnear_tfar_and_mask_are_honoured():
    acc = Accel(_two_floors(), threads=1, backend="native")
    f, i, _ = _one(acc)
    assert i[HIT_PRIM] in (0, 1) and f[RAY_TFAR] == pytest.approx(1.0)
    f, i, _ = _one(acc, tnear=1.5)  # starts past the upper floor: the lower one
    assert i[HIT_PRIM] in (2, 3) and f[RAY_TFAR] == pytest.approx(2.0)
    f, i, _ = _one(acc, tfar=0.5)  # ends before the upper floor: a miss
    assert i[HIT_GEOM] == -1 and f[RAY_TFAR] == np.float32(0.5)
    f, i, _ = _one(acc, tfar=1.5)
    assert i[HIT_PRIM] in (0, 1)
    f, i, _ = _one(acc, mask=0)  # the geometry's mask is all ones; a zero ray mask skips it
    assert i[HIT_GEOM] == -1


def test_occluded_sets_tfar_to_minus_inf_on_a_hit_only():
    acc = Accel(_two_floors(), threads=1, backend="native")
    f, i, _ = _one(acc, occluded=True, tfar=3.0)
    assert f[RAY_TFAR] == -np.inf
    assert np.all(i[12:] == SENTINEL)  # rtcOccluded1 reads and writes an RTCRay only
    f, _, _ = _one(acc, occluded=True, tfar=0.5)
    assert f[RAY_TFAR] == np.float32(0.5)
    f, _, _ = _one(acc, occluded=True, tnear=2.5, tfar=9.0)
    assert f[RAY_TFAR] == np.float32(9.0)


def test_vertex_buffer_is_shared_and_padded():
    """Embree reads our vertex and index arrays in place (shared, not copied), and the vertex
    array stays readable for the 16-byte load of its last 12-byte vertex."""
    tris = _two_floors()
    acc = Accel(tris, threads=1, backend="native")
    nat = acc._native
    assert nat.buffer_address(index=False) == nat.vertices.ctypes.data
    assert nat.buffer_address(index=True) == nat.indices.ctypes.data
    assert nat.vertices.dtype == np.float32 and VERTEX_PAD_FLOATS >= 1
    assert nat.vertices.nbytes >= tris.shape[0] * 3 * 12 + 4
    np.testing.assert_array_equal(nat.vertices[: tris.size], tris.astype(np.float32).ravel())


def test_the_accel_keeps_device_scene_and_buffers_alive(monkeypatch):
    """The caller's triangles may go away; the scene and the buffers it reads stay until close(),
    which releases the scene and the device reference once, however often it is called."""
    lib = accel_mod.native_embree()
    released = {"scene": 0, "device": 0}
    real_scene, real_device = lib.release_scene, lib.release_device

    def count_scene(s):
        released["scene"] += 1
        real_scene(s)

    def count_device(d):
        released["device"] += 1
        real_device(d)

    monkeypatch.setattr(lib, "release_scene", count_scene)
    monkeypatch.setattr(lib, "release_device", count_device)
    tris = _two_floors()
    acc = Accel(tris.copy(), threads=2, backend="native")
    del tris
    gc.collect()
    # Overwrite freed memory with other allocations, then trace: the Accel's own copies answer.
    junk = [np.full(64, 1e9) for _ in range(1000)]
    h = acc.intersect(np.array([[0.2, 0.3, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert h.t[0] == pytest.approx(1.0) and h.prim[0] in (0, 1)
    del junk
    assert released == {"scene": 0, "device": 0}
    acc.close()
    acc.close()
    assert released == {"scene": 1, "device": 1}
    with pytest.raises(RuntimeError, match="after close"):
        acc.intersect(np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]))
    with pytest.raises(RuntimeError, match="after close"):
        acc.native_handles()
    del acc
    gc.collect()
    assert released == {"scene": 1, "device": 1}
    # An Accel dropped without close() releases once too (garbage collection).
    acc2 = Accel(_two_floors(), threads=1, backend="native")
    del acc2
    gc.collect()
    assert released == {"scene": 2, "device": 2}


def test_kernels_release_the_gil():
    for k in (accel_mod._intersect_rows, accel_mod._occluded_rows):
        assert k.targetoptions.get("nogil") is True


def test_unloadable_library_falls_back_to_embreex_with_one_warning(monkeypatch):
    monkeypatch.setattr(accel_mod, "_NATIVE", [])
    monkeypatch.setattr(accel_mod, "embree_library_path", lambda: None)
    with pytest.warns(RuntimeWarning, match="native Embree unavailable"):
        a = Accel(_two_floors(), threads=1)
    assert a.backend == "embreex"
    b = Accel(_two_floors(), threads=1)  # no second warning (filterwarnings=error would raise)
    assert b.backend == "embreex"
    assert b.intersect(np.array([[0.2, 0.3, 1.0]]), np.array([[0.0, 0.0, -1.0]])).prim[0] in (0, 1)
    with pytest.raises(RuntimeError, match="could not be loaded"):
        Accel(_two_floors(), backend="native")


# ---- agreement with embreex -------------------------------------------------------------
def _stage_rays(stage):
    """A stage's triangles and its camera rays, one cosine bounce from their hits and shadow
    rays from those hits to random points of the bounds (float64 (n, 3) o, d and (n,) tmax)."""
    from renderer.bench import raw_ray_batches
    from renderer.camera import Camera
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    desc = load_stage(os.path.join(ROOT, "stages", stage))
    scene = build_scene(desc, threads=1)
    try:
        assert scene.accel.backend == "native"
        cam = Camera(scene.desc.camera, 48, 48, desc.settings.pixel_aspect_ratio, desc.settings.aspect_ratio_conform_policy)
        b = raw_ray_batches(scene, cam, 48, 48, seed=3, min_rays=40000)
        o_b, d_b = b["bounce"]
        rng = np.random.default_rng(4)
        lo, hi = scene.accel.bounds
        q = lo + rng.random(o_b.shape) * (hi - lo)
        t_s = np.linalg.norm(q - o_b, axis=1)
        d_s = (q - o_b) / t_s[:, None]
        return scene.geometry.vertices, [b["camera"] + (None,), (o_b, d_b, None), (o_b, d_s, t_s)]
    finally:
        scene.close()


@pytest.mark.parametrize("stage", ["cornell_box.usda", "textured.usda"])
@pytest.mark.parametrize("threads", [1, 2])
def test_native_answers_as_embreex_does_on_a_real_stage(stage, threads):
    tris, batches = _stage_rays(stage)
    nat = Accel(tris, threads=threads, backend="native")
    ex = Accel(tris, threads=threads, backend="embreex")
    try:
        for o, d, t in batches:
            a, b = nat.intersect(o, d, t), ex.intersect(o, d, t)
            assert 0.05 < a.hit.mean()
            np.testing.assert_array_equal(a.prim, b.prim)
            hit = a.hit
            np.testing.assert_array_equal(a.t[hit], b.t[hit])
            assert np.all(np.isinf(a.t[~hit]))
            np.testing.assert_array_equal(a.b1[hit], b.b1[hit])
            np.testing.assert_array_equal(a.b2[hit], b.b2[hit])
        o, d, t = batches[2]
        blocked = nat.occluded(o, d, t)
        assert 0.02 < blocked.mean() < 0.98
        np.testing.assert_array_equal(blocked, ex.occluded(o, d, t))
    finally:
        nat.close()
        ex.close()


@pytest.mark.parametrize("width", PACKET_WIDTHS[1:])
def test_packets_answer_as_single_rays(width):
    """rtcIntersect4/8/16 and rtcOccluded4/8/16 (with a partly switched-off last packet: 10007
    rays) give the single-ray answers (the batch routes use packets of BATCH_WIDTH)."""
    tris, batches = _stage_rays("cornell_box.usda")
    acc = Accel(tris, threads=2, backend="native")
    o, d, t = (x[:10007] for x in batches[2])
    o32, d32, t32 = (np.ascontiguousarray(x, dtype=np.float32) for x in (o, d, t))
    t1, tw = t32.copy(), t32.copy()
    p1, u1, v1 = acc.intersect_prepared(o32, d32, t1, width=1)
    pw, uw, vw = acc.intersect_prepared(o32, d32, tw, width=width)
    assert (p1 >= 0).mean() > 0.05
    np.testing.assert_array_equal(pw, p1)
    np.testing.assert_array_equal(tw, t1)
    np.testing.assert_array_equal(uw, u1)
    np.testing.assert_array_equal(vw, v1)
    np.testing.assert_array_equal(acc.occluded_prepared(o32, d32, t32.copy(), width=width),
                                  acc.occluded_prepared(o32, d32, t32.copy(), width=1))
    with pytest.raises(ValueError, match="packet width"):
        acc.intersect_prepared(o32, d32, t32.copy(), width=3)
    acc.close()


def test_an_empty_scene_is_a_valid_handle_that_every_ray_misses():
    acc = Accel(np.zeros((0, 3, 3)), threads=1, backend="native")
    f, i, _ = _one(acc, tfar=4.0)
    assert i[HIT_GEOM] == -1 and f[RAY_TFAR] == np.float32(4.0)
    f, _, _ = _one(acc, occluded=True, tfar=4.0)
    assert f[RAY_TFAR] == np.float32(4.0)
    o, d = np.zeros((20, 3)), np.tile([0.0, 0.0, 1.0], (20, 1))
    assert np.all(acc.intersect(o, d).prim == -1) and not acc.occluded(o, d, np.full(20, 9.0)).any()
    acc.close()
