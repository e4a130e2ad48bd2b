"""The compiled per-row mesh-light functions (kernels/mesh_light.py mesh_light_*_row, which the
fast path's vertex kernel calls) reproduce MeshLight.sample_li and pdf_li (the general path's)
on the same uniforms: a small light (per-point oriented pick), a large one (its triangle BVH), a
two-sided one, all in one MeshLight."""

import numpy as np
from numba import njit

from renderer.kernels import mesh_light as kern
from renderer.lights.base import ShadingContext
from renderer.lights.mesh import EXACT_PICK_TRIANGLES, MeshLight
from tests.lights.test_mesh_light import mesh_desc, octahedron, quad, sphere_mesh


@njit(cache=False)
def _rows(MS, idx, p, ns, u, wi, out_L, out_wi, out_pdf, out_pdf_wi, out_t):
    for r in range(idx.shape[0]):
        pr = (p[r, 0], p[r, 1], p[r, 2])
        nr = (ns[r, 0], ns[r, 1], ns[r, 2])
        L, w, pdf, _d, _x = kern.mesh_light_sample_row(MS, idx[r], pr, nr, u[r, 0], u[r, 1])
        for c in range(3):
            out_L[r, c] = L[c]
            out_wi[r, c] = w[c]
        out_pdf[r] = pdf
        t, _Le, p_l = kern.mesh_light_along_row(MS, idx[r], pr, nr, (wi[r, 0], wi[r, 1], wi[r, 2]))
        out_pdf_wi[r] = p_l
        out_t[r] = t


def test_compiled_rows_reproduce_sample_li_and_pdf_li():
    big = sphere_mesh(np.array([0.0, 3.0, 0.0]), 0.8)
    assert big.shape[0] > EXACT_PICK_TRIANGLES
    light = MeshLight.build([mesh_desc(octahedron(np.array([1.5, 1.0, 0.5]), 0.4)), mesh_desc(big),
                             mesh_desc(quad(np.array([-1.5, 1.5, 0.0]), np.array([1.0, 0, 0]),
                                            np.array([0, 0.3, 0.8])), mesh_two_sided=True)])
    rng = np.random.default_rng(3)
    n = 3000
    idx = rng.integers(0, 3, n)
    p = rng.uniform([-2.5, -0.5, -2.0], [2.5, 0.5, 2.0], (n, 3))
    ns = rng.normal(size=(n, 3))
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    ctx = ShadingContext(p, ns, ns)
    u = rng.random((n, 2))
    s = light.sample_li(idx, ctx, u)
    # Directions toward the light (its samples) and random ones.
    wi = np.where((np.arange(n) % 2 == 0)[:, None], s.wi, ns)
    out_L, out_wi, out_pdf, out_pdf_wi, out_t = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n), \
        np.empty(n)
    _rows(light.compiled_record(), idx, p, ns, u, wi, out_L, out_wi, out_pdf, out_pdf_wi, out_t)
    ok = s.pdf > 0.0
    assert ok.mean() > 0.3 and (idx[ok] == 1).any()
    np.testing.assert_array_equal(out_pdf, s.pdf)
    np.testing.assert_array_equal(out_L, s.L)
    np.testing.assert_allclose(out_wi[ok], s.wi[ok], rtol=0, atol=1e-15)
    ref = light.pdf_li(idx, ctx, wi)
    assert (ref > 0).mean() > 0.2
    # The large light's first triangle: embree (numpy route) against exact float64 tests here.
    np.testing.assert_allclose(out_pdf_wi, ref, rtol=1e-9, atol=0)
