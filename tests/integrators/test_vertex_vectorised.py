"""The fast path's vectorised vertex passes stay vectorised. (The branch-free sin, cos and atan
they rely on: tests/core/test_vmath.py; the light samplers' loops: tests/lights/test_rect_batch.py.)

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


def _has_avx2() -> bool:
    try:
        with open("/proc/cpuinfo") as fh:
            return " avx2" in fh.read()
    except OSError:
        return False


def _uncached(dispatcher):
    """The same function compiled with the same options, uncached (numba shows no assembly for
    cached code), through the same noalias pipeline."""
    opts = {k: v for k, v in dispatcher.targetoptions.items() if k not in ("cache", "nopython")}
    return njit(pipeline_class=vk._NoAliasCompiler, **opts)(dispatcher.py_func)


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


