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
        """(n, 3) the diffuse (constant) lobe alone, used by the control-variate estimators."""
        ...

    def f_specular(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) every non-diffuse lobe (f == f_diffuse + f_specular)."""
        ...
