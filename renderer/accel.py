"""The one module that touches embreex: batched closest-hit and occlusion queries.

embree works in float32 with tnear fixed at 0, so this module (1) converts to float32 here and
nowhere else, (2) offers ``ray_epsilon`` so callers can push ray origins off surfaces by an
amount proportional to the coordinates' magnitude (a stage placed 1e4 units from the origin
needs a larger offset than one at the origin), and (3) splits large batches into chunks that run
on a thread pool: embreex releases the GIL inside ``run``, so threads scale.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

# embreex reports a miss as tfar = 1e37 and primID = -1.
_EMBREE_INF = np.float32(1e37)
# Rays per embree call: large enough to amortise the Python call, small enough to keep
# both cores busy on a 256x256 batch.
CHUNK = 32768
# Relative float32 error budget for origin offsets: about 8 float32 ulps (2^-23 ~ 1.2e-7) of
# the coordinate magnitude, enough for embree's own intersection error. Larger offsets let
# shadow rays start past nearby occluders (the stress suite caught 2e-5 erasing shadows 1e5
# units from the origin).
_REL_EPS = 5.0e-7


@dataclass(frozen=True)
class Hits:
    """Closest hits of a ray batch.

    t: (n,) float64 hit distance, inf where the ray missed.
    prim: (n,) int64 triangle index, -1 where missed.
    b1, b2: (n,) float64 barycentrics of vertices 1 and 2 (b0 = 1 - b1 - b2).
    """

    t: np.ndarray
    prim: np.ndarray
    b1: np.ndarray
    b2: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def default_threads() -> int:
    return max(1, os.cpu_count() or 1)


class Accel:
    """A static triangle BVH.

    triangles: (T, 3, 3) float64 world-space vertices. An empty scene is allowed (every ray misses).
    threads: worker threads for batched queries.
    tri_index: (T,) int64, for a BVH over a subset of a scene's triangles (a shadowLink BVH):
    the scene index of each of its triangles, so a hit's material can be looked up; None when
    the BVH holds the scene's triangles in order.
    """

    def __init__(self, triangles: np.ndarray, threads: int | None = None, tri_index: np.ndarray | None = None):
        tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        self.tri_index = tri_index
        self.count = tri.shape[0]
        self.threads = max(1, int(threads or default_threads()))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        if self.count:
            lo = tri.reshape(-1, 3).min(axis=0)
            hi = tri.reshape(-1, 3).max(axis=0)
        else:
            lo = hi = np.zeros(3)
        self.bounds = (lo, hi)
        self.diagonal = float(np.linalg.norm(hi - lo))
        self.magnitude = float(max(np.abs(lo).max(), np.abs(hi).max()))
        # Largest |coordinate| of each triangle's vertices (T,): embree's float32 hit distance
        # errs in proportion to the vertices' magnitude, not only the hit point's (a tilted
        # plane through the origin with vertices 50 units out self-shadowed a third of its
        # shadow rays near the origin when the offset scaled with |p| alone).
        self.tri_mag = np.ascontiguousarray(np.abs(tri).max(axis=(1, 2))) if self.count else np.zeros(0)
        self._scene = None
        if self.count:
            self._scene = rtcs.EmbreeScene()
            # The mesh object must stay alive as long as the scene uses its buffers.
            self._mesh = TriangleMesh(self._scene, np.ascontiguousarray(tri, dtype=np.float32))
        self.rays_traced = {"intersect": 0, "occluded": 0}

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    # ----------------------------------------------------------------------------------
    def ray_epsilon(self, p: np.ndarray, prim: np.ndarray | None = None) -> np.ndarray:
        """(n,) origin offset for points p (n, 3) on triangles prim (n,): proportional to the
        float32 rounding error of the point and of the triangle's vertices (``tri_mag``)."""
        a = np.abs(p)
        mag = np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])  # cheaper than max(axis=1) on (n, 3)
        if prim is not None and self.count:
            mag = np.maximum(mag, self.tri_mag[np.asarray(prim, dtype=np.int64)])
        return _REL_EPS * np.maximum(mag, 1e-3 * self.diagonal) + 1e-9 * self.diagonal + 1e-30

    def epsilon_terms(self) -> tuple[float, float, float]:
        """(rel, floor, add) with ray_epsilon(p, prim) = rel max(max_k |p_k|, tri_mag[prim], floor)
        + add, for kernels that offset origins themselves."""
        return _REL_EPS, 1e-3 * self.diagonal, 1e-9 * self.diagonal + 1e-30

    def _map(self, fn, n: int):
        bounds = [(s, min(n, s + CHUNK)) for s in range(0, n, CHUNK)]
        if self._pool is None or len(bounds) == 1:
            return [fn(a, b) for a, b in bounds]
        return list(self._pool.map(lambda ab: fn(*ab), bounds))

    def intersect(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray | None = None) -> Hits:
        """Closest hit along o + t d for t in (0, tmax). o, d: (n, 3); tmax: (n,) or None (inf)."""
        n = o.shape[0]
        self.rays_traced["intersect"] += n
        if n == 0 or self._scene is None:
            return Hits(np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n), np.zeros(n))
        o32 = np.ascontiguousarray(o, dtype=np.float32)
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        if tmax is None:
            t32 = np.full(n, _EMBREE_INF, dtype=np.float32)
        else:
            t32 = np.minimum(np.asarray(tmax, dtype=np.float64), 1e37).astype(np.float32)
        t_out = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        b1 = np.zeros(n)
        b2 = np.zeros(n)

        def run(a: int, b: int) -> None:
            # embreex overwrites a dists array it is given, so pass a copy of our slice.
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), output=1)
            pid = r["primID"].astype(np.int64)
            hit = pid >= 0
            prim[a:b] = pid
            t_out[a:b] = np.where(hit, r["tfar"].astype(np.float64), np.inf)
            b1[a:b] = r["u"]
            b2[a:b] = r["v"]

        self._map(run, n)
        return Hits(t_out, prim, b1, b2)

    def occluded(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """(n,) bool: is anything hit along o + t d for t in (0, tmax)?"""
        n = o.shape[0]
        self.rays_traced["occluded"] += n
        if n == 0 or self._scene is None:
            return np.zeros(n, dtype=bool)
        o32 = np.ascontiguousarray(o, dtype=np.float32)
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        t32 = np.minimum(np.asarray(tmax, dtype=np.float64), 1e37).astype(np.float32)
        out = np.zeros(n, dtype=bool)

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), query="OCCLUDED")
            # OCCLUDED answers 0 where blocked and -1 where the segment is free.
            out[a:b] = np.asarray(r) != -1

        self._map(run, n)
        return out


    # ---- float32 batches prepared by compiled kernels (the fast path) -------------------
    def intersect_prepared(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray):
        """Closest hits of rays a kernel wrote in embree's own format, without conversions.

        o32, d32: (n, 3) C-contiguous float32; t32: (n,) float32 far limits (<= 1e37), which
        are *overwritten* with the hit distances (unchanged where the ray missed).
        Returns prim (n,) int32 (-1 on a miss) and the barycentrics u, v (n,) float32.
        """
        n = o32.shape[0]
        self.rays_traced["intersect"] += n
        prim = np.full(n, -1, dtype=np.int32)
        u = np.zeros(n, dtype=np.float32)
        v = np.zeros(n, dtype=np.float32)
        if n == 0 or self._scene is None:
            return prim, u, v

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b], output=1)
            prim[a:b] = r["primID"]
            u[a:b] = r["u"]
            v[a:b] = r["v"]
            t32[a:b] = r["tfar"]

        self._map(run, n)
        return prim, u, v

    def occluded_prepared(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray) -> np.ndarray:
        """occluded() for float32 rays in embree's format (as intersect_prepared; t32 may be
        overwritten). Returns (n,) bool, True where blocked."""
        n = o32.shape[0]
        self.rays_traced["occluded"] += n
        out = np.zeros(n, dtype=bool)
        if n == 0 or self._scene is None:
            return out

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b], query="OCCLUDED")
            out[a:b] = np.asarray(r) != -1

        self._map(run, n)
        return out


def raw_throughput_probe(accel: Accel, o: np.ndarray, d: np.ndarray, query: str = "INTERSECT") -> float:
    """Time embree alone on a prepared float32 batch, in seconds (for the benchmark's ratio).

    Uses the same chunking and threads as Accel but no float64 conversion or post-processing.
    """
    import time

    o32 = np.ascontiguousarray(o, dtype=np.float32)
    d32 = np.ascontiguousarray(d, dtype=np.float32)
    n = o32.shape[0]
    t32 = np.full(n, _EMBREE_INF, dtype=np.float32)

    def run(a: int, b: int):
        if query == "INTERSECT":
            return accel._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), output=1)
        return accel._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), query="OCCLUDED")

    t0 = time.perf_counter()
    accel._map(run, n)
    return time.perf_counter() - t0
