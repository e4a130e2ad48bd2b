"""Hypothesis-driven accuracy tests: renderer.lights.analytic against independent quadrature.

Every example builds one configuration (configs.py: global scale 1e-6..1e6, points that are
generic, close, grazing, far (distance/size up to 1e12), near an edge/corner/rim, in the
light's plane or behind it; normals random, straddling the light, tangent to it, facing,
facing down or up) and checks it with harness.check (REL_TOL = 1e-5 plus the documented
conditioning floors). The default profile draws 300 configurations per light kind (400 ellipses); the
``slow`` tests add more (many more with ILLUM_HYPOTHESIS_PROFILE=long). The errors are
collected in harness.RECORD and printed at the end of the run (conftest.py).
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from . import harness
from ._profile import hyp_settings
from .configs import N_MODES, N_PERMS, N_UNIFORMS, P_MODES, S_MODES, planar_config, sphere_config

unit = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
uniforms = st.lists(unit, min_size=N_UNIFORMS, max_size=N_UNIFORMS)
p_mode = st.integers(0, len(P_MODES) - 1)
n_mode = st.integers(0, len(N_MODES) - 1)
perm = st.integers(0, N_PERMS - 1)
s_mode = st.integers(0, len(S_MODES) - 1)

DEFAULT = 300       # per light kind, default profile (the suite's time budget)
LONG = 20000        # per light kind and test, long profile


def _planar(kind, pm, nm, pr, u, k=4):
    ok, msg = harness.run_planar(planar_config(kind, pm, nm, pr, u, k=k))
    assert ok, msg


@hyp_settings(DEFAULT, LONG)
@given(pm=p_mode, nm=n_mode, pr=perm, u=uniforms)
def test_rect_matches_quadrature(pm, nm, pr, u):
    _planar("rect", pm, nm, pr, u)


@hyp_settings(DEFAULT, LONG)
@given(pm=p_mode, nm=n_mode, pr=perm, u=uniforms)
def test_disk_matches_quadrature(pm, nm, pr, u):
    _planar("disk", pm, nm, pr, u)


@hyp_settings(DEFAULT, LONG)
@given(pm=p_mode, nm=n_mode, pr=perm, u=uniforms, k=st.integers(3, 7))
def test_polygon_matches_quadrature(pm, nm, pr, u, k):
    _planar("polygon", pm, nm, pr, u, k)


# Ellipses (an extra: the disk light under non-uniform scale), aspect 1e-2..1.
@hyp_settings(400, LONG)
@given(pm=p_mode, nm=n_mode, pr=perm, u=uniforms)
def test_ellipse_matches_quadrature(pm, nm, pr, u):
    _planar("ellipse", pm, nm, pr, u)


@hyp_settings(DEFAULT, LONG)
@given(sm=s_mode, u=uniforms)
def test_sphere_matches_quadrature(sm, u):
    ok, msg = harness.run_sphere(sphere_config(sm, u))
    assert ok, msg


# --- long profile ------------------------------------------------------------------------
@pytest.mark.slow
@hyp_settings(40, LONG)
@given(kind=st.sampled_from(["rect", "disk", "polygon", "ellipse"]), pm=p_mode, nm=n_mode, pr=perm, u=uniforms,
       k=st.integers(3, 7))
def test_long_planar_sweep(kind, pm, nm, pr, u, k):
    _planar(kind, pm, nm, pr, u, k)


@pytest.mark.slow
@hyp_settings(40, LONG)
@given(sm=s_mode, u=uniforms)
def test_long_sphere_sweep(sm, u):
    ok, msg = harness.run_sphere(sphere_config(sm, u))
    assert ok, msg
