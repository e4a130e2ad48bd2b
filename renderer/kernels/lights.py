"""Fused per-row kernels for the rect, disk and sphere lights (see ``renderer.kernels``).

Each kernel does, in one pass per row, what the light's numpy code did in many whole-array
passes: gather the light's parameters by ``idx``, choose the sampling strategy, build the
spherical rectangle *once* (the numpy code built it once to choose the strategy and again to
sample), sample, convert the pdf and write the outputs. The sampling methods, strategy rules and
every guard (zero lengths, grazing angles, non-finite pdfs) are those of the numpy code they
replace, documented in ``renderer/lights/{rect,disk,sphere,spherical_rect}.py``. Most formulas
are that code's, to float rounding; where the kernels spend fewer transcendental calls, square
roots or divisions on the same quantity (the spherical rectangle's solid angle and inverse CDF,
the sphere's sin^2 theta / sin^2 theta_max) the equivalent form is derived in a comment, and
results agree with the numpy code to ~1e-9 relative or better (the kernels' spherical-rectangle
solid angle is the more accurate one: the numpy asin sum loses digits for small solid angles).

Vectors are passed around as 3-tuples of floats, which LLVM keeps in registers.

Shapes: ``idx`` (n,) int64 local light indices; points/directions (n, 3) float64; per-light
tables (count, ...) float64, int64 or bool. Outputs are preallocated by the caller and fully
overwritten.
"""

from __future__ import annotations

import math

from numba import njit

from renderer.kernels import guard_cache, module_dispatchers
from renderer.kernels.vmath import arg_upper, sincos

_PI = math.pi
_TWO_PI = 2.0 * math.pi


# --------------------------------------------------------------------------------------
# 3-vector helpers (tuples)
#
# Helpers take scalars and tuples; only the branch-free ``_row``/``_put`` touch arrays. LLVM inlines
# these small njit calls. (In the BSDF kernels, helpers that took arrays and returned from several
# branches, numba-inlined with ``inline="always"``, made the loop 4x slower; keeping array reads
# with branches in the kernel bodies avoids that.) LLVM does *not* inline the large spherical-
# rectangle helpers: called, they passed their tuples through memory, so those two (scalars and
# tuples only) are numba-inlined, which measured ~10% faster.
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _row(a, r):
    return (a[r, 0], a[r, 1], a[r, 2])


@njit(cache=True, nogil=True)
def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, nogil=True)
def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, nogil=True)
def _scale(k, a):
    return (k * a[0], k * a[1], k * a[2])


@njit(cache=True, nogil=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True)
def _cross(a, b):
    # np.cross's component formulas.
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, nogil=True)
def _put(out, r, v):
    out[r, 0] = v[0]
    out[r, 1] = v[1]
    out[r, 2] = v[2]


@njit(cache=True, nogil=True, inline="always")
def _around(axis, c, sn, phi):
    """c axis + sn (cos phi s + sin phi t): the direction at polar cosine c (sine sn) and azimuth
    phi about the unit axis, in geometry.coordinate_frame(axis)'s frame (Duff et al. 2017).
    numba-inlined: as a call it passed its tuples through memory (sphere sample 52 -> 83 ns/row)."""
    sign = 1.0 if axis[2] >= 0.0 else -1.0
    fa = -1.0 / (sign + axis[2])
    fb = axis[0] * axis[1] * fa
    s = (1.0 + sign * axis[0] * axis[0] * fa, sign * fb, -sign * axis[0])
    t = (fb, sign + axis[1] * axis[1] * fa, -axis[1])
    sp, cp = sincos(phi)
    ks = sn * cp
    kt = sn * sp
    return _add(_add(_scale(c, axis), _scale(ks, s)), _scale(kt, t))


@njit(cache=True, nogil=True)
def _dir_dist(p, q):
    """_common.direction_and_distance for one row: unit p -> q and the distance (zero stays zero)."""
    v = _sub(q, p)
    d = math.sqrt(_dot(v, v))
    # One division and three products: divisions and square roots share one unit, the
    # vectorised samplers' bottleneck.
    inv = 1.0 / (d if d > 0.0 else 1.0)
    return (v[0] * inv, v[1] * inv, v[2] * inv), d


@njit(cache=True, nogil=True)
def _area_to_solid_angle(pdf_area, dist, cos_light):
    """_common.area_to_solid_angle for one row."""
    c = abs(cos_light)
    if not (c > 0.0 and pdf_area > 0.0):
        return 0.0
    out = pdf_area * dist * dist / c
    return out if math.isfinite(out) else 0.0


@njit(cache=True, nogil=True)
def _clip(x, lo, hi):
    # np.clip(x, lo, hi) == minimum(maximum(x, lo), hi)
    return min(max(x, lo), hi)


# --------------------------------------------------------------------------------------
# Spherical rectangle (the method of spherical_rect.setup / spherical_rect.sample, one row)
#
# spherical_rect.py sums four asin for the solid angle and keeps h2 + h3 as an angle; here the
# same quantities cost one atan and no other inverse trigonometric call:
# * the solid angle is that of the triangles (v00, v10, v11) and (v00, v11, v01) of the corners
#   v (relative to p), each by Van Oosterom & Strackee's tan(Omega_k / 2) = N / D_k with
#   N = |v_a . (v_b x v_c)| = |z0| lx ly and D_k = r_a r_b r_c + (v_a . v_b) r_c + (v_a . v_c) r_b
#   + (v_b . v_c) r_a, added as Omega / 2 = arg((D_1 + iN)(D_2 + iN)) in [0, pi). It keeps its
#   relative accuracy for small solid angles, where the asin sum cancels (measured against long
#   double: asin sum up to ~1e-8 relative error near 1e-4 sr and ~1e-4 at 1e-8 sr, this ~1e-12);
# * h2 + h3 is carried as the unit complex number e^{i(h2 + h3)}: with nz_k = n_k / d_k,
#   sin h_k = nz_k nz_{k+1} and cos h_k = sqrt(1 - sin^2 h_k) = |z0| r / (d_k d_{k+1}), r the
#   distance to the corner the two edges share (r01 for h2, r00 for h3), so the sampler
#   rotates e^{i u0 Omega} by it instead of taking cos / sin of u0 Omega - h2 - h3.
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _sr_frame(ex, ey):
    """Unit edge directions and lengths (x_hat, y_hat, lx, ly) of orthogonal edges ex, ey."""
    lx = math.sqrt(_dot(ex, ex))
    ly = math.sqrt(_dot(ey, ey))
    sx = lx if lx > 0.0 else 1.0
    sy = ly if ly > 0.0 else 1.0
    return (ex[0] / sx, ex[1] / sx, ex[2] / sx), (ey[0] / sy, ey[1] / sy, ey[2] / sy), lx, ly


