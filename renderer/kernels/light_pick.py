"""The lighting services per row, for compiled integrators: pick a light, replay a pick's pmf,
and find the lights a ray crosses.

The numpy lighting services (renderer/light_samplers) pick for a whole batch; the fast path's
vertex kernel (renderer/integrators/_vertex_kernels.py) picks one row at a time with the same
numbers. Each service's tables travel as one record, ``PickTables``
(renderer/light_samplers/__init__.py ``pick_tables`` builds it), a tuple:

    (mode, cand, pmf, alias_q, alias_i, p_inf, infinite, is_inf, slot, depth, trail,
     pair_next, root_light, root_c, root_b, pair_c, pair_b, boxes)

* mode: EXHAUSTIVE, UNIFORM, POWER or BVH (below);
* cand (k,) int64: the uniform service's candidates (lights with power > 0);
* pmf (count,) float64: the pmf of every global light for the uniform and power services
  (UniformLightSampler._pmf, AliasTable.pmf; zeros for a power service with no power);
* alias_q, alias_i (count,): the power service's alias table (sampling.AliasTable), empty when
  no light has power;
* p_inf ... pair_b: BVHLightSampler's traversal tables (renderer/kernels/light_bvh.py), the
  tree also serving ``crossed_row`` for the uniform and power services;
* boxes (P, 2, 6) float64: the AABB of each node of the tree's sibling pairs
  (light_bvh.node_boxes_kernel), which ``crossed_row`` walks.

Each formula is the numpy service's own: ``pick_row`` reproduces UniformLightSampler.sample
and AliasTable.sample on one u, and calls light_bvh.bvh_pick_row, the function behind
BVHLightSampler.sample; ``pick_pmf_row`` reads the same pmf tables or calls bvh_pmf_row.
They are compiled without reference counting (``_nrt=False``; light_bvh.py says why: the
record's 18 arrays cost ~0.4 us of atomic increments and decrements per call otherwise).
numba keys this file's cache on it alone, so guard_cache (end of file) flushes it when
light_bvh.py changes.
"""

from __future__ import annotations

from numba import njit

from renderer.kernels import guard_cache, module_dispatchers
from renderer.kernels.light_bvh import bvh_crossed_row, bvh_pick_row, bvh_pmf_row

EXHAUSTIVE = 0
UNIFORM = 1
POWER = 2
BVH = 3
MODES = {"exhaustive": EXHAUSTIVE, "uniform": UNIFORM, "power": POWER, "bvh": BVH}


@njit(cache=True, nogil=True, _nrt=False)
def pick_row(sp, u, px, py, pz, nx, ny, nz):
    """One light for a shading point (px, py, pz) with shading normal (nx, ny, nz) from u in
    [0, 1): (global light index, pmf), pmf 0 where the service gives no light (not for
    EXHAUSTIVE, which does not pick)."""
    mode = sp[0]
    if mode == UNIFORM:
        cand = sp[1]
        k = cand.shape[0]
        if k == 0:
            return 0, 0.0
        return cand[min(int(u * k), k - 1)], 1.0 / k
    if mode == POWER:
        q = sp[3]
        n = q.shape[0]
        if n == 0:
            return 0, 0.0
        x = u * n
        i = min(int(x), n - 1)
        j = i if x - i < q[i] else sp[4][i]
        return j, sp[2][j]
    if mode == BVH:
        li, pr, _uu, _tree = bvh_pick_row(u, px, py, pz, nx, ny, nz, True, sp[5], sp[6], sp[11], sp[12], sp[13],
                                          sp[14], sp[15], sp[16])
        return li, pr
    return 0, 0.0


@njit(cache=True, nogil=True, _nrt=False)
def pick_pmf_row(sp, li, px, py, pz, nx, ny, nz):
    """The probability that pick_row picks global light li at the point (px, py, pz) with
    shading normal (nx, ny, nz); 1 for EXHAUSTIVE (every light at every vertex)."""
    mode = sp[0]
    if mode == UNIFORM or mode == POWER:
        return sp[2][li]
    if mode == BVH:
        return bvh_pmf_row(li, px, py, pz, nx, ny, nz, True, sp[5], sp[7], sp[6].shape[0], sp[8], sp[9], sp[10],
                           sp[11], sp[12], sp[13], sp[14], sp[15], sp[16])
    return 1.0


@njit(cache=True, nogil=True, _nrt=False)
def crossed_row(sp, ox, oy, oz, dx, dy, dz, t_max, stack, out):
    """The finite lights the segment o + t d, 0 <= t <= t_max, may cross: their global indices
    into out[:k], k returned, a superset the caller confirms with each light's exact hit test
    (light_bvh.bvh_crossed_row on the record's tree; stack, out: its scratch)."""
    return bvh_crossed_row(ox, oy, oz, dx, dy, dz, t_max, sp[11], sp[12], sp[17], stack, out)


guard_cache(__name__, module_dispatchers(globals()), ["renderer/kernels/light_bvh.py"])
