"""The contract every BSDF implements.

A BSDF object holds per-shading-point parameters as arrays (batch axis first), already
evaluated from the material table (textures looked up). All directions are in the *local
shading frame* (z = shading normal), unit length, (n, 3) float64; ``wo`` points away from the
surface toward the previous vertex, ``wi`` toward the next. f excludes the cosine term.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class BSDFSample:
    """f: (n, 3) BSDF value (no cosine); wi: (n, 3) local direction; pdf: (n,) solid-angle pdf
    of the whole (lobe-mixture) BSDF for wi (0 = failed sample); lobe: (n,) int8 index of the
    lobe that produced it (0 diffuse, 1 specular)."""

    f: np.ndarray
    wi: np.ndarray
    pdf: np.ndarray
    lobe: np.ndarray


class BSDF(Protocol):
    def f(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) BSDF value for the pair (no cosine)."""
        ...

    def sample_f(self, wo: np.ndarray, u_lobe: np.ndarray, u: np.ndarray) -> BSDFSample:
        """Pick a lobe with u_lobe (n,) in proportion to its estimated albedo, then sample it with u (n, 2)."""
        ...

    def pdf(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n,) solid-angle pdf of sample_f producing wi (the mixture over lobes)."""
        ...

    def f_diffuse(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) the diffuse lobe alone, used by the control-variate estimators.

        It factors as ``diffuse_constant(wo) * diffuse_factor_wi(wi)`` (see
        ``SupportsDiffuseControlVariate``); for Lambert the factor is 1 (constant lobe), for the
        preview surface it is a reciprocal, energy-conserving coupling that is not constant in wi.
        """
        ...

    def f_specular(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) every non-diffuse lobe (f == f_diffuse + f_specular)."""
        ...


class SupportsDiffuseControlVariate(Protocol):
    """Optional extension (Lambert and PreviewSurfaceBSDF implement it) for control variates.

    f_diffuse(wo, wi) == diffuse_constant(wo) * diffuse_factor_wi(wi), where the factor's
    cosine-weighted mean over the upper hemisphere is 1. So g(wi) = diffuse_constant(wo) L(wi) cos
    is a constant-in-wi lobe with the diffuse lobe's directional albedo, and its integral against
    any light is analytic whenever the light's unshadowed irradiance is. A control variate built
    on it is unbiased as long as the Monte Carlo residual is f(wo, wi) - diffuse_constant(wo)
    (the full BSDF minus g), not f_specular alone, unless diffuse_factor_wi is identically 1.
    """

    def diffuse_albedo(self) -> np.ndarray:
        """(n, 3) the diffuse base albedo rho_d (before any angular coupling)."""
        ...

    def diffuse_constant(self, wo: np.ndarray) -> np.ndarray:
        """(n, 3) directional albedo of the diffuse lobe for wo, divided by pi (0 if wo.z <= 0)."""
        ...

    def diffuse_factor_wi(self, wi: np.ndarray) -> np.ndarray:
        """(n, 3) the wi-dependent factor of f_diffuse (1 for Lambert; 0 if wi.z <= 0)."""
        ...
