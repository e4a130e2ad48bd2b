"""Colour helpers: blackbody colour temperature and Rec.709 luminance.

Every colour in illum is linear Rec.709 RGB (sRGB primaries, D65 white, no transfer curve).

Blackbody convention
--------------------
``blackbody_rgb(T)`` integrates Planck's law against the CIE 1931 2-degree observer
(colour-science), converts XYZ (scaled to Y = 1) to linear Rec.709 *without* chromatic
adaptation, and divides component-wise by the same quantity at 6500 K, so that

    blackbody_rgb(6500) == (1, 1, 1)   exactly.

This follows the normative UsdLux text ("always calculated as an RGB color using a D65 white
point ... normalized such that the fallback value of 6500 will always result in white"). It is
*not* what OpenUSD's own ``UsdLux.BlackbodyTemperatureAsRgb`` returns: that normalises to Rec.709
luma 1, so 6500 K gives (1.0433, 0.9836, 1.0346). Between 2000 K and 10000 K the two differ by
at most 4.2 % per component (a near-constant ratio, the white point of the spectral locus);
below ~1700 K OpenUSD uses its own approximation knots and the small green/blue components
differ more (at 1000 K the green is 0.041 here vs 0.118 in OpenUSD). Luminance is close to,
but not exactly, 1 (0.994 at 3000 K).

Negative components (the spectral route gives a slightly negative blue below ~1900 K) are
clamped to 0. T is clamped to the documented valid range [1000, 10000] K; the caller (the USD
reader or the light builder) is responsible for warning about out-of-range values.
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np

# Rec.709 / sRGB luminance weights (Y row of the RGB->XYZ matrix for D65).
REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

BLACKBODY_T_MIN = 1000.0
BLACKBODY_T_MAX = 10000.0
BLACKBODY_WHITE_T = 6500.0


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec.709 luminance of linear RGB: rgb (..., 3) -> (...)."""
    return np.asarray(rgb, dtype=np.float64) @ REC709_LUMINANCE


def clamp_temperature(T: float) -> float:
    """T clamped to the UsdLux valid range [1000, 10000] K (NaN maps to 6500 K)."""
    T = float(T)
    if not np.isfinite(T):
        return BLACKBODY_WHITE_T if np.isnan(T) else (BLACKBODY_T_MAX if T > 0 else BLACKBODY_T_MIN)
    return min(max(T, BLACKBODY_T_MIN), BLACKBODY_T_MAX)


@lru_cache(maxsize=None)
def _spectral_rgb(T: float) -> tuple[float, float, float]:
    """Linear Rec.709 RGB of a blackbody at T kelvin, scaled so that Y == 1 (not yet white-balanced)."""
    # colour-science warns (ColourUsageWarning) when SciPy or Matplotlib are missing, at import
    # and on some calls; none of it affects this computation, so keep the warnings local.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour  # imported lazily: ~1.5 s

        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
        sd = colour.sd_blackbody(T, colour.SpectralShape(360, 830, 1))
        xyz = np.asarray(colour.sd_to_XYZ(sd, cmfs), dtype=np.float64)
        rgb = colour.XYZ_to_RGB(
            xyz / xyz[1],
            colour.RGB_COLOURSPACES["sRGB"],
            chromatic_adaptation_transform=None,
            apply_cctf_encoding=False,
        )
    rgb = np.asarray(rgb, dtype=np.float64)
    return float(rgb[0]), float(rgb[1]), float(rgb[2])


@lru_cache(maxsize=1024)
def _blackbody_cached(T: float) -> tuple[float, float, float]:
    rgb = np.array(_spectral_rgb(T)) / np.array(_spectral_rgb(BLACKBODY_WHITE_T))
    rgb = np.maximum(rgb, 0.0)
    return float(rgb[0]), float(rgb[1]), float(rgb[2])


def blackbody_rgb(T: float) -> np.ndarray:
    """Linear Rec.709 colour (3,) of a blackbody at T kelvin, 6500 K -> exactly (1, 1, 1).

    T is clamped to [1000, 10000] K; negative components are clamped to 0. Results are cached.
    """
    T = clamp_temperature(T)
    if T == BLACKBODY_WHITE_T:
        return np.ones(3)
    return np.array(_blackbody_cached(T))
