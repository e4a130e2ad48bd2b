"""UsdLuxCylinderLight: the side of a cylinder emitting outward (no end caps), or a line light.

Geometry (UsdLux): centred at the origin, major axis along local X, ``length`` along X and
``radius`` in the local YZ plane; light leaves the side outward only ("does not emit light from
the flat end-caps"; like the sphere it is one-sided, so nothing reaches a point inside the tube).
Under the world transform M (linear part M3, centre c) the side is

    x(s, phi) = c + M3 (s, r cos phi, r sin phi),   s in [-l, l] (l = length / 2),

an elliptic (possibly oblique) cylinder for a non-uniform scale or shear. Everything below is
exact for any invertible affine M: sampling and intersection run in the local frame
(o_l = M^-1 (o - c), d_l = M3^-1 d keep the ray parameter t), and densities are converted with the
exact world area element J(phi) = |a x (-sin phi b1 + cos phi b2)|, a = M3 e_x,
b1 = r M3 e_y, b2 = r M3 e_z. The outward world normal is normalize(M3^-T (0, cos phi, sin phi))
(an affine map keeps "outside" outside, so front-facing is decided in either frame).

**normalize** divides by the world side area. For a uniform scale that is 2 pi r L; in general
it is |a| L times the perimeter of the cross-section perpendicular to the axis, an ellipse whose
semi-axes come from the SVD of [P b1, P b2] (P: projection orthogonal to a). That perimeter uses
Ramanujan's first approximation pi (3 (a + b) - sqrt((3 a + b)(a + 3 b))), as hdEmbree does
(exact for circles, relative error below 4e-4 for any ellipse; the sampling densities use the
exact J, only the normalising constant is approximate).

**Sampling** (from a point p outside the tube; p inside gets nothing: pdf 0, L 0). Only the part
of the side that faces p can reach it, and for a cylinder that part is a band of constant phi
range: in the local cross-section p sits at distance rho from the axis and sees the arc
|phi - phi_p| <= arccos(r / rho), whatever s is. So samples never land on the hidden half
(uniform area sampling would waste at least half of them, and more the closer p is):

* phi: uniform in the *angle alpha the arc subtends at p* in the cross-section plane,
  alpha in [-asin(r / rho), asin(r / rho)] (the 2-D analogue of sphere cone sampling), mapped to
  the near intersection of that 2-D ray with the circle. Its density is
  pdf(phi) = r (rho cos psi - r) / (2 alpha_max h^2), psi = phi - phi_p, h the 2-D distance from
  p to the sampled line of the side;
* s: equiangular along that line (Kulla & Fajardo's line sampling): s - s_p = h tan theta,
  theta uniform between the angles of the two ends, pdf(s) = h / ((theta_b - theta_a) d^2).

For a circular cylinder the estimator L cos_p cos_l / (d^2 pdf_A) then reduces to
L cos_p 2 alpha_max (theta_b - theta_a) cos(theta): all the 1/d^2 and cos_l variation cancels
and only the receiver's cosine and a factor in [cos theta_max, 1] remain (as good as solid-angle
sampling for a long thin tube, which uniform area sampling is not: its weight varies like
(d_far / d_near)^3). pdf_A = pdf(s) pdf(phi) / J(phi), pdf_w = pdf_A d^2 / cos_l.

pdf_li(wi) intersects the side's *front* (first) crossing and evaluates the same densities;
rays that only meet the inside through an open end get 0 (their L is 0 anyway).

**treatAsLine** (a hint in UsdLux, as treatAsPoint for spheres): the tube collapses to the
segment on its axis, a delta light in the radial direction. Its intensity matches the cylinder
it replaces: a Lambertian tube of radiance L has intensity per unit length
dI/ds = L * (projected width) * sin(theta) = L (P / pi) sin(theta), where P is the
cross-section perimeter (P / pi is the mean projected width; 2 r for a circle) and theta the
angle between the emission direction and the axis. With ``normalize`` this is
intensity / (pi * world length) for any radius (so radius 0 is allowed). Convention for delta
lights in illum (see sphere.py): sample_li returns pdf 1 and L equal to the irradiance-style
term, here an equiangular sample s of the segment: L = (dI/ds)(theta) / d^2 / pdf(s)
= I_lin (theta_b - theta_a) / d; pdf_li is 0, intersect() is inf, there are no proxies.

phi() is pi * area * lum(L) (one-sided Lambertian side), and pi^2 * length * lum(I_lin) for a
line (the same number for the cylinder a line replaces). There is no exact unshadowed integral
F: the estimators fall back to MIS (irradiance.py).

Implementation: sample_li and pdf_li are numba kernels (``renderer.kernels.cylinder``); the
numpy helpers below (_frame, _param_pdf, _to_solid_angle, _jacobian, _world_normal) state the
same formulas; le() and the tests use them (tests/lights/test_cylinder.py checks the kernels
against them).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.kernels import cylinder as kern
from renderer.lights._common import (
    as_points,
    dot,
    invalid_sample,
    linear_part,
    translation,
)
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.radiometry import emitted_radiance

# Sides of the prism (and end-cap fans) that bound each tube for the proxy BVH.
PROXY_SIDES = 8
# Relative padding of the proxy prism (float32 rounding in the ray tracer stays conservative).
PROXY_PAD = 1e-5


def ellipse_perimeter(a: float, b: float) -> float:
    """Ramanujan's first approximation of the perimeter of an ellipse of semi-axes a, b."""
    a, b = abs(float(a)), abs(float(b))
    return math.pi * (3.0 * (a + b) - math.sqrt((3.0 * a + b) * (a + 3.0 * b)))


