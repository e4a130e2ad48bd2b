"""Shared helpers for BSDF tests: building BSDFs with constant parameters, directions."""

from __future__ import annotations

import numpy as np

from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF


def direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    """Unit (3,) local direction at polar angle theta from +z, azimuth phi."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def tile(v, n: int) -> np.ndarray:
    return np.tile(np.asarray(v, dtype=np.float64), (n, 1))


def preview(
    n: int,
    *,
    diffuse=(0.8, 0.8, 0.8),
    specular=(0.0, 0.0, 0.0),
    specular_workflow: bool = False,
    metallic: float = 0.0,
    roughness: float = 0.5,
    ior: float = 1.5,
) -> PreviewSurfaceBSDF:
    """A PreviewSurfaceBSDF of n identical points from UsdPreviewSurface inputs."""
    return PreviewSurfaceBSDF.from_inputs(
        tile(diffuse, n),
        tile(specular, n),
        np.full(n, specular_workflow),
        np.full(n, float(metallic)),
        np.full(n, float(roughness)),
        np.full(n, float(ior)),
    )


def reflect_z(w: np.ndarray) -> np.ndarray:
    """Mirror direction about the normal: (-x, -y, z)."""
    return np.array([-w[0], -w[1], w[2]])


