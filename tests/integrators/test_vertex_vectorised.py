"""The fast path's vectorised vertex passes stay vectorised. (The branch-free sin, cos and atan
they rely on: tests/core/test_vmath.py; the light samplers' loops: tests/lights/test_rect_batch.py.)

The passes (renderer/integrators/_vertex_kernels.py) are correct by the fast-path tests (they
z-test the fast path against the general path and render stages with both); what those cannot
see is a change that silently turns a pass back into scalar code, ~2x slower per row. Any branch
around work, a libm call, an exception check, a helper taking arrays inlined by numba, or a
runtime row stride does that (the module docstring lists them)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from numba import njit

import renderer.integrators._vertex_kernels as vk
from tests.simd import assembly, needs_avx2, uncached


def _uncached(dispatcher):
    """An uncached copy through the passes' noalias pipeline."""
    return uncached(dispatcher, pipeline_class=vk._NoAliasCompiler)


def _surface_args(n=8):
    """Arguments of _surface_pass with the dtypes FastPath passes (one triangle, one material)."""
    rng = np.random.default_rng(1)
    S = np.zeros((n, vk.NS))
    S[:, vk.B:vk.B + 3] = 1.0
    S[:, vk.D + 2] = -1.0
    Pm = np.zeros((1, 22))
    Pm[0, vk.ALPHA] = 0.5
    verts = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    return (0, n, np.zeros(n, np.int32), np.full(n, 0.25, np.float32), np.full(n, 0.25, np.float32), S,
            rng.random((6, n)), np.zeros(n, np.int64), Pm, np.zeros(0, np.int64), np.zeros((0, 3)), verts, np.array([[0.0, 0.0, 1.0]]),
            np.repeat(np.array([[[0.0, 0.0, 1.0]]]), 3, axis=1), np.zeros(1, np.int64), np.ones(1), 3, 1e-6, 1e-3,
            1e-9, np.empty(vk.NW * vk.BLK))


@needs_avx2
@pytest.mark.parametrize("which", ["surface", "light", "cross"])
def test_vertex_pass_loop_is_vectorised(which):
    args = _surface_args()
    if which == "cross":
        kernel = _uncached(vk._cross_pass)
        kernel(*_cross_args(np.random.default_rng(3), 8))
        asm = assembly(kernel)
        # The rect test's division, packed (there is no square root in this pass).
        assert re.search(r"vdivpd\s+%[yz]mm", asm), "_cross_pass's loops are no longer vectorised"
        return
    if which == "surface":
        kernel = _uncached(vk._surface_pass)
        kernel(*args)
    else:
        vk._surface_pass(*args)
        kernel = _uncached(vk._light_pass)
        smp = np.zeros((5, 8))
        smp[2] = 1.0
        smp[3:5] = 1.0
        kernel(0, 8, smp, False, 1.0, 1.0, 1.0, False, True, args[5], args[-1], args[8], np.empty(4 * vk.BLK))
    asm = assembly(kernel)
    # Packed double square roots on ymm/zmm registers come only from the loop vectoriser (the SLP
    # vectoriser pairs scalar code on xmm at most).
    assert re.search(r"vsqrtpd\s+%[yz]mm", asm), f"_{which}_pass's loop is no longer vectorised"




