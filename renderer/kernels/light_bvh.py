"""Light BVH traversal (``renderer.light_samplers.bvh``): pick a light, and replay a pick's pmf.

One loop over rows; each row descends from the root to a leaf alone, evaluating the importance
of the two children of each node it visits (``_importance``) and going left with probability
I_left / (I_left + I_right). The numpy traversal this replaces moved every still-descending row
one level per pass, with a few dozen (2, k)-array operations per level and a compaction when
rows finished: 2.3-3.5 us of CPU per pick on the fireflies stage (mean depth 13), most of it
numpy dispatch and temporaries, against ~0.5 us here (0.4 us per pmf replay; measured on
68722 picks recorded from a fireflies render; bench/bench_light_samplers.py build gives the
same on random points).

**What made it fast.** (1) The importance is branch-free where it used to branch: the emission
cone test, the incidence factor and the choice between a child's cosines are selects, not
ifs, which halved the cost of a pmf replay (0.74 -> 0.40 us): with an early ``return 0`` LLVM
kept every data-dependent test a branch, and those mispredict. (2) Cosines and sines are
carried multiplied by the distance d (``_importance``), so the square roots and the one
division depend on d^2 only and run side by side instead of one after the other (0.81 ->
0.74 us per replay, before (1)). (3) The
descent decides a branch with a multiplication (u (I_0 + I_1) >= I_0) instead of waiting
for the division I_0 / (I_0 + I_1), which only enters the pmf, and it walks sibling pairs:
``pair_next`` gives the pair of the chosen child's children (or its light) directly, one
dependent load per level instead of two. (Tried too, no measurable gain: a 64-byte record
per node, centres, bounds and links in one cache line; a branch-free choice of the child;
doing without d = sqrt(d^2). numba's error_model="numpy", which drops the zero-division
checks, made picks slower.)

**Exactness.** ``bvh_sample_kernel`` and ``bvh_pmf_kernel`` reach every branching probability
through the same function (``_pair_importances``) with the same scalar float64 operations in
the same order (fastmath is off, so LLVM neither contracts nor reassociates), and multiply
the probabilities in the same order: pmf(ctx, sample(ctx, u).index) equals the pmf that sample
reported, bit for bit.

**Node tables** (built in bvh.py ``_finish``): ``pair_c`` (P, 2, 3) float64 node centres and
``pair_b`` (P, 2, 8) float32 bounds of the sibling pair p = (c - 1) / 2 of children c, c + 1
(children are allocated in pairs after the root), one pair's values contiguous; ``root_c``
(1, 1, 3) and ``root_b`` (1, 1, 8) the root's. Bounds columns: r = |diagonal| / 2 (the
bounding sphere's radius), w (3) the cone axis, phi, cos theta_o, sin theta_o, cos theta_e,
each rounded the conservative way to float32 (bvh.py ``_traversal_columns``). ``pair_next``
(P, 2) int32: for each node of a pair, the pair of its own children, or -1 - its global light
when it is a leaf; ``root_light`` the global light of a one-light tree (no pairs), else -1.
``trail`` (m, words) uint64 root-to-leaf bits (0 = first child) and ``depth`` (m,) int32 per
tree light, ``slot`` (count,) int32 the tree light of each global light (-1: not in the tree).

The row functions (``bvh_pick_row``, ``bvh_pmf_row``, ``bvh_crossed_row`` and what they call)
are compiled without numba's reference counting (``_nrt=False``: they allocate nothing and
only borrow their arrays): with it, every call increfs and decrefs each array argument with
atomic operations that numba could not prune across the branches, ~20 ns per array per call,
which made a uniform pick through the service record cost ~170-400 ns instead of ~2 ns and a
BVH pick ~830 ns instead of ~280 (measured from a compiled loop on the 60-light test set).

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
# picks, measured when they still branched. (Walking two or four rows down together, to overlap their latency chains,
# was measured too: slower, 1.2-1.7 us per pick, from the per-lane state.)
@njit(cache=True, nogil=True, inline="always")
def _importance(px, py, pz, nx, ny, nz, has_n, c, b, pair, side):
    """pbrt-v4's LightBounds::Importance with the d^2 clamp fixed, for one point and the node
    (pair, side) of the tables c (P, 2, 3) float64 and b (P, 2, 8) float32.

    The point is (px, py, pz); (nx, ny, nz) its shading normal, used for the clamped-incidence
    factor when has_n. Returns phi cos(theta') / max(d^2, CLAMP_R2 r^2) * max(cos(theta_i'), 0),
    0 when theta' >= theta_e (see bvh.py's module docstring for the angles).

    Every cosine and sine is carried multiplied by d = |p - centre| (d cos_w = w . (p - c),
    d sin_w = sqrt(d^2 - (w . (p - c))^2), ...), so that neither the unit direction nor 1 / d
    is needed: the square roots (d, d cos_b, d sin_i, d sin_w) and the one division (by
    d^2 d^2 max(d^2, clamp)) depend on d^2 and a dot product only and run side by side.
    Data-dependent tests are written as selects (``x if c else y`` on values already
    computed), which LLVM compiles without branches; see the module docstring.
    """
    dx = px - c[pair, side, 0]
    dy = py - c[pair, side, 1]
    dz = pz - c[pair, side, 2]
    r = np.float64(b[pair, side, 0])      # bounding-sphere radius, rounded up to float32
    r2 = r * r
    d2_true = dx * dx + dy * dy + dz * dz
    d2 = max(d2_true, D2_MIN)
    d = math.sqrt(d2)
    # 1 / (d^2 for the cosine of theta', d^2 for the incidence cosine, the clamped d^2).
    inv_den = 1.0 / (d2 * d2 * max(d2_true, CLAMP_R2 * r2, D2_MIN))
    # theta_b: half-angle of the cone of directions from the point to the bounding sphere,
    # the whole sphere when the point is inside it. cb = d cos_b, sb = d sin_b.
    inside = d2_true < r2
    cb = -d if inside else math.sqrt(max(d2 - r2, 0.0))
    sb = 0.0 if inside else r
    # theta_x = max(theta_w - theta_o, 0): xc = d cos_x, xs = d sin_x.
    wd = (np.float64(b[pair, side, 1]) * dx + np.float64(b[pair, side, 2]) * dy
          + np.float64(b[pair, side, 3]) * dz)
    cos_o = np.float64(b[pair, side, 5])
    sin_o = np.float64(b[pair, side, 6])
    sw = math.sqrt(max(d2 - wd * wd, 0.0))
    in_cone = wd > cos_o * d
    xc = d if in_cone else wd * cos_o + sw * sin_o
    xs = 0.0 if in_cone else max(sw * cos_o - wd * sin_o, 0.0)
    # theta' = max(theta_x - theta_b, 0): pc = d^2 cos(theta').
    pc = d2 if xc > cb else xc * cb + xs * sb
    # Clamped incidence at the shading normal (the light is toward c - p from the point):
    # ic = d^2 cos of max(theta_i - theta_b, 0), clamped at 0 (padded against rounding).
    ci = -(nx * dx + ny * dy + nz * dz)
    si = math.sqrt(max(d2 - ci * ci, 0.0))
    ic = d2 if ci > cb else ci * cb + si * sb
    ic = min(max(ic + INCIDENCE_PAD * d2, 0.0), d2)
    ic = ic if has_n else d2
    imp = np.float64(b[pair, side, 4]) * pc * ic * inv_den
    imp = min(max(imp, 0.0), MAX_IMPORTANCE)
    # 0 outside the emission cone: theta' >= theta_e.
    return imp if pc > np.float64(b[pair, side, 7]) * d2 else 0.0


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
def _pair_importances(pair, px, py, pz, nx, ny, nz, has_n, pair_c, pair_b):
    """Importances (i0, i1) of the two nodes of sibling pair ``pair``, and the probability of
    the first, i0 / (i0 + i1) (0 where both are 0). The only place either traversal computes
    a branching probability."""
    i0 = _importance(px, py, pz, nx, ny, nz, has_n, pair_c, pair_b, pair, 0)
    i1 = _importance(px, py, pz, nx, ny, nz, has_n, pair_c, pair_b, pair, 1)
    tot = i0 + i1
    p0 = i0 / tot if tot > 0.0 else 0.0
    return i0, i1, tot, p0


@njit(cache=True, nogil=True, _nrt=False)
def _tree_alive(px, py, pz, nx, ny, nz, has_n, root_light, root_c, root_b, pair_c, pair_b):
    """Can the tree give a light here: the root's children do not both have importance 0 (for a
    one-light tree, that light's importance is positive)."""
    if root_light >= 0:
        return _importance(px, py, pz, nx, ny, nz, has_n, root_c, root_b, 0, 0) > 0.0
    if pair_c.shape[0] == 0:
        return False
    return _pair_importances(0, px, py, pz, nx, ny, nz, has_n, pair_c, pair_b)[2] > 0.0


