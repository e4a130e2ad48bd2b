"""The bounces' low-discrepancy numbers (renderer/kernels/sobol.py): the Sobol' points, the two
scrambles' structure, per-pixel stratification and uniformity across pixels (chi-square)."""

from __future__ import annotations

import numpy as np
from numba import njit

from renderer.kernels.sobol import (owen_scramble32, pixel_keys, reverse_bits32, shuffle_index32,
                                    sobol_second32, sobol_u01)
from renderer.sampling import _sobol2
from tests.stats import SIGNIFICANCE, chi2_sf


@njit(cache=False)
def _points(key, dim, n, start=0):
    out = np.empty((n, 2))
    for i in range(n):
        out[i, 0] = sobol_u01(key, np.uint64(start + i), np.uint64(dim), 0)
        out[i, 1] = sobol_u01(key, np.uint64(start + i), np.uint64(dim), 1)
    return out


@njit(cache=False)
def _apply(f, xs, seed):
    """f(x, seed) for each uint64 x of xs, compiled."""
    out = np.empty(xs.shape[0], dtype=np.uint64)
    for i in range(xs.shape[0]):
        out[i] = f(xs[i], seed)
    return out


@njit(cache=False)
def _reverse(x, seed):
    return reverse_bits32(x)


@njit(cache=False)
def _second(x, seed):
    return sobol_second32(x)


def test_the_unscrambled_points_are_sobols():
    k = np.arange(4096, dtype=np.uint64)
    ref = np.array([_sobol2(int(i)) for i in k], dtype=np.uint64)
    np.testing.assert_array_equal(_apply(_reverse, k, 0), ref[:, 0])
    np.testing.assert_array_equal(_apply(_second, k, 0), ref[:, 1])
    top = np.array([0xFFFFFFFF, 0x80000000, 0x12345678], dtype=np.uint64)
    np.testing.assert_array_equal(_apply(_second, top, 0), [_sobol2(int(i))[1] for i in top])


def test_scrambles_are_nested_permutations():
    """Owen scrambling permutes 0..2^16 - 1 (in the top bits) and keeps every prefix of bits:
    values sharing their top b bits share them after the scramble. The index shuffle maps each
    aligned block of 2^k indices onto an aligned block of 2^k."""
    rng = np.random.default_rng(3)
    for seed in rng.integers(0, 2 ** 32, size=4, dtype=np.uint64):
        x = np.arange(1 << 16, dtype=np.uint64) << np.uint64(16)
        y = _apply(owen_scramble32, x, seed)
        assert np.unique(y >> np.uint64(16)).size == 1 << 16
        for b in (1, 4, 9):
            top_x = x >> np.uint64(32 - b)
            top_y = y >> np.uint64(32 - b)
            for t in range(1 << b):
                assert np.unique(top_y[top_x == t]).size == 1
        i = np.arange(1 << 12, dtype=np.uint64)
        j = _apply(shuffle_index32, i, seed)
        for k in (1, 5, 12):
            for s in range(0, 1 << 12, 1 << k):
                block = j[s:s + (1 << k)]
                assert np.unique(block >> np.uint64(k)).size == 1 and np.unique(block).size == 1 << k


def test_every_power_of_two_prefix_stratifies_each_pair():
    """A pixel's first 2^k passes put one point in each of the 2^k cells of every elementary
    grid (2^a x 2^(k - a)) of each pair: the (0, 2)-sequence property, kept by the scrambles."""
    for dim in (0, 1, 7, 30):
        key = pixel_keys(11, np.array([dim * 977 + 5]))[0]
        for k in (4, 6, 8):
            n = 1 << k
            p = _points(key, dim, n)
            assert p.min() >= 0.0 and p.max() < 1.0
            for a in range(k + 1):
                cells = (p[:, 0] * (1 << a)).astype(int) * (1 << (k - a)) + (p[:, 1] * (1 << (k - a))).astype(int)
                assert np.unique(cells).size == n, (dim, k, a)


def test_pairs_of_one_pixel_are_decorrelated_and_pixels_independent():
    """Chi-square on 16 x 16 bins: across 20000 pixels at one pass, each pair's points are
    uniform; within one pixel, the x of two pairs over 4096 passes are jointly uniform (the
    shuffles decorrelate them: without, they would be equal); and a pass's points of
    neighbouring pixels are jointly uniform."""

    def p_value(counts):
        e = counts.sum() / counts.size
        return chi2_sf(float(((counts - e) ** 2 / e).sum()), counts.size - 1)

    def joint(a, b):
        return np.bincount((a * 16).astype(int) * 16 + (b * 16).astype(int), minlength=256)

    keys = pixel_keys(0, np.arange(20000))
    for index in (0, 1, 37):
        p = np.array([_points(k, 3, 1, index)[0] for k in keys[:20000]])
        assert p_value(joint(p[:, 0], p[:, 1])) > SIGNIFICANCE
        assert p_value(joint(p[:-1, 0], p[1:, 0])) > SIGNIFICANCE
    one = keys[42]
    a, b = _points(one, 2, 4096), _points(one, 5, 4096)
    assert p_value(joint(a[:, 0], b[:, 0])) > SIGNIFICANCE
    assert p_value(joint(a[:, 1], b[:, 1])) > SIGNIFICANCE
    # A second seed's pixel keys differ everywhere: its passes are independent of the first's.
    assert np.all(pixel_keys(1, np.arange(1000)) != pixel_keys(0, np.arange(1000)))
