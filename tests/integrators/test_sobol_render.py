"""The default sampler (--sampler sobol: each pixel's own scrambled low-discrepancy numbers for
every bounce, renderer/kernels/sobol.py) renders the image --sampler independent renders, with
less noise. The sequence itself is tested in tests/core/test_sobol.py."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.render import RenderOptions, render
from tests.integrators.test_fast_path import Z_BLOCK, Z_MAX
from tests.stats import film_difference_z

# The rows' columns (continuation MIS on the Cornell box), the per-light estimators' own samples
# (the control variate with 4 samples and the 1/(N - 1) alpha, which needs the 4 samples of a
# pass independent), and the light BVH's 1D pick with emitter samples on the many-lights stage.
CASES = [
    ("cornell_box.usda", {}),
    ("talk/penumbra.usda", {"cv_alpha": {"": "averageVisibilityUnbiased"}}),
    ("instanced.usda", {"light_sampler": "bvh", "emitter_samples": 2}),
]


@pytest.mark.parametrize("stage,opt", CASES)
def test_sobol_renders_what_independent_numbers_render(stage, opt):
    """z per channel over the image and 16 blocks (filter importance sampling: independent
    pixels). The film's per-pixel variance assumes independent passes: for the stratified
    passes it overstates the error, so the comparison errs on the safe side."""
    common = dict(spp=64, resolution=(48, 36), max_depth=4, rr_depth=1, threads=1,
                  pixel_filter_mode="importance", **opt)
    lds = render(f"stages/{stage}", RenderOptions(seed=3, sampler="sobol", **common))
    iid = render(f"stages/{stage}", RenderOptions(seed=4, sampler="independent", **common))
    assert lds.stats["fast_path"] == "on" and lds.stats["sampler"] == "sobol"
    z, zs = film_difference_z(lds.film, iid.film)
    assert abs(z) < Z_MAX, f"whole image: sobol - independent = {z:.2f} sigma"
    assert max(abs(x) for x in zs) < Z_BLOCK, f"blocks: {np.round(zs, 2)}"


def _spread(stage, sampler, seeds=6, **opt):
    """Per-pixel variance (h, w, 3) of the image over seeds, and the seeds' mean image."""
    imgs = np.array([render(f"stages/{stage}", RenderOptions(seed=s, sampler=sampler, threads=1, **opt)).film.mean()
                     for s in range(seeds)], dtype=np.float64)
    return imgs.var(axis=0, ddof=1), imgs.mean(axis=0)


@pytest.mark.parametrize("stage,opt,gain", [
    # Direct light from the ceiling rect (continuation MIS: the rows' pairs): 1.9x measured.
    ("cornell_box.usda", {"max_depth": 1}, 1.4),
    # The disks' control variate with 4 samples a pass (the estimator's own pairs): 3.2x measured.
    ("talk/penumbra.usda", {"max_depth": 2}, 2.0),
])
def test_sobol_lowers_the_error(stage, opt, gain):
    """The relative variance over 6 seeds (each pixel's spread / (its value^2 + 0.01), the
    benchmarks' relMSE) falls by at least ``gain`` at 16 samples: the pixels' passes stratify.
    With 6 x 96 x 96 pixels the ratio's own noise is a few per cent."""
    common = dict(spp=16, resolution=(96, 96), **opt)
    v_iid, m_iid = _spread(stage, "independent", **common)
    v_lds, m_lds = _spread(stage, "sobol", **common)
    ref = 0.5 * (m_iid + m_lds)
    w = 1.0 / (ref ** 2 + 0.01)
    ratio = float((v_iid * w).mean() / (v_lds * w).mean())
    assert ratio > gain, f"{stage}: independent / sobol relative variance {ratio:.2f}"
