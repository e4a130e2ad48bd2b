"""Light BVH traversal (``renderer.light_samplers.bvh``): pick a light, and replay a pick's pmf.

One loop over rows; each row descends from the root to a leaf alone, evaluating the importance
of the two children of each node it visits (``_importance``) and going left with probability
I_left / (I_left + I_right). The numpy traversal this replaces moved every still-descending row
one level per pass, with a few dozen (2, k)-array operations per level and a compaction when
rows finished: 2.3-3.5 us of CPU per pick on the fireflies stage (mean depth 13), most of it
numpy dispatch and temporaries, against ~0.9 us here, where what is left is the latency of
each level's chain of a division and two or three square roots.

**Exactness.** ``bvh_sample_kernel`` and ``bvh_pmf_kernel`` reach every branching probability
through the same function (``_first_child_prob``) with the same scalar float64 operations in
the same order (fastmath is off, so LLVM neither contracts nor reassociates), and multiply
the probabilities in the same order: pmf(ctx, sample(ctx, u).index) equals the pmf that sample
reported, bit for bit.

**Node tables** (built in bvh.py ``_finish``): ``pair_c`` (P, 2, 3) float64 node centres and
``pair_b`` (P, 2, 8) float32 bounds of the sibling pair p = (c - 1) / 2 of children c, c + 1
(children are allocated in pairs after the root), one pair's values contiguous; ``root_c``
(1, 1, 3) and ``root_b`` (1, 1, 8) the root's. Bounds columns: r = |diagonal| / 2 (the
bounding sphere's radius), w (3) the cone axis, phi, cos theta_o, sin theta_o, cos theta_e,
each rounded the conservative way to float32 (bvh.py ``_traversal_columns``). ``child`` (N,) int32 first child
(-1 for a leaf), ``leaf_light`` (N,) int32 global light of a leaf; ``trail`` (m, words) uint64
root-to-leaf bits (0 = first child) and ``depth`` (m,) int32 per tree light, ``slot`` (count,)
int32 the tree light of each global light (-1: not in the tree).

The constants below are the traversal's and live here because numba freezes globals into its
on-disk cache per defining file (see ``renderer.kernels``); the build's CONE_PAD is bvh.py's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Added to the clamped-incidence cosine so that rounding at the horizon never zeroes a light
# that is (just) above it (a missed light would get pmf 0: bias).
INCIDENCE_PAD = 1e-6
# Largest u below 1 (pbrt's OneMinusEpsilon), so a remapped u never reaches 1.
ONE_MINUS_EPSILON = 1.0 - 2.0**-53
# Importances are clamped here, and squared distances are at least D2_MIN (scene units^2), so
# that phi / d^2 and the sum of two children stay finite.
MAX_IMPORTANCE = 1e37
D2_MIN = 1e-12
# The squared distance in phi / d^2 is clamped at CLAMP_R2 * r^2, r the radius of the node's
# bounding sphere (half its AABB diagonal). pbrt-v4 clamps at |diagonal| / 2, a length compared
# with a squared length (REFERENCE.md 4.3); the unit-consistent (|diagonal| / 2)^2 is still
# too strong: inside that sphere every point gets phi / r^2 although the lights are, on
# average, nearer. 1/3 makes the leaf of a sphere light exact: its AABB half-diagonal is
# sqrt(3) rho (rho its radius), so the clamp is rho^2, and phi / d^2 (phi = 4 pi^2 rho^2 L)
# is then 4 pi times the sphere's unoccluded normal irradiance pi L rho^2 / d^2 at every point
# outside it; and 3 / r^2 is the mean of 1 / d^2 over a ball of radius r seen from its
# centre, the expected importance of lights spread through a node around the point. Measured
# at the camera's first hits (bench/bench_light_samplers.py pick --stride 2), the relative
# variance of the light choice drops from 9.6 to 2.4 on stages/fireflies and goes from 3.5 to
# 3.8 on stages/city_lights (its median from 2.0 to 1.8). Other factors (--stride 4): 1/4,
# Cycles' clamp, 2.1 and 5.4 (city, against 5.1 at 1/3); 1/10, 2.0 and 5.9; 1/100, 2.1 and
# 6.5. Distances to the bounding sphere instead of its centre were much worse (13-32, 7-13).
CLAMP_R2 = 1.0 / 3.0


# inline="always" (numba-level inlining) on the two functions of the descent: ~10 % faster
# picks, measured. (Walking two or four rows down together, to overlap their latency chains,
# was measured too: slower, 1.2-1.7 us per pick, from the per-lane state.)
@njit(cache=True, nogil=True, inline="always")
def _importance(px, py, pz, nx, ny, nz, has_n, c, b, pair, side):
    """pbrt-v4's LightBounds::Importance with the d^2 clamp fixed, for one point and the node
    (pair, side) of the tables c (P, 2, 3) float64 and b (P, 2, 8) float32.

    The point is (px, py, pz); (nx, ny, nz) its shading normal, used for the clamped-incidence
    factor when has_n. Returns phi cos(theta') / max(d^2, CLAMP_R2 r^2) * max(cos(theta_i'), 0),
    0 when theta' >= theta_e (see bvh.py's module docstring for the angles). One division and
    two square roots on the common path (the sines of theta_w and theta_i only when needed).
    """
    dx = px - c[pair, side, 0]
    dy = py - c[pair, side, 1]
    dz = pz - c[pair, side, 2]
    r = np.float64(b[pair, side, 0])      # bounding-sphere radius, rounded up to float32
    r2 = r * r
    d2_true = dx * dx + dy * dy + dz * dz
    inv_d2 = 1.0 / max(d2_true, D2_MIN)
    inv_d = math.sqrt(inv_d2)
    # wi: unit direction from the node centre toward the point (zero when they coincide).
    dx *= inv_d
    dy *= inv_d
    dz *= inv_d
    cos_w = (np.float64(b[pair, side, 1]) * dx + np.float64(b[pair, side, 2]) * dy
             + np.float64(b[pair, side, 3]) * dz)
    # theta_b: half-angle of the cone of directions from the point to the bounding sphere,
    # the whole sphere when the point is inside it.
    if d2_true < r2:
        cos_b = -1.0
        sin_b = 0.0
    else:
        sin_b = min(r * inv_d, 1.0)
        cos_b = math.sqrt(max(1.0 - sin_b * sin_b, 0.0))
    # theta_x = max(theta_w - theta_o, 0).
    cos_o = np.float64(b[pair, side, 5])
    if cos_w > cos_o:
        cos_x = 1.0
        sin_x = 0.0
    else:
        sin_o = np.float64(b[pair, side, 6])
        sin_w = math.sqrt(max(1.0 - cos_w * cos_w, 0.0))
        cos_x = cos_w * cos_o + sin_w * sin_o
        sin_x = max(sin_w * cos_o - cos_w * sin_o, 0.0)
    # theta' = max(theta_x - theta_b, 0).
    if cos_x > cos_b:
        cos_p = 1.0
    else:
        cos_p = cos_x * cos_b + sin_x * sin_b
    if not cos_p > np.float64(b[pair, side, 7]):
        return 0.0
    # phi cos(theta') / max(d^2, CLAMP_R2 r^2, D2_MIN), dividing only where the clamp acts.
    clamp = max(CLAMP_R2 * r2, D2_MIN)
    if d2_true >= clamp:
        imp = np.float64(b[pair, side, 4]) * cos_p * inv_d2
    else:
        imp = np.float64(b[pair, side, 4]) * cos_p / clamp
    if has_n:
        # Clamped incidence at the shading normal (the light is toward -wi from the point):
        # cos of max(theta_i - theta_b, 0), clamped at 0.
        cos_i = -(nx * dx + ny * dy + nz * dz)
        if cos_i > cos_b:
            cos_ib = 1.0
        else:
            sin_i = math.sqrt(max(1.0 - cos_i * cos_i, 0.0))
            cos_ib = cos_i * cos_b + sin_i * sin_b
        cos_ib = min(max(cos_ib + INCIDENCE_PAD, 0.0), 1.0)
        imp *= cos_ib
    return min(max(imp, 0.0), MAX_IMPORTANCE)


@njit(cache=True, nogil=True)
def _normal(ng, ns, row):
    """The normal for the incidence bound at a row: the shading normal ns, else the geometric
    ng, and whether there is one (both rows zero: no incidence factor)."""
    x, y, z = ns[row, 0], ns[row, 1], ns[row, 2]
    if x != 0.0 or y != 0.0 or z != 0.0:
        return x, y, z, True
    x, y, z = ng[row, 0], ng[row, 1], ng[row, 2]
    return x, y, z, (x != 0.0 or y != 0.0 or z != 0.0)


@njit(cache=True, nogil=True, inline="always")
def _first_child_prob(node, px, py, pz, nx, ny, nz, has_n, child, pair_c, pair_b):
    """(probability of the first child of interior node ``node``, False where both children
    have importance 0). The only place either traversal computes a branching probability."""
    pair = (child[node] - 1) >> 1
    i0 = _importance(px, py, pz, nx, ny, nz, has_n, pair_c, pair_b, pair, 0)
    i1 = _importance(px, py, pz, nx, ny, nz, has_n, pair_c, pair_b, pair, 1)
    tot = i0 + i1
    if tot > 0.0:
        return i0 / tot, True
    return 0.0, False


@njit(cache=True, nogil=True)
def _tree_alive(px, py, pz, nx, ny, nz, has_n, child, root_c, root_b, pair_c, pair_b):
    """Can the tree give a light here: the root's children do not both have importance 0 (for a
    one-light tree, that light's importance is positive)."""
    if child.shape[0] == 0:
        return False
    if child[0] < 0:
        return _importance(px, py, pz, nx, ny, nz, has_n, root_c, root_b, 0, 0) > 0.0
    return _first_child_prob(0, px, py, pz, nx, ny, nz, has_n, child, pair_c, pair_b)[1]


