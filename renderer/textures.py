"""Image textures for UsdUVTexture: load once with OpenImageIO, look up bilinearly, vectorised.

Conventions
-----------
* **st orientation**: USD's st = (0, 0) is the *bottom-left* corner of the image and t grows
  upward, while OIIO's row 0 is the top row. Images are flipped once at load, so internally
  row 0 is the bottom row and texel (i, j) covers s in [i/W, (i+1)/W), t in [j/H, (j+1)/H).
* **Filtering**: bilinear between the four nearest texel centres (texel centres at
  ((i + 0.5)/W, (j + 0.5)/H)). No mipmapping, so strongly minified textures alias (a limitation).
* **Wrap modes**, per axis: 'black' (texels outside the image are (0, 0, 0, 0)), 'clamp' (edge
  texels extend), 'repeat' (periodic), 'mirror' (mirrored repeat, period 2W: ... 1 0 | 0 1 ... W-1 |
  W-1 ... 0 | 0 ...). 'useMetadata' (UsdUVTexture's fallback) reads the file's wrap metadata
  (OIIO's "wrapmodes", e.g. "periodic,clamp"; periodic = repeat) and, when the file has none,
  falls back to 'black', as the UsdPreviewSurface spec says ("If the texture contains no such
  metadata, then fall back to black"). hdStorm falls back to repeat instead, for legacy assets.
* **Channels** (UsdUVTexture spec): 1 channel -> (v, v, v, 1); 2 channels -> (v, v, v, a);
  3 -> (r, g, b, 1); 4 or more -> the first four. Colour is read as stored (unassociated alpha:
  OIIO's automatic premultiplication of PNG/TIFF colour by alpha is turned off), so an alpha
  channel used as opacity does not also darken the colour.
* **Colour space**: texels are decoded from sRGB to linear (the IEC 61966-2-1 piecewise curve,
  RGB only, never alpha) when ``sourceColorSpace`` is 'sRGB', or when it is 'auto' and the file
  is 8-bit (UINT8) with 3 or 4 channels -- the UsdPreviewSurface spec's rule for 'auto' without
  colour-space metadata ("mark texture as sRGB if it is either 8-bit and has 3 channels or if it
  is 8-bit and has 4 channels. Otherwise, do not mark texture as sRGB"), which is also what
  hioOiio's IsColorSpaceSRGB does. So under 'auto' 1- and 2-channel 8-bit files (roughness,
  metallic, opacity masks) and 16-bit, half and float files are read as stored; 'raw' never
  decodes. File colour-space metadata is not consulted (OIIO tags most PNGs 'sRGB' by default,
  which would decode single-channel data maps, the case the spec's rule exists to avoid).
* **Output**: ``out = texel * scale + bias`` (per RGBA channel, after decoding). Where the file
  could not be read, ``fallback`` is returned as is (no scale / bias).
* **Bad texels**: non-finite texel values (NaN, +-inf) are replaced by 0 at load; the count is
  reported once per file in ``TextureCache.warnings``.
* **Errors**: a file that does not exist raises ``renderer.errors.StageError`` naming it (unless
  the cache was built with ``missing='fallback'``); a file that exists but OIIO cannot read gives
  a warning and the fallback value, or a StageError when the cache was built with
  ``strict=True`` (``illum render --strict``: every missing or unreadable asset is an error).
  The stage reader has already applied that policy to files it could not find or whose header
  it could not read (renderer/usd), naming the layer, prim and attribute.
* **UDIM**: a texture with ``udim_tiles`` looks up st' (after its st transform) in tile
  1001 + floor(s') + 10 floor(t') at (s' - floor(s'), t' - floor(t')), each tile clamped at its
  own edges (no filtering across tiles); where st' falls on no tile (s' outside [0, 10),
  t' < 0, or a tile that was not found) the lookup gives ``fallback``, as where a file is missing.
* **Packages**: a texture inside a ``.usdz`` package carries its bytes (``TextureDesc.data``,
  read through USD's asset resolver); it is decoded from them (renderer/assets.py).

Memory: decoded images are kept as float32 (H, W, 4); lookups compute in float64.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Iterable, Optional

import numpy as np
from numba import njit

from renderer.assets import local_file
from renderer.description import TextureDesc
from renderer.errors import StageError

WRAP_MODES = ("black", "clamp", "repeat", "mirror")
# OIIO "wrapmodes" metadata names -> UsdUVTexture wrap modes.
_OIIO_WRAP = {"black": "black", "clamp": "clamp", "periodic": "repeat", "mirror": "mirror"}
COLOR_SPACES = ("raw", "sRGB", "auto")
OUTPUT_CHANNELS = {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,), "rgba": (0, 1, 2, 3)}


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB electro-optical transfer function (IEC 61966-2-1), elementwise on any shape."""
    v = np.asarray(v)
    lo = v / 12.92
    hi = ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4
    return np.where(v <= 0.04045, lo, hi)


