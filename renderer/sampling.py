"""Sample warps, discrete and piecewise-constant distributions, and MIS heuristics.

Every function takes its random numbers ``u`` as arguments (batch axis first) and is
deterministic. This is the only module that divides by a pdf: use ``safe_div`` so a pdf of 0
gives a contribution of 0, never Inf or NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

INV_PI = 1.0 / np.pi
INV_2PI = 0.5 / np.pi
INV_4PI = 0.25 / np.pi

# Below this sin^2(theta_max) the cone is sampled with a Taylor expansion, because 1 - cos
# cancels catastrophically (pbrt-v4 and Mitsuba use the same constant, sin^2 1.5 degrees).
SMALL_CONE_SIN2 = 0.00068523


def safe_div(num: np.ndarray, pdf: np.ndarray) -> np.ndarray:
    """num / pdf where pdf > 0 (and finite), else 0. num may be (n,) or (n, k); pdf is (n,)."""
    pdf = np.asarray(pdf, dtype=np.float64)
    ok = (pdf > 0.0) & np.isfinite(pdf)
    inv = np.divide(1.0, pdf, out=np.zeros_like(pdf), where=ok)
    num = np.asarray(num)
    return num * (inv[:, None] if num.ndim == 2 else inv)


def power_heuristic(n_f: float, pdf_f: np.ndarray, n_g: float, pdf_g: np.ndarray) -> np.ndarray:
    """Veach's power heuristic (beta = 2) weight for technique f, guarded against inf/0."""
    f = n_f * np.asarray(pdf_f, dtype=np.float64)
    g = n_g * np.asarray(pdf_g, dtype=np.float64)
    # Inf pdf (a delta-like technique) takes all the weight.
    f2 = np.where(np.isinf(f), 1.0, f * f)
    g2 = np.where(np.isinf(f), 0.0, np.where(np.isinf(g), np.inf, g * g))
    den = f2 + g2
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(den > 0.0, f2 / np.where(den > 0.0, den, 1.0), 0.0)
    return np.where(np.isfinite(w), w, 0.0)


def balance_heuristic(n_f: float, pdf_f: np.ndarray, n_g: float, pdf_g: np.ndarray) -> np.ndarray:
    """Balance heuristic weight for technique f, guarded against inf/0 as power_heuristic:
    an infinite pdf_f (a delta light) takes the whole weight (inf/inf would give NaN -> 0)."""
    f = n_f * np.asarray(pdf_f, dtype=np.float64)
    g = n_g * np.asarray(pdf_g, dtype=np.float64)
    den = f + g
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(den > 0.0, f / np.where(den > 0.0, den, 1.0), 0.0)
    return np.where(np.isinf(f), 1.0, np.where(np.isfinite(w), w, 0.0))