@njit(cache=True, nogil=True)
def bvh_importance_kernel(p, nrm, has_n, c, b, out):
    """Importance (k,) of k (point, node) pairs: p, nrm (k, 3) float64, has_n (k,) bool,
    c (k, 1, 3) float64 and b (k, 1, 8) float32 node columns (one node per row)."""
    for row in range(p.shape[0]):
        out[row] = _importance(p[row, 0], p[row, 1], p[row, 2], nrm[row, 0], nrm[row, 1], nrm[row, 2],
                               has_n[row], c, b, row, 0)


@njit(cache=True, nogil=True)
def bvh_sample_kernel(u, p, ng, ns, p_inf, infinite, child, leaf_light, root_c, root_b, pair_c, pair_b,
                      out_index, out_pmf, out_u):
    """BVHLightSampler.sample for rows of u (n,) in [0, 1) at points p with geometric and
    shading normals ng, ns (n, 3) (see _normal). Infinite lights (global indices ``infinite``)
    are picked with probability p_inf uniformly among themselves, or with probability 1 where
    the tree cannot give a light; otherwise the tree is descended reusing u. Writes the global index and the pmf (0, index 0:
    no light), and on rows given a tree light, out_u: u rescaled into that leaf's interval (a
    fresh uniform in [0, 1); other rows of out_u are left as they are)."""
    k_inf = infinite.shape[0]
    has_tree = child.shape[0] > 0
    for row in range(u.shape[0]):
        out_index[row] = 0
        out_pmf[row] = 0.0
        px, py, pz = p[row, 0], p[row, 1], p[row, 2]
        nx, ny, nz, hn = _normal(ng, ns, row)
        ur = u[row]
        if k_inf > 0:
            p_row = p_inf
            if not _tree_alive(px, py, pz, nx, ny, nz, hn, child, root_c, root_b, pair_c, pair_b):
                p_row = 1.0
            if ur < p_row:
                j = min(int(ur / p_row * k_inf), k_inf - 1)
                out_index[row] = infinite[j]
                out_pmf[row] = p_row / k_inf
                continue
        if not has_tree:
            continue
        uu = min((ur - p_inf) / (1.0 - p_inf), ONE_MINUS_EPSILON)
        pr = 1.0 - p_inf
        node = 0
        if child[0] < 0:
            if _importance(px, py, pz, nx, ny, nz, hn, root_c, root_b, 0, 0) > 0.0:
                out_index[row] = leaf_light[0]
                out_pmf[row] = pr
                out_u[row] = uu
            continue
        while child[node] >= 0:
            p0, ok = _first_child_prob(node, px, py, pz, nx, ny, nz, hn, child, pair_c, pair_b)
            if not ok:
                pr = 0.0
                break
            if uu >= p0:
                q = 1.0 - p0
                uu = uu - p0
                node = child[node] + 1
            else:
                q = p0
                node = child[node]
            pr = pr * q
            # Reuse u: rescale the chosen sub-interval to [0, 1).
            uu = min(uu / (q if q > 0.0 else 1.0), ONE_MINUS_EPSILON)
        if pr > 0.0:
            out_index[row] = leaf_light[node]
            out_pmf[row] = pr
            out_u[row] = uu


