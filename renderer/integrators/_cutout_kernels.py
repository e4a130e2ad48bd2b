"""Compiled cut-out walks of the fast path (renderer/integrators/fast_path.py): rays that meet
surfaces absent by their presence (opacity, renderer/materials.py) go on past them, tracing
Embree from the kernel through accel.py's native single-ray calls.

Both walks estimate what the general path's numpy loops estimate (PathIntegrator.trace's
pass-through and PathIntegrator._visible_through_cutouts): each surface of a material that may be
cut out is present with its presence at the hit, against one uniform; an absent one is passed by
going on from just behind it (the hit point offset by the ray epsilon against the geometric
normal, which faces the ray), at most CUTOUT_PASSES surfaces a ray. Uniforms come from the
counter-based stream of the vertex kernel (splitmix_u01), number row * CUTOUT_PASSES + pass + 1
after the caller's key.

``geo``: (vertices (T, 3, 3), face_normal (T, 3), normals (T, 3, 3), st (T, 3, 2), tri_mat (T,),
tri_mag (T,)); ``cut``: (materials,) bool, the material may be absent; ``tab``:
MaterialTable.surface_record() (presence_hit); ``eps``: Accel.epsilon_terms(); ``fns``: (scene, intersect1,
occluded1) of Accel.native_handles().
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.accel import (HIT_GEOM, HIT_PRIM, HIT_U, HIT_V, INVALID_ID, RAY_TFAR, RAY_WORDS, RAYHIT_WORDS,
                            aligned_record, ray_epsilon_row, rtc_intersect1, rtc_occluded1, set_ray)
from renderer.geometry import _interaction_row, st_row
from renderer.integrators._vertex_kernels import D, O, TMAX, splitmix_u01
from renderer.kernels import guard_cache, guarded_sources, module_dispatchers
from renderer.materials import presence_hit

# Cut-out surfaces one ray may pass (as the general path, which bounds its loops by 64).
CUTOUT_PASSES = 64


@njit(cache=True, nogil=True)
def _absent(geo, tab, k, w1, w2, u, stv):
    """Whether triangle k's surface at barycentrics (w1, w2) is absent for the uniform u (the
    general path passes through where u >= presence); stv: scratch for the hit's per-hit
    coordinates (geo[3]'s columns)."""
    st_row(geo[3], k, w1, w2, stv)
    return u >= presence_hit(tab, geo[4][k], stv)


@njit(cache=True, nogil=True)
def _behind(geo, eps, k, w1, w2, dx, dy, dz):
    """The point just behind triangle k's surface at (w1, w2) for a ray along d: the hit point
    moved by the ray epsilon against the geometric normal (which faces -d)."""
    pp, gg, _ = _interaction_row(geo[0], geo[1], geo[2], k, w1, w2, dx, dy, dz)
    e = ray_epsilon_row(pp[0], pp[1], pp[2], geo[5][k], eps[0], eps[1], eps[2])
    return pp[0] - gg[0] * e, pp[1] - gg[1] * e, pp[2] - gg[2] * e


@njit(cache=True, nogil=True)
def through_cutouts_kernel(fns, key, S, d32, prim, b1, b2, t32, geo, cut, tab, eps):
    """Camera and extension rays (state S (n, NS) of the vertex kernel, d32 (n, 3) their float32
    directions) whose closest hits prim (int32), b1, b2, t32 (float32, distance from S's origin)
    lie on absent surfaces: the first present surface behind them, or a miss (prim -1), written
    in place, with t32 still measured from the ray's origin (so the vertex kernel counts the
    lights crossed on the way as on one segment). Returns the number of rays traced."""
    scene, fn = fns[0], fns[1]
    rec = aligned_record(RAYHIT_WORDS, 64)
    rec_i = rec.view(np.int32)
    traced = 0
    tri_mat = geo[4]
    stv = np.empty(geo[3].shape[2])
    for r in range(prim.shape[0]):
        k = prim[r]
        if k < 0 or not cut[tri_mat[k]]:
            continue
        w1 = float(b1[r])
        w2 = float(b2[r])
        t_hit = float(t32[r])
        dx, dy, dz = S[r, D], S[r, D + 1], S[r, D + 2]
        for q in range(CUTOUT_PASSES):
            u = splitmix_u01(key, r * CUTOUT_PASSES + q + 1)
            if not (cut[tri_mat[k]] and _absent(geo, tab, k, w1, w2, u, stv)):
                break
            ox, oy, oz = _behind(geo, eps, k, w1, w2, dx, dy, dz)
            t0 = (ox - S[r, O]) * dx + (oy - S[r, O + 1]) * dy + (oz - S[r, O + 2]) * dz
            far = min(max(S[r, TMAX] - t0, 0.0), 1e37)
            set_ray(rec, rec_i, 0, 1, ox, oy, oz, d32[r, 0], d32[r, 1], d32[r, 2], 0.0, far, -1)
            rtc_intersect1(fn, scene, rec)
            traced += 1
            if rec_i[HIT_GEOM] == INVALID_ID:
                k = -1
                break
            k = rec_i[HIT_PRIM]
            w1 = float(rec[HIT_U])
            w2 = float(rec[HIT_V])
            t_hit = t0 + rec[RAY_TFAR]
        prim[r] = k
        b1[r] = w1
        b2[r] = w2
        t32[r] = t_hit
    return traced


@njit(cache=True, nogil=True)
def shadow_cutouts_kernel(fns, key, sh_o, sh_d, sh_t, geo, cut, tab, eps, blocked):
    """blocked[i] (bool) for shadow rays sh_o, sh_d (k, 3), sh_t (k,) (float32, origins already
    offset) that see cut-outs as camera rays do: clear where an any-hit query finds nothing,
    else walked through their closest hits until a present surface (blocked) or the far limit
    (clear). Returns the number of closest-hit rays traced."""
    scene, fn_i, fn_o = fns
    rec = aligned_record(RAYHIT_WORDS, 64)
    rec_i = rec.view(np.int32)
    shadow = aligned_record(RAY_WORDS, 64)
    shadow_i = shadow.view(np.int32)
    traced = 0
    tri_mat = geo[4]
    stv = np.empty(geo[3].shape[2])
    for i in range(sh_o.shape[0]):
        ox, oy, oz = float(sh_o[i, 0]), float(sh_o[i, 1]), float(sh_o[i, 2])
        dx, dy, dz = float(sh_d[i, 0]), float(sh_d[i, 1]), float(sh_d[i, 2])
        t_left = float(sh_t[i])
        set_ray(shadow, shadow_i, 0, 1, ox, oy, oz, dx, dy, dz, 0.0, t_left, -1)
        rtc_occluded1(fn_o, scene, shadow)
        b = shadow[RAY_TFAR] == -math.inf
        q = 0
        while b and q < CUTOUT_PASSES and t_left > 0.0:
            set_ray(rec, rec_i, 0, 1, ox, oy, oz, dx, dy, dz, 0.0, t_left, -1)
            rtc_intersect1(fn_i, scene, rec)
            traced += 1
            if rec_i[HIT_GEOM] == INVALID_ID:
                b = False
                break
            k = rec_i[HIT_PRIM]
            w1 = float(rec[HIT_U])
            w2 = float(rec[HIT_V])
            u = splitmix_u01(key, i * CUTOUT_PASSES + q + 1)
            if not (cut[tri_mat[k]] and _absent(geo, tab, k, w1, w2, u, stv)):
                break  # a present surface
            nx, ny, nz = _behind(geo, eps, k, w1, w2, dx, dy, dz)
            t_left -= (nx - ox) * dx + (ny - oy) * dy + (nz - oz) * dz
            ox, oy, oz = nx, ny, nz
            q += 1
            # Past the last absent surface with no budget or distance left: clear, as the
            # general path leaves such rays.
            b = q < CUTOUT_PASSES and t_left > 0.0
        blocked[i] = b
    return traced


guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/accel.py", *guarded_sources("renderer.materials", "renderer.integrators._vertex_kernels")])
