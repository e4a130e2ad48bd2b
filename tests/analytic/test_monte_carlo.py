"""An independent sanity check by ray casting: cosine-weighted directions from p, exact
ray-shape hits, G = π · P(hit). z-tested (tests/stats.py) against the analytic value."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.geometry import coordinate_frame
from renderer.lights.analytic import (
    projected_solid_angle_disk,
    projected_solid_angle_ellipse,
    projected_solid_angle_rect,
    projected_solid_angle_sphere,
)
from tests.stats import SIGNIFICANCE, z_test

N_SAMPLES = 200_000


def _cosine_dirs(nrm, u):
    s, t = coordinate_frame(nrm[None].repeat(u.shape[0], axis=0))
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    z = np.sqrt(np.maximum(0.0, 1.0 - u[:, 0]))
    return (r * np.cos(phi))[:, None] * s + (r * np.sin(phi))[:, None] * t + z[:, None] * nrm[None]


def _plane_hit(p, d, c, n):
    dn = d @ n
    ok = dn != 0
    t = np.where(ok, ((c - p) @ n) / np.where(ok, dn, 1.0), -1.0)
    return t > 0, p + t[:, None] * d


CASES = [
    # (kind, p, nrm, params)
    ("rect", [0.3, 0.2, 1.0], [0.1, 0.0, -1.0], dict(center=[0, 0, 0], ex=[2, 0, 0], ey=[0, 1, 0], en=[0, 0, 1])),
    ("rect", [2.0, 0.1, 0.3], [-0.8, 0.2, 0.3], dict(center=[0, 0, 0], ex=[2, 0, 0], ey=[0.5, 1, 0], en=[0, 0, 1])),
    ("rect", [0.0, 0.0, 0.5], [1.0, 0.0, 0.05], dict(center=[0, 0, 0], ex=[2, 0, 0], ey=[0, 2, 0], en=[0, 0, 1])),
    ("disk", [0.2, 0.1, 0.8], [0.3, 0.0, -1.0], dict(center=[0, 0, 0], en=[0, 0, 1], radius=1.0)),
    ("disk", [1.5, 0.0, 0.2], [-1.0, 0.2, 0.4], dict(center=[0, 0, 0], en=[0, 0, 1], radius=1.0)),
    ("disk", [0.0, 0.3, 0.4], [0.0, 1.0, 0.1], dict(center=[0, 0, 0], en=[0, 0, 1], radius=1.0)),
    ("ellipse", [0.5, 0.1, 0.3], [-0.2, 0.1, -1.0], dict(center=[0, 0, 0], e1=[2.0, 0.5, 0], e2=[-0.1, 0.4, 0],
                                                       en=[0, 0, 1])),
    ("ellipse", [2.5, 0.0, 0.4], [-1.0, 0.0, 0.3], dict(center=[0, 0, 0], e1=[2.0, 0, 0], e2=[0, 0.3, 0],
                                                      en=[0, 0, 1])),
    ("sphere", [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], dict(center=[0, 0, 3.0], radius=1.0)),
    ("sphere", [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], dict(center=[3.0, 0, 0.4], radius=1.0)),
    ("sphere", [0.0, 0.0, 0.0], [0.3, 0.0, 1.0], dict(center=[1.2, 0.5, -0.2], radius=1.0)),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_monte_carlo_matches_analytic(case):
    kind, p, nrm, prm = CASES[case]
    p = np.asarray(p, float)
    nrm = np.asarray(nrm, float)
    nrm /= np.linalg.norm(nrm)
    rng = np.random.default_rng(100 + case)
    d = _cosine_dirs(nrm, rng.random((N_SAMPLES, 2)))
    P = np.broadcast_to(p, d.shape)
    if kind == "rect":
        c, ex, ey, en = (np.asarray(prm[k], float) for k in ("center", "ex", "ey", "en"))
        n = np.cross(ex, ey)
        ok, x = _plane_hit(P, d, c, n)
        # parallelogram coordinates through the dual basis
        g = np.array([[ex @ ex, ex @ ey], [ex @ ey, ey @ ey]])
        ab = np.linalg.solve(g, np.stack([(x - c) @ ex, (x - c) @ ey]))
        hit = ok & (np.abs(ab[0]) <= 0.5) & (np.abs(ab[1]) <= 0.5) & ((p - c) @ en > 0)
        G = projected_solid_angle_rect(p[None], nrm[None], c, ex, ey, en)[0]
    elif kind == "disk":
        c, en = (np.asarray(prm[k], float) for k in ("center", "en"))
        ok, x = _plane_hit(P, d, c, en)
        hit = ok & (np.linalg.norm(x - c, axis=1) <= prm["radius"]) & ((p - c) @ en > 0)
        G = projected_solid_angle_disk(p[None], nrm[None], c, en, prm["radius"])[0]
    elif kind == "ellipse":
        c, e1, e2, en = (np.asarray(prm[k], float) for k in ("center", "e1", "e2", "en"))
        ok, x = _plane_hit(P, d, c, en)
        g = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
        xy = np.linalg.solve(g, np.stack([(x - c) @ e1, (x - c) @ e2]))
        hit = ok & (xy[0] ** 2 + xy[1] ** 2 <= 1.0) & ((p - c) @ en > 0)
        G = projected_solid_angle_ellipse(p[None], nrm[None], c, e1, e2, en)[0]
    else:
        c = np.asarray(prm["center"], float)
        r = prm["radius"]
        oc = p - c
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        hit = (disc >= 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0)
        G = projected_solid_angle_sphere(p[None], nrm[None], c, r)[0]
    samples = np.pi * hit.astype(float)
    assert G > 0
    assert z_test(samples, G) > SIGNIFICANCE, (samples.mean(), G)
