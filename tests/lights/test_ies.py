"""IES LM-63 parser: header versions, multipliers, symmetry expansion, lookup, power, errors."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from renderer.lights.ies import IesError, load_ies, parse_ies

IES_DIR = os.path.join(os.path.dirname(__file__), "..", "..", "stages", "ies")


def ies(v, h, cand, *, version="IESNA:LM-63-2002", tilt="TILT=NONE", mult=1.0, ballast=1.0, second=1.0,
        ptype=1, extra_header=()):
    """Text of a small IES file (candela (H, V))."""
    lines = [version] if version else []
    lines += ["[TEST] unit test", *extra_header, tilt]
    lines.append(f"1 -1 {mult:g} {len(v)} {len(h)} {ptype} 2 0 0 0")
    lines.append(f"{ballast:g} {second:g} 10")
    lines.append(" ".join(f"{x:g}" for x in v))
    lines.append(" ".join(f"{x:g}" for x in h))
    for row in np.asarray(cand, dtype=float).reshape(len(h), len(v)):
        lines.append(" ".join(f"{x:g}" for x in row))
    return "\n".join(lines) + "\n"


def deg(x):
    return np.radians(np.asarray(x, dtype=float))


# ------------------------------------------------------------------ committed profiles
def test_narrow_spot_is_rotationally_symmetric_and_exact_at_knots():
    p = load_ies(os.path.join(IES_DIR, "narrow_spot.ies"))
    assert p.version == "LM-63-2002"
    v = np.arange(0, 91, 5.0)
    expect = np.round(np.where(v <= 40.0, 1000.0 * np.exp(-(v / 12.0) ** 2), 0.0), 1)
    for phi in (0.0, 1.0, 3.0, 5.5):
        np.testing.assert_allclose(p.eval(deg(v), np.full(v.size, phi)), expect, rtol=0, atol=1e-9)
    # Linear between knots, zero beyond the table's last vertical angle (a downlight).
    mid = p.eval(deg([2.5]), [0.3])[0]
    assert mid == pytest.approx(0.5 * (expect[0] + expect[1]))
    assert p.eval(deg([95.0, 170.0]), [0.0, 0.0]).tolist() == [0.0, 0.0]


def test_quadrant_1995_multipliers_tilt_include_and_mirroring():
    p = load_ies(os.path.join(IES_DIR, "quadrant.ies"))
    assert p.version == "LM-63-1995"
    # Candela multiplier 2 x ballast 1.0 x ballast-lamp photometric factor 0.9 (LM-63-1995 only).
    raw_0_0 = 450.0
    assert p.eval(deg([0.0]), deg([0.0]))[0] == pytest.approx(1.8 * raw_0_0)
    theta = deg([0, 20, 35, 50, 90])
    for phi in (10.0, 30.0, 45.0, 75.0):
        base = p.eval(theta, deg([phi] * 5))
        for mirrored in (180.0 - phi, 180.0 + phi, 360.0 - phi):
            np.testing.assert_allclose(p.eval(theta, deg([mirrored] * 5)), base, rtol=1e-12)
    # Brighter along the 0-180 plane than along 90-270 (1 + 0.5 cos 2 phi).
    assert p.eval(deg([30]), deg([0]))[0] == pytest.approx(3.0 * p.eval(deg([30]), deg([90]))[0])


def test_wallwash_2019_ignores_the_file_generation_type():
    p = load_ies(os.path.join(IES_DIR, "wallwash.ies"))
    assert p.version == "LM-63-2019"
    # multiplier 0.5; the 1.1 on the ballast line is the file generation type, not a factor.
    expect = 0.5 * round(60.0 + 500.0 * math.exp(-((45.0 - 50.0) / 25.0) ** 2), 1)
    assert p.eval(deg([45.0]), [0.0])[0] == pytest.approx(expect)
    assert p.eval(deg([120.0]), [1.0])[0] == pytest.approx(0.5 * 20.0)
    # Asymmetric: the lobe points toward horizontal angle 0.
    assert p.eval(deg([45.0]), deg([0.0]))[0] > 4 * p.eval(deg([45.0]), deg([180.0]))[0]


def test_bilinear_interpolation_in_theta_and_phi():
    v = [0.0, 30.0, 60.0]
    h = [0.0, 90.0, 180.0, 270.0, 360.0]
    cand = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90], [100, 110, 120], [10, 20, 30.0]])
    p = parse_ies(ies(v, h, cand))
    # Halfway in both: mean of the four corners.
    assert p.eval(deg([15.0]), deg([45.0]))[0] == pytest.approx((10 + 20 + 40 + 50) / 4)
    # A quarter of the way in theta at a phi knot.
    assert p.eval(deg([37.5]), deg([180.0]))[0] == pytest.approx(80 + 0.25 * 10)
    # phi wraps around: 350 deg lies between the 270 and 360 rows.
    assert p.eval(deg([0.0]), deg([-10.0]))[0] == pytest.approx(p.eval(deg([0.0]), deg([350.0]))[0])
    assert p.eval(deg([0.0]), deg([315.0]))[0] == pytest.approx(0.5 * (100 + 10))


def test_bilateral_and_90_270_symmetries():
    v = [0.0, 45.0, 90.0]
    cand = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9.0]])
    half = parse_ies(ies(v, [0.0, 90.0, 180.0], cand))       # symmetric about the 0-180 plane
    assert half.eval(deg([45.0]), deg([270.0]))[0] == pytest.approx(5.0)
    assert half.eval(deg([45.0]), deg([300.0]))[0] == pytest.approx(half.eval(deg([45.0]), deg([60.0]))[0])
    side = parse_ies(ies(v, [90.0, 180.0, 270.0], cand))     # symmetric about the 90-270 plane
    assert side.eval(deg([45.0]), deg([180.0]))[0] == pytest.approx(5.0)
    for phi in (0.0, 30.0, 80.0, 300.0):
        assert side.eval(deg([45.0]), deg([phi]))[0] == pytest.approx(
            side.eval(deg([45.0]), deg([(180.0 - phi) % 360.0]))[0])


def test_missing_360_entry_is_repaired():
    v = [0.0, 90.0]
    h = np.arange(0.0, 331.0, 30.0)
    cand = np.tile([[5.0, 1.0]], (h.size, 1))
    cand[0] = [8.0, 2.0]
    p = parse_ies(ies(v, h, cand))
    assert p.eval(deg([0.0]), deg([345.0]))[0] == pytest.approx(0.5 * (5.0 + 8.0))


def test_old_formats_without_version_line():
    p = parse_ies(ies([0.0, 90.0], [0.0], [[3.0, 1.0]], version="", second=2.0))
    assert p.version == "LM-63-1986"
    assert p.eval(deg([0.0]), [0.0])[0] == pytest.approx(6.0)  # ballast-lamp factor applies before 2002
    q = parse_ies(ies([0.0, 90.0], [0.0], [[3.0, 1.0]], version="IESNA91", second=2.0))
    assert q.version == "LM-63-1991" and q.eval(deg([0.0]), [0.0])[0] == pytest.approx(6.0)


# ------------------------------------------------------------------ power (ies:normalize)
def test_power_of_isotropic_profiles_is_their_intensity():
    sphere = parse_ies(ies([0.0, 90.0, 180.0], [0.0], [[100.0, 100.0, 100.0]]))
    assert sphere.integral() == pytest.approx(400.0 * math.pi, rel=1e-12)
    assert sphere.power() == pytest.approx(100.0, rel=1e-12)
    hemi = parse_ies(ies([0.0, 45.0, 90.0], [0.0], [[100.0, 100.0, 100.0]]))
    assert hemi.power() == pytest.approx(100.0, rel=1e-12)  # hdEmbree: mean over the hemisphere


def test_integral_matches_dense_quadrature():
    p = load_ies(os.path.join(IES_DIR, "wallwash.ies"))
    n_t, n_p = 1440, 720
    t = (np.arange(n_t) + 0.5) * math.pi / n_t
    ph = (np.arange(n_p) + 0.5) * 2 * math.pi / n_p
    T, P = np.meshgrid(t, ph, indexing="ij")
    val = p.eval(T.ravel(), P.ravel()).reshape(T.shape)
    ref = float((val * np.sin(T)).sum() * (math.pi / n_t) * (2 * math.pi / n_p))
    assert p.integral() == pytest.approx(ref, rel=2e-4)


def test_theta_support():
    p = load_ies(os.path.join(IES_DIR, "narrow_spot.ies"))
    # 1000 exp(-(40/12)^2) rounds to 0.0 in the file: the last non-zero knot is 35 degrees.
    assert p.theta_support() == pytest.approx(math.radians(40.0))
    assert p.eval(deg([39.9]), [0.0])[0] > 0.0
    assert p.eval(deg([40.0, 60.0]), [0.0, 0.0]).tolist() == [0.0, 0.0]
    zero = parse_ies(ies([0.0, 90.0], [0.0], [[0.0, 0.0]]))
    assert zero.theta_support() == -1.0


# ------------------------------------------------------------------ errors name file and line
def _error(text, tmp_path, name="bad.ies"):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(IesError) as exc:
        load_ies(str(path))
    msg = str(exc.value)
    assert str(path) in msg
    return msg


def test_malformed_number_names_the_line(tmp_path):
    text = ies([0.0, 45.0, 90.0], [0.0], [[1.0, 2.0, 3.0]]).replace("1 2 3\n", "1 abc 3\n")
    msg = _error(text, tmp_path)
    line = text.splitlines().index("1 abc 3") + 1
    assert f"line {line}:" in msg and "'abc'" in msg


def test_truncated_file_reports_end_of_file(tmp_path):
    text = ies([0.0, 45.0, 90.0], [0.0, 90.0], [[1, 2, 3], [4, 5, 6]])
    msg = _error(text.rsplit("\n", 2)[0] + "\n", tmp_path)
    assert "unexpected end of file" in msg and "candela" in msg


@pytest.mark.parametrize("mutate, fragment", [
    (lambda t: t.replace("TILT=NONE", "TILT=lamp.tlt"), "external tilt"),
    (lambda t: t.replace("TILT=NONE\n", ""), "no 'TILT=' line"),
    (lambda t: t.replace(" 1 2 0 0 0", " 2 2 0 0 0"), "photometric type B"),
    (lambda t: t.replace("0 45 90\n", "0 60 45\n"), "vertical angles must increase"),
    (lambda t: t.replace("1 2 3\n", "1 -2 3\n"), "negative"),
    (lambda t: t.replace("1 2 3\n", "1 nan 3\n"), "must be finite"),
])
def test_bad_files(tmp_path, mutate, fragment):
    text = mutate(ies([0.0, 45.0, 90.0], [0.0], [[1.0, 2.0, 3.0]]))
    msg = _error(text, tmp_path)
    assert fragment in msg and "line " in msg


def test_bad_horizontal_range(tmp_path):
    msg = _error(ies([0.0, 90.0], [0.0, 45.0, 135.0], np.ones((3, 2))), tmp_path)
    assert "must end at 0, 90, 180 or 360" in msg


def test_missing_file_is_an_error(tmp_path):
    with pytest.raises(IesError, match="cannot read"):
        load_ies(str(tmp_path / "nope.ies"))
