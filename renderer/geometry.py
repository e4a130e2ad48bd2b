"""Small vector helpers over (n, 3) float64 arrays. Batch axis first everywhere."""

from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (n, 3) arrays -> (n,)."""
    return np.einsum("ij,ij->i", a, b)


def norm(a: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean length of (n, 3) -> (n,)."""
    return np.sqrt(dot(a, a))


def normalize(a: np.ndarray) -> np.ndarray:
    """Row-wise unit vectors; zero rows stay zero rather than becoming NaN."""
    length = norm(a)
    return a / np.where(length > 0.0, length, 1.0)[:, None]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.cross(a, b)


def coordinate_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents (s, t) for unit normals n (n, 3), branchless (Duff et al. 2017).

    (s, t, n) is right-handed: s x t = n.
    """
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], axis=1)
    t = np.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], axis=1)
    return s, t


def to_local(v: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """World vector -> shading-frame coordinates (x along s, y along t, z along n)."""
    return np.stack([dot(v, s), dot(v, t), dot(v, n)], axis=1)


def to_world(v: np.ndarray, s: np.ndarray, t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Shading-frame coordinates -> world vector."""
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a 4x4 column-vector matrix to (n, 3) points (with perspective divide if needed)."""
    h = p @ m[:3, :3].T + m[:3, 3]
    w = p @ m[3, :3] + m[3, 3]
    if np.all(w == 1.0):
        return h
    return h / w[:, None]


def transform_vectors(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Apply the linear part of a 4x4 matrix to (n, 3) direction vectors."""
    return v @ m[:3, :3].T


def transform_normals(m: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """Transform (n, 3) normals by the inverse transpose of m's linear part, then normalise."""
    inv_t = np.linalg.inv(m[:3, :3]).T
    return normalize(nrm @ inv_t.T)


def offset_origin(p: np.ndarray, ng: np.ndarray, w: np.ndarray, eps: np.ndarray | float) -> np.ndarray:
    """Move ray origins off a surface to the side that w leaves from.

    p: (n, 3) hit points; ng: (n, 3) geometric normals; w: (n, 3) outgoing directions;
    eps: scalar or (n,) offset length, in scene units. embree's tnear is fixed at 0, so this
    is how we avoid self-intersection; eps scales with the magnitude of p (see accel.ray_epsilon).
    """
    side = np.where(dot(ng, w) >= 0.0, 1.0, -1.0)
    e = np.asarray(eps, dtype=np.float64)
    if e.ndim == 1:
        e = e[:, None]
    return p + ng * (side[:, None] * e)