@njit(cache=True, nogil=True, inline="always")
def _sr_setup(p, corner, x_hat, y_hat, lx, ly, min_solid_angle, grazing_nz2):
    """Rectangle corner + [0, lx] x_hat + [0, ly] y_hat (orthogonal unit x_hat, y_hat) seen from p.

    Returns (x_hat, y_hat, z_hat, x0, x1, y0, y1, z0, r00, r01, dd0, dd2, dd3, solid_angle,
    usable): the local frame (z_hat flipped so that z0 <= 0), the corner distances r00, r01 and
    the squared distances dd_k = n_k^2 + z0^2 that _sr_sample needs.
    """
    z_hat = _cross(x_hat, y_hat)
    d = _sub(corner, p)
    x0 = _dot(d, x_hat)
    y0 = _dot(d, y_hat)
    z0 = _dot(d, z_hat)
    if z0 > 0.0:
        z_hat = (-z_hat[0], -z_hat[1], -z_hat[2])
        z0 = -z0
    x1 = x0 + lx
    y1 = y0 + ly
    z2 = z0 * z0
    xx0 = x0 * x0
    xx1 = x1 * x1
    # z-components of the unit normals of the planes through p and each edge: nz_k = n_k / d_k,
    # n = (-y0, x1, y1, -x0), dd_k = d_k^2 = n_k^2 + z0^2.
    dd0 = y0 * y0 + z2
    dd1 = xx1 + z2
    dd2 = y1 * y1 + z2
    dd3 = xx0 + z2
    all_ok = dd0 > 0.0 and dd1 > 0.0 and dd2 > 0.0 and dd3 > 0.0
    # min_k nz_k^2 > grazing_nz2, without the divisions (nz_k = 0 where d_k = 0).
    grazing = (y0 * y0 > grazing_nz2 * dd0 and xx1 > grazing_nz2 * dd1
               and y1 * y1 > grazing_nz2 * dd2 and xx0 > grazing_nz2 * dd3)
    r00 = math.sqrt(xx0 + dd0)
    r10 = math.sqrt(xx1 + dd0)
    r11 = math.sqrt(xx1 + dd2)
    r01 = math.sqrt(xx0 + dd2)
    x01 = x0 * x1
    y01 = y0 * y1
    v00_v11 = x01 + y01 + z2
    d1 = r00 * r10 * r11 + (x01 + dd0) * r11 + v00_v11 * r10 + (xx1 + y01 + z2) * r00
    d2 = r00 * r11 * r01 + v00_v11 * r01 + (xx0 + y01 + z2) * r11 + (x01 + dd2) * r00
    nn = -z0 * lx * ly
    # Omega / 2 = arg(re + i im) in [0, pi], by vmath's branch-free atan (libm's is a call the
    # batch kernel's loop would make one lane at a time). im < 0 only by rounding, at Omega ~ 0
    # or ~ 2 pi: clamped to 0, the argument is then 0 or pi.
    im = max(nn * (d1 + d2), 0.0)
    re = d1 * d2 - nn * nn
    half = arg_upper(re, im)
    if all_ok and z0 < 0.0:
        solid = max(2.0 * half, 0.0)
    else:
        solid = 0.0
    usable = solid >= min_solid_angle and not grazing and math.isfinite(solid)
    return x_hat, y_hat, z_hat, x0, x1, y0, y1, z0, r00, r01, dd0, dd2, dd3, solid, usable


@njit(cache=True, nogil=True, inline="always")
def _sr_sample(p, st, u0, u1):
    """Point on the rectangle of st = _sr_setup(p, ...) (a usable row), uniformly distributed in
    solid angle seen from p."""
    x_hat, y_hat, z_hat, x0, x1, y0, y1, z0, r00, r01, dd0, dd2, dd3, solid, _ = st
    z2 = z0 * z0
    n0 = -y0
    n2 = y1
    n3 = -x0
    d0 = math.sqrt(dd0)
    d2 = math.sqrt(dd2)
    # One division for b0 = n0 / d0, b1 = n2 / d2 and k (divisions and square roots share one unit,
    # the vectorised sampler's bottleneck). All three are 0 where a distance is 0 (an unusable row).
    k = d0 * d2 * dd3
    k = 1.0 / k if k > 0.0 else 0.0
    b0 = n0 * (d2 * dd3 * k)  # nz0
    b1 = n2 * (d0 * dd3 * k)  # nz2
    # e^{i(h2 + h3)} (see the section comment), both parts over the common d0 d2 d3^2: k.
    cos_h = (z2 * r00 * r01 - n0 * n2 * n3 * n3) * k
    sin_h = -z0 * n3 * (n2 * r00 + n0 * r01) * k
    # au = u0 * solid - (h2 + h3): cos au and sin au by rotating e^{i u0 solid}.
    phi = u0 * solid
    sp, cp = sincos(phi)
    num = (cp * cos_h + sp * sin_h) * b0 + b1
    den = sp * cos_h - cp * sin_h
    # spherical_rect.sample: cu = den sign(num) / sqrt(num^2 + b0^2 den^2), xu = -cu z0 / sqrt(1 -
    # cu^2). As 1 - cu^2 = (num^2 - (1 - b0^2) den^2) / (num^2 + b0^2 den^2) and 1 - b0^2 =
    # z0^2 / dd0, xu = -z0 den sign(num) / sqrt(num^2 - z0^2 den^2 / dd0)
    # = -z0 den sign(num) d0 / sqrt(num^2 dd0 - z0^2 den^2): one sqrt, one division.
    t = -z0 * den * math.copysign(1.0, num) * d0
    rad = num * num * dd0 - z2 * den * den if dd0 > 0.0 else 0.0
    if rad > 0.0:
        xu = t / math.sqrt(rad)
    else:
        xu = math.copysign(math.inf, t) if t != 0.0 else 0.0  # |cu| = 1: an end of [x0, x1]
    xu = _clip(xu, x0, x1)
    # hv = lerp(u1, y0 / r0, y1 / r1) = a / b (r_k = sqrt(xu^2 + z0^2 + y_k^2)), and
    # yv = hv dd / sqrt(1 - hv^2) = a dd / sqrt(b^2 - a^2) (dd = sqrt(xu^2 + z0^2)).
    e2 = xu * xu + z2
    dd = math.sqrt(e2)
    r0 = math.sqrt(e2 + y0 * y0)
    r1 = math.sqrt(e2 + y1 * y1)
    a = y0 * r1 + u1 * (y1 * r0 - y0 * r1)
    b = r0 * r1
    w2 = (b - a) * (b + a)
    if w2 > 0.0:
        yv = a * dd / math.sqrt(w2)
    else:
        yv = math.copysign(math.inf, a) if a != 0.0 else 0.0  # |hv| = 1: an end of [y0, y1]
    yv = _clip(yv, y0, y1)
    return (
        p[0] + xu * x_hat[0] + yv * y_hat[0] + z0 * z_hat[0],
        p[1] + xu * x_hat[1] + yv * y_hat[1] + z0 * z_hat[1],
        p[2] + xu * x_hat[2] + yv * y_hat[2] + z0 * z_hat[2],
    )


