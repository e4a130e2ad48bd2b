"""The control variate where a light straddles the shading point's horizon (issue 22).

F leaves out the part of a light below the horizon, so the average visibility v̄ that α uses
must measure only the samples F covers. Counting the samples below the horizon as v = 0 made a
fully lit point under a dome see v̄ ≈ 1/2, and the control variate noisier than MIS on the white
furnace. These tests pin the fixed behaviour: zero variance where the covered part is fully
lit, and unbiased expectations in a penumbra, for a rect light cut by the horizon and for a
constant dome over a convex object.
"""

import numpy as np
import pytest

from renderer.accel import Accel
from renderer.bsdfs.lambert import LambertBSDF
from renderer.description import LightDesc
from renderer.estimators.control_variates import cv_diffuse
from renderer.geometry import coordinate_frame, to_local
from renderer.lights.analytic import projected_solid_angle_rect
from renderer.lights.base import ShadingContext
from renderer.lights.light_set import LightSet
from tests.estimators.helpers import L_RECT, RHO, Setup
from tests.stats import SIGNIFICANCE, z_test


def _quad_accel(quad) -> Accel:
    q = np.asarray(quad, dtype=float)
    return Accel(np.array([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]), threads=1)


def straddling_rect(occluded: bool, n: int) -> Setup:
    """A 2 x 2 rect light standing in the plane y = 2, facing the origin, spanning z in [-1, 1]:
    its lower half is below the horizon of the shading points (origin, normal +z). With
    ``occluded`` a wall at y = 1 over x > 0 hides the light's x > 0 half."""
    s = Setup("none", n=n)
    m = np.eye(4)
    # local X -> world X, local Y -> world -Z, local Z -> world +Y: emits along local -Z = world -Y.
    m[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    m[1, 3] = 2.0
    s.lights = LightSet.build([LightDesc(path="/Light", kind="rect", light_to_world=m, intensity=L_RECT,
                                         width=2.0, height=2.0)], np.zeros(3), 5.0)
    if occluded:
        s.accel = _quad_accel([[0, 1, -100], [100, 1, -100], [100, 1, 100], [0, 1, 100]])
    return s


def straddling_reference(occluded: bool) -> float:
    """Exact outgoing radiance: the projected solid angle of the part above the horizon
    (z in [0, 1]), of its x < 0 half where occluded."""
    p, nz, facing = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([0.0, -1.0, 0.0])
    if occluded:
        G = projected_solid_angle_rect(p, nz, [-0.5, 2, 0.5], [1, 0, 0], [0, 0, 1], facing)[0]
    else:
        G = projected_solid_angle_rect(p, nz, [0, 2, 0.5], [2, 0, 0], [0, 0, 1], facing)[0]
    return RHO / np.pi * L_RECT * G


@pytest.mark.parametrize("alpha,N", [("one", 1), ("one", 4), ("averageVisibilityUnbiased", 2),
                                     ("averageVisibilityUnbiased", 4), ("averageVisibilityUnbiased", 8)])
def test_control_variate_is_unbiased_for_a_light_cut_by_the_horizon(alpha, N):
    s = straddling_rect(occluded=True, n=20000)
    Ld = s.estimate("controlVariate", N, alpha, seed=40 + N)[:, 0]
    ref = straddling_reference(occluded=True)
    p = z_test(Ld, ref)
    assert p > SIGNIFICANCE, f"{alpha}/N={N}: mean {Ld.mean():.6f} vs {ref:.6f} (p={p:.2e})"
    # The fixture must be able to fail: the whole light's visible half is a different answer.
    assert abs(straddling_reference(occluded=False) / ref - 1) > 0.5


@pytest.mark.parametrize("alpha", ["averageVisibility", "averageVisibilityUnbiased"])
def test_light_cut_by_the_horizon_fully_lit_gives_exactly_F(alpha):
    """About half of the light samples fall below the horizon; they must not pull v̄ down."""
    s = straddling_rect(occluded=False, n=2000)
    Ld = s.estimate("controlVariate", 4, alpha, seed=7)[:, 0]
    F = straddling_reference(occluded=False)
    np.testing.assert_allclose(Ld, F, rtol=1e-9)


def _icosphere(subdiv: int = 3) -> np.ndarray:
    """(T, 3, 3) triangles of a unit sphere (convex)."""
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    tris = np.array([[v[i] for i in tri] for tri in f], dtype=float)
    tris /= np.linalg.norm(tris, axis=2, keepdims=True)
    for _ in range(subdiv):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [x / np.linalg.norm(x, axis=1, keepdims=True) for x in (a + b, b + c, c + a)]
        tris = np.concatenate([np.stack(x, axis=1) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tris


class DomeOverSphere(Setup):
    """Shading points at the centroids of a tessellated unit sphere's triangles (normal = the
    face normal), wo along the normal, under a constant dome of radiance L_DOME; the sphere
    itself is the scene (convex: it never shadows its own points)."""

    L_DOME = 2.0

    def __init__(self, occluder: bool = False):
        tris = _icosphere(3)
        ng = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        ng /= np.linalg.norm(ng, axis=1, keepdims=True)
        self.n = tris.shape[0]
        p = tris.mean(axis=1)
        self.ctx = ShadingContext(p, ng, ng)
        self.s, self.t = coordinate_frame(ng)
        self.wo_l = to_local(ng, self.s, self.t, ng)
        self.bsdf = LambertBSDF(np.full((self.n, 3), RHO))
        self.eps = np.full(self.n, 1e-5)
        self.rays = 0
        self.lights = LightSet.build([LightDesc(path="/Dome", kind="dome", light_to_world=np.eye(4),
                                                intensity=self.L_DOME)], np.zeros(3), 2.0)
        geo = [tris]
        if occluder:
            # A big floor just under the sphere: the lower points see the dome partly hidden.
            geo.append(np.array([[[-50, -1.2, -50], [50, -1.2, -50], [50, -1.2, 50]],
                                 [[-50, -1.2, -50], [50, -1.2, 50], [-50, -1.2, 50]]], dtype=float))
        self.accel = Accel(np.concatenate(geo), threads=1)


@pytest.mark.parametrize("alpha", ["one", "averageVisibility", "averageVisibilityUnbiased"])
def test_convex_object_under_a_constant_dome_has_zero_variance(alpha):
    """The white furnace's first vertex: every point sees the whole upper hemisphere of the
    dome, so the control variate returns F = rho L exactly, without noise."""
    s = DomeOverSphere()
    Ld = s.estimate("controlVariate", 4, alpha, seed=3)
    np.testing.assert_allclose(Ld, RHO * s.L_DOME, rtol=1e-9)


def test_ratio_estimator_is_exact_on_a_convex_object_under_a_constant_dome():
    """With N = 4 about one point in 16 has every sample below its horizon: the ratio must not
    read that as a shadow."""
    s = DomeOverSphere()
    Ld = s.estimate("ratio", 4, seed=4)
    np.testing.assert_allclose(Ld, RHO * s.L_DOME, rtol=1e-9)


@pytest.mark.parametrize("alpha,N", [("one", 4), ("averageVisibilityUnbiased", 2), ("averageVisibilityUnbiased", 4)])
def test_dome_control_variate_expectation_unchanged(alpha, N):
    """With a floor under the sphere some points are in a penumbra: the control variate's mean
    equals MIS's (an independent estimator of the same integral) point by point on average."""
    s = DomeOverSphere(occluder=True)
    reps = 24
    cv = np.stack([s.estimate("controlVariate", N, alpha, seed=100 + k)[:, 0] for k in range(reps)])
    mis = np.stack([s.estimate("mis", 4, seed=500 + k)[:, 0] for k in range(reps)])
    shadowed = mis.mean(axis=0) < 0.98 * RHO * s.L_DOME
    assert shadowed.sum() > 50, "the floor must shadow part of the sphere"
    d = (cv - mis)[:, shadowed].ravel()
    p = z_test(d, 0.0)
    assert p > SIGNIFICANCE, f"mean difference {d.mean():.5f} (p={p:.2e})"


def test_leave_one_out_equals_the_talks_rescaled_form_when_every_sample_is_covered():
    rng = np.random.default_rng(1)
    n, N = 50, 5
    F = rng.random((n, 3))
    X = rng.random((n, N, 3))
    v = (rng.random((n, N)) < 0.6).astype(float)
    covered = np.ones((n, N), dtype=bool)
    v_bar = v.mean(axis=1)
    talk = v_bar[:, None] * F + (X * (v - v_bar[:, None])[:, :, None]).sum(axis=1) / (N - 1)
    np.testing.assert_allclose(cv_diffuse(F, X, v, covered, "averageVisibilityUnbiased"), talk, rtol=1e-12)
    biased = v_bar[:, None] * F + (X * (v - v_bar[:, None])[:, :, None]).sum(axis=1) / N
    np.testing.assert_allclose(cv_diffuse(F, X, v, covered, "averageVisibility"), biased, rtol=1e-12)
