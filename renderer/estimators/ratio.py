"""Ratio estimator (Heitz, Hill & McGuire 2018, "Combining Analytic Direct Illumination and
Stochastic Shadows"): F · Σ(f_i v_i / p_i) / Σ(f_i / p_i) for the diffuse lobe.

Biased (the ratio of two means) but consistent, and noise-free where the light is fully visible
or fully hidden, however many of the samples fall below the horizon (they carry f = 0 and weigh
nothing in either sum). Specular lobes use MIS; lights without an exact F fall back to MIS.
"""

from __future__ import annotations

import numpy as np

from .base import DirectQuery, DirectRandom, DirectResult, TraceFn
from ..kernels.direct import RATIO
from .control_variates import covered_samples, diffuse_combine, diffuse_cv_inputs, specular_and_fallback
from ..sampling import safe_div


class RatioEstimator:
    token = "ratio"

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str = "one", heuristic: str = "power") -> DirectResult:
        F, exact, ls, rays = diffuse_cv_inputs(q, lights, trace, N, u)
        p = ls.p_l.reshape(-1)
        g = safe_div(ls.fd.reshape(-1, 3), p).reshape(ls.fd.shape)
        # No sample fell where F integrates (all below the horizon, say): nothing is known of the
        # visibility there, and 0 would darken a fully lit point whenever that happens (1 in 16
        # points under a dome with N = 4); take it as visible, as the control variate's α does
        # (kernels.direct.diffuse_combine_row, mode RATIO).
        diffuse = diffuse_combine(F, g, ls.v, covered_samples(ls.fd, ls.valid), RATIO)
        spec, full, rays_s = specular_and_fallback(q, lights, trace, N, u, heuristic, exact, ls)
        Ld = np.where(exact[:, None], diffuse + spec, full)
        return DirectResult(Ld, rays + rays_s)
