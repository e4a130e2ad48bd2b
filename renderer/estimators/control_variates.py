"""Control variates on the light's analytic unshadowed integral (the talk's core).

For the diffuse lobe f_d (constant in wi) the unshadowed integral F = ∫ f_d L cos dω is known
exactly (lights/analytic.py), and the shadowed integral is estimated as

    α = 1                         F + (1/N)     Σ f_i (v_i − 1) / p_i      unbiased, can go negative
    α = v̄   (averageVisibility)   v̄F + (1/N)   Σ f_i (v_i − v̄) / p_i      biased: E = E[V]E[F]/N + (N−1)/N E[FV]
    α = v̄   (…Unbiased)           v̄F + (1/(N−1)) Σ f_i (v_i − v̄) / p_i   unbiased for independent samples

with f_i = f_d L cos at light sample i, p_i its light pdf, v_i its visibility and v̄ the mean of
the v_i. Samples below the geometric or shading horizon have v_i = 0 (the surface itself blocks
them), so a light straddling the horizon keeps an unbiased estimate.

Here f is the BSDF's *control lobe* g = c(wo), constant in wi (UsdPreviewSurface's diffuse lobe
is c(wo)·k(wi) with k averaging 1, see bsdfs/preview_surface.py), and F = c(wo)·E exactly. The
residual f − g (specular lobes and the diffuse lobe's wi-dependent part) of the same point uses MIS (light samples shared with the control variate,
plus N BSDF samples, only on rows whose BSDF has a specular lobe). Rows whose light has no exact
F (a textured rect, a dome without irradiance) fall back to MIS over the whole BSDF.
With N = 1 an α based on v̄ is undefined: α = 1 is used (the reader warned once).
"""

from __future__ import annotations

import numpy as np

from .base import DirectQuery, DirectRandom, DirectResult, TraceFn, light_samples, ratio
from .mis import mis_parts


def diffuse_cv_inputs(q: DirectQuery, lights, trace, N, u):
    """Shared by the control variate and the ratio estimator: F (n,3), exact (n,), light samples."""
    E, exact = lights.irradiance(q.light, q.ctx)
    F = q.control * E * lights.diffuse_scale[q.light][:, None]
    ls, rays = light_samples(q, lights, trace, N, u)
    return F, exact, ls, rays


def residual_rows(bsdf) -> np.ndarray:
    """(n,) rows whose BSDF differs from its control lobe (f ≠ g): they need BSDF samples."""
    fn = getattr(bsdf, "has_residual", None)
    return fn() if fn is not None else np.ones(len(bsdf), dtype=bool)


def specular_and_fallback(q, lights, trace, N, u, heuristic, exact, ls):
    """MIS (n, 3) for the specular lobes and for the whole BSDF, sharing the light samples ls.

    BSDF samples are drawn only on rows that need them: a specular lobe, or no exact F.
    """
    need = residual_rows(q.bsdf) | ~exact
    if not np.any(need):
        return np.zeros((q.n, 3)), np.zeros((q.n, 3)), 0
    full, spec, rays, _ = mis_parts(q, lights, trace, N, u, heuristic, bsdf_rows=need, ls=ls)
    return spec, full, rays


class ControlVariateEstimator:
    token = "controlVariate"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "averageVisibilityUnbiased", heuristic: str = "power") -> DirectResult:
        F, exact, ls, rays = diffuse_cv_inputs(q, lights, trace, N, u)
        g = ratio(ls.fd, ls.p_l)                       # (n, N, 3): f_i / p_i
        if alpha == "one" or N < 2:
            a = np.ones(q.n)
            scale = 1.0 / N
        else:
            a = ls.v.mean(axis=1)                      # v̄ per row
            scale = 1.0 / (N - 1) if alpha == "averageVisibilityUnbiased" else 1.0 / N
        diffuse = a[:, None] * F + scale * (g * (ls.v - a[:, None])[:, :, None]).sum(axis=1)
        spec, full, rays_s = specular_and_fallback(q, lights, trace, N, u, heuristic, exact, ls)
        Ld = np.where(exact[:, None], diffuse + spec, full)
        return DirectResult(Ld, rays + rays_s)
