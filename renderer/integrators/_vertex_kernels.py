"""The compiled path vertex of the fast path (renderer/integrators/fast_path.py).

One call per bounce does, for every live ray, all the work between two embree calls that the
general integrator spreads over ~150 numpy passes and a dozen kernels: emission of the rect
lights the ray crossed (MIS-weighted on continuation rays), the surface interaction, the
material's packed UsdPreviewSurface row, the shading frame, the light half of continuation MIS
for every light (the rect and sphere lights' samples drawn beforehand by the vectorised batch
kernels of kernels/lights.py, the others' here), and the BSDF sample with the throughput update
and Russian roulette. It writes the shadow rays and the next bounce's rays compactly; Python
only calls embree and adds the unblocked shadow contributions.

The maths is not restated here: it calls the per-row helpers of the surface interaction
(renderer/geometry.py), the rect, sphere and disk lights (renderer/kernels/lights.py) and the BSDF
(renderer/bsdfs/_preview_kernels.py), the same functions the general path's kernels use. numba's
on-disk cache is keyed on this file only, so ``guard_cache`` (renderer/kernels/__init__.py) flushes
this file's cache whenever any of the files it inlines from changes.

Shapes: n live rays; S (n, 20) float64 per-ray state, columns ``B`` (beta), ``O`` (origin),
``D`` (unit direction), ``TMAX``, ``PP``/``PNG``/``PNS`` (the previous vertex's point, geometric
and shading normal) and ``PB`` (the BSDF pdf of d there); U (4 + 2 lights, n) uniforms, batch
axis last (the rect lights' samples are drawn from it by a vectorised kernel, which needs
unit stride along the batch); rs (rect lights, 5, n) and sps (sphere lights, 6, n) those
samples.
"""

from __future__ import annotations

import math

from numba import njit

from renderer.bsdfs._preview_kernels import (
    ALPHA, F0, F90, FY, J0, KD, RHO,
    _lookup, _mis_weight, _p_diffuse, _sample_dir, _specular,
)
from renderer.geometry import _interaction_row
from renderer.kernels import guard_cache
from renderer.kernels.lights import (
    _disk_hit, _disk_pdf_row, _disk_sample_row, _distant_pdf_row, _dome_sample_row, _dome_texel_row, _distant_sample_row, _rect_hit, _rect_pdf_row,
    _row, _sphere_hit_row, _sphere_pdf_row, _uniform_sphere_row,
)

_INV_PI = 1.0 / math.pi
_INV_4PI = 0.25 / math.pi

# State columns.
B = 0
O = 3
D = 6
TMAX = 9
PP = 10
PNG = 13
PNS = 16
PB = 19
NS = 20
# Uniform columns: lobe choice, direction (2), roulette, then (2 per light) light samples.
U_LOBE = 0
U_DIR = 1
U_RR = 3
U_LIGHT = 4


