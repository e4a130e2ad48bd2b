"""Exact zeros, symmetries, closed-form special cases, cross-checks between the light kinds,
vectorisation and invariance of renderer.lights.analytic."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.lights import analytic as an
from renderer.lights.analytic import (
    projected_solid_angle_disk,
    projected_solid_angle_dome_constant,
    projected_solid_angle_ellipse,
    projected_solid_angle_polygon,
    projected_solid_angle_rect,
    projected_solid_angle_sphere,
)

from .configs import N_MODES, N_PERMS, N_UNIFORMS, P_MODES, planar_config
from .reference import disk_reference, polygon_reference

Z = np.array([0.0, 0.0, 1.0])


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def test_dome_constant():
    assert projected_solid_angle_dome_constant() == np.pi


# --- exact zeros -----------------------------------------------------------------------------
def test_planar_lights_zero_behind_in_plane_and_below_horizon():
    c, ex, ey = np.zeros(3), np.array([2.0, 0, 0]), np.array([0, 1.0, 0])
    p = np.array([[0.1, 0.2, -1.0],      # behind the emitting side
                  [0.3, 0.1, 0.0],       # in the plane, inside the footprint
                  [5.0, 0.0, 0.0],       # in the plane, outside
                  [0.0, 0.0, 1.0],       # in front, but the normal faces away from the light
                  [0.0, 0.0, 1.0]])      # zero normal
    nrm = np.array([Z, Z, Z, Z, np.zeros(3)])
    nrm[0] = _unit([0.3, -0.2, 1.0])               # behind, facing the light's back
    nrm[1:3] = _unit([0.3, -0.2, -1.0])
    assert np.all(projected_solid_angle_rect(p, nrm, c, ex, ey, Z) == 0.0)
    assert np.all(projected_solid_angle_disk(p, nrm, c, Z, 1.5) == 0.0)
    # the generic polygon is two-sided: only the in-plane, away-facing and zero-normal rows vanish
    V = np.array([c - ex / 2 - ey / 2, c + ex / 2 - ey / 2, c + ex / 2 + ey / 2, c - ex / 2 + ey / 2])
    g = projected_solid_angle_polygon(p, nrm, V)
    assert g[0] > 0 and np.all(g[1:] == 0.0)
    assert np.all(projected_solid_angle_polygon(p, nrm, V, e_n=Z)[:3] == 0.0)


def test_sphere_zero_inside_on_surface_and_below_horizon():
    c = np.array([0.0, 0.0, 0.0])
    p = np.array([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 0.0, 3.0]])
    nrm = np.array([Z, Z, Z, Z, np.zeros(3)])       # row 3: centre 3 below, radius 1: below horizon
    assert np.all(projected_solid_angle_sphere(p, nrm, c, 1.0) == 0.0)


def test_degenerate_shapes_give_zero():
    p = np.array([[0.3, 0.2, 1.0]])
    line = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    point = np.zeros((4, 3))
    assert projected_solid_angle_polygon(p, -Z[None], line)[0] == 0.0
    assert projected_solid_angle_polygon(p, -Z[None], point)[0] == 0.0
    assert projected_solid_angle_rect(p, -Z[None], np.zeros(3), np.zeros(3), np.array([0, 1.0, 0]), Z)[0] == 0.0
    assert projected_solid_angle_disk(p, -Z[None], np.zeros(3), Z, 0.0)[0] == 0.0
    assert projected_solid_angle_sphere(p, -Z[None], np.zeros(3), 0.0)[0] == 0.0


# --- closed forms -----------------------------------------------------------------------------
@pytest.mark.parametrize("R,h,tilt", [(1.0, 1.0, 0.0), (1e-6, 3e-7, 0.3), (5e5, 2.0, 0.7), (2.0, 1e6, 1.2),
                                      (1.0, 1e-9, 0.0)])
def test_disk_on_axis(R, h, tilt):
    """On the axis the vector irradiance is π R²/(R²+h²) along the axis: G = that · cos(tilt)
    whenever the horizon does not cut the disk."""
    p = np.array([[0.0, 0.0, h]])
    nrm = np.array([[np.sin(tilt), 0.0, -np.cos(tilt)]])
    g = projected_solid_angle_disk(p, nrm, np.zeros(3), Z, R)[0]
    expect = np.pi * R * R / (R * R + h * h) * np.cos(tilt)
    if np.tan(tilt) < h / R:                      # not clipped
        assert g == pytest.approx(expect, rel=1e-13)


@pytest.mark.parametrize("a,b,h", [(1.0, 1.0, 1.0), (3.0, 0.2, 0.5), (1e-5, 2e-5, 3e-6), (1e4, 1.0, 1e-3),
                                   (1.0, 1.0, 1e5)])
def test_rect_corner_on_normal_classical_form_factor(a, b, h):
    """Differential area facing a parallel a×b rectangle, on the normal through a corner:
    F = (1/2π)[X/√(1+X²)·atan(Y/√(1+X²)) + Y/√(1+Y²)·atan(X/√(1+Y²))], X = a/h, Y = b/h; G = πF."""
    X, Y = a / h, b / h
    F = (X / np.sqrt(1 + X * X) * np.arctan(Y / np.sqrt(1 + X * X))
         + Y / np.sqrt(1 + Y * Y) * np.arctan(X / np.sqrt(1 + Y * Y))) / (2 * np.pi)
    p = np.array([[0.0, 0.0, h]])
    g = projected_solid_angle_rect(p, -Z[None], np.array([a / 2, b / 2, 0.0]), np.array([a, 0, 0]),
                                   np.array([0, b, 0]), Z)[0]
    assert g == pytest.approx(np.pi * F, rel=1e-12)


def _snyder(sin2s, cos_t):
    """Frostbite's illuminanceSphereOrDisk partial-visibility branch (without its clamp)."""
    sin_t = np.sqrt(1.0 - cos_t * cos_t)
    x = np.sqrt(1.0 / sin2s - 1.0)
    y = -x * cos_t / sin_t
    s = sin_t * np.sqrt(1.0 - y * y)
    return (cos_t * np.arccos(y) - x * s) * sin2s + np.arctan(s / x)


