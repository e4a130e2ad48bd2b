"""Random extreme light configurations and the checks run on them.

A ``LightCase`` is one light (rect, disk or sphere) of size 1e-6..1e6 under a random rotation
and translation, one shading point placed relative to it (free, close above it, grazing its
plane, on it, inside or behind it, or with the light straddling its horizon) and a shading
normal. The hypothesis strategies in ``strategies.py`` and the standalone ``report.py`` both
build LightCases and run the checks below, which record their errors in ``record.RECORD``.

Error model. A float64 position near a light carries a rounding error of about
ε·(|p| + |c| + size), while the quantities checked (pdf, G) depend on p through the distance to
the light's surface h. The checks therefore accept errors up to a few ε·κ with the condition
number κ = (|p| + |c| + size) / h, on top of a fixed relative tolerance; ``kappa`` is reported
with every case.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from renderer.description import LightDesc
from renderer.lights.base import ShadingContext
from renderer.lights.light_set import LightSet

from . import quadrature
from .record import note

EPS = float(np.finfo(np.float64).eps)
KINDS = ("rect", "disk", "sphere")
# where the shading point is, relative to the light
PLACEMENTS = ("free", "near", "grazing", "on", "inside", "behind", "far")
# how the shading normal is chosen
NORMALS = ("random", "facing", "straddle")

# Relative tolerance of G against the quadrature (the quadrature itself is good to ~1e-12;
# the closed forms reach ~1e-11 where p is well conditioned). Tight enough to see a 6e-7 error
# such as a too-low quadrature order in analytic.py's far-field disk.
G_RTOL = 1e-9
# pdf_li(sample_li(u).wi) against sample_li(u).pdf, relative, before the κ allowance.
PDF_RTOL = 1e-9


def quat_matrix(q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q)
    a, b, c, d = q
    return np.array([
        [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
        [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d],
    ])


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class LightCase:
    """One light and one shading point. Lengths are absolute (scene units)."""

    kind: str
    size: float            # rect width, disk/sphere radius
    aspect: float          # rect height / width
    quat: tuple            # rotation of the light (any non-zero 4-vector)
    offset: tuple          # translation of the light
    placement: str
    dist: float            # distance parameter of the placement
    where: tuple           # (a, b, c) uniforms in [0, 1) placing the point
    direction: tuple       # any non-zero 3-vector
    normal: str
    tilt: float            # in [-1, 1]: straddle tilt
    nrm: tuple             # any non-zero 3-vector (random normal)

    def label(self) -> str:
        return (f"{self.kind} size={self.size:.3g} aspect={self.aspect:.3g} {self.placement} "
                f"dist={self.dist:.3g} normal={self.normal} |offset|={np.linalg.norm(self.offset):.3g}")

    # ------------------------------------------------------------------ construction
    def desc(self, **extra) -> LightDesc:
        m = np.eye(4)
        m[:3, :3] = quat_matrix(self.quat)
        m[:3, 3] = self.offset
        kw = dict(width=self.size, height=self.size * self.aspect) if self.kind == "rect" else dict(radius=self.size)
        kw.update(extra)
        return LightDesc(path="/Stress/Light", kind=self.kind, light_to_world=m, intensity=1.0, **kw)

    def build(self, **extra):
        """(LightSet, kind object, point p (3,), normal (3,), kappa, h) for this case."""
        lights = LightSet.build([self.desc(**extra)], np.asarray(self.offset, dtype=np.float64), max(self.size, 1e-6))
        obj = lights.kinds[int(lights.kind_of[0])]
        a, b, c = self.where
        d = unit(self.direction)
        if self.kind == "sphere":
            ctr = obj.center[0]
            r = float(obj.radius[0])
            if self.placement == "inside":
                p = ctr + r * a * d
            elif self.placement == "on":
                p = ctr + r * d
            elif self.placement == "grazing":
                p = ctr + r * (1.0 + 10.0 ** (-12.0 * a)) * d
            elif self.placement == "near":
                p = ctr + (r + self.dist * a) * d
            else:  # free, far, behind
                p = ctr + (r + self.dist) * d
            to_c = ctr - p
        else:
            ctr = obj.center[0]
            if self.kind == "rect":
                e1, e2, en = obj.ex[0], obj.ey[0], obj.n[0]
                hx, hy = 0.5 * e1, 0.5 * e2
            else:
                en = obj.n[0]
                e1 = obj.s1[0] * obj.u1[0]
                e2 = obj.s2[0] * obj.u2[0]
                hx, hy = e1, e2
            if self.placement == "on":
                p = ctr + (2 * a - 1) * hx + (2 * b - 1) * hy
            elif self.placement == "near":
                p = ctr + 3 * (a - 0.5) * hx * 2 + 3 * (b - 0.5) * hy * 2 + self.dist * en
            elif self.placement == "grazing":
                # in (or a hair above) the light's plane, anywhere from on the light to far out
                inplane = unit(math.cos(2 * math.pi * a) * unit(e1) + math.sin(2 * math.pi * a) * unit(e2))
                p = ctr + self.dist * inplane + self.size * 10.0 ** (-14.0 * b) * (1 if c < 0.8 else 0) * en
            elif self.placement == "behind":
                p = ctr - self.dist * unit(en + 0.5 * (a - 0.5) * unit(e1))
            else:  # free, far
                p = ctr + self.dist * d
            to_c = ctr - p
        if self.normal == "facing":
            nrm = unit(to_c) if np.any(to_c) else unit(self.nrm)
        elif self.normal == "straddle" and np.any(to_c):
            w = unit(to_c)
            t = unit(np.cross(w, unit(self.nrm)))
            nrm = unit(t + 0.5 * self.tilt * w)
        else:
            nrm = unit(self.nrm)
        kappa, h = conditioning(obj, self.kind, p)
        return lights, obj, p, nrm, kappa, h


def conditioning(obj, kind: str, p: np.ndarray) -> tuple[float, float]:
    """(κ, h): distance h of p to the light's plane / sphere surface (extended precision) and
    κ = (|p| + |c| + extent) / h (inf when h = 0)."""
    P = np.asarray(p, dtype=np.longdouble)
    C = np.asarray(obj.center[0], dtype=np.longdouble)
    if kind == "sphere":
        D = P - C
        r = float(obj.radius[0])
        h = abs(float(np.sqrt((D * D).sum())) - r)
        extent = r
    else:
        N = np.asarray(obj.n[0], dtype=np.longdouble)
        h = abs(float(((P - C) * N).sum()))
        extent = float(np.sqrt(obj.area[0])) if kind == "rect" else float(obj.s1[0])
    scale = float(np.linalg.norm(p)) + float(np.linalg.norm(obj.center[0])) + extent
    return (scale / h if h > 0 else math.inf), h


_ONE = float(np.nextafter(1.0, 0.0))
# u on the boundary of [0, 1)^2: corners and edges map to points on the light's outline.
BOUNDARY_U = np.array([[0.0, 0.0], [_ONE, _ONE], [0.0, _ONE], [_ONE, 0.0], [0.5, 0.0], [0.0, 0.5], [0.5, _ONE]])


def sample_u(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(u (n, 2) in [0,1)^2, interior (n,) bool): the boundary rows first, then random rows."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 2))
    k = min(n, len(BOUNDARY_U))
    u[:k] = BOUNDARY_U[:k]
    interior = np.ones(n, dtype=bool)
    interior[:k] = False
    return u, interior


# --------------------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------------------
def check_sampling(case: LightCase, n: int = 64, seed: int = 0) -> None:
    """sample_li / pdf_li contract at one case (raises AssertionError with the case label)."""
    lights, obj, p, nrm, kappa, h = case.build()
    ctx = ShadingContext(np.tile(p, (n, 1)), np.tile(nrm, (n, 1)), np.tile(nrm, (n, 1)))
    idx = np.zeros(n, dtype=np.int64)
    u, interior = sample_u(n, seed)
    label = case.label() + f" kappa={kappa:.3g}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # a numpy floating-point warning is a failure here too
        s = lights.sample_li(idx, ctx, u)
        pdf_back = lights.pdf_li(idx, ctx, s.wi)
    for name, arr in (("L", s.L), ("wi", s.wi), ("pdf", s.pdf), ("p_light", s.p_light), ("pdf_li", pdf_back)):
        assert np.all(np.isfinite(arr)), f"non-finite {name} from sample_li/pdf_li: {label}"
    assert np.all(s.pdf >= 0.0) and np.all(pdf_back >= 0.0), f"negative pdf: {label}"
    assert np.all(s.L >= 0.0), f"negative L: {label}"
    if sees_nothing(case):
        assert not np.any(s.pdf > 0.0), f"a light sampled from {case.placement}: {label}"
    ok = s.pdf > 0.0
    if np.any(ok):
        length_err = float(np.max(np.abs(np.linalg.norm(s.wi[ok], axis=1) - 1.0)))
        note("sample_li |wi| - 1", length_err, label)
        assert length_err <= 1e-12, f"wi not unit ({length_err:.3g}): {label}"
        assert np.all(s.dist[ok] > 0.0) and np.all(np.isfinite(s.dist[ok])), f"bad dist: {label}"
        # A valid sample lies on the light's emitting side.
        assert np.all(np.any(s.L[ok] > 0.0, axis=1)), f"valid sample with L = 0: {label}"
        # The round trip is checked on interior u: boundary u give points exactly on the
        # light's outline, which a replayed ray may miss by one rounding (a set of measure 0).
        ok = ok & interior
        if not np.any(ok):
            return
        rel = np.abs(pdf_back[ok] - s.pdf[ok]) / s.pdf[ok]
        tol = PDF_RTOL + 64.0 * EPS * kappa
        bad = rel > tol
        frac = float(bad.mean())
        if kappa * EPS <= 1e-12:
            note("pdf_li(sample) vs pdf, rel (kappa*eps<=1e-12)", float(rel.max()), label)
            assert not bad.any(), f"pdf_li disagrees with sample_li.pdf by {rel.max():.3g}: {label}"
        elif kappa * EPS <= 1e-6:
            # Ill-conditioned: samples within rounding of the light's outline may miss it when
            # the ray is replayed; allow a small fraction of such rows.
            note("pdf_li(sample) mismatch fraction (1e-12<kappa*eps<=1e-6)", frac, label)
            assert frac <= 0.05, f"{frac:.1%} of samples fail the pdf round trip: {label}"
        else:
            # Grazing at angles near rounding (kappa*eps > 1e-6): the replayed ray's hit point
            # is not determined by float64; nothing to assert beyond finiteness.
            note("pdf_li(sample) mismatch fraction (kappa*eps>1e-6, not asserted)", frac, label)


def sees_nothing(case: LightCase) -> bool:
    """The point cannot see the emitting side at all (inside a sphere, behind a planar light)."""
    return (case.kind == "sphere" and case.placement == "inside") or (
        case.kind != "sphere" and case.placement == "behind")


def random_case(rng: np.random.Generator) -> LightCase:
    """A LightCase from a numpy generator (report.py); the hypothesis strategy draws the same fields."""
    return LightCase(
        kind=KINDS[rng.integers(len(KINDS))],
        size=10.0 ** rng.uniform(-6, 6),
        aspect=10.0 ** rng.uniform(-1, 1),
        quat=tuple(rng.normal(size=4)),
        offset=tuple(rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3)),
        placement=PLACEMENTS[rng.integers(len(PLACEMENTS))],
        dist=10.0 ** rng.uniform(-4, 7),
        where=tuple(rng.random(3)),
        direction=tuple(rng.normal(size=3)),
        normal=NORMALS[rng.integers(len(NORMALS))],
        tilt=float(rng.uniform(-1, 1)),
        nrm=tuple(rng.normal(size=3)),
    )


def check_irradiance(case: LightCase) -> None:
    """LightSet.irradiance (E = L·G for intensity 1) against the independent quadrature."""
    lights, obj, p, nrm, kappa, h = case.build()
    ctx = ShadingContext(p[None], nrm[None], nrm[None])
    label = case.label() + f" kappa={kappa:.3g}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        E, exact = lights.irradiance(np.zeros(1, dtype=np.int64), ctx)
    assert np.all(np.isfinite(E)) and np.all(E >= 0.0), f"irradiance {E} not finite/non-negative: {label}"
    assert bool(exact[0]), f"an untextured {case.kind} light must have an exact integral: {label}"
    if not math.isfinite(kappa) or kappa * EPS > 1e-2:
        # p is within rounding of the light's plane / surface: only finiteness is meaningful.
        note("irradiance: cases within rounding of the surface (finite only)", 0.0, label)
        return
    newell = rect_normal_error(case, obj, p, h)
    if newell > 1e-3:
        # Known bug (tests/stress/test_light_calls.py::test_rect_G_far_grazing_uses_exact_normal):
        # projected_solid_angle_rect rebuilds the normal from rounded corners.
        note("irradiance: rect cases skipped for the Newell-normal bug", 0.0, label)
        return
    L = float(obj.L[0, 0])
    G = float(E[0, 0]) / L
    if case.kind == "rect":
        ref, omega = quadrature.rect_G(p, nrm, obj.center[0], obj.ex[0], obj.ey[0], obj.n[0])
    elif case.kind == "disk":
        ref, omega = quadrature.disk_G(p, nrm, obj.center[0], obj.n[0], obj.s1[0])
    else:
        ref, omega = quadrature.sphere_G(p, nrm, obj.center[0], obj.radius[0])
    err = abs(G - ref)
    floor = omega * (1e-10 + 256.0 * EPS * kappa)
    if ref > 0.0 and kappa * EPS <= 1e-10 and ref >= 1e-6 * omega:
        note(f"irradiance vs quadrature, rel ({case.kind})", err / ref, label)
    if omega > 0.0:
        note(f"irradiance vs quadrature, |err|/Omega ({case.kind})", err / omega, label)
    if sees_nothing(case) or omega == 0.0:
        assert G <= floor or G == 0.0, f"G = {G:.3g} where nothing is seen: {label}"
        return
    # (+ the relative error that the known Newell-normal bug allows below its skip threshold)
    assert err <= (G_RTOL + 8.0 * newell) * ref + floor, (
        f"G = {G:.17g}, quadrature {ref:.17g} (rel {err / max(ref, 1e-300):.3g}, Omega {omega:.3g}): {label}")


def rect_normal_error(case: LightCase, obj, p: np.ndarray, h: float) -> float:
    """Relative error of h, hence of G, that renderer.lights.analytic's polygon code incurs by
    taking the light's normal from its float64 corners: direction error ~ε(|c| + size)/edge,
    times the distance |p − c|, over the height h (0 for disks and spheres)."""
    if case.kind != "rect" or not h > 0.0:
        return 0.0
    edge = min(float(np.linalg.norm(obj.ex[0])), float(np.linalg.norm(obj.ey[0])))
    c = obj.center[0]
    dn = EPS * (float(np.linalg.norm(c)) + math.sqrt(float(obj.area[0]))) / edge
    return dn * float(np.linalg.norm(p - c)) / h
