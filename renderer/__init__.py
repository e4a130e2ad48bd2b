"""illum: a USD-native path tracer (see README.md).

Importing the package sets one process-wide numba option before any kernel compiles: on CPUs
with AVX-512 that run it at full clock, the compiled kernels' vectorised loops use 512-bit
registers (8 doubles) instead of LLVM's default 256 for Intel server parts. The fast path's
vertex kernel runs ~15% faster per row with them (bench/results.md). ``ILLUM_VECTOR_WIDTH``
chooses: ``auto`` (the default: 512 where AVX-512 is present, except the Skylake-SP family,
whose clock drops under 512-bit work), ``512`` or ``256`` (LLVM's default). numba's own
``NUMBA_CPU_FEATURES``, when set, wins. numba keys its on-disk cache on the target features, so
code compiled for one width is never loaded for the other.
"""

from __future__ import annotations

import os

# LLVM CPU names whose AVX-512 units lower the core clock (licence-based down-clocking): LLVM's
# preference for 256-bit vectors exists for them.
_DOWNCLOCKING_AVX512 = ("skylake-avx512", "cascadelake", "cooperlake", "knl", "knm")


def _vector_width_features(mode: str, cpu: str, features: str) -> str | None:
    """The numba CPU feature string for ILLUM_VECTOR_WIDTH ``mode`` on host ``cpu`` with host
    ``features`` (LLVM's flattened +/- list), or None to keep numba's default."""
    if mode not in ("auto", "512", "256"):
        raise ValueError(f"ILLUM_VECTOR_WIDTH must be auto, 512 or 256, not {mode!r}")
    if mode == "256" or "+avx512f" not in features.split(","):
        return None
    if mode == "auto" and cpu in _DOWNCLOCKING_AVX512:
        return None
    return features + ",-prefer-256-bit"


def _configure_numba() -> None:
    from numba.core import config

    if config.CPU_FEATURES is not None:
        return  # NUMBA_CPU_FEATURES: the user's choice
    import llvmlite.binding as ll
    from numba.core.codegen import get_host_cpu_features

    cpu = config.CPU_NAME or ll.get_host_cpu_name()
    feats = _vector_width_features(os.environ.get("ILLUM_VECTOR_WIDTH", "auto").strip().lower(), cpu,
                                   get_host_cpu_features())
    if feats is not None:
        config.CPU_FEATURES = feats


_configure_numba()
