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
L_eff = L pi r^2 / d^2 and phi = 4 pi I (equal to the sphere's pi * 4 pi r^2 * L).

Non-uniform scale: the sphere used for sampling, intersection and proxies has the largest
world scale factor times the radius (a bounding sphere of the ellipsoid); the normalize area
is still the ellipsoid's (Knud-Thomsen approximation, as hdEmbree). A warning is recorded.
"""

from __future__ import annotations

import math

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.geometry import coordinate_frame, cross
from renderer.lights._common import (
    SHAPE_RTOL,
    direction_and_distance,
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
        self.center = center
        self.radius = radius
        self.L = L
        self.delta = delta
        self.warnings: list[str] = list(warnings or [])

    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """World-space surface area (exact for uniform scale, Knud-Thomsen for ellipsoids)."""
        a, b, c = (float(x) for x in sphere_scales(desc))
        return ellipsoid_area(a, b, c)

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
            if s[0] - s[2] > SHAPE_RTOL * s[0] and not d.treat_as_point:
                warns.append(
                    f"{d.path}: SphereLight with non-uniform scale: sampled and intersected as a "
                    f"sphere of radius {s[0]:.6g} (the largest scaled axis); normalize uses the "
                    f"ellipsoid's area"
                )
        return cls([d.path for d in descs], center, radius, L, delta, warns)

    # ----------------------------------------------------------------------------------
    def _cone(self, idx: np.ndarray, p: np.ndarray):
        """Per row: (w_c unit toward centre, dc distance, sin2_max, one_minus_cos_max, outside)."""
        w_c, dc = direction_and_distance(p, self.center[idx])
        r = self.radius[idx]
        outside = dc * dc > r * r * (1.0 + 1e-12)
        sin2 = np.where(outside, (r * r) / np.where(outside, dc * dc, 1.0), 1.0)
        cos_max = np.sqrt(np.maximum(0.0, 1.0 - sin2))
        omc = sin2 / (1.0 + cos_max)  # 1 - cos theta_max without cancellation
        return w_c, dc, sin2, omc, outside & ~self.delta[idx] & (r > 0.0)

    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Cone sampling from outside; fails inside. Point lights: pdf 1, L = L pi r^2 / d^2."""
        idx = np.asarray(idx, dtype=np.int64)
        p = ctx.p
        n_rows = idx.size
        if n_rows == 0:
            return invalid_sample(0)
        w_c, dc, sin2_max, omc, ok = self._cone(idx, p)
        r = self.radius[idx]
        sin_max = np.sqrt(sin2_max)
        # theta of the sampled direction: x = 1 - cos theta uniform in [0, 1 - cos theta_max].
        x = u[:, 0] * omc
        cos_t = 1.0 - x
        sin2 = x * (2.0 - x)
        # Angle alpha at the centre between -w_c and the sphere point.
        ratio = np.divide(sin2, sin_max, out=np.zeros(n_rows), where=sin_max > 0.0)
        ratio2 = np.divide(sin2, sin2_max, out=np.zeros(n_rows), where=sin2_max > 0.0)
        cos_a = np.clip(ratio + cos_t * np.sqrt(np.maximum(0.0, 1.0 - ratio2)), -1.0, 1.0)
        sin_a = np.sqrt(np.maximum(0.0, 1.0 - cos_a * cos_a))
        phi = 2.0 * np.pi * u[:, 1]
        s, t = coordinate_frame(w_c)
        # Outward normal at the sampled point: -w_c tilted by alpha around it.
        n_s = (
            -cos_a[:, None] * w_c
            + (sin_a * np.cos(phi))[:, None] * s
            + (sin_a * np.sin(phi))[:, None] * t
        )
        p_l = self.center[idx] + r[:, None] * n_s
        wi, dist = direction_and_distance(p, p_l)
        pdf = np.divide(1.0, 2.0 * np.pi * omc, out=np.zeros(n_rows), where=ok & (omc > 0.0))
        ok &= (pdf > 0.0) & (dist > 0.0)
        L = np.where(ok[:, None], self.L[idx], 0.0)
        pdf = np.where(ok, pdf, 0.0)

        # Delta (treatAsPoint) rows.
        dl = self.delta[idx]
        if dl.any():
            good = dl & (dc > 0.0)
            inv_d2 = np.divide(1.0, dc * dc, out=np.zeros(n_rows), where=good)
            Lp = self.L[idx] * (np.pi * r * r * inv_d2)[:, None]
            L = np.where(dl[:, None], np.where(good[:, None], Lp, 0.0), L)
            wi = np.where(dl[:, None], w_c, wi)
            dist = np.where(dl, dc, dist)
            p_l = np.where(dl[:, None], self.center[idx], p_l)
            pdf = np.where(dl, np.where(good, 1.0, 0.0), pdf)
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_l)

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """1 / (2 pi (1 - cos theta_max)) inside the cone, 0 outside, inside the sphere, or delta."""
        idx = np.asarray(idx, dtype=np.int64)
        p = ctx.p
        if idx.size == 0:
            return np.zeros(0)
        w_c, dc, sin2_max, omc, ok = self._cone(idx, p)
        # sin^2 of the angle between wi and w_c, accurate for tiny cones (no 1 - cos).
        c = cross(wi, w_c)
        sin2 = dot(c, c)
        in_cone = (dot(wi, w_c) > 0.0) & (sin2 <= sin2_max * (1.0 + 1e-9))
        ok &= in_cone
        return np.divide(1.0, 2.0 * np.pi * omc, out=np.zeros(idx.size), where=ok & (omc > 0.0))

    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First hit distance t > 0 (n,) with the sphere (inner hits included), inf where none;
        inf for point lights."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0)
        oc = o - self.center[idx]
        r = self.radius[idx]
        b = dot(oc, d)
        # Discriminant from the perpendicular offset (better conditioned than b^2 - c).
        perp = oc - b[:, None] * d
        disc = r * r - dot(perp, perp)
        hit = (disc >= 0.0) & ~self.delta[idx] & (r > 0.0)
        sq = np.sqrt(np.maximum(disc, 0.0))
        cc = dot(oc, oc) - r * r
        q = -b - np.copysign(sq, b)
        t0 = np.divide(cc, q, out=np.full(idx.size, np.inf), where=q != 0.0)
        t1 = q
        tn = np.minimum(t0, t1)
        tf = np.maximum(t0, t1)
        t = np.where(tn > 0.0, tn, np.where(tf > 0.0, tf, np.inf))
        return np.where(hit, t, np.inf)

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

