"""Shared helpers for the light tests: transforms, contexts, samplers wrapped for tests.stats."""

from __future__ import annotations

import math

import numpy as np

from renderer.lights.base import ShadingContext


def translate(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def scale(x: float, y: float, z: float) -> np.ndarray:
    return np.diag([x, y, z, 1.0])


def rotate(axis, deg: float) -> np.ndarray:
    """Right-handed rotation by deg degrees about axis (4x4)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    r = np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)
    m = np.eye(4)
    m[:3, :3] = r
    return m


def look_down(target_dir) -> np.ndarray:
    """Rotation (4x4) taking local -Z to the unit vector target_dir."""
    d = np.asarray(target_dir, dtype=np.float64)
    d = d / np.linalg.norm(d)
    z = -d
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m


def ctx(p, n=(0.0, 0.0, 0.0), count: int = 1) -> ShadingContext:
    p = np.tile(np.asarray(p, dtype=np.float64), (count, 1))
    n = np.tile(np.asarray(n, dtype=np.float64), (count, 1))
    return ShadingContext(p, n, n.copy())


def sampler_for(kind, light: int, p):
    """(sample, pdf) callables for tests.stats.chi2_directions from a point p."""

    def sample(u):
        n = u.shape[0]
        s = kind.sample_li(np.full(n, light, dtype=np.int64), ctx(p, count=n), u)
        return s.wi, s.pdf > 0.0

    def pdf(wi):
        n = wi.shape[0]
        return kind.pdf_li(np.full(n, light, dtype=np.int64), ctx(p, count=n), wi)

    return sample, pdf


def irradiance_samples(kind, light: int, p, n_normal, n: int = 200_000, seed: int = 7, channel: int = 0):
    """Per-sample estimates L cos+ / pdf (one channel) of the unshadowed irradiance at p."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    c = ctx(p, n_normal, count=n)
    s = kind.sample_li(np.full(n, light, dtype=np.int64), c, u)
    cos = np.maximum(0.0, s.wi @ np.asarray(n_normal, dtype=np.float64))
    ok = s.pdf > 0.0
    return np.where(ok, s.L[:, channel] * cos / np.where(ok, s.pdf, 1.0), 0.0)


def cone_quadrature_irradiance(axis, cos_max: float, n_normal, L: float, res: int = 800) -> float:
    """E = integral over the cone {w: w.axis >= cos_max} of L max(0, n.w) dw (midpoint rule)."""
    axis = np.asarray(axis, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, axis)
    s /= np.linalg.norm(s)
    t = np.cross(axis, s)
    # Integrate in x = 1 - cos theta (accurate for narrow cones).
    omc = 1.0 - cos_max
    x = (np.arange(res) + 0.5) / res * omc
    phi = (np.arange(2 * res) + 0.5) / (2 * res) * 2 * np.pi
    X, P = np.meshgrid(x, phi, indexing="ij")
    cos_t = 1.0 - X
    sin_t = np.sqrt(np.maximum(0.0, X * (2.0 - X)))
    nloc = np.array([np.dot(n_normal, s), np.dot(n_normal, t), np.dot(n_normal, axis)])
    cosn = sin_t * np.cos(P) * nloc[0] + sin_t * np.sin(P) * nloc[1] + cos_t * nloc[2]
    return float(L * np.maximum(cosn, 0.0).sum() * (omc / res) * (2 * np.pi / (2 * res)))


def area_quadrature_irradiance(points, normals_l, dA, p, n_normal, L: float) -> float:
    """E = sum L max(0, n.w) max(0, -n_l.w) dA / d^2 over quadrature points on a light."""
    v = points - np.asarray(p, dtype=np.float64)
    d2 = np.einsum("ij,ij->i", v, v)
    d = np.sqrt(d2)
    w = v / d[:, None]
    cos_p = np.maximum(0.0, w @ np.asarray(n_normal, dtype=np.float64))
    cos_l = np.maximum(0.0, -np.einsum("ij,ij->i", w, normals_l))
    return float(L * (cos_p * cos_l / d2 * dA).sum())


def ray_triangle(o, d, tris):
    """Moller-Trumbore: t (n, T) of rays (n, 3) against triangles (T, 3, 3), inf where missed."""
    v0, v1, v2 = tris[:, 0], tris[:, 1], tris[:, 2]
    e1 = v1 - v0
    e2 = v2 - v0
    pvec = np.cross(d[:, None, :], e2[None])
    det = np.einsum("ntk,tk->nt", pvec, e1)
    ok = np.abs(det) > 1e-300
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
    tvec = o[:, None, :] - v0[None]
    uu = np.einsum("ntk,ntk->nt", tvec, pvec) * inv
    qvec = np.cross(tvec, e1[None])
    vv = np.einsum("ntk,nk->nt", qvec, d) * inv
    t = np.einsum("ntk,tk->nt", qvec, e2) * inv
    hit = ok & (uu >= 0) & (vv >= 0) & (uu + vv <= 1) & (t > 0)
    return np.where(hit, t, np.inf)


def offset_axis_setup(p, boundary_points, center=None):
    """(axis, cos_range) for chi2_directions that keep a light's region *off* the bin pole.

    Binning about the direction to the light puts its centre on the pole, where uniform-cos bins
    resolve thin shapes (lights seen edge-on) badly. Instead tilt the axis by twice the light's
    angular radius alpha, so the light covers theta in [alpha, 3 alpha] and a fair share of
    the phi bins. Falls back to the direction toward the light with the full range when the
    light is too wide for that (3 alpha > 150 degrees).
    boundary_points: (m, 3) dense points on the light's outline (its extreme directions).
    """
    p = np.asarray(p, dtype=np.float64)
    pts = np.asarray(boundary_points, dtype=np.float64)
    c = pts.mean(axis=0) if center is None else np.asarray(center, dtype=np.float64)
    w_c = (c - p) / np.linalg.norm(c - p)
    v = pts - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    alpha = float(np.arccos(np.clip((v @ w_c).min(), -1.0, 1.0)))
    if 3.0 * alpha > math.radians(150.0):
        return w_c, (-1.0, 1.0)
    helper = np.array([1.0, 0.0, 0.0]) if abs(w_c[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    side1 = np.cross(w_c, helper)
    side1 /= np.linalg.norm(side1)
    side2 = np.cross(w_c, side1)
    # A generic tilt direction, so that no straight edge of the light lies along a bin meridian.
    side = math.cos(0.61) * side1 + math.sin(0.61) * side2
    beta = 2.0 * alpha
    axis = math.cos(beta) * w_c + math.sin(beta) * side
    cos = v @ axis
    lo = max(-1.0, math.cos(min(math.pi, 3.2 * alpha)))
    hi = min(1.0, math.cos(0.8 * alpha))
    lo = min(lo, float(cos.min()) - 1e-6)
    hi = max(hi, float(min(1.0, cos.max() + 1e-6)))
    return axis, (lo, hi)


def polygon_outline(corners, per_edge: int = 200) -> np.ndarray:
    """Dense points (m, 3) along a closed polygon's edges."""
    corners = np.asarray(corners, dtype=np.float64)
    t = (np.arange(per_edge) / per_edge)[:, None]
    return np.concatenate([corners[i] + t * (corners[(i + 1) % len(corners)] - corners[i]) for i in range(len(corners))])


def planar_axis_setup(kind, light: int, p, outline, toward_p_normal):
    """(axis, cos_range) for a planar light: bin about its normal (pointing to p's side).

    cos theta about the normal is the elevation above the light's plane, so even a light seen
    edge-on (a band a fraction of a degree thick) is resolved by the cos bins, and no straight
    edge lies along a bin meridian unless it points at the foot point. The range is that of
    the outline's directions, extended to 1 when the foot point of p lies on the light.
    """
    p = np.asarray(p, dtype=np.float64)
    axis = -np.asarray(toward_p_normal, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    v = np.asarray(outline, dtype=np.float64) - p
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    cos = v @ axis
    foot_on_light = np.isfinite(kind.intersect(np.array([light]), p[None], axis[None]))[0]
    lo, hi = float(cos.min()), (1.0 if foot_on_light else float(cos.max()))
    m = 0.02 * (hi - lo)
    return axis, (max(-1.0, lo - m), min(1.0, hi + m))


def chi2_on_surface(points_to_param, density, sample_points, n: int, res: int = 16, k: int = 16):
    """Chi-square test of sampled points in a light's own 2-D parameterisation [-1/2, 1/2]^2.

    Complements tests.stats.chi2_directions for shapes seen almost edge-on, whose direction
    bins cannot be integrated accurately (a band a fraction of a degree thick): in the light's
    parameter space the same distribution is smooth and easy to integrate.
    points_to_param(x (m, 3)) -> (m, 2); density(ab (m, 2)) -> (m,) pdf w.r.t. d(a) d(b)
    (zero outside the shape); sample_points: (n, 3) sampled points (failed samples removed).
    Returns the p-value (pooling bins with expectation < 5).
    """
    from tests.stats import chi2_sf

    ab = points_to_param(sample_points)
    obs, _, _ = np.histogram2d(ab[:, 0], ab[:, 1], bins=res, range=[[-0.5, 0.5], [-0.5, 0.5]])
    g = (np.arange(res * k) + 0.5) / (res * k) - 0.5
    A, B = np.meshgrid(g, g, indexing="ij")
    dens = density(np.stack([A.ravel(), B.ravel()], axis=1)).reshape(res, k, res, k)
    exp = dens.sum(axis=(1, 3)) / (res * k) ** 2 * n
    obs, exp = obs.ravel(), exp.ravel()
    small = exp < 5.0
    o = np.concatenate([obs[~small], [obs[small].sum()]])
    e = np.concatenate([exp[~small], [exp[small].sum()]])
    keep = e > 0
    if np.any(~keep & (o > 0)):
        return 0.0
    chi2 = float(((o[keep] - e[keep]) ** 2 / e[keep]).sum())
    return chi2_sf(chi2, int(keep.sum()) - 1)
