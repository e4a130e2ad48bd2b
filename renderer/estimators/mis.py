"""Multiple importance sampling: N light samples plus N BSDF samples, balance or power heuristic.

    (1/N) Σ_light w_l f L v / p_l  +  (1/N) Σ_bsdf w_b f L v / p_b,   w_x = h(p_x, p_other)

With equal sample counts the counts cancel inside the heuristics. Rows whose BSDF has no lobe
that light sampling cannot cover still get their BSDF samples, because the BSDF samples also
cover the light's emission that the light sampler reaches with a poor pdf.
"""

from __future__ import annotations

import numpy as np

from .base import DirectQuery, DirectRandom, DirectResult, TraceFn, bsdf_samples, light_samples, mis_weights, ratio


def mis_parts(q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom, heuristic: str,
              bsdf_rows: np.ndarray | None = None, ls=None):
    """MIS estimates (n, 3) of the whole BSDF and of its specular lobes alone, from one set of
    samples, plus the rays traced and the light samples.

    bsdf_rows: (n,) rows that take BSDF samples (others: light samples only, weighted as MIS
    still, which is correct only where the caller ignores those rows' result).
    ls: light samples already drawn by the caller (the control variate shares them).
    """
    rays = 0
    if ls is None:
        ls, rays = light_samples(q, lights, trace, N, u)
    bs, rays_b = bsdf_samples(q, lights, trace, N, u, rows_mask=bsdf_rows)
    w_l = mis_weights(heuristic, ls.p_l.reshape(-1), ls.p_b.reshape(-1)).reshape(ls.p_l.shape)
    w_b = mis_weights(heuristic, bs.p_b.reshape(-1), bs.p_l.reshape(-1)).reshape(bs.p_b.shape)
    p_l = np.where(np.isinf(ls.p_l), 1.0, ls.p_l)  # delta lights: weight 1, pdf 1
    wl = (w_l * ls.v)[:, :, None]
    wb = (w_b * bs.v)[:, :, None]
    spec = ratio(ls.fs * wl, p_l).mean(axis=1) + ratio(bs.fs * wb, bs.p_b).mean(axis=1)
    diff = ratio(ls.fd * wl, p_l).mean(axis=1) + ratio(bs.fd * wb, bs.p_b).mean(axis=1)
    return diff + spec, spec, rays + rays_b, ls


def mis_light_half(q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                   heuristic: str) -> DirectResult:
    """The light-sampling half of MIS whose BSDF half is the path's continuation ray.

    The integrator reuses the BSDF sample that continues the path as the BSDF technique for
    every light it reaches (pbrt's scheme): that ray adds L_e weighted by h(p_b, pmf·p_l) when
    it hits the light. This half weights its light samples by h(pmf·p_l, p_b), with pmf the
    probability that the lighting service picked the light, so the two halves sum to one
    estimator and no BSDF sample, light intersection or second shadow ray is spent here.
    Returns the contribution *not yet* divided by pmf, like every estimator.
    """
    ls, rays = light_samples(q, lights, trace, N, u)
    pmf = np.ones(q.n) if q.pmf is None else q.pmf
    p_pick = ls.p_l * pmf[:, None]  # delta lights keep p_l = inf, so their weight is 1
    w_l = mis_weights(heuristic, p_pick.reshape(-1), ls.p_b.reshape(-1)).reshape(ls.p_l.shape)
    p_l = np.where(np.isinf(ls.p_l), 1.0, ls.p_l)
    f = (ls.fd + ls.fs) * (w_l * ls.v)[:, :, None]
    return DirectResult(ratio(f, p_l).mean(axis=1), rays)


class MISEstimator:
    token = "mis"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "one", heuristic: str = "power") -> DirectResult:
        est, _, rays, _ = mis_parts(q, lights, trace, N, u, heuristic)
        return DirectResult(est, rays)