def output_channels(output: str) -> tuple[int, ...]:
    """Channel indices (into RGBA) of a UsdUVTexture output name."""
    try:
        return OUTPUT_CHANNELS[output]
    except KeyError:
        raise StageError(f"unknown UsdUVTexture output {output!r}") from None


@dataclass(frozen=True)
class LoadedImage:
    """A decoded-from-file image: pixels (H, W, 4) float32, row 0 = bottom (USD t = 0), raw values
    (not colour-decoded); is_integer: the file stores integer data; nonfinite: texels fixed at load."""

    path: str
    pixels: np.ndarray
    is_integer: bool
    channels: int
    nonfinite: int
    is_8bit: bool = False  # UINT8 storage: with 3 or 4 channels, sRGB under 'auto'
    wrap_metadata: tuple[str, str] | None = None  # (s, t) wrap modes the file declares, if any

    @property
    def width(self) -> int:
        return self.pixels.shape[1]

    @property
    def height(self) -> int:
        return self.pixels.shape[0]


def _expand_channels(px: np.ndarray) -> np.ndarray:
    """(H, W, C) -> (H, W, 4) RGBA per the UsdUVTexture channel rules."""
    h, w, c = px.shape
    out = np.ones((h, w, 4), dtype=np.float32)
    if c == 1:
        out[..., 0:3] = px[..., 0:1]
    elif c == 2:
        out[..., 0:3] = px[..., 0:1]
        out[..., 3] = px[..., 1]
    elif c == 3:
        out[..., 0:3] = px
    else:
        out[...] = px[..., 0:4]
    return out


def load_image(path: str, data: Optional[bytes] = None) -> tuple[Optional[LoadedImage], str]:
    """Read ``path`` (or its bytes ``data``, renderer/assets.py) with OpenImageIO ->
    (LoadedImage or None, error message or '')."""
    import OpenImageIO as oiio

    # Keep colour channels as stored ("straight"): without this OIIO premultiplies the colour of
    # PNG/TIFF files with alpha on read, darkening colours wherever alpha < 1.
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    with local_file(path, data) as local:
        buf = oiio.ImageBuf(local, 0, 0, config)
        if buf.has_error:
            return None, buf.geterror()
        spec = buf.spec()
        if spec.width <= 0 or spec.height <= 0 or spec.nchannels <= 0:
            return None, "image has no pixels"
        px = buf.get_pixels(oiio.FLOAT)
        if buf.has_error:
            return None, buf.geterror()
    px = np.asarray(px, dtype=np.float32)
    if px.ndim == 4:  # (depth, H, W, C) for volume files: take the first slice
        px = px[0]
    if px.ndim == 2:
        px = px[:, :, None]
    bad = ~np.isfinite(px)
    nonfinite = int(bad.any(axis=2).sum())
    if nonfinite:
        px = np.where(bad, np.float32(0.0), px)
    base = spec.format.basetype
    is_integer = base not in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    # Flip so that row 0 is the bottom row (USD t = 0).
    pixels = np.ascontiguousarray(_expand_channels(px)[::-1])
    return LoadedImage(path, pixels, bool(is_integer), int(spec.nchannels), nonfinite,
                       is_8bit=base == oiio.UINT8, wrap_metadata=_wrap_metadata(spec)), ""


