"""BSDF sampling only: (1/N) Σ f_i L_i v_i / p_b,i over BSDF samples that reach the light.

Delta lights (points, zero-angle distant lights) cannot be reached by BSDF samples, so for them
this estimator returns 0: that is the textbook behaviour, kept for study (the talk's "BSDF
sampling misses bright spots" story); `auto` never picks it for such lights.
"""

from __future__ import annotations

from .base import DirectQuery, DirectRandom, DirectResult, TraceFn, bsdf_samples, ratio


class BSDFSamplingEstimator:
    token = "bsdfSampling"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "one", heuristic: str = "power") -> DirectResult:
        bs, rays = bsdf_samples(q, lights, trace, N, u)
        f = (bs.fd + bs.fs) * bs.v[:, :, None]
        return DirectResult(ratio(f, bs.p_b).mean(axis=1), rays)
