"""UsdLuxDistantLight: light from a cone of directions at infinity (or one direction).

The light shines along its local -Z, so the direction *toward* the light is the world image of
local +Z (transformed as a vector, normalised). ``angle`` is the angular **diameter** in
degrees; the half-angle is theta_max = clamp(radians(angle) / 2, 0, pi).

* angle > 0: uniform radiance L inside the cone; sample_li draws wi uniformly in the cone,
  pdf_w = 1 / (2 pi (1 - cos theta_max)), where 1 - cos theta_max is evaluated as
  2 sin^2(theta_max / 2) (no cancellation for the 0.53-degree sun). pdf_li tests cone
  membership with |wi - axis|^2 / 2 = 1 - cos, which is accurate for tiny cones too.
* angle = 0: a delta light (``delta[i]`` True): sample_li returns wi = axis, pdf = 1 and L equal
  to the irradiance at normal incidence (radiometry gives sizeFactor 1, so that is
  intensity * 2^exposure * color); pdf_li is 0 and le_escaped is 0.

Both are infinite lights: dist = inf and p_light = p + wi * (a distance beyond the scene).
phi() follows pbrt: the power through a disk of the scene's radius R facing the light,
pi R^2 * lum(E_perp), E_perp the irradiance at normal incidence (L pi sin^2 theta_max for
theta_max <= pi/2, L pi beyond; L itself for delta lights).
"""

from __future__ import annotations

import math

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.geometry import coordinate_frame
from renderer.lights._common import far_distance, invalid_sample, linear_part
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.radiometry import distant_half_angle, emitted_radiance


class DistantLight:
    """All distant lights as structure-of-arrays.

    axis: (count, 3) unit direction toward the light; theta_max: (count,) half-angle (rad);
    omc: (count,) 1 - cos theta_max; L: (count, 3) radiance (irradiance for delta lights);
    delta: (count,) bool (angle == 0).
    """

    name = "distant"
    infinite = True

    def __init__(self, paths, axis, theta_max, L, scene_center, scene_radius):
        self.paths = list(paths)
        self.count = len(self.paths)
        self.axis = axis
        self.theta_max = theta_max
        self.omc = 2.0 * np.sin(0.5 * theta_max) ** 2
        self.L = L
        self.delta = self.omc <= 0.0
        self.scene_center = np.asarray(scene_center, dtype=np.float64).reshape(3)
        self.scene_radius = float(scene_radius)
        self.warnings: list[str] = []

    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """Distant lights have no area (normalize uses the angular sizeFactor); returns 1."""
        return 1.0

    @staticmethod
    def world_axis(desc: LightDesc) -> np.ndarray:
        """(3,) unit world direction toward the light (zeros for a degenerate transform)."""
        v = linear_part(desc.light_to_world) @ np.array([0.0, 0.0, 1.0])
        n = float(np.linalg.norm(v))
        return v / n if n > 0.0 else np.zeros(3)

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=(0.0, 0.0, 0.0), scene_radius: float = 1.0) -> "DistantLight":
        k = len(descs)
        axis = np.zeros((k, 3))
        theta = np.zeros(k)
        L = np.zeros((k, 3))
        for i, d in enumerate(descs):
            axis[i] = cls.world_axis(d)
            theta[i] = distant_half_angle(d.angle)
            L[i] = emitted_radiance(d, 1.0)
        return cls([d.path for d in descs], axis, theta, L, scene_center, scene_radius)

    # ----------------------------------------------------------------------------------
    def _in_cone(self, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
        diff = w - self.axis[idx]
        one_minus_cos = 0.5 * np.einsum("ij,ij->i", diff, diff)
        return (one_minus_cos <= self.omc[idx] * (1.0 + 1e-9)) & ~self.delta[idx]

    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Uniform direction in the cone (delta lights: the axis, pdf 1). u (n, 2)."""
        idx = np.asarray(idx, dtype=np.int64)
        n_rows = idx.size
        if n_rows == 0:
            return invalid_sample(0)
        omc = self.omc[idx]
        x = u[:, 0] * omc  # 1 - cos theta, uniform in [0, omc]
        cos_t = 1.0 - x
        sin_t = np.sqrt(np.maximum(0.0, x * (2.0 - x)))
        phi = 2.0 * np.pi * u[:, 1]
        a = self.axis[idx]
        s, t = coordinate_frame(a)
        wi = cos_t[:, None] * a + (sin_t * np.cos(phi))[:, None] * s + (sin_t * np.sin(phi))[:, None] * t
        dl = self.delta[idx]
        pdf = np.divide(1.0, 2.0 * np.pi * omc, out=np.ones(n_rows), where=~dl)
        far = far_distance(ctx.p, self.scene_center, self.scene_radius)
        return LightLiSample(
            L=self.L[idx].copy(),
            wi=wi,
            pdf=pdf,
            dist=np.full(n_rows, np.inf),
            p_light=ctx.p + wi * far[:, None],
        )

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """1 / (2 pi (1 - cos theta_max)) inside the cone, else 0 (always 0 for delta lights)."""
        idx = np.asarray(idx, dtype=np.int64)
        inside = self._in_cone(idx, wi)
        return np.divide(1.0, 2.0 * np.pi * self.omc[idx], out=np.zeros(idx.size), where=inside)

    def le_escaped(self, idx: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Radiance (n, 3) arriving along -d for escaped rays of direction d (inside the cone)."""
        idx = np.asarray(idx, dtype=np.int64)
        return np.where(self._in_cone(idx, d)[:, None], self.L[idx], 0.0)

    def irradiance_normal(self) -> np.ndarray:
        """(count, 3) irradiance on a surface facing the light (no occlusion)."""
        s2 = np.sin(np.minimum(self.theta_max, math.pi / 2.0)) ** 2
        factor = np.where(self.delta, 1.0, np.pi * s2)
        return self.L * factor[:, None]

    def phi(self) -> np.ndarray:
        """(count,) pi R^2 * lum(E_perp), R the scene radius (pbrt's convention)."""
        return np.pi * self.scene_radius**2 * luminance(self.irradiance_normal())
