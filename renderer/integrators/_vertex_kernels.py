"""The compiled path vertex of the fast path (renderer/integrators/fast_path.py).

One call per bounce does, for every live ray, all the work between two embree calls that the
general integrator spreads over ~150 numpy passes and a dozen kernels: emission of the rect
lights the ray crossed (MIS-weighted on continuation rays), the surface interaction, the
material's packed UsdPreviewSurface row, the shading frame, the light half of continuation MIS
for every light on it (the exhaustive lighting service: the rect and sphere lights' samples
drawn block by block by the vectorised batch kernels of kernels/lights.py, the others' row by
row) or for the one light a uniform, power or bvh service picks per row (kernels/light_pick.py:
the pick, its pmf replayed for the emission weight, and the lights a ray crosses found by a walk
of the light BVH instead of a loop over every light), the per-light estimators of the lights
not on it (renderer/estimators/compiled.py on samples drawn row by row, _direct_pair, divided by
the pick's pmf), and the BSDF sample with the throughput update and Russian roulette. It writes
the shadow rays and the next bounce's rays compactly; Python
only calls embree and adds the unblocked shadow contributions.

The rows go in blocks of BLK. Most of the work on a block is loops LLVM vectorises (4 rows per
AVX2 instruction, 8 with AVX-512; renderer/__init__.py): ``_uniform_pass`` (the block's random
numbers, a counter-based stream), ``_surface_pass`` (surface interaction, frame, material wo
terms, BSDF sample, roulette), the rect and sphere lights' batch samplers (kernels/lights.py, from
the block's hit points), ``_light_pass`` (each such sample weighed by the BSDF and MIS) and
``_cross_pass`` (which rows may cross a light before their surface). A scalar pass then adds
emission, takes the disk and infinite lights' light half and writes the rays compactly. What keeps
those loops vectorised, each checked by tests/integrators/test_vertex_vectorised.py: no branches
around work (both BSDF lobes are computed and one is selected), no libm calls (kernels/vmath.py's
sin, cos and atan), error_model="numpy" (no exception exits), array arguments marked noalias
(_NoAliasCompiler), the albedo tables as module constants, a compile-time row stride in the block
state, no isfinite (LLVM does not widen it), and only scalar-argument helpers numba-inlined
(inlining one that takes arrays leaves reference counting calls in the loop). The passes are bound
by the unit that does divisions and square roots, so the helpers avoid the ones they can.

The maths is not restated here: it calls the per-row helpers of the surface interaction
(renderer/geometry.py), the rect, sphere and disk lights (renderer/kernels/lights.py), the
cylinder lights (renderer/kernels/cylinder.py), the mesh lights (renderer/kernels/mesh_light.py)
and the BSDF (renderer/bsdfs/_preview_kernels.py), the same functions the general path's kernels
use. numba's
on-disk cache is keyed on this file only, so ``guard_cache`` (renderer/kernels/__init__.py) flushes
this file's cache whenever any of the files it inlines from changes.

Shapes: n live rays; S (n, NS) float64 per-ray state, columns ``B`` (beta), ``O`` (origin),
``D`` (unit direction), ``TMAX``, ``PP`` (the previous vertex's point, for the light pdf of
continuation MIS), ``PB`` (the BSDF pdf of d there), ``PN`` (its shading normal, for the
light BVH's pmf replay) and ``PM`` (its mesh, for light linking). A block's uniforms UB (4 + 2 lights or 4 + 3,
BLK) come from a counter-based generator inside the kernel (_uniform_pass), batch axis last (the
rect and sphere lights' batch samplers need unit stride along the batch); columns ``U_*``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from renderer.bsdfs._preview_kernels import (
    ALPHA, F0, F90, FY, J0, KD, RHO,
    _diffuse_constant, _lookup_weights, _mis_weight, _p_diffuse, _sample_dir, _specular,
)
from renderer.estimators import compiled as ec
from renderer.kernels.direct import diffuse_combine_row, shadowed_row
from renderer.bsdfs.microfacet import albedo_tables
from renderer.geometry import _interaction_tri
from renderer.kernels import NoAliasCompiler, guard_cache, module_dispatchers
from renderer.kernels.cylinder import CY_DELTA, NCY, cylinder_front_hit_row, cylinder_pdf_row, cylinder_sample_row
from renderer.kernels.mesh_light import (
    mesh_G_row, mesh_hit_row, mesh_light_along_row, mesh_light_emission_row, mesh_light_pdf_row, mesh_light_sample_row,
    plane_distance_row,
)
from renderer.kernels.light_pick import EXHAUSTIVE, crossed_row, pick_pmf_row, pick_row
from renderer.kernels.portal import portal_dome_pdf_row, portal_dome_sample_row
from renderer.kernels.shaping import shaping_factor_row
from renderer.kernels.sobol import sobol_pair, sobol_u01
from renderer.materials import surface_hits
from renderer.lights.analytic import disk_F, distant_F, dome_constant_F, rect_F, sphere_F
from renderer.preconvolve import packed_row
from renderer.kernels.lights import (
    rect_sample_batch_kernel, sphere_sample_batch_kernel, _disk_hit, _disk_pdf_row, _disk_sample_row, _distant_pdf_row, _dome_sample_row, _dome_texel_row, _distant_sample_row, _rect_hit, _rect_pdf_row,
    _rect_sample_row, _row, _sphere_hit_row, _sphere_pdf_row, _sphere_sample_row, _uniform_sphere_row,
    rect_radiance_row, rect_texel_pdf_row, rect_texel_sample_row,
)

_INV_PI = 1.0 / math.pi
_INV_4PI = 0.25 / math.pi

# State columns.
B = 0
O = 3
D = 6
TMAX = 9
PP = 10
PB = 13
PN = 14
PM = 17
NS = 18
# Uniform columns: lobe choice, direction (2), roulette, then (2 per light) light samples, or
# with a lighting service that picks (uniform, power, bvh), the pick's u and one light sample.
U_LOBE = 0
U_DIR = 1
U_RR = 3
U_LIGHT = 4


# The noalias pipeline (renderer/kernels: NoAliasCompiler), under the name the tests use.
_NoAliasCompiler = NoAliasCompiler


# Per-row state of a block's surface pass (_surface_pass), rows of W (NW * BLK,; row c of column i at c * BLK + i, a
# compile-time stride, so LLVM sees the rows never overlap): the point,
# geometric normal, shading normal and the rest of the shading frame (FS, FT), wo in that frame,
# the material's wo terms (AO, BO: albedo-table values at wo.z; PD: the diffuse lobe's pick
# probability), the material row M, the ray epsilon, and the BSDF sample's outcome (the next
# throughput NB, world direction WN, pdf PDFB, OKN 1.0 where the path goes on).
W_P = 0
W_G = 3
W_N = 6
W_FS = 9
W_FT = 12
W_WO = 15
W_AO = 18
W_BO = 19
W_PD = 20
W_M = 21
W_EPS = 22
W_NB = 23
W_WN = 26
W_PDFB = 29
W_OKN = 30
NW = 31
# Rows per block: the passes' per-row state (NW + 4 per rect or sphere light doubles a row) stays
# in L1/L2 between the vectorised passes and the scalar one.
BLK = 128

# The albedo tables as module constants: numba freezes them into the kernels, and LLVM knows a
# read from constant memory cannot alias the block state the passes write (a table passed as an
# argument could), so the lookups at computed rows do not keep the loops scalar. guard_cache
# (below) recompiles the kernels when the tables' source changes.
_TABLES = albedo_tables()
_TA = np.ascontiguousarray(_TABLES.a)
_TB = np.ascontiguousarray(_TABLES.b)

# The BSDF helpers, numba-inlined into the passes (so compiled with their error_model="numpy":
# a division by zero gives inf or NaN, masked by the passes' flags, rather than an exception
# exit LLVM cannot vectorise). Only helpers taking scalars: inlining one that takes arrays
# leaves numba's reference counting of them as calls in the loop body.
_specular_i = njit(cache=True, nogil=True, inline="always")(_specular.py_func)
_sample_dir_i = njit(cache=True, nogil=True, inline="always")(_sample_dir.py_func)
_p_diffuse_i = njit(cache=True, nogil=True, inline="always")(_p_diffuse.py_func)
_mis_weight_i = njit(cache=True, nogil=True, inline="always")(_mis_weight.py_func)


@njit(cache=True, nogil=True, inline="always")
def _albedo(mu, j0, fy):
    """_preview_kernels._lookup on the module's tables: (A, B) at (mu, (j0, fy))."""
    i0, w00, w10, w01, w11 = _lookup_weights(mu, fy)
    a = _TA[i0, j0] * w00 + _TA[i0 + 1, j0] * w10 + _TA[i0, j0 + 1] * w01 + _TA[i0 + 1, j0 + 1] * w11
    b = _TB[i0, j0] * w00 + _TB[i0 + 1, j0] * w10 + _TB[i0, j0 + 1] * w01 + _TB[i0 + 1, j0 + 1] * w11
    return a, b


@njit(cache=True, nogil=True, inline="always")
def _f(kd, f0, f90, ao, bo, ai, bi, fw, dv):
    """f(wo, wi) of a material in one channel from its diffuse colour kd, Fresnel F0 and F90,
    the wo terms (ao, bo), the wi terms (ai, bi), the Schlick weight fw and D V of _specular
    (the formula of _preview_kernels.eval_kernel)."""
    return _f_d(kd, f0, f90, ao, bo, ai, bi) + (f0 + (f90 - f0) * fw) * dv


@njit(cache=True, nogil=True, inline="always")
def _f_d(kd, f0, f90, ao, bo, ai, bi):
    """The diffuse lobe of _f (the rest is the specular lobe, (f0 + (f90 - f0) fw) D V)."""
    c_o = 1.0 - (f0 * ao + f90 * bo)
    c_i = 1.0 - (f0 * ai + f90 * bi)
    return kd * c_o * c_i




# Helpers that read arrays are plain njit functions LLVM inlines (numba-inlining them would not
# do, see above); error_model="numpy" keeps exception checks out of the loops calling them.
@njit(cache=True, nogil=True, error_model="numpy")
def _mat(Pm, m):
    """Material row m's (alpha, j0, fy, kd, f0, f90), the colours as 3-tuples."""
    return (Pm[m, ALPHA], int(Pm[m, J0]), Pm[m, FY], (Pm[m, KD], Pm[m, KD + 1], Pm[m, KD + 2]),
            (Pm[m, F0], Pm[m, F0 + 1], Pm[m, F0 + 2]), (Pm[m, F90], Pm[m, F90 + 1], Pm[m, F90 + 2]))


@njit(cache=True, nogil=True, inline="always")
def _light_contrib(wi, pdf_l, Le, delta, power_g, fs, ft, ns, ng, wo, ao, bo, p_d, a, j0, fy, kd, f0, f90, beta):
    """The light half of continuation MIS for one light sample (wi world direction, pdf_l its
    solid-angle pdf, Le its radiance) at a vertex with shading frame (fs, ft, ns), geometric
    normal ng, wo in the frame, the material's wo terms (ao, bo, p_d) and row (a, j0, fy, kd,
    f0, f90), and throughput beta, all 3-tuples or scalars: (ok, c0, c1, c2), c the radiance
    the shadow ray adds if unblocked, ok False where the sample is unusable (pdf 0, below either
    normal, zero contribution). The caller checks pdf_l is finite (math.isfinite in a loop keeps
    LLVM from vectorising it). Branch-free, so the light pass vectorises."""
    wx = wi[0] * fs[0] + wi[1] * fs[1] + wi[2] * fs[2]
    wy = wi[0] * ft[0] + wi[1] * ft[1] + wi[2] * ft[2]
    wz = wi[0] * ns[0] + wi[1] * ns[1] + wi[2] * ns[2]
    cos_g = wi[0] * ng[0] + wi[1] * ng[1] + wi[2] * ng[2]
    oks, dv, fw, pdf_s = _specular_i(wo[0], wo[1], wo[2], wx, wy, wz, a)
    ai, bi = _albedo(wz, j0, fy)
    p_b = p_d * wz * _INV_PI + (1.0 - p_d) * pdf_s
    # A delta light (treatAsPoint) takes the whole weight, and its p_l counts as 1.
    kk = wz if delta else wz * _mis_weight_i(pdf_l, p_b, power_g) / pdf_l
    c0 = beta[0] * _f(kd[0], f0[0], f90[0], ao, bo, ai, bi, fw, dv) * Le[0] * kk
    c1 = beta[1] * _f(kd[1], f0[1], f90[1], ao, bo, ai, bi, fw, dv) * Le[1] * kk
    c2 = beta[2] * _f(kd[2], f0[2], f90[2], ao, bo, ai, bi, fw, dv) * Le[2] * kk
    ok = (pdf_l > 0.0 and wz > 0.0 and cos_g > 0.0 and wo[2] > 0.0 and oks
          and (c0 > 0.0 or c1 > 0.0 or c2 > 0.0))
    return ok, c0, c1, c2