@njit(cache=True, nogil=True)
def vertex_kernel(
    path, depth, unsampled, S, hit_t, hit_prim, hit_b1, hit_b2, U, rs, sps, Pm, mat_row, emission, max_depth,
    vertices, face_normal, normals, tri_mat, tri_mag, ta, tb,
    center, ex, ey, x_hat, y_hat, edge_len, nrm, area, radiance, is_rect, exd, eyd, rect_light,
    s_center, s_radius, s_radiance, s_delta, sphere_light,
    d_center, d_nrm, d_u1, d_u2, d_e1, d_e2, d_s1, d_s2, d_area, d_radiance, disk_light, close_ratio,
    i_dome, i_axis, i_omc, i_delta, i_radiance, inf_light, i_tex, i_rot,
    im_texels, im_offset, im_height, im_width, im_weight, im_total, im_row_cdf, im_row_cdf_start, im_col_cdf,
    im_col_cdf_start,
    power, min_sa, graz, rr_depth, eps_rel, eps_floor, eps_add,
    L, n_path, n_depth, n_S, n_o32, n_d32, n_t32, sh_o, sh_d, sh_t, sh_path, sh_c, counts,
):
    """One bounce for n live rays (see the module docstring). The arguments from ``vertices``
    to ``eps_add`` describe the scene and stay fixed for a render (FastPath.tables).

    path, depth: (n,) int64 (the path's row in L, scattering events so far); unsampled: (n,) bool
    (camera rays: emission counts fully; all others carry continuation MIS for every light); hit_*:
    embree's closest hits as Accel.intersect_prepared gives them (float32 t, u, v; int32 prim, -1 on
    a miss, where t is meaningless); rs: each rect light's sample at each hit, drawn before the kernel
    by kernels.lights.rect_sample_batch_kernel (wi, distance, pdf; pdf 0 where unusable); sps: each
    sphere light's, by sphere_sample_batch_kernel (the same and the radiance scale); Pm: (materials, K) packed BSDF rows, or with mat_row (n,)
    non-empty, per-hit rows: ray r's row is mat_row[r], and emission (hits, 3) (if not empty) is
    the radiance its surface emits (added in full: emitting surfaces are reached by BSDF samples
    only, as in the general path); light tables: the
    RectLight arrays (all untextured), the SphereLight arrays (s_*), the DiskLight arrays (d_*) and
    the infinite lights (i_*: i_dome True for a DomeLight, with i_tex its image in the ImageSet
    im_* or -1 for a constant one and i_rot (3, 3) its local -> world rotation; else a
    DistantLight with i_axis, i_omc = 1 - cos theta_max, i_delta), with rect_light / sphere_light / disk_light /
    inf_light (count,) the global light index of each (which picks the light's uniforms in U and
    its power flag); power: (lights,) bool heuristic. L (m, 3)
    receives emission in place. Next rays go to n_path, n_depth, n_S and, in embree's float32
    format, n_o32, n_d32, n_t32 (capacity n); shadow rays to sh_o, sh_d, sh_t (float32), sh_path,
    sh_c (capacity n * lights), sh_c (k, 3) being the radiance each adds if unblocked. counts[0],
    counts[1]: how many of each; counts[2]: how many vertices scattered (took the light half).
    """
    n_rect = center.shape[0]
    n_rs = n_rect + s_center.shape[0]  # rect, then sphere, then disk, then infinite lights
    n_fin = n_rs + d_center.shape[0]
    nl = n_fin + i_radiance.shape[0]
    k_next = 0
    k_sh = 0
    n_vertices = 0
    for r in range(path.shape[0]):
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
        for g in range(n_fin):
            if g < n_rect:
                j = g
                tl, _a, _b, hit = _rect_hit(o, d, _row(center, j), _row(nrm, j), _row(exd, j), _row(eyd, j))
                # The back of a one-sided light emits nothing.
                front = -(d[0] * nrm[j, 0] + d[1] * nrm[j, 1] + d[2] * nrm[j, 2]) > 0.0
                gl = rect_light[j]
                Le = _row(radiance, j)
            elif g >= n_rs:
                j = g - n_rs
                tl, hit = _disk_hit(o, d, _row(d_center, j), _row(d_nrm, j), _row(d_u1, j), _row(d_u2, j), d_s1[j],
                                    d_s2[j])
                front = -(d[0] * d_nrm[j, 0] + d[1] * d_nrm[j, 1] + d[2] * d_nrm[j, 2]) > 0.0
                gl = disk_light[j]
                Le = _row(d_radiance, j)
            else:
                j = g - n_rect
                tl = _sphere_hit_row(o, d, _row(s_center, j), s_radius[j], s_delta[j])
                hit = tl < math.inf
                # Outward emission only: a ray leaving the sphere's inside sees nothing.
                front = -((o[0] + tl * d[0] - s_center[j, 0]) * d[0] + (o[1] + tl * d[1] - s_center[j, 1]) * d[1]
                          + (o[2] + tl * d[2] - s_center[j, 2]) * d[2]) > 0.0 if hit else False
                gl = sphere_light[j]
                Le = _row(s_radiance, j)
            if not (hit and tl < t_geo and front):
                continue
            if unsampled[r]:
                w = 1.0
            else:
                # h(p_b, p_l): p_l from the vertex the ray left, as the light half there used.
                pv = (S[r, PP], S[r, PP + 1], S[r, PP + 2])
                if g < n_rect:
                    p_l = _rect_pdf_row(pv, d, _row(center, j), _row(nrm, j), _row(exd, j), _row(eyd, j),
                                        _row(ex, j), _row(ey, j), _row(x_hat, j), _row(y_hat, j), edge_len[j, 0],
                                        edge_len[j, 1], area[j], False, is_rect[j], 0.0, min_sa, graz)
                elif g >= n_rs:
                    p_l = _disk_pdf_row(pv, d, _row(d_center, j), _row(d_nrm, j), _row(d_u1, j), _row(d_u2, j),
                                        _row(d_e1, j), _row(d_e2, j), d_s1[j], d_s2[j], d_area[j], close_ratio,
                                        min_sa, graz)
                else:
                    p_l = _sphere_pdf_row(pv, d, _row(s_center, j), s_radius[j], s_delta[j])
                w = _mis_weight(S[r, PB], p_l, power[gl])
            L[pr_path, 0] += b0 * Le[0] * w
            L[pr_path, 1] += b1 * Le[1] * w
            L[pr_path, 2] += b2 * Le[2] * w
        if k < 0:
            # ---- escaped: the infinite lights (a camera ray sees them whatever its far clip) --
            for q in range(n_fin, nl):
                j = q - n_fin
                if i_dome[j]:
                    if i_tex[j] >= 0:
                        p_l, kt = _dome_texel_row(d, i_tex[j], i_rot[j], im_height, im_width, im_weight, im_total,
                                                  im_offset)
                        Le = (i_radiance[j, 0] * im_texels[kt, 0], i_radiance[j, 1] * im_texels[kt, 1],
                              i_radiance[j, 2] * im_texels[kt, 2])
                    else:
                        p_l = _INV_4PI
                        Le = _row(i_radiance, j)
                else:
                    p_l = _distant_pdf_row(d, _row(i_axis, j), i_omc[j], i_delta[j])
                    if p_l <= 0.0:
                        continue  # outside the cone (a delta light is never seen)
                    Le = _row(i_radiance, j)
                w = 1.0 if unsampled[r] else _mis_weight(S[r, PB], p_l, power[inf_light[j]])
                L[pr_path, 0] += b0 * Le[0] * w
                L[pr_path, 1] += b1 * Le[1] * w
                L[pr_path, 2] += b2 * Le[2] * w
            continue
        per_hit = mat_row.shape[0] > 0
        m = mat_row[r] if per_hit else tri_mat[k]
        if emission.shape[0] > 0:
            L[pr_path, 0] += b0 * emission[m, 0]
            L[pr_path, 1] += b1 * emission[m, 1]
            L[pr_path, 2] += b2 * emission[m, 2]
        if depth[r] >= max_depth:
            continue
        n_vertices += 1
        # ---- surface interaction -----------------------------------------------------------
        pp, gg, ss = _interaction_row(vertices, face_normal, normals, k, hit_b1[r], hit_b2[r], d[0], d[1], d[2])
        px, py, pz = pp
        gx, gy, gz = gg
        sx, sy, sz = ss
        # ---- shading frame (geometry._frame_kernel) and wo in it ---------------------------
        sign = 1.0 if sz >= 0.0 else -1.0
        fa = -1.0 / (sign + sz)
        fb = sx * sy * fa
        s = (1.0 + sign * sx * sx * fa, sign * fb, -sign * sx)
        t = (fb, sign + sy * sy * fa, -sy)
        wox = -(d[0] * s[0] + d[1] * s[1] + d[2] * s[2])
        woy = -(d[0] * t[0] + d[1] * t[1] + d[2] * t[2])
        woz = -(d[0] * sx + d[1] * sy + d[2] * sz)
        # ---- the material's BSDF and its wo terms -----------------------------------------
        a = Pm[m, ALPHA]
        j0 = int(Pm[m, J0])
        fy = Pm[m, FY]
        ao, bo = _lookup(woz, j0, fy, ta, tb)
        p_d = _p_diffuse(Pm[m, RHO], Pm[m, RHO + 1], Pm[m, RHO + 2], Pm[m, F0], Pm[m, F0 + 1], Pm[m, F0 + 2],
                         Pm[m, F90], Pm[m, F90 + 1], Pm[m, F90 + 2], ao, bo)
        # Accel.ray_epsilon: the point's and the triangle's vertices' float32 error.
        mag = max(max(max(abs(px), abs(py)), abs(pz)), tri_mag[k])
        eps = eps_rel * max(mag, eps_floor) + eps_add
        # ---- the light half of continuation MIS, every light (the exhaustive sampler) ------
        for g in range(nl):
            if g < n_rect:
                j = g
                gl = rect_light[j]
                # Sampled before the kernel, vectorised (rs; rect_sample_batch_kernel).
                wi = (rs[j, 0, r], rs[j, 1, r], rs[j, 2, r])
                dist = rs[j, 3, r]
                pdf_l = rs[j, 4, r]
                ok = pdf_l > 0.0
                Le = _row(radiance, j)
                delta = False
            elif g >= n_fin:
                j = g - n_fin
                gl = inf_light[j]
                Le = _row(i_radiance, j)
                if i_dome[j] and i_tex[j] >= 0:
                    wi, pdf_l, kt = _dome_sample_row(
                        U[U_LIGHT + 2 * gl, r], U[U_LIGHT + 2 * gl + 1, r], i_tex[j], i_rot[j], im_height, im_width,
                        im_row_cdf, im_row_cdf_start, im_col_cdf, im_col_cdf_start, im_weight, im_total, im_offset)
                    Le = (Le[0] * im_texels[kt, 0], Le[1] * im_texels[kt, 1], Le[2] * im_texels[kt, 2])
                elif i_dome[j]:
                    wi = _uniform_sphere_row(U[U_LIGHT + 2 * gl, r], U[U_LIGHT + 2 * gl + 1, r])
                    pdf_l = _INV_4PI
                else:
                    wi, pdf_l = _distant_sample_row(U[U_LIGHT + 2 * gl, r], U[U_LIGHT + 2 * gl + 1, r],
                                                    _row(i_axis, j), i_omc[j], i_delta[j])
                dist = math.inf
                ok = pdf_l > 0.0
                delta = i_delta[j] and not i_dome[j]
            elif g >= n_rs:
                j = g - n_rs
                gl = disk_light[j]
                wi, dist, pdf_l, _pl, ok = _disk_sample_row(
                    (px, py, pz), U[U_LIGHT + 2 * gl, r], U[U_LIGHT + 2 * gl + 1, r], _row(d_center, j),
                    _row(d_nrm, j), _row(d_u1, j), _row(d_u2, j), _row(d_e1, j), _row(d_e2, j), d_s1[j], d_s2[j],
                    d_area[j], close_ratio, min_sa, graz)
                Le = _row(d_radiance, j)
                delta = False
            else:
                j = g - n_rect
                gl = sphere_light[j]
                # Sampled before the kernel, vectorised (sps; sphere_sample_batch_kernel).
                wi = (sps[j, 0, r], sps[j, 1, r], sps[j, 2, r])
                dist = sps[j, 3, r]
                pdf_l = sps[j, 4, r]
                ok = pdf_l > 0.0
                l_scale = sps[j, 5, r]
                Le = (s_radiance[j, 0] * l_scale, s_radiance[j, 1] * l_scale, s_radiance[j, 2] * l_scale)
                delta = s_delta[j]
            if not ok or not math.isfinite(pdf_l):
                continue
            wx = wi[0] * s[0] + wi[1] * s[1] + wi[2] * s[2]
            wy = wi[0] * t[0] + wi[1] * t[1] + wi[2] * t[2]
            wz = wi[0] * sx + wi[1] * sy + wi[2] * sz
            cos_g = wi[0] * gx + wi[1] * gy + wi[2] * gz
            if not (wz > 0.0 and cos_g > 0.0 and woz > 0.0):
                continue
            oks, dv, fw, pdf_s = _specular(wox, woy, woz, wx, wy, wz, a)
            if not oks:
                continue
            ai, bi = _lookup(wz, j0, fy, ta, tb)
            p_b = p_d * wz * _INV_PI + (1.0 - p_d) * pdf_s
            # A delta light (treatAsPoint) takes the whole weight, and its p_l counts as 1.
            kk = wz if delta else wz * _mis_weight(pdf_l, p_b, power[gl]) / pdf_l
            c0 = b0 * _f_channel(Pm, m, 0, ao, bo, ai, bi, fw, dv) * Le[0] * kk
            c1 = b1 * _f_channel(Pm, m, 1, ao, bo, ai, bi, fw, dv) * Le[1] * kk
            c2 = b2 * _f_channel(Pm, m, 2, ao, bo, ai, bi, fw, dv) * Le[2] * kk
            if not (c0 > 0.0 or c1 > 0.0 or c2 > 0.0):
                continue
            side = eps if cos_g >= 0.0 else -eps
            sh_o[k_sh, 0] = px + gx * side
            sh_o[k_sh, 1] = py + gy * side
            sh_o[k_sh, 2] = pz + gz * side
            sh_d[k_sh, 0] = wi[0]
            sh_d[k_sh, 1] = wi[1]
            sh_d[k_sh, 2] = wi[2]
            # Stop short of the light by a relative margin and the origin offset (as _visible).
            # Infinite lights: embree's far limit, as Accel gives inf.
            sh_t[k_sh] = dist * (1.0 - 1e-5) - eps if dist < math.inf else 1e37
            sh_path[k_sh] = pr_path
            sh_c[k_sh, 0] = c0
            sh_c[k_sh, 1] = c1
            sh_c[k_sh, 2] = c2
            k_sh += 1
        # ---- BSDF sample, throughput, Russian roulette (_preview_kernels.scatter_kernel) ----
        wix, wiy, wiz = _sample_dir(wox, woy, woz, a, U[U_LOBE, r] < p_d, U[U_DIR, r], U[U_DIR + 1, r])
        wx = wix * s[0] + wiy * t[0] + wiz * sx
        wy = wix * s[1] + wiy * t[1] + wiz * sy
        wz = wix * s[2] + wiy * t[2] + wiz * sz
        okb, dv, fw, pdf_s = _specular(wox, woy, woz, wix, wiy, wiz, a)
        pdf_b = p_d * wiz * _INV_PI + (1.0 - p_d) * pdf_s if okb else 0.0
        cos_g = wx * gx + wy * gy + wz * gz
        if not (okb and pdf_b > 0.0 and math.isfinite(pdf_b) and cos_g > 0.0):
            continue
        ai, bi = _lookup(wiz, j0, fy, ta, tb)
        kk = abs(wiz) / pdf_b
        nb0 = b0 * _f_channel(Pm, m, 0, ao, bo, ai, bi, fw, dv) * kk
        nb1 = b1 * _f_channel(Pm, m, 1, ao, bo, ai, bi, fw, dv) * kk
        nb2 = b2 * _f_channel(Pm, m, 2, ao, bo, ai, bi, fw, dv) * kk
        if not ((nb0 > 0.0 or nb1 > 0.0 or nb2 > 0.0) and math.isfinite(nb0 + nb1 + nb2)):
            continue
        if depth[r] + 1 >= rr_depth:
            q = min(max(1.0 - max(nb0, max(nb1, nb2)), 0.0), 0.95)
            if U[U_RR, r] < q:
                continue
            inv = 1.0 / (1.0 - q)
            nb0 *= inv
            nb1 *= inv
            nb2 *= inv
        # ---- the next bounce's ray ------------------------------------------------------
        side = eps if cos_g >= 0.0 else -eps
        n_path[k_next] = pr_path
        n_depth[k_next] = depth[r] + 1
        n_S[k_next, B] = nb0
        n_S[k_next, B + 1] = nb1
        n_S[k_next, B + 2] = nb2
        n_S[k_next, O] = px + gx * side
        n_S[k_next, O + 1] = py + gy * side
        n_S[k_next, O + 2] = pz + gz * side
        n_S[k_next, D] = wx
        n_S[k_next, D + 1] = wy
        n_S[k_next, D + 2] = wz
        n_S[k_next, TMAX] = math.inf
        n_S[k_next, PP] = px
        n_S[k_next, PP + 1] = py
        n_S[k_next, PP + 2] = pz
        n_S[k_next, PNG] = gx
        n_S[k_next, PNG + 1] = gy
        n_S[k_next, PNG + 2] = gz
        n_S[k_next, PNS] = sx
        n_S[k_next, PNS + 1] = sy
        n_S[k_next, PNS + 2] = sz
        n_S[k_next, PB] = pdf_b
        for c in range(3):
            n_o32[k_next, c] = n_S[k_next, O + c]
            n_d32[k_next, c] = n_S[k_next, D + c]
        n_t32[k_next] = 1e37
        k_next += 1
    counts[0] = k_next
    counts[1] = k_sh
    counts[2] = n_vertices


