"""A minimal real direct-lighting setup for estimator tests: one shading point on the z = 0
plane facing +z, a rect light above it, an optional occluder traced by embree, a Lambert BSDF.

The occluder is a half-plane at height h_occ covering x > 0: seen from the origin it hides
exactly the x > 0 half of a light centred over the origin (rays from the origin to points
with x > 0 cross it), so the shadowed integral is the projected solid angle of the other half
-- an analytic reference.
"""

from __future__ import annotations

import numpy as np

from renderer.accel import Accel
from renderer.bsdfs.lambert import LambertBSDF
from renderer.description import LightDesc
from renderer.estimators import REGISTRY, DirectQuery, DirectRandom
from renderer.geometry import coordinate_frame, offset_origin, to_local
from renderer.lights.analytic import projected_solid_angle_rect
from renderer.lights.base import ShadingContext
from renderer.lights.light_set import LightSet

RHO = 0.5
L_RECT = 3.0
HALF = 1.0     # the light spans [-HALF, HALF]^2
HEIGHT = 2.0   # light height


def rect_light_desc(height=HEIGHT, size=2 * HALF, intensity=L_RECT) -> LightDesc:
    # RectLight emits along local -Z; placed at z = height, facing down with no rotation.
    m = np.eye(4)
    m[2, 3] = height
    return LightDesc(path="/Light", kind="rect", light_to_world=m, intensity=intensity, width=size, height=size)


# "offset": the occluder's edge at x = X_EDGE (half the light's height) hides light points with
# x > 2 X_EDGE, so visibility correlates with the cosine (the visible part holds
# the light's centre): this is where alpha = v_bar's bias shows.
X_EDGE = 0.25


def occluder(kind: str, height: float = HEIGHT) -> Accel:
    """The occluder sits halfway between the shading point and the light."""
    big = 100.0
    H_OCC = 0.5 * height
    if kind == "offset":
        quad = np.array([[X_EDGE, -big, H_OCC], [big, -big, H_OCC], [big, big, H_OCC], [X_EDGE, big, H_OCC]], float)
    elif kind == "half":
        quad = np.array([[0, -big, H_OCC], [big, -big, H_OCC], [big, big, H_OCC], [0, big, H_OCC]], float)
    elif kind == "full":
        quad = np.array([[-big, -big, H_OCC], [big, -big, H_OCC], [big, big, H_OCC], [-big, big, H_OCC]], float)
    elif kind == "none":
        quad = np.array([[50, 50, -5], [51, 50, -5], [51, 51, -5], [50, 51, -5]], float)  # out of the way
    else:
        raise ValueError(kind)
    return Accel(np.array([[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]), threads=1)


class Setup:
    """n identical shading points at the origin with normal +z, wo straight up."""

    def __init__(self, occ: str = "half", n: int = 20000, height: float = HEIGHT):
        self.lights = LightSet.build([rect_light_desc(height=height)], np.zeros(3), 5.0)
        self.accel = occluder(occ, height)
        self.n = n
        p = np.zeros((n, 3))
        nz = np.tile([0.0, 0.0, 1.0], (n, 1))
        self.ctx = ShadingContext(p, nz, nz)
        self.s, self.t = coordinate_frame(nz)
        self.wo_l = to_local(nz, self.s, self.t, nz)
        self.bsdf = LambertBSDF(np.full((n, 3), RHO))
        self.eps = np.full(n, 1e-6)
        self.rays = 0

    def trace(self, p, ng, wi, dist, eps):
        o = offset_origin(p, ng, wi, eps)
        t_max = np.where(np.isfinite(dist), dist * (1 - 1e-6) - eps, np.inf)
        self.rays += p.shape[0]
        return ~self.accel.occluded(o, wi, t_max)

    def query(self) -> DirectQuery:
        light = np.zeros(self.n, dtype=np.int64)
        return DirectQuery(self.ctx, self.s, self.t, self.wo_l, self.bsdf, light, self.eps,
                           self.bsdf.diffuse_constant(self.wo_l))

    def estimate(self, token: str, N: int, alpha: str = "one", heuristic: str = "power", seed: int = 0):
        rng = np.random.default_rng(seed)
        res = REGISTRY[token].estimate(self.query(), self.lights, self.trace, N,
                                       DirectRandom.draw(rng, self.n, N), alpha, heuristic)
        return res.Ld


def reference(kind: str, height: float = HEIGHT) -> float:
    """Exact outgoing radiance (one channel) toward wo for the setups above."""
    p = np.zeros((1, 3))
    nz = np.array([[0.0, 0.0, 1.0]])
    down = np.array([0.0, 0.0, -1.0])
    if kind == "none":
        G = projected_solid_angle_rect(p, nz, [0, 0, height], [2 * HALF, 0, 0], [0, 2 * HALF, 0], down)[0]
    elif kind == "half":
        # The visible half: x in [-HALF, 0].
        G = projected_solid_angle_rect(p, nz, [-HALF / 2, 0, height], [HALF, 0, 0], [0, 2 * HALF, 0], down)[0]
    elif kind == "offset":
        x1 = min(HALF, 2.0 * X_EDGE)   # visible: x in [-HALF, x1]
        G = projected_solid_angle_rect(p, nz, [(x1 - HALF) / 2, 0, height], [x1 + HALF, 0, 0],
                                       [0, 2 * HALF, 0], down)[0]
    else:
        G = 0.0
    return RHO / np.pi * L_RECT * G


def unshadowed_F(height: float = HEIGHT) -> float:
    return reference("none", height)
