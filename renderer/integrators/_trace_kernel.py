"""The fast path's whole bounce loop for one chunk of camera rays, as one compiled call.

FastPath.trace (renderer/integrators/fast_path.py) runs, per bounce, Embree's closest hits of
the live rays, the cut-out walk, the vertex kernel, the shadow rays and the two kernels that add
what the unblocked ones carry. ``trace_kernel`` makes those same calls, in the same order, with
the same per-bounce keys, from compiled code: Embree through accel.py's native handles
(``_intersect_rows`` / ``_occluded_rows``, packets of the width the caller picks), the walks of
_cutout_kernels.py, and _vertex_kernels' ``vertex_kernel``, ``add_unblocked_kernel`` and
``resolve_groups_kernel`` (with shadow groups: ``shadow_visibility_kernel`` below, which the
Python loop calls too, and the visible kernels), not copies of them. So a chunk's image is the Python loop's to the
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
from renderer.integrators._vertex_kernels import (_GAMMA, NS, add_unblocked_kernel, add_visible_kernel, lds_at,
                                                  resolve_groups_kernel, resolve_groups_visible_kernel, start_kernel,
                                                  vertex_kernel)
from renderer.integrators.shadow_api import shadow_strength
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
# A shadow group's rays (FastPath._shadow_record) as integrators/shadow_api.py's visibility and
# PathIntegrator.visible_from trace them: plain rays against the group's shadowLink BVH (through
# cut-outs where the scene has them), none (shadow:enable off: v = 1), an occlusion query up to
# shadow:distance, or the nearest occluder's distance for the falloff zone (v = 1 - s(t)).
SH_PLAIN = 0
SH_OFF = 1
SH_NEAR = 2
SH_FADE = 3
# A group g's cut-out walks number their uniforms from (g + 1) 2^40 on, past those of the plain
# rays under the same key.
_GROUP_STRIDE = np.uint64(1 << 40)


@njit(cache=True, nogil=True)
def trace_kernel(emb, o, d, tmax, keys, keys2, ckeys, n_u, max_depth, surf, tables, plan, walk, L, tally, shadows,
                 lds):
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
    (2, l) bool those falling back to alpha = one, emits: a material emits (extension_useful)).
    walk: _cutout_kernels' record (fns, geo, cut,
    tab, eps; FastPath.walk), or None for a scene without cut-outs (numba prunes the walks' branches
    then: a plain scene compiles none of their code). tally (N_TALLY + 2 groups,) int64: counters
    T_* added in place, then each shadow group's BVH queries (shadow_visibility_kernel).
    shadows: FastPath._shadow_record (shadowLink, ShadowAPI, shadow colours: the shadow rays go
    through shadow_visibility_kernel and add their visibility with the colour), or None for plain
    shadows (numba prunes that branch then). lds: (pix (m,) uint64, sidx uint64, roles (n_u, 2)
    int64), the camera rays' pixel keys, pass and the uniforms' dimension pairs (FastPath.trace:
    the vertex kernel draws each pixel's low-discrepancy numbers, _sobol_pass), or pix empty
    for the keys' independent streams."""
    scene, fn_i, fn_o, width = emb
    tok, alpha, N_at, cont_at, cap_at, grp_at, cv, fallback, emits = plan
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
    # With shadow groups: each shadow ray's visibility in [0, 1] and its light's shadow colour.
    n_vis = 0 if shadows is None else m * cap
    vis = np.empty(n_vis)
    tint = np.empty((n_vis, 3))
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
                      np.uint64(keys[bounce]), lds_at(lds, bounce, n_u), n_u, surf, max_depth, *tables, L,
                      n_path[:n], n_depth[:n], n_S[:n],
                      n_o32[:n], n_d32[:n], n_t32[:n], sh_o[:n * c], sh_d[:n * c], sh_t[:n * c], sh_path[:n * c],
                      sh_c[:n * c], counts, est, est_out)
        k_next, k_sh, k_grp = counts[0], counts[1], counts[3]
        if not extension_useful(bounce, max_depth, cont, emits):
            k_next = 0
        # The (vertex, light) pairs each light got at this bounce, into the rule counters.
        for li in range(nl):
            pairs = counts[4 + li]
            if cont[li]:
                tally[T_CONTINUATION] += pairs
            if bounce == 0 and cv[li]:
                tally[T_OWN_SAMPLES] += pairs
            if fallback[j, li]:
                tally[T_ALPHA_ONE_FALLBACK] += pairs
        if k_sh and shadows is not None:
            shadow_visibility_kernel(emb, np.uint64(ckeys[bounce, 1]), sh_o[:k_sh], sh_d[:k_sh], sh_t[:k_sh],
                                     sh_l[:k_sh], walk, shadows, vis[:k_sh], tint[:k_sh], tally)
            add_visible_kernel(L, sh_path[:k_sh], sh_c[:k_sh], vis[:k_sh], tint[:k_sh])
            if k_grp:
                resolve_groups_visible_kernel(L, g_int[:k_grp], g_f[:k_grp], sh_x[:k_sh], sh_cov[:k_sh], vis[:k_sh])
        elif k_sh:
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



