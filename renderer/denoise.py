"""Denoising the beauty with Intel Open Image Denoise 2 (the optional ``pyoidn`` package,
``pip install 'illum[denoise]'``).

The RT filter runs in HDR mode on the beauty's RGB, guided by the first-hit albedo and world
normal (renderer/aov.py), which come from the same camera samples as the beauty. Auxiliaries:
``clean_aux=False`` (OIDN treats them as possibly noisy and cleans them itself): ours are
noise-free inside surfaces (first hit only, no indirect or glossy noise) but not at silhouettes,
textures and cut-outs at low spp, where their anti-aliasing noise is the beauty's. On the
Cornell box (bench/bench_denoise.py, bench/results/denoise/README.md) noisy auxiliaries beat
cleanAux by 7-22 % on a splatted film and come within 16 % of it with filter importance
sampling, the film mode --denoise defaults to (OIDN removes per-pixel independent noise far
better than a splatted film's correlated noise: 29x lower relMSE at 4 spp instead of 1.3x).
The raw beauty is always kept; the denoised one is a separate layer or file.
"""

from __future__ import annotations

import time

import numpy as np

from .errors import SettingsError

__all__ = ["require_oidn", "denoise", "CLEAN_AUX"]

CLEAN_AUX = False


def require_oidn():
    """The pyoidn module, or a SettingsError (exit 2, before any rendering) saying how to get it."""
    try:
        import pyoidn
    except Exception as e:  # a broken install (missing shared library) fails here too, not mid-render
        raise SettingsError(f"needs Intel Open Image Denoise: the pyoidn package is not importable ({e}); "
                            "install it with pip install 'illum[denoise]' (pyoidn==2.5.1)",
                            attribute="denoise") from None
    return pyoidn


def denoise(color: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None, *,
            clean_aux: bool = CLEAN_AUX) -> tuple[np.ndarray, float]:
    """(denoised (h, w, 3) float32, seconds) of a linear HDR beauty color (h, w, 3), guided by
    albedo in [0, 1] and world normal in [-1, 1] (each (h, w, 3), or None). OIDN failures are a
    RuntimeError naming OIDN's message."""
    pyoidn = require_oidn()
    col = np.ascontiguousarray(np.maximum(color, 0.0), dtype=np.float32)  # OIDN's HDR input is >= 0
    aux = {}
    if albedo is not None:
        aux["albedo"] = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), dtype=np.float32)
        if normal is not None:  # OIDN takes a normal only along with an albedo
            aux["normal"] = np.ascontiguousarray(np.clip(normal, -1.0, 1.0), dtype=np.float32)
    t0 = time.perf_counter()
    try:
        out = pyoidn.denoise(col, hdr=True, clean_aux=bool(clean_aux and aux), **aux)
    except Exception as e:
        raise RuntimeError(f"OIDN denoising failed: {e}") from None
    return np.asarray(out, dtype=np.float32), time.perf_counter() - t0
