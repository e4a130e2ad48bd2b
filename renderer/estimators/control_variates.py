"""Control variates on the light's analytic unshadowed integral (the talk's core).

For the diffuse lobe f_d (constant in wi) the unshadowed integral F = ∫ f_d L cos dω is known
exactly (lights/analytic.py), and the shadowed integral is estimated as

    α = 1                         F + (1/N)     Σ f_i (v_i − 1) / p_i      unbiased, can go negative
    α = v̄   (averageVisibility)   v̄F + (1/N)   Σ f_i (v_i − v̄) / p_i      biased: E = E[V]E[F]/N + (N−1)/N E[FV]
    α = v̄   (…Unbiased)           v̄F + (1/(N−1)) Σ f_i (v_i − v̄) / p_i   unbiased for independent samples

with f_i = f_d L cos at light sample i, p_i its light pdf, v_i its visibility and v̄ the mean of
the v_i. Samples below the geometric or shading horizon carry f_i = 0: F leaves that part out,
so v̄ is the mean over the samples F covers (``covered_samples``), and the unbiased form takes
it leave-one-out (``cv_diffuse``). Counting those samples as v = 0 made v̄ ≈ 1/2 at a fully lit
point under a dome, and the control variate noisier than MIS on a white furnace.

Here f is the BSDF's *control lobe* g = c(wo), constant in wi (UsdPreviewSurface's diffuse lobe
is c(wo)·k(wi) with k averaging 1, see bsdfs/preview_surface.py), and F = c(wo)·E exactly. The
residual f − g (specular lobes and the diffuse lobe's wi-dependent part) of the same point uses MIS (light samples shared with the control variate,
plus N BSDF samples, only on rows whose BSDF has a specular lobe). Rows whose light has no exact
F (a textured rect, a dome without irradiance) fall back to MIS over the whole BSDF.
With N = 1 an α based on v̄ is undefined: α = 1 is used (the reader warned once).
"""

from __future__ import annotations

import numpy as np

from ..kernels.direct import diffuse_combine_kernel
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


def covered_samples(fd: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(n, N) bool: the samples that fall where F integrates, i.e. whose control integrand
    fd (n, N, 3) is non-zero. Samples below the geometric or shading horizon (or where the
    light's radiance is zero) carry fd = 0: the surface, not the scene, hides them, and F
    already leaves them out, so they say nothing about the visibility that α must measure."""
    return valid & ((fd[:, :, 0] > 0.0) | (fd[:, :, 1] > 0.0) | (fd[:, :, 2] > 0.0))


def cv_diffuse(F: np.ndarray, X: np.ndarray, v: np.ndarray, covered: np.ndarray, alpha: str) -> np.ndarray:
    """The control-variate estimate (n, 3) of ∫ g L v cos⁺ dω from F (n, 3), X = f_i / p_i
    (n, N, 3), the visibilities v (n, N) and the covered mask (n, N) (``covered_samples``).

    one:  F + (1/N) Σ X_i (v_i − 1).
    averageVisibility (the talk's biased form): v̄ F + (1/N) Σ X_i (v_i − v̄), with v̄ the mean
        visibility of the covered samples (α = 1 where none is covered: then every X_i = 0).
    averageVisibilityUnbiased: leave-one-out, (1/N) Σ_i [α_i F + X_i (v_i − α_i)] with α_i the
        mean visibility of the *other* covered samples (1 where there is none). α_i does not
        depend on sample i, so each term has expectation E[α_i] F + ∫fv − F E[α_i] = ∫fv: the
        estimate is unbiased. Where every sample is covered it equals the talk's
        v̄ F + 1/(N−1) Σ X_i (v_i − v̄) term for term.
    A fully lit point (every covered v_i = 1) gives F exactly, a fully shadowed one 0, in the
    last two forms, whatever share of the samples fell below the horizon.
    """
    from . import ALPHAS

    return diffuse_combine(F, X, v, covered, ALPHAS.index(alpha))


def diffuse_combine(F: np.ndarray, X: np.ndarray, v: np.ndarray, covered: np.ndarray, mode: int) -> np.ndarray:
    """kernels.direct.diffuse_combine_row over n rows (the one implementation of the control
    variate's and the ratio estimator's formulas, shared with the compiled path): F (n, 3),
    X (n, N, 3), v (n, N), covered (n, N) bool, mode a kernels.direct mode. Returns (n, 3)."""
    n, N = v.shape
    out = np.empty((n, 3))
    c = np.ascontiguousarray
    diffuse_combine_kernel(c(F, dtype=np.float64), c(X, dtype=np.float64).reshape(n * N, 3),
                           c(v, dtype=np.float64).reshape(n * N), c(covered, dtype=np.float64).reshape(n * N),
                           mode, out)
    return out


class ControlVariateEstimator:
    token = "controlVariate"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "averageVisibilityUnbiased", heuristic: str = "power") -> DirectResult:
        F, exact, ls, rays = diffuse_cv_inputs(q, lights, trace, N, u)
        X = ratio(ls.fd, ls.p_l)                       # (n, N, 3): f_i / p_i
        diffuse = cv_diffuse(F, X, ls.v, covered_samples(ls.fd, ls.valid), alpha)
        spec, full, rays_s = specular_and_fallback(q, lights, trace, N, u, heuristic, exact, ls)
        Ld = np.where(exact[:, None], diffuse + spec, full)
        return DirectResult(Ld, rays + rays_s)