def test_sphere_fully_above_and_snyder_is_exact():
    rng = np.random.default_rng(3)
    d = 1.0 + rng.uniform(0.05, 20.0, 400)
    r = np.ones(400)
    sin_s = r / d
    # fully above: π sin²σ cos θ
    cos_t = rng.uniform(sin_s, 1.0)
    c = np.stack([d * np.sqrt(1 - cos_t ** 2), np.zeros(400), d * cos_t], axis=1)
    g = projected_solid_angle_sphere(np.zeros((400, 3)), np.tile(Z, (400, 1)), c, r)
    np.testing.assert_allclose(g, np.pi * sin_s ** 2 * cos_t, rtol=1e-13)
    # straddling: the implementation equals Snyder's formula (which is exact, see the docstring)
    cos_t = sin_s * rng.uniform(-0.95, 0.95, 400)
    c = np.stack([d * np.sqrt(1 - cos_t ** 2), np.zeros(400), d * cos_t], axis=1)
    g = projected_solid_angle_sphere(np.zeros((400, 3)), np.tile(Z, (400, 1)), c, r)
    np.testing.assert_allclose(g, _snyder(sin_s ** 2, cos_t), rtol=1e-9)
    # centre on the horizon: σ − sin σ cos σ
    c = np.stack([d, np.zeros(400), np.zeros(400)], axis=1)
    g = projected_solid_angle_sphere(np.zeros((400, 3)), np.tile(Z, (400, 1)), c, r)
    sig = np.arcsin(sin_s)
    np.testing.assert_allclose(g, sig - np.sin(sig) * np.cos(sig), rtol=1e-12)


def test_sphere_tiny_angle_no_cancellation():
    """σ down to 1e-12 with the horizon through the sphere: G ~ σ³ keeps full precision."""
    for sig in (1e-3, 1e-6, 1e-9, 1e-12):
        d = 1.0
        r = sig
        g = projected_solid_angle_sphere(np.zeros((1, 3)), Z[None], np.array([d, 0.0, 0.0]), r)[0]
        s = np.arcsin(r / d)
        # σ − sin σ cos σ = (2/3)σ³ − (2/15)σ⁵ + ...
        expect = (2.0 / 3.0) * s ** 3 - (2.0 / 15.0) * s ** 5 + (4.0 / 315.0) * s ** 7
        assert g == pytest.approx(expect, rel=1e-12)