def cylinder_vectors(desc: LightDesc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World vectors (a, b1, b2) (3,) each: a = M3 e_x (per unit of local length), b1 = r M3 e_y,
    b2 = r M3 e_z (the cross-section's conjugate semi-axes)."""
    m3 = linear_part(desc.light_to_world)
    r = float(desc.radius)
    return m3[:, 0].copy(), r * m3[:, 1], r * m3[:, 2]


def cross_section_semi_axes(a: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> tuple[float, float]:
    """Semi-axes of the cross-section perpendicular to the axis a (SVD of [P b1, P b2])."""
    na = float(np.linalg.norm(a))
    if na <= 0.0:
        return 0.0, 0.0
    ah = a / na
    pb = np.stack([b1 - (b1 @ ah) * ah, b2 - (b2 @ ah) * ah], axis=1)
    s = np.linalg.svd(pb, compute_uv=False)
    return float(s[0]), float(s[1])


def _perimeter_and_length(desc: LightDesc) -> tuple[float, float]:
    """(cross-section perimeter, world length of the axis) of the tube."""
    a, b1, b2 = cylinder_vectors(desc)
    s1, s2 = cross_section_semi_axes(a, b1, b2)
    return ellipse_perimeter(s1, s2), float(desc.length) * float(np.linalg.norm(a))


def _einsum_rows(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """m (n, 3, 3) @ v (n, 3) -> (n, 3)."""
    return np.einsum("nij,nj->ni", m, v)


class CylinderLight:
    """All cylinder lights (and treatAsLine line lights) as structure-of-arrays.

    center: (count, 3); m3, m3_inv, normal_m: (count, 3, 3) linear part, its inverse and
    inverse transpose; a, b1, b2: (count, 3) world axis / cross-section vectors (see the module
    docstring); radius, half: (count,) local radius and half-length; L: (count, 3) radiance of
    the side (line lights: I_lin, intensity per unit length per sin theta); area: (count,) world
    side area (Ramanujan perimeter); delta: (count,) bool (treatAsLine).
    """

    name = "cylinder"
    infinite = False

    def __init__(self, paths, center, m3, radius, half, L, area, delta, length_w, warnings=None):
        self.paths = list(paths)
        self.count = len(self.paths)
        self.center = as_points(center)
        self.m3 = np.ascontiguousarray(m3, dtype=np.float64).reshape(-1, 3, 3)
        self.radius = np.ascontiguousarray(radius, dtype=np.float64)
        self.half = np.ascontiguousarray(half, dtype=np.float64)
        self.L = as_points(L)
        self.area = np.ascontiguousarray(area, dtype=np.float64)
        self.delta = np.ascontiguousarray(delta, dtype=bool)
        self.length_w = np.ascontiguousarray(length_w, dtype=np.float64)
        self.warnings: list[str] = list(warnings or [])
        # Inverses exist for every kept light (is_degenerate drops singular tubes); line lights
        # with a flat cross-section keep an identity stand-in (only their axis is used).
        det = np.linalg.det(self.m3) if self.count else np.zeros(0)
        safe = np.where((np.abs(det) > 0.0)[:, None, None], self.m3, np.eye(3))
        self.m3_inv = np.linalg.inv(safe) if self.count else np.zeros((0, 3, 3))
        self.m3_inv = np.ascontiguousarray(self.m3_inv)
        self.normal_m = np.ascontiguousarray(np.transpose(self.m3_inv, (0, 2, 1)))
        self.a = np.ascontiguousarray(self.m3[:, :, 0])
        self.b1 = np.ascontiguousarray(self.m3[:, :, 1] * self.radius[:, None])
        self.b2 = np.ascontiguousarray(self.m3[:, :, 2] * self.radius[:, None])
        self.packed = self.pack()

    def pack(self) -> np.ndarray:
        """(count, kern.NCY) float64: each light's row for the compiled row functions
        (renderer/kernels/cylinder.py, columns CY_*), which both integrators call."""
        k = self.count
        out = np.zeros((k, kern.NCY))
        out[:, kern.CY_C:kern.CY_C + 3] = self.center
        out[:, kern.CY_M3:kern.CY_M3 + 9] = self.m3.reshape(k, 9)
        out[:, kern.CY_MI:kern.CY_MI + 9] = self.m3_inv.reshape(k, 9)
        out[:, kern.CY_NM:kern.CY_NM + 9] = self.normal_m.reshape(k, 9)
        out[:, kern.CY_A:kern.CY_A + 3] = self.a
        out[:, kern.CY_B1:kern.CY_B1 + 3] = self.b1
        out[:, kern.CY_B2:kern.CY_B2 + 3] = self.b2
        out[:, kern.CY_R] = self.radius
        out[:, kern.CY_H] = self.half
        out[:, kern.CY_L:kern.CY_L + 3] = self.L
        out[:, kern.CY_DELTA] = self.delta
        return out

    # ----------------------------------------------------------------------------------
    # Build
    # ----------------------------------------------------------------------------------
    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """World-space side area: world length times the cross-section's (Ramanujan) perimeter."""
        perimeter, length = _perimeter_and_length(desc)
        return perimeter * length

    @staticmethod
    def is_degenerate(desc: LightDesc) -> bool:
        """No extent to emit from: zero world length, or (not a line) a singular transform or
        zero side area. A line light only needs its axis."""
        m3 = linear_part(desc.light_to_world)
        length = float(desc.length) * float(np.linalg.norm(m3[:, 0]))
        if not length > 0.0:
            return True
        if desc.treat_as_line:
            return False
        return not (abs(float(np.linalg.det(m3))) > 0.0 and CylinderLight.world_area(desc) > 0.0)

    @staticmethod
    def radiance(desc: LightDesc) -> np.ndarray:
        """(3,) emitted quantity: the side's radiance L, or for a line light I_lin (see the
        module docstring; finite with normalize even at radius 0)."""
        perimeter, length = _perimeter_and_length(desc)
        if not desc.treat_as_line:
            return emitted_radiance(desc, perimeter * length)
        if desc.normalize:
            # L = base / (P * length) and I_lin = L * P / pi: the perimeter cancels.
            base = _base_radiance(desc)
            return base / (math.pi * length) if length > 0.0 else np.zeros(3)
        return emitted_radiance(desc, perimeter * length) * perimeter / math.pi

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=None, scene_radius: float = 1.0) -> "CylinderLight":
        k = len(descs)
        center = np.zeros((k, 3))
        m3 = np.tile(np.eye(3), (k, 1, 1))
        radius = np.zeros(k)
        half = np.zeros(k)
        L = np.zeros((k, 3))
        area = np.zeros(k)
        delta = np.zeros(k, dtype=bool)
        length_w = np.zeros(k)
        warns = []
        for i, d in enumerate(descs):
            center[i] = translation(d.light_to_world)
            m3[i] = linear_part(d.light_to_world)
            radius[i] = float(d.radius)
            half[i] = 0.5 * float(d.length)
            perimeter, length_w[i] = _perimeter_and_length(d)
            area[i] = perimeter * length_w[i]
            delta[i] = bool(d.treat_as_line)
            L[i] = cls.radiance(d)
        return cls([d.path for d in descs], center, m3, radius, half, L, area, delta, length_w, warns)

    # ----------------------------------------------------------------------------------
    # Local-frame helpers
    # ----------------------------------------------------------------------------------
    def _jacobian(self, idx: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """World area per (s, phi) parameter area, |a x (-sin phi b1 + cos phi b2)| (n,)."""
        t = -np.sin(phi)[:, None] * self.b1[idx] + np.cos(phi)[:, None] * self.b2[idx]
        return np.linalg.norm(np.cross(self.a[idx], t), axis=1)

    def _world_normal(self, idx: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Outward unit world normal (n, 3) at angle phi."""
        nl = np.stack([np.zeros(phi.size), np.cos(phi), np.sin(phi)], axis=1)
        nw = _einsum_rows(self.normal_m[idx], nl)
        ln = np.linalg.norm(nw, axis=1)
        return nw / np.where(ln > 0.0, ln, 1.0)[:, None]

    def _to_world(self, idx: np.ndarray, x_l: np.ndarray) -> np.ndarray:
        return self.center[idx] + _einsum_rows(self.m3[idx], x_l)

    def _frame(self, idx: np.ndarray, p: np.ndarray):
        """Local view of p: (s_p, rho, phi_p, outside) (n,) each."""
        pl = _einsum_rows(self.m3_inv[idx], p - self.center[idx])
        rho = np.hypot(pl[:, 1], pl[:, 2])
        outside = rho > self.radius[idx] * (1.0 + 1e-12)
        return pl[:, 0], rho, np.arctan2(pl[:, 2], pl[:, 1]), outside

    @staticmethod
    def _lateral(rho: np.ndarray, r: np.ndarray, psi: np.ndarray) -> np.ndarray:
        """2-D distance h (n,) from p to the side line at psi: h^2 = (rho - r)^2 + 4 rho r sin^2(psi/2)."""
        sh = np.sin(0.5 * psi)
        return np.sqrt((rho - r) ** 2 + 4.0 * rho * r * sh * sh)

    def _param_pdf(self, idx, s, psi, s_p, rho):
        """Density (n,) of (s, phi) under the sampler (see the module docstring); 0 outside."""
        r = self.radius[idx]
        hl = self.half[idx]
        ratio = np.clip(np.divide(r, rho, out=np.ones_like(rho), where=rho > 0.0), 0.0, 1.0)
        alpha_max = np.arcsin(ratio)
        h = self._lateral(rho, r, psi)
        cosn = rho * np.cos(psi) - r  # n . (p - x) in the cross-section
        ok = (alpha_max > 0.0) & (h > 0.0) & (cosn > 0.0)
        hs = np.where(ok, h, 1.0)
        pdf_phi = np.where(ok, r * cosn / (2.0 * np.where(ok, alpha_max, 1.0) * hs * hs), 0.0)
        th_a = np.arctan2(-hl - s_p, hs)
        th_b = np.arctan2(hl - s_p, hs)
        span = th_b - th_a
        ok &= span > 0.0
        ds = s - s_p
        pdf_s = np.where(ok, hs / (np.where(ok, span, 1.0) * (hs * hs + ds * ds)), 0.0)
        return pdf_phi * pdf_s

    def _to_solid_angle(self, idx, pdf_param, phi, wi, dist):
        """pdf_w = pdf(s, phi) / J(phi) * d^2 / cos_l (0 where the side faces away)."""
        cos_l = -dot(wi, self._world_normal(idx, phi))
        J = self._jacobian(idx, phi)
        ok = (cos_l > 0.0) & (J > 0.0) & (pdf_param > 0.0) & np.isfinite(dist)
        num = pdf_param * dist * dist
        den = np.where(ok, J * cos_l, 1.0)
        out = np.where(ok, num / den, 0.0)
        return np.where(np.isfinite(out), out, 0.0)

    # ----------------------------------------------------------------------------------
    # LightKind protocol
    # ----------------------------------------------------------------------------------
    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Sample light idx (n,) from ctx.p with u (n, 2): the facing band of the side (tubes),
        an equiangular point of the segment (lines). Fails (pdf 0) from inside a tube."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n = idx.size
        if n == 0:
            return invalid_sample(0)
        L = np.empty((n, 3))
        wi = np.empty((n, 3))
        pdf = np.empty(n)
        dist = np.empty(n)
        p_l = np.empty((n, 3))
        kern.cylinder_sample_kernel(idx, as_points(ctx.p), as_points(u, 2), self.packed, L, wi, pdf, dist, p_l)
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_l)

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (n,) of sample_li producing wi: evaluated at the side's front crossing;
        0 for misses, from inside, and for line lights."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        out = np.empty(idx.size)
        kern.cylinder_pdf_kernel(idx, as_points(ctx.p), as_points(wi), self.packed, out)
        return out

    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First hit distance t > 0 (n,) with the side (inner hits included), inf where none;
        inf for line lights."""
        idx = np.asarray(idx, dtype=np.int64)
        n = idx.size
        if n == 0:
            return np.zeros(0)
        ol = _einsum_rows(self.m3_inv[idx], o - self.center[idx])
        dl = _einsum_rows(self.m3_inv[idx], d)
        r = self.radius[idx]
        a2 = dl[:, 1] ** 2 + dl[:, 2] ** 2
        b2 = ol[:, 1] * dl[:, 1] + ol[:, 2] * dl[:, 2]
        rho = np.hypot(ol[:, 1], ol[:, 2])
        c2 = (rho - r) * (rho + r)
        disc = b2 * b2 - a2 * c2
        ok = (a2 > 0.0) & (disc >= 0.0) & ~self.delta[idx]
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -(b2 + np.where(b2 >= 0.0, sq, -sq))
        qs = np.where(q != 0.0, q, 1.0)
        r1 = np.where(ok & (q != 0.0), q / np.where(ok, a2, 1.0), np.inf)
        r2 = np.where(ok & (q != 0.0), c2 / qs, np.inf)
        lo = np.minimum(r1, r2)
        hi = np.maximum(r1, r2)
        t = np.full(n, np.inf)
        for root in (hi, lo):  # lo last, so it wins where both qualify
            good = np.isfinite(root) & (root > 0.0)
            s = ol[:, 0] + np.where(good, root, 0.0) * dl[:, 0]
            good &= np.abs(s) <= self.half[idx]
            t = np.where(good, root, t)
        return t

    def le(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """L toward -wi where wi arrives on the outside of the side; 0 inside and for lines."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros((0, 3))
        xl = _einsum_rows(self.m3_inv[idx], p_light - self.center[idx])
        phi = np.arctan2(xl[:, 2], xl[:, 1])
        front = (-dot(wi, self._world_normal(idx, phi)) > 0.0) & ~self.delta[idx]
        return np.where(front[:, None], self.L[idx], 0.0)

    def phi(self) -> np.ndarray:
        """(count,) luminance power: pi * area * lum(L); lines pi^2 * length * lum(I_lin)."""
        lum = luminance(self.L)
        return np.where(self.delta, np.pi**2 * self.length_w * lum, np.pi * self.area * lum)

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """A closed circumscribed prism per tube (PROXY_SIDES sides, two capping fans), so every
        ray reaching the side from outside -- through an open end too -- crosses a proxy first."""
        keep = np.nonzero(~self.delta)[0]
        k = PROXY_SIDES
        ang = 2.0 * np.pi * (np.arange(k) + 0.5) / k
        rad = (1.0 + PROXY_PAD) / np.cos(np.pi / k)
        ring = np.stack([np.zeros(k), rad * np.cos(ang), rad * np.sin(ang)], axis=1)  # unit radius
        r = self.radius[keep]
        hl = self.half[keep] * (1.0 + PROXY_PAD)
        # Local vertices (m, k, 3) of both rings, then the world map.
        base = ring[None, :, :] * np.stack([np.ones_like(r), r, r], axis=1)[:, None, :]
        lo_ring = base.copy()
        lo_ring[:, :, 0] = -hl[:, None]
        hi_ring = base.copy()
        hi_ring[:, :, 0] = hl[:, None]
        c_lo = np.stack([-hl, np.zeros_like(hl), np.zeros_like(hl)], axis=1)[:, None, :].repeat(k, axis=1)
        c_hi = np.stack([hl, np.zeros_like(hl), np.zeros_like(hl)], axis=1)[:, None, :].repeat(k, axis=1)
        lo_next = np.roll(lo_ring, -1, axis=1)
        hi_next = np.roll(hi_ring, -1, axis=1)
        tris = np.concatenate([
            np.stack([lo_ring, lo_next, hi_next], axis=2),
            np.stack([lo_ring, hi_next, hi_ring], axis=2),
            np.stack([c_lo, lo_next, lo_ring], axis=2),
            np.stack([c_hi, hi_ring, hi_next], axis=2),
        ], axis=1)  # (m, 4k, 3, 3) local
        world = self.center[keep][:, None, None, :] + np.einsum("mij,mtvj->mtvi", self.m3[keep], tris)
        owner = np.repeat(keep.astype(np.int64), 4 * k)
        return world.reshape(-1, 3, 3), owner


def _base_radiance(desc: LightDesc) -> np.ndarray:
    """intensity * 2^exposure * color * blackbody, without the normalize size factor."""
    import dataclasses

    return emitted_radiance(dataclasses.replace(desc, normalize=False), 1.0)
