"""UsdLux ShadowAPI on shadow rays: enable, distance and falloff (the colour is folded into the
estimators' integrand, see estimators/base.py ``tint_shadows``).

The visibility v of a shadow ray from the shading point toward a light is, for a light with
ShadowAPI (UsdLux user doc, ShadowAPI; RenderMan's shadow distance/falloff controls):

* ``shadow:enable = false``: v = 1, and no ray is traced.
* ``shadow:distance`` d > 0: only occluders closer than d to the shading point cast shadow
  ("the maximum distance between occluder and shadow-receiving surface within which shadows
  will be cast"); with no falloff zone that is an occlusion query over [0, min(d, dist)).
* ``shadow:falloff`` f in (0, d] and ``shadow:falloffGamma`` g: the shadow strength fades over
  the zone [d - f, d] "from full shadow at the beginning of the falloff zone to no shadow at
  the maximum shadow distance", as a gamma of the linear distance:

      s(t) = 1                      t <= d - f
             ((d - t) / f) ** g     d - f < t < d
             0                      t >= d

  with t the distance from the shading point to the occluder. s is non-increasing in t, so the
  nearest occluder decides: one closest-hit query over [0, min(d, dist)) gives t, v = 1 - s(t).

v is then fractional (in [0, 1]); every estimator is linear in v, so MIS, light and BSDF
sampling stay unbiased, and the control variate's alpha = v_bar is simply the mean of the
fractional v (docs/lights.md, "Shaping and shadows").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["ShadowParams", "shadow_params", "shadow_strength", "visibility"]


@dataclass(frozen=True)
class ShadowParams:
    """Shadow-ray behaviour of a group of lights (hashable: lights with equal params share it).

    enable: trace shadow rays at all; distance: occluders beyond it are ignored (inf: no limit);
    falloff: width of the fade zone before distance (0: a hard cut); gamma: fade exponent.
    """

    enable: bool = True
    distance: float = math.inf
    falloff: float = 0.0
    gamma: float = 1.0


def shadow_params(desc) -> ShadowParams | None:
    """ShadowParams of a ShadowDesc, or None when the shadow rays are plain (the colour alone
    does not change the rays)."""
    if desc is None:
        return None
    if not desc.enable:
        return ShadowParams(enable=False)
    if not desc.distance > 0.0:
        return None
    falloff = min(float(desc.falloff), float(desc.distance)) if desc.falloff > 0.0 else 0.0
    return ShadowParams(True, float(desc.distance), falloff, float(desc.falloff_gamma))


def visibility(accel, o: np.ndarray, wi: np.ndarray, t_max: np.ndarray, params: ShadowParams) -> tuple[np.ndarray, int]:
    """(v (m,) float in [0, 1], rays traced) for shadow rays o + t wi, t in (0, t_max).

    o: (m, 3) already offset origins; wi: (m, 3) unit; t_max: (m,) (inf for infinite lights).
    """
    m = o.shape[0]
    if not params.enable:
        return np.ones(m), 0
    t_lim = np.minimum(t_max, params.distance)
    if params.falloff <= 0.0:
        return (~accel.occluded(o, wi, t_lim)).astype(np.float64), m
    t = accel.intersect(o, wi, t_lim).t  # inf where nothing is hit before the limit
    v = np.empty(m)
    strength_kernel(t, params.distance, params.falloff, params.gamma, v)
    return 1.0 - v, m


@njit(cache=True, nogil=True)
def shadow_strength(t, distance, falloff, gamma):
    """s(t) of the module docstring for the nearest occluder at distance t (inf: none) and a
    falloff zone of width falloff > 0 ending at distance: the one formula of both routes (the
    fast path's kernels call it per shadow ray, _trace_kernel.shadow_visibility_kernel)."""
    if not math.isfinite(t):
        return 0.0
    x = min(max((distance - t) / falloff, 0.0), 1.0)  # 1 at the zone's start (and nearer), 0 at d
    return x ** gamma


@njit(cache=True, nogil=True)
def strength_kernel(t, distance, falloff, gamma, out):
    """out[i] = shadow_strength(t[i], distance, falloff, gamma) for t (m,) float64."""
    for i in range(t.shape[0]):
        out[i] = shadow_strength(t[i], distance, falloff, gamma)
