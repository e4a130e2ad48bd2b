"""Progressive film: per-pixel running sums, a variance estimate, and EXR/PNG output.

Two modes (renderer/pixel_filter.py says which is the default and why):
* filter importance sampling (``Film(..., splat=None)``): each sample was drawn from the pixel
  filter, has weight 1 and adds to its own pixel only;
* splatting (``Film(..., splat=PixelFilter)``): each sample, taken uniformly in its pixel, adds
  w = f(dx, dy) times its radiance into every data-window pixel whose footprint covers it
  (``_splat_kernel``); a pixel is sum(w L) / sum(w). Samples are not taken outside the data
  window, so its edge pixels weigh the part of their footprint inside it (as Mitsuba's film
  without ``sample_border``).

Both keep the same moments per pixel -- sum = sum(w L), sum_sq = sum(w^2 L^2), sum_w2 =
sum(w^2 L), weight = (sum w, sum w^2, sum w^3) -- where importance sampling's w = 1 makes the
last two the sum and the count, so it stores neither; one formula (``variance_of_mean``) serves
both. ``count`` is the camera samples taken in each pixel, the samples per pixel, in both.

Policy for unusual samples (documented in docs/design.md, "Film policy"):
* non-finite samples (NaN/Inf in any channel) are dropped -- the pixel's sample count is not
  increased -- and counted in ``nonfinite_dropped``; output can therefore never hold NaN/Inf;
* negative samples are *kept* (the alpha = 1 control variate is unbiased only if they are) and
  counted in ``negative_samples``; the EXR stores the signed mean; the PNG preview clamps to
  [0, 1] for display only.

Files are written to a temporary name in the same directory and renamed, so a crash never
leaves a half-written image under the final name.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .output import srgb_encode, write_image  # noqa: F401  (srgb_encode: re-exported)
from .pixel_filter import PixelFilter


_F32_MAX = float(np.finfo(np.float32).max)


@njit(cache=True, nogil=True, inline="always")
def _sample_kind(r, g, b) -> int:
    """The film's policy for one sample's RGB (module docstring): -1 when a channel is not
    finite (dropped), 1 when one is negative (kept, counted), else 0."""
    if not (np.isfinite(r) and np.isfinite(g) and np.isfinite(b)):
        return -1
    return 1 if (r < 0.0 or g < 0.0 or b < 0.0) else 0


@njit(cache=True, nogil=True)
def _add_kernel(rows, L, flat_sum, flat_sq, flat_n):
    """Film.add in one pass (conventions: renderer/kernels/__init__.py): rows (n,) flat pixel
    indices (negative ones count from the end, as in numpy), L (n, 3); adds each finite row of L
    to flat_sum (m, 3), its square to flat_sq and 1 to flat_n (m,), one row after another, so
    repeated rows accumulate (np.add.at semantics). Returns (nonfinite rows dropped, negative
    rows kept), or (-1, -1) with nothing added when an index is out of range."""
    m = flat_n.shape[0]
    for i in range(rows.shape[0]):  # validate first: an IndexError must leave the film untouched
        if rows[i] < -m or rows[i] >= m:
            return -1, -1
    dropped = 0
    negative = 0
    for i in range(rows.shape[0]):
        r = L[i, 0]
        g = L[i, 1]
        b = L[i, 2]
        kind = _sample_kind(r, g, b)
        if kind < 0:
            dropped += 1
            continue
        negative += kind
        k = rows[i]
        if k < 0:
            k += m
        flat_sum[k, 0] += r
        flat_sum[k, 1] += g
        flat_sum[k, 2] += b
        flat_sq[k, 0] += r * r
        flat_sq[k, 1] += g * g
        flat_sq[k, 2] += b * b
        flat_n[k] += 1
    return dropped, negative


@njit(cache=True, nogil=True, inline="always")
def _profile_row(s, j0, j1, values, scale, out):
    """out[j - j0] = f1(|s - (j + 0.5)|) for pixels j0..j1 of one axis, lerped in values (V,)
    (f1 at evenly spaced |x| in [0, radius], scale = (V - 1) / radius); 0 from the radius on."""
    last = values.shape[0] - 1
    for j in range(j0, j1 + 1):
        t = abs(s - (j + 0.5)) * scale
        q = int(t)
        out[j - j0] = values[q] + (t - q) * (values[q + 1] - values[q]) if q < last else 0.0


@njit(cache=True, nogil=True, inline="always")
def splat_scratch(values, radius):
    """(scale, wx, wy, ps, ws): splat_weights' lerp scale for the filter profile values (V,) of
    radius pixels, and its scratch arrays for the filter's span."""
    span = int(math.ceil(2.0 * radius)) + 1
    return ((values.shape[0] - 1) / radius, np.empty(span), np.empty(span), np.empty(span * span, dtype=np.int64),
            np.empty(span * span))


