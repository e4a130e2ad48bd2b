"""Every light at every vertex, as in the talk's small scenes (pmf 1 per light).

The integrator recognises ``exhaustive = True`` and pairs each shading point with every light;
``sample`` exists for protocol completeness (it picks uniformly, but reports the pmf of the
exhaustive strategy only through ``pmf``, which is 1).
"""

from __future__ import annotations

import numpy as np

from ..lights.base import ShadingContext


class ExhaustiveLightSampler:
    name = "exhaustive"
    exhaustive = True

    def __init__(self, phi: np.ndarray):
        self.count = int(np.asarray(phi).size)

    def sample(self, ctx: ShadingContext, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise TypeError("the exhaustive sampler pairs every point with every light; it does not pick")

    def pmf(self, ctx: ShadingContext, index: np.ndarray) -> np.ndarray:
        return np.ones(np.shape(index))
