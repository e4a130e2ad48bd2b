"""Lighting services: pick one light for a next-event connection.

``sample(ctx, u)`` returns (index (n,) int64 global light index, pmf (n,)) and ``pmf(ctx, index)``
returns the probability that ``sample`` would pick ``index`` at that point, which MIS needs when a
BSDF-sampled ray hits an emitter. A pmf of 0 (no light can contribute) means "no light": the
integrator skips the connection. Lights with zero power are never picked.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..lights.base import ShadingContext


class LightSampler(Protocol):
    name: str

    def sample(self, ctx: ShadingContext, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ...

    def pmf(self, ctx: ShadingContext, index: np.ndarray) -> np.ndarray:
        ...
