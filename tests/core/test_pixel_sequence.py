"""Progressive per-pixel filter samples (renderer.sampling.pixel_sequence)."""

import numpy as np

from renderer.sampling import pixel_sequence
from tests.stats import chi2_sf

ALPHA = 1e-4


def test_every_pass_is_uniform_over_pixels():
    """Each pass, across pixels, is a uniform sample of [0,1)^2 (chi-square):
    that is what keeps each pass's estimate unbiased."""
    pix = np.arange(200_000)
    for index in (0, 1, 17, 1000):
        u = pixel_sequence(3, pix, index)
        assert u.shape == (pix.size, 2) and np.all((u >= 0) & (u < 1))
        h, _, _ = np.histogram2d(u[:, 0], u[:, 1], bins=16, range=[[0, 1], [0, 1]])
        e = pix.size / 256
        assert chi2_sf(float(((h - e) ** 2 / e).sum()), 255) > ALPHA


def test_passes_of_one_pixel_are_stratified():
    """A pixel half-covered by an edge: the mean over 64 passes errs far less than with
    independent samples (whose RMS error is sqrt(.37*.63/64) = 0.060)."""
    pix = np.arange(4000)
    u = np.stack([pixel_sequence(5, pix, k) for k in range(64)], axis=1)
    for d in range(2):
        err = np.sqrt((((u[:, :, d] < 0.37).mean(axis=1) - 0.37) ** 2).mean())
        assert err < 0.02, (d, err)
    # A diagonal edge (2D stratification, not just 1D); independent samples: sqrt(.32*.68/64) = 0.058.
    err = np.sqrt((((u[:, :, 0] + u[:, :, 1] < 0.8).mean(axis=1) - 0.32) ** 2).mean())
    assert err < 0.04, err
    # ...and the same with seeds changes the points (different images per seed).
    assert not np.allclose(pixel_sequence(5, pix, 3), pixel_sequence(6, pix, 3))
