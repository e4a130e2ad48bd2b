"""Pixel reconstruction filters and the two ways the film applies them.

A filter is separable, f(dx, dy) = f1(dx) f1(dy), with dx, dy the offset in pixels from a pixel
centre, and zero for |dx| or |dy| >= radius:

* ``gaussian``: f1(x) = exp(-x^2 / (2 sigma^2)) - exp(-r^2 / (2 sigma^2)), sigma = r / 3 (the
  default r = 1.5 px gives pbrt-v4's sigma = 0.5 px; subtracting the value at r makes it reach 0
  there instead of jumping);
* ``box``: f1(x) = 1 (default r = 0.5 px: each pixel averages its own square);
* ``blackman-harris``: the 4-term Blackman-Harris window over [-r, r],
  f1(x) = a0 + a1 cos(pi x / r) + a2 cos(2 pi x / r) + a3 cos(3 pi x / r) (Cycles' default filter;
  default r = 1.5 px, the Gaussian's footprint).

Modes (``--pixel-filter-mode``, ``illum:pixelFilter:mode``; renderer/film.py):

* ``splat``: each camera sample is taken at a uniformly jittered point of its pixel and adds
  w = f(dx, dy) times its radiance into every pixel whose footprint covers it; a pixel is
  sum(w L) / sum(w) (Mitsuba, RenderMan, Karma).
* ``importance``: filter importance sampling: the sample's offset is drawn from f itself (a
  tabulated inverse CDF), every sample has weight 1 and lands in its own pixel only (pbrt-v4,
  Cycles).

The default is ``splat``: at equal time and the same filter its per-pixel relMSE, each mode
against its own converged render, is lower on the benchmark stages (bench/results/film/README.md:
3.6x on the Cornell box). A pixel averages the ~9 samples under its footprint rather than one,
weighted, which for the Gaussian cuts the noise variance to about 1 / (4 pi sigma^2) = 0.32 of
filter importance sampling's; the splat costs ~140 ns of CPU a sample more than importance
sampling's add (film._splat_kernel, 3 x 3 pixels, 12 sums each), about a tenth of a fast-path
sample. Its price: neighbouring pixels' errors are correlated, and a pixel is a ratio estimate
(consistent, with an O(1/n) bias), so tests that sum per-pixel variances over an image use
``importance``.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import SettingsError

FILTERS = ("gaussian", "box", "blackman-harris")
MODES = ("splat", "importance")
DEFAULT_FILTER = "gaussian"
DEFAULT_MODE = "splat"
DEFAULT_RADIUS = {"gaussian": 1.5, "box": 0.5, "blackman-harris": 1.5}
# Below half a pixel a splatted sample near a pixel's corner would reach no pixel centre; beyond 8
# a splat touches more than 256 pixels.
MIN_RADIUS = 0.5
MAX_RADIUS = 8.0
_BLACKMAN_HARRIS = (0.35875, 0.48829, 0.14128, 0.01168)


def filter_profile(name: str, radius: float, x: np.ndarray) -> np.ndarray:
    """The 1-D profile f1 at offsets x (any shape, pixels): peak 1 at x = 0 for the box and
    Blackman-Harris, 1 - exp(-4.5) for the Gaussian; 0 for |x| >= radius."""
    x = np.abs(np.asarray(x, dtype=np.float64))
    if name == "gaussian":
        sigma = radius / 3.0
        v = np.exp(-0.5 * (x / sigma) ** 2) - math.exp(-0.5 * (radius / sigma) ** 2)
    elif name == "box":
        v = np.ones_like(x)
    elif name == "blackman-harris":
        a0, a1, a2, a3 = _BLACKMAN_HARRIS
        t = np.pi * x / radius
        v = a0 + a1 * np.cos(t) + a2 * np.cos(2.0 * t) + a3 * np.cos(3.0 * t)
    else:
        raise SettingsError(f"'{name}' is not one of {', '.join(FILTERS)}", attribute="pixel-filter")
    return np.where(x < radius, np.maximum(v, 0.0), 0.0)


def check_filter(name, radius, attribute_name: str = "pixel-filter",
                 attribute_radius: str = "pixel-filter-width") -> tuple[str, float]:
    """(name, radius) validated: a known filter and a finite radius in [MIN_RADIUS, MAX_RADIUS]
    (None: the filter's default). SettingsError naming the attribute otherwise."""
    if name not in FILTERS:
        raise SettingsError(f"'{name}' is not one of {', '.join(FILTERS)}", attribute=attribute_name)
    if radius is None:
        return name, DEFAULT_RADIUS[name]
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise SettingsError(f"expected a number of pixels, got {radius!r}", attribute=attribute_radius) from None
    if not (math.isfinite(r) and MIN_RADIUS <= r <= MAX_RADIUS):
        raise SettingsError(f"radius {radius!r} px is outside [{MIN_RADIUS:g}, {MAX_RADIUS:g}]",
                            attribute=attribute_radius)
    return name, r


def check_mode(mode, attribute: str = "pixel-filter-mode") -> str:
    if mode not in MODES:
        raise SettingsError(f"'{mode}' is not one of {', '.join(MODES)}", attribute=attribute)
    return mode


class PixelFilter:
    """A separable pixel filter (module docstring) with its two tables:

    * ``_inv`` (T,): the inverse CDF of f1 normalised, at evenly spaced u in [0, 1], so drawing
      an offset is an index computation and a lerp (camera._filter_offset);
    * ``_values`` (V,): f1 at evenly spaced |x| in [0, radius], for the splatting film's weights
      (film._splat_kernel lerps in it).
    """

    def __init__(self, name: str = DEFAULT_FILTER, radius: float | None = None, table: int = 1025):
        self.name, self.radius = check_filter(name, radius)
        r = self.radius
        x = np.linspace(-r, r, table)
        g = filter_profile(self.name, r, x)
        g[-1] = g[0] = filter_profile(self.name, r, np.nextafter(r, 0.0))  # the closed end of [-r, r]
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(x))])
        self._cdf = cdf / cdf[-1]
        self._x = x
        if self.name == "box":
            # The box's CDF is linear: two knots sample it exactly (offset = -r + 2 r u).
            self._inv = np.array([-r, r])
        else:
            # The inverse CDF tabulated at evenly spaced u, so a sample is one index computation
            # and a lerp instead of np.interp's binary search (~6x cheaper, per camera ray); 16x
            # the CDF's knots keep the steep tails exact to the chi-square test's resolution.
            self._inv = np.interp(np.linspace(0.0, 1.0, 16 * (table - 1) + 1), self._cdf, self._x)
        values = filter_profile(self.name, r, np.linspace(0.0, r, 4 * (table - 1) + 1))
        values[-1] = 0.0  # f1(r) = 0: the kernel only weighs pixels strictly inside the footprint
        self._values = np.ascontiguousarray(values)

    def __repr__(self) -> str:
        return f"PixelFilter({self.name!r}, {self.radius:g})"

    def evaluate(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """f(dx, dy) = f1(dx) f1(dy) (unnormalised), offsets in pixels (any matching shapes)."""
        return filter_profile(self.name, self.radius, dx) * filter_profile(self.name, self.radius, dy)

    def sample(self, u: np.ndarray) -> np.ndarray:
        """u (n, 2) -> pixel offsets (n, 2) from the pixel centre, distributed as f normalised."""
        k = self._inv.size - 1
        f = np.clip(u, 0.0, 1.0) * k
        i = np.minimum(f.astype(np.int64), k - 1)
        lo = self._inv[i]
        return lo + (f - i) * (self._inv[i + 1] - lo)


def jitter() -> PixelFilter:
    """What a splatting camera samples: offsets uniform over its own pixel (a box of radius 0.5,
    whose inverse CDF is offset = u - 0.5)."""
    return PixelFilter("box", 0.5)
