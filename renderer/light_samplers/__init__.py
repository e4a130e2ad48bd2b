"""Lighting services (light samplers), chosen by name."""

from __future__ import annotations

import numpy as np

from ..errors import SettingsError
from .power import PowerLightSampler
from .uniform import UniformLightSampler

SAMPLERS = {"uniform": UniformLightSampler, "power": PowerLightSampler}

__all__ = ["SAMPLERS", "make_light_sampler", "PowerLightSampler", "UniformLightSampler"]


def make_light_sampler(name: str, phi: np.ndarray):
    """Build the named sampler over light powers phi (count,). 'auto' picks by light count."""
    if name in ("", "auto"):
        name = "power"
    if name not in SAMPLERS:
        raise SettingsError(f"unknown light sampler {name!r}; choose from {sorted(SAMPLERS)}",
                            attribute="light_sampler")
    return SAMPLERS[name](phi)