def probe_image(path: str, data: Optional[bytes] = None) -> tuple[str, tuple[int, int, int]]:
    """Read only the header of the image at ``path`` (or of its bytes ``data``) with
    OpenImageIO -> (why it cannot be opened, '' when it can; (width, height, depth) it declares,
    zeros when it cannot), so what decoding it would allocate is known before it is decoded."""
    import OpenImageIO as oiio

    with local_file(path, data) as local:
        inp = oiio.ImageInput.open(local)
        if inp is None:
            # OIIO names the file it opened: the asset's own name, not a temporary copy's
            return (" ".join(oiio.geterror().replace(local, path).split()) or "not an image OpenImageIO can read",
                    (0, 0, 0))
        spec = inp.spec()
        inp.close()
    if spec.width <= 0 or spec.height <= 0 or spec.nchannels <= 0:
        return "image has no pixels", (0, 0, 0)
    return "", (int(spec.width), int(spec.height), max(int(spec.depth), 1))


def _wrap_metadata(spec) -> tuple[str, str] | None:
    """The (s, t) wrap modes in OIIO's "wrapmodes" attribute ("periodic,clamp" or one mode for
    both), or None when absent or unrecognised."""
    raw = spec.getattribute("wrapmodes")
    if not isinstance(raw, str) or not raw:
        return None
    parts = [_OIIO_WRAP.get(p.strip()) for p in raw.split(",")]
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or None in parts:
        return None
    return parts[0], parts[1]


@njit(cache=True, nogil=True, inline="always")
def _wrap_row(i, n, mode):
    """Integer texel coordinate i on an axis of n texels under wrap mode code ``mode``
    (WRAP_MODES.index): (index in [0, n), 1.0 if a texel of the image else 0.0 ('black'))."""
    if mode == 2:  # repeat
        return i % n, 1.0
    if mode == 3:  # mirror, period 2n
        m = i % (2 * n)
        return (2 * n - 1 - m if m >= n else m), 1.0
    k = min(max(i, 0), n - 1)
    if mode == 1:  # clamp
        return k, 1.0
    return k, (1.0 if 0 <= i < n else 0.0)  # black: a texel outside contributes 0


# inline="always" (numba IR): a per-hit caller's texture lookups then cost no calls (each call
# of a helper taking the texel array cost ~50 ns in reference counting, 4x the bilinear itself).
@njit(cache=True, nogil=True, inline="always")
def texel_row(px, off, h, w, nc, s, t, ws, wt, c):
    """Bilinear value (float64) of channel c at (s, t) of an (h, w, nc) image stored flat from
    px[off] (row 0 = t bottom; texel centres at ((i + 0.5)/w, (j + 0.5)/h)), wrap codes ws, wt.
    s, t must be finite. The one bilinear formula (``bilinear`` and compiled callers)."""
    # Keep coordinates where float64 -> int64 conversion is exact and harmless.
    x = min(max(s, -1.0e9), 1.0e9) * w - 0.5
    y = min(max(t, -1.0e9), 1.0e9) * h - 0.5
    x0f = math.floor(x)
    y0f = math.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = int(x0f)
    y0 = int(y0f)
    ix0, in_x0 = _wrap_row(x0, w, ws)
    ix1, in_x1 = _wrap_row(x0 + 1, w, ws)
    iy0, in_y0 = _wrap_row(y0, h, wt)
    iy1, in_y1 = _wrap_row(y0 + 1, h, wt)
    wx0 = (1.0 - fx) * in_x0
    wx1 = fx * in_x1
    wy0 = (1.0 - fy) * in_y0
    wy1 = fy * in_y1
    out = float(px[off + (iy0 * w + ix0) * nc + c]) * (wx0 * wy0)
    out += px[off + (iy0 * w + ix1) * nc + c] * (wx1 * wy0)
    out += px[off + (iy1 * w + ix0) * nc + c] * (wx0 * wy1)
    out += px[off + (iy1 * w + ix1) * nc + c] * (wx1 * wy1)
    return out