def _cross_args(rng, n, rects=3, spheres=2):
    """_cross_pass arguments: n rays from around the origin, some ending on a surface (hit_t),
    random rect lights (centre, normal, dual edge vectors) and sphere lights (one treatAsPoint)."""
    S = np.zeros((n, vk.NS))
    S[:, vk.O:vk.O + 3] = rng.uniform(-1.0, 1.0, (n, 3))
    d = rng.normal(size=(n, 3))
    S[:, vk.D:vk.D + 3] = d / np.linalg.norm(d, axis=1, keepdims=True)
    S[:, vk.TMAX] = np.where(rng.random(n) < 0.1, rng.uniform(0.5, 3.0, n), np.inf)
    hit_prim = np.where(rng.random(n) < 0.6, 0, -1).astype(np.int32)
    hit_t = rng.uniform(0.1, 4.0, n).astype(np.float32)
    center = rng.uniform(-2.0, 2.0, (rects, 3))
    nrm = rng.normal(size=(rects, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    e1 = np.cross(nrm, rng.normal(size=(rects, 3)))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(nrm, e1)
    size = rng.uniform(0.5, 3.0, (rects, 2))
    # Duals of the edges e1 * size0, e2 * size1 (orthogonal): e / |e|^2.
    exd, eyd = e1 / size[:, :1], e2 / size[:, 1:]
    s_center = rng.uniform(-2.0, 2.0, (spheres, 3))
    s_radius = rng.uniform(0.2, 1.0, spheres)
    s_delta = np.arange(spheres) == spheres - 1
    return (0, n, S, hit_t, hit_prim, center, nrm, exd, eyd, s_center, s_radius, s_delta, np.full(vk.BLK, 7.0))


def _exact_crossings(args):
    """(n,) bool: the rows of _cross_args' rays that cross a light by the scalar pass's exact
    tests (_rect_hit's front-side hit before the surface; _sphere_hit_row's hit, never for a
    treatAsPoint sphere)."""
    from renderer.kernels.lights import _rect_hit, _sphere_hit_row

    exact_rect = njit(lambda o, d, c, nl, exd, eyd: _rect_hit(o, d, c, nl, exd, eyd))
    exact_sphere = njit(lambda o, d, c, r, delta: _sphere_hit_row(o, d, c, r, delta))
    _, n, S, hit_t, hit_prim, center, nrm, exd, eyd, s_center, s_radius, s_delta, _X = args
    out = np.zeros(n, dtype=bool)
    for r in range(n):
        o, d = tuple(S[r, vk.O:vk.O + 3]), tuple(S[r, vk.D:vk.D + 3])
        t_geo = min(float(hit_t[r]) if hit_prim[r] >= 0 else np.inf, S[r, vk.TMAX])
        for j in range(center.shape[0]):
            tl, _a, _b, hit = exact_rect(o, d, tuple(center[j]), tuple(nrm[j]), tuple(exd[j]), tuple(eyd[j]))
            out[r] |= bool(hit and tl < t_geo and np.dot(d, nrm[j]) < 0.0)
        for j in range(s_center.shape[0]):
            tl = exact_sphere(o, d, tuple(s_center[j]), float(s_radius[j]), bool(s_delta[j]))
            out[r] |= bool(tl < np.inf and not s_delta[j])
    return out


def test_cross_pass_never_misses_a_light_the_exact_test_finds():
    """_cross_pass only pre-filters the scalar pass's exact emission test: every row the exact
    tests find crossing a light must have X = 1, else emission would be lost. With rect lights
    only the pre-test equals the exact one (but for its 1e-9 margins), so it does filter."""
    rng = np.random.default_rng(11)
    n = vk.BLK
    crossed_total = 0
    for _ in range(40):
        args = _cross_args(rng, n)
        vk._cross_pass(*args)
        X = args[-1][:n]
        assert np.all((X == 0.0) | (X == 1.0))
        crossed = _exact_crossings(args)
        assert np.all(X[crossed] == 1.0)
        crossed_total += int(crossed.sum())
    assert crossed_total > 200  # the comparison saw many crossings
    for _ in range(10):
        args = _cross_args(rng, n, rects=2, spheres=0)
        vk._cross_pass(*args)
        np.testing.assert_array_equal(args[-1][:n], _exact_crossings(args).astype(float))


def _block_uniforms(key, n, n_u):
    """_uniform_pass over n rows in blocks, as vertex_kernel draws them: (n_u, n)."""
    out = np.empty((n_u, n))
    UB = np.empty((n_u, vk.BLK))
    for lo in range(0, n, vk.BLK):
        hi = min(n, lo + vk.BLK)
        vk._uniform_pass(np.uint64(key), lo, hi, UB)
        out[:, lo:hi] = UB[:, :hi - lo]
    return out


def test_uniform_stream_is_uniform_and_pairs_are_independent():
    """Chi-square tests of the kernel's counter-based uniforms: the marginal of every column on
    64 bins, and the joint of neighbouring columns (one row's lobe and direction numbers) and of
    the same column in neighbouring rows on 16 x 16 bins. A generator that repeated a stream,
    correlated neighbours or missed part of [0, 1) fails at these counts."""
    from tests.stats import SIGNIFICANCE, chi2_sf

    n, n_u = 200_003, 6
    u = _block_uniforms(0x1234_5678_9ABC, n, n_u)
    assert u.min() >= 0.0 and u.max() < 1.0

    def p_value(counts):
        e = counts.sum() / counts.size
        return chi2_sf(float(((counts - e) ** 2 / e).sum()), counts.size - 1)

    for c in range(n_u):
        assert p_value(np.bincount((u[c] * 64).astype(int), minlength=64)) > SIGNIFICANCE, c
    for a, b in ((u[0], u[1]), (u[1], u[2]), (u[3][:-1], u[3][1:]), (u[5][:-1], u[0][1:])):
        joint = np.bincount((a * 16).astype(int) * 16 + (b * 16).astype(int), minlength=256)
        assert p_value(joint) > SIGNIFICANCE


def test_uniform_stream_depends_on_key_and_row_not_on_blocking():
    """A row's numbers are a function of (key, row, column) only: the same whatever block it falls
    in, different for another key; every 53-bit value distinct over a large draw."""
    a = _block_uniforms(99, 1000, 6)
    UB = np.empty((6, vk.BLK))
    vk._uniform_pass(np.uint64(99), 700, 700 + vk.BLK, UB)  # a block starting mid-way
    np.testing.assert_array_equal(UB, a[:, 700:700 + vk.BLK])
    b = _block_uniforms(100, 1000, 6)
    assert not np.any(a == b)
    assert np.unique(_block_uniforms(7, 100_000, 6)).size == 600_000