# --------------------------------------------------------------------------------------
# Planar hits (rect, disk)
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _ray_plane(o, d, c, n):
    """_common.ray_plane for one row: (t, ok), t = inf when the ray is parallel."""
    den = _dot(n, d)
    ok = den != 0.0
    num = _dot(n, _sub(c, o))
    t = num / den if ok else math.inf
    ok = ok and math.isfinite(t)
    return (t if ok else math.inf), ok


@njit(cache=True, nogil=True)
def _rect_hit(o, d, c, n, exd, eyd):
    """RectLight._hit for one row: (t or inf, a, b, hit)."""
    t, ok = _ray_plane(o, d, c, n)
    tt = t if ok else 0.0
    q = (o[0] + tt * d[0], o[1] + tt * d[1], o[2] + tt * d[2])
    rel = _sub(q, c)
    a = _dot(rel, exd)
    b = _dot(rel, eyd)
    hit = ok and t > 0.0 and abs(a) <= 0.5 and abs(b) <= 0.5
    return (t if hit else math.inf), a, b, hit


# --------------------------------------------------------------------------------------
# Rect light
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _rect_sample_row(pr, u0, u1, c, e1, e2, xh, yh, lx, ly, nl, area_i, textured, is_rect_i, tex_a, tex_b,
                     tex_pdf, min_sa, graz):
    """One row of RectLight.sample_li from pr with (u0, u1): (wi, dist, pdf, pl, ok). The rect
    is c + [-1/2, 1/2] e1 + [-1/2, 1/2] e2 (xh, yh, lx, ly: e1, e2 as unit vectors and lengths),
    nl its emitting normal; textured rows sample (tex_a, tex_b) with area pdf tex_pdf (texel
    sampling, done by the caller). ok = False (pdf 0): seen from behind or unusable."""
    use = False
    pdf_sph = 0.0
    pdf_area = 0.0
    pl = c
    if not textured and is_rect_i:
        # Strategy choice and sampling share this one setup.
        corner = _sub(_sub(c, _scale(0.5, e1)), _scale(0.5, e2))
        st = _sr_setup(pr, corner, xh, yh, lx, ly, min_sa, graz)
        if st[14]:
            use = True
            pdf_sph = 1.0 / st[13]
            pl = _sr_sample(pr, st, u0, u1)
    if not use:
        if textured:
            a = tex_a
            b = tex_b
            pdf_area = tex_pdf
        else:
            a = u0 - 0.5
            b = u1 - 0.5
            pdf_area = 1.0 / area_i if area_i > 0.0 else 0.0
        pl = _add(_add(c, _scale(a, e1)), _scale(b, e2))
    wi, dist = _dir_dist(pr, pl)
    cos_l = -_dot(wi, nl)
    pdf = pdf_sph if use else _area_to_solid_angle(pdf_area, dist, cos_l)
    front = _dot(_sub(pr, c), nl) > 0.0
    ok = front and cos_l > 0.0 and dist > 0.0 and pdf > 0.0
    return wi, dist, (pdf if ok else 0.0), pl, ok


# The same row, numba-inlined into rect_sample_batch_kernel's loop, so the loop body is one
# function LLVM can vectorise.
_rect_sample_row_inline = njit(cache=True, nogil=True, inline="always")(_rect_sample_row.py_func)


@njit(cache=True, nogil=True, error_model="numpy")
def rect_sample_batch_kernel(p, u, col, lo, n, c, e1, e2, xh, yh, lx, ly, nl, area_i, is_rect_i, min_sa, graz, out):
    """_rect_sample_row for one untextured rect light at n points, in a loop LLVM vectorises
    (LLVM predicates the branches; the atan, sin and cos are vmath's polynomials, so the whole
    row runs packed).

    Row i < n takes its point from p[0:3, i] and its uniforms from u[col, lo + i] and
    u[col + 1, lo + i], and writes out[0:5, i]: the fast path's vertex kernel passes its block
    state as p (the hit points are its first rows) and the bounce's uniforms with the block's
    first row as lo. Batch axis last, unlike the rest of the kernels: the vectoriser needs unit
    stride along the loop, which numba knows only for the last axis of a C array. The light's c,
    e1, e2, xh, yh, nl as 3-tuples, lx, ly, area_i floats, is_rect_i bool. out receives wi
    (3 rows, unit, toward the light), the distance and the solid-angle pdf, 0 where the sample is
    unusable (ok False in _rect_sample_row).
    error_model="numpy": numba's ZeroDivisionError checks are branches the vectoriser refuses;
    every division here is guarded or meant to give inf.
    """
    for i in range(n):
        wi, dist, pdf, _pl, ok = _rect_sample_row_inline(
            (p[0, i], p[1, i], p[2, i]), u[col, lo + i], u[col + 1, lo + i], c, e1, e2, xh, yh, lx, ly, nl, area_i,
            False, is_rect_i, 0.0, 0.0, 0.0, min_sa, graz)
        out[0, i] = wi[0]
        out[1, i] = wi[1]
        out[2, i] = wi[2]
        out[3, i] = dist
        out[4, i] = pdf if ok else 0.0


