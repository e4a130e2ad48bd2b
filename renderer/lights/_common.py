"""Small helpers shared by the light kinds (private to ``renderer.lights``).

All arrays have the batch axis first and are float64.
"""

from __future__ import annotations

import numpy as np

from renderer.geometry import dot, norm
from renderer.lights.base import LightLiSample

# Relative tolerance used when deciding whether a transform is a similarity (uniform scale)
# or a rectangle is still a rectangle (no shear).
SHAPE_RTOL = 1e-9


def linear_part(m: np.ndarray) -> np.ndarray:
    """(3, 3) linear part of a (4, 4) column-vector affine matrix."""
    return np.asarray(m, dtype=np.float64)[:3, :3]


def translation(m: np.ndarray) -> np.ndarray:
    """(3,) translation of a (4, 4) column-vector affine matrix."""
    return np.asarray(m, dtype=np.float64)[:3, 3].copy()


def emission_normal(ex: np.ndarray, ey: np.ndarray, m3: np.ndarray) -> np.ndarray:
    """World direction (3,) of local -Z for a planar light whose local X/Y axes map to ex, ey.

    Normals transform with the cofactor matrix: cof(M) z = (M x) x (M y), so the world image of
    local -Z (as a normal) is -sign(det M) * normalize(ex x ey). With a singular M (a zero Z
    scale, which leaves the flat light well defined) the sign is taken as +1. Returns zeros
    when ex and ey are parallel (a degenerate light).
    """
    c = np.cross(ex, ey)
    length = float(np.linalg.norm(c))
    if length <= 0.0:
        return np.zeros(3)
    det = float(np.linalg.det(m3))
    sign = -1.0 if det < 0.0 else 1.0
    return -sign * c / length


def as_points(a: np.ndarray, k: int = 3) -> np.ndarray:
    """C-contiguous float64 (n, k) view (or copy, if needed) of a: the layout the kernels take."""
    return np.ascontiguousarray(a, dtype=np.float64).reshape(-1, k)


def far_distance(p: np.ndarray, scene_center: np.ndarray, scene_radius: float) -> np.ndarray:
    """(n,) a distance from p that is outside the scene's bounding sphere in every direction."""
    r = max(float(scene_radius), 1e-30)
    return 2.0 * (r + norm(p - scene_center[None, :]))


def invalid_sample(n: int, p: np.ndarray | None = None) -> LightLiSample:
    """A batch of n failed samples (pdf 0, L 0)."""
    wi = np.zeros((n, 3))
    wi[:, 2] = 1.0
    return LightLiSample(
        L=np.zeros((n, 3)),
        wi=wi,
        pdf=np.zeros(n),
        dist=np.zeros(n),
        p_light=np.zeros((n, 3)) if p is None else p.copy(),
    )


def direction_and_distance(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction (n, 3) from p toward q and the distance (n,). Zero rows stay zero."""
    v = q - p
    d = norm(v)
    return v / np.where(d > 0.0, d, 1.0)[:, None], d


def area_to_solid_angle(pdf_area: np.ndarray, dist: np.ndarray, cos_light: np.ndarray) -> np.ndarray:
    """pdf_w = pdf_A * d^2 / |cos theta_l|, 0 where cos is 0 (grazing) or the inputs are 0."""
    c = np.abs(cos_light)
    ok = (c > 0.0) & (pdf_area > 0.0)
    num = pdf_area * dist * dist
    out = np.divide(num, np.where(ok, c, 1.0), out=np.zeros_like(num), where=ok)
    return np.where(np.isfinite(out), out, 0.0)


def ray_plane(
    o: np.ndarray, d: np.ndarray, c: np.ndarray, n: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Hit distance t (n,) of rays o + t d with the planes through c (n, 3) of normal n (n, 3).

    Returns (t, ok) with ok False for rays parallel to the plane (t is then inf).
    """
    den = dot(n, d)
    ok = den != 0.0
    num = dot(n, c - o)
    t = np.divide(num, np.where(ok, den, 1.0), out=np.full(num.shape, np.inf), where=ok)
    ok &= np.isfinite(t)
    return np.where(ok, t, np.inf), ok


def polar_decomposition_rotation(m3: np.ndarray) -> np.ndarray:
    """The orthogonal factor R (3, 3) of M = R S (closest orthogonal matrix; keeps a mirror)."""
    u, _, vt = np.linalg.svd(m3)
    return u @ vt


__all__ = [
    "SHAPE_RTOL",
    "area_to_solid_angle",
    "as_points",
    "direction_and_distance",
    "dot",
    "emission_normal",
    "far_distance",
    "invalid_sample",
    "linear_part",
    "polar_decomposition_rotation",
    "ray_plane",
    "translation",
]