@njit(cache=True, nogil=True, error_model="numpy")
def _w3(W, c, i):
    """Rows c..c+2 of the block state W at column i, as a 3-tuple."""
    return (W[c * BLK + i], W[(c + 1) * BLK + i], W[(c + 2) * BLK + i])


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
def _surface_pass(lo, hi, hit_prim, hit_b1, hit_b2, S, U, depth, Pm, mat_row, bent_ns, vertices, face_normal,
                  normals, tri_mat, tri_mag, rr_depth, eps_rel, eps_floor, eps_add, W):
    """Rows lo..hi of a bounce into the block state W (NW * BLK,), at column r - lo: the surface
    interaction, shading frame, the material's wo terms, and the BSDF sample with its throughput
    update and Russian roulette. U: the block's uniforms (_uniform_pass), row r at column r - lo.
    bent_ns: (hits, 3) the normal-mapped shading normal of each hit (row mat_row[r]), or empty
    where no material bends normals. One branch-free loop that LLVM vectorises; a row that missed
    (or will not scatter) is computed on triangle 0 and ignored by vertex_kernel, which also
    checks the sample's pdf and throughput are finite."""
    per_hit = mat_row.shape[0] > 0
    bent = bent_ns.shape[0] > 0
    for r in range(lo, hi):
        i = r - lo
        k = max(hit_prim[r], 0)
        dx = S[r, D]
        dy = S[r, D + 1]
        dz = S[r, D + 2]
        # The triangle's loads are written out here, as in geometry._interaction_row: a helper
        # returning its tuples (a call LLVM leaves in place) turns this loop scalar.
        pp, gg, ss = _interaction_tri(
            (vertices[k, 0, 0], vertices[k, 0, 1], vertices[k, 0, 2]),
            (vertices[k, 1, 0], vertices[k, 1, 1], vertices[k, 1, 2]),
            (vertices[k, 2, 0], vertices[k, 2, 1], vertices[k, 2, 2]),
            (normals[k, 0, 0], normals[k, 0, 1], normals[k, 0, 2]),
            (normals[k, 1, 0], normals[k, 1, 1], normals[k, 1, 2]),
            (normals[k, 2, 0], normals[k, 2, 1], normals[k, 2, 2]),
            (face_normal[k, 0], face_normal[k, 1], face_normal[k, 2]), hit_b1[r], hit_b2[r], dx, dy, dz)
        px, py, pz = pp
        gx, gy, gz = gg
        sx, sy, sz = ss
        if bent:
            # Normal maps: the shading normal materials.surface_hits bent (geometry.perturb_row).
            q = max(mat_row[r], 0)
            sx, sy, sz = bent_ns[q, 0], bent_ns[q, 1], bent_ns[q, 2]
        # ---- shading frame (geometry._frame_kernel) and wo in it ---------------------------
        sign = 1.0 if sz >= 0.0 else -1.0
        fa = -1.0 / (sign + sz)
        fb = sx * sy * fa
        s0 = 1.0 + sign * sx * sx * fa
        s1 = sign * fb
        s2 = -sign * sx
        t0 = fb
        t1 = sign + sy * sy * fa
        t2 = -sy
        wox = -(dx * s0 + dy * s1 + dz * s2)
        woy = -(dx * t0 + dy * t1 + dz * t2)
        woz = -(dx * sx + dy * sy + dz * sz)
        # ---- the material's BSDF and its wo terms -----------------------------------------
        m = max(mat_row[r], 0) if per_hit else tri_mat[k]
        a, j0, fy, kd, f0, f90 = _mat(Pm, m)
        ao, bo = _albedo(woz, j0, fy)
        p_d = _p_diffuse_i(Pm[m, RHO], Pm[m, RHO + 1], Pm[m, RHO + 2], f0[0], f0[1], f0[2], f90[0], f90[1], f90[2],
                           ao, bo)
        # Accel.ray_epsilon: the point's and the triangle's vertices' float32 error.
        mag = max(max(max(abs(px), abs(py)), abs(pz)), tri_mag[k])
        eps = eps_rel * max(mag, eps_floor) + eps_add
        # ---- BSDF sample, throughput, Russian roulette (_preview_kernels.scatter_kernel) ----
        wix, wiy, wiz = _sample_dir_i(wox, woy, woz, a, U[U_LOBE, i] < p_d, U[U_DIR, i], U[U_DIR + 1, i])
        wx = wix * s0 + wiy * t0 + wiz * sx
        wy = wix * s1 + wiy * t1 + wiz * sy
        wz = wix * s2 + wiy * t2 + wiz * sz
        okb, dv, fw, pdf_s = _specular_i(wox, woy, woz, wix, wiy, wiz, a)
        pdf_b = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s if okb else 0.0
        cos_g = wx * gx + wy * gy + wz * gz
        ai, bi = _albedo(wiz, j0, fy)
        kk = abs(wiz) / pdf_b
        nb0 = S[r, B] * _f(kd[0], f0[0], f90[0], ao, bo, ai, bi, fw, dv) * kk
        nb1 = S[r, B + 1] * _f(kd[1], f0[1], f90[1], ao, bo, ai, bi, fw, dv) * kk
        nb2 = S[r, B + 2] * _f(kd[2], f0[2], f90[2], ao, bo, ai, bi, fw, dv) * kk
        ok = okb and pdf_b > 0.0 and cos_g > 0.0 and (nb0 > 0.0 or nb1 > 0.0 or nb2 > 0.0)
        rr = depth[r] + 1 >= rr_depth
        q = min(max(1.0 - max(nb0, max(nb1, nb2)), 0.0), 0.95)
        inv = 1.0 / (1.0 - q)
        ok = ok and not (rr and U[U_RR, i] < q)
        # Stores written out, like the triangle loads: a store helper (the counterpart of _w3)
        # turns this loop scalar, 2x slower a row (tried; test_vertex_vectorised catches it).
        W[W_P * BLK + i] = px
        W[(W_P + 1) * BLK + i] = py
        W[(W_P + 2) * BLK + i] = pz
        W[W_G * BLK + i] = gx
        W[(W_G + 1) * BLK + i] = gy
        W[(W_G + 2) * BLK + i] = gz
        W[W_N * BLK + i] = sx
        W[(W_N + 1) * BLK + i] = sy
        W[(W_N + 2) * BLK + i] = sz
        W[W_FS * BLK + i] = s0
        W[(W_FS + 1) * BLK + i] = s1
        W[(W_FS + 2) * BLK + i] = s2
        W[W_FT * BLK + i] = t0
        W[(W_FT + 1) * BLK + i] = t1
        W[(W_FT + 2) * BLK + i] = t2
        W[W_WO * BLK + i] = wox
        W[(W_WO + 1) * BLK + i] = woy
        W[(W_WO + 2) * BLK + i] = woz
        W[W_AO * BLK + i] = ao
        W[W_BO * BLK + i] = bo
        W[W_PD * BLK + i] = p_d
        W[W_M * BLK + i] = m
        W[W_EPS * BLK + i] = eps
        W[W_NB * BLK + i] = nb0 * inv if rr else nb0
        W[(W_NB + 1) * BLK + i] = nb1 * inv if rr else nb1
        W[(W_NB + 2) * BLK + i] = nb2 * inv if rr else nb2
        W[W_WN * BLK + i] = wx
        W[(W_WN + 1) * BLK + i] = wy
        W[(W_WN + 2) * BLK + i] = wz
        W[W_PDFB * BLK + i] = pdf_b
        W[W_OKN * BLK + i] = 1.0 if ok else 0.0


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
def _light_pass(lo, hi, smp, scaled, Le0, Le1, Le2, delta, power_g, S, W, Pm, C):
    """One rect or sphere light's samples of the block, smp (6, BLK) (kernels.lights' batch
    kernels: wi, distance, pdf and, with scaled, the radiance scale in row 5) at rows lo..hi
    through _light_contrib into C (4 * BLK,): the contribution and 1.0 where usable, else 0.0
    (vertex_kernel checks the pdf is finite). Vectorised like _surface_pass."""
    for r in range(lo, hi):
        i = r - lo
        sc = smp[5, i] if scaled else 1.0
        a, j0, fy, kd, f0, f90 = _mat(Pm, int(W[W_M * BLK + i]))
        ok, c0, c1, c2 = _light_contrib(
            (smp[0, i], smp[1, i], smp[2, i]), smp[4, i], (Le0 * sc, Le1 * sc, Le2 * sc), delta, power_g,
            _w3(W, W_FS, i), _w3(W, W_FT, i), _w3(W, W_N, i), _w3(W, W_G, i), _w3(W, W_WO, i), W[W_AO * BLK + i],
            W[W_BO * BLK + i], W[W_PD * BLK + i], a, j0, fy, kd, f0, f90, (S[r, B], S[r, B + 1], S[r, B + 2]))
        C[0 * BLK + i] = c0
        C[1 * BLK + i] = c1
        C[2 * BLK + i] = c2
        C[3 * BLK + i] = 1.0 if ok else 0.0


# SplitMix64 (Steele, Lea & Flood 2014): the golden-ratio increment and the output mix.
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
def _uniform_pass(key, lo, hi, UB):
    """The uniforms of rows lo..hi into UB (n_u, BLK) at column r - lo: element (r, c) is
    SplitMix64's output number r n_u + c + 1 after state ``key`` (uint64, drawn per call from the
    integrator's generator), as 53-bit doubles in [0, 1). A counter-based stream (any row's
    numbers without the ones before it) whose integer mixing LLVM vectorises: ~10x cheaper than
    numpy's Generator.random filling an (n_u, n) array (~2 ns a number) that the kernel then
    reads back from memory. SplitMix64 passes BigCrush; tests/integrators/test_vertex_vectorised.py
    chi-square tests the marginals and neighbouring pairs."""
    n_u = UB.shape[0]
    for c in range(n_u):
        for r in range(lo, hi):
            UB[c, r - lo] = splitmix_u01(key, r * n_u + c + 1)


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
def _sobol_pass(lo, hi, UB, path, pix, sidx, dim0, roles):
    """The uniforms of rows lo..hi into UB (n_u, BLK) from each row's pixel's low-discrepancy
    sequence (kernels/sobol.py): row r's pixel key pix[path[r]] (uint64), sample index sidx
    (uint64, the pass), column c's dimension pair dim0 + roles[c, 0] (dim0: the bounce's first,
    bounce * n_u) and coordinate roles[c, 1] (FastPath.sobol_roles: the BSDF's direction and
    each light's point are pairs, the lobe, the roulette and the pick 1D)."""
    n_u = UB.shape[0]
    for c in range(n_u):
        if roles[c, 1] == 1:
            continue  # written with the pair's first column
        dim = dim0 + np.uint64(roles[c, 0])
        if c + 1 < n_u and roles[c + 1, 1] == 1:
            for r in range(lo, hi):
                x, y = sobol_pair(pix[path[r]], sidx, dim)
                UB[c, r - lo] = x
                UB[c + 1, r - lo] = y
        else:
            for r in range(lo, hi):
                UB[c, r - lo] = sobol_pair(pix[path[r]], sidx, dim)[0]


