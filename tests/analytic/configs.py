"""Random light/shading-point configurations, built from a vector of uniforms in [0, 1].

Shared by the hypothesis tests (which draw the uniforms and the mode indices) and by
``report_errors.py`` (which draws them from a seeded numpy generator).

Every configuration is built in the light's local frame (light in the plane z = 0, emitting
towards +z) and then mapped to world space by an exact signed axis permutation, so the
implementation under test and the quadrature reference see bit-identical geometry. The
global scale S = 10^U(−6, 6) and distance/size ratios from 1e-12 to 1e12 cover tiny and huge
sizes and distances.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

# p placement modes (planar lights)
P_MODES = ("generic", "close", "grazing", "far", "rim", "plane", "behind")
# normal modes
N_MODES = ("random", "straddle", "facing", "down", "up", "tangent")
N_UNIFORMS = 12

_PERMS = []
for perm in itertools.permutations(range(3)):
    for signs in itertools.product((1.0, -1.0), repeat=3):
        m = np.zeros((3, 3))
        for i, j in enumerate(perm):
            m[i, j] = signs[i]
        _PERMS.append(m)
N_PERMS = len(_PERMS)


def _logu(u, lo, hi):
    return 10.0 ** (lo + (hi - lo) * u)


def _unit(v):
    return v / np.linalg.norm(v)


def _sphere_dir(u1, u2):
    z = 2.0 * u1 - 1.0
    s = np.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u2
    return np.array([s * np.cos(phi), s * np.sin(phi), z])


def _perp_frame(a):
    a = _unit(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(a, helper))
    return e1, np.cross(a, e1)


@dataclass
class PlanarConfig:
    kind: str              # "rect" | "disk" | "polygon" | "ellipse"
    p_mode: str
    n_mode: str
    p: np.ndarray          # local (px, py, h)
    nrm: np.ndarray        # unit, local
    perm: np.ndarray       # (3, 3) exact signed permutation local -> world
    # rect: full edge vectors (local) and centre 0; polygon: vertices (k, 2); disk: radius
    ex: np.ndarray | None = None
    ey: np.ndarray | None = None
    verts2d: np.ndarray | None = None
    radius: float = 0.0
    radius_b: float = 0.0  # ellipse: semi-axis along local y (radius: along local x)
    scale: float = 1.0

    def world(self):
        M = self.perm
        return M @ self.p, M @ self.nrm, M @ np.array([0.0, 0.0, 1.0])

    def rect_world(self):
        M = self.perm
        return np.zeros(3), M @ self.ex, M @ self.ey

    def polygon_world(self):
        V = np.concatenate([self.verts2d, np.zeros((self.verts2d.shape[0], 1))], axis=1)
        return V @ self.perm.T


def _light_points(cfg, u):
    """A point of the light (local, z = 0) from two uniforms."""
    if cfg.kind in ("disk", "ellipse"):
        r = np.sqrt(u[0])
        t = 2.0 * np.pi * u[1]
        rb = cfg.radius_b if cfg.kind == "ellipse" else cfg.radius
        return np.array([cfg.radius * r * np.cos(t), rb * r * np.sin(t), 0.0])
    V = cfg.verts2d
    i = int(u[0] * 0.999999 * V.shape[0])
    a, b = V[0], V[i]
    c = V[(i + 1) % V.shape[0]]
    s, t = u[1], 1.0 - u[1]
    q = a + s * (b - a) * 0.5 + t * (c - a) * 0.5
    return np.array([q[0], q[1], 0.0])


def planar_config(kind: str, p_mode: int, n_mode: int, perm: int, u: np.ndarray, k: int = 4) -> PlanarConfig:
    """Build a configuration; u: (N_UNIFORMS,) in [0, 1]."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    S = _logu(u[0], -6.0, 6.0)
    cfg = PlanarConfig(kind=kind, p_mode=P_MODES[p_mode], n_mode=N_MODES[n_mode],
                       p=np.zeros(3), nrm=np.zeros(3), perm=_PERMS[perm], scale=S)
    if kind == "rect":
        a = S
        b = S * _logu(u[1], -3.0, 0.0)
        shear = (u[2] - 0.5) * 2.0 if u[2] > 0.7 else 0.0       # 30 %: parallelogram
        cfg.ex = np.array([a, 0.0, 0.0])
        cfg.ey = np.array([shear * b, b, 0.0])
        hx, hy = 0.5 * cfg.ex, 0.5 * cfg.ey
        c = np.zeros(3)
        # exactly the implementation's vertex arithmetic
        V = np.stack([c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy])
        cfg.verts2d = V[:, :2]
        ext = max(a, b)
    elif kind == "polygon":
        ang = np.sort(2.0 * np.pi * ((u[1] + np.arange(k) / k + 0.6 / k * np.sin(7.0 * u[2] * np.arange(k)))
                                     % 1.0))
        rx, ry = S, S * _logu(u[2], -2.0, 0.0)
        V = np.stack([rx * np.cos(ang), ry * np.sin(ang)], axis=1)
        if u[1] > 0.5:
            V = V[::-1]                                         # both windings
        cfg.verts2d = V
        ext = S
    elif kind == "ellipse":
        cfg.radius = S                                         # semi-axis along local x
        cfg.radius_b = S * _logu(u[1], -2.0, 0.0)               # along local y
        ext = S
    else:
        cfg.radius = S
        ext = S
    # --- shading point ------------------------------------------------------------------
    mode = cfg.p_mode
    if mode == "generic":
        d = _logu(u[3], -2.0, 3.0) * ext
        dirn = _sphere_dir(0.5 + 0.5 * u[4], u[5])
        p = d * dirn + np.array([(u[6] - 0.5) * ext, (u[7] - 0.5) * ext, 0.0])
        p[2] = abs(p[2]) if p[2] != 0 else ext
    elif mode == "close":
        p = np.array([(u[3] - 0.5) * 3.0 * ext, (u[4] - 0.5) * 3.0 * ext, _logu(u[5], -9.0, 0.0) * ext])
    elif mode == "grazing":
        p = np.array([(u[3] - 0.5) * 10.0 * ext, (u[4] - 0.5) * 10.0 * ext, _logu(u[5], -12.0, -4.0) * ext])
    elif mode == "far":
        d = _logu(u[3], 2.0, 12.0) * ext
        p = d * _sphere_dir(0.5 + 0.5 * u[4], u[5])
        if p[2] <= 0:
            p[2] = d * 1e-9
    elif mode == "rim":
        # close to the boundary (edge or corner), inside or outside, low height
        off = _logu(u[3], -10.0, -1.0) * ext * (1.0 if u[4] > 0.5 else -1.0)
        if kind in ("disk", "ellipse"):
            t = 2.0 * np.pi * u[5]
            rb = cfg.radius_b if kind == "ellipse" else cfg.radius
            p = np.array([(cfg.radius + off) * np.cos(t), (rb + off) * np.sin(t), 0.0])
        else:
            V = cfg.verts2d
            i = int(u[5] * 0.999999 * V.shape[0])
            a_, b_ = V[i], V[(i + 1) % V.shape[0]]
            q = a_ + (b_ - a_) * (u[6] if u[7] > 0.3 else 0.0)  # on an edge or at a corner
            e = _unit(b_ - a_)
            nout = np.array([e[1], -e[0]])
            e01, e12 = V[1] - V[0], V[2] - V[1]
            if e01[0] * e12[1] - e01[1] * e12[0] < 0:
                nout = -nout
            q = q + off * nout
            p = np.array([q[0], q[1], 0.0])
        p[2] = _logu(u[8], -10.0, 0.0) * ext
    elif mode == "plane":
        p = np.array([(u[3] - 0.5) * 4.0 * ext, (u[4] - 0.5) * 4.0 * ext, 0.0])
    else:  # behind
        p = np.array([(u[3] - 0.5) * 4.0 * ext, (u[4] - 0.5) * 4.0 * ext, -_logu(u[5], -6.0, 2.0) * ext])
    cfg.p = p
    # --- normal ---------------------------------------------------------------------------
    nm = cfg.n_mode
    if nm == "random":
        nrm = _sphere_dir(u[9], u[10])
    elif nm in ("straddle", "tangent"):
        x0 = _light_points(cfg, u[9:11])
        v = x0 - p
        if np.linalg.norm(v) == 0.0:
            v = -p if np.linalg.norm(p) > 0 else np.array([0.0, 0.0, -1.0])
        e1, e2 = _perp_frame(v)
        t = 2.0 * np.pi * u[11]
        nrm = np.cos(t) * e1 + np.sin(t) * e2
        if nm == "tangent":                                   # tilt slightly off the point
            tilt = _logu(u[10], -12.0, -2.0) * (1.0 if u[9] > 0.5 else -1.0)
            nrm = nrm + tilt * _unit(v)
    elif nm == "facing":
        c = np.zeros(3)
        v = c - p
        if np.linalg.norm(v) == 0.0:
            v = np.array([0.0, 0.0, -1.0])
        nrm = _unit(v) + 0.3 * (_sphere_dir(u[9], u[10]) * u[11])
    elif nm == "down":
        nrm = np.array([0.0, 0.0, -1.0]) + 0.5 * u[11] * _sphere_dir(u[9], u[10])
    else:  # up: facing away from the light's plane (sees only lights above its horizon)
        nrm = np.array([0.0, 0.0, 1.0]) + 0.999 * u[11] * _sphere_dir(u[9], u[10])
    cfg.nrm = _unit(nrm)
    return cfg


