"""Direct-lighting estimators run straight on random light configurations.

Like ``tests/estimators/helpers.py`` but for any LightCase: n identical shading points (the
case's p and normal), wo along a chosen direction, a Lambert or UsdPreviewSurface BSDF, and a
``trace`` callback modelling a half-space occluder through p (an infinite wall: a shadow ray
toward wi is blocked unless clip·wi > 0), so the shadowed integral has a quadrature reference
(``quadrature.rect_G(..., clips=[clip])``). The callback counts the rays it is asked to trace.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from renderer.bsdfs.lambert import LambertBSDF
from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.estimators import REGISTRY, DirectQuery, DirectRandom
from renderer.geometry import coordinate_frame, to_local
from renderer.lights.base import ShadingContext

from . import quadrature
from .cases import LightCase, unit

# (token, alpha, heuristic, minimum N) of the estimators that are unbiased.
UNBIASED = (
    ("lightSampling", "one", "power", 1),
    ("bsdfSampling", "one", "power", 1),
    ("mis", "one", "power", 1),
    ("mis", "one", "balance", 1),
    ("controlVariate", "one", "power", 1),
    ("controlVariate", "averageVisibilityUnbiased", "power", 2),
)
# Every estimator and alpha (finiteness and sign checks).
ALL = UNBIASED + (
    ("controlVariate", "averageVisibility", "power", 2),
    ("ratio", "one", "power", 1),
)
# Estimators whose every sample is >= 0 (a sum of f L v / p terms with f, L, v, p >= 0 and
# MIS weights >= 0). The control variate's correction f (v - alpha) / p and, on
# UsdPreviewSurface, the residual f - g that the control variate and the ratio estimator send
# to MIS can be negative (see test_negative_samples.py).
NON_NEGATIVE = ("lightSampling", "bsdfSampling", "mis")


@dataclass
class Rig:
    """n shading points at one place, a BSDF, and a half-space occluder (clip None: none)."""

    lights: object
    p: np.ndarray
    nrm: np.ndarray
    wo: np.ndarray
    bsdf: object
    clip: np.ndarray | None
    n: int
    rays: int = 0
    eps: float = 1e-9          # ray-origin offset handed to the estimators (scene units)

    def trace(self, p, ng, wi, dist, eps):
        self.rays += p.shape[0]
        assert np.all(np.isfinite(wi)) and np.all(dist > 0.0), "shadow ray with a bad direction or length"
        if self.clip is None:
            return np.ones(p.shape[0], dtype=bool)
        return wi @ self.clip > 0.0

    def query(self) -> DirectQuery:
        n = self.n
        P = np.tile(self.p, (n, 1))
        N = np.tile(self.nrm, (n, 1))
        ctx = ShadingContext(P, N, N.copy())
        s, t = coordinate_frame(N)
        wo_l = to_local(np.tile(self.wo, (n, 1)), s, t, N)
        return DirectQuery(ctx, s, t, wo_l, self.bsdf, np.zeros(n, dtype=np.int64), np.full(n, self.eps),
                           self.bsdf.diffuse_constant(wo_l))

    def estimate(self, token: str, N: int, alpha: str, heuristic: str, seed: int):
        """(Ld (n, 3), shadow rays the estimator reported, rays it traced through ``trace``)."""
        self.rays = 0
        rng = np.random.default_rng(seed)
        res = REGISTRY[token].estimate(self.query(), self.lights, self.trace, N,
                                       DirectRandom.draw(rng, self.n, N), alpha, heuristic)
        return res.Ld, res.shadow_rays, self.rays


def make_bsdf(kind: str, n: int, rho: float, roughness: float = 0.5, metallic: float = 0.0):
    if kind == "lambert":
        return LambertBSDF(np.full((n, 3), rho))
    return PreviewSurfaceBSDF.from_inputs(np.full((n, 3), rho), np.zeros((n, 3)), np.zeros(n, dtype=bool),
                                          np.full(n, metallic), np.full(n, roughness), np.full(n, 1.5))


def rig_for(case: LightCase, n: int, bsdf: str = "lambert", rho: float = 0.7, roughness: float = 0.5,
            metallic: float = 0.0, clip_dir=None, wo_tilt: float = 0.0) -> Rig:
    lights, obj, p, nrm, kappa, h = case.build()
    # wo: the normal tilted toward a tangent by wo_tilt (in [0, 1): up to ~80 degrees)
    helper = np.array([1.0, 0.0, 0.0]) if abs(nrm[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    tangent = unit(np.cross(nrm, helper))
    wo = unit(nrm + 5.0 * wo_tilt * tangent)
    clip = None if clip_dir is None else unit(clip_dir)
    return Rig(lights, p, nrm, wo, make_bsdf(bsdf, n, rho, roughness, metallic), clip, n)


def reference_lambert(case: LightCase, rig: Rig, rho: float) -> float:
    """Exact (quadrature) shadowed direct lighting, one channel, of a Lambert rig."""
    lights = rig.lights
    obj = lights.kinds[int(lights.kind_of[0])]
    clips = () if rig.clip is None else (rig.clip,)
    if case.kind == "rect":
        G, _ = quadrature.rect_G(rig.p, rig.nrm, obj.center[0], obj.ex[0], obj.ey[0], obj.n[0], clips)
    elif case.kind == "disk":
        G, _ = quadrature.disk_G(rig.p, rig.nrm, obj.center[0], obj.n[0], obj.s1[0], clips)
    else:
        assert not clips, "no sphere quadrature with occluders"
        G, _ = quadrature.sphere_G(rig.p, rig.nrm, obj.center[0], obj.radius[0])
    return rho / math.pi * float(obj.L[0, 0]) * G


def z_score(x: np.ndarray, ref: float, rel_floor: float = 1e-7) -> float:
    """(mean − ref) / standard error, with a relative floor on the error (a zero-variance
    estimator must match to ~rel_floor rather than exactly)."""
    x = np.asarray(x, dtype=np.float64)
    se = x.std(ddof=1) / math.sqrt(x.size)
    scale = math.hypot(se, rel_floor * abs(ref))
    if scale == 0.0:
        return 0.0 if x.mean() == ref else math.inf
    return (x.mean() - ref) / scale