@njit(cache=True, nogil=True)
def extension_useful(bounce, max_depth, cont, emits):
    """Whether the extension rays that leave the vertices of ``bounce`` can add anything: what
    such a ray finds counts as emission of a surface (emits) or, as continuation MIS's BSDF half,
    of the lights on continuation MIS at those vertices (cont (lights,) bool); past the last
    scattering vertex (bounce max_depth - 1) it reaches nothing that scatters, and without
    lights nothing scatters light at all."""
    if emits:
        return True
    if cont.shape[0] == 0:
        return False
    if bounce < max_depth - 1:
        return True
    for li in range(cont.shape[0]):
        if cont[li]:
            return True
    return False


@njit(cache=True, nogil=True)
def shadow_visibility_kernel(emb, key, sh_o, sh_d, sh_t, sh_l, walk, shadows, v, tint, tally):
    """Visibility v (k,) in [0, 1] and shadow colour tint (k, 3) of the shadow rays sh_o, sh_d (k, 3),
    sh_t (k,) float32 (origins offset, as the vertex kernel wrote them) of the lights sh_l (k,)
    (kernel order), each traced by its light's shadow group: what FastPath._visibility gets from
    PathIntegrator.visible_from and integrators/shadow_api.py, from compiled code.

    emb, walk: as trace_kernel's (walk None: no cut-outs); key: the cut-out walks' key of the
    bounce's shadow rays. shadows: FastPath._shadow_record, (grp (lights,) int64 each light's
    group, -1 plain; tint_l (lights, 3) its shadow:color; g_scene (G,) int64 each group's Embree
    scene; g_mode (G,) SH_*; g_par (G, 3) distance, falloff, gamma; g_geo (off (G + 1,), then
    _cutout_kernels' geo arrays of every group's triangles, group g's from off[g], in its BVH's
    order); g_eps (G, 3) each group BVH's Accel.epsilon_terms). The rays are taken set by set
    (the plain ones first, in their order, as FastPath._blocked takes them; then group by group)
    into packets. tally: T_SHADOW gains the rays traced (none for shadow:enable off), T_OCCLUDED
    the plain rays' occlusion queries where no cut-out walk replaces them, and tally[N_TALLY + 2 g]
    (closest hits), [N_TALLY + 2 g + 1] (occlusion queries) group g's BVH queries."""
    scene, fn_i, fn_o, width = emb
    grp, tint_l, g_scene, g_mode, g_par, g_geo, g_eps = shadows
    k = sh_o.shape[0]
    n_g = g_scene.shape[0]
    # The rays ordered by set (plain, then group 0, 1, ...), stable: start[s] .. start[s + 1] - 1
    # are set s's (s = group + 1).
    start = np.zeros(n_g + 2, dtype=np.int64)
    for i in range(k):
        start[grp[sh_l[i]] + 2] += 1
    for s in range(n_g + 1):
        start[s + 1] += start[s]
    order = np.empty(k, dtype=np.int64)
    fill = start[:n_g + 1].copy()
    for i in range(k):
        s = grp[sh_l[i]] + 1
        order[fill[s]] = i
        fill[s] += 1
    o = np.empty((k, 3), dtype=np.float32)
    dr = np.empty((k, 3), dtype=np.float32)
    t = np.empty(k, dtype=np.float32)
    for j in range(k):
        i = order[j]
        for c in range(3):
            o[j, c] = sh_o[i, c]
            dr[j, c] = sh_d[i, c]
        t[j] = sh_t[i]
        for c in range(3):
            tint[i, c] = tint_l[sh_l[i], c]
    blocked = np.zeros(k, dtype=np.bool_)
    vis = np.ones(k)
    # Plain rays: the scene BVH, as trace_kernel traces them without groups.
    a, b = start[0], start[1]
    if b > a:
        if walk is not None:
            shadow_cutouts_kernel(walk[0], key, o[a:b], dr[a:b], t[a:b], walk[1], walk[2], walk[3], walk[4],
                                  blocked[a:b])
        else:
            _occluded_rows(fn_o, scene, width, o, dr, t, a, b, blocked)
            tally[T_OCCLUDED] += b - a
        tally[T_SHADOW] += b - a
        for j in range(a, b):
            vis[j] = 0.0 if blocked[j] else 1.0
    t_lim = np.empty(k)
    t_hit = np.empty(k)
    prim = np.empty(k, dtype=np.int64)
    bu = np.empty(k)
    bv = np.empty(k)
    for g in range(n_g):
        a, b = start[g + 1], start[g + 2]
        mode = g_mode[g]
        if b == a or mode == SH_OFF:
            continue  # shadow:enable off: visible, no ray
        tally[T_SHADOW] += b - a
        if mode == SH_PLAIN:
            if walk is not None:
                lo, hi = g_geo[0][g], g_geo[0][g + 1]
                geo = (g_geo[1][lo:hi], g_geo[2][lo:hi], g_geo[3][lo:hi], g_geo[4][lo:hi], g_geo[5][lo:hi],
                       g_geo[6][lo:hi])
                fns = (g_scene[g], walk[0][1], walk[0][2])
                key_g = key + np.uint64(g + 1) * _GROUP_STRIDE * _GAMMA
                tally[N_TALLY + 2 * g] += shadow_cutouts_kernel(fns, key_g, o[a:b], dr[a:b], t[a:b], geo, walk[2],
                                                                walk[3], (g_eps[g, 0], g_eps[g, 1], g_eps[g, 2]),
                                                                blocked[a:b])
            else:
                _occluded_rows(fn_o, g_scene[g], width, o, dr, t, a, b, blocked)
            tally[N_TALLY + 2 * g + 1] += b - a
            for j in range(a, b):
                vis[j] = 0.0 if blocked[j] else 1.0
            continue
        # ShadowAPI's distance: only occluders nearer than it cast shadow (no cut-outs, as
        # shadow_api.visibility).
        dist, falloff, gamma = g_par[g, 0], g_par[g, 1], g_par[g, 2]
        for j in range(a, b):
            t_lim[j] = min(float(t[j]), dist)
        if mode == SH_NEAR:
            _occluded_rows(fn_o, g_scene[g], width, o, dr, t_lim, a, b, blocked)
            tally[N_TALLY + 2 * g + 1] += b - a
            for j in range(a, b):
                vis[j] = 0.0 if blocked[j] else 1.0
        else:
            _intersect_rows(fn_i, g_scene[g], width, o, dr, t_lim, True, a, b, t_hit, prim, bu, bv, True)
            tally[N_TALLY + 2 * g] += b - a
            for j in range(a, b):
                vis[j] = 1.0 - shadow_strength(t_hit[j], dist, falloff, gamma)
    for j in range(k):
        v[order[j]] = vis[j]


guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/accel.py", "renderer/integrators/shadow_api.py",
             *guarded_sources("renderer.integrators._vertex_kernels", "renderer.integrators._cutout_kernels")])
