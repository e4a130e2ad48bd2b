"""Lighting services (light samplers), chosen by name."""

from __future__ import annotations

import numpy as np

from ..errors import SettingsError
from .exhaustive import ExhaustiveLightSampler
from .power import PowerLightSampler
from .uniform import UniformLightSampler

SAMPLERS = {"exhaustive": ExhaustiveLightSampler, "uniform": UniformLightSampler, "power": PowerLightSampler}

# Up to this many lights, every light is estimated at every vertex (each with its own
# estimator and N): the variance of picking is worse than the cost of a few more shadow rays.
EXHAUSTIVE_MAX_LIGHTS = 8

__all__ = ["SAMPLERS", "make_light_sampler", "ExhaustiveLightSampler", "PowerLightSampler", "UniformLightSampler"]


def make_light_sampler(name: str, lights):
    """Build the named sampler over a LightSet. 'auto' picks by light count:
    exhaustive up to EXHAUSTIVE_MAX_LIGHTS lights, power beyond."""
    phi = lights.phi() if lights.count else np.zeros(0)
    if name in ("", "auto"):
        name = "exhaustive" if np.asarray(phi).size <= EXHAUSTIVE_MAX_LIGHTS else "power"
    if name not in SAMPLERS:
        raise SettingsError(f"unknown light sampler {name!r}; choose from {sorted(SAMPLERS)}",
                            attribute="light_sampler")
    return SAMPLERS[name](phi)