@njit(cache=True, nogil=True)
def bvh_importance_kernel(p, nrm, has_n, c, b, out):
    """Importance (k,) of k (point, node) pairs: p, nrm (k, 3) float64, has_n (k,) bool,
    c (k, 1, 3) float64 and b (k, 1, 8) float32 node columns (one node per row)."""
    for row in range(p.shape[0]):
        out[row] = _importance(p[row, 0], p[row, 1], p[row, 2], nrm[row, 0], nrm[row, 1], nrm[row, 2],
                               has_n[row], c, b, row, 0)


@njit(cache=True, nogil=True, _nrt=False)
def bvh_pick_row(ur, px, py, pz, nx, ny, nz, hn, p_inf, infinite, pair_next, root_light, root_c, root_b, pair_c,
                 pair_b):
    """One row of BVHLightSampler.sample: (global light, pmf, remapped u, tree) for u = ur in
    [0, 1) at the point (px, py, pz) with normal (nx, ny, nz) (used where hn; see _normal).
    Infinite lights (global indices ``infinite``) are picked with probability p_inf uniformly
    among themselves, or with probability 1 where the tree cannot give a light; otherwise the
    tree is descended reusing u. pmf 0 (light 0): no light. tree: the light came from the tree,
    and the remapped u (u rescaled into that leaf's interval, a fresh uniform in [0, 1)) is
    meaningful. root_light: the global light of a one-light tree, else -1."""
    k_inf = infinite.shape[0]
    if k_inf > 0:
        p_row = p_inf
        if not _tree_alive(px, py, pz, nx, ny, nz, hn, root_light, root_c, root_b, pair_c, pair_b):
            p_row = 1.0
        if ur < p_row:
            j = min(int(ur / p_row * k_inf), k_inf - 1)
            return infinite[j], p_row / k_inf, ur, False
    if not (root_light >= 0 or pair_c.shape[0] > 0):
        return 0, 0.0, ur, False
    uu = min((ur - p_inf) / (1.0 - p_inf), ONE_MINUS_EPSILON)
    pr = 1.0 - p_inf
    if root_light >= 0:
        if _importance(px, py, pz, nx, ny, nz, hn, root_c, root_b, 0, 0) > 0.0:
            return root_light, pr, uu, True
        return 0, 0.0, ur, False
    pair = 0
    side = 0
    while True:
        i0, i1, tot, p0 = _pair_importances(pair, px, py, pz, nx, ny, nz, hn, pair_c, pair_b)
        if not tot > 0.0:
            return 0, 0.0, ur, False
        # Go to the second child where u tot >= i0 (and it can be picked), and rescale the
        # chosen sub-interval of u to [0, 1): one multiplication decides the branch, so
        # the next level need not wait for a division (p0 only enters the pmf).
        t = uu * tot
        if t >= i0 and i1 > 0.0:
            side = 1
            pr = pr * (1.0 - p0)
            uu = (t - i0) / i1
        else:
            side = 0
            pr = pr * p0
            uu = t / i0
        uu = min(uu, ONE_MINUS_EPSILON)
        nxt = pair_next[pair, side]
        if nxt < 0:
            break
        pair = nxt
    if pr > 0.0:
        return -1 - pair_next[pair, side], pr, uu, True
    return 0, 0.0, ur, False


