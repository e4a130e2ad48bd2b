"""LightSet: building, global indexing and dispatch by kind."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.description import EstimatorSettings, LightDesc
from renderer.lights.light_set import KIND_NAMES, LightSet
from tests.lights.helpers import ctx, look_down, ray_triangle, translate


def L(path, kind, m=np.eye(4), **kw):
    return LightDesc(path, kind, np.asarray(m, dtype=np.float64), **kw)


@pytest.fixture
def scene():
    descs = [
        L("/Key", "rect", translate(0, 0, 3), width=2.0, estimator=EstimatorSettings(estimator="controlVariate")),
        L("/Off", "rect", translate(0, 0, 3), intensity=0.0),
        L("/Fill", "sphere", translate(2, 0, 2), radius=0.3, intensity=5.0),
        L("/Sun", "distant", look_down((0.2, 0.1, -1.0)), intensity=3.0, angle=0.53),
        L("/Flat", "disk", translate(0, 0, 3), radius=0.0),
        L("/Bulb", "sphere", translate(-2, 0, 2), radius=0.1, treat_as_point=True, intensity=100.0),
        L("/Sky", "dome", intensity=0.2),
        L("/Tube", "cylinder", translate(0, 1, 2)),
        L("/Blob", "blob", translate(0, 1, 2)),
        L("/Spot", "disk", translate(0, -1, 2.5), radius=0.4, intensity=4.0),
        L("/Rim", "distant", look_down((0, 1.0, 0)), angle=0.0, intensity=2.0),
    ]
    return LightSet.build(descs, scene_center=(0, 0, 0), scene_radius=4.0)


def test_build_indexing(scene):
    assert scene.count == 8
    assert scene.paths == ["/Key", "/Fill", "/Sun", "/Bulb", "/Sky", "/Tube", "/Spot", "/Rim"]
    assert scene.dropped == ["/Off", "/Flat", "/Blob"]
    names = [KIND_NAMES[k] for k in scene.kind_of]
    assert names == ["rect", "sphere", "distant", "sphere", "dome", "cylinder", "disk", "distant"]
    np.testing.assert_array_equal(scene.local_of, [0, 0, 0, 1, 0, 0, 0, 1])
    np.testing.assert_array_equal(scene.delta, [False, False, False, True, False, False, False, True])
    np.testing.assert_array_equal(scene.infinite, [2, 4, 7])
    assert scene.kind_of.dtype == np.int8 and scene.local_of.dtype == np.int64
    assert scene.estimators[0].estimator == "controlVariate"
    assert any("/Blob" in w and "unknown light kind" in w for w in scene.warnings)
    assert any("/Flat" in w for w in scene.warnings)
    phi = scene.phi()
    assert phi.shape == (8,) and np.all(phi > 0)


def test_dispatch_matches_kinds(scene):
    n = 700
    rng = np.random.default_rng(0)
    light = rng.integers(0, scene.count, n)
    p = rng.normal(size=(n, 3)) * 0.5
    c = ctx((0, 0, 0), count=n)
    c = type(c)(p, np.zeros((n, 3)), np.zeros((n, 3)))
    u = rng.random((n, 2))
    s = scene.sample_li(light, c, u)
    for g in range(scene.count):
        rows = np.nonzero(light == g)[0]
        kind = scene.kinds[scene.kind_of[g]]
        ref = kind.sample_li(np.full(rows.size, scene.local_of[g]), c.take(rows), u[rows])
        np.testing.assert_array_equal(s.L[rows], ref.L)
        np.testing.assert_array_equal(s.pdf[rows], ref.pdf)
        np.testing.assert_array_equal(s.wi[rows], ref.wi)
    pdf = scene.pdf_li(light, c, s.wi)
    ok = ~scene.delta[light] & (s.pdf > 0)
    np.testing.assert_allclose(pdf[ok], s.pdf[ok], rtol=1e-6)
    assert np.all(pdf[scene.delta[light]] == 0)
    # Finite lights: the sampled point is hit at the sampled distance and emits L toward p.
    finite = ok & ~np.isin(light, scene.infinite)
    t = scene.intersect(light, c.p, s.wi)
    np.testing.assert_allclose(t[finite], s.dist[finite], rtol=1e-6)
    np.testing.assert_allclose(scene.le(light, s.p_light, s.wi)[finite], s.L[finite])
    assert np.all(np.isinf(t[np.isin(light, scene.infinite)]))
    # Infinite lights: escaped rays along the sample see L.
    inf_rows = ok & np.isin(light, scene.infinite)
    np.testing.assert_allclose(scene.le_escaped(light, s.wi)[inf_rows], s.L[inf_rows])
    assert np.all(scene.le_escaped(light, s.wi)[~np.isin(light, scene.infinite)] == 0)


def test_le_escaped_all_sums_infinite_lights(scene):
    sun_dir = -np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])
    d = np.array([sun_dir, [1.0, 0.0, 0.0]])
    total = scene.le_escaped_all(d)
    sky = 0.2
    sun = scene.kinds[KIND_NAMES.index("distant")].L[0, 0]
    np.testing.assert_allclose(total[:, 0], [sky + sun, sky])


def test_proxy_triangles_global_owner(scene):
    tris, owner = scene.proxy_triangles()
    assert set(owner.tolist()) == {0, 1, 5, 6}  # rect, sphere, cylinder, disk; not the point light nor infinite
    # A ray at the sphere light's centre hits one of its proxies.
    o = np.array([[2.0, 0.0, 0.0]])
    d = np.array([[0.0, 0.0, 1.0]])
    t = ray_triangle(o, d, tris)[0]
    assert np.isfinite(t[owner == 1]).any()
    assert np.isfinite(scene.intersect(np.array([1]), o, d))[0]


def test_empty_set():
    ls = LightSet.build([], (0, 0, 0), 1.0)
    assert ls.count == 0
    assert ls.phi().shape == (0,)
    tris, owner = ls.proxy_triangles()
    assert tris.shape == (0, 3, 3) and owner.shape == (0,)
    s = ls.sample_li(np.zeros(0, dtype=np.int64), ctx((0, 0, 0), count=0), np.zeros((0, 2)))
    assert s.pdf.shape == (0,)
