"""Uniform light picking among lights that emit anything."""

from __future__ import annotations

import numpy as np

from ..lights.base import ShadingContext


class UniformLightSampler:
    name = "uniform"

    def __init__(self, phi: np.ndarray):
        """phi: (count,) light powers; zero-power lights are excluded from picking."""
        phi = np.asarray(phi, dtype=np.float64)
        self.candidates = np.nonzero(phi > 0.0)[0].astype(np.int64)
        self._pmf = np.zeros(phi.size)
        if self.candidates.size:
            self._pmf[self.candidates] = 1.0 / self.candidates.size

    def sample(self, ctx: ShadingContext, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = u.shape[0]
        k = self.candidates.size
        if k == 0:
            return np.zeros(n, np.int64), np.zeros(n)
        i = np.minimum((u * k).astype(np.int64), k - 1)
        return self.candidates[i], np.full(n, 1.0 / k)

    def pmf(self, ctx: ShadingContext, index: np.ndarray) -> np.ndarray:
        return self._pmf[index]