@njit(cache=True, nogil=True)
def _rect_pdf_row(pr, w, c, nl, exd_i, eyd_i, e1, e2, xh, yh, lx, ly, area_i, textured, is_rect_i, tex_pdf,
                  min_sa, graz):
    """One row of RectLight.pdf_li: the solid-angle pdf of sampling direction w from pr (0 where
    w misses the front of the rect). Arguments as _rect_sample_row; exd_i, eyd_i: the duals."""
    t, a, b, hit = _rect_hit(pr, w, c, nl, exd_i, eyd_i)
    cos_l = -_dot(w, nl)
    if not (hit and _dot(_sub(pr, c), nl) > 0.0 and cos_l > 0.0):
        return 0.0
    if textured:
        pdf_area = tex_pdf
    else:
        pdf_area = 1.0 / area_i if area_i > 0.0 else 0.0
    pdf = _area_to_solid_angle(pdf_area, t, cos_l)
    if not textured and is_rect_i:
        corner = _sub(_sub(c, _scale(0.5, e1)), _scale(0.5, e2))
        st = _sr_setup(pr, corner, xh, yh, lx, ly, min_sa, graz)
        if st[14]:
            pdf = 1.0 / st[13]
    return pdf


@njit(cache=True, nogil=True)
def rect_sample_kernel(
    idx, p, u, center, ex, ey, x_hat, y_hat, edge_len, nrm, area, radiance, tex, is_rect, exd, eyd, IM,
    min_sa, graz, out_L, out_wi, out_pdf, out_dist, out_pl,
):
    """RectLight.sample_li. Textured rows (tex >= 0) sample a texel of their image in the
    ImageSet record IM (ImageSet.kernel_record) and take its colour (rect_texel_sample_row,
    rect_radiance_row). x_hat, y_hat (count, 3) and edge_len (count, 2) are ex, ey as unit
    vectors and lengths; exd, eyd the duals."""
    for r in range(idx.shape[0]):
        i = idx[r]
        textured = tex[i] >= 0
        ta = tb = t_pdf = 0.0
        if textured:
            ta, tb, t_pdf = rect_texel_sample_row(tex[i], u[r, 0], u[r, 1], area[i], IM)
        wi, dist, pdf, pl, ok = _rect_sample_row(
            _row(p, r), u[r, 0], u[r, 1], _row(center, i), _row(ex, i), _row(ey, i), _row(x_hat, i),
            _row(y_hat, i), edge_len[i, 0], edge_len[i, 1], _row(nrm, i), area[i], textured, is_rect[i],
            ta, tb, t_pdf, min_sa, graz)
        out_pdf[r] = pdf
        Le = _row(radiance, i)
        if textured and ok:
            Le = rect_radiance_row(Le, tex[i], pl, _row(center, i), _row(exd, i), _row(eyd, i), IM)
        for k in range(3):
            out_L[r, k] = Le[k] if ok else 0.0
        _put(out_wi, r, wi)
        out_dist[r] = dist
        _put(out_pl, r, pl)


@njit(cache=True, nogil=True)
def rect_pdf_kernel(
    idx, p, wi, center, ex, ey, x_hat, y_hat, edge_len, nrm, area, exd, eyd, tex, is_rect, IM,
    min_sa, graz, out_pdf,
):
    """RectLight.pdf_li. Textured rows take the texel pmf where wi meets the plane
    (rect_texel_pdf_row). x_hat, y_hat, edge_len as in rect_sample_kernel."""
    for r in range(idx.shape[0]):
        i = idx[r]
        textured = tex[i] >= 0
        t_pdf = 0.0
        if textured:
            _t, a, b, _hit = _rect_hit(_row(p, r), _row(wi, r), _row(center, i), _row(nrm, i), _row(exd, i),
                                       _row(eyd, i))
            t_pdf = rect_texel_pdf_row(tex[i], a, b, area[i], IM)
        out_pdf[r] = _rect_pdf_row(
            _row(p, r), _row(wi, r), _row(center, i), _row(nrm, i), _row(exd, i), _row(eyd, i), _row(ex, i),
            _row(ey, i), _row(x_hat, i), _row(y_hat, i), edge_len[i, 0], edge_len[i, 1], area[i], textured,
            is_rect[i], t_pdf, min_sa, graz)


@njit(cache=True, nogil=True)
def rect_radiance_kernel(idx, q, center, exd, eyd, radiance, tex, IM, out_L):
    """RectLight's front-side radiance at points q (n, 3) on lights idx (n,): the texel's colour
    times L on textured rows (rect_radiance_row), L elsewhere."""
    for r in range(idx.shape[0]):
        i = idx[r]
        Le = _row(radiance, i)
        if tex[i] >= 0:
            Le = rect_radiance_row(Le, tex[i], _row(q, r), _row(center, i), _row(exd, i), _row(eyd, i), IM)
        _put(out_L, r, Le)


# --------------------------------------------------------------------------------------
# Textured rect light, per row (renderer/lights/rect.py's texture rule: uv = 1/2 - (a, b),
# image column floor(u W), row floor((1 - v) H), nearest texel; texels picked by the image's
# luminance distribution, area pdf pmf H W / A). IM: ImageSet.kernel_record().
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def rect_texel_row(img, a, b, IM):
    """The flat index of the texel of image img at the rect's edge coordinates (a, b)."""
    offset, height, width = IM[1], IM[2], IM[3]
    h = height[img]
    w = width[img]
    u = min(max(0.5 - a, 0.0), 1.0)
    v = min(max(0.5 - b, 0.0), 1.0)
    col = min(int(math.floor(u * w)), w - 1)
    row = min(int(math.floor((1.0 - v) * h)), h - 1)
    return offset[img] + row * w + col


@njit(cache=True, nogil=True)
def rect_radiance_row(Le, img, q, c, exd, eyd, IM):
    """Le (3-tuple) times the colour of image img's texel at the point q of the rect centred at
    c (duals exd, eyd)."""
    rel = _sub(q, c)
    k = rect_texel_row(img, _dot(rel, exd), _dot(rel, eyd), IM)
    texels = IM[0]
    return (Le[0] * texels[k, 0], Le[1] * texels[k, 1], Le[2] * texels[k, 2])


