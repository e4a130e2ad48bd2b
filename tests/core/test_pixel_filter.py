"""Pixel filters (renderer/pixel_filter.py) and the splatting film (renderer/film.py): filter
shapes, the sampled offsets and the splatted footprint weights chi-square-tested against the
analytic filter, the variance estimate z-tested in both modes, checkpoints and merges."""

import math
import pickle

import numpy as np
import pytest

from renderer.errors import SettingsError
from renderer.film import Film
from renderer.pixel_filter import FILTERS, PixelFilter, filter_profile
from tests.stats import chi2_sf

BH = (0.35875, 0.48829, 0.14128, 0.01168)


def _bin_integrals(f: PixelFilter, edges: np.ndarray) -> np.ndarray:
    """Integral of the 1-D profile over each bin (fine midpoint rule), normalised to sum 1."""
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        x = a + (np.arange(4000) + 0.5) * (b - a) / 4000
        out.append(filter_profile(f.name, f.radius, x).sum() * (b - a) / 4000)
    out = np.array(out)
    return out / out.sum()


@pytest.mark.parametrize("name", FILTERS)
def test_profiles_are_the_documented_formulas(name):
    r = 1.5 if name != "box" else 0.5
    x = np.linspace(-2.0 * r, 2.0 * r, 401)
    v = filter_profile(name, r, x)
    inside = np.abs(x) < r
    if name == "gaussian":
        sigma = r / 3.0
        expect = np.exp(-0.5 * (x / sigma) ** 2) - math.exp(-4.5)
    elif name == "box":
        expect = np.ones_like(x)
    else:
        t = np.pi * x / r
        expect = BH[0] + BH[1] * np.cos(t) + BH[2] * np.cos(2 * t) + BH[3] * np.cos(3 * t)
    np.testing.assert_allclose(v[inside], expect[inside], rtol=1e-12, atol=1e-14)
    assert np.all(v[~inside] == 0.0)
    np.testing.assert_allclose(v, v[::-1], rtol=0, atol=1e-14)  # symmetric (linspace rounds)
    assert v.max() == filter_profile(name, r, 0.0)


def test_default_widths_and_bad_values():
    assert PixelFilter().name == "gaussian" and PixelFilter().radius == 1.5  # sigma 0.5 px, as before
    assert PixelFilter("box").radius == 0.5 and PixelFilter("blackman-harris").radius == 1.5
    with pytest.raises(SettingsError, match="pixel-filter: 'mitchell' is not one of"):
        PixelFilter("mitchell")
    for bad in (0.25, 9.0, float("nan"), "wide"):
        with pytest.raises(SettingsError, match="pixel-filter-width"):
            PixelFilter("box", bad)


@pytest.mark.parametrize("name,radius", [("gaussian", 1.5), ("box", 0.5), ("blackman-harris", 1.5),
                                         ("gaussian", 2.5), ("box", 1.25)])
def test_importance_sampled_offsets_follow_the_filter(name, radius):
    """Filter importance sampling: each coordinate's offsets, chi-square against the profile."""
    f = PixelFilter(name, radius)
    u = np.random.default_rng(3).random((200_000, 2))
    off = f.sample(u)
    edges = np.linspace(-radius, radius, 41)
    expect = _bin_integrals(f, edges) * off.shape[0]
    for c in range(2):
        obs, _ = np.histogram(off[:, c], edges)
        keep = expect > 5
        chi2 = float(((obs[keep] - expect[keep]) ** 2 / expect[keep]).sum())
        assert chi2_sf(chi2, int(keep.sum()) - 1) > 1e-4, chi2


def _footprint_offsets(f: PixelFilter, n_targets: int, rng) -> np.ndarray:
    """Splat one uniform sample near each of n_targets pixels spaced wider than the footprint,
    and keep each sample with probability (its weight in its target pixel) / max weight:
    rejection turns the film's weights into sample offsets that follow the filter itself when
    the weights are right. Returns the kept offsets (k, 2) from the target pixel centres."""
    side = int(math.ceil(2 * f.radius)) + 2  # targets this far apart never share a sample
    g = int(math.ceil(math.sqrt(n_targets)))
    film = Film(g * side, g * side, None, f)
    ty, tx = np.mgrid[0:g, 0:g]
    cx, cy = tx.ravel() * side + side // 2, ty.ravel() * side + side // 2
    # A sample uniform over the target's footprint square [-r, r]^2 around its centre.
    d = (rng.random((cx.size, 2)) * 2.0 - 1.0) * f.radius
    sx, sy = cx + 0.5 + d[:, 0], cy + 0.5 + d[:, 1]
    px, py = np.floor(sx).astype(np.int64), np.floor(sy).astype(np.int64)
    rows = py * film.width + px
    film.add(rows, np.ones((rows.size, 3)), offsets=np.stack([sx - px - 0.5, sy - py - 0.5], axis=1))
    w = film.weight[cy, cx, 0]
    peak = filter_profile(f.name, f.radius, 0.0) ** 2
    keep = rng.random(w.size) * peak < w
    return d[keep]


@pytest.mark.parametrize("name,radius", [("gaussian", 1.5), ("blackman-harris", 1.5), ("box", 1.0),
                                         ("gaussian", 2.0)])
def test_splat_footprint_weights_follow_the_filter(name, radius):
    """Chi-square of the splatting film's footprint weights: the offsets (2-D, 8 x 8 bins) of
    samples kept in proportion to the weight they gave a pixel follow f(dx, dy)."""
    f = PixelFilter(name, radius)
    rng = np.random.default_rng(7)
    d = np.concatenate([_footprint_offsets(f, 40_000, rng) for _ in range(4)])
    edges = np.linspace(-radius, radius, 9)
    p1 = _bin_integrals(f, edges)
    expect = np.outer(p1, p1) * d.shape[0]
    obs, _, _ = np.histogram2d(d[:, 1], d[:, 0], [edges, edges])
    keep = expect > 5
    chi2 = float(((obs[keep] - expect[keep]) ** 2 / expect[keep]).sum())
    assert chi2_sf(chi2, int(keep.sum()) - 1) > 1e-4, chi2