@njit(cache=True, nogil=True)
def _f_channel(Pm, m, c, ao, bo, ai, bi, fw, dv):
    """f(wo, wi) of material m in channel c, from the wo terms (ao, bo), the wi terms (ai, bi),
    the Schlick weight fw and D V of _specular (the formula of _preview_kernels.eval_kernel)."""
    fk = Pm[m, F0 + c]
    gk = Pm[m, F90 + c]
    c_o = 1.0 - (fk * ao + gk * bo)
    c_i = 1.0 - (fk * ai + gk * bi)
    return Pm[m, KD + c] * c_o * c_i + (fk + (gk - fk) * fw) * dv


@njit(cache=True, nogil=True)
def add_unblocked_kernel(L, sh_path, sh_c, blocked):
    """L[sh_path[i]] += sh_c[i] where not blocked[i] (repeated paths accumulate)."""
    for i in range(sh_path.shape[0]):
        if not blocked[i]:
            r = sh_path[i]
            L[r, 0] += sh_c[i, 0]
            L[r, 1] += sh_c[i, 1]
            L[r, 2] += sh_c[i, 2]


guard_cache(__name__, [vertex_kernel, _f_channel, add_unblocked_kernel],
            ["renderer/bsdfs/_preview_kernels.py", "renderer/kernels/lights.py", "renderer/bsdfs/microfacet.py",
             "renderer/geometry.py"])
