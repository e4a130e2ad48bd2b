"""Light textures (RectLight / DomeLight ``texture:file``) follow UsdUVTexture's 'auto' colour-space
rule from the UsdPreviewSurface spec: sRGB-decode only 8-bit files with 3 or 4 channels."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.lights.texture import load_texture_rgb, srgb_to_linear


def _write(path, px: np.ndarray, fmt) -> str:
    h, w, c = px.shape
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(w, h, c, fmt)), out.geterror()
    assert out.write_image(np.ascontiguousarray(px)), out.geterror()
    out.close()
    return str(path)


HALF = 128.0 / 255.0


@pytest.mark.parametrize("channels,fmt,dtype,stored,expected", [
    (3, oiio.UINT8, np.uint8, 128, srgb_to_linear(np.array(HALF))),   # colour: decoded
    (4, oiio.UINT8, np.uint8, 128, srgb_to_linear(np.array(HALF))),
    (1, oiio.UINT8, np.uint8, 128, HALF),                              # grey mask: as stored
    (2, oiio.UINT8, np.uint8, 128, HALF),
    (3, oiio.UINT16, np.uint16, 32768, 32768 / 65535),                 # 16-bit: as stored
])
def test_auto_rule(tmp_path, channels, fmt, dtype, stored, expected):
    px = np.full((2, 4, channels), stored, dtype=dtype)
    path = _write(tmp_path / f"t{channels}_{np.dtype(dtype).name}.png", px, fmt)
    rgb = load_texture_rgb(path, "/Light")
    assert rgb.shape == (2, 4, 3)
    np.testing.assert_allclose(rgb, float(expected), rtol=1e-6)