@njit(cache=True, nogil=True)
def rect_texel_sample_row(img, u0, u1, area_i, IM):
    """A texel of image img picked by its luminance (u1 the row, u0 the column) and a point in
    it: (a, b, area pdf) on the rect of area area_i."""
    texels, offset, height, width, weight, total, row_cdf, row_cdf_start, col_cdf, col_cdf_start = IM
    row, col, s, t = _image_sample_row(img, u0, u1, height, width, row_cdf, row_cdf_start, col_cdf, col_cdf_start)
    h = height[img]
    w = width[img]
    pmf = weight[_texel_flat(img, row, col, offset, height, width)] / total[img]
    return 0.5 - (col + s) / w, (row + t) / h - 0.5, (pmf * (h * w) / area_i if area_i > 0.0 else 0.0)


@njit(cache=True, nogil=True)
def rect_texel_pdf_row(img, a, b, area_i, IM):
    """The area pdf of rect_texel_sample_row at the edge coordinates (a, b)."""
    weight, total, height, width = IM[4], IM[5], IM[2], IM[3]
    k = rect_texel_row(img, a, b, IM)
    return weight[k] / total[img] * (height[img] * width[img]) / area_i if area_i > 0.0 else 0.0


@njit(cache=True, nogil=True)
def rect_hit_kernel(idx, o, d, center, nrm, exd, eyd, out_t, out_ab):
    """RectLight._hit: t (n,) (inf on a miss) and the edge coordinates (a, b) (n, 2) of the
    plane hit (meaningful only where t is finite). out_ab may have 0 rows (not wanted)."""
    want_ab = out_ab.shape[0] > 0
    for r in range(idx.shape[0]):
        i = idx[r]
        t, a, b, hit = _rect_hit(
            _row(o, r), _row(d, r), _row(center, i), _row(nrm, i), _row(exd, i), _row(eyd, i)
        )
        out_t[r] = t
        if want_ab:
            out_ab[r, 0] = a
            out_ab[r, 1] = b


# --------------------------------------------------------------------------------------
# Disk light
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _disk_q(x, c, u1, u2, s1, s2):
    """DiskLight._q for one row: unit-disk coordinates of x projected onto the disk's plane."""
    rel = _sub(x, c)
    q1 = _dot(rel, u1) / s1 if s1 > 0 else 0.0
    q2 = _dot(rel, u2) / s2 if s2 > 0 else 0.0
    return q1, q2


@njit(cache=True, nogil=True)
def _disk_close(p, c, nl, u1, u2, s1, s2, close_ratio):
    """First half of DiskLight._strategy for one row: (d_far > close_ratio d_near, p in front)."""
    rel = _sub(p, c)
    hn = _dot(rel, nl)
    h = abs(hn)
    q1, q2 = _disk_q(p, c, u1, u2, s1, s2)
    qn = math.sqrt(q1 * q1 + q2 * q2 + 0.0)
    rho = math.sqrt(max(_dot(rel, rel) - h * h, 0.0))  # in-plane distance to the centre
    # Bounds of the distances from p to the ellipse: in-plane nearest >= s2 (|q| - 1),
    # in-plane farthest <= rho + s1 (exact for circles).
    near = s2 * max(qn - 1.0, 0.0)
    far = rho + s1
    d_near = math.sqrt(h * h + near * near)
    d_far = math.sqrt(h * h + far * far)
    return d_far > close_ratio * d_near, hn > 0.0


@njit(cache=True, nogil=True)
def _disk_rect(p, c, a1, a2, min_sa, graz):
    """Spherical-rectangle setup of the bounding rectangle [-a1, a1] x [-a2, a2] of a disk
    centred at c, seen from p."""
    corner = _sub(_sub(c, a1), a2)
    x_hat, y_hat, lx, ly = _sr_frame(_scale(2.0, a1), _scale(2.0, a2))
    return _sr_setup(p, corner, x_hat, y_hat, lx, ly, min_sa, graz)


@njit(cache=True, nogil=True)
def disk_strategy_kernel(idx, p, center, e1, e2, nrm, u1, u2, s1, s2, close_ratio, min_sa, graz,
                         out_use, out_solid):
    """DiskLight._strategy: use solid-angle sampling (n,) bool and the bounding rectangle's
    solid angle (n,) (sr, from p)."""
    for r in range(idx.shape[0]):
        i = idx[r]
        pr = _row(p, r)
        c = _row(center, i)
        close, front = _disk_close(pr, c, _row(nrm, i), _row(u1, i), _row(u2, i), s1[i], s2[i], close_ratio)
        st = _disk_rect(pr, c, _row(e1, i), _row(e2, i), min_sa, graz)
        out_use[r] = close and front and st[14]
        out_solid[r] = st[13]


@njit(cache=True, nogil=True)
def _disk_sample_row(pr, u0, u1, c, nl, v1, v2, a1, a2, s1_i, s2_i, area_i, close_ratio, min_sa, graz):
    """One row of DiskLight.sample_li from pr: (wi, dist, pdf, pl, ok). Concentric area sampling
    or bounding-rectangle solid-angle sampling (samples outside the ellipse fail). The disk is
    c + e1 cos + e2 sin, with e_k = a_k = s_k v_k (v_k unit), nl its emitting normal."""
    close, front = _disk_close(pr, c, nl, v1, v2, s1_i, s2_i, close_ratio)
    use = False
    inside = True
    pdf_sph = 0.0
    pl = c
    if close and front:
        st = _disk_rect(pr, c, a1, a2, min_sa, graz)
        if st[14]:
            use = True
            pdf_sph = 1.0 / st[13]
            pl = _sr_sample(pr, st, u0, u1)
            q1, q2 = _disk_q(pl, c, v1, v2, s1_i, s2_i)
            inside = q1 * q1 + q2 * q2 <= 1.0
    if not use:
        # Shirley-Chiu concentric map (sampling.sample_uniform_disk_concentric).
        sa = 2.0 * u0 - 1.0
        sb = 2.0 * u1 - 1.0
        if abs(sa) > abs(sb):
            rad = sa
            th = (_PI / 4.0) * (sb / sa)
        else:
            rad = sb
            th = (_PI / 2.0) - (_PI / 4.0) * (sa / sb if sb != 0.0 else 0.0)
        qa = rad * math.cos(th)
        qb = rad * math.sin(th)
        pl = _add(_add(c, _scale(qa, a1)), _scale(qb, a2))
    wi, dist = _dir_dist(pr, pl)
    cos_l = -_dot(wi, nl)
    if use:
        pdf = pdf_sph
    else:
        pdf_area = 1.0 / area_i if area_i > 0.0 else 0.0
        pdf = _area_to_solid_angle(pdf_area, dist, cos_l)
    ok = inside and front and cos_l > 0.0 and dist > 0.0 and pdf > 0.0
    return wi, dist, (pdf if ok else 0.0), pl, ok