@njit(cache=True, nogil=True, inline="always")
def splat_weights(k, ox, oy, width, height, radius, values, scale, wx, wy, ps, ws):
    """The pixels a sample splats to and their weights: n, with ps[:n] the flat data-window
    pixels (row-major over width columns) whose centres lie strictly within radius of the sample
    taken in flat pixel k at offset (ox, oy) from its centre, in x and in y, and ws[:n] > 0 their
    weights f1(dx) f1(dy) (_profile_row; wx, wy: scratch of the filter's span)."""
    # The sample in pixel units; pixel j's centre is j + 0.5.
    sx = (k % width) + 0.5 + ox
    sy = (k // width) + 0.5 + oy
    jx0 = max(int(math.floor(sx - 0.5 - radius)) + 1, 0)
    jx1 = min(int(math.ceil(sx - 0.5 + radius)) - 1, width - 1)
    jy0 = max(int(math.floor(sy - 0.5 - radius)) + 1, 0)
    jy1 = min(int(math.ceil(sy - 0.5 + radius)) - 1, height - 1)
    _profile_row(sx, jx0, jx1, values, scale, wx)
    _profile_row(sy, jy0, jy1, values, scale, wy)
    n = 0
    for y in range(jy0, jy1 + 1):
        for x in range(jx0, jx1 + 1):
            w = wy[y - jy0] * wx[x - jx0]
            if w > 0.0:
                ps[n] = y * width + x
                ws[n] = w
                n += 1
    return n


@njit(cache=True, nogil=True)
def _splat_kernel(rows, off, L, count_rows, values, radius, width, flat_sum, flat_sq, flat_w2x, flat_weight,
                  flat_n):
    """Film.add in splatting mode (conventions: renderer/kernels/__init__.py): sample i, taken in
    data-window pixel rows[i] (flat, row-major over width columns, 0 <= rows[i] < m) at offset
    off[i] (2,) pixels from its centre, adds w = f1(dx) f1(dy) times L[i] (3,) to every pixel of
    the data window whose centre lies strictly within radius of it in x and in y (f1 lerped from
    values (V,), f1 at evenly spaced |x| in [0, radius]): w L to flat_sum, w^2 L^2 to flat_sq,
    w^2 L to flat_w2x (m, 3), (w, w^2, w^3) to flat_weight (m, 3); and 1 to flat_n[rows[i]] when
    count_rows. Rows with non-finite L or offsets are dropped. Returns (dropped, negative), or
    (-1, -1) with nothing added when a row is out of range."""
    m = flat_n.shape[0]
    height = m // width
    for i in range(rows.shape[0]):  # validate first: an IndexError must leave the film untouched
        if rows[i] < 0 or rows[i] >= m:
            return -1, -1
    scale, wx, wy, ps, ws = splat_scratch(values, radius)
    dropped = 0
    negative = 0
    for i in range(rows.shape[0]):
        r = L[i, 0]
        g = L[i, 1]
        b = L[i, 2]
        ox = off[i, 0]
        oy = off[i, 1]
        kind = _sample_kind(r, g, b)
        if kind < 0 or not (np.isfinite(ox) and np.isfinite(oy)):
            dropped += 1
            continue
        negative += kind
        k = rows[i]
        if count_rows:
            flat_n[k] += 1
        for j in range(splat_weights(k, ox, oy, width, height, radius, values, scale, wx, wy, ps, ws)):
            p = ps[j]
            w = ws[j]
            w2 = w * w
            flat_sum[p, 0] += w * r
            flat_sum[p, 1] += w * g
            flat_sum[p, 2] += w * b
            flat_w2x[p, 0] += w2 * r
            flat_w2x[p, 1] += w2 * g
            flat_w2x[p, 2] += w2 * b
            flat_sq[p, 0] += w2 * r * r
            flat_sq[p, 1] += w2 * g * g
            flat_sq[p, 2] += w2 * b * b
            flat_weight[p, 0] += w
            flat_weight[p, 1] += w2
            flat_weight[p, 2] += w2 * w
    return dropped, negative


@dataclass
class Film:
    """width x height film with a data window (x0, y0, x1, y1) in pixels (half-open).

    sum, sum_sq: (h, w, 3) float64 over the data window (sum(w L), sum(w^2 L^2)); count: (h, w)
    camera samples taken in each pixel. splat: the pixel filter a splatting film spreads samples
    with (module docstring), None for filter importance sampling; a splatting film also keeps
    sum_w2 (h, w, 3) = sum(w^2 L) and weight (h, w, 3) = (sum w, sum w^2, sum w^3).
    """

    width: int
    height: int
    window: tuple[int, int, int, int] | None = None
    splat: PixelFilter | None = None
    sum: np.ndarray = field(init=False)
    sum_sq: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)
    sum_w2: np.ndarray | None = field(init=False, default=None)
    weight: np.ndarray | None = field(init=False, default=None)
    nonfinite_dropped: int = 0
    negative_samples: int = 0
    overflow_clamped: int = 0

    def __post_init__(self):
        if self.window is None:
            self.window = (0, 0, self.width, self.height)
        x0, y0, x1, y1 = self.window
        h, w = y1 - y0, x1 - x0
        self.sum = np.zeros((h, w, 3))
        self.sum_sq = np.zeros((h, w, 3))
        self.count = np.zeros((h, w), dtype=np.int64)
        if self.splat is not None:
            self.sum_w2 = np.zeros((h, w, 3))
            self.weight = np.zeros((h, w, 3))

    @staticmethod
    def bytes_per_pixel(splat: bool) -> int:
        """Bytes a data-window pixel takes: the arrays __post_init__ allocates (float64 RGB sums,
        int64 count; a splatting film two more RGB sums), plus what writing it needs at once
        (mean(): a float64 RGB quotient, a boolean mask and the float32 result)."""
        accumulated = 2 * 3 * 8 + 8 + (2 * 3 * 8 if splat else 0)
        return accumulated + 3 * 8 + 3 + 3 * 4

    @property
    def shape(self) -> tuple[int, int]:
        return self.sum.shape[0], self.sum.shape[1]

    @property
    def mode(self) -> str:
        """'splat' or 'importance' (pixel_filter.MODES)."""
        return "importance" if self.splat is None else "splat"

    def pixel_coords(self) -> tuple[np.ndarray, np.ndarray]:
        """Full-image pixel coordinates (px, py) of every data-window pixel, row-major, (h*w,) each."""
        x0, y0, x1, y1 = self.window
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return xs.ravel(), ys.ravel()

    def add(self, rows: np.ndarray, L: np.ndarray, unique: bool = True, offsets: np.ndarray | None = None,
            count: bool = True) -> None:
        """Add one sample per entry: rows (n,) flat data-window pixel indices, L (n, 3) radiance.

        offsets (n, 2): where in its pixel each sample was taken, in pixels from the centre; a
        splatting film needs them (and takes rows in [0, h w) only), importance sampling ignores
        them. count: whether the samples count toward their pixels' ``count`` (False for the
        extra camera rays of emitter samples, renderer/integrators/path.py).

        unique: rows hold no repeats (one sample per pixel, the progressive case). The compiled
        pass (_add_kernel) adds rows one after another, so repeats accumulate either way (the
        np.add.at semantics unique=False asks for); the flag is kept for callers' intent.
        """
        rows = np.asarray(rows)
        L = np.asarray(L)
        if self.splat is not None:
            if offsets is None:
                raise ValueError("a splatting film needs each sample's offset in its pixel")
            f = self.splat
            dropped, negative = _splat_kernel(
                np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(offsets, dtype=np.float64),
                np.ascontiguousarray(L, dtype=np.float64), bool(count), f._values, float(f.radius),
                int(self.shape[1]), self.sum.reshape(-1, 3), self.sum_sq.reshape(-1, 3),
                self.sum_w2.reshape(-1, 3), self.weight.reshape(-1, 3), self.count.reshape(-1))
            if dropped < 0:
                raise IndexError(f"film rows out of range [0, {self.count.size})")
            self.nonfinite_dropped += int(dropped)
            self.negative_samples += int(negative)
            return
        if not count:
            raise ValueError("a filter importance sampling film counts every sample")
        # float64 L only: float32 would square in float32 in numpy; other inputs take the numpy path.
        if rows.ndim == 1 and rows.dtype.kind == "i" and L.dtype == np.float64 and L.shape == (rows.shape[0], 3):
            flat_sum = self.sum.reshape(-1, 3)
            flat_sq = self.sum_sq.reshape(-1, 3)
            flat_n = self.count.reshape(-1)
            if (flat_sum.flags.c_contiguous and flat_sq.flags.c_contiguous and flat_n.flags.c_contiguous
                    and flat_sum.dtype == np.float64 and flat_sq.dtype == np.float64 and flat_n.dtype == np.int64):
                dropped, negative = _add_kernel(np.ascontiguousarray(rows, dtype=np.int64),
                                                np.ascontiguousarray(L), flat_sum, flat_sq, flat_n)
                if dropped < 0:
                    raise IndexError(f"film rows out of range [0, {flat_n.shape[0]})")
                self.nonfinite_dropped += int(dropped)
                self.negative_samples += int(negative)
                return
        self._add_numpy(rows, L, unique)

    def _add_numpy(self, rows: np.ndarray, L: np.ndarray, unique: bool = True) -> None:
        """add in numpy, for inputs the kernel does not take (and the reference it is tested against)."""
        ok = np.all(np.isfinite(L), axis=1)
        bad = int((~ok).sum())
        if bad:
            self.nonfinite_dropped += bad
            rows = rows[ok]
            L = L[ok]
        self.negative_samples += int(np.any(L < 0.0, axis=1).sum())
        h, w = self.shape
        flat_sum = self.sum.reshape(-1, 3)
        flat_sq = self.sum_sq.reshape(-1, 3)
        flat_n = self.count.reshape(-1)
        if unique:
            flat_sum[rows] += L
            flat_sq[rows] += L * L
            flat_n[rows] += 1
        else:
            np.add.at(flat_sum, rows, L)
            np.add.at(flat_sq, rows, L * L)
            np.add.at(flat_n, rows, 1)

    def _arrays(self) -> dict:
        """The accumulated arrays by name (what merge adds, copy owns and save_state writes)."""
        out = {"sum": self.sum, "sum_sq": self.sum_sq, "count": self.count}
        if self.splat is not None:
            out.update(sum_w2=self.sum_w2, weight=self.weight)
        return out

    def merge(self, other: "Film") -> None:
        """Accumulate another film's samples (same size/window/mode): how distributed passes combine."""
        if (other.width, other.height, other.window, other.mode) != (self.width, self.height, self.window, self.mode):
            raise ValueError("cannot merge films of different size, window or mode")
        mine = self._arrays()
        for name, a in other._arrays().items():
            mine[name] += a
        self.nonfinite_dropped += other.nonfinite_dropped
        self.negative_samples += other.negative_samples

    def copy(self) -> "Film":
        """A film owning copies of this one's arrays (the Ray backend's blocks arrive read-only)."""
        out = Film(self.width, self.height, self.window, self.splat)
        for name, a in self._arrays().items():
            setattr(out, name, np.array(a, copy=True))
        out.nonfinite_dropped = self.nonfinite_dropped
        out.negative_samples = self.negative_samples
        return out

    def _moments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(W1, W2, W3) (h, w, 1) = sums of w, w^2, w^3 and sum_w2 (h, w, 3) = sum(w^2 L); with
        importance sampling's w = 1 they are the count (thrice) and the sum."""
        if self.splat is None:
            n = self.count[:, :, None].astype(np.float64)
            return n, n, n, self.sum
        return self.weight[:, :, 0:1], self.weight[:, :, 1:2], self.weight[:, :, 2:3], self.sum_w2

    def mean(self) -> np.ndarray:
        """(h, w, 3) float32 per-pixel value sum(w L) / sum(w) of the data window (0 where no
        sample weighs in yet).

        Means beyond the float32 range are clamped to its limit (``overflow_clamped`` counts
        them): the EXR cannot hold them, and Inf must never reach a file.
        """
        W1 = self._moments()[0]
        m = self.sum / np.where(W1 > 0.0, W1, 1.0)
        big = np.abs(m) > _F32_MAX
        self.overflow_clamped = int(big.any(axis=2).sum())
        return np.clip(m, -_F32_MAX, _F32_MAX).astype(np.float32)

    def variance_of_mean(self) -> np.ndarray:
        """(h, w, 3) estimate of the variance of each pixel's value R = sum(w L) / sum(w).

        S = sum(w^2 (L - R)^2) is the linearised (delta-method) variance of a ratio times W1^2;
        the estimate is S (W2 / W1^2) / D with D = W2 - 2 W3 / W1 + (W2 / W1)^2 (W1, W2, W3 the
        sums of w, w^2, w^3), which is exactly unbiased when the samples' L are i.i.d. given
        their positions (then E S = sigma^2 D and Var R = sigma^2 W2 / W1^2). With unit weights
        (importance sampling) D = n - 1 and it is the usual s^2 / n. 0 where D is 0 (fewer than
        two samples weigh in). Splatted pixels' errors are correlated with their neighbours'.
        """
        W1, W2, W3, sum_w2 = self._moments()
        safe = np.where(W1 > 0.0, W1, 1.0)
        R = self.sum / safe
        S = np.maximum(self.sum_sq - 2.0 * R * sum_w2 + R * R * W2, 0.0)
        D = W2 - 2.0 * W3 / safe + (W2 / safe) ** 2
        ok = (W1 > 0.0) & (D > 1e-12 * W2)
        return np.where(ok, S * (W2 / (safe * safe)) / np.where(ok, D, 1.0), 0.0)

    def image(self) -> np.ndarray:
        """The full display window (height, width, 3) float32 (zeros outside the data window)."""
        x0, y0, x1, y1 = self.window
        if (x0, y0, x1, y1) == (0, 0, self.width, self.height):
            return self.mean()
        full = np.zeros((self.height, self.width, 3), dtype=np.float32)
        full[y0:y1, x0:x1] = self.mean()
        return full

    # ------------------------------------------------------------------ checkpointing
    def save_state(self, path: str) -> None:
        """Checkpoint the raw sums (npz, atomic) so a render can resume where it stopped; a
        splatting film also records its filter (name, radius)."""
        d = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix=".tmp_", suffix=".npz", dir=d)
        os.close(fd)
        extra = {} if self.splat is None else {"splat": np.array([self.splat.name]),
                                               "splat_radius": np.array([self.splat.radius])}
        np.savez(tmp, **self._arrays(), **extra,
                 meta=np.array([self.width, self.height, *self.window, self.nonfinite_dropped,
                                self.negative_samples], dtype=np.int64))
        os.replace(tmp, path)

    @staticmethod
    def load_state(path: str) -> "Film":
        with np.load(path) as z:
            m = z["meta"]
            splat = PixelFilter(str(z["splat"][0]), float(z["splat_radius"][0])) if "splat" in z.files else None
            film = Film(int(m[0]), int(m[1]), tuple(int(v) for v in m[2:6]), splat)
            for name in film._arrays():
                setattr(film, name, z[name])
            film.nonfinite_dropped = int(m[6])
            film.negative_samples = int(m[7])
        return film


