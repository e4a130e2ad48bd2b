"""The compiled row functions of renderer.lights.analytic (rect_F, polygon_F, sphere_F, disk_F,
ellipse_F, dome_constant_F) against the numpy implementation they replaced, and their use from
other compiled code.

The reference (data/numpy_reference.npz, written by make_numpy_reference.py from the numpy
module at commit 0332038) holds 800 randomised configurations per kind from configs.py, half of
them moved by a random rigid motion: every placement mode (grazing down to 1e-12 sizes above the
plane, in the plane, behind, within 1e-10 of an edge, corner or rim, very close, far up to 1e12
sizes) and normal mode (straddling the light, tangent to it, facing, away), scales 1e-6..1e6, and
for spheres straddling, tiny and far, near the surface, on it and inside.

Acceptance per row: |G − G_numpy| ≤ 1e-10·G_numpy + 4·S, where S is how much G itself moves when
every input coordinate is perturbed by up to 8 ulps (the max over 6 random perturbations): the
two implementations evaluate the same formulas in a different order (scalar loops instead of
array reductions; the ellipse's breakpoints come from another root finder), so where the inputs
determine G only to rounding (a horizon slicing a light, a point on a sphere's surface) they may
differ by that much, and nowhere else. The test checks that S is small for almost every row, so
the tolerance is not vacuous: 69-81 % of the non-zero rows by kind must agree to 1e-9 or better (in
fact 43-85 % agree to the last bit, and the median relative difference is below 1e-14).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from renderer.lights import analytic as an

REF = np.load(Path(__file__).resolve().parent / "data" / "numpy_reference.npz")
EPS = float(np.finfo(np.float64).eps)

# kind -> (numpy API function, argument keys, reference key, keyword arguments)
CASES = {
    "rect": (an.projected_solid_angle_rect, ("p", "nrm", "c", "ex", "ey", "en"), "G"),
    "disk": (an.projected_solid_angle_disk, ("p", "nrm", "c", "en", "R"), "G"),
    "ellipse": (an.projected_solid_angle_ellipse, ("p", "nrm", "c", "e1", "e2", "en"), "G"),
    "triangle_two_sided": (an.projected_solid_angle_polygon, ("p", "nrm", "V"), "G2"),
    "triangle_one_sided": (an.projected_solid_angle_polygon, ("p", "nrm", "V", "en"), "G1"),
    "pentagon_two_sided": (an.projected_solid_angle_polygon, ("p", "nrm", "V"), "G2"),
    "pentagon_one_sided": (an.projected_solid_angle_polygon, ("p", "nrm", "V", "en"), "G1"),
    "sphere": (an.projected_solid_angle_sphere, ("p", "nrm", "c", "R"), "G"),
}
PREFIX = {"triangle_two_sided": "polygon3", "triangle_one_sided": "polygon3", "pentagon_two_sided": "polygon5",
          "pentagon_one_sided": "polygon5"}


def _case(kind):
    fn, keys, gkey = CASES[kind]
    pre = PREFIX.get(kind, kind)
    return fn, [REF[f"{pre}_{k}"] for k in keys], REF[f"{pre}_{gkey}"], REF[f"{pre}_mode"]


def _input_spread(fn, args, g, rng, trials=6):
    """Max |G(inputs·(1 + 8ε·U(−1, 1))) − G| over a few random perturbations of every input."""
    spread = np.zeros_like(g)
    for _ in range(trials):
        moved = [a * (1.0 + 8.0 * EPS * rng.uniform(-1.0, 1.0, np.shape(a))) for a in args]
        spread = np.maximum(spread, np.abs(fn(*moved) - g))
    return spread


@pytest.mark.parametrize("kind", list(CASES))
def test_compiled_matches_numpy_implementation(kind):
    fn, args, g_old, modes = _case(kind)
    g = fn(*args)
    assert np.all(np.isfinite(g)) and np.all(g >= 0.0)
    spread = _input_spread(fn, args, g, np.random.default_rng(7))
    err = np.abs(g - g_old)
    tol = 1e-10 * g_old + 4.0 * spread
    bad = np.nonzero(err > tol)[0]
    assert bad.size == 0, [(int(i), str(modes[i]), float(g_old[i]), float(g[i]), float(spread[i])) for i in bad[:5]]
    # not vacuous: the inputs pin G down to 1e-9 for most rows it is non-zero in (69-81 % by kind;
    # the rest are the deliberately ill-conditioned grazing, straddling and tangent cases), and
    # the expected zeros (behind, in the plane, below the horizon, inside) are a real share
    nz = g_old > 0.0
    assert np.mean(4.0 * spread[nz] <= 1e-9 * g_old[nz]) > 0.6
    assert 0.1 < np.mean(~nz) < 0.6
    # the hard configurations are all there
    seen = Counter(str(m) for m in modes)
    if kind == "sphere":
        for mode in ("straddle", "near_surface", "far", "tiny_far_straddle", "inside", "surface"):
            assert seen[mode] >= 50, mode
    else:
        p_modes = Counter(m.split("/")[0] for m in seen.elements())
        n_modes = Counter(m.split("/")[1] for m in seen.elements())
        for mode in ("close", "grazing", "far", "rim", "plane", "behind"):
            assert p_modes[mode] >= 50, mode
        for mode in ("straddle", "tangent"):
            assert n_modes[mode] >= 50, mode


# --- called from another compiled function ---------------------------------------------------
@njit(cache=False, nogil=True)
def _from_kernel(p, nrm, c, ex, ey, en, R, tri, out):
    """Every row function from compiled code with tuples, the quadrature switches left at their
    defaults: columns rect, disk, ellipse (ex, ey as semi-diameters), sphere, triangle (a tuple
    of three 3-tuples, as a mesh light passes it), the same triangle as a (3, 3) array, dome."""
    for i in range(p.shape[0]):
        P = (p[i, 0], p[i, 1], p[i, 2])
        N = (nrm[i, 0], nrm[i, 1], nrm[i, 2])
        C = (c[i, 0], c[i, 1], c[i, 2])
        X = (ex[i, 0], ex[i, 1], ex[i, 2])
        Y = (ey[i, 0], ey[i, 1], ey[i, 2])
        E = (en[i, 0], en[i, 1], en[i, 2])
        T = ((tri[i, 0, 0], tri[i, 0, 1], tri[i, 0, 2]), (tri[i, 1, 0], tri[i, 1, 1], tri[i, 1, 2]),
             (tri[i, 2, 0], tri[i, 2, 1], tri[i, 2, 2]))
        out[i, 0] = an.rect_F(P, N, C, X, Y, E)
        out[i, 1] = an.disk_F(P, N, C, E, R[i])
        out[i, 2] = an.ellipse_F(P, N, C, X, Y, E)
        out[i, 3] = an.sphere_F(P, N, C, R[i])
        out[i, 4] = an.polygon_F(P, N, T, E, True)
        out[i, 5] = an.polygon_F(P, N, tri[i], E, False)
        out[i, 6] = an.dome_constant_F()


def test_row_functions_callable_from_compiled_code():
    fn, (p, nrm, c, ex, ey, en), _, _ = _case("rect")
    R = 0.5 * np.sqrt(np.einsum("ij,ij->i", ex, ex))
    tri = np.ascontiguousarray(np.stack([c - 0.5 * ex, c + 0.5 * ex, c + 0.5 * ey], axis=1))
    out = np.zeros((p.shape[0], 7))
    _from_kernel(p, nrm, c, ex, ey, en, R, tri, out)
    # the same arithmetic as the numpy API's compiled loops: equal to the last bit
    np.testing.assert_array_equal(out[:, 0], an.projected_solid_angle_rect(p, nrm, c, ex, ey, en))
    np.testing.assert_array_equal(out[:, 1], an.projected_solid_angle_disk(p, nrm, c, en, R))
    np.testing.assert_array_equal(out[:, 2], an.projected_solid_angle_ellipse(p, nrm, c, ex, ey, en))
    np.testing.assert_array_equal(out[:, 3], an.projected_solid_angle_sphere(p, nrm, c, R))
    np.testing.assert_array_equal(out[:, 4], an.projected_solid_angle_polygon(p, nrm, tri, e_n=en))
    np.testing.assert_array_equal(out[:, 5], an.projected_solid_angle_polygon(p, nrm, tri))
    assert np.all(out[:, 6] == np.pi)
    assert np.count_nonzero(out[:, :6]) > 0.3 * out[:, :6].size


def test_row_functions_allocate_nothing():
    """No heap allocation in any row function: numba's allocator counts (NRT statistics) grow by
    the same amount per call of the compiled caller (the boxing of its array arguments) whether
    it evaluates 8 rows or 800 (7 row functions each)."""
    from numba.core.runtime import _nrt_python

    fn, (p, nrm, c, ex, ey, en), _, _ = _case("rect")
    R = 0.5 * np.sqrt(np.einsum("ij,ij->i", ex, ex))
    tri = np.ascontiguousarray(np.stack([c - 0.5 * ex, c + 0.5 * ex, c + 0.5 * ey], axis=1))
    out = np.zeros((p.shape[0], 7))
    _from_kernel(p, nrm, c, ex, ey, en, R, tri, out)                 # compile first

    def allocations(n):
        args = [np.ascontiguousarray(a[:n]) for a in (p, nrm, c, ex, ey, en, R, tri, out)]
        _nrt_python.memsys_enable_stats()
        try:
            before = _nrt_python.memsys_get_stats_alloc() + _nrt_python.memsys_get_stats_mi_alloc()
            _from_kernel(*args)
            return _nrt_python.memsys_get_stats_alloc() + _nrt_python.memsys_get_stats_mi_alloc() - before
        finally:
            _nrt_python.memsys_disable_stats()

    assert allocations(8) == allocations(p.shape[0])