# --------------------------------------------------------------------------------------
# Warps
# --------------------------------------------------------------------------------------
def sample_uniform_disk_concentric(u: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of u (n, 2) in [0,1)^2 to the unit disk -> (n, 2)."""
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    use_a = np.abs(a) > np.abs(b)
    r = np.where(use_a, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = np.where(
            use_a,
            (np.pi / 4.0) * np.where(a != 0.0, b / np.where(a != 0.0, a, 1.0), 0.0),
            (np.pi / 2.0) - (np.pi / 4.0) * np.where(b != 0.0, a / np.where(b != 0.0, b, 1.0), 0.0),
        )
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)


def sample_cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """Cosine-weighted direction about +z (local frame), pdf = cos(theta)/pi. u (n, 2) -> (n, 3)."""
    d = sample_uniform_disk_concentric(u)
    z = np.sqrt(np.maximum(0.0, 1.0 - d[:, 0] ** 2 - d[:, 1] ** 2))
    return np.stack([d[:, 0], d[:, 1], z], axis=1)


def cosine_hemisphere_pdf(cos_theta: np.ndarray) -> np.ndarray:
    return np.maximum(cos_theta, 0.0) * INV_PI


def sample_uniform_sphere(u: np.ndarray) -> np.ndarray:
    """Uniform direction on the unit sphere, pdf = 1/(4 pi). u (n, 2) -> (n, 3)."""
    z = 1.0 - 2.0 * u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sample_uniform_cone(u: np.ndarray, cos_theta_max: np.ndarray) -> np.ndarray:
    """Uniform direction in the cone about +z with half-angle acos(cos_theta_max) -> (n, 3)."""
    cos_t = (1.0 - u[:, 0]) + u[:, 0] * cos_theta_max
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


def uniform_cone_pdf(cos_theta_max: np.ndarray) -> np.ndarray:
    return safe_div(np.full(np.shape(cos_theta_max), INV_2PI), 1.0 - np.asarray(cos_theta_max))


def sample_uniform_triangle(u: np.ndarray) -> np.ndarray:
    """Uniform barycentrics (b0, b1, b2) on a triangle from u (n, 2) (Heitz 2019 low-distortion map)."""
    b0 = np.where(u[:, 0] < u[:, 1], u[:, 0] / 2.0, u[:, 0] - u[:, 1] / 2.0)
    b1 = np.where(u[:, 0] < u[:, 1], u[:, 1] - b0, u[:, 1] / 2.0)
    return np.stack([b0, b1, 1.0 - b0 - b1], axis=1)


# --------------------------------------------------------------------------------------
# Discrete distributions
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AliasTable:
    """Walker/Vose alias table over n weights: O(1) sampling, exact pmf.

    q: (n,) acceptance probabilities; alias: (n,) int; pmf: (n,) normalised weights.
    """

    q: np.ndarray
    alias: np.ndarray
    pmf: np.ndarray

    @staticmethod
    def build(weights: np.ndarray) -> "AliasTable":
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 1 or w.size == 0:
            raise ValueError("AliasTable needs a non-empty 1-D weight array")
        w = np.where(np.isfinite(w) & (w > 0.0), w, 0.0)
        total = w.sum()
        n = w.size
        if total <= 0.0:
            pmf = np.full(n, 1.0 / n)
        else:
            pmf = w / total
        scaled = pmf * n
        q = np.ones(n)
        alias = np.arange(n)
        small = [i for i in np.nonzero(scaled < 1.0)[0]]
        large = [i for i in np.nonzero(scaled >= 1.0)[0]]
        scaled = scaled.copy()
        # Vose's method. O(n) Python for the build only; sampling is vectorised.
        while small and large:
            s = small.pop()
            g = large.pop()
            q[s] = scaled[s]
            alias[s] = g
            scaled[g] = (scaled[g] + scaled[s]) - 1.0
            (small if scaled[g] < 1.0 else large).append(g)
        for i in large + small:
            q[i] = 1.0
        # Zero-weight entries must never be returned: an entry with pmf 0 keeps q = 0.
        q = np.where(pmf > 0.0, q, 0.0)
        return AliasTable(q=q, alias=alias.astype(np.int64), pmf=pmf)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u (m,) in [0,1) -> (index (m,) int64, pmf (m,))."""
        n = self.q.size
        x = np.asarray(u, dtype=np.float64) * n
        i = np.minimum(x.astype(np.int64), n - 1)
        frac = x - i
        idx = np.where(frac < self.q[i], i, self.alias[i])
        return idx, self.pmf[idx]


@dataclass(frozen=True)
class Distribution1D:
    """Piecewise-constant 1-D distribution over [0, 1) with n cells.

    func: (n,) non-negative cell values; cdf: (n+1,); integral: mean of func over [0,1).
    """

    func: np.ndarray
    cdf: np.ndarray
    integral: float

    @staticmethod
    def build(func: np.ndarray) -> "Distribution1D":
        f = np.where(np.isfinite(func) & (func > 0.0), np.asarray(func, dtype=np.float64), 0.0)
        n = f.size
        cdf = np.concatenate([[0.0], np.cumsum(f) / n])
        integral = float(cdf[-1])
        if integral <= 0.0:
            cdf = np.linspace(0.0, 1.0, n + 1)
        else:
            cdf = cdf / integral
        cdf[-1] = 1.0
        return Distribution1D(func=f, cdf=cdf, integral=integral)

    @property
    def count(self) -> int:
        return self.func.size

    def sample_continuous(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """u (m,) -> (x in [0,1) (m,), pdf (m,) w.r.t. x, cell index (m,))."""
        n = self.func.size
        idx = np.clip(np.searchsorted(self.cdf, u, side="right") - 1, 0, n - 1)
        width = self.cdf[idx + 1] - self.cdf[idx]
        du = np.where(width > 0.0, (u - self.cdf[idx]) / np.where(width > 0.0, width, 1.0), 0.0)
        x = (idx + du) / n
        pdf = self.pdf_cell(idx)
        return np.minimum(x, np.nextafter(1.0, 0.0)), pdf, idx

    def pdf_cell(self, idx: np.ndarray) -> np.ndarray:
        """Density w.r.t. x in [0,1) for points in cell idx."""
        if self.integral <= 0.0:
            return np.ones(np.shape(idx))
        return self.func[idx] / self.integral


@dataclass(frozen=True)
class Distribution2D:
    """Piecewise-constant 2-D distribution over [0,1)^2 from an (ny, nx) image of weights.

    Rows (v, the y axis) are chosen by the marginal, then columns (u) by the row's conditional.
    """

    marginal: Distribution1D
    conditional_cdf: np.ndarray  # (ny, nx+1)
    func: np.ndarray  # (ny, nx)
    row_integral: np.ndarray  # (ny,)

    @staticmethod
    def build(func: np.ndarray) -> "Distribution2D":
        f = np.where(np.isfinite(func) & (func > 0.0), np.asarray(func, dtype=np.float64), 0.0)
        ny, nx = f.shape
        cdf = np.concatenate([np.zeros((ny, 1)), np.cumsum(f, axis=1) / nx], axis=1)
        row_integral = cdf[:, -1].copy()
        safe = np.where(row_integral > 0.0, row_integral, 1.0)
        cdf = np.where(
            row_integral[:, None] > 0.0, cdf / safe[:, None], np.linspace(0.0, 1.0, nx + 1)[None, :]
        )
        cdf[:, -1] = 1.0
        return Distribution2D(
            marginal=Distribution1D.build(row_integral),
            conditional_cdf=cdf,
            func=f,
            row_integral=row_integral,
        )

    def sample_continuous(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u (m, 2) -> (uv (m, 2) in [0,1)^2, pdf (m,) w.r.t. area in [0,1)^2)."""
        ny, nx = self.func.shape
        v, _, row = self.marginal.sample_continuous(u[:, 1])
        cdf = self.conditional_cdf[row]
        col = np.clip((cdf <= u[:, 0:1]).sum(axis=1) - 1, 0, nx - 1)
        lo = cdf[np.arange(col.size), col]
        hi = cdf[np.arange(col.size), col + 1]
        width = hi - lo
        du = np.where(width > 0.0, (u[:, 0] - lo) / np.where(width > 0.0, width, 1.0), 0.0)
        x = np.minimum((col + du) / nx, np.nextafter(1.0, 0.0))
        return np.stack([x, v], axis=1), self.pdf(np.stack([x, v], axis=1))

    def pdf(self, uv: np.ndarray) -> np.ndarray:
        """Density w.r.t. area in [0,1)^2 at uv (m, 2)."""
        ny, nx = self.func.shape
        ix = np.clip((uv[:, 0] * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip((uv[:, 1] * ny).astype(np.int64), 0, ny - 1)
        total = self.marginal.integral
        if total <= 0.0:
            return np.ones(uv.shape[0])
        return self.func[iy, ix] / total


# --------------------------------------------------------------------------------------
# Progressive pixel samples: a rank-1 lattice sequence per pixel
# --------------------------------------------------------------------------------------
def _sobol2(k: int) -> tuple[int, int]:
    """Point k of the 2D Sobol' (0,2)-sequence as two 32-bit integers: the first coordinate is
    the base-2 radical inverse of k, the second uses Sobol's direction numbers for x + 1
    (v_1 = 2^31, v_i = v_(i-1) xor v_(i-1) >> 1). Every power-of-two prefix stratifies both
    axes and the unit square's elementary intervals, which a progressive film needs (it may
    stop after any pass)."""
    x = int(f"{k & 0xFFFFFFFF:032b}"[::-1], 2)
    y, v = 0, 1 << 31
    while k:
        if k & 1:
            y ^= v
        k >>= 1
        v ^= v >> 1
    return x, y


def _seed_key(seed: int) -> np.uint64:
    """The seed's term of pixel_sequence's hash keys, wrapped to 64 bits in Python ints (a numpy
    uint64 scalar product would warn when it wraps, an error under the tests' filterwarnings)."""
    return np.uint64(((seed & 0xFFFFFFFF) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF)


def _hash_increment(stream: int) -> np.uint64:
    """The splitmix64 key offset of random stream ``stream`` (a multiple of the golden ratio)."""
    return np.uint64((0x9E3779B97F4A7C15 * (stream + 1)) & 0xFFFFFFFFFFFFFFFF)


def _hash_bits(keys: np.ndarray, stream: int) -> np.ndarray:
    """Deterministic 64 random bits per uint64 key (splitmix64 finaliser)."""
    z = keys.astype(np.uint64) + _hash_increment(stream)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def pixel_sequence(seed: int, pixel: np.ndarray, index: int) -> np.ndarray:
    """Sample ``index`` (the pass number) of each pixel's own 2D Sobol' sequence -> (n, 2) in [0, 1).

    Each pixel's sequence is XOR-scrambled by a random 32-bit key per axis hashed from
    (seed, pixel) (a random digital shift), so every pass is uniformly distributed and the
    progressive estimate stays unbiased, while the passes of one pixel fill the pixel filter's
    domain evenly: anti-aliasing noise falls faster than 1/N, which matters where a subpixel
    emitter (a firefly of hundreds of nits) covers part of a pixel. Only the filter uses it: a
    second sequence for the lens, indexed alike, would be correlated with the first.
    """
    p = np.asarray(pixel)
    x, y = _sobol2(int(index))
    if p.ndim != 1 or p.dtype.kind not in "iu":
        return _pixel_sequence_numpy(seed, p, x, y)
    p = np.ascontiguousarray(p.astype(np.uint64, copy=False)).view(np.int64)  # two's complement bits
    out = np.empty((p.shape[0], 2))
    _pixel_sequence_kernel(p, _seed_key(seed),
                           _hash_increment(0), _hash_increment(1), np.uint64(x), np.uint64(y), out)
    return out


def _pixel_sequence_numpy(seed: int, pixel: np.ndarray, x: int, y: int) -> np.ndarray:
    """pixel_sequence in numpy for pixels of any shape (...,) -> (..., 2), given the Sobol' point (x, y)."""
    keys = np.asarray(pixel, dtype=np.uint64) * np.uint64(4) + _seed_key(seed)
    scrambled = [(_hash_bits(keys, axis) >> np.uint64(32)) ^ np.uint64(bits) for axis, bits in enumerate((x, y))]
    return np.stack(scrambled, axis=-1).astype(np.float64) * (1.0 / 4294967296.0)


@njit(cache=True, nogil=True)
def _pixel_sequence_kernel(pixel, seed_key, inc0, inc1, x, y, out):
    """pixel_sequence in one pass (conventions: renderer/kernels/__init__.py): pixel (n,) int64
    bits of the uint64 keys, seed_key the seed's key term, inc0/inc1 _hash_bits' increments for
    streams 0 and 1, (x, y) the Sobol' point; writes out (n, 2). All integer maths in uint64
    (mixed with int64, numba would promote to float64)."""
    m1 = np.uint64(0xBF58476D1CE4E5B9)
    m2 = np.uint64(0x94D049BB133111EB)
    s27 = np.uint64(27)
    s30 = np.uint64(30)
    s31 = np.uint64(31)
    s32 = np.uint64(32)
    for i in range(pixel.shape[0]):
        key = np.uint64(pixel[i]) * np.uint64(4) + seed_key
        z = key + inc0
        z = (z ^ (z >> s30)) * m1
        z = (z ^ (z >> s27)) * m2
        z = z ^ (z >> s31)
        out[i, 0] = np.float64((z >> s32) ^ x) * (1.0 / 4294967296.0)
        z = key + inc1
        z = (z ^ (z >> s30)) * m1
        z = (z ^ (z >> s27)) * m2
        z = z ^ (z >> s31)
        out[i, 1] = np.float64((z >> s32) ^ y) * (1.0 / 4294967296.0)
