"""UsdLuxSphereLight: a sphere emitting outward only, or a point light with ``treatAsPoint``.

Sampling from a point outside the sphere: uniform in the cone of directions it subtends
(pbrt-v4's method) and the exact map of the sampled cone direction to the visible sphere point
(cos alpha = sin^2 theta / sin theta_max + cos theta sqrt(1 - sin^2 theta / sin^2 theta_max)),
so no ray is cast. pdf_w = 1 / (2 pi (1 - cos theta_max)).

Small cones: pbrt switches to a Taylor branch when sin^2 theta_max < 0.00068523 (sin^2 1.5 deg),
using 1 - cos theta_max ~ sin^2 theta_max / 2 and sin^2 theta = u0 sin^2 theta_max. Those
approximations make the sampled density differ from the reported pdf by up to
sin^2 theta_max / 2 (relative), which a tight z-test detects (9e-5 for a 0.2-radius sphere at
distance 10). illum keeps the branch point but makes both sides exact and cancellation-free:
1 - cos theta_max = sin^2 theta_max / (1 + cos theta_max), the sample draws
x = 1 - cos theta = u0 (1 - cos theta_max) directly, and sin^2 theta = x (2 - x). Below the
threshold the same expressions are used (they are accurate at every angle; the constant only
documents where pbrt's approximation would have started), so pdf_li matches sample_li to
rounding for any sphere size, down to sin^2 theta_max ~ 1e-30.

Inside the sphere (|p - c| <= r): the light is one-sided ("no light is emitted inside the
sphere"), so nothing reaches p: sample_li fails (pdf 0, L 0), pdf_li is 0 and le() of an inner
hit is 0. (pbrt area-samples here because its spheres can be two-sided; for UsdLux the
sample would always carry L = 0.)

``treatAsPoint``: a delta light at the centre. Convention for delta lights in illum: sample_li
returns pdf = 1 and L already equal to the *incident* radiance-times-solid-angle term, i.e. the
irradiance-style value I / d^2; pdf_li is 0 for every wi; ``delta[i]`` is True so the integrator
skips MIS and BSDF-sampled hits (intersect() is inf, the light has no proxy triangles). The
intensity is that of the sphere it replaces: a sphere of radius r and radiance L has the same
intensity I = L pi r^2 in every direction (projected area pi r^2), so
L_eff = L pi r^2 / d^2 and phi = 4 pi I (equal to the sphere's pi * 4 pi r^2 * L). A point of
radius 0 with normalize gets the r -> 0 limit, I = intensity 2^exposure color / 4, the same as
any normalized radius (``point_intensity``); without normalize it emits nothing.

Non-uniform scale: the sphere used for sampling, intersection and proxies has the largest
world scale factor times the radius (a bounding sphere of the ellipsoid); the normalize area
is still the ellipsoid's (Knud-Thomsen approximation, as hdEmbree). A warning is recorded.

Implementation: sample_li, pdf_li and intersect are fused numba kernels
(``renderer.kernels.lights``), one pass per row with the formulas above.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.kernels import lights as kern
from renderer.lights._common import (
    SHAPE_RTOL,
    as_points,
    dot,
    invalid_sample,
    linear_part,
    translation,
)
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.radiometry import emitted_radiance

# hdEmbree's exponent (Knud Thomsen's best-fit value is 1.6075; 1.6 keeps us comparable with
# hdEmbree renders, max relative error ~1.2 %).
KNUD_THOMSEN_P = 1.6


def sphere_scales(desc: LightDesc) -> np.ndarray:
    """(3,) world semi-axes of the (possibly ellipsoidal) sphere, descending."""
    return float(desc.radius) * np.linalg.svd(linear_part(desc.light_to_world), compute_uv=False)


def ellipsoid_area(a: float, b: float, c: float) -> float:
    """Surface area of an ellipsoid: exact for a sphere, Knud-Thomsen with p = 1.6 otherwise."""
    if a == b == c:
        return 4.0 * math.pi * a * a
    p = KNUD_THOMSEN_P
    return 4.0 * math.pi * (((a * b) ** p + (a * c) ** p + (b * c) ** p) / 3.0) ** (1.0 / p)


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit-circumradius icosahedron: vertices (12, 3), faces (20, 3) counter-clockwise outward."""
    g = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array(
        [[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0],
         [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
         [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
         [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
         [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
         [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    return v, f


_ICO_V, _ICO_F = _icosahedron()
# Distance from the centre to the face planes of the unit-circumradius icosahedron.
_ICO_INRADIUS = float(
    np.min(np.abs(np.einsum("ij,ij->i", np.cross(_ICO_V[_ICO_F[:, 1]] - _ICO_V[_ICO_F[:, 0]],
                                                   _ICO_V[_ICO_F[:, 2]] - _ICO_V[_ICO_F[:, 0]]),
                            _ICO_V[_ICO_F[:, 0]]))
           / np.linalg.norm(np.cross(_ICO_V[_ICO_F[:, 1]] - _ICO_V[_ICO_F[:, 0]],
                                     _ICO_V[_ICO_F[:, 2]] - _ICO_V[_ICO_F[:, 0]]), axis=1))
)


class SphereLight:
    """All sphere lights (and treatAsPoint point lights) as structure-of-arrays.

    center: (count, 3); radius: (count,) world radius used for sampling (largest scale);
    L: (count, 3) emitted radiance; delta: (count,) bool (treatAsPoint).
    """

    name = "sphere"
    infinite = False

    def __init__(self, paths, center, radius, L, delta, warnings=None):
        self.paths = list(paths)
        self.count = len(self.paths)
        # C-contiguous float64 / bool: the kernels index these tables directly.
        self.center = as_points(center)
        self.radius = np.ascontiguousarray(radius, dtype=np.float64)
        self.L = as_points(L)
        self.delta = np.ascontiguousarray(delta, dtype=bool)
        self.warnings: list[str] = list(warnings or [])

    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """World-space surface area (exact for uniform scale, Knud-Thomsen for ellipsoids)."""
        a, b, c = (float(x) for x in sphere_scales(desc))
        return ellipsoid_area(a, b, c)

    @staticmethod
    def is_degenerate(desc: LightDesc) -> bool:
        """No surface to emit from. A treatAsPoint light needs only its position: UsdLux calls it
        "effectively a zero-radius sphere", and Maya-USD writes point lights as radius 0 with
        treatAsPoint (its intensity is ``point_intensity``: zero, hence degenerate, for a
        zero-radius point without normalize)."""
        if desc.treat_as_point:
            return not (desc.normalize or float(sphere_scales(desc)[0]) > 0.0)
        return not SphereLight.world_area(desc) > 0.0

    @staticmethod
    def point_intensity(desc: LightDesc) -> np.ndarray:
        """(3,) intensity I of a treatAsPoint light: the sphere's L pi r^2 (r its largest world
        semi-axis). With normalize, L = base / (4 pi r^2), so I = base / 4 at every radius and
        the zero-radius point is that limit (the sizeFactor of a zero-area sphere would divide by
        0); without normalize a zero-radius sphere emits nothing."""
        r0 = float(sphere_scales(desc)[0])
        if r0 > 0.0:
            return emitted_radiance(desc, SphereLight.world_area(desc)) * (math.pi * r0 * r0)
        if desc.normalize:
            return emitted_radiance(dataclasses.replace(desc, normalize=False), 1.0) / 4.0
        return np.zeros(3)

    @staticmethod
    def radiance(desc: LightDesc) -> np.ndarray:
        """(3,) emitted quantity: the radiance L, or a point light's intensity I."""
        if desc.treat_as_point:
            return SphereLight.point_intensity(desc)
        return emitted_radiance(desc, SphereLight.world_area(desc))

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=None, scene_radius: float = 1.0) -> "SphereLight":
        k = len(descs)
        center = np.zeros((k, 3))
        radius = np.zeros(k)
        L = np.zeros((k, 3))
        delta = np.zeros(k, dtype=bool)
        warns = []
        for i, d in enumerate(descs):
            s = sphere_scales(d)
            center[i] = translation(d.light_to_world)
            radius[i] = s[0]
            L[i] = emitted_radiance(d, cls.world_area(d))
            delta[i] = bool(d.treat_as_point)
            if delta[i] and not s[0] > 0.0:
                # The kernels give a point light L pi r^2 / d^2: store its intensity with the
                # radius for which pi r^2 = 1 (a point has no extent; only that product is used).
                radius[i] = 1.0 / math.sqrt(math.pi)
                L[i] = cls.point_intensity(d)
            if s[0] - s[2] > SHAPE_RTOL * s[0] and not d.treat_as_point:
                warns.append(
                    f"{d.path}: SphereLight with non-uniform scale: sampled and intersected as a "
                    f"sphere of radius {s[0]:.6g} (the largest scaled axis); normalize uses the "
                    f"ellipsoid's area"
                )
        return cls([d.path for d in descs], center, radius, L, delta, warns)

    # ----------------------------------------------------------------------------------
    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Cone sampling from outside; fails inside. Point lights: pdf 1, L = L pi r^2 / d^2."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n_rows = idx.size
        if n_rows == 0:
            return invalid_sample(0)
        L = np.empty((n_rows, 3))
        wi = np.empty((n_rows, 3))
        pdf = np.empty(n_rows)
        dist = np.empty(n_rows)
        p_l = np.empty((n_rows, 3))
        kern.sphere_sample_kernel(
            idx, as_points(ctx.p), as_points(u, 2), self.center, self.radius, self.L, self.delta,
            L, wi, pdf, dist, p_l,
        )
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_l)

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """1 / (2 pi (1 - cos theta_max)) inside the cone, 0 outside, inside the sphere, or delta."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0)
        pdf = np.empty(idx.size)
        kern.sphere_pdf_kernel(idx, as_points(ctx.p), as_points(wi), self.center, self.radius, self.delta, pdf)
        return pdf

    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First hit distance t > 0 (n,) with the sphere (inner hits included), inf where none;
        inf for point lights."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0)
        t = np.empty(idx.size)
        kern.sphere_hit_kernel(idx, as_points(o), as_points(d), self.center, self.radius, self.delta, t)
        return t

    def le(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """L toward -wi where wi arrives on the outside of the sphere; 0 inside and for points."""
        idx = np.asarray(idx, dtype=np.int64)
        n_out = p_light - self.center[idx]
        front = (-dot(wi, n_out) > 0.0) & ~self.delta[idx]
        return np.where(front[:, None], self.L[idx], 0.0)

    def phi(self) -> np.ndarray:
        """(count,) luminance power: pi * 4 pi r^2 * lum(L) (the same value for point lights)."""
        return np.pi * 4.0 * np.pi * self.radius**2 * luminance(self.L)

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """A circumscribed icosahedron (20 triangles) per non-point sphere."""
        keep = np.nonzero(~self.delta & (self.radius > 0.0))[0]
        scale = self.radius[keep] / _ICO_INRADIUS * (1.0 + 1e-5)
        tri_local = _ICO_V[_ICO_F]  # (20, 3, 3)
        tris = self.center[keep, None, None, :] + scale[:, None, None, None] * tri_local[None]
        owner = np.repeat(keep.astype(np.int64), _ICO_F.shape[0])
        return tris.reshape(-1, 3, 3), owner

