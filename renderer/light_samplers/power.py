"""Light picking in proportion to emitted power, with an O(1) alias table."""

from __future__ import annotations

import numpy as np

from ..lights.base import ShadingContext
from ..sampling import AliasTable


class PowerLightSampler:
    name = "power"

    def __init__(self, phi: np.ndarray):
        """phi: (count,) light powers (luminance-weighted); zero-power lights get pmf 0."""
        phi = np.asarray(phi, dtype=np.float64)
        self.empty = not np.any(phi > 0.0)
        self.table = AliasTable.build(np.where(phi > 0.0, phi, 0.0)) if phi.size else None

    def sample(self, ctx: ShadingContext, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = u.shape[0]
        if self.table is None or self.empty:
            return np.zeros(n, np.int64), np.zeros(n)
        return self.table.sample(u)

    def pmf(self, ctx: ShadingContext, index: np.ndarray) -> np.ndarray:
        if self.table is None or self.empty:
            return np.zeros(np.shape(index))
        return self.table.pmf[index]
