"""DomeLight.irradiance_lookup: the renderer side of issue #6 (control variate of a textured dome)."""

from __future__ import annotations

import numpy as np
import pytest

from renderer import preconvolve as pc
from renderer.description import EstimatorSettings, LightDesc
from renderer.lights.base import ShadingContext
from renderer.lights.dome import DomeLight
from renderer.lights.irradiance import _dome
from renderer.lights.light_set import LightSet
from renderer.lights.radiometry import emitted_radiance
from tests.lights.helpers import rotate
from tests.stats import SIGNIFICANCE, z_test

from .conftest import random_normals, write_image


def sky_sun(h=32, w=64, sun=2e3, seed=0) -> np.ndarray:
    d = pc.latlong_directions(h, w)
    img = 0.5 + 0.8 * np.clip(d[..., 1:2], 0, None) * np.array([0.6, 0.8, 1.2])
    img = img + 0.2 * np.random.default_rng(seed).random((h, w, 3))
    img[h // 4, w // 3] = sun
    return img.astype(np.float32)


def dome(tex="", m=np.eye(4), irradiance="", **kw) -> LightDesc:
    return LightDesc("/Dome", "dome", np.asarray(m, dtype=np.float64), texture_file=tex,
                     estimator=EstimatorSettings(dome_irradiance=irradiance), **kw)


def lookup(light, n):
    return light.irradiance_lookup(np.zeros(len(n), dtype=np.int64), n)


def test_lookup_is_rotated_scaled_and_accurate(tmp_path):
    img = sky_sun()
    tex = write_image(tmp_path / "env.exr", img)
    m = rotate((0.3, 1.0, 0.2), 70.0)
    desc = dome(tex, m, intensity=3.0, exposure=0.5, color=(1.0, 0.5, 0.25))
    light = DomeLight.build([desc])
    assert light.warnings == []
    n = random_normals(3000, seed=1)
    E, ok = lookup(light, n)
    assert ok.all()
    R = m[:3, :3]
    ref = pc.exact_irradiance(img.astype(np.float64), n @ R) * emitted_radiance(desc, 1.0)
    rel = np.abs(E / ref - 1.0)
    assert rel.max() < 1e-3  # the target for the interpolation (here with a sun)
    assert rel.max() < 2e-4  # what the table achieves (the sun is taken out analytically)
    # At the table's own texel centres the lookup is the exact value.
    nodes = pc.latlong_directions(32, 64).reshape(-1, 3)
    E_nodes, _ = lookup(light, nodes @ R.T)
    assert np.allclose(E_nodes, pc.exact_irradiance(img.astype(np.float64), nodes) * emitted_radiance(desc, 1.0),
                       rtol=1e-6)  # the table holds E as float32, like its cache file


def test_interpolation_error_plain_bilinear_vs_table():
    """What the analytic part buys: plain bilinear interpolation of E is fine on a smooth map but
    not across a sun's horizon (the kink of L Ω max(0, n·s) is one table texel wide)."""
    img = sky_sun(64, 128, sun=2e4).astype(np.float64)
    n = random_normals(3000, seed=2)
    ref = pc.exact_irradiance(img, n)
    table = pc.build_table(img, size=64)
    plain = pc.build_table(img, size=64, analytic=False)
    assert np.abs(table.lookup(n) / ref - 1).max() < 2e-4
    assert np.abs(plain.lookup(n) / ref - 1).max() > 1e-2
    smooth = img.copy()
    smooth[16, 42] = smooth[15, 42]
    ref = pc.exact_irradiance(smooth, n)
    assert np.abs(pc.build_table(smooth, size=64, analytic=False).lookup(n) / ref - 1).max() < 1e-3


def test_agrees_with_what_the_light_samples_integrate(tmp_path):
    """The lookup equals E[L max(0, n·wi) / pdf] over DomeLight.sample_li (nearest texel,
    uniform in solid angle inside the texel). Here the horizon of n halves a bright texel: the
    texel-centre sum counts none of it, the light samples (and the lookup) half of it."""
    img = np.full((8, 16, 3), 1.0, np.float32)
    img[3, 3] = 200.0  # centre at lon 101.25°, just above the equator
    tex = write_image(tmp_path / "small.exr", img)
    light = DomeLight.build([dome(tex)])
    a = np.radians(11.25)
    n = np.array([np.sin(a), 0.0, np.cos(a)])  # horizon through the texel's centre meridian
    N = 100_000
    u = np.random.default_rng(4).random((N, 2))
    p = np.zeros((N, 3))
    s = light.sample_li(np.zeros(N, dtype=np.int64), ShadingContext(p, np.tile(n, (N, 1)), np.tile(n, (N, 1))), u)
    f = s.L[:, 0] * np.maximum(0.0, s.wi @ n) / s.pdf
    E = lookup(light, n[None])[0][0, 0]
    assert z_test(f, E) > SIGNIFICANCE
    mid = pc.midpoint_irradiance(img.astype(np.float64), n[None])[0, 0]
    assert z_test(f, mid) < SIGNIFICANCE and mid < 0.8 * E  # the centre sum would be a biased F


def test_second_load_hits_the_disk_cache(tmp_path, cache_dir, monkeypatch):
    tex = write_image(tmp_path / "env.exr", sky_sun())
    first = DomeLight.build([dome(tex)])
    assert first.irradiance[0].source == "computed"
    files = list(cache_dir.glob("*.exr"))
    assert len(files) == 1 and files[0].name.startswith(pc.file_sha256(tex))

    def no_compute(*a, **k):
        raise AssertionError("recomputed despite the cache")

    monkeypatch.setattr(pc, "_ExactAccumulator", no_compute)
    second = DomeLight.build([dome(tex)])
    assert second.irradiance[0].source == "cache" and second.warnings == []
    n = random_normals(200)
    assert np.array_equal(lookup(first, n)[0], lookup(second, n)[0])


def test_authored_map_is_used_when_fresh(tmp_path, monkeypatch):
    img = sky_sun()
    tex = write_image(tmp_path / "env.exr", img)
    irr = tmp_path / "env_irradiance.exr"
    pc.preconvolve(tex, str(irr), size=64)
    monkeypatch.setattr(pc, "_ExactAccumulator", lambda *a, **k: pytest.fail("recomputed"))
    light = DomeLight.build([dome(tex, irradiance=str(irr))])
    assert light.irradiance[0].source == "authored" and light.warnings == []
    n = random_normals(1000, seed=5)
    monkeypatch.undo()
    ref = pc.exact_irradiance(img.astype(np.float64), n)
    assert np.abs(lookup(light, n)[0] / ref - 1).max() < 1e-3  # float32 file + interpolation


def test_stale_authored_map_warns_and_recomputes(tmp_path):
    tex = write_image(tmp_path / "env.exr", sky_sun(seed=0))
    irr = tmp_path / "env_irradiance.exr"
    pc.preconvolve(tex, str(irr), size=32)
    new = sky_sun(seed=1)  # the texture was edited after the preconvolution
    new[5, 50] = 1e3
    write_image(tmp_path / "env.exr", new)
    light = DomeLight.build([dome(tex, irradiance=str(irr))])
    assert len(light.warnings) == 1
    w = light.warnings[0]
    assert "/Dome" in w and "stale" in w and "sourceHash" in w and str(irr) in w
    assert light.irradiance[0].source == "computed"
    n = random_normals(500, seed=6)
    ref = pc.exact_irradiance(new.astype(np.float64), n)
    assert np.abs(lookup(light, n)[0] / ref - 1).max() < 1e-3
    # The warning reaches the LightSet (and so the render's warnings).
    assert any("stale" in x for x in LightSet.build([dome(tex, irradiance=str(irr))]).warnings)


def test_approximate_or_unreadable_authored_map_is_replaced(tmp_path):
    tex = write_image(tmp_path / "env.exr", sky_sun())
    sh = tmp_path / "sh.exr"
    pc.preconvolve(tex, str(sh), size=16, method="sh")
    light = DomeLight.build([dome(tex, irradiance=str(sh))])
    assert "approximate method 'sh'" in light.warnings[0] and light.irradiance[0].source == "computed"
    junk = tmp_path / "junk.exr"
    junk.write_text("nope")
    light = DomeLight.build([dome(tex, irradiance=str(junk))])
    assert "cannot be read" in light.warnings[0] and light.irradiance[0].source in ("computed", "cache")


def test_constant_and_textured_domes_in_irradiance_py(tmp_path):
    tex = write_image(tmp_path / "env.exr", sky_sun())
    light = DomeLight.build([dome(intensity=2.0), dome(tex)])
    assert light.irradiance[0] is None
    n = random_normals(50, seed=7)
    idx = np.repeat([0, 1], len(n))
    nn = np.vstack([n, n])
    E, ok = light.irradiance_lookup(idx, nn)
    assert not ok[: len(n)].any() and ok[len(n):].all()
    ctx = ShadingContext(np.zeros_like(nn), nn, nn)
    E2, exact = _dome(light, idx, ctx)
    assert exact.all()
    assert np.allclose(E2[: len(n)], 2.0 * np.pi)
    assert np.array_equal(E2[len(n):], E[len(n):])
    ls = LightSet.build([dome(tex)])
    assert ls.has_exact_integral.all()
