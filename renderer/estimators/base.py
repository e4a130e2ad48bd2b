"""Direct-lighting estimators: the shared sampling stage and the estimator contract.

An estimator computes, for rows of (shading point, light) pairs, the light's direct
contribution  ∫ f(wo, wi) L(wi) v(wi) |cos θ_i| dωi  toward ``wo``, with that light's N samples.
Each estimator is self-contained: it draws its own light samples and/or BSDF samples, traces
their shadow rays through ``trace`` and returns the *whole* contribution of the light. The
path's continuation ray therefore never adds emission from a light that an estimator already
covered at that vertex (see integrators/path.py), so nothing is counted twice.

Everything here is batched with the batch axis first; ``N`` samples per row are laid out as
(n, N, ...) arrays. Random numbers come in through ``DirectRandom`` from the integrator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from ..geometry import dot, offset_origin, to_local, to_world
from ..kernels.direct import split_kernel, tint_rows_kernel
from ..lights.base import ShadingContext
from ..sampling import balance_heuristic, power_heuristic, safe_div

# visible(p, ng, wi, dist, eps) -> (m,) bool.  p, ng, wi: (m, 3); dist, eps: (m,)
TraceFn = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class DirectQuery:
    """n rows, each one shading point and one light.

    ctx: shading points (p, ng, ns faced toward wo); s, t: (n, 3) shading tangents;
    wo_l: (n, 3) wo in the local shading frame; bsdf: the BSDF for these rows;
    light: (n,) global light index; eps: (n,) ray-origin offsets;
    control: (n, 3) c(wo), the BSDF's wi-constant diffuse lobe at each row (the control
    variate's function, whose integral F = c(wo)·E is exact).
    pmf: (n,) probability with which the lighting service picked each row's light, or None
    (1). Only the light half of continuation MIS needs it (see mis.mis_light_half).
    """

    ctx: ShadingContext
    s: np.ndarray
    t: np.ndarray
    wo_l: np.ndarray
    bsdf: object
    light: np.ndarray
    eps: np.ndarray
    control: np.ndarray
    pmf: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.light.shape[0]


@dataclass(frozen=True)
class DirectRandom:
    """u_light: (n, N, 2); u_lobe: (n, N); u_bsdf: (n, N, 2)."""

    u_light: np.ndarray
    u_lobe: np.ndarray
    u_bsdf: np.ndarray

    @staticmethod
    def draw(rng: np.random.Generator, n: int, N: int) -> "DirectRandom":
        return DirectRandom(rng.random((n, N, 2)), rng.random((n, N)), rng.random((n, N, 2)))


@dataclass
class SampleSet:
    """N samples per row of one technique. All (n, N[, 3]).

    fd: the control lobe g = c(wo) (the BSDF's wi-constant diffuse part, ``diffuse_constant``)
        times |cos| times the light's radiance L (unshadowed): its integral is known exactly;
    fs: the residual f − g (the specular lobes plus the diffuse lobe's wi-dependent part),
        times |cos| times L. fd + fs is the whole integrand;
    p_l, p_b: the sample direction's light pdf and BSDF (mixture) pdf; v: visibility (0/1),
    0 below the geometric or shading horizon; valid: the sample carries a usable pdf.
    """

    fd: np.ndarray
    fs: np.ndarray
    p_l: np.ndarray
    p_b: np.ndarray
    v: np.ndarray
    valid: np.ndarray


@dataclass
class DirectResult:
    """Ld: (n, 3) contribution (not yet divided by the light-pick pmf).
    shadow_rays: rays traced; negative: rows whose estimate has a negative channel."""

    Ld: np.ndarray
    shadow_rays: int = 0


class DirectEstimator(Protocol):
    token: str

    def estimate(self, q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 alpha: str, heuristic: str) -> DirectResult:
        ...


def _flat(q: DirectQuery, N: int) -> np.ndarray:
    """Row index of every sample when the (n, N) layout is flattened."""
    return np.repeat(np.arange(q.n), N)


def light_samples(q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                  need_visibility: bool = True, trace_mask: np.ndarray | None = None) -> tuple[SampleSet, int]:
    """N light samples per row, unshadowed integrands and (optionally) their visibility.

    trace_mask: (n,) rows for which shadow rays may be traced (others get v = 0 where f > 0);
    shadow rays are traced only where the unshadowed integrand is non-zero.
    """
    n = q.n
    r = _flat(q, N)
    # One sample per row (every vertex but the first): the rows are the query's own, uncopied.
    rep = (lambda a: a) if N == 1 else (lambda a: a[r])
    ctx = q.ctx if N == 1 else q.ctx.take(r)
    light = rep(q.light)
    ls = lights.sample_li(light, ctx, u.u_light.reshape(-1, 2))
    wi_l = to_local(ls.wi, rep(q.s), rep(q.t), ctx.ns)
    cos_i = np.abs(wi_l[:, 2])
    above = (wi_l[:, 2] > 0.0) & (dot(ls.wi, ctx.n) > 0.0)
    valid = ls.pdf > 0.0
    bsdf = q.bsdf if N == 1 else q.bsdf.take(r)
    fd, fs, p_b = split_integrand(bsdf, rep(q.wo_l), wi_l, (cos_i * above)[:, None] * ls.L, lights, light,
                                  control=rep(q.control))
    v = np.zeros(r.size)
    rays = 0
    if need_visibility:
        want = valid & above & _any_positive(fd, fs)
        if trace_mask is not None:
            want &= rep(trace_mask)
        idx = np.nonzero(want)[0]
        if idx.size:
            v[idx] = trace(ctx.p[idx], ctx.n[idx], ls.wi[idx], ls.dist[idx], rep(q.eps)[idx]).astype(np.float64)
            rays = idx.size
            if getattr(lights, "shadow_tint", None) is not None:
                tint_shadows(lights.shadow_tint, light[idx], idx, v, fd, fs)
    delta = lights.delta[light]
    # Delta lights cannot be hit by BSDF samples: their light pdf is "infinite" for MIS.
    p_l = np.where(delta, np.inf, ls.pdf)
    return SampleSet(fd.reshape(n, N, 3), fs.reshape(n, N, 3), p_l.reshape(n, N), p_b.reshape(n, N),
                     v.reshape(n, N), valid.reshape(n, N)), rays


def bsdf_samples(q: DirectQuery, lights, trace: TraceFn, N: int, u: DirectRandom,
                 rows_mask: np.ndarray | None = None) -> tuple[SampleSet, int]:
    """N BSDF samples per row; each finds whether it hits *this row's light* and with what L.

    rows_mask: (n,) rows that need BSDF samples at all (others get zeros, no rays).
    """
    n = q.n
    r = _flat(q, N)
    if rows_mask is not None:
        keep = rows_mask[r]
    else:
        keep = np.ones(r.size, dtype=bool)
    fd = np.zeros((r.size, 3))
    fs = np.zeros((r.size, 3))
    p_l = np.zeros(r.size)
    p_b = np.zeros(r.size)
    v = np.zeros(r.size)
    valid = np.zeros(r.size, dtype=bool)
    rays = 0
    k = np.nonzero(keep)[0]
    if k.size:
        rk = r[k]
        bsdf = q.bsdf.take(rk)
        bs = bsdf.sample_f(q.wo_l[rk], u.u_lobe.reshape(-1)[k], u.u_bsdf.reshape(-1, 2)[k])
        wi = to_world(bs.wi, q.s[rk], q.t[rk], q.ctx.ns[rk])
        ctx = q.ctx.take(rk)
        light = q.light[rk]
        ok = (bs.pdf > 0.0) & (dot(wi, ctx.n) > 0.0) & (bs.wi[:, 2] > 0.0)
        # Which samples reach the light, and at what distance / radiance. Lights are not in the
        # BVH, so they are intersected from p itself: the distance and pdf_li then refer to the
        # same point the shadow ray starts from (offsetting here biased MIS by offset/distance).
        t_l, Le = light_along(lights, light, ctx.p, wi)
        hit = ok & np.any(Le > 0.0, axis=1)
        cos_i = np.abs(bs.wi[:, 2])
        fdk, fsk, _ = split_integrand(bsdf, q.wo_l[rk], bs.wi, (cos_i * hit)[:, None] * Le, lights, light,
                                      control=q.control[rk], with_pdf=False)
        pl = np.zeros(k.size)
        if np.any(hit):
            h = np.nonzero(hit)[0]
            pl[h] = lights.pdf_li(light[h], ctx.take(h), wi[h])
        want = hit & _any_positive(fdk, fsk)
        vk = np.zeros(k.size)
        w_idx = np.nonzero(want)[0]
        if w_idx.size:
            # The shadow ray stops at the light (finite) or runs to infinity (dome, distant).
            vk[w_idx] = trace(ctx.p[w_idx], ctx.n[w_idx], wi[w_idx], t_l[w_idx], q.eps[rk][w_idx]).astype(np.float64)
            rays = w_idx.size
            if getattr(lights, "shadow_tint", None) is not None:
                tint_shadows(lights.shadow_tint, light[w_idx], w_idx, vk, fdk, fsk)
        fd[k], fs[k], p_l[k], p_b[k], v[k], valid[k] = fdk, fsk, pl, bs.pdf, vk, ok
    return SampleSet(fd.reshape(n, N, 3), fs.reshape(n, N, 3), p_l.reshape(n, N), p_b.reshape(n, N),
                     v.reshape(n, N), valid.reshape(n, N)), rays


def _any_positive(fd: np.ndarray, fs: np.ndarray) -> np.ndarray:
    """(m,) whether some channel of fd or fs (m, 3) is > 0, column by column: numpy's axis=1
    reductions over (m, 3) cost several times more, and this runs once per light sample."""
    return ((fd[:, 0] > 0.0) | (fd[:, 1] > 0.0) | (fd[:, 2] > 0.0)
            | (fs[:, 0] > 0.0) | (fs[:, 1] > 0.0) | (fs[:, 2] > 0.0))


def tint_shadows(tint: np.ndarray, light: np.ndarray, idx: np.ndarray, v: np.ndarray, fd: np.ndarray,
                 fs: np.ndarray) -> None:
    """UsdLux ShadowAPI ``shadow:color``: fold a light's shadow colour c into the integrand.

    The shadowed fraction 1 - v of a sample shows c, so channel k sees v + (1 - v) c_k. For
    the traced samples idx (m,) of lights light (m,) with a non-black tint (count, 3), fd and
    fs (rows, 3) are scaled by that per-channel visibility and v (rows,) set to 1, in place.
    MIS, light and BSDF sampling only use the product f v, so they stay exact; the control
    variate cannot (its alpha is one scalar), and those lights report no exact F
    (LightSet.inexact), so it falls back to MIS for them.
    """
    c = tint[light]
    has = np.any(c != 0.0, axis=1)
    if not np.any(has):
        return
    k = np.ascontiguousarray(idx[has], dtype=np.int64)
    tint_rows_kernel(k, v, np.ascontiguousarray(c[has], dtype=np.float64), fd, fs)


def split_integrand(bsdf, wo_l, wi_l, weight, lights, light, control, with_pdf=True):
    """Control lobe g and residual f − g of the integrand, each times ``weight`` (m, 3)
    (= |cos| · L · geometric masks), with UsdLux's per-light diffuse/specular multipliers.

    control: (m, 3) c(wo) of each row (the BSDF's wi-constant diffuse part).
    Returns (g (m, 3), residual (m, 3), BSDF pdf of wi (m,) or None).
    """
    # One fused evaluation gives the whole BSDF, its diffuse lobe and the pdf.
    f_all, f_d, pdf = bsdf.f_parts(wo_l, wi_l)
    if not with_pdf:
        pdf = None
    # f = g + (f_d − g) + f_s, g = c(wo) where both directions are above the surface; the
    # diffuse multiplier scales both diffuse parts (one compiled pass: kernels/direct.py).
    m = f_all.shape[0]
    g, residual = np.empty((m, 3)), np.empty((m, 3))
    c = np.ascontiguousarray
    split_kernel(c(f_all, dtype=np.float64), c(f_d, dtype=np.float64), c(control, dtype=np.float64),
                 c(wo_l[:, 2], dtype=np.float64), c(wi_l[:, 2], dtype=np.float64),
                 lights.diffuse_scale[light].astype(np.float64), lights.specular_scale[light].astype(np.float64),
                 c(weight, dtype=np.float64), g, residual)
    return g, residual, pdf


def light_along(lights, light: np.ndarray, o: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m,) and radiance (m, 3) of light ``light`` seen from o along wi.

    Finite lights: exact intersection (inf and L = 0 on a miss). Infinite lights: t = inf and
    the escaped radiance (0 outside a distant light's cone).
    """
    m = light.shape[0]
    t = np.full(m, np.inf)
    Le = np.zeros((m, 3))
    inf = lights.is_infinite[light]
    fi = np.nonzero(~inf)[0]
    if fi.size:
        tf = lights.intersect(light[fi], o[fi], wi[fi])
        h = np.isfinite(tf)
        if np.any(h):
            hi = fi[h]
            t[hi] = tf[h]
            Le[hi] = lights.le(light[hi], o[hi] + wi[hi] * tf[h][:, None], wi[hi])
    ii = np.nonzero(inf)[0]
    if ii.size:
        Le[ii] = lights.le_escaped(light[ii], wi[ii])
    return t, Le


def mis_weights(heuristic: str, p_this: np.ndarray, p_other: np.ndarray) -> np.ndarray:
    """Equal sample counts on both techniques cancel in the heuristics."""
    h = power_heuristic if heuristic == "power" else balance_heuristic
    return h(1, p_this, 1, p_other)


def mean_over_samples(x: np.ndarray) -> np.ndarray:
    """(n, N, 3) -> (n, 3) mean over samples."""
    return x.mean(axis=1)


def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den per sample, 0 where den is 0 or non-finite (a pdf of 0 marks a failed sample)."""
    shape = num.shape
    if num.ndim == 3:
        out = safe_div(num.reshape(-1, 3), den.reshape(-1))
    else:
        out = safe_div(num.reshape(-1), den.reshape(-1))
    return out.reshape(shape)
