"""UsdLux emission: from a light's raw inputs to the radiance it emits (linear Rec.709, nits).

The formula is the clarified UsdLux one (OpenUSD user doc, "Clarification of UsdLux
Quantities"), applied multiplicatively in sequence:

    L = intensity * 2^exposure                      (scalar, nits)
    L /= sizeFactor                    if normalize (ignored for domes)
    L = L * color                                   (rendering colour space = linear Rec.709)
    L *= blackbody_rgb(colorTemperature) if enableColorTemperature (6500 K -> white)

sizeFactor is the *world-space* surface area for area lights (rect, disk, sphere, cylinder),
including any scale in the light's transform (each kind module computes it:
``RectLight.world_area`` ...), and for distant lights, with
theta_max = clamp(radians(angle) / 2, 0, pi):

    1                          if theta_max == 0
    pi * sin^2(theta_max)      if theta_max <= pi / 2
    pi * (2 - sin^2(theta_max)) otherwise

so that a normalized distant light's intensity is the illuminance (lux) at normal incidence.
For a distant light with angle 0 (a delta light) the value returned is that irradiance itself.

Shaping (focus, cone, IES) is not applied here: it depends on the emission direction.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.color import blackbody_rgb
from renderer.description import LightDesc
from renderer.errors import StageError

AREA_KINDS = ("rect", "disk", "sphere", "cylinder", "mesh")


def distant_half_angle(angle_deg: float) -> float:
    """theta_max = clamp(radians(angle) / 2, 0, pi) in radians."""
    return min(max(math.radians(float(angle_deg)) / 2.0, 0.0), math.pi)


def distant_size_factor(angle_deg: float) -> float:
    """The UsdLux sizeFactor of a distant light of angular diameter ``angle_deg`` (degrees)."""
    theta = distant_half_angle(angle_deg)
    if theta == 0.0:
        return 1.0
    s2 = math.sin(theta) ** 2
    if theta <= math.pi / 2.0:
        return math.pi * s2
    return math.pi * (2.0 - s2)


def size_factor(desc: LightDesc, world_area: float) -> float:
    """The divisor applied when ``normalize`` is on (1 when it is off or ignored)."""
    if not desc.normalize or desc.kind == "dome":
        return 1.0
    if desc.kind == "distant":
        return distant_size_factor(desc.angle)
    return float(world_area)


def emitted_radiance(desc: LightDesc, world_area: float) -> np.ndarray:
    """Radiance (3,) emitted by the light, linear Rec.709, in nits.

    world_area: world-space surface area of an area light (scene units^2; ignored for domes
    and distant lights). A normalized area light with zero area gets zero radiance (the light
    set drops it as degenerate). Raises StageError for non-finite inputs.
    """
    scalar = float(desc.intensity) * 2.0 ** float(desc.exposure)
    color = np.asarray(desc.color, dtype=np.float64).reshape(3)
    if not math.isfinite(scalar) or not np.all(np.isfinite(color)):
        raise StageError(
            f"light intensity * 2^exposure * color is not finite "
            f"(intensity={desc.intensity}, exposure={desc.exposure}, color={tuple(desc.color)})",
            prim=desc.path,
        )
    sf = size_factor(desc, world_area)
    if not sf > 0.0 or not math.isfinite(sf):
        return np.zeros(3)
    L = (scalar / sf) * color
    if desc.enable_color_temperature:
        L = L * blackbody_rgb(desc.color_temperature)
    return L