@njit(cache=True, nogil=True, inline="always")
def lookup_row(px, off, h, w, nc, s, t, ws, wt, xf, c, scale, bias, fallback):
    """UsdUVTexture output channel c at st = (s, t): the st transform xf (6,) (m00, m01, m10,
    m11, t0, t1; empty for none), bilinear (texel_row), then texel * scale + bias; fallback
    where st is not finite (TextureCache.lookup's rules, one row)."""
    if not (math.isfinite(s) and math.isfinite(t)):
        return fallback
    if xf.shape[0] > 0:
        s, t = xf[0] * s + xf[1] * t + xf[4], xf[2] * s + xf[3] * t + xf[5]
    return texel_row(px, off, h, w, nc, s, t, ws, wt, c) * scale + bias


# The columns of TextureCache.pack's tables: per image (IMI), per texture (TXI, TXF), per UDIM
# tile (tiles).
IM_OFFSET, IM_HEIGHT, IM_WIDTH, IM_CHANNELS = 0, 1, 2, 3
TX_IMAGE, TX_WRAP_S, TX_WRAP_T, TX_HAS_XF, TX_UDIM, TX_TILE_LO, TX_TILE_HI = 0, 1, 2, 3, 4, 5, 6
TX_XF, TX_SCALE, TX_BIAS, TX_FALLBACK = 0, 6, 10, 14


@njit(cache=True, nogil=True, _nrt=False)
def texture_row(px, IMI, TXI, TXF, tiles, j, s, t, c):
    """Output channel c of texture j of the packed set (TextureCache.pack: px, IMI, TXI, TXF,
    tiles) at st = (s, t): TextureCache.lookup's rules for one row. A plain texture: its image
    through lookup_row, or its fallback where the file could not be read. A UDIM texture (module
    docstring): the st transform, then tile 1001 + floor(s') + 10 floor(t') at the tile-local st
    through lookup_row (clamped at the tile's edges, no transform), the fallback off the tiles or
    on a tile that could not be read."""
    fb = TXF[j, TX_FALLBACK + c]
    xf = TXF[j, TX_XF:TX_XF + 6]
    if TXI[j, TX_UDIM] == 0:
        i = TXI[j, TX_IMAGE]
        if i < 0:
            return fb
        return lookup_row(px, IMI[i, IM_OFFSET], IMI[i, IM_HEIGHT], IMI[i, IM_WIDTH], IMI[i, IM_CHANNELS], s, t,
                          TXI[j, TX_WRAP_S], TXI[j, TX_WRAP_T], xf if TXI[j, TX_HAS_XF] != 0 else xf[:0], c,
                          TXF[j, TX_SCALE + c], TXF[j, TX_BIAS + c], fb)
    if not (math.isfinite(s) and math.isfinite(t)):
        return fb
    if TXI[j, TX_HAS_XF] != 0:
        s, t = xf[0] * s + xf[1] * t + xf[4], xf[2] * s + xf[3] * t + xf[5]
    u = math.floor(s)
    v = math.floor(t)
    if not (u >= 0.0 and u < 10.0 and v >= 0.0 and v < 1e6):
        return fb
    number = int(1001.0 + u + 10.0 * v)
    i = -2
    for q in range(TXI[j, TX_TILE_LO], TXI[j, TX_TILE_HI]):
        if tiles[q, 0] == number:
            i = tiles[q, 1]  # the last tile of that number, as a loop over the tiles leaves it
    if i < 0:
        return fb
    return lookup_row(px, IMI[i, IM_OFFSET], IMI[i, IM_HEIGHT], IMI[i, IM_WIDTH], IMI[i, IM_CHANNELS], s - u, t - v,
                      1, 1, xf[:0], c, TXF[j, TX_SCALE + c], TXF[j, TX_BIAS + c], fb)