@njit(cache=True, nogil=True)
def bvh_sample_kernel(u, p, ng, ns, p_inf, infinite, pair_next, root_light, root_c, root_b, pair_c, pair_b,
                      out_index, out_pmf, out_u):
    """BVHLightSampler.sample for rows of u (n,) in [0, 1) at points p with geometric and
    shading normals ng, ns (n, 3) (see _normal): bvh_pick_row per row. Writes the global index
    and the pmf (0, index 0: no light), and on rows given a tree light, out_u: the remapped u
    (other rows of out_u are left as they are)."""
    for row in range(u.shape[0]):
        nx, ny, nz, hn = _normal(ng, ns, row)
        li, pr, uu, tree = bvh_pick_row(u[row], p[row, 0], p[row, 1], p[row, 2], nx, ny, nz, hn, p_inf, infinite,
                                        pair_next, root_light, root_c, root_b, pair_c, pair_b)
        out_index[row] = li
        out_pmf[row] = pr
        if tree:
            out_u[row] = uu


@njit(cache=True, nogil=True, _nrt=False)
def bvh_pmf_row(li, px, py, pz, nx, ny, nz, hn, p_inf, is_inf, k_inf, slot, depth, trail, pair_next, root_light,
                root_c, root_b, pair_c, pair_b):
    """One row of BVHLightSampler.pmf: the probability that bvh_pick_row picks global light li
    at the point (px, py, pz) with normal (nx, ny, nz) (used where hn), replaying the light's
    root-to-leaf trail with the same arithmetic. is_inf (count,) bool marks the infinite lights
    (k_inf of them)."""
    if li < 0 or li >= slot.shape[0]:
        return 0.0
    if is_inf[li]:
        if _tree_alive(px, py, pz, nx, ny, nz, hn, root_light, root_c, root_b, pair_c, pair_b):
            return p_inf / k_inf
        return 1.0 / k_inf
    s = slot[li]
    if s < 0:
        return 0.0
    pr = 1.0 - p_inf
    if root_light >= 0:
        return pr if _importance(px, py, pz, nx, ny, nz, hn, root_c, root_b, 0, 0) > 0.0 else 0.0
    pair = 0
    for level in range(depth[s]):
        side = (trail[s, level >> 6] >> np.uint64(level & 63)) & np.uint64(1)
        i0, i1, tot, p0 = _pair_importances(pair, px, py, pz, nx, ny, nz, hn, pair_c, pair_b)
        if not tot > 0.0:
            return 0.0
        if side:
            pr = pr * (1.0 - p0)
        else:
            pr = pr * p0
        pair = pair_next[pair, side]
    return pr


