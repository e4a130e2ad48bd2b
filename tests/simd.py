"""Helpers for the tests that check a compiled loop stays vectorised (its assembly has packed
instructions): the skip marker for machines without AVX2, and the kernel compiled afresh (numba
shows no assembly for cached code)."""

from __future__ import annotations

import platform

import pytest
from numba import njit


def _has_avx2() -> bool:
    try:
        with open("/proc/cpuinfo") as fh:
            return " avx2" in fh.read()
    except OSError:
        return False


needs_avx2 = pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64") or not _has_avx2(),
                                reason="checks x86 AVX packed instructions")


def uncached(dispatcher, **extra):
    """The same function compiled with the same options (plus ``extra``, e.g. a pipeline_class),
    uncached, so its assembly can be inspected after a call."""
    opts = {k: v for k, v in dispatcher.targetoptions.items() if k not in ("cache", "nopython")}
    return njit(**{**opts, **extra})(dispatcher.py_func)


def assembly(kernel) -> str:
    """All the assembly of a called (compiled) kernel."""
    return "\n".join(kernel.inspect_asm().values())
