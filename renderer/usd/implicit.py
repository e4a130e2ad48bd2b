"""Tessellation of UsdGeom's implicit surfaces (pure numpy, local space, scene units).

Every function returns ``(points (V, 3) float64, triangles (T, 3) int64, normals (V, 3)
float64)``: unit outward normals per vertex, triangles counter-clockwise seen from outside.
Vertices along creases (cap rims, cube edges) are duplicated so normals stay analytic.

Quadrics are built as surfaces of revolution about the local +Z axis from a meridian profile,
then the ``axis`` token rotates Z onto X or Y with a proper rotation (det +1).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["sphere", "cube", "cylinder", "cone", "capsule", "plane", "SEGMENTS", "RINGS"]

# Resolution chosen so that per-vertex normal interpolation shades smoothly at film
# resolution: 96 segments around, 48 rings pole to pole (~9k triangles per sphere).
SEGMENTS = 96
RINGS = 48


def _axis_matrix(axis: str) -> np.ndarray:
    """(3, 3) rotation taking local +Z to the given axis (cyclic permutation, det +1)."""
    if axis == "X":
        return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    if axis == "Y":
        return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    return np.eye(3)


def _revolve(segments: list[np.ndarray], axis: str, n_around: int = SEGMENTS):
    """Revolve meridian profiles about +Z.

    segments: list of (m, 4) arrays of (rho, z, n_rho, n_z) samples, each a smooth run going
    from the surface's -Z end towards +Z along the outside; consecutive runs meet at creases.
    """
    phi = np.linspace(0.0, 2.0 * math.pi, n_around + 1)  # seam column duplicated
    cos, sin = np.cos(phi), np.sin(phi)
    pts, nrm, tris = [], [], []
    base = 0
    for prof in segments:
        rho, z, nr, nz = (prof[:, k][:, None] for k in range(4))
        m = len(prof)
        p = np.stack([rho * cos, rho * sin, np.broadcast_to(z, (m, n_around + 1))], axis=-1)
        n = np.stack([nr * cos, nr * sin, np.broadcast_to(nz, (m, n_around + 1))], axis=-1)
        pts.append(p.reshape(-1, 3))
        nrm.append(n.reshape(-1, 3))
        i, j = np.meshgrid(np.arange(m - 1), np.arange(n_around), indexing="ij")
        a = base + i * (n_around + 1) + j
        b = a + 1
        c = a + (n_around + 1) + 1
        d = a + (n_around + 1)
        # (a, b, c) goes around then up: its normal is d(phi) x d(profile), i.e. outward.
        lower_ok = (prof[:-1, 0] > 0.0)[:, None] & np.ones_like(a, dtype=bool)
        upper_ok = (prof[1:, 0] > 0.0)[:, None] & np.ones_like(a, dtype=bool)
        # At a pole (rho = 0) one triangle of the quad is degenerate: drop it.
        tris.append(np.stack([a, b, c], axis=-1)[lower_ok])
        tris.append(np.stack([a, c, d], axis=-1)[upper_ok])
        base += m * (n_around + 1)
    points = np.concatenate(pts)
    normals = np.concatenate(nrm)
    triangles = np.concatenate(tris).astype(np.int64)
    r = _axis_matrix(axis)
    return points @ r.T, triangles, normals @ r.T


def _arc(center_z: float, radius: float, lat0: float, lat1: float, n: int) -> np.ndarray:
    """Meridian samples of a sphere of ``radius`` at z = center_z, latitudes lat0..lat1 (rad)."""
    lat = np.linspace(lat0, lat1, max(n, 1) + 1)
    c, s = np.cos(lat), np.sin(lat)
    rho = np.where(np.abs(c) < 1e-15, 0.0, radius * c)  # exact zero at the poles
    return np.stack([np.maximum(rho, 0.0), center_z + radius * s, np.maximum(c, 0.0), s], axis=1)


def _disk(z: float, radius: float, up: bool) -> np.ndarray:
    """Flat cap at height z: from the centre outwards (bottom) or from the rim inwards (top)."""
    nz = 1.0 if up else -1.0
    prof = np.array([[0.0, z, 0.0, nz], [radius, z, 0.0, nz]])
    return prof[::-1].copy() if up else prof


def _side(r0: float, r1: float, half: float) -> np.ndarray:
    """Straight side from (r0, -half) to (r1, +half), normal perpendicular to it, outward."""
    h = 2.0 * half
    n = np.array([h, r0 - r1])
    n = n / (np.linalg.norm(n) or 1.0)
    return np.array([[r0, -half, n[0], n[1]], [r1, half, n[0], n[1]]])


def sphere(radius: float):
    """UsdGeom.Sphere: centred at the origin."""
    return _revolve([_arc(0.0, radius, -math.pi / 2, math.pi / 2, RINGS)], "Z")


def cylinder(radius_bottom: float, radius_top: float, height: float, axis: str):
    """UsdGeom.Cylinder / Cylinder_1: spine along ``axis``, centred, with both end caps."""
    half = 0.5 * height
    segs = []
    if radius_bottom > 0.0:
        segs.append(_disk(-half, radius_bottom, up=False))
    segs.append(_side(radius_bottom, radius_top, half))
    if radius_top > 0.0:
        segs.append(_disk(half, radius_top, up=True))
    return _revolve(segs, axis)


def cone(radius: float, height: float, axis: str):
    """UsdGeom.Cone: base of ``radius`` at -height/2, apex at +height/2 along ``axis``; base capped."""
    return cylinder(radius, 0.0, height, axis)


def capsule(radius_bottom: float, radius_top: float, height: float, axis: str):
    """UsdGeom.Capsule / Capsule_1: spheres of the two radii centred at -/+height/2, joined by
    the cone tangent to both (a straight cylinder when the radii are equal)."""
    half = 0.5 * height
    r0, r1 = radius_bottom, radius_top
    if height <= abs(r0 - r1):
        # One sphere contains the other: the surface is the larger sphere.
        big, zc = (r0, -half) if r0 >= r1 else (r1, half)
        return _revolve([_arc(zc, big, -math.pi / 2, math.pi / 2, RINGS)], axis)
    # Tangent latitude: the side's normal elevation a satisfies sin(a) = (r0 - r1) / height.
    a = math.asin((r0 - r1) / height)
    nb = max(2, int(round(RINGS * (a + math.pi / 2) / math.pi)))
    nt = max(2, int(round(RINGS * (math.pi / 2 - a) / math.pi)))
    bottom = _arc(-half, r0, -math.pi / 2, a, nb)
    top = _arc(half, r1, a, math.pi / 2, nt)
    # bottom's last sample and top's first sample are the tangent points, with the side's normal:
    # so the three runs join smoothly and can share one profile.
    profile = np.concatenate([bottom, top])
    return _revolve([profile], axis)


def cube(size: float):
    """UsdGeom.Cube: edge length ``size``, centred; 24 vertices (flat normals), 12 triangles."""
    h = 0.5 * size
    pts, nrm, tris = [], [], []
    for k in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[k] = sign
            u = np.zeros(3)
            u[(k + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed: corners below wind counter-clockwise
            c = n * h
            base = len(pts) * 4
            pts.append([c - u * h - v * h, c + u * h - v * h, c + u * h + v * h, c - u * h + v * h])
            nrm.append([n] * 4)
            tris.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    return (np.asarray(pts, float).reshape(-1, 3), np.asarray(tris, np.int64),
            np.asarray(nrm, float).reshape(-1, 3))


def plane(width: float, length: float, axis: str):
    """UsdGeom.Plane: normal along +axis; width along X (axis Z or Y) or Z (axis X); length along
    Y (axis Z or X) or Z (axis Y), per the schema doc."""
    w, l = 0.5 * width, 0.5 * length
    if axis == "X":
        u, v, n = np.array([0.0, 0.0, 1.0]) * w, np.array([0.0, 1.0, 0.0]) * l, np.array([1.0, 0.0, 0.0])
    elif axis == "Y":
        u, v, n = np.array([1.0, 0.0, 0.0]) * w, np.array([0.0, 0.0, 1.0]) * l, np.array([0.0, 1.0, 0.0])
    else:
        u, v, n = np.array([1.0, 0.0, 0.0]) * w, np.array([0.0, 1.0, 0.0]) * l, np.array([0.0, 0.0, 1.0])
    pts = np.array([-u - v, u - v, u + v, -u + v])
    tris = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    if np.dot(np.cross(u, v), n) < 0.0:  # width x length may point against the normal (axis Y)
        tris = tris[:, [0, 2, 1]]
    return pts, tris, np.tile(n, (4, 1))