@njit(cache=True, nogil=True)
def bvh_pmf_kernel(index, p, ng, ns, p_inf, is_inf, k_inf, slot, depth, trail, pair_next, root_light, root_c,
                   root_b, pair_c, pair_b, out):
    """BVHLightSampler.pmf: bvh_pmf_row for each global light index (n,) at p, ng, ns."""
    for row in range(index.shape[0]):
        nx, ny, nz, hn = _normal(ng, ns, row)
        out[row] = bvh_pmf_row(index[row], p[row, 0], p[row, 1], p[row, 2], nx, ny, nz, hn, p_inf, is_inf, k_inf,
                               slot, depth, trail, pair_next, root_light, root_c, root_b, pair_c, pair_b)


@njit(cache=True, nogil=True)
def node_boxes_kernel(pair_next, light_lo, light_hi, out):
    """The AABB of every node of the sibling pairs, out (P, 2, 6) float64 (lo, hi), from the
    AABBs light_lo, light_hi (count, 3) of the global lights at the leaves: children pairs come
    after their parents (bvh.py ``_finish``), so one backward sweep unions them bottom-up."""
    for pair in range(pair_next.shape[0] - 1, -1, -1):
        for side in range(2):
            nxt = pair_next[pair, side]
            for k in range(3):
                if nxt < 0:
                    out[pair, side, k] = light_lo[-1 - nxt, k]
                    out[pair, side, 3 + k] = light_hi[-1 - nxt, k]
                else:
                    out[pair, side, k] = min(out[nxt, 0, k], out[nxt, 1, k])
                    out[pair, side, 3 + k] = max(out[nxt, 0, 3 + k], out[nxt, 1, 3 + k])


@njit(cache=True, nogil=True, _nrt=False)
def _box_crossed(ox, oy, oz, ix, iy, iz, t_max, boxes, pair, side):
    """Whether the segment o + t d, 0 <= t <= t_max, meets the AABB of node (pair, side) (slab
    test with i = 1 / d, a zero component of d replaced by a tiny one; boxes padded outward by
    ``node_boxes``, and the caller confirms each light exactly)."""
    ax = (boxes[pair, side, 0] - ox) * ix
    bx = (boxes[pair, side, 3] - ox) * ix
    ay = (boxes[pair, side, 1] - oy) * iy
    by = (boxes[pair, side, 4] - oy) * iy
    az = (boxes[pair, side, 2] - oz) * iz
    bz = (boxes[pair, side, 5] - oz) * iz
    t0 = max(max(min(ax, bx), min(ay, by)), max(min(az, bz), 0.0))
    t1 = min(min(max(ax, bx), max(ay, by)), min(max(az, bz), t_max))
    return t0 <= t1


@njit(cache=True, nogil=True, _nrt=False)
def bvh_crossed_row(ox, oy, oz, dx, dy, dz, t_max, pair_next, root_light, boxes, stack, out):
    """The tree lights whose node boxes the segment o + t d, 0 <= t <= t_max, meets: their
    global indices into out[:k], k returned (every light the segment crosses is among them; the
    caller runs the exact test). A depth-first walk of the sibling pairs, pruning subtrees whose
    AABB (boxes (P, 2, 6), node_boxes_kernel) the segment misses: a few dozen box tests for a
    ray that passes few lights, where a loop over the lights is O(lights). A one-light tree
    gives its light. stack: int64 scratch of at least the tree's depth + 2 entries; out: at
    least as many entries as the tree has lights."""
    if root_light >= 0:
        out[0] = root_light
        return 1
    if pair_next.shape[0] == 0:
        return 0
    ix = 1.0 / (dx if dx != 0.0 else 1e-300)
    iy = 1.0 / (dy if dy != 0.0 else 1e-300)
    iz = 1.0 / (dz if dz != 0.0 else 1e-300)
    k = 0
    top = 1
    stack[0] = 0
    while top > 0:
        top -= 1
        pair = stack[top]
        for side in range(2):
            if _box_crossed(ox, oy, oz, ix, iy, iz, t_max, boxes, pair, side):
                nxt = pair_next[pair, side]
                if nxt < 0:
                    out[k] = -1 - nxt
                    k += 1
                else:
                    stack[top] = nxt
                    top += 1
    return k
