"""Progressive film: per-pixel running sums, a variance estimate, and EXR/PNG output.

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

import json
import os
import tempfile
from dataclasses import dataclass, field

import numpy as np
from numba import njit


_F32_MAX = float(np.finfo(np.float32).max)


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
        if not (np.isfinite(r) and np.isfinite(g) and np.isfinite(b)):
            dropped += 1
            continue
        if r < 0.0 or g < 0.0 or b < 0.0:
            negative += 1
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


@dataclass
class Film:
    """width x height film with a data window (x0, y0, x1, y1) in pixels (half-open).

    sum, sum_sq: (h, w, 3) float64 over the data window; count: (h, w) samples per pixel.
    """

    width: int
    height: int
    window: tuple[int, int, int, int] | None = None
    sum: np.ndarray = field(init=False)
    sum_sq: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)
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

    @property
    def shape(self) -> tuple[int, int]:
        return self.sum.shape[0], self.sum.shape[1]

    def pixel_coords(self) -> tuple[np.ndarray, np.ndarray]:
        """Full-image pixel coordinates (px, py) of every data-window pixel, row-major, (h*w,) each."""
        x0, y0, x1, y1 = self.window
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return xs.ravel(), ys.ravel()

    def add(self, rows: np.ndarray, L: np.ndarray, unique: bool = True) -> None:
        """Add one sample per entry: rows (n,) flat data-window pixel indices, L (n, 3) radiance.

        unique: rows hold no repeats (one sample per pixel, the progressive case). The compiled
        pass (_add_kernel) adds rows one after another, so repeats accumulate either way (the
        np.add.at semantics unique=False asks for); the flag is kept for callers' intent.
        """
        rows = np.asarray(rows)
        L = np.asarray(L)
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

    def merge(self, other: "Film") -> None:
        """Accumulate another film's samples (same size/window): how distributed passes combine."""
        self.sum += other.sum
        self.sum_sq += other.sum_sq
        self.count += other.count
        self.nonfinite_dropped += other.nonfinite_dropped
        self.negative_samples += other.negative_samples

    def mean(self) -> np.ndarray:
        """(h, w, 3) float32 per-pixel mean of the data window (0 where no samples yet).

        Means beyond the float32 range are clamped to its limit (``overflow_clamped`` counts
        them): the EXR cannot hold them, and Inf must never reach a file.
        """
        n = np.maximum(self.count, 1)[:, :, None]
        m = self.sum / n
        big = np.abs(m) > _F32_MAX
        self.overflow_clamped = int(big.any(axis=2).sum())
        return np.clip(m, -_F32_MAX, _F32_MAX).astype(np.float32)

    def variance_of_mean(self) -> np.ndarray:
        """(h, w, 3) unbiased estimate of the variance of each pixel's mean."""
        n = self.count[:, :, None].astype(np.float64)
        safe = np.maximum(n, 2.0)
        var = (self.sum_sq - self.sum * self.sum / safe) / (safe - 1.0)
        return np.where(n >= 2, np.maximum(var, 0.0) / safe, 0.0)

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
        """Checkpoint the raw sums (npz, atomic) so a render can resume where it stopped."""
        d = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix=".tmp_", suffix=".npz", dir=d)
        os.close(fd)
        np.savez(tmp, sum=self.sum, sum_sq=self.sum_sq, count=self.count,
                 meta=np.array([self.width, self.height, *self.window, self.nonfinite_dropped,
                                self.negative_samples], dtype=np.int64))
        os.replace(tmp, path)

    @staticmethod
    def load_state(path: str) -> "Film":
        with np.load(path) as z:
            m = z["meta"]
            film = Film(int(m[0]), int(m[1]), tuple(int(v) for v in m[2:6]))
            film.sum = z["sum"]
            film.sum_sq = z["sum_sq"]
            film.count = z["count"]
            film.nonfinite_dropped = int(m[6])
            film.negative_samples = int(m[7])
        return film


# ---------------------------------------------------------------------------------- I/O
def _atomic_target(path: str) -> tuple[str, str]:
    d = os.path.dirname(os.path.abspath(path)) or "."
    os.makedirs(d, exist_ok=True)
    base, ext = os.path.splitext(os.path.basename(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=ext, dir=d)
    os.close(fd)
    return tmp, path


def write_rgb_exr(path: str, pixels: np.ndarray, metadata: dict | None = None, *,
                  origin: tuple[int, int] = (0, 0), full: tuple[int, int] | None = None) -> None:
    """Write (h, w, 3) pixels as a float32 RGB EXR, atomically (temporary name, then rename).

    origin: data-window position inside the display window of size ``full`` (width, height),
    default the image itself. metadata: str/int/float values become EXR attributes; numpy (4,4)
    arrays become matrices; dicts/lists are stored as JSON strings.
    """
    import OpenImageIO as oiio

    h, w = pixels.shape[:2]
    spec = oiio.ImageSpec(w, h, 3, oiio.FLOAT)
    spec.x, spec.y = origin
    spec.full_x, spec.full_y = 0, 0
    spec.full_width, spec.full_height = full or (w, h)
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "zip")
    spec.attribute("oiio:ColorSpace", "lin_rec709")
    for key, value in (metadata or {}).items():
        _set_attr(spec, key, value)
    tmp, final = _atomic_target(path)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise OSError(f"cannot open {path} for writing: {oiio.geterror()}")
        if not out.write_image(np.ascontiguousarray(pixels, dtype=np.float32)):
            raise OSError(f"cannot write {path}: {out.geterror()}")
        out.close()
        os.replace(tmp, final)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_exr(path: str, film: Film, metadata: dict | None = None) -> None:
    """Write the film as a float32 RGB EXR with display window = full image, data window = crop."""
    x0, y0, x1, y1 = film.window
    pixels = film.mean()
    if not np.all(np.isfinite(pixels)):  # unreachable by construction; a guard, not a policy
        raise RuntimeError("film holds non-finite pixels")
    write_rgb_exr(path, pixels, metadata, origin=(x0, y0), full=(film.width, film.height))


def _set_attr(spec, key: str, value) -> None:
    import OpenImageIO as oiio

    if isinstance(value, np.ndarray) and value.shape == (4, 4):
        # EXR matrices are row-vector (Imath); ours are column-vector, so store the transpose.
        spec.attribute(key, oiio.TypeDesc("matrix"), np.ascontiguousarray(value.T, dtype=np.float32).ravel())
    elif isinstance(value, bool):
        spec.attribute(key, int(value))
    elif isinstance(value, (int, np.integer)):
        spec.attribute(key, int(value))
    elif isinstance(value, (float, np.floating)):
        spec.attribute(key, float(value))
    elif isinstance(value, str):
        spec.attribute(key, value)
    else:
        spec.attribute(key, json.dumps(value, sort_keys=True))


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function on [0,1]-clamped linear values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def write_png(path: str, film_or_image) -> None:
    """8-bit sRGB preview (display only: values are clamped to [0, 1])."""
    import OpenImageIO as oiio

    img = film_or_image.image() if isinstance(film_or_image, Film) else np.asarray(film_or_image)
    data = np.round(srgb_encode(img) * 255.0).astype(np.uint8)
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], 3, oiio.UINT8)
    spec.attribute("oiio:ColorSpace", "srgb_rec709_scene")
    tmp, final = _atomic_target(path)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise OSError(f"cannot open {path} for writing: {oiio.geterror()}")
        out.write_image(data)
        out.close()
        os.replace(tmp, final)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


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