@dataclass
class SphereConfig:
    mode: str
    r: float
    center: np.ndarray     # world, p = 0
    nrm: np.ndarray


S_MODES = ("generic", "straddle", "near_surface", "far", "tiny_far_straddle", "inside", "surface")


def sphere_config(mode: int, u: np.ndarray) -> SphereConfig:
    """p at the origin, nrm = +z (exact), centre c with height z = c_z above the horizon."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    r = _logu(u[0], -6.0, 6.0)
    m = S_MODES[mode]
    if m == "generic":
        d = r * (1.0 + _logu(u[1], -3.0, 3.0))
        z = d * (2.0 * u[2] - 1.0)
    elif m == "straddle":
        d = r * (1.0 + _logu(u[1], -9.0, 6.0))
        z = r * (2.0 * u[2] - 1.0)
    elif m == "near_surface":
        d = r * (1.0 + _logu(u[1], -13.0, -4.0))
        z = d * (2.0 * u[2] - 1.0)
    elif m == "far":
        d = r * _logu(u[1], 3.0, 12.0)
        z = d * (2.0 * u[2] - 1.0)
    elif m == "tiny_far_straddle":
        d = r * _logu(u[1], 3.0, 8.0)
        z = r * (2.0 * u[2] - 1.0) * (1.0 - _logu(u[3], -12.0, 0.0) * 0.999)
    elif m == "inside":
        d = r * u[1] * 0.999999
        z = d * (2.0 * u[2] - 1.0)
    else:  # exactly on the surface
        d = r
        z = 0.0
    # horizontal offset so that |c| = d with c_z = z exactly
    hor = np.sqrt(max(0.0, (d - z) * (d + z)))
    t = 2.0 * np.pi * u[4]
    c = np.array([hor * np.cos(t), hor * np.sin(t), z])
    if m == "surface":
        c = np.array([r, 0.0, 0.0]) if u[4] < 0.5 else np.array([0.0, 0.0, -r])
    return SphereConfig(mode=m, r=r, center=c, nrm=np.array([0.0, 0.0, 1.0]))