def test_footprint_chi_square_detects_a_wrong_width():
    """The same test against a filter 10 % narrower than the film's fails: it can fail."""
    f = PixelFilter("gaussian", 1.5)
    d = _footprint_offsets(f, 160_000, np.random.default_rng(8))
    edges = np.linspace(-1.5, 1.5, 9)
    p1 = _bin_integrals(PixelFilter("gaussian", 1.35), np.clip(edges, -1.35, 1.35))
    expect = np.outer(p1, p1) * d.shape[0]
    obs, _, _ = np.histogram2d(d[:, 1], d[:, 0], [edges, edges])
    keep = expect > 5
    chi2 = float(((obs[keep] - expect[keep]) ** 2 / expect[keep]).sum())
    assert chi2_sf(chi2, int(keep.sum()) - 1) < 1e-6


def _passes(film: Film, n: int, rng, L_fn):
    """n progressive passes: one sample per pixel, uniform in it, radiance L_fn(m, rng) (m, 3)."""
    m = film.count.size
    for _ in range(n):
        film.add(np.arange(m), L_fn(m, rng), offsets=rng.random((m, 2)) - 0.5 if film.splat else None)


@pytest.mark.parametrize("mode", ["splat", "importance"])
def test_variance_estimate_is_unbiased_for_a_known_variance(mode):
    """Samples i.i.d. exponential (mean 2, variance 4) wherever they land: each pixel's value
    R has mean 2 and E (R - 2)^2 = Var R, which the film's estimate must match on average.
    z-test over pixels three apart (their footprints share no sample: independent)."""
    rng = np.random.default_rng(11)
    film = Film(240, 240, None, PixelFilter() if mode == "splat" else None)
    _passes(film, 4, rng, lambda m, r: np.repeat(r.exponential(2.0, (m, 1)), 3, axis=1))
    sl = (slice(2, None, 3), slice(2, None, 3), 0)
    R = film.mean().astype(np.float64)[sl]
    V = film.variance_of_mean()[sl]
    D = ((R - 2.0) ** 2 - V).ravel()
    z = D.mean() / (D.std(ddof=1) / math.sqrt(D.size))
    assert abs(z) < 4.0, z
    if mode == "splat":
        # Without the small-sample factor (the plain delta-method estimate sum(w^2 (L-R)^2) / W1^2)
        # the same test fails at 4 passes: it has the power to see a wrong estimate.
        W1, W2 = film.weight[..., 0], film.weight[..., 1]
        Rf = film.sum[..., 0] / W1
        plain = ((film.sum_sq[..., 0] - 2 * Rf * film.sum_w2[..., 0] + Rf * Rf * W2) / W1 ** 2)[sl[:2]]
        Dp = ((R - 2.0) ** 2 - plain).ravel()
        assert Dp.mean() / (Dp.std(ddof=1) / math.sqrt(Dp.size)) > 4.0


def test_splat_of_a_constant_is_exact_everywhere_and_drops_nonfinite():
    """A constant image stays constant to rounding, the window's edge pixels included (their
    footprint is weighed over the part inside the window); NaN/Inf samples are dropped."""
    rng = np.random.default_rng(2)
    film = Film(20, 14, (3, 2, 17, 11), PixelFilter("blackman-harris", 2.0))
    m = film.count.size
    for _ in range(3):
        L = np.full((m, 3), 0.7)
        L[5] = np.nan
        L[9, 1] = np.inf
        film.add(np.arange(m), L, offsets=rng.random((m, 2)) - 0.5)
    img = film.mean()
    assert film.nonfinite_dropped == 6 and np.all(np.isfinite(img))
    np.testing.assert_allclose(img, 0.7, rtol=1e-6)
    assert np.all(np.isfinite(film.variance_of_mean())) and film.count.max() == 3
    with pytest.raises(IndexError):
        film.add(np.array([m]), np.ones((1, 3)), offsets=np.zeros((1, 2)))


def test_splat_films_merge_pickle_and_checkpoint(tmp_path):
    """Two halves of the passes merged equal one film holding them all; a checkpoint and a
    pickle (the Ray backend's transport) keep the mode, the filter and every sum."""
    rng = np.random.default_rng(4)
    f = PixelFilter("gaussian", 2.0)
    data = [(rng.random((48, 3)), rng.random((48, 2)) - 0.5) for _ in range(6)]
    whole, a, b = (Film(8, 6, None, f) for _ in range(3))
    for k, (L, off) in enumerate(data):
        whole.add(np.arange(48), L, offsets=off)
        (a if k < 3 else b).add(np.arange(48), L, offsets=off)
    merged = pickle.loads(pickle.dumps(a)).copy()
    merged.merge(pickle.loads(pickle.dumps(b)))
    np.testing.assert_allclose(merged.mean(), whole.mean(), rtol=1e-12)
    np.testing.assert_allclose(merged.variance_of_mean(), whole.variance_of_mean(), rtol=1e-9)
    p = str(tmp_path / "ck.npz")
    merged.save_state(p)
    back = Film.load_state(p)
    assert back.mode == "splat" and repr(back.splat) == repr(f) and back.count.max() == 6
    np.testing.assert_array_equal(back.weight, merged.weight)
    np.testing.assert_array_equal(back.mean(), merged.mean())
    with pytest.raises(ValueError, match="mode"):
        back.merge(Film(8, 6))