@njit(cache=True, nogil=True, inline="always")
def splitmix_u01(key, i):
    """SplitMix64's output number i (>= 1) after state ``key`` (uint64) as a 53-bit double in
    [0, 1): the counter-based stream of _uniform_pass, for any kernel that draws its own."""
    z = key + np.uint64(i) * _GAMMA
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=_NoAliasCompiler)
def _cross_pass(lo, hi, S, hit_t, hit_prim, center, nrm, exd, eyd, s_center, s_radius, s_delta, X):
    """X[r - lo] = 1.0 for the rows lo..hi that may cross a rect or sphere light before their
    surface, else 0.0: a conservative pre-test (margins of 1e-9 relative; a sphere's whole line)
    in loops LLVM vectorises, so that vertex_kernel's scalar pass runs its exact emission test
    (_rect_hit, _sphere_hit_row) only for those rows, a few per cent of them in a typical scene.
    No isfinite (LLVM does not widen it): an infinite or NaN t fails a compare instead."""
    for r in range(lo, hi):
        X[r - lo] = 0.0
    for j in range(center.shape[0]):
        cx, cy, cz = center[j, 0], center[j, 1], center[j, 2]
        nx, ny, nz = nrm[j, 0], nrm[j, 1], nrm[j, 2]
        for r in range(lo, hi):
            ox, oy, oz = S[r, O], S[r, O + 1], S[r, O + 2]
            dx, dy, dz = S[r, D], S[r, D + 1], S[r, D + 2]
            t_geo = min(float(hit_t[r]) if hit_prim[r] >= 0 else math.inf, S[r, TMAX])
            # As _rect_hit: the plane's t, then the hit's edge coordinates (a, b).
            den = nx * dx + ny * dy + nz * dz
            t = (nx * (cx - ox) + ny * (cy - oy) + nz * (cz - oz)) / den
            qx = ox + t * dx - cx
            qy = oy + t * dy - cy
            qz = oz + t * dz - cz
            a = qx * exd[j, 0] + qy * exd[j, 1] + qz * exd[j, 2]
            b = qx * eyd[j, 0] + qy * eyd[j, 1] + qz * eyd[j, 2]
            crossed = (den < 0.0 and t > 0.0 and t <= t_geo * (1.0 + 1e-9) and abs(a) <= 0.5 + 1e-9
                       and abs(b) <= 0.5 + 1e-9)
            X[r - lo] = 1.0 if crossed else X[r - lo]
    for j in range(s_center.shape[0]):
        cx, cy, cz = s_center[j, 0], s_center[j, 1], s_center[j, 2]
        rr = s_radius[j] * s_radius[j] * (1.0 + 1e-9)
        seen = s_radius[j] > 0.0 and not s_delta[j]
        for r in range(lo, hi):
            ox, oy, oz = S[r, O] - cx, S[r, O + 1] - cy, S[r, O + 2] - cz
            dx, dy, dz = S[r, D], S[r, D + 1], S[r, D + 2]
            # The line's squared distance from the centre (as _sphere_hit_row's discriminant).
            b = ox * dx + oy * dy + oz * dz
            px, py, pz = ox - b * dx, oy - b * dy, oz - b * dz
            crossed = seen and px * px + py * py + pz * pz <= rr
            X[r - lo] = 1.0 if crossed else X[r - lo]


# ---- per-light helpers shared by emission, continuation MIS and the per-light estimators ------
# A light's index g runs over rect, sphere, disk, then infinite lights (vertex_kernel's order).
# The helpers read one flat table LP (lights, NLP) that _light_table builds once per call from the
# kinds' arrays: taking an array out of a tuple costs numba a reference count increment and
# decrement (atomic), and the tuples of tables made those the main cost of a sample. Only a
# textured dome also reads its image (IMG: i_rot and the ImageSet arrays, vertex_kernel's order).
K_RECT, K_SPHERE, K_DISK, K_DOME, K_DISTANT = range(5)
# Cylinder lights (and treatAsLine line lights): finite, after the disks in the kernel's order;
# then mesh lights (scene geometry: their emission is found at surface hits, never by a
# crossing test), before the infinite lights.
K_CYL = 5
K_MESH = 6
LP_KIND = 0
LP_C = 1  # centre
LP_A = 4  # rect ex, disk u1, distant axis
LP_B = 7  # rect ey, disk u2
LP_XH = 10  # rect x_hat, disk e1
LP_YH = 13  # rect y_hat, disk e2
LP_N = 16  # emitting normal
LP_EXD = 19
LP_EYD = 22
LP_L = 25  # radiance
LP_P0 = 28  # rect edge length x, sphere radius, disk s1, distant 1 - cos theta_max
LP_P1 = 29  # rect edge length y, disk s2
LP_AREA = 30
LP_FLAG = 31  # rect is_rect, sphere and distant delta
LP_TEX = 32  # dome image, -1 for a constant dome
LP_J = 33  # the row in the light's kind table
LP_SHAPE = 34  # the light's row in the ShapingAPI table (lights/shaping.py), -1 when unshaped
LP_CY = 35  # a cylinder's packed row (renderer/kernels/cylinder.py, columns CY_*)
NLP = LP_CY + NCY
# A dome's first portal row and portal count (vertex_kernel sets them from the portal record; a
# dome has no sizes in LP_P0, LP_P1). A rect's image is in LP_TEX (-1 untextured), set from the
# texrect record: the rects' images follow the domes' in IMG's ImageSet.
LP_PORTAL0 = LP_P0
LP_PORTALS = LP_P1
# After the images in IMG (vertex_kernel): the mesh lights' record (IMG_MESH), then the portal
# record's two arrays (DomeLight.portal_record, kernels/portal.py). Only two: numba counts
# references to each array of IMG at every call that passes it.
IMG_MESH = 11
IMG_PORTAL = 12
IMG_PORTAL_T = 13


@njit(cache=True, nogil=True)
def _put3(LP, g, col, a, j):
    """LP[g, col:col + 3] = a[j] (a (m, 3))."""
    for c in range(3):
        LP[g, col + c] = a[j, c]


@njit(cache=True, nogil=True)
def _light_table(center, ex, ey, x_hat, y_hat, edge_len, nrm, area, radiance, is_rect, exd, eyd, s_center,
                 s_radius, s_radiance, s_delta, d_center, d_nrm, d_u1, d_u2, d_e1, d_e2, d_s1, d_s2, d_area,
                 d_radiance, i_dome, i_axis, i_omc, i_delta, i_radiance, i_tex):
    """LP (lights, NLP): every light's parameters in one row (columns LP_*), kernel order."""
    n_rect = center.shape[0]
    n_rs = n_rect + s_center.shape[0]
    n_fin = n_rs + d_center.shape[0]
    nl = n_fin + i_radiance.shape[0]
    LP = np.zeros((nl, NLP))
    for g in range(nl):
        if g < n_rect:
            j = g
            LP[g, LP_KIND] = K_RECT
            for col, a in ((LP_C, center), (LP_A, ex), (LP_B, ey), (LP_XH, x_hat), (LP_YH, y_hat), (LP_N, nrm),
                           (LP_EXD, exd), (LP_EYD, eyd), (LP_L, radiance)):
                _put3(LP, g, col, a, j)
            LP[g, LP_P0] = edge_len[j, 0]
            LP[g, LP_P1] = edge_len[j, 1]
            LP[g, LP_AREA] = area[j]
            LP[g, LP_FLAG] = 1.0 if is_rect[j] else 0.0
        elif g < n_rs:
            j = g - n_rect
            LP[g, LP_KIND] = K_SPHERE
            _put3(LP, g, LP_C, s_center, j)
            _put3(LP, g, LP_L, s_radiance, j)
            LP[g, LP_P0] = s_radius[j]
            LP[g, LP_FLAG] = 1.0 if s_delta[j] else 0.0
        elif g < n_fin:
            j = g - n_rs
            LP[g, LP_KIND] = K_DISK
            for col, a in ((LP_C, d_center), (LP_A, d_u1), (LP_B, d_u2), (LP_XH, d_e1), (LP_YH, d_e2),
                           (LP_N, d_nrm), (LP_L, d_radiance)):
                _put3(LP, g, col, a, j)
            LP[g, LP_P0] = d_s1[j]
            LP[g, LP_P1] = d_s2[j]
            LP[g, LP_AREA] = d_area[j]
        else:
            j = g - n_fin
            LP[g, LP_KIND] = K_DOME if i_dome[j] else K_DISTANT
            _put3(LP, g, LP_A, i_axis, j)
            _put3(LP, g, LP_L, i_radiance, j)
            LP[g, LP_P0] = i_omc[j]
            LP[g, LP_FLAG] = 1.0 if (i_delta[j] and not i_dome[j]) else 0.0
            LP[g, LP_TEX] = i_tex[j]
        LP[g, LP_J] = j
        LP[g, LP_SHAPE] = -1.0
    return LP


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _shaped(LP, g, SHP, d, Le):
    """Le (3-tuple) of light g seen along unit d (receiver -> light) times the light's ShapingAPI
    factor toward the emission direction -d (kernels/shaping.shaping_factor_row, the general
    path's formula); Le itself for an unshaped light. SHP: ShapingTable.kernel_record().
    Callers test LP[g, LP_SHAPE] >= 0 first: a call costs numba an atomic reference count
    increment and decrement for each of SHP's 14 arrays (not pruned), twice per estimator sample,
    which unshaped lights (most) need not pay."""
    j = int(LP[g, LP_SHAPE])
    if j < 0:
        return Le
    f0, f1, f2 = shaping_factor_row(j, -d[0], -d[1], -d[2], *SHP)
    return (Le[0] * f0, Le[1] * f1, Le[2] * f2)


