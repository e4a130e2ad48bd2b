"""Uniform sampling of the solid angle of a rectangle (Urena, Fajardo, King 2013), vectorised.

Written from the paper's maths in the cancellation-free form (the one Cycles uses): the four
angles g_i of the spherical quad are written as pi/2 + h_i with h_i = asin(nz_i * nz_{i+1}),
where nz = (-y0, x1, y1, -x0) / sqrt(. ^2 + z0^2) are the z-components of the unit normals of
the planes through the reference point and each edge. Then

    solid angle  S = h0 + h1 + h2 + h3      (no "sum of four ~pi/2 angles minus 2 pi")

and, with b0 = nz0, b1 = nz2, the inverse CDF along x is

    au = u0 * S - h2 - h3,  fu = (cos(au) b0 + b1) / sin(au),
    cu = sign(fu) / sqrt(fu^2 + b0^2),  xu = -cu z0 / sqrt(1 - cu^2)

(cu is evaluated as D sign(N) / sqrt(N^2 + b0^2 D^2) with fu = N / D, which stays finite when
sin(au) = 0), and along y the projected height is interpolated linearly:

    d = sqrt(xu^2 + z0^2),  h_k = y_k / sqrt(d^2 + y_k^2),  hv = lerp(u1, h0, h1),
    yv = hv d / sqrt(1 - hv^2).

The local frame has x along the first edge, y along the second, and z flipped so that z0 < 0.
The sample density is 1/S per steradian.

The rect and disk lights run the same method per row inside their numba kernels
(``renderer.kernels.lights._sr_setup`` / ``_sr_sample``); ``setup`` and ``sample`` below stay as
the vectorised statement of the method and for tests (and the dome's portal sampling). The
kernels compute the same quantities with fewer transcendental calls (the solid angle by one
atan, Van Oosterom & Strackee's formula for the rectangle's two triangles; h2 + h3 as a unit
complex number), agreeing with these formulas to ~1e-9 relative at worst, and more accurately
than the asin sum here for small solid angles, where its terms cancel.
MIN_SOLID_ANGLE and GRAZING_NZ2 are passed to those kernels as arguments, so this module
stays their single source of truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from renderer.geometry import cross, dot, norm

# pbrt-v4 and Cycles fall back to area sampling below ~1e-4 sr (and Cycles for grazing views);
# illum uses the same limits, decided from the (light, point) pair only.
MIN_SOLID_ANGLE = 1e-4
GRAZING_NZ2 = 0.99999


@dataclass(frozen=True)
class SphericalRect:
    """Per-row setup of a rectangle seen from a point. All (n,) or (n, 3) float64."""

    p: np.ndarray
    x_hat: np.ndarray
    y_hat: np.ndarray
    z_hat: np.ndarray
    x0: np.ndarray
    x1: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    z0: np.ndarray
    b0: np.ndarray
    b1: np.ndarray
    h2h3: np.ndarray
    solid_angle: np.ndarray
    grazing: np.ndarray

    @property
    def usable(self) -> np.ndarray:
        """(n,) bool: solid-angle sampling is well conditioned for this row."""
        return (self.solid_angle >= MIN_SOLID_ANGLE) & ~self.grazing & np.isfinite(self.solid_angle)


def setup(p: np.ndarray, corner: np.ndarray, ex: np.ndarray, ey: np.ndarray) -> SphericalRect:
    """Rectangle corner + [0,1]^2 (ex, ey) seen from p. ex and ey must be orthogonal. (n, 3) each."""
    lx = norm(ex)
    ly = norm(ey)
    x_hat = ex / np.where(lx > 0.0, lx, 1.0)[:, None]
    y_hat = ey / np.where(ly > 0.0, ly, 1.0)[:, None]
    z_hat = cross(x_hat, y_hat)
    d = corner - p
    x0 = dot(d, x_hat)
    y0 = dot(d, y_hat)
    z0 = dot(d, z_hat)
    flip = z0 > 0.0
    z_hat = np.where(flip[:, None], -z_hat, z_hat)
    z0 = np.where(flip, -z0, z0)
    x1 = x0 + lx
    y1 = y0 + ly
    z2 = z0 * z0
    num = np.stack([-y0, x1, y1, -x0], axis=1)
    den = np.sqrt(num * num + z2[:, None])
    ok = den > 0.0
    nz = np.divide(num, np.where(ok, den, 1.0), out=np.zeros_like(num), where=ok)
    prod = np.clip(nz * np.roll(nz, -1, axis=1), -1.0, 1.0)
    h = np.arcsin(prod)
    solid = h.sum(axis=1)
    solid = np.where(ok.all(axis=1) & (z0 < 0.0), np.maximum(solid, 0.0), 0.0)
    grazing = np.min(nz * nz, axis=1) > GRAZING_NZ2
    return SphericalRect(
        p=p,
        x_hat=x_hat,
        y_hat=y_hat,
        z_hat=z_hat,
        x0=x0,
        x1=x1,
        y0=y0,
        y1=y1,
        z0=z0,
        b0=nz[:, 0],
        b1=nz[:, 2],
        h2h3=h[:, 2] + h[:, 3],
        solid_angle=solid,
        grazing=grazing,
    )


def sample(sr: SphericalRect, u: np.ndarray) -> np.ndarray:
    """Points (n, 3) on the rectangle, uniformly distributed in solid angle seen from sr.p."""
    au = u[:, 0] * sr.solid_angle - sr.h2h3
    num = np.cos(au) * sr.b0 + sr.b1
    den = np.sin(au)
    q = np.sqrt(num * num + sr.b0 * sr.b0 * den * den)
    cu = np.divide(den * np.copysign(1.0, num), np.where(q > 0.0, q, 1.0), out=np.zeros_like(q), where=q > 0.0)
    cu = np.clip(cu, -1.0, 1.0)
    s = np.sqrt(np.maximum(1.0 - cu * cu, 1e-300))
    xu = np.clip(-cu * sr.z0 / s, sr.x0, sr.x1)
    dd = np.sqrt(xu * xu + sr.z0 * sr.z0)
    r0 = np.sqrt(dd * dd + sr.y0 * sr.y0)
    r1 = np.sqrt(dd * dd + sr.y1 * sr.y1)
    h0 = np.divide(sr.y0, np.where(r0 > 0.0, r0, 1.0), out=np.zeros_like(r0), where=r0 > 0.0)
    h1 = np.divide(sr.y1, np.where(r1 > 0.0, r1, 1.0), out=np.ones_like(r1), where=r1 > 0.0)
    hv = h0 + u[:, 1] * (h1 - h0)
    yv = np.clip(hv * dd / np.sqrt(np.maximum(1.0 - hv * hv, 1e-300)), sr.y0, sr.y1)
    return sr.p + xu[:, None] * sr.x_hat + yv[:, None] * sr.y_hat + sr.z0[:, None] * sr.z_hat
