"""Adaptive sampling: pixels stop receiving samples once their noise is below a threshold.

The rule (``--noise-threshold T``, or IllumRenderSettingsAPI ``illum:adaptive:noiseThreshold``):

* Every pixel traces two independent streams of camera samples. Of the first t passes of the
  render, ``decisions(t) = floor(min(t / 4, 2 sqrt(t)))`` are *decision* passes (pass t, counting
  from 0, is one when decisions(t + 1) > decisions(t)) and the others *image* passes: one in four
  up to 64 samples (16 decision samples), then ever fewer (32 of 256, 64 of 1024). The two
  streams have different seeds (their own chunk streams and their own scrambles of each pixel's
  Sobol' sequence, ``decision_seed``), so the decision samples are independent of the image
  samples.
* The image (the beauty film, its AOVs, the denoiser's input) holds the image samples only: a
  pixel's value is the mean of its n_B image samples.
* After each pass, an active pixel stops when it has traced at least the minimum
  samples (``--adaptive-min-spp``, default ``DEFAULT_MIN_SPP``; both streams count), has at least
  two decision samples, and

      sum_c w_c SE_c  <  T * sum_c w_c mu_c,

  with w the Rec.709 luminance weights (renderer/color.py), mu_c the mean of its n_D decision
  samples in channel c and SE_c = s_c / sqrt(n_B) the standard error its image mean will have
  (s_c^2 the decision samples' variance, Film.variance_of_mean times n_D). The left side bounds
  the standard error of the luminance from above (the standard deviation of a sum is at most the
  sum of the standard deviations), so the rule reads: the relative standard error of the
  pixel's mean luminance is below T. A pixel whose decision samples all agree (SE = 0, a sky
  or a black background) stops at the minimum; one whose mean luminance is not positive and
  whose samples vary never stops by the rule.
* ``--spp`` (default 64; both streams count) and ``--time-budget`` cap every pixel as in a
  uniform render; the render ends early once every pixel has stopped.

Why the image stays unbiased: when a pixel stops depends on its decision samples only, which are
independent of its image samples. Given its stopping count n_B, its image samples are still what
they would have been without the rule (each an unbiased sample of the pixel: its Sobol' point,
randomly shifted, is uniform in the pixel), so E[mean of the n_B image samples | n_B] is the
pixel's value, and so is the expectation over n_B. The textbook rule -- decide from the samples
that form the image -- is biased: a pixel stops when its samples happen to agree or, with a
relative threshold, when their mean happens to be high (biased high: tests/cli/test_adaptive.py
finds it in the decision film of the pixels that stopped early, with the z-test that finds no
bias in the image), and before the rare large sample of a caustic or a small light has come
(biased low). Cycles' split, which decides from the difference between all samples and one half
and keeps both in the image, keeps part of that bias.
The price is the decision samples: at a given number of traced samples the image's variance is
t / (t - decisions(t)) of what all samples would give: 4/3 up to 64 samples, 1.14 at 256, 1.07
at 1024 (bench/results/adaptive/README.md weighs it). Between decision passes the rule is
evaluated again as n_B grows: the stopping count still depends on the decision samples alone.

Only filter importance sampling (``--pixel-filter-mode importance``, adaptive sampling's
default) is allowed: a splatted pixel mixes its neighbours' samples, and where their sample
counts differ it would weigh their parts of its footprint by their sample density, a different
image.
"""

from __future__ import annotations

import numpy as np

from .color import REC709_LUMINANCE
from .errors import SettingsError
from .film import Film

__all__ = ["DEFAULT_MIN_SPP", "Adaptive", "adaptive_settings", "decision_seed", "decisions"]

# The decision share: a quarter at first, not Cycles' half: the decision samples cost image
# variance (4/3 here, 2 with a half), and at the default minimum of 32 samples a quarter still
# gives 8 decision samples (7 degrees of freedom: a pixel's variance is underestimated 4-fold with
# probability 2.8 %, P(chi2_7 / 7 < 1/4), against 14 % with 4 samples). Later the variance
# estimate is good enough that more decision samples change few decisions: their number grows as
# 2 sqrt(t) (the estimate's relative error as t^-1/4), so their share falls.
DECISION_SHARE = 4
DECISION_SQRT = 2.0
DEFAULT_MIN_SPP = 32
_DECISION_KEY = 0xA5A5A5A5   # flips bits of every byte of the low 32, which key the pixel sequences


def decisions(t):
    """How many of the first t passes (int or int array) are decision passes (module docstring)."""
    t = np.asarray(t)
    return np.floor(np.minimum(t / DECISION_SHARE, DECISION_SQRT * np.sqrt(t))).astype(np.int64)


def decision_seed(seed: int) -> int:
    """The seed of the decision stream: a non-negative integer whose chunk streams and pixel
    sequence scrambles (renderer/sampling.py pixel_sequence, keyed by its low 32 bits) differ from
    ``seed``'s."""
    return int(seed) ^ _DECISION_KEY


