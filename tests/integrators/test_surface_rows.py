"""The compiled per-hit surface rows (renderer/materials.py surface_hits, which the fast path's
vertex kernel calls at every hit) give what the general path's evaluation gives: the surface
interaction, MaterialTable.evaluate, make_bsdf's packed row, the emission and the bent shading
normal (PathIntegrator.bent_normals), bit for bit, on random hits of the textured stages; and
those stages run as one compiled trace_kernel call (FastPath.kernel_reason() == '').
"""

import numpy as np
import pytest

from renderer.camera import Camera
from renderer.geometry import perturb_normals, surface_interaction
from renderer.integrators import _vertex_kernels as vk
from renderer.integrators.path import IntegratorOptions, PathIntegrator
from renderer.materials import B_SLOT, make_bsdf, surface_hits
from renderer.scene import build_scene
from renderer.usd import load_stage
from tests.materials.test_udim import FALLBACK, TILES, _emissive_quad_stage, udim_dir  # noqa: F401

STAGES = ["stages/textured.usda", "stages/plant/plant.usda", "stages/dof.usda"]


def _scene(path):
    return build_scene(load_stage(path), threads=1)


def _random_hits(g, n, seed):
    """n random hits: triangles, float32 barycentrics inside them, unit directions (float64)."""
    rng = np.random.default_rng(seed)
    k = rng.integers(0, g.vertices.shape[0], n).astype(np.int32)
    u = rng.random((n, 2))
    flip = u.sum(axis=1) > 1.0
    u[flip] = 1.0 - u[flip]
    b1, b2 = u[:, 0].astype(np.float32), u[:, 1].astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return k, b1, b2, d


def _numpy_rows(scene, k, b1, b2, d):
    """The general path's evaluation at the hits: (packed rows, emission, bent normals)."""
    g, mats = scene.geometry, scene.materials
    _, ng, ns, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, k.astype(np.int64), b1, b2, d)
    mat = g.material[k]
    params = mats.evaluate(mat, st)
    bent = ns if g.tangent is None else perturb_normals(ns, ng, -d, params.normal, mats.normal_mapped[mat], k,
                                                         g.tangent, g.handed, g.face_normal)
    return make_bsdf(params).packed, params.emission, bent, params


@pytest.mark.parametrize("path", STAGES[:2])
def test_compiled_rows_equal_the_numpy_evaluation(path):
    scene = _scene(path)
    try:
        g, mats = scene.geometry, scene.materials
        n = 4000
        k, b1, b2, d = _random_hits(g, n, 7)
        # Some rays miss: their rows are -1 and the hits keep their order.
        prim = k.copy()
        prim[::5] = -1
        S = np.zeros((n, vk.NS))
        S[:, vk.D:vk.D + 3] = d
        P, row, emission, bent = surface_hits(mats.hit_record(g), g.vertices, g.face_normal, g.normals,
                                              np.ascontiguousarray(g.material, dtype=np.int64), prim, b1, b2, S, vk.D)
        hit = prim >= 0
        np.testing.assert_array_equal(row[hit], np.arange(hit.sum()))
        assert np.all(row[~hit] == -1)
        P_np, em_np, bent_np, params = _numpy_rows(scene, k[hit], b1[hit], b2[hit], d[hit])
        np.testing.assert_array_equal(P, P_np)
        np.testing.assert_array_equal(bent if mats.has_normal_map else np.zeros((0, 3)),
                                      bent_np if mats.has_normal_map else np.zeros((0, 3)))
        if mats.has_emission:
            np.testing.assert_array_equal(emission, em_np)
        else:
            assert emission.shape == (0, 3)
        # The hits do exercise textures (and, on the plant, normal maps): inputs vary per hit
        # within one material, and bent normals differ from the interpolated ones.
        textured = np.any(mats.surface_record()[1][g.material[k[hit]], :, B_SLOT] >= 0, axis=1)
        assert textured.sum() > 100
        varied = np.concatenate([params.diffuse, params.roughness[:, None], params.opacity[:, None]], axis=1)
        assert np.unique(varied[textured], axis=0).shape[0] > 50
        if mats.has_normal_map:
            _, _, ns, _ = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, k[hit].astype(np.int64),
                                              b1[hit], b2[hit], d[hit])
            assert np.mean(np.any(bent != ns, axis=1)) > 0.3
    finally:
        scene.close()


def test_udim_rows_pick_the_tile_of_each_hit(udim_dir):
    """A UDIM emission texture (TextureCache._lookup_udim's rules, textures.texture_row): each
    compiled row emits its tile's colour, or the fallback on the missing tile 1011."""
    path = _emissive_quad_stage(udim_dir / "s.usda", "./maps/paint.<UDIM>.exr", [(0, 0), (2, 0), (2, 2), (0, 2)])
    scene = _scene(path)
    try:
        g, mats = scene.geometry, scene.materials
        n = 2000
        k, b1, b2, d = _random_hits(g, n, 3)
        S = np.zeros((n, vk.NS))
        S[:, vk.D:vk.D + 3] = d
        _, _, emission, _ = surface_hits(mats.hit_record(g), g.vertices, g.face_normal, g.normals,
                                         np.ascontiguousarray(g.material, dtype=np.int64), k, b1, b2, S, vk.D)
        _, _, _, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, k.astype(np.int64), b1, b2, d)
        tile = 1001 + np.floor(st[:, 0]).astype(int) + 10 * np.floor(st[:, 1]).astype(int)
        want = np.array([TILES.get(t, FALLBACK[:3]) for t in tile])
        assert set(np.unique(tile)) == {1001, 1002, 1011, 1012}
        np.testing.assert_allclose(emission, want, rtol=1e-6)
        np.testing.assert_array_equal(emission, mats.evaluate(g.material[k], st).emission)
    finally:
        scene.close()


@pytest.mark.parametrize("path", STAGES)
def test_textured_stages_run_as_one_trace_kernel_call(path):
    scene = _scene(path)
    try:
        integ = PathIntegrator(scene, Camera(scene.desc.camera, 8, 8), IntegratorOptions(threads=1))
        assert integ.fast is not None, integ.fast_path_reason
        assert integ.fast.kernel_reason() == ""
    finally:
        scene.close()
