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
def sobol_second32(i):
    """Sobol's second dimension of index i (32 bits): the XOR of direction numbers v_(k+1) over
    the set bits k of i, v_1 = 2^31, v_(k+1) = v_k ^ (v_k >> 1), by Horner's rule from the top
    bit (branch-free: 32 shift-xor steps)."""
    acc = np.uint64(0)
    for k in range(31, -1, -1):
        acc = (acc ^ (acc >> np.uint64(1))) ^ (((i >> np.uint64(k)) & np.uint64(1)) << np.uint64(31))
    return acc


@njit(cache=True, nogil=True, inline="always")
def mix64(z):
    """SplitMix64's finaliser: 64 well-mixed bits of the uint64 z."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, nogil=True, inline="always")
def sobol_u01(pixel_key, index, dim, coord):
    """Coordinate coord (0 or 1; 0 for a 1D decision) of sample ``index`` (uint64, the pixel's
    pass number) of dimension pair ``dim`` (uint64, unique per bounce and decision) in the pixel
    whose key is pixel_key (uint64, pixel_keys' hash of the pixel and the render seed): a double
    in [0, 1)."""
    h = mix64(pixel_key + (dim + np.uint64(1)) * _GAMMA)
    j = shuffle_index32(index, h & _M32)
    if coord == 0:
        v = reverse_bits32(j)
    else:
        v = sobol_second32(j)
    s = mix64(h + np.uint64(coord + 1) * _GAMMA)
    return float(owen_scramble32(v, s >> np.uint64(32))) * _INV32


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