@njit(cache=True, nogil=True)
def _with_kinds(LP0, n_fin0, cy_packed, cy_L, ms_L):
    """LP0 (_light_table's) with the cylinder lights' rows, then the mesh lights', inserted
    after its n_fin0 finite lights, before the infinite ones. Cylinders: kind K_CYL, their
    radiance in LP_L, treatAsLine in LP_FLAG and their packed row (CylinderLight.packed) from
    column LP_CY. Mesh lights: kind K_MESH, radiance, LP_J their row in the mesh record."""
    n_c = cy_packed.shape[0]
    n_m = ms_L.shape[0]
    LP = np.zeros((LP0.shape[0] + n_c + n_m, NLP))
    LP[:n_fin0] = LP0[:n_fin0]
    LP[n_fin0 + n_c + n_m:] = LP0[n_fin0:]
    for j in range(n_m):
        g = n_fin0 + n_c + j
        LP[g, LP_KIND] = K_MESH
        _put3(LP, g, LP_L, ms_L, j)
        LP[g, LP_J] = j
    for j in range(n_c):
        g = n_fin0 + j
        LP[g, LP_KIND] = K_CYL
        _put3(LP, g, LP_L, cy_L, j)
        for c in range(NCY):
            LP[g, LP_CY + c] = cy_packed[j, c]
        LP[g, LP_FLAG] = cy_packed[j, CY_DELTA]
        LP[g, LP_J] = j
    return LP


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _lp(LP, g, c):
    """Columns c..c+2 of LP's row g as a 3-tuple."""
    return (LP[g, c], LP[g, c + 1], LP[g, c + 2])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _finite_seen(LP, g, o, d):
    """Finite light g seen from o along unit d: (t, Le (3-tuple), seen): seen where the ray hits
    the light's emitting side (the back of a one-sided light and a sphere's inside emit nothing)."""
    kind = LP[g, LP_KIND]
    Le = _lp(LP, g, LP_L)
    if kind == K_CYL:
        # The side's emitting face, met from outside (a line light is never seen).
        tl, _s, _phi = cylinder_front_hit_row(LP, g, LP_CY, o, d)
        return tl, Le, tl < math.inf
    if kind == K_MESH:
        return math.inf, Le, False  # geometry: seen at the surface hit (vertex_kernel)
    if kind == K_SPHERE:
        c = _lp(LP, g, LP_C)
        tl = _sphere_hit_row(o, d, c, LP[g, LP_P0], LP[g, LP_FLAG] != 0.0)
        hit = tl < math.inf
        # Outward emission only: a ray leaving the sphere's inside sees nothing.
        front = -((o[0] + tl * d[0] - c[0]) * d[0] + (o[1] + tl * d[1] - c[1]) * d[1]
                  + (o[2] + tl * d[2] - c[2]) * d[2]) > 0.0 if hit else False
        return tl, Le, hit and front
    n = _lp(LP, g, LP_N)
    if kind == K_RECT:
        tl, _a, _b, hit = _rect_hit(o, d, _lp(LP, g, LP_C), n, _lp(LP, g, LP_EXD), _lp(LP, g, LP_EYD))
    else:
        tl, hit = _disk_hit(o, d, _lp(LP, g, LP_C), n, _lp(LP, g, LP_A), _lp(LP, g, LP_B), LP[g, LP_P0],
                            LP[g, LP_P1])
    # The back of a one-sided light emits nothing.
    front = -(d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) > 0.0
    return tl, Le, hit and front


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _finite_pdf(LP, g, p, d, close_ratio, min_sa, graz):
    """The solid-angle pdf with which finite light g's sampler, at p, picks direction d."""
    kind = LP[g, LP_KIND]
    if kind == K_CYL:
        return cylinder_pdf_row(LP, g, LP_CY, p, d)
    if kind == K_MESH:
        return 0.0  # (its pdf needs the shading normal: vertex_kernel and _light_along ask it)
    if kind == K_RECT:
        return _rect_pdf_row(p, d, _lp(LP, g, LP_C), _lp(LP, g, LP_N), _lp(LP, g, LP_EXD), _lp(LP, g, LP_EYD),
                             _lp(LP, g, LP_A), _lp(LP, g, LP_B), _lp(LP, g, LP_XH), _lp(LP, g, LP_YH), LP[g, LP_P0],
                             LP[g, LP_P1], LP[g, LP_AREA], False, LP[g, LP_FLAG] != 0.0, 0.0, min_sa, graz)
    if kind == K_DISK:
        return _disk_pdf_row(p, d, _lp(LP, g, LP_C), _lp(LP, g, LP_N), _lp(LP, g, LP_A), _lp(LP, g, LP_B),
                             _lp(LP, g, LP_XH), _lp(LP, g, LP_YH), LP[g, LP_P0], LP[g, LP_P1], LP[g, LP_AREA],
                             close_ratio, min_sa, graz)
    return _sphere_pdf_row(p, d, _lp(LP, g, LP_C), LP[g, LP_P0], LP[g, LP_FLAG] != 0.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _infinite_seen(LP, g, d, IMG):
    """Infinite light g along unit d: (its sampler's pdf of d, Le (3-tuple)); a DistantLight
    outside its cone (a delta one always) gives (0, black)."""
    Le = _lp(LP, g, LP_L)
    if LP[g, LP_KIND] == K_DOME:
        tex = int(LP[g, LP_TEX])
        if tex >= 0:
            i_rot, im_texels, im_offset, im_height, im_width, im_weight, im_total = IMG[:7]
            p_l, kt = _dome_texel_row(d, tex, i_rot[int(LP[g, LP_J])], im_height, im_width, im_weight, im_total,
                                      im_offset)
            return p_l, (Le[0] * im_texels[kt, 0], Le[1] * im_texels[kt, 1], Le[2] * im_texels[kt, 2])
        return _INV_4PI, Le
    p_l = _distant_pdf_row(d, _lp(LP, g, LP_A), LP[g, LP_P0], LP[g, LP_FLAG] != 0.0)
    if p_l <= 0.0:
        return 0.0, (0.0, 0.0, 0.0)
    return p_l, Le


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _tex_rect(LP, g):
    """Light g is a textured RectLight (its texel rows apply: _texrect_*)."""
    return LP[g, LP_KIND] == K_RECT and LP[g, LP_TEX] >= 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _texrect_sample(LP, g, p, u0, u1, IMG, min_sa, graz):
    """_light_sample for a textured RectLight: a texel picked by luminance and a point in it
    (kernels/lights.rect_texel_sample_row), the radiance the texel's colour at the sampled point
    (rect_radiance_row): RectLight.sample_li's rule. Kept out of the inlined _light_sample, so
    the untextured rows' code stays as it was."""
    IM = IMG[1:11]
    tex = int(LP[g, LP_TEX])
    ta, tb, t_pdf = rect_texel_sample_row(tex, u0, u1, LP[g, LP_AREA], IM)
    c = _lp(LP, g, LP_C)
    wi, dist, pdf, pl, ok = _rect_sample_row(p, u0, u1, c, _lp(LP, g, LP_A), _lp(LP, g, LP_B), _lp(LP, g, LP_XH),
                                             _lp(LP, g, LP_YH), LP[g, LP_P0], LP[g, LP_P1], _lp(LP, g, LP_N),
                                             LP[g, LP_AREA], True, LP[g, LP_FLAG] != 0.0, ta, tb, t_pdf, min_sa, graz)
    Le = rect_radiance_row(_lp(LP, g, LP_L), tex, pl, c, _lp(LP, g, LP_EXD), _lp(LP, g, LP_EYD), IM)
    return wi, dist, (pdf if ok else 0.0), Le, False


@njit(cache=True, nogil=True, error_model="numpy")
def _texrect_seen(LP, g, o, d, tl, IMG):
    """The radiance a ray o + t d meeting textured RectLight g's front at t = tl sees: L times
    the colour of the texel there (rect_radiance_row, RectLight.le's rule)."""
    q = (o[0] + tl * d[0], o[1] + tl * d[1], o[2] + tl * d[2])
    return rect_radiance_row(_lp(LP, g, LP_L), int(LP[g, LP_TEX]), q, _lp(LP, g, LP_C), _lp(LP, g, LP_EXD),
                             _lp(LP, g, LP_EYD), IMG[1:11])


@njit(cache=True, nogil=True, error_model="numpy")
def _texrect_pdf(LP, g, p, d, IMG, min_sa, graz):
    """_finite_pdf for a textured RectLight: its texel sampling's solid-angle pdf of direction d
    from p (the texel d meets: rect_texel_pdf_row; RectLight.pdf_li's rule)."""
    c = _lp(LP, g, LP_C)
    n = _lp(LP, g, LP_N)
    exd = _lp(LP, g, LP_EXD)
    eyd = _lp(LP, g, LP_EYD)
    _t, a, b, _hit = _rect_hit(p, d, c, n, exd, eyd)
    t_pdf = rect_texel_pdf_row(int(LP[g, LP_TEX]), a, b, LP[g, LP_AREA], IMG[1:11])
    return _rect_pdf_row(p, d, c, n, exd, eyd, _lp(LP, g, LP_A), _lp(LP, g, LP_B), _lp(LP, g, LP_XH),
                         _lp(LP, g, LP_YH), LP[g, LP_P0], LP[g, LP_P1], LP[g, LP_AREA], True, LP[g, LP_FLAG] != 0.0,
                         t_pdf, min_sa, graz)


@njit(cache=True, nogil=True, error_model="numpy")
def _portal_sample(LP, g, p, u0, u1, IMG, min_sa, graz):
    """_light_sample for a DomeLight with portals: kernels/portal.portal_dome_sample_row (through
    the portals usable from p, or the dome's own sampling), the radiance the dome's along wi."""
    (i_rot, im_texels, im_offset, im_height, im_width, im_weight, im_total, im_row_cdf, im_row_cdf_start,
     im_col_cdf, im_col_cdf_start) = IMG[:11]
    j = int(LP[g, LP_J])
    wi, pdf, kt = portal_dome_sample_row(IMG[IMG_PORTAL], IMG[IMG_PORTAL_T], int(LP[g, LP_PORTAL0]),
                                         int(LP[g, LP_PORTALS]), p, u0, u1, int(LP[g, LP_TEX]), i_rot[j], im_height,
                                         im_width, im_row_cdf, im_row_cdf_start, im_col_cdf, im_col_cdf_start,
                                         im_weight, im_total, im_offset, min_sa, graz)
    Le = _lp(LP, g, LP_L)
    if kt >= 0:
        Le = (Le[0] * im_texels[kt, 0], Le[1] * im_texels[kt, 1], Le[2] * im_texels[kt, 2])
    return wi, math.inf, pdf, Le, False


@njit(cache=True, nogil=True, error_model="numpy")
def _portal_pdf(LP, g, p, d, IMG, min_sa, graz):
    """The light pdf of a DomeLight with portals along unit d from p (portal_dome_pdf_row): the
    MIS weight of a BSDF ray that escapes to it must use the density its light samples have."""
    i_rot, _texels, im_offset, im_height, im_width, im_weight, im_total = IMG[:7]
    j = int(LP[g, LP_J])
    return portal_dome_pdf_row(IMG[IMG_PORTAL], IMG[IMG_PORTAL_T], int(LP[g, LP_PORTAL0]), int(LP[g, LP_PORTALS]),
                               p, d, int(LP[g, LP_TEX]), i_rot[j], im_height, im_width, im_weight, im_total,
                               im_offset, min_sa, graz)[0]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _light_sample(LP, g, p, u0, u1, IMG, close_ratio, min_sa, graz, ns):
    """A sample of light g from p (shading normal ns, for a mesh light's triangle pick) with
    uniforms (u0, u1): (wi, dist, pdf, Le, delta), pdf the solid-angle pdf (1 for a delta
    light) and 0 where the sample is unusable, dist inf for an infinite light (kernels/lights.py's
    samplers; kernels/cylinder.py's and kernels/mesh_light.py's rows). IMG: the domes' images,
    then (IMG[IMG_MESH]) the mesh lights' record."""
    kind = LP[g, LP_KIND]
    Le = _lp(LP, g, LP_L)
    delta = LP[g, LP_FLAG] != 0.0 and kind != K_RECT
    if kind == K_RECT and LP[g, LP_TEX] >= 0.0:
        return _texrect_sample(LP, g, p, u0, u1, IMG, min_sa, graz)
    if kind == K_DOME and LP[g, LP_PORTALS] > 0.0:
        return _portal_sample(LP, g, p, u0, u1, IMG, min_sa, graz)
    if kind == K_RECT:
        wi, dist, pdf, _pl, ok = _rect_sample_row(p, u0, u1, _lp(LP, g, LP_C), _lp(LP, g, LP_A), _lp(LP, g, LP_B),
                                                  _lp(LP, g, LP_XH), _lp(LP, g, LP_YH), LP[g, LP_P0], LP[g, LP_P1],
                                                  _lp(LP, g, LP_N), LP[g, LP_AREA], False, LP[g, LP_FLAG] != 0.0,
                                                  0.0, 0.0, 0.0, min_sa, graz)
        return wi, dist, (pdf if ok else 0.0), Le, False
    if kind == K_CYL:
        Lc, wi, pdf, dist, _x = cylinder_sample_row(LP, g, LP_CY, p, u0, u1)
        return wi, dist, pdf, Lc, delta
    if kind == K_MESH:
        Lm, wi, pdf, dist, _x = mesh_light_sample_row(IMG[IMG_MESH], int(LP[g, LP_J]), p, ns, u0, u1)
        return wi, dist, pdf, Lm, False
    if kind == K_SPHERE:
        wi, dist, pdf, _pl, ok, sc = _sphere_sample_row(p, u0, u1, _lp(LP, g, LP_C), LP[g, LP_P0], delta)
        return wi, dist, (pdf if ok else 0.0), (Le[0] * sc, Le[1] * sc, Le[2] * sc), delta
    if kind == K_DISK:
        wi, dist, pdf, _pl, ok = _disk_sample_row(p, u0, u1, _lp(LP, g, LP_C), _lp(LP, g, LP_N), _lp(LP, g, LP_A),
                                                  _lp(LP, g, LP_B), _lp(LP, g, LP_XH), _lp(LP, g, LP_YH),
                                                  LP[g, LP_P0], LP[g, LP_P1], LP[g, LP_AREA], close_ratio, min_sa,
                                                  graz)
        return wi, dist, (pdf if ok else 0.0), Le, False
    tex = int(LP[g, LP_TEX])
    if kind == K_DOME and tex >= 0:
        (i_rot, im_texels, im_offset, im_height, im_width, im_weight, im_total, im_row_cdf, im_row_cdf_start,
         im_col_cdf, im_col_cdf_start) = IMG[:11]
        wi, pdf, kt = _dome_sample_row(u0, u1, tex, i_rot[int(LP[g, LP_J])], im_height, im_width, im_row_cdf,
                                       im_row_cdf_start, im_col_cdf, im_col_cdf_start, im_weight, im_total, im_offset)
        Le = (Le[0] * im_texels[kt, 0], Le[1] * im_texels[kt, 1], Le[2] * im_texels[kt, 2])
    elif kind == K_DOME:
        wi = _uniform_sphere_row(u0, u1)
        pdf = _INV_4PI
    else:
        wi, pdf = _distant_sample_row(u0, u1, _lp(LP, g, LP_A), LP[g, LP_P0], delta)
    return wi, math.inf, pdf, Le, delta


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _light_along(LP, g, p, wi, IMG, close_ratio, min_sa, graz, ns):
    """Light g seen from p (shading normal ns) along unit wi (estimators.base.light_along, then
    pdf_li where it is seen): (t (inf for an infinite light or a miss), Le (black on a miss), p_l
    (0 on a miss))."""
    if LP[g, LP_KIND] == K_MESH:
        return mesh_light_along_row(IMG[IMG_MESH], int(LP[g, LP_J]), p, ns, wi)
    if LP[g, LP_KIND] == K_DOME or LP[g, LP_KIND] == K_DISTANT:
        p_l, Le = _infinite_seen(LP, g, wi, IMG)
        if LP[g, LP_KIND] == K_DOME and LP[g, LP_PORTALS] > 0.0:
            p_l = _portal_pdf(LP, g, p, wi, IMG, min_sa, graz)
        return math.inf, Le, p_l
    tl, Le, seen = _finite_seen(LP, g, p, wi)
    if not seen:
        return math.inf, (0.0, 0.0, 0.0), 0.0
    if _tex_rect(LP, g):
        return tl, _texrect_seen(LP, g, p, wi, tl, IMG), _texrect_pdf(LP, g, p, wi, IMG, min_sa, graz)
    return tl, Le, _finite_pdf(LP, g, p, wi, close_ratio, min_sa, graz)


@njit(cache=True, nogil=True, error_model="numpy")
def _light_F(LP, g, p, ns, theta_g, far_ratio, kappa_max):
    """Light g's unshadowed irradiance E (3-tuple) at p (3-tuple) about the shading normal ns,
    the control variate's F = c(wo) E: lights/irradiance.py's rule per kind, by the same compiled
    rows (lights/analytic.py's rect_F, sphere_F, disk_F on the radius s1, distant_F of the cone
    theta_g and dome_constant_F), for every light but a textured dome (_dome_table_F) and a mesh
    light (_mesh_F). far_ratio, kappa_max: the quadrature switches (FastPath.fcalc). Only LP
    crosses the call: each array argument of a call costs numba an atomic reference count increment and decrement, and the
    per-light estimators call this once per (vertex, light) pair."""
    kind = LP[g, LP_KIND]
    Le = _lp(LP, g, LP_L)
    if kind == K_RECT:
        G = rect_F(p, ns, _lp(LP, g, LP_C), _lp(LP, g, LP_A), _lp(LP, g, LP_B), _lp(LP, g, LP_N), far_ratio,
                   kappa_max)
    elif kind == K_SPHERE:
        G = sphere_F(p, ns, _lp(LP, g, LP_C), LP[g, LP_P0])
    elif kind == K_DISK:
        G = disk_F(p, ns, _lp(LP, g, LP_C), _lp(LP, g, LP_N), LP[g, LP_P0], far_ratio, kappa_max)
    elif kind == K_DISTANT:
        G = distant_F(ns, _lp(LP, g, LP_A), theta_g)
    elif kind == K_CYL:
        G = 0.0  # (no exact F: lights/irradiance.py; its estimators fall back to MIS)
    else:
        G = dome_constant_F()
    return (G * Le[0], G * Le[1], G * Le[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _dome_table_F(LP, g, ns, R, PK, tbuf):
    """_light_F of a textured dome g: its preconvolved table (preconvolve.irradiance_row through
    packed_row on PK, FastPath.fcalc's packed tables) at R^T ns, R (3, 3) the dome's local ->
    world rotation, times the dome's radiance scale; tbuf: packed_row's scratch."""
    Le = _lp(LP, g, LP_L)
    # The normal in the dome's frame (R^T ns; R local -> world), as DomeLight.irradiance_lookup.
    e = packed_row(PK, int(LP[g, LP_J]), ns[0] * R[0, 0] + ns[1] * R[1, 0] + ns[2] * R[2, 0],
                   ns[0] * R[0, 1] + ns[1] * R[1, 1] + ns[2] * R[2, 1],
                   ns[0] * R[0, 2] + ns[1] * R[1, 2] + ns[2] * R[2, 2], tbuf)
    return (e[0] * Le[0], e[1] * Le[1], e[2] * Le[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _mesh_F(LP, g, p, ns, MS, far_ratio, kappa_max):
    """_light_F of mesh light g: Lambert's polygon sum over its triangles about ns
    (kernels/mesh_light.mesh_G_row on its record MS, IMG[IMG_MESH]) times its radiance."""
    Le = _lp(LP, g, LP_L)
    j = int(LP[g, LP_J])
    G = mesh_G_row(p, ns, MS[3][j], MS[4][j], MS[0], MS[1], MS[5][j], far_ratio, kappa_max)
    return (G * Le[0], G * Le[1], G * Le[2])


@njit(cache=True, nogil=True, error_model="numpy")
def _table_F(LP, g):
    """Whether light g's F comes from its preconvolved table (_dome_table_F: a textured dome),
    else from _light_F."""
    return LP[g, LP_KIND] == K_DOME and LP[g, LP_TEX] >= 0.0


@njit(cache=True, nogil=True)
def _uses_F(tok, exact):
    """Whether the estimator of token index tok takes a group with F (estimators/compiled.py:
    the control variate and ratio, where F is exact; estimate's mode is not NO_GROUP then)."""
    return exact and (tok == ec.T_CV or tok == ec.T_RATIO)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _split_at(V, Pm, wx, wy, wz, Le, sd, ss):
    """The integrand of the vertex V's BSDF at world direction (wx, wy, wz) for radiance Le,
    split as estimators.base.split_integrand does (light samples and BSDF samples alike), with
    the light's diffuse and specular multipliers sd, ss (kernels.direct.split_kernel's rule):
    (fd, fs, p_b, wl_z, cos_g): fd = g sd |cos| Le the control lobe, fs = ((f_d - g) sd + f_s ss)
    |cos| Le the residual (3-tuples), p_b the BSDF pdf, wl_z the direction's shading-frame cosine
    and cos_g its geometric one. f = f_d + f_s is _preview_kernels.eval_kernel's (0 unless the
    specular factors are defined), g the control lobe c(wo) (0 unless both directions are above
    the shading normal). V: (p, ng, fs, ft, ns, wo, ao, bo, p_d, eps, m), its vectors 3-tuples."""
    _p, ng, sf, tf, ns, wo, ao, bo, p_d, _eps, m = V
    a, j0, fy, kd, f0, f90 = _mat(Pm, m)
    lx = wx * sf[0] + wy * sf[1] + wz * sf[2]
    ly = wx * tf[0] + wy * tf[1] + wz * tf[2]
    lz = wx * ns[0] + wy * ns[1] + wz * ns[2]
    cos_g = wx * ng[0] + wy * ng[1] + wz * ng[2]
    oks, dv, fw, pdf_s = _specular_i(wo[0], wo[1], wo[2], lx, ly, lz, a)
    ai, bi = _albedo(lz, j0, fy)
    p_b = p_d * lz * _INV_PI + (1.0 - p_d) * pdf_s if oks else 0.0
    up = lz > 0.0 and wo[2] > 0.0
    cos = abs(lz)
    fd = (0.0, 0.0, 0.0)
    fs = (0.0, 0.0, 0.0)
    for c in range(3):
        g = _diffuse_constant(Pm[m, RHO + c], f0[c], f90[c], ao, bo) if up else 0.0
        f_d = _f_d(kd[c], f0[c], f90[c], ao, bo, ai, bi) if oks else 0.0
        f_s = (f0[c] + (f90[c] - f0[c]) * fw) * dv if oks else 0.0
        k = cos * Le[c]
        fd = _set3(fd, c, g * sd * k)
        fs = _set3(fs, c, ((f_d - g) * sd + f_s * ss) * k)
    return fd, fs, p_b, lz, cos_g


@njit(cache=True, nogil=True, inline="always")
def _set3(t, c, x):
    """The 3-tuple t with component c (0, 1 or 2) replaced by x."""
    return (x if c == 0 else t[0], x if c == 1 else t[1], x if c == 2 else t[2])


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _record(smp, i, wi, dist, p_l, p_b, fd, fs, usable):
    """Row i of a sample record (estimators/compiled.py's columns); S_TR where usable and some
    channel of fd or fs is positive (estimators.base: shadow rays only there)."""
    for c in range(3):
        smp[i, ec.S_WI + c] = wi[c]
        smp[i, ec.S_FD + c] = fd[c]
        smp[i, ec.S_FS + c] = fs[c]
    smp[i, ec.S_DIST] = dist
    smp[i, ec.S_PL] = p_l
    smp[i, ec.S_PB] = p_b
    pos = fd[0] > 0.0 or fd[1] > 0.0 or fd[2] > 0.0 or fs[0] > 0.0 or fs[1] > 0.0 or fs[2] > 0.0
    smp[i, ec.S_TR] = 1.0 if (usable and pos) else 0.0


@njit(cache=True, nogil=True, inline="always")
def _est_u(key, c, lq, i, pair, coord):
    """Number c of an estimator's stream (splitmix_u01(key, c)), or with lq = (on, pixel key,
    pass, first pair) on: coordinate coord of the pixel's low-discrepancy pair
    ``first + 3 i + pair`` at the pass (kernels/sobol.py). Sample i of the N has pairs of its
    own: the N samples of one pass stay independent of each other, as the estimators' formulas
    assume (the 1/(N - 1) control variate, the talk's bias of alpha = v_bar), and each is
    stratified over the passes."""
    on, pk, sidx, dim0 = lq
    if on:
        return sobol_u01(pk, sidx, dim0 + np.uint64(3 * i + pair), coord)
    return splitmix_u01(key, c)


@njit(cache=True, nogil=True, inline="always")
def _est_u2(key, c, lq, i, pair):
    """_est_u's numbers c and c + 1 as one pair's two coordinates (one sobol_pair)."""
    on, pk, sidx, dim0 = lq
    if on:
        return sobol_pair(pk, sidx, dim0 + np.uint64(3 * i + pair))
    return splitmix_u01(key, c), splitmix_u01(key, c + np.uint64(1))


@njit(cache=True, nogil=True)
def lds_at(lds, bounce, n_u):
    """The vertex kernel's lds record at a bounce from trace_kernel's (pix, sidx, roles): the
    bounce's first dimension pair is bounce * n_u. For compiled callers (FastPath.trace_loop
    builds the same tuple in Python, keeping the uint64s)."""
    return lds[0], lds[1], np.uint64(bounce * n_u), lds[2]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _draw_pair(g, N, need_l, need_b, V, Pm, key, ctr, lq, LP, IMG, lcon, sd, ss, ls, bs, SHP):
    """Light g's N light samples into ls and N BSDF samples into bs (those its estimator needs)
    at the vertex V, as estimators.base.light_samples and bsdf_samples draw them: uniforms
    splitmix_u01(key, ctr + 1 ...), five per sample, or the pixel's sequence (lq, _est_u: the
    light's point a pair, the lobe 1D, the direction a pair); sd, ss: the light's diffuse and
    specular multipliers (_split_at). SHP: the ShapingAPI record (_shaped)."""
    p, ng, sf, tf, ns, wo, ao, bo, p_d, eps, m = V
    for i in range(N if need_l else 0):
        c = ctr + np.uint64(5 * i + 1)
        u0, u1 = _est_u2(key, c, lq, i, 0)
        wi, dist, pdf, Le, delta = _light_sample(LP, g, p, u0, u1, IMG, lcon[0], lcon[1], lcon[2], ns)
        if LP[g, LP_SHAPE] >= 0.0:
            Le = _shaped(LP, g, SHP, wi, Le)
        fd, fs, p_b, lz, cos_g = _split_at(V, Pm, wi[0], wi[1], wi[2], Le, sd, ss)
        above = lz > 0.0 and cos_g > 0.0
        if not above:
            fd = (0.0, 0.0, 0.0)
            fs = (0.0, 0.0, 0.0)
        # Delta lights cannot be reached by BSDF samples: their p_l is "infinite" for MIS.
        _record(ls, i, wi, dist, math.inf if delta else pdf, p_b, fd, fs, pdf > 0.0 and above)
    a = Pm[m, ALPHA]
    for i in range(N if need_b else 0):
        c = ctr + np.uint64(5 * i + 3)
        # The BSDF's own sample (_preview_kernels.sample_kernel), to world.
        u1, u2 = _est_u2(key, c + np.uint64(1), lq, i, 2)
        wl = _sample_dir_i(wo[0], wo[1], wo[2], a, _est_u(key, c, lq, i, 1, 0) < p_d, u1, u2)
        wx = wl[0] * sf[0] + wl[1] * tf[0] + wl[2] * ns[0]
        wy = wl[0] * sf[1] + wl[1] * tf[1] + wl[2] * ns[1]
        wz = wl[0] * sf[2] + wl[1] * tf[2] + wl[2] * ns[2]
        # Lights are intersected from p itself (estimators.base.bsdf_samples).
        t_l, Le, p_l = _light_along(LP, g, p, (wx, wy, wz), IMG, lcon[0], lcon[1], lcon[2], ns)
        if LP[g, LP_SHAPE] >= 0.0:
            Le = _shaped(LP, g, SHP, (wx, wy, wz), Le)
        fd, fs, p_b, lz, cos_g = _split_at(V, Pm, wx, wy, wz, Le, sd, ss)
        hit = p_b > 0.0 and cos_g > 0.0 and wl[2] > 0.0 and (Le[0] > 0.0 or Le[1] > 0.0 or Le[2] > 0.0)
        if not hit:
            fd = (0.0, 0.0, 0.0)
            fs = (0.0, 0.0, 0.0)
        _record(bs, i, (wx, wy, wz), t_l, p_l if hit else 0.0, p_b, fd, fs, hit)


@njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
def _direct_pair(g, tok, alpha, N, power_g, exact, E, sd, ss, V, Pm, beta, pr_path, key, ctr, lq, LP, IMG, lcon, SH,
                 GR, k_sh, k_grp, scratch, SHP):
    """Light g's whole direct contribution at the vertex V (not on continuation MIS there) by its
    estimator (token index tok, α index alpha, N samples, heuristic power_g; exact, E: whether
    its F = c(wo) E is exact and E (3-tuple; _light_F, taken by the caller where _uses_F); sd,
    ss: the light's diffuse and specular multipliers, FastPath.mult): the samples (_draw_pair),
    the estimator's coefficients (estimators/compiled.py), then the shadow rays at SH[k_sh:]
    (sh_o, sh_d, sh_t, sh_path, sh_c, sh_x, sh_cov: sh_c the radiance each adds if unblocked,
    sh_x, sh_cov its X and covered flag; the caller writes their light) and, for a diffuse
    combination, group k_grp of GR (g_int (path, first ray, rays, N, mode), g_f (F, beta)),
    which resolve_groups_kernel adds once the rays are traced. Returns the new (k_sh, k_grp).
    SHP: the ShapingAPI record (_shaped). Called once per (vertex, light) pair. Compiled
    without reference counting (``_nrt=False``, as the pair helpers it calls: they allocate
    nothing and only borrow their arrays): with it numba incremented and decremented the count
    of each of its ~30 array arguments per call (~20 ns an array, light_bvh.py), which made a
    light sample through this route cost ~1 us more than the continuation MIS's."""
    ls, bs, cl, cb = scratch
    need_l, need_b = ec.needs(tok)
    _draw_pair(g, N, need_l, need_b, V, Pm, key, ctr, lq, LP, IMG, lcon, sd, ss, ls, bs, SHP)
    mode = ec.estimate(tok, N, ls, bs, power_g, exact, alpha, cl, cb)
    sh_o, sh_d, sh_t, sh_path, sh_c, sh_x, sh_cov = SH
    p, ng, eps = V[0], V[1], V[9]
    first = k_sh
    for half in range(2):
        smp = ls if half == 0 else bs
        co = cl if half == 0 else cb
        for i in range(N if (need_l if half == 0 else need_b) else 0):
            c0 = beta[0] * co[i, ec.C_C]
            c1 = beta[1] * co[i, ec.C_C + 1]
            c2 = beta[2] * co[i, ec.C_C + 2]
            cov = co[i, ec.C_COV] if half == 0 and mode != ec.NO_GROUP else 0.0
            # Only rays whose visibility changes the estimate (the sample above ng: offset along it).
            if smp[i, ec.S_TR] == 0.0 or (c0 == 0.0 and c1 == 0.0 and c2 == 0.0 and cov == 0.0):
                continue
            dist = smp[i, ec.S_DIST]
            for c in range(3):
                sh_o[k_sh, c] = p[c] + ng[c] * eps
                sh_d[k_sh, c] = smp[i, ec.S_WI + c]
                sh_x[k_sh, c] = co[i, ec.C_X + c] if cov > 0.0 else 0.0
            sh_t[k_sh] = dist * (1.0 - 1e-5) - eps if dist < math.inf else 1e37
            sh_path[k_sh] = pr_path
            sh_c[k_sh, 0] = c0
            sh_c[k_sh, 1] = c1
            sh_c[k_sh, 2] = c2
            sh_cov[k_sh] = cov
            k_sh += 1
    if mode != ec.NO_GROUP:
        g_int, g_f = GR
        g_int[k_grp, 0] = pr_path
        g_int[k_grp, 1] = first
        g_int[k_grp, 2] = k_sh - first
        g_int[k_grp, 3] = N
        g_int[k_grp, 4] = mode
        _p, _ng, _sf, _tf, _ns, wo, ao, bo, _pd, _eps, m = V
        a, j0, fy, kd, f0, f90 = _mat(Pm, m)
        for c in range(3):
            # F = c(wo) E sd (estimators.control_variates.diffuse_cv_inputs).
            g_f[k_grp, c] = _diffuse_constant(Pm[m, RHO + c], f0[c], f90[c], ao, bo) * E[c] * sd if wo[2] > 0.0 else 0.0
            g_f[k_grp, 3 + c] = beta[c]
        k_grp += 1
    return k_sh, k_grp


@njit(cache=True, nogil=True)
def vertex_kernel(
    path, depth, unsampled, S, hit_t, hit_prim, hit_b1, hit_b2, key, lds, n_u, surf, max_depth,
    vertices, face_normal, normals, tri_mat, tri_mag,
    center, ex, ey, x_hat, y_hat, edge_len, nrm, area, radiance, is_rect, exd, eyd, rect_light,
    s_center, s_radius, s_radiance, s_delta, sphere_light,
    d_center, d_nrm, d_u1, d_u2, d_e1, d_e2, d_s1, d_s2, d_area, d_radiance, disk_light, close_ratio,
    i_dome, i_axis, i_omc, i_delta, i_radiance, inf_light, i_tex, i_rot,
    im_texels, im_offset, im_height, im_width, im_weight, im_total, im_row_cdf, im_row_cdf_start, im_col_cdf,
    im_col_cdf_start,
    power, min_sa, graz, rr_depth, eps_rel, eps_floor, eps_add, fast_of, sp, lux, fcalc, mult, cyl, mesh,
    portal, texrect, tex,
    L, n_path, n_depth, n_S, n_o32, n_d32, n_t32, sh_o, sh_d, sh_t, sh_path, sh_c, counts, est, est_out,
):
    """One bounce for n live rays (see the module docstring). The arguments from ``vertices``
    to ``eps_add`` describe the scene and stay fixed for a render (FastPath.tables).

    path, depth: (n,) int64 (the path's row in L, scattering events so far); unsampled: (n,) bool
    (camera rays: emission counts fully; all others carry continuation MIS for every light, with
    the pick pmf of the service at the vertex they left); hit_*:
    embree's closest hits as Accel.intersect_prepared gives them (float32 t, u, v; int32 prim, -1 on
    a miss, where t is meaningless); key: uint64, n_u: uniforms per row (4 + 2 lights, or 4 + 3
    with a picking service: the pick's u, then the light sample's two): the
    rows' uniforms are _uniform_pass's stream for key, drawn block by block, or with lds =
    (pix, sidx, dim0, roles) and pix (paths,) uint64 not empty, each path's pixel's
    low-discrepancy numbers (_sobol_pass; FastPath.trace's record); surf: the record
    (Pm, mat_row, emission, bent_ns) (materials.surface_hits' with tex): Pm (materials, K) packed BSDF rows,
    or with mat_row (n,) non-empty, per-hit rows: ray r's row is mat_row[r], emission (hits, 3)
    (if not empty; (materials, 3) by the hit's material where mat_row is empty: constant
    emission) the radiance its surface emits (added in full: emitting surfaces are reached
    by BSDF samples only, as in the general path) and bent_ns (hits, 3) (if not empty) its
    normal-mapped shading normal; light tables: the
    RectLight arrays (their textures in texrect), the SphereLight arrays (s_*), the DiskLight arrays (d_*) and
    the infinite lights (i_*: i_dome True for a DomeLight, with i_tex its image in the ImageSet
    im_* or -1 for a constant one and i_rot (3, 3) its local -> world rotation; else a
    DistantLight with i_axis, i_omc = 1 - cos theta_max, i_delta), with rect_light / sphere_light / disk_light /
    inf_light (count,) the global light index of each (which picks the light's uniforms in U and
    its power flag); power: (lights,) bool heuristic; fast_of (lights,) int64: each global
    light's index in the kernel's order (rect, sphere, disk, cylinder, mesh, then infinite
    lights); sp: the lighting service's record (kernels/light_pick.py;
    light_samplers.pick_tables); lux: the UsdLux
    record (FastPath.lux: each global light's ShapingAPI row, -1 unshaped, and
    ShapingTable.kernel_record(); lightLink: each triangle's mesh (T,) int64 and illum (lights,
    meshes) bool, or (0, 0) without light linking); fcalc: the
    analytic integrals' record (FastPath.fcalc, read by _light_F); mult: the lights' (diffuse,
    specular) multipliers, (lights,) each in kernel order (lights with other than 1 are never on
    continuation MIS: their estimators apply them, _split_at); cyl: the CylinderLights' record
    (packed rows (k, kernels.cylinder.NCY), radiance (k, 3), global index (k,)); mesh: the mesh
    lights' record (FastPath._mesh_record: MeshLight.compiled_record(), global index (k,), and
    per scene triangle its mesh light, its triangle in the record and whether it absorbs);
    portal: the domes' portals (DomeLight.portal_record's PP and PT, kernels/portal.py; each
    dome's first row and count: a dome with portals samples and weighs through them,
    _portal_sample and _portal_pdf); texrect: (rects,) int64 each rect's image in the im_* set
    (after the domes'), -1 untextured (_texrect_*); tex: the per-hit surfaces' record
    (MaterialTable.hit_record: textured inputs, emission, normal maps), or None where one packed
    row per material serves: with it, surf's rows are materials.surface_hits' at this bounce's
    hits (the general path's evaluate, make_bsdf and bent normals, one compiled row a hit). L (m, 3)
    receives emission in place. Next rays go to n_path, n_depth, n_S and, in embree's float32
    format, n_o32, n_d32, n_t32 (capacity n); shadow rays to sh_o, sh_d, sh_t (float32), sh_path,
    sh_c (capacity n * the shadow rays a vertex may write: FastPath._estimators' cap), sh_c (k, 3)
    being the radiance each adds if unblocked. counts[0], counts[1]: how many of each; counts[2]:
    how many vertices scattered (took the light half); counts[3]: how many estimator groups (below);
    counts[4 + l] (zero on entry) gains the (vertex, light l) pairs this bounce estimated.
    est_out[4] (capacity as sh_path) receives each shadow ray's light (kernel order), for its
    shadowLink BVH and ShadowAPI settings (FastPath._visibility).

    est, est_out: the per-light estimators' records (FastPath._estimators). Lights on continuation
    MIS at this bounce's vertices (est[3]) take the light half above; every other light takes its
    whole contribution from its estimator (_direct_pair: N light and/or BSDF samples, their shadow
    rays in sh_* with their X and covered flag in est_out[0:2], and for the control variate and
    ratio a group in est_out[2:4] that resolve_groups_kernel adds once the rays are traced), divided
    by the pick's pmf as path.py's _direct does. A continuation ray adds emission only for the
    lights on continuation MIS at the vertex it left (est[4]), weighted with the pmf replayed there.

    The rows go in blocks of BLK: vectorised passes (_surface_pass; with the exhaustive service,
    when a row of the block scatters, each rect and sphere light's batch sampler and _light_pass)
    fill the block's state, then one scalar pass per row adds emission, takes the other lights'
    light half or estimator (or the picked light's: _light_sample, _direct_pair) and writes the rays compactly.
    """
    Pm, mat_row, emission, bent_ns = surf
    # The cylinder lights (FastPath.tables' cyl): packed rows (renderer/kernels/cylinder.py),
    # radiance and global index of each.
    cy_packed, cy_L, cyl_light = cyl
    # The mesh lights (FastPath.tables' mesh): their record (kernels/mesh_light.py), global
    # index of each, and per scene triangle its mesh light (global, -1: none), its triangle in the
    # record (-1: unknown) and whether it absorbs (materialSyncMode noMaterialResponse).
    MS, mesh_light, prim_light, prim_tri, prim_absorb = mesh
    if tex is not None:
        Pm, mat_row, emission, bent_ns = surface_hits(tex, vertices, face_normal, normals, tri_mat, hit_prim, hit_b1,
                                                      hit_b2, S, D)
    n_rect = center.shape[0]
    n_rs = n_rect + s_center.shape[0]  # rect, sphere, disk, cylinder, mesh, then infinite lights
    n_fin = n_rs + d_center.shape[0] + cy_packed.shape[0] + mesh_light.shape[0]
    nl = n_fin + i_radiance.shape[0]
    k_next = 0
    k_sh = 0
    n_vertices = 0
    n = path.shape[0]
    # A lighting service that picks (uniform, power, bvh): one light per vertex, sampled by its
    # row sampler, and the lights a ray crosses found through the light BVH (light_pick.py);
    # the exhaustive one: every light, the rect and sphere lights sampled block-wise.
    picks = sp[0] != EXHAUSTIVE
    n_batch = 0 if picks else n_rs
    # Scratch of the light BVH walk (crossed_row): its stack (tree depth + 2) and the lights found.
    stack = np.empty((sp[9].max() if sp[9].shape[0] else 0) + 2, dtype=np.int64)
    found = np.empty(max(n_fin, 1), dtype=np.int64)
    W = np.empty(NW * BLK)
    # The block state as (NW, BLK) rows: its first three (W_P = 0) are the hit points the batch
    # samplers read.
    W2 = W.reshape((NW, BLK))
    C = np.empty((n_batch, 4 * BLK))
    # The block's rect and sphere light samples (wi, distance, pdf, radiance scale).
    R = np.empty((n_batch, 6, BLK))
    # 1.0 for the block's rows that may cross a rect or sphere light (_cross_pass).
    X = np.empty(BLK)
    # The block's uniforms, (n_u, BLK): columns U_* of the module docstring.
    UB = np.empty((n_u, BLK))
    # The passes read triangle 0 and material row 0 for rows that missed: only when they exist
    # (no geometry or, with per-hit rows, no hit at all: nothing scatters).
    surfaces = vertices.shape[0] > 0 and Pm.shape[0] > 0
    # The lights as one table for the per-light helpers (_finite_seen and the rest), the domes'
    # images, and the samplers' constants.
    LP = _with_kinds(_light_table(center, ex, ey, x_hat, y_hat, edge_len, nrm, area, radiance, is_rect, exd, eyd,
                                      s_center, s_radius, s_radiance, s_delta, d_center, d_nrm, d_u1, d_u2, d_e1, d_e2,
                                      d_s1, d_s2, d_area, d_radiance, i_dome, i_axis, i_omc, i_delta, i_radiance,
                                      i_tex), n_rs + d_center.shape[0], cy_packed, cy_L, MS[6])
    IMG = (i_rot, im_texels, im_offset, im_height, im_width, im_weight, im_total, im_row_cdf, im_row_cdf_start,
           im_col_cdf, im_col_cdf_start, MS, portal[0], portal[1])
    # Each dome's portal rows and each rect's image (-1: untextured) into LP (LP_PORTAL0,
    # LP_PORTALS, LP_TEX).
    portal_start = portal[2]
    portal_count = portal[3]
    rect_tex = texrect
    for g in range(LP.shape[0]):
        if LP[g, LP_KIND] == K_DOME:
            LP[g, LP_PORTAL0] = portal_start[int(LP[g, LP_J])]
            LP[g, LP_PORTALS] = portal_count[int(LP[g, LP_J])]
        elif LP[g, LP_KIND] == K_RECT:
            LP[g, LP_TEX] = rect_tex[int(LP[g, LP_J])]
    lcon = (close_ratio, min_sa, graz)
    # The global index of each light in the kernel's order.
    glob = np.concatenate((rect_light, sphere_light, disk_light, cyl_light, mesh_light, inf_light))
    # ShapingAPI: each light's shaping row in LP, the factor's tables in SHP (_shaped).
    shp_row = lux[0]
    SHP = lux[1]
    # lightLink: each triangle's mesh and illum[light, mesh] (empty: every light lights everything).
    tri_mesh = lux[2]
    illum = lux[3]
    linked = illum.shape[0] > 0
    for g in range(nl):
        LP[g, LP_SHAPE] = shp_row[glob[g]]
    # The per-light estimators (FastPath.trace's record): token, alpha and N per light at this
    # bounce's vertices; whether each light is on continuation MIS there (cont) and was at the
    # vertex the rays left (cont_prev); the key of their uniforms (F is taken per pair, _light_F).
    # Outputs: each shadow ray's X and covered flag, the groups, and each shadow ray's light.
    e_tok, e_alpha, e_N, cont, cont_prev, e_key = est
    sh_x, sh_cov, g_int, g_f, sh_l = est_out
    SH = (sh_o, sh_d, sh_t, sh_path, sh_c, sh_x, sh_cov)
    GR = (g_int, g_f)
    n_max = max(1, e_N.max()) if nl else 1
    scratch = (np.empty((n_max, ec.NSMP)), np.empty((n_max, ec.NSMP)), np.empty((n_max, ec.NC)),
               np.empty((n_max, ec.NC)))
    # F's record and the multipliers, unpacked once here (each pair reads its light's entries:
    # taking an array out of a tuple per pair costs an atomic reference count pair).
    f_exact, f_theta, far_ratio, kappa_max, f_pk = fcalc
    tbuf = np.empty(f_pk[-1])
    m_d, m_s = mult
    k_grp = 0
    lds_pix, lds_sidx, lds_dim0, lds_roles = lds
    sobol = lds_pix.shape[0] > 0
    # The per-light estimators' pairs (3 a sample: its point, the lobe, the direction; up to
    # 2^20 samples a light), apart from the rows' columns.
    est_dim0 = np.uint64(1 << 62) + lds_dim0 * np.uint64(3 << 40)
    for lo in range(0, n, BLK):
        hi = min(n, lo + BLK)
        if sobol:
            _sobol_pass(lo, hi, UB, path, lds_pix, lds_sidx, lds_dim0, lds_roles)
        else:
            _uniform_pass(key, lo, hi, UB)
        if surfaces:
            _surface_pass(lo, hi, hit_prim, hit_b1, hit_b2, S, UB, depth, Pm, mat_row, bent_ns, vertices,
                          face_normal, normals, tri_mat, tri_mag, rr_depth, eps_rel, eps_floor, eps_add, W)
            # Light samples only for a block where some row scatters (none at the last bounce).
            sampled = False
            for r in range(lo, hi):
                sampled = sampled or (hit_prim[r] >= 0 and depth[r] < max_depth)
            if sampled and not picks:
                for j in range(n_rect):
                    if not cont[rect_light[j]] or rect_tex[j] >= 0:
                        continue  # its estimator samples it in the scalar pass, or _light_sample (textured)
                    rect_sample_batch_kernel(W2, UB, U_LIGHT + 2 * rect_light[j], 0, hi - lo, _row(center, j),
                                             _row(ex, j), _row(ey, j), _row(x_hat, j), _row(y_hat, j), edge_len[j, 0],
                                             edge_len[j, 1], _row(nrm, j), area[j], is_rect[j], min_sa, graz, R[j])
                    _light_pass(lo, hi, R[j], False, radiance[j, 0], radiance[j, 1], radiance[j, 2], False,
                                power[rect_light[j]], S, W, Pm, C[j])
                for j in range(n_rs - n_rect):
                    g = n_rect + j
                    if not cont[sphere_light[j]]:
                        continue
                    sphere_sample_batch_kernel(W2, UB, U_LIGHT + 2 * sphere_light[j], 0, hi - lo, _row(s_center, j),
                                               s_radius[j], s_delta[j], R[g])
                    _light_pass(lo, hi, R[g], True, s_radiance[j, 0], s_radiance[j, 1], s_radiance[j, 2],
                                s_delta[j], power[sphere_light[j]], S, W, Pm, C[g])
        if n_rs and not picks:
            _cross_pass(lo, hi, S, hit_t, hit_prim, center, nrm, exd, eyd, s_center, s_radius, s_delta, X)
        for r in range(lo, hi):
            i = r - lo
            pr_path = path[r]
            b0 = S[r, B]
            b1 = S[r, B + 1]
            b2 = S[r, B + 2]
            o = (S[r, O], S[r, O + 1], S[r, O + 2])
            d = (S[r, D], S[r, D + 1], S[r, D + 2])
            k = hit_prim[r]
            t_hit = float(hit_t[r]) if k >= 0 else math.inf
            t_geo = min(t_hit, S[r, TMAX])
            # ---- emission of the lights crossed before the surface (lights are transparent) ----
            # Picking services: the lights whose BVH nodes the ray meets. Exhaustive: every light,
            # the rect and sphere lights only where _cross_pass found the row may cross one.
            if picks:
                n_c = crossed_row(sp, o[0], o[1], o[2], d[0], d[1], d[2], t_geo, stack, found) if n_fin else 0
                g0 = 0
            else:
                g0 = 0 if n_rs and X[i] != 0.0 else n_rs
                n_c = n_fin - g0
            for c_ in range(n_c):
                g = fast_of[found[c_]] if picks else g0 + c_
                gl = glob[g]
                # A light whose estimator covered it at the vertex the ray left adds nothing here,
                # nor one that does not illuminate that vertex's mesh (lightLink).
                if not (unsampled[r] or cont_prev[gl]):
                    continue
                if linked and not unsampled[r] and not illum[gl, int(S[r, PM])]:
                    continue
                tl, Le, seen = _finite_seen(LP, g, o, d)
                if not (seen and tl < t_geo):
                    continue
                tex_rect = _tex_rect(LP, g)
                if tex_rect:
                    Le = _texrect_seen(LP, g, o, d, tl, IMG)
                if LP[g, LP_SHAPE] >= 0.0:
                    Le = _shaped(LP, g, SHP, d, Le)
                if unsampled[r]:
                    w = 1.0
                else:
                    # h(p_b, pmf p_l): p_l and the service's pmf from the vertex the ray left, as
                    # the light half there used.
                    pv = (S[r, PP], S[r, PP + 1], S[r, PP + 2])
                    p_l = (_texrect_pdf(LP, g, pv, d, IMG, min_sa, graz) if tex_rect
                           else _finite_pdf(LP, g, pv, d, close_ratio, min_sa, graz))
                    pmf = pick_pmf_row(sp, gl, pv[0], pv[1], pv[2], S[r, PN], S[r, PN + 1], S[r, PN + 2])
                    w = _mis_weight(S[r, PB], p_l * pmf, power[gl])
                L[pr_path, 0] += b0 * Le[0] * w
                L[pr_path, 1] += b1 * Le[1] * w
                L[pr_path, 2] += b2 * Le[2] * w
            if k < 0:
                # ---- escaped: the infinite lights (a camera ray sees them whatever its far clip) --
                for q in range(n_fin, nl):
                    gl = glob[q]
                    if not (unsampled[r] or cont_prev[gl]):
                        continue
                    if linked and not unsampled[r] and not illum[gl, int(S[r, PM])]:
                        continue
                    p_l, Le = _infinite_seen(LP, q, d, IMG)
                    if Le[0] == 0.0 and Le[1] == 0.0 and Le[2] == 0.0:
                        continue  # outside a distant light's cone (a delta light is never seen)
                    if unsampled[r]:
                        w = 1.0
                    else:
                        if LP[q, LP_KIND] == K_DOME and LP[q, LP_PORTALS] > 0.0:
                            # Through portals: the density the light half drew with from the vertex.
                            p_l = _portal_pdf(LP, q, (S[r, PP], S[r, PP + 1], S[r, PP + 2]), d, IMG, min_sa, graz)
                        pmf = pick_pmf_row(sp, gl, S[r, PP], S[r, PP + 1], S[r, PP + 2], S[r, PN], S[r, PN + 1],
                                           S[r, PN + 2])
                        w = _mis_weight(S[r, PB], p_l * pmf, power[gl])
                    L[pr_path, 0] += b0 * Le[0] * w
                    L[pr_path, 1] += b1 * Le[1] * w
                    L[pr_path, 2] += b2 * Le[2] * w
                continue
            if prim_light.shape[0] > 0 and prim_light[k] >= 0:
                # ---- a mesh light's triangle (scene geometry): its emission here, MIS-weighted on
                # continuation rays with its pdf and pmf at the vertex the ray left (path.py's
                # _add_mesh_light_hits) ----
                gl = prim_light[k]
                # (Nor one that does not illuminate the mesh of the vertex the ray left: lightLink.)
                if (unsampled[r] or cont_prev[gl]) and not (linked and not unsampled[r]
                                                             and not illum[gl, int(S[r, PM])]):
                    j = int(LP[fast_of[gl], LP_J])
                    Le = _shaped(LP, fast_of[gl], SHP, d, mesh_light_emission_row(
                        MS, j, -(d[0] * face_normal[k, 0] + d[1] * face_normal[k, 1] + d[2] * face_normal[k, 2])))
                    if Le[0] != 0.0 or Le[1] != 0.0 or Le[2] != 0.0:
                        if unsampled[r]:
                            w = 1.0
                        else:
                            pv = (S[r, PP], S[r, PP + 1], S[r, PP + 2])
                            pn = (S[r, PN], S[r, PN + 1], S[r, PN + 2])
                            # The light's first triangle along d from pv (the one hit, or found).
                            tri = prim_tri[k]
                            if tri >= 0:
                                t_l = plane_distance_row(tri, pv, d, MS[0], MS[1])
                            else:
                                t_l, tri = mesh_hit_row(pv, d, MS[3][j], MS[4][j], MS[0])
                            p_l = mesh_light_pdf_row(MS, j, pv, pn, d, tri, t_l)
                            pmf = pick_pmf_row(sp, gl, pv[0], pv[1], pv[2], pn[0], pn[1], pn[2])
                            w = _mis_weight(S[r, PB], p_l * pmf, power[gl])
                        L[pr_path, 0] += b0 * Le[0] * w
                        L[pr_path, 1] += b1 * Le[1] * w
                        L[pr_path, 2] += b2 * Le[2] * w
                if prim_absorb[k]:
                    continue  # noMaterialResponse: the path ends here (path.py zeroes beta)
            if emission.shape[0] > 0:
                m = mat_row[r] if mat_row.shape[0] > 0 else tri_mat[k]
                L[pr_path, 0] += b0 * emission[m, 0]
                L[pr_path, 1] += b1 * emission[m, 1]
                L[pr_path, 2] += b2 * emission[m, 2]
            if depth[r] >= max_depth:
                continue
            n_vertices += 1
            px = W[W_P * BLK + i]
            py = W[(W_P + 1) * BLK + i]
            pz = W[(W_P + 2) * BLK + i]
            eps = W[W_EPS * BLK + i]
            # ---- direct light: every light (exhaustive), or the one the service picks, by continuation
            # MIS's light half or by the light's own estimator, divided by the pick's pmf --------
            for q in range(1 if picks else nl):
                if picks:
                    gl, pmf = pick_row(sp, UB[U_LIGHT, i], px, py, pz, W[W_N * BLK + i], W[(W_N + 1) * BLK + i],
                                       W[(W_N + 2) * BLK + i])
                    if not pmf > 0.0:
                        continue
                    g = fast_of[gl]
                    u0 = UB[U_LIGHT + 1, i]
                    u1 = UB[U_LIGHT + 2, i]
                else:
                    g = q
                    pmf = 1.0
                    gl = glob[g]
                    u0 = UB[U_LIGHT + 2 * gl, i]
                    u1 = UB[U_LIGHT + 2 * gl + 1, i]
                if linked and not illum[gl, tri_mesh[k]]:
                    continue  # lightLink: the light does not illuminate this mesh
                counts[4 + gl] += 1
                if not cont[gl]:
                    # Not on continuation MIS at this vertex: the light's own estimator.
                    V = ((px, py, pz), _w3(W, W_G, i), _w3(W, W_FS, i), _w3(W, W_FT, i), _w3(W, W_N, i),
                         _w3(W, W_WO, i), W[W_AO * BLK + i], W[W_BO * BLK + i], W[W_PD * BLK + i], eps,
                         int(W[W_M * BLK + i]))
                    tok = e_tok[gl]
                    exact = f_exact[g]
                    E = (0.0, 0.0, 0.0)
                    if _uses_F(tok, exact):
                        # F only for the pairs whose estimate uses it (this light's own, not every light's).
                        if _table_F(LP, g):
                            E = _dome_table_F(LP, g, V[4], i_rot[int(LP[g, LP_J])], f_pk, tbuf)
                        elif LP[g, LP_KIND] == K_MESH:
                            E = _mesh_F(LP, g, V[0], V[4], MS, far_ratio, kappa_max)
                        else:
                            E = _light_F(LP, g, V[0], V[4], f_theta[g], far_ratio, kappa_max)
                    first = k_sh
                    k_sh, k_grp = _direct_pair(g, tok, e_alpha[gl], e_N[gl], power[gl], exact, E, m_d[g], m_s[g], V,
                                               Pm, (b0 / pmf, b1 / pmf, b2 / pmf), pr_path, e_key,
                                               np.uint64((r * nl + g) * 5 * 4096),
                                               (sobol, lds_pix[pr_path] if sobol else np.uint64(0), lds_sidx,
                                                est_dim0 + np.uint64(3 << 20) * np.uint64(g)), LP, IMG, lcon, SH,
                                               GR, k_sh, k_grp,
                                               scratch, SHP)
                    for s_ in range(first, k_sh):
                        sh_l[s_] = g
                    continue
                if g < n_batch and not _tex_rect(LP, g):
                    # Rect and sphere lights: sampled and weighed by the vectorised passes.
                    wi = (R[g, 0, i], R[g, 1, i], R[g, 2, i])
                    dist = R[g, 3, i]
                    pdf_l = R[g, 4, i]
                    if C[g, 3 * BLK + i] == 0.0 or not math.isfinite(pdf_l):
                        continue
                    c0 = C[g, 0 * BLK + i]
                    c1 = C[g, 1 * BLK + i]
                    c2 = C[g, 2 * BLK + i]
                    if LP[g, LP_SHAPE] >= 0.0:
                        # ShapingAPI: the contribution is linear in the sample's radiance.
                        c0, c1, c2 = _shaped(LP, g, SHP, wi, (c0, c1, c2))
                        if not (c0 > 0.0 or c1 > 0.0 or c2 > 0.0):
                            continue
                else:
                    wi, dist, pdf_l, Le, delta = _light_sample(LP, g, (px, py, pz), u0, u1, IMG, close_ratio, min_sa,
                                                               graz, _w3(W, W_N, i))
                    if not (pdf_l > 0.0 and math.isfinite(pdf_l)):
                        continue
                    if LP[g, LP_SHAPE] >= 0.0:
                        Le = _shaped(LP, g, SHP, wi, Le)
                    # Divided by the pick's pmf: a delta light's weight is 1 (its radiance is
                    # divided), the others' h(pmf p_l, p_b) / (pmf p_l).
                    if delta:
                        Le = (Le[0] / pmf, Le[1] / pmf, Le[2] / pmf)
                    a, j0, fy, kd, f0, f90 = _mat(Pm, int(W[W_M * BLK + i]))
                    ok, c0, c1, c2 = _light_contrib(
                        wi, pdf_l if delta else pdf_l * pmf, Le, delta, power[gl], _w3(W, W_FS, i), _w3(W, W_FT, i),
                        _w3(W, W_N, i), _w3(W, W_G, i), _w3(W, W_WO, i), W[W_AO * BLK + i], W[W_BO * BLK + i],
                        W[W_PD * BLK + i], a, j0, fy, kd, f0, f90, (b0, b1, b2))
                    if not ok:
                        continue
                # The sample is above the geometric normal (ok): the shadow ray leaves on its side.
                sh_o[k_sh, 0] = px + W[W_G * BLK + i] * eps
                sh_o[k_sh, 1] = py + W[(W_G + 1) * BLK + i] * eps
                sh_o[k_sh, 2] = pz + W[(W_G + 2) * BLK + i] * eps
                sh_d[k_sh, 0] = wi[0]
                sh_d[k_sh, 1] = wi[1]
                sh_d[k_sh, 2] = wi[2]
                # Stop short of the light by a relative margin and the origin offset (as _visible).
                # Infinite lights: embree's far limit, as Accel gives inf.
                sh_t[k_sh] = dist * (1.0 - 1e-5) - eps if dist < math.inf else 1e37
                sh_path[k_sh] = pr_path
                sh_l[k_sh] = g
                sh_c[k_sh, 0] = c0
                sh_c[k_sh, 1] = c1
                sh_c[k_sh, 2] = c2
                k_sh += 1
            if W[W_OKN * BLK + i] == 0.0 or not (math.isfinite(W[W_PDFB * BLK + i])
                                          and math.isfinite(W[W_NB * BLK + i] + W[(W_NB + 1) * BLK + i] + W[(W_NB + 2) * BLK + i])):
                continue
            # ---- the next bounce's ray (the BSDF sample _surface_pass drew; it left above ng) ----
            n_path[k_next] = pr_path
            n_depth[k_next] = depth[r] + 1
            for c in range(3):
                n_S[k_next, B + c] = W[(W_NB + c) * BLK + i]
                n_S[k_next, O + c] = W[(W_P + c) * BLK + i] + W[(W_G + c) * BLK + i] * eps
                n_S[k_next, D + c] = W[(W_WN + c) * BLK + i]
                n_S[k_next, PP + c] = W[(W_P + c) * BLK + i]
                n_S[k_next, PN + c] = W[(W_N + c) * BLK + i]
                n_o32[k_next, c] = n_S[k_next, O + c]
                n_d32[k_next, c] = n_S[k_next, D + c]
            n_S[k_next, TMAX] = math.inf
            n_S[k_next, PM] = tri_mesh[k] if linked else 0.0
            n_S[k_next, PB] = W[W_PDFB * BLK + i]
            n_t32[k_next] = 1e37
            k_next += 1
    counts[0] = k_next
    counts[1] = k_sh
    counts[2] = n_vertices
    counts[3] = k_grp


@njit(cache=True, nogil=True)
def start_kernel(o, d, tmax, S, o32, d32, t32):
    """The state of m camera rays o, d (m, 3), tmax (m,) into S (m, NS) (beta 1, no previous
    vertex) and embree's float32 o32, d32 (m, 3), t32 (m,) (far limit at most 1e37): one pass
    instead of numpy's zero fill, four column copies and three conversions."""
    for r in range(o.shape[0]):
        for c in range(3):
            S[r, B + c] = 1.0
            S[r, O + c] = o[r, c]
            S[r, D + c] = d[r, c]
            S[r, PP + c] = 0.0
            S[r, PN + c] = 0.0
            o32[r, c] = o[r, c]
            d32[r, c] = d[r, c]
        S[r, TMAX] = tmax[r]
        S[r, PB] = 0.0
        S[r, PM] = 0.0
        t32[r] = min(tmax[r], 1e37)


@njit(cache=True, nogil=True)
def resolve_groups_kernel(L, g_int, g_f, sh_x, sh_cov, blocked):
    """Add the diffuse combinations of the per-light estimators (groups written by _direct_pair:
    g_int (k, 5) path, first ray, rays, N, mode; g_f (k, 6) F and beta) once their shadow rays
    are traced: L[path] += beta * kernels.direct.diffuse_combine_row(F, X, v, covered) over the
    group's rays (sh_x (3), sh_cov, blocked: the occlusion of each ray)."""
    v = np.empty(blocked.shape[0])
    for i in range(v.shape[0]):
        v[i] = 0.0 if blocked[i] else 1.0
    resolve_groups_visible_kernel(L, g_int, g_f, sh_x, sh_cov, v)


@njit(cache=True, nogil=True)
def resolve_groups_visible_kernel(L, g_int, g_f, sh_x, sh_cov, v):
    """resolve_groups_kernel given each ray's visibility v (k,) in [0, 1] (ShadowAPI's falloff
    makes it fractional, integrators/shadow_api.py)."""
    for k in range(g_int.shape[0]):
        first = g_int[k, 1]
        e = diffuse_combine_row(g_f[k, 0], g_f[k, 1], g_f[k, 2], sh_x, v, sh_cov, first, first + g_int[k, 2],
                                g_int[k, 3], g_int[k, 4])
        r = g_int[k, 0]
        for c in range(3):
            L[r, c] += g_f[k, 3 + c] * e[c]


@njit(cache=True, nogil=True)
def add_visible_kernel(L, sh_path, sh_c, v, tint):
    """L[sh_path[i]] += sh_c[i] (v[i] + (1 - v[i]) tint[i]) (repeated paths accumulate): each
    shadow ray's contribution at its visibility v (k,) in [0, 1], the shadowed fraction showing
    the light's ShadowAPI shadow:color tint (k, 3) (0: black shadows; kernels/direct.shadowed_row)."""
    for i in range(sh_path.shape[0]):
        r = sh_path[i]
        for c in range(3):
            L[r, c] += sh_c[i, c] * shadowed_row(v[i], tint[i, c])


@njit(cache=True, nogil=True)
def add_unblocked_kernel(L, sh_path, sh_c, blocked):
    """L[sh_path[i]] += sh_c[i] where not blocked[i] (repeated paths accumulate)."""
    for i in range(sh_path.shape[0]):
        if not blocked[i]:
            r = sh_path[i]
            L[r, 0] += sh_c[i, 0]
            L[r, 1] += sh_c[i, 1]
            L[r, 2] += sh_c[i, 2]


guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/bsdfs/_preview_kernels.py", "renderer/kernels/lights.py", "renderer/kernels/direct.py",
             "renderer/estimators/compiled.py", "renderer/bsdfs/microfacet.py",
             "renderer/bsdfs/_ggx_albedo_data.py", "renderer/geometry.py", "renderer/kernels/vmath.py",
             "renderer/kernels/light_pick.py", "renderer/kernels/light_bvh.py", "renderer/kernels/shaping.py",
             "renderer/lights/analytic.py", "renderer/preconvolve.py", "renderer/kernels/cylinder.py",
             "renderer/kernels/mesh_light.py",
             "renderer/kernels/portal.py", "renderer/materials.py", "renderer/textures.py",
             "renderer/kernels/sobol.py"])