# --- cross-checks between kinds -----------------------------------------------------------------
def test_sphere_equals_disk_spanning_the_same_cone():
    """A sphere and the disk perpendicular to the view axis spanning the same cone of directions
    have the same projected solid angle (two unrelated formulas: Snyder vs Green on the arc)."""
    rng = np.random.default_rng(7)
    n = 3000
    a = _unit(rng.normal(size=(n, 3)))
    d = 10.0 ** rng.uniform(-3, 3, n)
    sin_s = 10.0 ** rng.uniform(-6, np.log10(0.999), n)
    r = d * sin_s
    nrm = _unit(rng.normal(size=(n, 3)))
    # bias half of the normals to straddle: nrm nearly ⟂ a
    half = n // 2
    perp = _unit(np.cross(a[:half], rng.normal(size=(half, 3))))
    nrm[:half] = _unit(perp + a[:half] * sin_s[:half, None] * rng.uniform(-1.2, 1.2, (half, 1)))
    p = rng.normal(size=(n, 3))
    gs = projected_solid_angle_sphere(p, nrm, p + d[:, None] * a, r)
    t = d                                              # disk at distance t along a
    rad = t * sin_s / np.sqrt((1 - sin_s) * (1 + sin_s))   # t tan σ
    gd = projected_solid_angle_disk(p, nrm, p + t[:, None] * a, -a, rad)
    omega = 2 * np.pi * sin_s ** 2 / (1 + np.sqrt((1 - sin_s) * (1 + sin_s)))
    np.testing.assert_array_less(np.abs(gs - gd), 1e-9 * gs + 1e-11 * omega)


def test_rect_equals_polygon_and_sum_of_triangles():
    rng = np.random.default_rng(11)
    n = 2000
    c = rng.normal(size=(n, 3))
    en = _unit(rng.normal(size=(n, 3)))
    ex = np.cross(en, rng.normal(size=(n, 3))) * 2.0
    ey = np.cross(en, ex) * rng.uniform(0.1, 1.0, (n, 1)) + 0.3 * ex * rng.uniform(-1, 1, (n, 1))
    p = c + rng.normal(size=(n, 3)) * 1.5
    nrm = _unit(rng.normal(size=(n, 3)))
    g = projected_solid_angle_rect(p, nrm, c, ex, ey, en)
    V = np.stack([c - ex / 2 - ey / 2, c + ex / 2 - ey / 2, c + ex / 2 + ey / 2, c - ex / 2 + ey / 2], axis=1)
    front = np.einsum("ij,ij->i", p - c, en) > 0
    gp = projected_solid_angle_polygon(p, nrm, V, e_n=en)
    # The rect uses its exact centre, offsets and ex × ey normal; the polygon rebuilds them from
    # the corners (centroid, Newell normal), so they agree to rounding, relative to the solid
    # angle scale (|G| <= pi) where G itself is tiny.
    np.testing.assert_allclose(gp, g, rtol=1e-12, atol=1e-15)
    gt = (projected_solid_angle_polygon(p, nrm, V[:, [0, 1, 2]]) + projected_solid_angle_polygon(p, nrm, V[:, [0, 2, 3]]))
    gt = np.where(front, gt, 0.0)
    assert np.all(np.abs(gt - g) <= 1e-10 * g + 1e-13)


def test_polygon_winding_and_two_sidedness():
    rng = np.random.default_rng(5)
    n = 1000
    k = 6
    ang = np.sort(rng.uniform(0, 2 * np.pi, (n, k)), axis=1)
    V = np.stack([np.cos(ang), 0.5 * np.sin(ang), np.zeros((n, k))], axis=-1)
    p = rng.normal(size=(n, 3))
    nrm = _unit(rng.normal(size=(n, 3)))
    g = projected_solid_angle_polygon(p, nrm, V)
    # (atol: horizon slivers, G ≪ Ω ≤ 2π, carry ~1e-16·Ω of rounding)
    np.testing.assert_allclose(projected_solid_angle_polygon(p, nrm, V[:, ::-1]), g, rtol=1e-12, atol=1e-15)
    mirror = np.array([1.0, 1.0, -1.0])
    np.testing.assert_allclose(projected_solid_angle_polygon(p * mirror, nrm * mirror, V), g, rtol=1e-12,
                               atol=1e-15)


# --- implementation paths agree -------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["rect", "disk"])
def test_closed_form_and_quadrature_agree(kind, monkeypatch):
    """Where both are usable (light radius / distance 0.002..0.25) the boundary closed form and
    the area quadrature agree (1e-9: the closed form alone loses up to ~ε·(d/size)²/(G/Ω) to
    cancellation at the small-ratio end, which is why production switches to quadrature there)."""
    rng = np.random.default_rng(19)
    n = 3000
    R = 1.0
    ratio = 10.0 ** rng.uniform(np.log10(0.002), np.log10(0.25), n)
    dirn = _unit(rng.normal(size=(n, 3)))
    dirn[:, 2] = np.abs(dirn[:, 2]) + 0.05
    p = _unit(dirn) * (R / ratio)[:, None]
    nrm = _unit(rng.normal(size=(n, 3)))
    if kind == "rect":
        def f():
            return projected_solid_angle_rect(p, nrm, np.zeros(3), np.array([2 * R, 0, 0]),
                                              np.array([0, 1.2 * R, 0]), Z)
    else:
        def f():
            return projected_solid_angle_disk(p, nrm, np.zeros(3), Z, R)
    monkeypatch.setattr(an, "FAR_RATIO", 0.0)
    monkeypatch.setattr(an, "KAPPA_MAX", 1e300)
    g_closed = f()
    monkeypatch.setattr(an, "FAR_RATIO", 10.0)
    g_quad = f()
    scale = np.pi * (R * ratio) ** 2 / R ** 2           # ~ solid angle
    assert np.all(np.abs(g_closed - g_quad) <= 1e-9 * g_quad + 1e-13 * scale)


