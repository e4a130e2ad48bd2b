"""Row gathers and scatter-adds for the integrator's live-ray arrays (see ``renderer.kernels``).

The wavefront integrator moves rows around at every bounce: it compacts its state to the rays
that hit, gathers shading points for shadow rays, and adds contributions into the radiance of
their paths. numpy's fancy indexing is slow on (n, k) arrays (``a[idx]`` on a (16384, 3) float
array costs ~4x ``np.take(a, idx, axis=0)``, and ``L[idx] += v`` ~20x a compiled loop), so the
hot paths use these instead.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _add_rows_kernel(L, idx, v):
    # Sequential: rows repeated in idx accumulate (np.add.at semantics).
    for i in range(idx.shape[0]):
        r = idx[i]
        for k in range(L.shape[1]):
            L[r, k] += v[i, k]


def take_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows idx (k,) int of a (n, ...) -> (k, ...); a[idx], faster on 2-D arrays."""
    return np.take(a, idx, axis=0)


def add_rows(L: np.ndarray, idx: np.ndarray, v: np.ndarray) -> None:
    """L[idx[i]] += v[i] for every i, in place; repeated rows accumulate (np.add.at semantics).

    L: (n, k) float64, C-contiguous; idx: (m,) int; v: (m, k)."""
    if idx.shape[0] == 0:
        return
    if L.dtype != np.float64 or not L.flags.c_contiguous or L.ndim != 2:
        np.add.at(L, idx, v)
        return
    _add_rows_kernel(L, np.ascontiguousarray(idx, dtype=np.int64),
                     np.ascontiguousarray(np.broadcast_to(v, (idx.shape[0], L.shape[1])), dtype=np.float64))