@njit(cache=True, nogil=True)
def _texture_kernel(TX, j, st, out):
    px, IMI, TXI, TXF, tiles = TX
    for r in range(st.shape[0]):
        for c in range(out.shape[1]):
            out[r, c] = texture_row(px, IMI, TXI, TXF, tiles, j, st[r, 0], st[r, 1], c)


@njit(cache=True, nogil=True)
def _lookup_kernel(px, h, w, nc, st, ws, wt, xf, scale, bias, fallback, out):
    for i in range(st.shape[0]):
        for c in range(out.shape[1]):
            out[i, c] = lookup_row(px, 0, h, w, nc, st[i, 0], st[i, 1], ws, wt, xf, c, scale[c], bias[c], fallback[c])


def bilinear(pixels: np.ndarray, st: np.ndarray, wrap_s: str, wrap_t: str) -> np.ndarray:
    """Bilinear lookup of pixels (H, W, C) (row 0 = t bottom) at st (n, 2) -> (n, C) float64.

    st must be finite. Texel centres at ((i + 0.5)/W, (j + 0.5)/H) (texel_row).
    """
    c = pixels.shape[2]
    return _lookup(pixels, st, wrap_s, wrap_t, np.zeros(0), np.ones(c), np.zeros(c), np.zeros(c))


def _lookup(pixels, st, wrap_s, wrap_t, xf, scale, bias, fallback) -> np.ndarray:
    """lookup_row over st (n, 2) and every channel of pixels (H, W, C): (n, C) float64."""
    for mode in (wrap_s, wrap_t):
        if mode not in WRAP_MODES:
            raise StageError(f"unknown texture wrap mode {mode!r}")
    h, w, c = pixels.shape
    out = np.empty((st.shape[0], c))
    f64 = np.float64
    _lookup_kernel(np.ascontiguousarray(pixels).reshape(-1), h, w, c, np.ascontiguousarray(st, dtype=f64),
                   WRAP_MODES.index(wrap_s), WRAP_MODES.index(wrap_t), np.ascontiguousarray(xf, dtype=f64),
                   np.asarray(scale, dtype=f64), np.asarray(bias, dtype=f64), np.asarray(fallback, dtype=f64), out)
    return out