# ---------------------------------------------------------------------------------- I/O
# Writing lives in renderer/output.py (atomic, umask modes, display encodings); these keep the
# film's own shapes: the data window inside the display window.
def write_rgb_exr(path: str, pixels: np.ndarray, metadata: dict | None = None, *,
                  origin: tuple[int, int] = (0, 0), full: tuple[int, int] | None = None, **kw) -> None:
    """Write (h, w, 3) pixels as a float32 RGB EXR, atomically (output.write_image)."""
    write_image(path, pixels, metadata, origin=origin, full=full, **kw)


def write_exr(path: str, film: Film, metadata: dict | None = None, **kw) -> None:
    """Write the film as an EXR (or, by extension, a display-referred PNG/JPEG/TIFF of the data
    window) with display window = full image, data window = crop. kw: output.write_image's
    (files, compression, half)."""
    x0, y0, x1, y1 = film.window
    pixels = film.mean()
    if not np.all(np.isfinite(pixels)):  # unreachable by construction; a guard, not a policy
        raise RuntimeError("film holds non-finite pixels")
    write_image(path, pixels, metadata, origin=(x0, y0), full=(film.width, film.height), **kw)


def write_png(path: str, film_or_image, **kw) -> None:
    """Display-referred preview of the full image, by extension (8-bit PNG/JPEG, 16-bit TIFF;
    sRGB or the $OCIO display, output.display_encode; values clamped to [0, 1])."""
    img = film_or_image.image() if isinstance(film_or_image, Film) else np.asarray(film_or_image)
    write_image(path, img, **kw)


def read_exr(path: str) -> tuple[np.ndarray, dict]:
    """Read an EXR back: (full display-window image (H, W, C) float32, attributes dict)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    spec = inp.spec()
    data = inp.read_image(oiio.FLOAT)
    inp.close()
    attrs = {a.name: a.value for a in spec.extra_attribs}
    full = np.zeros((spec.full_height, spec.full_width, spec.nchannels), dtype=np.float32)
    full[spec.y - spec.full_y: spec.y - spec.full_y + spec.height,
         spec.x - spec.full_x: spec.x - spec.full_x + spec.width] = data
    return full, attrs