def adaptive_settings(opt, settings) -> tuple[float, int]:
    """(noise threshold, min spp) of a render: each from the options where given, else from the
    RenderSettings (IllumRenderSettingsAPI, renderer/usd/estimator_api.py read_adaptive), else
    off / DEFAULT_MIN_SPP. A threshold of 0 is off."""
    threshold = opt.noise_threshold if opt.noise_threshold is not None else settings.noise_threshold
    min_spp = opt.adaptive_min_spp or settings.adaptive_min_spp or DEFAULT_MIN_SPP
    return float(threshold or 0.0), int(min_spp)


def check_mode(mode: str, where: str) -> None:
    """SettingsError unless a film of pixel filter ``mode`` (set by ``where``) can be sampled
    adaptively (module docstring)."""
    if mode != "importance":
        raise SettingsError(f"adaptive sampling (a noise threshold) needs --pixel-filter-mode importance, but {where} "
                            f"sets {mode}: a splatted pixel mixes its neighbours' samples, and where their sample "
                            "counts differ it would weigh them by their sample density",
                            attribute="pixel_filter_mode")


class Adaptive:
    """The state of an adaptive render (module docstring): the decision film, which pixels are
    still active, and how many samples each traced.

    film: the beauty (image) film; threshold: T; min_spp: samples before a pixel may stop; seed:
    the image stream's seed (the decision stream's is decision_seed(seed)). A resumed film's
    image samples count toward its pixels' totals; its decisions start afresh.
    """

    def __init__(self, film: Film, threshold: float, min_spp: int, seed: int):
        self.threshold, self.min_spp = float(threshold), int(min_spp)
        self.seed = decision_seed(seed)
        self.decision = Film(film.width, film.height, film.window)
        self.active = np.ones(film.count.size, dtype=bool)
        self.stopped_at = np.zeros(film.count.size, dtype=np.int64)   # total samples at the stop, 0: never
        self.decision_passes = 0
        self._spread = self._mu = None

    @staticmethod
    def is_decision_pass(t: int) -> bool:
        """Whether render pass t (counting from 0) is a decision pass."""
        return bool(decisions(t + 1) > decisions(t))

    def rows(self) -> np.ndarray | None:
        """(n,) int64 flat data-window pixels still active, None while every pixel is (the
        integrator's full pass: the uniform render's streams exactly)."""
        return None if self.active.all() else np.flatnonzero(self.active)

    def count(self, film: Film) -> np.ndarray:
        """(h, w) int64 camera samples traced in each pixel, both streams (the sampleCount pass)."""
        return film.count + self.decision.count

    def decision_pass(self, integrator, rows) -> None:
        """Trace one decision sample in each pixel of rows (None: all)."""
        integrator.render_pass(self.decision, self.decision_passes, rows=rows, seed=self.seed)
        self.decision_passes += 1
        self._spread = None

    def _decision_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """(spread, mu), flat (h w,): sum_c w_c s_c and sum_c w_c mu_c of the decision samples
        (module docstring); spread is inf where fewer than two decision samples were taken. Kept
        until the next decision pass: between them only n_B changes."""
        if self._spread is None:
            d = self.decision
            n_d = d.count[:, :, None].astype(np.float64)
            spread = np.sqrt(d.variance_of_mean() * n_d) @ REC709_LUMINANCE
            self._spread = np.where(d.count >= 2, spread, np.inf).reshape(-1)
            self._mu = ((d.sum / np.maximum(n_d, 1.0)) @ REC709_LUMINANCE).reshape(-1)
        return self._spread, self._mu

    def relative_error(self, film: Film, pixels: np.ndarray | None = None) -> np.ndarray:
        """The rule's relative standard error of the image mean of each flat pixel (all, or
        ``pixels``) (module docstring), estimated from its decision samples: inf where there is
        nothing to estimate it from yet or where the mean luminance is not positive while the
        samples vary."""
        spread, mu = self._decision_moments()
        n_b = film.count.reshape(-1)
        if pixels is not None:
            spread, mu, n_b = spread[pixels], mu[pixels], n_b[pixels]
        se = spread / np.sqrt(np.maximum(n_b, 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(se == 0.0, 0.0, np.where(mu > 0.0, se / mu, np.inf))

    def update(self, film: Film) -> int:
        """Stop the active pixels that the rule lets stop; returns how many are still active."""
        pixels = np.flatnonzero(self.active)
        total = self.count(film).reshape(-1)[pixels]
        stop = (total >= self.min_spp) & (self.relative_error(film, pixels) < self.threshold)
        self.stopped_at[pixels[stop]] = total[stop]
        self.active[pixels[stop]] = False
        return int(pixels.size - stop.sum())

    def stats(self, film: Film) -> dict:
        """What the render's statistics record about the adaptive sampling."""
        total = self.count(film)
        n = max(total.size, 1)
        return {"noise_threshold": self.threshold, "min_spp": self.min_spp,
                "rule": "a pixel stops once its relative standard error of the mean luminance, estimated from "
                        "decision samples kept out of the image (floor(min(t / 4, 2 sqrt(t))) of its first t), "
                        "is below the threshold",
                "pixels_stopped": int((~self.active).sum()), "pixels": int(total.size),
                "samples_per_pixel": {"min": int(total.min()) if total.size else 0,
                                      "max": int(total.max()) if total.size else 0,
                                      "mean": float(total.sum() / n)},
                "image_samples_per_pixel": float(film.count.sum() / n),
                "decision_samples_per_pixel": float(self.decision.count.sum() / n)}
