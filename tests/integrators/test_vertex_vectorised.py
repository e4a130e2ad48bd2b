"""The fast path's vectorised loops (the vertex passes, the rect light's batch sampler) stay
vectorised. (The branch-free sin, cos and atan they rely on: tests/core/test_vmath.py.)

The passes (renderer/integrators/_vertex_kernels.py) are correct by the fast-path tests (they
z-test the fast path against the general path and render stages with both); what those cannot
see is a change that silently turns a pass back into scalar code, ~2x slower per row. Any branch
around work, a libm call, an exception check, a helper taking arrays inlined by numba, or a
runtime row stride does that (the module docstring lists them)."""

from __future__ import annotations

import platform
import re

import numpy as np
import pytest
from numba import njit

import renderer.integrators._vertex_kernels as vk
from renderer.kernels.lights import rect_sample_batch_kernel


def _has_avx2() -> bool:
    try:
        with open("/proc/cpuinfo") as fh:
            return " avx2" in fh.read()
    except OSError:
        return False


def _uncached(dispatcher, pipeline_class=vk._NoAliasCompiler):
    """The same function compiled with the same options, uncached (numba shows no assembly for
    cached code), through the same pipeline (the passes' noalias one by default)."""
    opts = {k: v for k, v in dispatcher.targetoptions.items() if k not in ("cache", "nopython")}
    if pipeline_class is not None:
        opts["pipeline_class"] = pipeline_class
    return njit(**opts)(dispatcher.py_func)


def _surface_args(n=8):
    """Arguments of _surface_pass with the dtypes FastPath passes (one triangle, one material)."""
    rng = np.random.default_rng(1)
    S = np.zeros((n, vk.NS))
    S[:, vk.B:vk.B + 3] = 1.0
    S[:, vk.D + 2] = -1.0
    Pm = np.zeros((1, 22))
    Pm[0, vk.ALPHA] = 0.5
    verts = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    return (0, n, np.zeros(n, np.int32), np.full(n, 0.25, np.float32), np.full(n, 0.25, np.float32), S,
            rng.random((6, n)), np.zeros(n, np.int64), Pm, np.zeros(0, np.int64), verts, np.array([[0.0, 0.0, 1.0]]),
            np.repeat(np.array([[[0.0, 0.0, 1.0]]]), 3, axis=1), np.zeros(1, np.int64), np.ones(1), 3, 1e-6, 1e-3,
            1e-9, np.empty(vk.NW * vk.BLK))


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64") or not _has_avx2(),
                    reason="checks x86 AVX packed instructions")
@pytest.mark.parametrize("which", ["surface", "light"])
def test_vertex_pass_loop_is_vectorised(which):
    args = _surface_args()
    if which == "surface":
        kernel = _uncached(vk._surface_pass)
        kernel(*args)
    else:
        vk._surface_pass(*args)
        kernel = _uncached(vk._light_pass)
        smp = np.zeros((5, 8))
        smp[2] = 1.0
        smp[3:5] = 1.0
        kernel(0, 8, smp, False, 1.0, 1.0, 1.0, False, True, args[5], args[-1], args[8], np.empty(4 * vk.BLK))
    asm = "\n".join(kernel.inspect_asm().values())
    # Packed double square roots on ymm/zmm registers come only from the loop vectoriser (the SLP
    # vectoriser pairs scalar code on xmm at most).
    assert re.search(r"vsqrtpd\s+%[yz]mm", asm), f"_{which}_pass's loop is no longer vectorised"



@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64") or not _has_avx2(),
                    reason="checks x86 AVX packed instructions")
def test_rect_batch_sampler_is_vectorised_without_libm_calls():
    """The rect light's batch sampler (FastPath's light samples) runs packed through: its atan,
    sin and cos are vmath's polynomials, so the loop has no libm call left to run lane by lane."""
    kernel = _uncached(rect_sample_batch_kernel, pipeline_class=None)
    rng = np.random.default_rng(2)
    n = 64
    p = np.ascontiguousarray(np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), np.full(n, -1.0)]))
    out = np.empty((5, n))
    kernel(p, rng.random((2, n)), 0, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0),
           (0.0, 1.0, 0.0), 1.0, 1.0, (0.0, 0.0, -1.0), 1.0, True, 1e-4, 0.99999, out)
    assert np.all(out[4] > 0.0)
    asm = "\n".join(kernel.inspect_asm().values())
    assert re.search(r"vsqrtpd\s+%[yz]mm", asm), "rect_sample_batch_kernel's loop is no longer vectorised"
    # numba calls libm through an address it loads first (movabsq $atan, %rax; callq *%rax).
    libm = set(re.findall(r"\$(\w*(?:atan|sin|cos)\w*)", asm))
    assert not libm, f"rect_sample_batch_kernel calls libm's {sorted(libm)} (one lane at a time)"