@njit(cache=True, nogil=True)
def disk_sample_kernel(
    idx, p, u, center, e1, e2, nrm, u1, u2, s1, s2, area, radiance, close_ratio, min_sa, graz,
    out_L, out_wi, out_pdf, out_dist, out_pl,
):
    """DiskLight.sample_li (_disk_sample_row per row)."""
    for r in range(idx.shape[0]):
        i = idx[r]
        wi, dist, pdf, pl, ok = _disk_sample_row(
            _row(p, r), u[r, 0], u[r, 1], _row(center, i), _row(nrm, i), _row(u1, i), _row(u2, i), _row(e1, i),
            _row(e2, i), s1[i], s2[i], area[i], close_ratio, min_sa, graz)
        out_pdf[r] = pdf
        for k in range(3):
            out_L[r, k] = radiance[i, k] if ok else 0.0
        _put(out_wi, r, wi)
        out_dist[r] = dist
        _put(out_pl, r, pl)


@njit(cache=True, nogil=True)
def _disk_hit(o, d, c, nl, u1, u2, s1, s2):
    t, ok = _ray_plane(o, d, c, nl)
    tt = t if ok else 0.0
    x = (o[0] + tt * d[0], o[1] + tt * d[1], o[2] + tt * d[2])
    q1, q2 = _disk_q(x, c, u1, u2, s1, s2)
    hit = ok and t > 0.0 and q1 * q1 + q2 * q2 <= 1.0
    return (t if hit else math.inf), hit


@njit(cache=True, nogil=True)
def _disk_pdf_row(pr, w, c, nl, v1, v2, a1, a2, s1_i, s2_i, area_i, close_ratio, min_sa, graz):
    """One row of DiskLight.pdf_li: the solid-angle pdf of sampling direction w from pr (0 where
    w misses the front of the disk). Arguments as _disk_sample_row."""
    t, hit = _disk_hit(pr, w, c, nl, v1, v2, s1_i, s2_i)
    cos_l = -_dot(w, nl)
    if not (hit and _dot(_sub(pr, c), nl) > 0.0 and cos_l > 0.0):
        return 0.0
    pdf_area = 1.0 / area_i if area_i > 0.0 else 0.0
    pdf = _area_to_solid_angle(pdf_area, t, cos_l)
    # hit implies p in front, the other half of the strategy rule.
    close, _ = _disk_close(pr, c, nl, v1, v2, s1_i, s2_i, close_ratio)
    if close:
        st = _disk_rect(pr, c, a1, a2, min_sa, graz)
        if st[14]:
            pdf = 1.0 / st[13]
    return pdf


@njit(cache=True, nogil=True)
def disk_pdf_kernel(
    idx, p, wi, center, e1, e2, nrm, u1, u2, s1, s2, area, close_ratio, min_sa, graz, out_pdf,
):
    """DiskLight.pdf_li (_disk_pdf_row per row)."""
    for r in range(idx.shape[0]):
        i = idx[r]
        out_pdf[r] = _disk_pdf_row(_row(p, r), _row(wi, r), _row(center, i), _row(nrm, i), _row(u1, i), _row(u2, i),
                                   _row(e1, i), _row(e2, i), s1[i], s2[i], area[i], close_ratio, min_sa, graz)


@njit(cache=True, nogil=True)
def disk_hit_kernel(idx, o, d, center, nrm, u1, u2, s1, s2, out_t):
    """DiskLight.intersect: t (n,), inf where the ray misses the (two-sided) ellipse."""
    for r in range(idx.shape[0]):
        i = idx[r]
        out_t[r] = _disk_hit(_row(o, r), _row(d, r), _row(center, i), _row(nrm, i), _row(u1, i), _row(u2, i),
                             s1[i], s2[i])[0]


# --------------------------------------------------------------------------------------
# Sphere light
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def _sphere_cone(p, c, r, delta):
    """SphereLight._cone for one row: (w_c, dc, sin2_max, 1 - cos theta_max, cos theta_max, ok)."""
    v = _sub(c, p)
    dc2 = _dot(v, v)  # used as is, not as sqrt(dc2)^2: keeps the sqrt off the critical path
    dc = math.sqrt(dc2)
    s = dc if dc > 0.0 else 1.0
    w_c = (v[0] / s, v[1] / s, v[2] / s)
    outside = dc2 > r * r * (1.0 + 1e-12)
    sin2 = (r * r) / dc2 if outside else 1.0
    cos_max = math.sqrt(max(0.0, 1.0 - sin2))
    omc = sin2 / (1.0 + cos_max)  # 1 - cos theta_max without cancellation
    return w_c, dc, sin2, omc, cos_max, outside and not delta and r > 0.0


@njit(cache=True, nogil=True)
def _sphere_sample_row(pr, u0, u1, c, r, delta_i):
    """One row of SphereLight.sample_li from pr: (wi, dist, pdf, pl, ok, l_scale), the radiance
    being l_scale times the light's. Uniform cone sampling mapped to the visible sphere point;
    a delta (treatAsPoint) light returns its centre with pdf 1 and l_scale pi r^2 / d^2."""
    w_c, dc, sin2_max, omc, cos_max, ok = _sphere_cone(pr, c, r, delta_i)
    x = u0 * omc
    cos_t = 1.0 - x
    # sin^2 theta = x (2 - x) and x = u0 sin^2 theta_max / (1 + cos theta_max), so
    # ratio2 = sin^2 theta / sin^2 theta_max = u0 (2 - x) / (1 + cos theta_max) without a
    # division by sin^2 theta_max (one division fewer on the critical path), and
    # ratio = sin^2 theta / sin theta_max = ratio2 sin theta_max.
    ratio2 = u0 * (2.0 - x) / (1.0 + cos_max)
    ratio = ratio2 * math.sqrt(sin2_max)
    cos_a = _clip(ratio + cos_t * math.sqrt(max(0.0, 1.0 - ratio2)), -1.0, 1.0)
    sin_a = math.sqrt(max(0.0, 1.0 - cos_a * cos_a))
    n_s = _around(w_c, -cos_a, sin_a, 2.0 * _PI * u1)
    pl = _add(c, _scale(r, n_s))
    wi, dist = _dir_dist(pr, pl)
    den = _TWO_PI * omc
    pdf = 1.0 / den if (ok and omc > 0.0) else 0.0
    ok = ok and pdf > 0.0 and dist > 0.0
    # Computed for every row and chosen by selects, not an early return: the batch kernel's
    # loop vectorises only without the branch.
    good = dc > 0.0
    inv_d2 = 1.0 / (dc * dc) if good else 0.0
    if delta_i:
        return w_c, dc, (1.0 if good else 0.0), c, good, _PI * r * r * inv_d2
    return wi, dist, (pdf if ok else 0.0), pl, ok, 1.0


