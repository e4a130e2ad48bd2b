"""Light textures: loading (OpenImageIO) and a set of per-image texel distributions.

``ImageSet`` stores the images of every textured light of a kind in one flat texel array
(structure-of-arrays: ``offset``/``height``/``width`` per image) so lookups and importance
sampling run vectorised over rows that may belong to different images. Indices are image
indices: ``row`` 0 is the *top* row of the file (OIIO's row 0), ``col`` 0 the left column.

Sampling picks a texel with probability weight/total (rows by the marginal, then columns by
the row's conditional, both by a vectorised binary search over the flat CDFs), and returns the
position inside the texel as fractions (s along columns, t along rows) in [0, 1). How a texel
maps to area or solid angle is up to the light kind.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from renderer.assets import local_file
from renderer.errors import StageError


def load_texture_rgb(path: str, prim: str, attribute: str = "inputs:texture:file",
                     data: bytes | None = None) -> np.ndarray:
    """Read an image as linear float RGB (H, W, 3) float64 (row 0 = top of the image); ``data``:
    its bytes when it is not a file on disk (LightDesc.texture_data, renderer/assets.py).

    One-channel images are replicated to grey, extra channels (alpha) are ignored. UsdLux has no
    colour-space input for light textures, so illum applies UsdUVTexture's 'auto' rule (the
    UsdPreviewSurface spec, as renderer/textures.py): 8-bit files with 3 or 4 channels are
    sRGB-encoded and decoded to linear; 1- and 2-channel 8-bit files and float, half and
    16-bit files are taken as linear.
    Raises StageError (naming the prim, the attribute and the file) when the file cannot be
    read, or when texels are NaN, infinite or negative (with their count).
    """
    import OpenImageIO as oiio

    with local_file(path, data) as local:
        buf = oiio.ImageBuf(local)
        spec = buf.spec()
        if buf.has_error or spec.width <= 0 or spec.height <= 0:
            msg = buf.geterror() if buf.has_error else "empty image"
            raise StageError(f"cannot read texture '{path}': {msg}", prim=prim, attribute=attribute)
        px = np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float64)
        if buf.has_error:
            raise StageError(f"cannot read texture '{path}': {buf.geterror()}", prim=prim, attribute=attribute)
    if px.ndim == 2:
        px = px[:, :, None]
    if px.ndim == 4:  # volume images: take the first slice
        px = px[0]
    nch = px.shape[2]
    if nch >= 3:
        rgb = px[:, :, :3]
    else:
        rgb = np.repeat(px[:, :, :1], 3, axis=2)
    if spec.format.basetype == oiio.UINT8 and nch in (3, 4):
        # UsdUVTexture 'auto': "sRGB if it is either 8-bit and has 3 channels or ... 4 channels"
        rgb = srgb_to_linear(rgb)
    bad = ~np.isfinite(rgb) | (rgb < 0.0)
    nbad = int(bad.any(axis=2).sum())
    if nbad:
        raise StageError(
            f"texture '{path}' has {nbad} texel(s) with NaN, infinite or negative values",
            prim=prim,
            attribute=attribute,
        )
    return np.ascontiguousarray(rgb)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB decoding curve (IEC 61966-2-1), element-wise on values in [0, 1]."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)


def _search(cdf: np.ndarray, start: np.ndarray, ncells: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Vectorised binary search in per-row CDF segments.

    cdf: flat array; segment r is cdf[start[r] : start[r] + ncells[r] + 1], non-decreasing from
    0 to 1. Returns k (n,) in [0, ncells-1]: the largest k with cdf[start + k] <= u, which skips
    cells of zero width.
    """
    lo = np.zeros(u.shape, dtype=np.int64)
    hi = ncells.astype(np.int64).copy()  # answer < hi
    while True:
        active = hi - lo > 1
        if not active.any():
            break
        mid = (lo + hi) // 2
        le = cdf[start + np.where(active, mid, 0)] <= u
        lo = np.where(active & le, mid, lo)
        hi = np.where(active & ~le, mid, hi)
    return lo


def _fraction(lo: np.ndarray, hi: np.ndarray, u: np.ndarray) -> np.ndarray:
    w = hi - lo
    f = np.divide(u - lo, np.where(w > 0.0, w, 1.0), out=np.zeros_like(u), where=w > 0.0)
    return np.clip(f, 0.0, np.nextafter(1.0, 0.0))


