"""The contract every light kind implements. One kind holds all its lights as structure-of-arrays.

All methods are batched: ``idx`` (n,) int64 are *local* indices into this kind's lights (one per
query row), positions/directions are (n, 3) float64 in world space, ``u`` are uniform random
numbers supplied by the integrator. Values come back raw: L is radiance (not divided by any
pdf) and pdf is a solid-angle density at the shading point. A pdf of 0 marks a failed sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class ShadingContext:
    """Where a light is sampled from.

    p: (n, 3) reference point; n: (n, 3) geometric normal at p (zeros if none, e.g. tests that
    sample from a free point); ns: (n, 3) shading normal (zeros if none).
    """

    p: np.ndarray
    n: np.ndarray
    ns: np.ndarray

    def __len__(self) -> int:
        return self.p.shape[0]

    def take(self, rows: np.ndarray) -> "ShadingContext":
        rows = np.asarray(rows)
        if rows.dtype == bool:
            return ShadingContext(self.p[rows], self.n[rows], self.ns[rows])
        # np.take gathers (n, 3) rows ~4x faster than fancy indexing.
        return ShadingContext(np.take(self.p, rows, axis=0), np.take(self.n, rows, axis=0),
                              np.take(self.ns, rows, axis=0))


@dataclass(frozen=True)
class LightLiSample:
    """A sampled direction toward a light, as seen from the shading point.

    L: (n, 3) radiance arriving at p along -wi (0 where the sample is invalid or the light is
       one-sided and seen from behind).
    wi: (n, 3) unit direction from p toward the light.
    pdf: (n,) solid-angle pdf of wi (0 = invalid sample; the integrator skips it).
    dist: (n,) distance from p to the sampled point (inf for infinite lights); the shadow ray
       is traced over [0, dist) less an epsilon.
    p_light: (n, 3) the sampled point on the light (for infinite lights, p + wi * a large number).
    """

    L: np.ndarray
    wi: np.ndarray
    pdf: np.ndarray
    dist: np.ndarray
    p_light: np.ndarray


class LightKind(Protocol):
    """A kind of light ('rect', 'sphere', ...) holding ``count`` lights."""

    name: str
    count: int
    paths: list[str]
    infinite: bool  # dome and distant: hit by rays that escape the scene

    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Sample a direction toward light idx from ctx.p. u: (n, 2)."""
        ...

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (n,) that sample_li(idx, ctx, .) returns wi. 0 if wi misses the light."""
        ...

    def phi(self) -> np.ndarray:
        """(count,) emitted power (luminance-weighted, in nits * m^2 * sr) for power-based light picking."""
        ...

    # Finite lights only --------------------------------------------------------------
    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Exact first hit distance (n,) of rays o + t d (d unit) with light idx; inf where none."""
        ...

    def le(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Radiance (n, 3) leaving light idx at p_light toward -wi (wi points *toward* the light)."""
        ...

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """Conservative bounding triangles for ray queries: ((T, 3, 3) float64, owner (T,) int64).

        Every ray that hits the exact shape also hits a proxy triangle of that light *at or before*
        the exact hit; the integrator confirms with ``intersect``.
        """
        ...

    # Infinite lights only -------------------------------------------------------------
    def le_escaped(self, idx: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Radiance (n, 3) arriving along -d for a ray with direction d that escaped the scene."""
        ...
