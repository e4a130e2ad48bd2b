"""Evaluate implementation vs reference for one configuration, and record the errors.

Acceptance, used by every accuracy test:

    |G − G_ref| ≤ REL_TOL · G_ref + FLOOR · Ω + POS · ε · X · B

* Ω is the (unclipped, one-sided) solid angle of the light seen from p.
* FLOOR · Ω is the absolute floor where the true value is ~0: rotating nrm by an angle δ
  changes G by up to δ·|∫ ω dω| ≤ δ·Ω, so when the horizon slices the light (G ≪ Ω) a float64
  nrm does not determine G to better than ~1e-16·Ω; FLOOR = 1e-12 leaves a factor 1e4 for
  rounding in the geometry.
* The last term is the conditioning with respect to the input *positions*: the coordinates
  (magnitude ≤ X) carry rounding ε·X, and moving the boundary sideways by δx changes G by up
  to δx·∮ h/d³ dl (= δx·B). It only matters for points within ~1e-8 of the size from an edge
  or the rim (POS = 8).
Expected zeros (back side, in the plane, inside the sphere) must be exactly 0.

Reported numbers: the max relative error over *well-conditioned* configurations (the two
conditioning terms, with FLOOR replaced by 16ε, below 1e-10·G_ref) and the max of
|err|/tolerance over all configurations (≤ 1 means all pass).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from renderer.lights.analytic import (
    projected_solid_angle_disk,
    projected_solid_angle_ellipse,
    projected_solid_angle_polygon,
    projected_solid_angle_rect,
    projected_solid_angle_sphere,
)

from .configs import PlanarConfig, SphereConfig
from .reference import disk_reference, ellipse_reference, polygon_reference, sphere_reference

REL_TOL = 1e-5
FLOOR = 1e-12
POS = 8.0
EPS = float(np.finfo(np.float64).eps)
WELL_CONDITIONED = 1e-10
# the reference stops refining a panel once its error estimate is below REF_ATOL·Ω
REF_ATOL = 1e-17
# ... and once it is below REF_RTOL relative (the reference's own accuracy target)
REF_RTOL = 1e-13

RECORD: dict[str, dict] = defaultdict(lambda: {"n": 0, "zeros": 0, "n_wc": 0, "max_rel": 0.0,
                                               "max_err_over_tol": 0.0, "worst": None})


def check(kind, g, ref, omega, pos_cond, label=""):
    """Record and return (ok, message). pos_cond: the absolute position-rounding term
    (ε·X·B for planar lights) for this configuration."""
    rec = RECORD[kind]
    rec["n"] += 1
    if not np.isfinite(g) or g < 0:
        return False, f"{kind}: non-finite or negative G={g!r} ({label})"
    err = abs(g - ref)
    tol = REL_TOL * ref + FLOOR * omega + POS * pos_cond
    rec["max_err_over_tol"] = max(rec["max_err_over_tol"], err / tol if tol > 0 else (np.inf if err else 0.0))
    if ref > 0 and 16.0 * EPS * omega + POS * pos_cond <= WELL_CONDITIONED * ref:
        rec["n_wc"] += 1
        rel = err / ref
        if rel > rec["max_rel"]:
            rec["max_rel"] = rel
            rec["worst"] = label
    if err > tol:
        return False, (f"{kind}: G={g!r} ref={ref!r} err={err:.3e} tol={tol:.3e} "
                       f"rel={err / ref if ref else np.inf:.3e} Ω={omega:.3e} ({label})")
    return True, ""


def check_zero(kind, g, label=""):
    RECORD[kind]["zeros"] += 1
    if g != 0.0:
        return False, f"{kind}: expected exactly 0, got {g!r} ({label})"
    return True, ""


def _boundary_sensitivity(V: np.ndarray, p: np.ndarray) -> float:
    """B = ∮ h/d³ dl over the boundary of the polygon V (k, 2) seen from p = (px, py, h):
    moving a piece dl of the boundary sideways by δx changes G by at most δx·h/d³·dl."""
    a = V - p[:2]
    b = np.roll(V, -1, axis=0) - p[:2]
    e = b - a
    L = np.sqrt(np.einsum("ij,ij->i", e, e))
    t = e / np.maximum(L, 1e-300)[:, None]
    sa = np.einsum("ij,ij->i", a, t)
    sb = sa + L
    delta = a[:, 0] * t[:, 1] - a[:, 1] * t[:, 0]
    h = p[2]
    w2 = delta * delta + h * h
    # ∫ h/(s² + w²)^{3/2} ds = (h/w²)·[s/√(s² + w²)]
    val = h / w2 * (sb / np.sqrt(sb * sb + w2) - sa / np.sqrt(sa * sa + w2))
    return float(np.sum(np.where(L > 0, val, 0.0)))


def position_condition(cfg: PlanarConfig, p: np.ndarray) -> float:
    """Absolute change of G allowed for rounding of the input positions: ε·X·B.

    X: magnitude of the coordinates that get rounded when forming p-relative geometry (the
    light's size plus |p| for points near it; far points are handled relative to the light),
    B = ∮ h/d³ dl (see _boundary_sensitivity)."""
    if cfg.kind == "ellipse":
        t = np.linspace(0.0, 2.0 * np.pi, 4097)[:-1]
        a, b = cfg.radius, cfg.radius_b
        V = np.stack([a * np.cos(t), b * np.sin(t)], axis=1)
        S = a
        B = _boundary_sensitivity(V, p)
        # near the rim the polygon misses the closest stretch: locally a straight edge at
        # distance d = |F|/|∇F| (F = x²/a² + y²/b² − 1) contributes 2h/(d² + h²)
        F = (p[0] / a) ** 2 + (p[1] / b) ** 2 - 1.0
        gF = np.hypot(2.0 * p[0] / a ** 2, 2.0 * p[1] / b ** 2)
        if gF > 0:
            d = abs(F) / gF
            B = max(B, 2.0 * p[2] / (d * d + p[2] * p[2]))
    elif cfg.kind == "disk":
        t = np.linspace(0.0, 2.0 * np.pi, 1025)[:-1]
        V = cfg.radius * np.stack([np.cos(t), np.sin(t)], axis=1)
        S = cfg.radius
        B = _boundary_sensitivity(V, p)
        # the 1024-gon misses the rim's nearest stretch when p is within ~1e-5 R of it: add
        # that stretch for the true circle, ∫ h R dt/(w² + P R t²)^{3/2} = 2h√(R/P)/w²
        P = float(np.hypot(p[0], p[1]))
        if P > 0:
            w2 = (P - cfg.radius) ** 2 + p[2] ** 2
            B = max(B, 2.0 * p[2] * np.sqrt(cfg.radius / P) / w2)
    else:
        V = cfg.verts2d
        S = float(np.abs(V).max())
        B = _boundary_sensitivity(V, p)
    X = S + min(float(np.abs(p).max()), 100.0 * S)
    return EPS * X * B


def eval_planar(cfg: PlanarConfig):
    """-> (G_impl, G_ref or None if expected 0, Ω)."""
    p_w, nrm_w, en_w = cfg.world()
    P, Nn = p_w[None], nrm_w[None]
    if cfg.kind == "rect":
        c, ex, ey = cfg.rect_world()
        g = projected_solid_angle_rect(P, Nn, c, ex, ey, en_w)[0]
    elif cfg.kind == "disk":
        g = projected_solid_angle_disk(P, Nn, np.zeros(3), en_w, cfg.radius)[0]
    elif cfg.kind == "ellipse":
        M = cfg.perm
        g = projected_solid_angle_ellipse(P, Nn, np.zeros(3), M @ np.array([cfg.radius, 0.0, 0.0]),
                                          M @ np.array([0.0, cfg.radius_b, 0.0]), en_w)[0]
    else:
        g = projected_solid_angle_polygon(P, Nn, cfg.polygon_world()[None])[0]
    p, nrm = cfg.p.copy(), cfg.nrm.copy()
    if cfg.kind == "polygon" and p[2] < 0:            # two-sided: mirror through the plane
        p[2], nrm[2] = -p[2], -nrm[2]
    if p[2] <= 0:
        return g, None, 0.0, 0.0
    # The reference cannot resolve G better than the inputs determine it: its own rounding of
    # edge positions shows up as noise of size ~pos, so its adaptive refinement stops there
    # (otherwise it would chase that noise).
    pos = position_condition(cfg, p)
    if cfg.kind == "disk":
        om = disk_reference(cfg.radius, p, nrm, "omega", atol=pos)
        ref = disk_reference(cfg.radius, p, nrm, "G", atol=max(REF_ATOL * om, pos))
    elif cfg.kind == "ellipse":
        om = ellipse_reference(cfg.radius, cfg.radius_b, p, nrm, "omega", atol=pos)
        ref = ellipse_reference(cfg.radius, cfg.radius_b, p, nrm, "G", atol=max(REF_ATOL * om, pos))
    else:
        om = polygon_reference(cfg.verts2d, p, nrm, "omega", atol=pos)
        ref = polygon_reference(cfg.verts2d, p, nrm, "G", atol=max(REF_ATOL * om, pos))
    return g, ref, om, pos


def run_planar(cfg: PlanarConfig):
    g, ref, om, pc = eval_planar(cfg)
    label = f"{cfg.kind}/{cfg.p_mode}/{cfg.n_mode} S={cfg.scale:.3g} p={cfg.p.tolist()} nrm={cfg.nrm.tolist()}"
    if ref is None:
        return check_zero(cfg.kind, g, label)
    return check(cfg.kind, g, ref, om, pc, label)


def eval_sphere(cfg: SphereConfig):
    g = projected_solid_angle_sphere(np.zeros((1, 3)), cfg.nrm[None], cfg.center, cfg.r)[0]
    d = float(np.sqrt(np.einsum("i,i->", cfg.center, cfg.center)))
    if d <= cfg.r:
        return g, None, 0.0, 0.0
    ref, om = sphere_reference(cfg.r, d, float(cfg.center[2]))
    # G ~ √(d − r) near the surface: rounding ε·d in d moves it by ~ε·√(d/(d − r))
    return g, ref, om, EPS * np.sqrt(d / (d - cfg.r)) * om


def run_sphere(cfg: SphereConfig):
    g, ref, om, pc = eval_sphere(cfg)
    label = f"sphere/{cfg.mode} r={cfg.r!r} c={cfg.center.tolist()}"
    if ref is None:
        return check_zero("sphere", g, label)
    return check("sphere", g, ref, om, pc, label)


def summary_lines():
    lines = []
    for kind in sorted(RECORD):
        r = RECORD[kind]
        lines.append(f"{kind:8s} configs={r['n'] + r['zeros']:6d} (exact zeros {r['zeros']:5d}, "
                     f"well-conditioned {r['n_wc']:5d})  max rel err (well-cond.) = {r['max_rel']:.2e}  "
                     f"max |err|/tol = {r['max_err_over_tol']:.2e}")
    return lines