# --- vectorisation, broadcasting, invariance ----------------------------------------------------
def test_batch_equals_rowwise_and_broadcasting():
    rng = np.random.default_rng(23)
    cfgs = [planar_config(kind, int(rng.integers(len(P_MODES))), int(rng.integers(len(N_MODES))),
                          int(rng.integers(N_PERMS)), rng.random(N_UNIFORMS)) for kind in ("rect", "disk")
            for _ in range(150)]
    rect = [c for c in cfgs if c.kind == "rect"]
    disk = [c for c in cfgs if c.kind == "disk"]
    for group, fn in ((rect, lambda P, N, c: projected_solid_angle_rect(P, N, *c.rect_world(), c.world()[2])),
                      (disk, lambda P, N, c: projected_solid_angle_disk(P, N, np.zeros(3), c.world()[2], c.radius))):
        rows = np.array([fn(c.world()[0][None], c.world()[1][None], c)[0] for c in group])
        P = np.array([c.world()[0] for c in group])
        Nn = np.array([c.world()[1] for c in group])
        if group is rect:
            batch = projected_solid_angle_rect(P, Nn, np.zeros((len(group), 3)),
                                               np.array([c.rect_world()[1] for c in group]),
                                               np.array([c.rect_world()[2] for c in group]),
                                               np.array([c.world()[2] for c in group]))
        else:
            batch = projected_solid_angle_disk(P, Nn, np.zeros((len(group), 3)),
                                               np.array([c.world()[2] for c in group]),
                                               np.array([c.radius for c in group]))
        np.testing.assert_allclose(batch, rows, rtol=1e-14, atol=0)
    # scalar / (3,) parameters broadcast against p
    p = rng.normal(size=(50, 3)) + np.array([0, 0, 3.0])
    nrm = _unit(rng.normal(size=(50, 3)))
    g1 = projected_solid_angle_sphere(p, nrm, np.zeros(3), 1.0)
    g2 = projected_solid_angle_sphere(p, nrm, np.zeros((50, 3)), np.ones(50))
    np.testing.assert_array_equal(g1, g2)


@pytest.mark.parametrize("kind", ["rect", "disk", "sphere"])
def test_rigid_motion_invariance(kind):
    """A random rotation + translation of the whole scene changes G only by rounding: compare
    against the light-local evaluation with the conditioning-aware tolerance."""
    rng = np.random.default_rng({"rect": 1, "disk": 2, "sphere": 3}[kind])
    for _ in range(120):
        Q = _random_rotation(rng)
        T = rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3)
        if kind == "sphere":
            r = 10.0 ** rng.uniform(-3, 3)
            c = _unit(rng.normal(size=3)) * r * (1 + 10.0 ** rng.uniform(-3, 3))
            nrm = _unit(rng.normal(size=3))
            g0 = projected_solid_angle_sphere(np.zeros((1, 3)), nrm[None], c, r)[0]
            g1 = projected_solid_angle_sphere(T[None], (Q @ nrm)[None], Q @ c + T, r)[0]
            d = np.linalg.norm(c)
            omega = 2 * np.pi * (1 - np.sqrt(max(0.0, 1 - (r / d) ** 2)))
            tol = 1e-9 * g0 + 1e-12 * omega
        else:
            cfg = planar_config(kind, int(rng.integers(0, 2)), int(rng.integers(0, 4)), 0, rng.random(N_UNIFORMS))
            if kind == "rect":
                g0 = projected_solid_angle_rect(cfg.p[None], cfg.nrm[None], np.zeros(3), cfg.ex, cfg.ey, Z)[0]
                g1 = projected_solid_angle_rect((Q @ cfg.p + T)[None], (Q @ cfg.nrm)[None], T, Q @ cfg.ex,
                                                Q @ cfg.ey, Q @ Z)[0]
                omega = polygon_reference(cfg.verts2d, cfg.p, cfg.nrm, "omega")
            else:
                g0 = projected_solid_angle_disk(cfg.p[None], cfg.nrm[None], np.zeros(3), Z, cfg.radius)[0]
                g1 = projected_solid_angle_disk((Q @ cfg.p + T)[None], (Q @ cfg.nrm)[None], T, Q @ Z, cfg.radius)[0]
                omega = disk_reference(cfg.radius, cfg.p, cfg.nrm, "omega")
            # the motion rounds the coordinates by a few ε·X (X = |p| + |T| + size), which moves
            # p relative to the light by that much: G changes by up to ~(ε·X/h)·Ω (G ∝ h when
            # grazing, h the height of p above the light's plane)
            X = np.linalg.norm(cfg.p) + np.linalg.norm(T) + cfg.scale
            tol = 1e-9 * g0 + 1e-12 * omega + 256 * np.finfo(float).eps * (X / abs(cfg.p[2])) * omega
        assert abs(g1 - g0) <= tol, (kind, g0, g1)