@dataclass(frozen=True)
class ImageSet:
    """Several RGB images and a texel distribution for each, flattened.

    texels: (N, 3) float64 all images, row-major, concatenated.
    offset, height, width: (k,) int64 per image.
    weight: (N,) float64 sampling weight per texel; total: (k,) its sum per image (> 0: an
        all-zero weight image is replaced by uniform weights at build).
    row_cdf: flat marginal CDFs, image i at row_cdf_start[i] (height[i] + 1 entries).
    col_cdf: flat conditional CDFs, row r of image i at col_cdf_start[i] + r * (width[i] + 1).
    mean_rgb: (k, 3) plain texel average of each image.
    """

    texels: np.ndarray
    offset: np.ndarray
    height: np.ndarray
    width: np.ndarray
    weight: np.ndarray
    total: np.ndarray
    row_cdf: np.ndarray
    row_cdf_start: np.ndarray
    col_cdf: np.ndarray
    col_cdf_start: np.ndarray
    mean_rgb: np.ndarray

    @property
    def count(self) -> int:
        return int(self.offset.size)

    @staticmethod
    def build(images: list[np.ndarray], weights: list[np.ndarray]) -> "ImageSet":
        """images: list of (H, W, 3); weights: list of (H, W) non-negative sampling weights."""
        texels, wflat, row_cdfs, col_cdfs = [], [], [], []
        offset, height, width, total, row_start, col_start, mean = [], [], [], [], [], [], []
        n_tex = n_row = n_col = 0
        for img, w in zip(images, weights):
            h, wd = img.shape[:2]
            w = np.where(np.isfinite(w) & (w > 0.0), np.asarray(w, dtype=np.float64), 0.0)
            if w.sum() <= 0.0:
                w = np.ones((h, wd))
            row_sum = w.sum(axis=1)
            tot = float(row_sum.sum())
            rc = np.concatenate([[0.0], np.cumsum(row_sum)]) / tot
            rc[-1] = 1.0
            safe = np.where(row_sum > 0.0, row_sum, 1.0)
            cc = np.concatenate([np.zeros((h, 1)), np.cumsum(w, axis=1)], axis=1) / safe[:, None]
            cc[:, -1] = 1.0
            cc[row_sum <= 0.0] = np.linspace(0.0, 1.0, wd + 1)[None, :]
            texels.append(img.reshape(-1, 3))
            wflat.append(w.ravel())
            row_cdfs.append(rc)
            col_cdfs.append(cc.ravel())
            offset.append(n_tex)
            row_start.append(n_row)
            col_start.append(n_col)
            height.append(h)
            width.append(wd)
            total.append(tot)
            mean.append(img.reshape(-1, 3).mean(axis=0))
            n_tex += h * wd
            n_row += h + 1
            n_col += h * (wd + 1)
        cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)  # noqa: E731
        return ImageSet(
            texels=cat(texels, (0, 3)),
            offset=np.array(offset, dtype=np.int64),
            height=np.array(height, dtype=np.int64),
            width=np.array(width, dtype=np.int64),
            weight=cat(wflat, (0,)),
            total=np.array(total, dtype=np.float64),
            row_cdf=cat(row_cdfs, (0,)),
            row_cdf_start=np.array(row_start, dtype=np.int64),
            col_cdf=cat(col_cdfs, (0,)),
            col_cdf_start=np.array(col_start, dtype=np.int64),
            mean_rgb=np.array(mean, dtype=np.float64).reshape(-1, 3),
        )

    @staticmethod
    def concat(a: "ImageSet", b: "ImageSet") -> "ImageSet":
        """The images of a, then those of b, as one set (image i of b is image a.count + i)."""
        return ImageSet(
            texels=np.concatenate([a.texels.reshape(-1, 3), b.texels.reshape(-1, 3)]),
            offset=np.concatenate([a.offset, b.offset + a.texels.reshape(-1, 3).shape[0]]).astype(np.int64),
            height=np.concatenate([a.height, b.height]).astype(np.int64),
            width=np.concatenate([a.width, b.width]).astype(np.int64),
            weight=np.concatenate([a.weight, b.weight]),
            total=np.concatenate([a.total, b.total]).astype(np.float64),
            row_cdf=np.concatenate([a.row_cdf, b.row_cdf]),
            row_cdf_start=np.concatenate([a.row_cdf_start, b.row_cdf_start + a.row_cdf.size]).astype(np.int64),
            col_cdf=np.concatenate([a.col_cdf, b.col_cdf]),
            col_cdf_start=np.concatenate([a.col_cdf_start, b.col_cdf_start + a.col_cdf.size]).astype(np.int64),
            mean_rgb=np.concatenate([a.mean_rgb.reshape(-1, 3), b.mean_rgb.reshape(-1, 3)]),
        )

    def kernel_record(self) -> tuple:
        """The set as the compiled rows read it (kernels/lights.py's textured rows): (texels,
        offset, height, width, weight, total, row_cdf, row_cdf_start, col_cdf, col_cdf_start),
        C-contiguous float64 / int64."""
        c = np.ascontiguousarray
        f64, i64 = np.float64, np.int64
        return (c(self.texels.reshape(-1, 3), dtype=f64), c(self.offset, dtype=i64), c(self.height, dtype=i64),
                c(self.width, dtype=i64), c(self.weight, dtype=f64), c(self.total, dtype=f64),
                c(self.row_cdf, dtype=f64), c(self.row_cdf_start, dtype=i64), c(self.col_cdf, dtype=f64),
                c(self.col_cdf_start, dtype=i64))

    def texel_index(self, img: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        r = np.clip(row, 0, self.height[img] - 1)
        c = np.clip(col, 0, self.width[img] - 1)
        return self.offset[img] + r * self.width[img] + c

    def lookup(self, img: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Texel RGB (n, 3) of image img at (row, col) (clamped to the image)."""
        return self.texels[self.texel_index(img, row, col)]

    def pmf(self, img: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Probability (n,) that ``sample`` picks texel (row, col) of image img."""
        return self.weight[self.texel_index(img, row, col)] / self.total[img]

    def sample(self, img: np.ndarray, u: np.ndarray):
        """Pick a texel of image img (n,) with u (n, 2): u[:, 1] picks the row, u[:, 0] the column.

        Returns (row, col, s, t, pmf): int64 texel indices, the position inside the texel as
        fractions s (along the row, i.e. columns) and t (down the column, i.e. rows) in [0, 1),
        and the texel's probability.
        """
        h = self.height[img]
        w = self.width[img]
        rs = self.row_cdf_start[img]
        row = _search(self.row_cdf, rs, h, u[:, 1])
        t = _fraction(self.row_cdf[rs + row], self.row_cdf[rs + row + 1], u[:, 1])
        cs = self.col_cdf_start[img] + row * (w + 1)
        col = _search(self.col_cdf, cs, w, u[:, 0])
        s = _fraction(self.col_cdf[cs + col], self.col_cdf[cs + col + 1], u[:, 0])
        return row, col, s, t, self.pmf(img, row, col)