@njit(cache=True, nogil=True)
def sphere_sample_kernel(
    idx, p, u, center, radius, radiance, delta, out_L, out_wi, out_pdf, out_dist, out_pl,
):
    """SphereLight.sample_li (_sphere_sample_row per row)."""
    for row in range(idx.shape[0]):
        i = idx[row]
        wi, dist, pdf, pl, ok, l_scale = _sphere_sample_row(_row(p, row), u[row, 0], u[row, 1], _row(center, i),
                                                            radius[i], delta[i])
        for j in range(3):
            out_L[row, j] = radiance[i, j] * l_scale if ok else 0.0
        _put(out_wi, row, wi)
        out_dist[row] = dist
        _put(out_pl, row, pl)
        out_pdf[row] = pdf


_sphere_sample_row_inline = njit(cache=True, nogil=True, inline="always")(_sphere_sample_row.py_func)


@njit(cache=True, nogil=True, error_model="numpy")
def sphere_sample_batch_kernel(p, u, col, lo, n, c, radius, delta_i, out):
    """_sphere_sample_row for one SphereLight at n points, vectorised as rect_sample_batch_kernel
    is (same rows: p[0:3, i], u[col:col + 2, lo + i], out[:, i]). c: 3-tuple, radius float,
    delta_i bool (treatAsPoint). out receives wi (3 rows), the distance, the pdf (0 where
    unusable) and the radiance scale l_scale."""
    for i in range(n):
        wi, dist, pdf, _pl, ok, l_scale = _sphere_sample_row_inline(
            (p[0, i], p[1, i], p[2, i]), u[col, lo + i], u[col + 1, lo + i], c, radius, delta_i)
        out[0, i] = wi[0]
        out[1, i] = wi[1]
        out[2, i] = wi[2]
        out[3, i] = dist
        out[4, i] = pdf if ok else 0.0
        out[5, i] = l_scale


@njit(cache=True, nogil=True)
def _sphere_pdf_row(pr, w, c, r, delta_i):
    """One row of SphereLight.pdf_li: 1 / (2 pi (1 - cos theta_max)) inside the cone, else 0."""
    w_c, dc, sin2_max, omc, _, ok = _sphere_cone(pr, c, r, delta_i)
    # sin^2 of the angle between wi and w_c, accurate for tiny cones (no 1 - cos).
    cr = _cross(w, w_c)
    sin2 = _dot(cr, cr)
    ok = ok and _dot(w, w_c) > 0.0 and sin2 <= sin2_max * (1.0 + 1e-9)
    return 1.0 / (_TWO_PI * omc) if (ok and omc > 0.0) else 0.0


@njit(cache=True, nogil=True)
def sphere_pdf_kernel(idx, p, wi, center, radius, delta, out_pdf):
    """SphereLight.pdf_li (_sphere_pdf_row per row)."""
    for row in range(idx.shape[0]):
        i = idx[row]
        out_pdf[row] = _sphere_pdf_row(_row(p, row), _row(wi, row), _row(center, i), radius[i], delta[i])


@njit(cache=True, nogil=True)
def _sphere_hit_row(o, dr, c, r, delta_i):
    """One row of SphereLight.intersect: first t > 0 (inner hits included), inf on a miss or
    for points."""
    oc = _sub(o, c)
    b = _dot(oc, dr)
    # Discriminant from the perpendicular offset (better conditioned than b^2 - c).
    perp = _sub(oc, _scale(b, dr))
    disc = r * r - _dot(perp, perp)
    if not (disc >= 0.0 and not delta_i and r > 0.0):
        return math.inf
    sq = math.sqrt(max(disc, 0.0))
    cc = _dot(oc, oc) - r * r
    q = -b - math.copysign(sq, b)
    t0 = cc / q if q != 0.0 else math.inf
    t1 = q
    tn = min(t0, t1)
    tf = max(t0, t1)
    return tn if tn > 0.0 else (tf if tf > 0.0 else math.inf)


@njit(cache=True, nogil=True)
def sphere_hit_kernel(idx, o, d, center, radius, delta, out_t):
    """SphereLight.intersect (_sphere_hit_row per row)."""
    for row in range(idx.shape[0]):
        i = idx[row]
        out_t[row] = _sphere_hit_row(_row(o, row), _row(d, row), _row(center, i), radius[i], delta[i])


# --------------------------------------------------------------------------------------
# Infinite lights, per row: a DistantLight's cone and a constant (untextured, portal-free)
# DomeLight's sphere (the formulas of renderer/lights/distant.py and dome.py, for the fast
# path's vertex kernel; those lights' own methods stay numpy).
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _distant_sample_row(u0, u1, axis, omc, delta_i):
    """DistantLight.sample_li's direction and pdf: (wi, pdf). Uniform in the cone of half-angle
    theta_max about axis (omc = 1 - cos theta_max); a delta light gives the axis with pdf 1."""
    if delta_i:
        return axis, 1.0
    x = u0 * omc  # 1 - cos theta, uniform in [0, omc]
    wi = _around(axis, 1.0 - x, math.sqrt(max(0.0, x * (2.0 - x))), 2.0 * _PI * u1)
    return wi, 1.0 / (_TWO_PI * omc)


