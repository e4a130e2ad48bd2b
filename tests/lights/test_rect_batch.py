"""The vectorised rect- and sphere-light samplers (kernels/lights.rect_sample_batch_kernel,
sphere_sample_batch_kernel) against the scalar rows they stand in for in the fast path.

It must give the scalar row's samples bit for bit (the same operations, four or eight rows at
a time), and must stay vectorised: an edit that makes its loop scalar again (a raising division,
a batch axis that is not the last) would silently halve the fast path's rect sampling speed, so
the compiled loop is checked for packed 256/512-bit square roots.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from numba import njit

from renderer.kernels.lights import (
    _rect_sample_row,
    rect_sample_batch_kernel,
    sphere_sample_batch_kernel,
    sphere_sample_kernel,
)
from renderer.lights.spherical_rect import GRAZING_NZ2, MIN_SOLID_ANGLE
from tests.simd import assembly, needs_avx2, uncached


@njit(cache=False)
def _scalar_rows(p, u, c, e1, e2, xh, yh, lx, ly, nl, area, is_rect, min_sa, graz, out):
    for r in range(p.shape[1]):
        wi, dist, pdf, _pl, ok = _rect_sample_row(
            (p[0, r], p[1, r], p[2, r]), u[0, r], u[1, r], c, e1, e2, xh, yh, lx, ly, nl, area, False, is_rect,
            0.0, 0.0, 0.0, min_sa, graz)
        out[0, r] = wi[0]
        out[1, r] = wi[1]
        out[2, r] = wi[2]
        out[3, r] = dist
        out[4, r] = pdf if ok else 0.0


def _light(tilt: float, lx: float, ly: float, center=(0.2, -0.1, 2.0)):
    """A rect light args tuple (rect_sample_batch_kernel's, after p, u, col): edges lx, ly, tilted
    about x by `tilt`, facing -z when untilted."""
    ct, st = math.cos(tilt), math.sin(tilt)
    xh = (1.0, 0.0, 0.0)
    yh = (0.0, ct, st)
    n = (0.0, st, -ct)  # x_hat x y_hat, negated: emits toward -z
    e1 = tuple(lx * v for v in xh)
    e2 = tuple(ly * v for v in yh)
    return (tuple(center), e1, e2, xh, yh, lx, ly, n, lx * ly, True, MIN_SOLID_ANGLE, GRAZING_NZ2)


@pytest.mark.parametrize("tilt,lx,ly", [(0.0, 1.0, 0.5), (0.7, 3.0, 0.2), (1.5, 0.05, 0.05), (0.3, 40.0, 40.0)])
def test_batch_kernel_gives_the_scalar_rows_samples(tilt, lx, ly):
    rng = np.random.default_rng(5)
    n = 20_000
    # Points around and below the light: near, far, behind (pdf 0), grazing, on its plane.
    p = np.concatenate([rng.uniform(-3, 3, (3, n)) * np.array([[1.0], [1.0], [0.7]]),
                        rng.uniform(-300, 300, (3, 200)),
                        np.array([[0.2], [-0.1], [2.0]]) + np.array([[1.0], [0.0], [0.0]]) * rng.uniform(-2, 2, 50)],
                       axis=1)
    u = rng.random((2, p.shape[1]))
    args = _light(tilt, lx, ly)
    ref = np.empty((5, p.shape[1]))
    got = np.empty((5, p.shape[1]))
    _scalar_rows(np.ascontiguousarray(p), u, *args, ref)
    rect_sample_batch_kernel(np.ascontiguousarray(p), u, 0, 0, p.shape[1], *args, got)
    ok = ref[4] > 0.0
    assert ok.mean() > 0.3  # the comparison covers real samples
    np.testing.assert_array_equal(got[4], ref[4])
    np.testing.assert_array_equal(got[:4][:, ok], ref[:4][:, ok])


def test_batch_kernel_reads_its_uniform_rows_from_col_and_lo():
    """Row i takes the uniforms u[col:col + 2, lo + i] (the vertex kernel's block at lo) and
    writes out[:, i], leaving columns from n on alone."""
    rng = np.random.default_rng(6)
    p = rng.uniform(-1, 1, (3, 1000))
    u = rng.random((6, 1300))
    args = _light(0.2, 1.0, 1.0)
    a = np.empty((5, 1000))
    b = np.full((5, 1000), -7.0)
    rect_sample_batch_kernel(p, np.ascontiguousarray(u[4:6, 300:]), 0, 0, 1000, *args, a)
    rect_sample_batch_kernel(p, u, 4, 300, 900, *args, b)
    np.testing.assert_array_equal(a[:, :900], b[:, :900])
    assert np.all(b[:, 900:] == -7.0)


@pytest.mark.parametrize("radius,delta", [(0.5, False), (1e-4, False), (3.0, False), (0.5, True)])
def test_sphere_batch_kernel_gives_the_scalar_rows_samples(radius, delta):
    rng = np.random.default_rng(7)
    # Points far, near, inside (pdf 0 for an area sphere) and at the centre of a unit-scale sphere.
    p = np.concatenate([rng.uniform(-4, 4, (3, 20_000)), rng.uniform(-1e4, 1e4, (3, 100)),
                        np.array([[0.1], [0.2], [0.3]]) + rng.uniform(-0.3, 0.3, (3, 100)),
                        np.array([[0.1], [0.2], [0.3]])], axis=1)
    u = rng.random((2, p.shape[1]))
    args = ((0.1, 0.2, 0.3), radius, delta)
    got = np.empty((6, p.shape[1]))
    sphere_sample_batch_kernel(p, u, 0, 0, p.shape[1], *args, got)
    # The reference: the general path's kernel (rows as the batch axis, unit radiance so that
    # its L is the radiance scale).
    n = p.shape[1]
    L, wi, pdf, dist, pl = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n), np.empty((n, 3))
    sphere_sample_kernel(np.zeros(n, dtype=np.int64), np.ascontiguousarray(p.T), np.ascontiguousarray(u.T),
                         np.array([args[0]]), np.array([radius]), np.ones((1, 3)), np.array([delta]), L, wi, pdf,
                         dist, pl)
    ok = pdf > 0.0
    assert ok.mean() > 0.5
    np.testing.assert_array_equal(got[4], pdf)
    np.testing.assert_array_equal(got[:3][:, ok], wi[ok].T)
    np.testing.assert_array_equal(got[3][ok], dist[ok])
    np.testing.assert_array_equal(got[5][ok], L[ok, 0])


@needs_avx2
@pytest.mark.parametrize("which", ["rect", "sphere"])
def test_batch_kernel_loop_is_vectorised(which):
    batch, args, rows = {"rect": (rect_sample_batch_kernel, _light(0.0, 1.0, 1.0), 5),
                         "sphere": (sphere_sample_batch_kernel, ((0.0, 0.0, 2.0), 0.5, False), 6)}[which]
    kernel = uncached(batch)
    kernel(np.zeros((3, 8)), np.zeros((2, 8)), 0, 0, 8, *args, np.empty((rows, 8)))
    asm = assembly(kernel)
    # Packed double square roots on ymm/zmm registers come only from the loop vectoriser (the SLP
    # vectoriser pairs scalar code on xmm at most).
    assert re.search(r"vsqrtpd\s+%[yz]mm", asm), f"{batch.__name__}'s loop is no longer vectorised"
    # Their atan, sin and cos are renderer/kernels/vmath.py's polynomials: a libm call would run one
    # lane at a time. numba calls libm through an address it loads first (movabsq $atan, %rax).
    libm = set(re.findall(r"\$(\w*(?:atan|sin|cos)\w*)", asm))
    assert not libm, f"{batch.__name__} calls libm's {sorted(libm)}"
