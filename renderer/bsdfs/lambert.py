"""Lambertian reflection: f = rho / pi on the upper hemisphere, cosine-weighted sampling.

Local shading frame (z = normal); reflection only: f and pdf are 0 when wo.z <= 0 or wi.z <= 0.
"""

from __future__ import annotations

import numpy as np

from renderer.bsdfs.base import BSDFSample
from renderer.sampling import INV_PI, sample_cosine_hemisphere

LOBE_DIFFUSE = 0


class LambertBSDF:
    """Lambert for n shading points. albedo: (n, 3) reflectance rho (linear RGB, not clamped)."""

    def __init__(self, albedo: np.ndarray):
        self.albedo = np.ascontiguousarray(albedo, dtype=np.float64)

    def __len__(self) -> int:
        return self.albedo.shape[0]

    def take(self, rows: np.ndarray) -> "LambertBSDF":
        """The BSDF of a subset of the shading points."""
        return LambertBSDF(self.albedo[rows])

    @staticmethod
    def _both_up(wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        return (wo[:, 2] > 0.0) & (wi[:, 2] > 0.0)

    def f(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) rho / pi where both directions are above the surface, else 0."""
        return np.where(self._both_up(wo, wi)[:, None], self.albedo * INV_PI, 0.0)

    def f_diffuse(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) the whole BSDF is the diffuse lobe."""
        return self.f(wo, wi)

    def f_parts(self, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f (n, 3), f_diffuse (n, 3), pdf (n,)) in one call (same interface as
        PreviewSurfaceBSDF.f_parts); f and f_diffuse are equal but distinct arrays."""
        up = self._both_up(wo, wi)
        f = np.where(up[:, None], self.albedo * INV_PI, 0.0)
        return f, f.copy(), np.where(up, wi[:, 2] * INV_PI, 0.0)

    def bind_wo(self, wo: np.ndarray) -> "LambertBSDF":
        """No-op (Lambert has no wo-dependent terms worth caching); returns self. Same interface
        as PreviewSurfaceBSDF.bind_wo."""
        return self

    def f_specular(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) zeros: Lambert has no non-diffuse lobe."""
        return np.zeros((wo.shape[0], 3))

    def pdf(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n,) cos(theta_i) / pi where both directions are above the surface, else 0."""
        return np.where(self._both_up(wo, wi), wi[:, 2] * INV_PI, 0.0)

    def sample_f(self, wo: np.ndarray, u_lobe: np.ndarray, u: np.ndarray) -> BSDFSample:
        """Cosine-weighted wi from u (n, 2); u_lobe is unused (one lobe). pdf 0 if wo.z <= 0."""
        wi = sample_cosine_hemisphere(u)
        return BSDFSample(
            f=self.f(wo, wi),
            wi=wi,
            pdf=self.pdf(wo, wi),
            lobe=np.full(wo.shape[0], LOBE_DIFFUSE, dtype=np.int8),
        )

    # Control-variate decomposition (same interface as PreviewSurfaceBSDF):
    # f_diffuse == diffuse_constant(wo) * diffuse_factor_wi(wi).
    def diffuse_albedo(self) -> np.ndarray:
        """(n, 3) rho."""
        return self.albedo

    def diffuse_constant(self, wo: np.ndarray) -> np.ndarray:
        """(n, 3) rho / pi (0 where wo.z <= 0): f_diffuse is constant in wi."""
        return np.where((wo[:, 2] > 0.0)[:, None], self.albedo * INV_PI, 0.0)

    def has_residual(self) -> np.ndarray:
        """(n,) bool: f differs from the control lobe diffuse_constant(wo) -- never for Lambert."""
        return np.zeros(self.albedo.shape[0], dtype=bool)

    def diffuse_factor_wi(self, wi: np.ndarray) -> np.ndarray:
        """(n, 3) 1 where wi.z > 0, else 0."""
        return np.broadcast_to((wi[:, 2] > 0.0).astype(np.float64)[:, None], (wi.shape[0], 3)).copy()