class TextureCache:
    """Loads every image file once and answers vectorised UsdUVTexture lookups.

    missing: 'error' (default) raises StageError for a file that does not exist; 'fallback'
        records a warning and returns the texture's fallback value instead.
    strict: a file that exists but cannot be decoded raises StageError too (else a warning and
        the fallback value).
    warnings: human-readable messages (unreadable files, non-finite texels), each said once.

    Build-time use: ``add(tex)`` for every TextureDesc (``MaterialTable.build`` does this); after
    that, ``lookup`` only reads, so one cache can be shared by render threads.
    """

    def __init__(self, missing: str = "error", strict: bool = False):
        if missing not in ("error", "fallback"):
            raise ValueError("missing must be 'error' or 'fallback'")
        self.missing = missing
        self.strict = strict
        self.warnings: list[str] = []
        self._files: dict[str, Optional[LoadedImage]] = {}
        self._decoded: dict[tuple[str, bool], np.ndarray] = {}

    # ----------------------------------------------------------------------------------
    # Loading
    # ----------------------------------------------------------------------------------
    def _load_file(self, path: str, data: Optional[bytes] = None) -> Optional[LoadedImage]:
        if path in self._files:
            return self._files[path]
        img: Optional[LoadedImage] = None
        if data is None and (not path or not os.path.isfile(path)):
            if self.missing == "error":
                raise StageError("texture file not found", file=path or "<empty asset path>")
            self.warnings.append(f"{path or '<empty asset path>'}: texture file not found; using fallback")
        else:
            img, err = load_image(path, data)
            if img is None:
                if self.strict:
                    raise StageError(f"cannot read texture: {err.strip()}", file=path)
                self.warnings.append(f"{path}: cannot read texture ({err.strip()}); using fallback")
            elif img.nonfinite:
                self.warnings.append(
                    f"{path}: {img.nonfinite} texel(s) with non-finite values replaced by 0"
                )
        self._files[path] = img
        return img

    @staticmethod
    def decodes_srgb(tex: TextureDesc, img: LoadedImage) -> bool:
        """Whether texels of ``img`` are sRGB-decoded for this texture's sourceColorSpace."""
        cs = tex.source_color_space
        if cs == "sRGB":
            return True
        if cs == "raw":
            return False
        if cs == "auto":
            # UsdPreviewSurface spec, sourceColorSpace 'auto' (no file metadata): sRGB only for
            # 8-bit files with 3 or 4 channels (module docstring).
            return img.is_8bit and img.channels in (3, 4)
        raise StageError(f"unknown sourceColorSpace {cs!r}", file=tex.file)

    @staticmethod
    def udim_tile(tex: TextureDesc, i: int) -> TextureDesc:
        """Tile i of a UDIM texture as a plain texture: its own file, clamped at its edges,
        looked up at tile-local st (the st transform is applied before the tile is chosen)."""
        return replace(tex, file=tex.udim_tiles[i][1], data=tex.udim_data[i] if tex.udim_data else None,
                       wrap_s="clamp", wrap_t="clamp", st_transform=(), udim_tiles=(), udim_data=())

    def add(self, tex: TextureDesc) -> None:
        """Load (once) and decode the image of ``tex`` (each tile of a UDIM texture); validate
        its wrap modes and output."""
        for mode in (tex.wrap_s, tex.wrap_t):
            if mode not in WRAP_MODES and mode != "useMetadata":
                raise StageError(f"unknown texture wrap mode {mode!r}", file=tex.file)
        output_channels(tex.output)
        if tex.udim_tiles:
            for i in range(len(tex.udim_tiles)):
                self.add(self.udim_tile(tex, i))
            return
        img = self._load_file(tex.file, tex.data)
        if img is None:
            return
        key = (tex.file, self.decodes_srgb(tex, img))
        if key not in self._decoded:
            px = img.pixels
            if key[1]:
                px = px.copy()
                px[..., 0:3] = srgb_to_linear(px[..., 0:3]).astype(np.float32)
            px.setflags(write=False)
            self._decoded[key] = px

    def wrap_modes(self, tex: TextureDesc) -> tuple[str, str]:
        """(s, t) wrap modes of ``tex`` with 'useMetadata' resolved from its file (module
        docstring: the file's wrap metadata, else 'black')."""
        img = self._files.get(tex.file)
        meta = img.wrap_metadata if img is not None else None
        modes = []
        for axis, mode in enumerate((tex.wrap_s, tex.wrap_t)):
            if mode == "useMetadata":
                mode = meta[axis] if meta is not None else "black"
            modes.append(mode)
        return modes[0], modes[1]

    def add_all(self, textures: Iterable[TextureDesc]) -> None:
        for tex in textures:
            self.add(tex)

    def image(self, tex: TextureDesc) -> Optional[np.ndarray]:
        """The decoded (H, W, 4) float32 pixels used for ``tex`` (row 0 = bottom), or None when
        the file could not be loaded."""
        if tex.file not in self._files:
            self.add(tex)
        img = self._files[tex.file]
        if img is None:
            return None
        key = (tex.file, self.decodes_srgb(tex, img))
        if key not in self._decoded:
            self.add(tex)
        return self._decoded[key]

    # ----------------------------------------------------------------------------------
    # Lookup
    # ----------------------------------------------------------------------------------
    def lookup(self, tex: TextureDesc, st: np.ndarray) -> np.ndarray:
        """RGBA (n, 4) float64 of ``tex`` at st (n, 2): bilinear texel * scale + bias.

        Rows whose st is not finite, and every row when the file failed to load, get ``fallback``.
        """
        st = np.asarray(st, dtype=np.float64).reshape(-1, 2)
        n = st.shape[0]
        fallback = np.asarray(tex.fallback, dtype=np.float64)
        if tex.udim_tiles:
            return self._lookup_udim(tex, st, fallback)
        px = self.image(tex)
        if px is None or n == 0:
            return np.broadcast_to(fallback, (n, 4)).copy()
        xf = np.asarray(tex.st_transform if tex.st_transform else (), dtype=np.float64)
        return _lookup(px, st, *self.wrap_modes(tex), xf, tex.scale, tex.bias, fallback)

    def _lookup_udim(self, tex: TextureDesc, st: np.ndarray, fallback: np.ndarray) -> np.ndarray:
        """lookup for a UDIM texture (module docstring): texture_row on every row."""
        out = np.empty((st.shape[0], 4))
        _texture_kernel(self.pack([tex]), 0, np.ascontiguousarray(st, dtype=np.float64), out)
        return out

    def pack(self, textures: list[TextureDesc]) -> tuple:
        """The textures (each added) as one record for compiled lookups (texture_row): (pixels
        (all images flat, float32), IMI (images, 4) int64 each image's offset, height, width,
        channels (IM_*), TXI (k, 7) int64 per texture its image or -1 (not read), wrap codes
        (WRAP_MODES), st transform and UDIM flags and its range of tiles (TX_*), TXF (k, 18) its
        st transform (m00, m01, m10, m11, t0, t1), scale, bias and fallback (4 each), tiles
        (tiles, 2) int64 each UDIM tile's number and image or -1)."""
        images: list[np.ndarray] = []

        def image_of(t: TextureDesc) -> int:
            px = self.image(t)
            if px is None:
                return -1
            for i, im in enumerate(images):
                if im is px:
                    return i
            images.append(px)
            return len(images) - 1

        k = len(textures)
        TXI = np.zeros((k, 7), dtype=np.int64)
        TXF = np.zeros((k, 18))
        tiles: list[tuple[int, int]] = []
        for j, tex in enumerate(textures):
            self.add(tex)
            for a, col in (("scale", TX_SCALE), ("bias", TX_BIAS), ("fallback", TX_FALLBACK)):
                TXF[j, col:col + 4] = np.ravel(np.asarray(getattr(tex, a), dtype=np.float64))
            if tex.st_transform:
                TXF[j, TX_XF:TX_XF + 6] = tex.st_transform
                TXI[j, TX_HAS_XF] = 1
            if tex.udim_tiles:
                TXI[j, TX_UDIM] = 1
                TXI[j, TX_TILE_LO] = len(tiles)
                tiles += [(int(number), image_of(self.udim_tile(tex, i))) for i, (number, _f) in
                          enumerate(tex.udim_tiles)]
                TXI[j, TX_TILE_HI] = len(tiles)
                continue
            TXI[j, TX_IMAGE] = image_of(tex)
            a, b = self.wrap_modes(tex)
            TXI[j, TX_WRAP_S], TXI[j, TX_WRAP_T] = WRAP_MODES.index(a), WRAP_MODES.index(b)
        shapes = np.array([im.shape for im in images], dtype=np.int64).reshape(len(images), 3)
        sizes = shapes.prod(axis=1)
        IMI = np.zeros((len(images), 4), dtype=np.int64)
        IMI[:, IM_OFFSET] = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if images else 0
        IMI[:, IM_HEIGHT:IM_CHANNELS + 1] = shapes
        pixels = (np.concatenate([im.reshape(-1) for im in images]).astype(np.float32) if images
                  else np.zeros(0, np.float32))
        return pixels, IMI, TXI, TXF, np.array(tiles, dtype=np.int64).reshape(len(tiles), 2)

    def lookup_output(self, tex: TextureDesc, st: np.ndarray) -> np.ndarray:
        """The connected output only: (n, 3) for 'rgb', (n, 1) for 'r' / 'g' / 'b' / 'a'."""
        return self.lookup(tex, st)[:, list(output_channels(tex.output))]
