"""The fast path's whole bounce loop for one chunk of camera rays, as one compiled call.

FastPath.trace (renderer/integrators/fast_path.py) runs, per bounce, Embree's closest hits of
the live rays, the cut-out walk, the vertex kernel, the shadow rays and the two kernels that add
what the unblocked ones carry. ``trace_kernel`` makes those same calls, in the same order, with
the same per-bounce keys, from compiled code: Embree through accel.py's native handles
(``_intersect_rows`` / ``_occluded_rows``, packets of the width the caller picks), the walks of
_cutout_kernels.py, and _vertex_kernels' ``vertex_kernel``, ``add_unblocked_kernel`` and
``resolve_groups_kernel``, not copies of them. So a chunk's image is the Python loop's to the
last bit, and the call holds no GIL from the camera rays to the last bounce: render threads
running chunks side by side scale (PathIntegrator.render_pass).

Scenes whose bounce still needs numpy work between the calls keep the Python loop;
FastPath.kernel_reason says which. Per-hit surfaces (textured inputs, emission, normal maps) are
evaluated inside the vertex kernel (its ``tex`` record, the last of ``tables``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from renderer.accel import _intersect_rows, _occluded_rows
from renderer.integrators._cutout_kernels import shadow_cutouts_kernel, through_cutouts_kernel
from renderer.integrators._vertex_kernels import (NS, add_unblocked_kernel, resolve_groups_kernel, start_kernel,
                                                  vertex_kernel)
from renderer.kernels import guard_cache, guarded_sources, module_dispatchers

# The counters trace_kernel adds to (its ``tally``): rays traced by kind (as RayCounters counts
# them: cut-out walks count as extension rays), the general path's rule counters (path.py
# _direct), and the BVH queries (Accel.rays_traced: the closest-hit batches, and the occlusion
# queries where no cut-out walk replaces them, as Accel's batch calls count them).
T_EXTENSION = 0
T_SHADOW = 1
T_CONTINUATION = 2
T_OWN_SAMPLES = 3
T_ALPHA_ONE_FALLBACK = 4
T_INTERSECT = 5
T_OCCLUDED = 6
N_TALLY = 7


@njit(cache=True, nogil=True)
def trace_kernel(emb, o, d, tmax, keys, keys2, ckeys, n_u, max_depth, surf, tables, plan, walk, L, tally):
    """Radiance along m camera rays, every bounce, added to L (m, 3) in place.

    emb: (scene, intersect, occluded, width): the Embree scene and the addresses of
    rtcIntersect<W> / rtcOccluded<W> for packets of W = width rays (1: single rays;
    Accel.packet_handles). o, d (m, 3), tmax (m,) float64: the camera rays (unit d). keys, keys2
    (max_depth + 1,) int64: the vertex kernel's and the per-light estimators' stream key of each
    bounce; ckeys (max_depth + 1, 2) int64: the cut-out walks' keys (camera and extension rays,
    shadow rays). n_u: uniforms per row; surf: the vertex kernel's surface record (fixed for the
    render); tables: FastPath.tables (passed on as the vertex kernel's scene arguments).
    plan: FastPath.plan, the estimators' record by vertex depth: (tokens (l,), alphas (l,), N
    (2, l) samples per light at the first vertex and deeper, cont (3, l) bool on continuation MIS
    for camera rays (all), at the first vertex and deeper, cap (2,) shadow rays per row at most,
    groups (2,) estimator groups per row, cv (l,) bool the control variate's lights, fallback
    (2, l) bool those falling back to alpha = one). walk: _cutout_kernels' record (fns, geo, cut,
    tab, eps; FastPath.walk), or None for a scene without cut-outs (numba prunes the walks' branches
    then: a plain scene compiles none of their code). tally (N_TALLY,) int64: counters T_* added
    in place."""
    scene, fn_i, fn_o, width = emb
    tok, alpha, N_at, cont_at, cap_at, grp_at, cv, fallback = plan
    nl = tok.shape[0]
    m = o.shape[0]
    cap = max(cap_at[0], cap_at[1])
    grp = max(grp_at[0], grp_at[1])
    # Two sets of ray state, read by one bounce and written by it for the next.
    S = np.empty((m, NS))
    o32 = np.empty((m, 3), dtype=np.float32)
    d32 = np.empty((m, 3), dtype=np.float32)
    t32 = np.empty(m, dtype=np.float32)
    path = np.arange(m)
    depth = np.zeros(m, dtype=np.int64)
    n_S = np.empty((m, NS))
    n_o32 = np.empty((m, 3), dtype=np.float32)
    n_d32 = np.empty((m, 3), dtype=np.float32)
    n_t32 = np.empty(m, dtype=np.float32)
    n_path = np.empty(m, dtype=np.int64)
    n_depth = np.empty(m, dtype=np.int64)
    unsampled = np.ones(m, dtype=np.bool_)
    sampled = np.zeros(m, dtype=np.bool_)
    start_kernel(o, d, tmax, S, o32, d32, t32)
    prim = np.empty(m, dtype=np.int32)
    b1 = np.empty(m, dtype=np.float32)
    b2 = np.empty(m, dtype=np.float32)
    # The shadow rays of a bounce (cap a row), their estimator records and groups.
    sh_o = np.empty((m * cap, 3), dtype=np.float32)
    sh_d = np.empty((m * cap, 3), dtype=np.float32)
    sh_t = np.empty(m * cap, dtype=np.float32)
    sh_path = np.empty(m * cap, dtype=np.int64)
    sh_c = np.empty((m * cap, 3))
    sh_x = np.empty((m * cap, 3))
    sh_cov = np.empty(m * cap)
    sh_l = np.empty(m * cap, dtype=np.int64)  # each shadow ray's light (read by the Python loop only)
    g_int = np.empty((m * grp, 5), dtype=np.int64)
    g_f = np.empty((m * grp, 6))
    blocked = np.empty(m * cap, dtype=np.bool_)
    counts = np.empty(4 + nl, dtype=np.int64)
    n = m
    for bounce in range(max_depth + 1):
        if n == 0:
            break
        _intersect_rows(fn_i, scene, width, o32[:n], d32[:n], t32[:n], True, 0, n, t32[:n], prim[:n], b1[:n], b2[:n],
                        False)
        tally[T_INTERSECT] += n
        if walk is not None:
            tally[T_EXTENSION] += through_cutouts_kernel(walk[0], np.uint64(ckeys[bounce, 0]), S[:n], d32[:n],
                                                         prim[:n], b1[:n], b2[:n], t32[:n], walk[1], walk[2],
                                                         walk[3], walk[4])
        j = min(bounce, 1)
        cont = cont_at[1 + j]
        c = cap_at[j]
        g = grp_at[j] if bounce < max_depth else 0
        est = (tok, alpha, N_at[j], cont, cont_at[min(bounce, 2)], np.uint64(keys2[bounce]))
        est_out = (sh_x[:n * c], sh_cov[:n * c], g_int[:n * g], g_f[:n * g], sh_l[:n * c])
        counts[:] = 0
        vertex_kernel(path[:n], depth[:n], unsampled[:n], S[:n], t32[:n], prim[:n], b1[:n], b2[:n],
                      np.uint64(keys[bounce]), n_u, surf, max_depth, *tables, L, n_path[:n], n_depth[:n], n_S[:n],
                      n_o32[:n], n_d32[:n], n_t32[:n], sh_o[:n * c], sh_d[:n * c], sh_t[:n * c], sh_path[:n * c],
                      sh_c[:n * c], counts, est, est_out)
        k_next, k_sh, k_grp = counts[0], counts[1], counts[3]
        # The (vertex, light) pairs each light got at this bounce, into the rule counters.
        for li in range(nl):
            pairs = counts[4 + li]
            if cont[li]:
                tally[T_CONTINUATION] += pairs
            if bounce == 0 and cv[li]:
                tally[T_OWN_SAMPLES] += pairs
            if fallback[j, li]:
                tally[T_ALPHA_ONE_FALLBACK] += pairs
        if k_sh:
            if walk is not None:
                shadow_cutouts_kernel(walk[0], np.uint64(ckeys[bounce, 1]), sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh],
                                      walk[1], walk[2], walk[3], walk[4], blocked[:k_sh])
            else:
                _occluded_rows(fn_o, scene, width, sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh], 0, k_sh, blocked[:k_sh])
                tally[T_OCCLUDED] += k_sh
            add_unblocked_kernel(L, sh_path[:k_sh], sh_c[:k_sh], blocked[:k_sh])
        if k_grp:
            resolve_groups_kernel(L, g_int[:k_grp], g_f[:k_grp], sh_x[:k_sh], sh_cov[:k_sh], blocked[:k_sh])
        tally[T_SHADOW] += k_sh
        tally[T_EXTENSION] += k_next
        S, n_S = n_S, S
        o32, n_o32 = n_o32, o32
        d32, n_d32 = n_d32, d32
        t32, n_t32 = n_t32, t32
        path, n_path = n_path, path
        depth, n_depth = n_depth, depth
        unsampled = sampled
        n = k_next


guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/accel.py", *guarded_sources("renderer.integrators._vertex_kernels",
                                                   "renderer.integrators._cutout_kernels")])