@njit(cache=True, nogil=True)
def bvh_pmf_kernel(index, p, ng, ns, p_inf, is_inf, k_inf, slot, depth, trail, child, root_c, root_b,
                   pair_c, pair_b, out):
    """BVHLightSampler.pmf: the probability (n,) that bvh_sample_kernel picks global light
    index (n,) at p, ng, ns, replaying the light's root-to-leaf trail with the same
    arithmetic. is_inf (count,) bool marks the infinite lights (k_inf of them)."""
    count = slot.shape[0]
    for row in range(index.shape[0]):
        out[row] = 0.0
        li = index[row]
        if li < 0 or li >= count:
            continue
        px, py, pz = p[row, 0], p[row, 1], p[row, 2]
        nx, ny, nz, hn = _normal(ng, ns, row)
        if is_inf[li]:
            if _tree_alive(px, py, pz, nx, ny, nz, hn, child, root_c, root_b, pair_c, pair_b):
                out[row] = p_inf / k_inf
            else:
                out[row] = 1.0 / k_inf
            continue
        s = slot[li]
        if s < 0:
            continue
        pr = 1.0 - p_inf
        if child[0] < 0:
            if _importance(px, py, pz, nx, ny, nz, hn, root_c, root_b, 0, 0) > 0.0:
                out[row] = pr
            continue
        node = 0
        for level in range(depth[s]):
            right = (trail[s, level >> 6] >> np.uint64(level & 63)) & np.uint64(1)
            p0, ok = _first_child_prob(node, px, py, pz, nx, ny, nz, hn, child, pair_c, pair_b)
            if not ok:
                pr = 0.0
                break
            if right:
                pr = pr * (1.0 - p0)
                node = child[node] + 1
            else:
                pr = pr * p0
                node = child[node]
        out[row] = pr