# --- ellipse --------------------------------------------------------------------------------------
def test_ellipse_circle_equals_disk_and_parametrisation_invariance():
    """A circle given as an ellipse (rotated conjugate semi-diameters) equals the disk, for
    points anywhere including within 1e-10 of the rim; and an ellipse is independent of which
    pair of conjugate semi-diameters describes it."""
    rng = np.random.default_rng(29)
    n = 4000
    en = _unit(rng.normal(size=(n, 3)))
    a = _unit(np.cross(en, rng.normal(size=(n, 3))))
    b = np.cross(en, a)
    R = 10.0 ** rng.uniform(-3, 3, n)
    c = rng.normal(size=(n, 3))
    # points: generic, and near the rim (in-plane offset 1e-10..1e-2 of R, low heights)
    ang = rng.uniform(0, 2 * np.pi, n)
    rim = (1 + rng.choice([-1, 1], n) * 10.0 ** rng.uniform(-10, -2, n)) * R
    near = c + (np.cos(ang) * rim)[:, None] * a + (np.sin(ang) * rim)[:, None] * b + \
        (R * 10.0 ** rng.uniform(-10, 0, n))[:, None] * en
    far = c + _unit(rng.normal(size=(n, 3))) * (R * 10.0 ** rng.uniform(-2, 3, n))[:, None]
    p = np.where((rng.random(n) < 0.5)[:, None], near, far)
    nrm = _unit(rng.normal(size=(n, 3)))
    gd = projected_solid_angle_disk(p, nrm, c, en, R)
    th = rng.uniform(0, 2 * np.pi, n)[:, None]
    e1 = R[:, None] * (np.cos(th) * a + np.sin(th) * b)
    e2 = R[:, None] * (-np.sin(th) * a + np.cos(th) * b)
    ge = projected_solid_angle_ellipse(p, nrm, c, e1, e2, en)
    d = np.linalg.norm(p - c, axis=1)
    omega = np.pi * R ** 2 / np.maximum(d * d, R * R)
    h = np.abs(np.einsum("ij,ij->i", p - c, en))
    # position rounding near the rim: ε·(|p−c| + R)/(distance to the rim) relative
    inplane = np.sqrt(np.maximum(d * d - h * h, 0.0))
    r_rim = np.hypot(inplane - R, h)
    cond = 64 * np.finfo(float).eps * (d + R) / r_rim
    assert np.all(np.abs(ge - gd) <= 1e-9 * gd + 1e-12 * omega + cond * np.maximum(gd, omega))
    # an elongated ellipse from two different conjugate pairs
    s_ = 10.0 ** rng.uniform(-2, 0, n)[:, None]
    f1, f2 = R[:, None] * a, s_ * R[:, None] * b
    g1 = projected_solid_angle_ellipse(p, nrm, c, f1, f2, en)
    k1, k2 = np.cos(th) * f1 + np.sin(th) * f2, -np.sin(th) * f1 + np.cos(th) * f2
    g2 = projected_solid_angle_ellipse(p, nrm, c, k1, k2, en)
    assert np.all(np.abs(g1 - g2) <= 1e-9 * g1 + 1e-12 * omega + cond * np.maximum(g1, omega))


def test_ellipse_zeros():
    p = np.array([[0.1, 0.2, -1.0], [0.3, 0.1, 0.0], [0.0, 0.0, 1.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    g = projected_solid_angle_ellipse(p, nrm, np.zeros(3), np.array([2.0, 0, 0]), np.array([0, 0.5, 0]), Z)
    assert np.all(g == 0.0)
    assert projected_solid_angle_ellipse(p[:1] * -1, -Z[None], np.zeros(3), np.array([2.0, 0, 0]),
                                         np.array([4.0, 0, 0]), Z)[0] == 0.0          # degenerate
