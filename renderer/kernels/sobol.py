"""Per-pixel low-discrepancy numbers for the path's bounces: padded, shuffled, Owen-scrambled Sobol'.

Each pixel draws its samples' numbers from its own randomised 2D Sobol' (0,2)-sequence, one per
*dimension pair* (a 2D decision of a bounce: the BSDF's direction, a light's point on its
surface) or per 1D decision (the lobe, the roulette, the light pick), as pbrt-v4's PaddedSobol
and Cycles' Sobol-Burley samplers do:

* sample ``index`` of the pixel (its pass number) is first *shuffled*: an Owen scramble of the
  index bits, keyed per pixel and dimension pair. The shuffle maps every aligned block of 2^k
  indices onto an aligned block of 2^k, whose points are a net as the first 2^k are, so the
  first 2^k passes still stratify, while two dimension pairs of one pixel visit their points
  in unrelated orders (no correlation between, say, the light point and the BSDF direction);
* the shuffled index's Sobol' point (the base-2 radical inverse and Sobol's second dimension)
  is Owen-scrambled (nested uniform scrambling, most significant bit first) with keys of the
  pixel and pair: every number is uniform in [0, 1) on its own, so each pass stays an unbiased
  estimate, while a pixel's passes stratify every pair's square and each 1D decision's line.

The nested scrambles use the hash of Laine and Karras (2011) with the constants of Burley,
"Practical Hash-based Owen Scrambling" (JCGT 2020): x += seed, then x ^= x * c for four even c,
in which bit k of the result depends on input bits k and below only: a nested permutation of
the bit-reversed value. Numbers carry 32 bits (steps of 2.3e-10).

Against independent numbers the error of a pixel falls faster than 1/N where its integrand is
smooth in a pair's two numbers (soft shadows, glossy lobes, the first diffuse bounce): what
RenderMan, Karma and Cycles draw by default. tests/kernels/test_sobol.py checks the sequence
against sampling._sobol2, the scrambles' stratification and the uniformity (chi-square).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_M32 = np.uint64(0xFFFFFFFF)
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_INV32 = 1.0 / 4294967296.0


@njit(cache=True, nogil=True, inline="always")
def reverse_bits32(x):
    """The 32 low bits of x (uint64) in reverse order (uint64 below 2^32): swaps of halves,
    bytes, nibbles, pairs and bits (branch-free, so loops over rows vectorise)."""
    x = ((x >> np.uint64(16)) | (x << np.uint64(16))) & _M32
    x = ((x >> np.uint64(8)) & np.uint64(0x00FF00FF)) | ((x & np.uint64(0x00FF00FF)) << np.uint64(8))
    x = ((x >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | ((x & np.uint64(0x0F0F0F0F)) << np.uint64(4))
    x = ((x >> np.uint64(2)) & np.uint64(0x33333333)) | ((x & np.uint64(0x33333333)) << np.uint64(2))
    x = ((x >> np.uint64(1)) & np.uint64(0x55555555)) | ((x & np.uint64(0x55555555)) << np.uint64(1))
    return x


@njit(cache=True, nogil=True, inline="always")
def _lk_permute(x, seed):
    """Laine-Karras hash of the 32-bit x keyed by the 32-bit seed: bit k of the result depends
    on bits 0..k of x only (additions and products by even constants carry upwards)."""
    x = (x + seed) & _M32
    x = (x ^ (x * np.uint64(0x6C50B47C))) & _M32
    x = (x ^ (x * np.uint64(0xB82F1E52))) & _M32
    x = (x ^ (x * np.uint64(0xC7AFE638))) & _M32
    x = (x ^ (x * np.uint64(0x8D22F6E6))) & _M32
    return x


@njit(cache=True, nogil=True, inline="always")
def owen_scramble32(x, seed):
    """Nested uniform (Owen) scrambling of the 32-bit fraction x (most significant bit first),
    keyed by seed: the hash on the bit-reversed value, reversed back."""
    return reverse_bits32(_lk_permute(reverse_bits32(x), seed))


@njit(cache=True, nogil=True, inline="always")
def shuffle_index32(i, seed):
    """The Owen scramble of a sample index (as a 32-bit fraction, most significant bit first):
    a permutation of 0..2^32-1 that maps each aligned block of 2^k indices onto an aligned
    block of 2^k (the Sobol' points of any such block form a net), while its low bits, which
    order the block, depend on all the index's higher bits: two pairs shuffled with different
    seeds visit their points in unrelated orders."""
    return owen_scramble32(i & _M32, seed)


@njit(cache=True, nogil=True, inline="always")
def _superset_xor32(i):
    """Bit m of the result: the XOR of the bits k of i (32 bits) whose positions contain m's
    (k & m == m): the subset-sum transform on the five-bit positions, one shift-mask step per
    position bit."""
    i = i ^ ((i >> np.uint64(1)) & np.uint64(0x55555555))
    i = i ^ ((i >> np.uint64(2)) & np.uint64(0x33333333))
    i = i ^ ((i >> np.uint64(4)) & np.uint64(0x0F0F0F0F))
    i = i ^ ((i >> np.uint64(8)) & np.uint64(0x00FF00FF))
    i = i ^ ((i >> np.uint64(16)) & np.uint64(0x0000FFFF))
    return i


@njit(cache=True, nogil=True, inline="always")
def sobol_second32(i):
    """Sobol's second dimension of index i (32 bits): the XOR of the direction numbers v_(k+1)
    over the set bits k of i, with v_1 = 2^31 and v_(k+1) = v_k ^ (v_k >> 1). Then
    v_(k+1) = sum_m C(k, m) 2^(31 - m), and C(k, m) is odd when m's bits are a subset of k's
    (Lucas): bit 31 - m of the result is the XOR of i's bits at the supersets of m, the
    reversed _superset_xor32."""
    return reverse_bits32(_superset_xor32(i & _M32))


@njit(cache=True, nogil=True, inline="always")
def mix64(z):
    """SplitMix64's finaliser: 64 well-mixed bits of the uint64 z."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True, inline="always")
def sobol_pair(pixel_key, index, dim):
    """The point (x, y), doubles in [0, 1), of sample ``index`` (uint64, the pixel's pass
    number) of dimension pair ``dim`` (uint64, unique per bounce and decision) in the pixel whose
    key is pixel_key (uint64, pixel_keys' hash of the pixel and the render seed); a 1D decision
    takes x. Branch-free, so loops over rows vectorise."""
    h = mix64(pixel_key + (dim + np.uint64(1)) * _GAMMA)
    j = shuffle_index32(index, h & _M32)
    s0 = mix64(h + _GAMMA) >> np.uint64(32)
    s1 = mix64(h + np.uint64(2) * _GAMMA) >> np.uint64(32)
    # owen_scramble32 of the point's coordinates, whose reversals are j itself (the radical
    # inverse) and _superset_xor32(j) (sobol_second32): the outer reversals cancel.
    x = float(reverse_bits32(_lk_permute(j, s0))) * _INV32
    y = float(reverse_bits32(_lk_permute(_superset_xor32(j), s1))) * _INV32
    return x, y


@njit(cache=True, nogil=True, inline="always")
def sobol_u01(pixel_key, index, dim, coord):
    """Coordinate coord (0 or 1; 0 for a 1D decision) of sobol_pair's point."""
    x, y = sobol_pair(pixel_key, index, dim)
    return x if coord == 0 else y


def pixel_keys(seed: int, pixel: np.ndarray) -> np.ndarray:
    """(n,) uint64 scramble keys of the pixels (flat indices, (n,) int) for the render seed:
    distinct seeds give independent scrambles (a second seed's passes are independent of the
    first's), one pixel's key is the same in every pass (its passes stratify)."""
    p = np.asarray(pixel, dtype=np.int64).astype(np.uint64)
    s = np.uint64(seed & 0xFFFFFFFFFFFFFFFF)
    with np.errstate(over="ignore"):
        z = p * np.uint64(0xD1B54A32D192ED03) + s * _GAMMA + np.uint64(0x632BE59BD9B4E019)
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
        return z ^ (z >> np.uint64(31))
