"""Light sampling only: (1/N) Σ f_i L_i v_i / p_l,i."""

from __future__ import annotations

import numpy as np

from .base import DirectQuery, DirectRandom, DirectResult, TraceFn, light_samples, ratio


class LightSamplingEstimator:
    token = "lightSampling"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "one", heuristic: str = "power") -> DirectResult:
        ls, rays = light_samples(q, lights, trace, N, u)
        f = (ls.fd + ls.fs) * ls.v[:, :, None]
        # Delta lights report p_l = inf for MIS; their own sampling pdf is 1 (L is already the
        # incident radiance-like term), so divide by 1 there.
        p = np.where(np.isinf(ls.p_l), 1.0, ls.p_l)
        return DirectResult(ratio(f, p).mean(axis=1), rays)