@njit(cache=True, nogil=True)
def _distant_pdf_row(w, axis, omc, delta_i):
    """DistantLight.pdf_li: 1 / (2 pi (1 - cos theta_max)) inside the cone (|w - axis|^2 / 2 =
    1 - cos, accurate for tiny cones), else 0; always 0 for a delta light. Also the test for
    le_escaped (the light is seen along w where the pdf is > 0)."""
    dd = _sub(w, axis)
    inside = 0.5 * _dot(dd, dd) <= omc * (1.0 + 1e-9) and not delta_i
    return 1.0 / (_TWO_PI * omc) if inside else 0.0


@njit(cache=True, nogil=True)
def _uniform_sphere_row(u0, u1):
    """sampling.sample_uniform_sphere for one row (pdf 1 / (4 pi))."""
    z = 1.0 - 2.0 * u0
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * _PI * u1
    return (r * math.cos(phi), r * math.sin(phi), z)


# --------------------------------------------------------------------------------------
# Textured DomeLight, per row (renderer/lights/dome.py and texture.ImageSet's numpy, for the
# fast path's vertex kernel): lat-long texel <-> direction and the texel-luminance distribution.
# --------------------------------------------------------------------------------------
_BELOW_ONE = 1.0 - 2.0 ** -53  # np.nextafter(1.0, 0.0)


@njit(cache=True, nogil=True)
def _cdf_search(cdf, start, ncells, u):
    """texture._search for one row: the largest k in [0, ncells - 1] with cdf[start + k] <= u."""
    lo = 0
    hi = ncells
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if cdf[start + mid] <= u:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _cdf_fraction(lo, hi, u):
    """texture._fraction for one row: where u falls in [lo, hi), in [0, 1)."""
    w = hi - lo
    f = (u - lo) / w if w > 0.0 else 0.0
    return min(max(f, 0.0), _BELOW_ONE)


@njit(cache=True, nogil=True)
def _image_sample_row(img, u0, u1, height, width, row_cdf, row_cdf_start, col_cdf, col_cdf_start):
    """ImageSet.sample for one row: (row, col, s, t) -- u1 picks the row, u0 the column."""
    h = height[img]
    w = width[img]
    rs = row_cdf_start[img]
    row = _cdf_search(row_cdf, rs, h, u1)
    t = _cdf_fraction(row_cdf[rs + row], row_cdf[rs + row + 1], u1)
    cs = col_cdf_start[img] + row * (w + 1)
    col = _cdf_search(col_cdf, cs, w, u0)
    s = _cdf_fraction(col_cdf[cs + col], col_cdf[cs + col + 1], u0)
    return row, col, s, t


@njit(cache=True, nogil=True)
def _texel_flat(img, row, col, offset, height, width):
    """ImageSet.texel_index for one row (clamped to the image)."""
    r = min(max(row, 0), height[img] - 1)
    c = min(max(col, 0), width[img] - 1)
    return offset[img] + r * width[img] + c


@njit(cache=True, nogil=True)
def _latlong_texel(dl, h, w):
    """dome.direction_to_texel for one local unit direction dl: the nearest (row, col)."""
    theta = math.atan2(math.hypot(dl[0], dl[2]), dl[1])  # from +Y, [0, pi]
    lon = math.atan2(dl[0], dl[2])  # (-pi, pi]
    u = (_PI - lon) / _TWO_PI  # [0, 1]
    row = min(max(int(math.floor(theta / _PI * h)), 0), h - 1)
    col = int(math.floor(u * w)) % w
    return row, col


@njit(cache=True, nogil=True)
def _latlong_band(row, h, w):
    """(cos theta at the top of texel row ``row``, at its bottom, its solid angle / texel)."""
    z_top = math.cos(_PI * row / h)
    z_bot = math.cos(_PI * (row + 1) / h)
    return z_top, z_bot, (_TWO_PI / w) * (z_top - z_bot)


@njit(cache=True, nogil=True)
def _dome_sample_row(u0, u1, img, rot, height, width, row_cdf, row_cdf_start, col_cdf, col_cdf_start, weight,
                     total, offset):
    """DomeLight._sample_dome for one textured row: (wi world, pdf, texel flat index). rot
    (3, 3) is the dome's local -> world rotation."""
    h = height[img]
    w = width[img]
    row, col, s, t = _image_sample_row(img, u0, u1, height, width, row_cdf, row_cdf_start, col_cdf,
                                       col_cdf_start)
    z_top, z_bot, omega = _latlong_band(row, h, w)
    cos_t = z_top + t * (z_bot - z_top)
    lon = _PI - _TWO_PI * ((col + s) / w)  # dome.texel_to_direction
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    dl = (math.sin(lon) * sin_t, cos_t, math.cos(lon) * sin_t)
    wi = (rot[0, 0] * dl[0] + rot[0, 1] * dl[1] + rot[0, 2] * dl[2],
          rot[1, 0] * dl[0] + rot[1, 1] * dl[1] + rot[1, 2] * dl[2],
          rot[2, 0] * dl[0] + rot[2, 1] * dl[1] + rot[2, 2] * dl[2])
    k = _texel_flat(img, row, col, offset, height, width)
    pmf = weight[k] / total[img]
    return wi, (pmf / omega if omega > 0.0 else 0.0), k


@njit(cache=True, nogil=True)
def _dome_texel_row(wi, img, rot, height, width, weight, total, offset):
    """DomeLight._pdf_dome and le_escaped's texel for one textured row: (pdf, texel flat index)
    of world direction wi."""
    h = height[img]
    w = width[img]
    dl = (rot[0, 0] * wi[0] + rot[1, 0] * wi[1] + rot[2, 0] * wi[2],  # R^T wi
          rot[0, 1] * wi[0] + rot[1, 1] * wi[1] + rot[2, 1] * wi[2],
          rot[0, 2] * wi[0] + rot[1, 2] * wi[1] + rot[2, 2] * wi[2])
    row, col = _latlong_texel(dl, h, w)
    _, _, omega = _latlong_band(row, h, w)
    k = _texel_flat(img, row, col, offset, height, width)
    pmf = weight[k] / total[img]
    return (pmf / omega if omega > 0.0 else 0.0), k


# The spherical rectangle and the cone inline vmath's sin, cos and atan: flush this file's cached
# kernels when vmath.py changes.
guard_cache(__name__, module_dispatchers(globals()), ["renderer/kernels/vmath.py"])
