"""illum: a USD-native path tracer (see README.md).

Importing the package registers illum's USD schemas (``_register_schemas``).

Importing the package sets two process-wide code-generation options before any kernel compiles:
on CPUs with AVX-512 that run it at full clock, the compiled kernels' vectorised loops use
512-bit registers (8 doubles) instead of LLVM's default 256 for Intel server parts, and LLVM's
loop vectoriser interleaves two vectors per iteration. The fast path's vertex passes are long
chains of dependent square roots and divisions, too long for the core to overlap iterations on
its own; two independent chains per iteration (32 vector registers leave room for them) hide
part of that latency. Together they make the vertex kernel ~20% faster per row
(bench/results.md). ``ILLUM_VECTOR_WIDTH`` chooses: ``auto`` (the default: 512 where AVX-512
is present, except the Skylake-SP family, whose clock drops under 512-bit work), ``512`` or
``256`` (LLVM's defaults, no interleaving). numba's own ``NUMBA_CPU_FEATURES``, when set, wins.
numba keys its on-disk cache on the target features string, so code compiled one way is never
loaded the other way; the interleaving, an LLVM option rather than a feature, is recorded in
that string too, by a tuning feature that is off on these CPUs anyway (``-prefer-128-bit``).
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
    # -prefer-128-bit: a no-op here (no AVX-512 CPU prefers 128-bit vectors) that marks code
    # compiled with _INTERLEAVE in numba's cache key (the module docstring).
    return features + ",-prefer-256-bit,-prefer-128-bit"


# Vectors per iteration of LLVM's loop vectoriser in the 512-bit mode (its cost model picks 1
# for the vertex passes' long loop bodies).
_INTERLEAVE = 2


def _configure_numba() -> None:
    from numba.core import config

    if config.CPU_FEATURES is not None:
        return  # NUMBA_CPU_FEATURES: the user's choice
    import llvmlite.binding as ll
    from numba.core.codegen import get_host_cpu_features

    cpu = config.CPU_NAME or ll.get_host_cpu_name()
    mode = os.environ.get("ILLUM_VECTOR_WIDTH", "auto").strip().lower()
    try:
        feats = _vector_width_features(mode, cpu, get_host_cpu_features())
    except ValueError as exc:
        # A performance setting: say what is wrong and render anyway, with the default.
        import warnings

        warnings.warn(f"{exc}; using auto", RuntimeWarning, stacklevel=3)
        feats = _vector_width_features("auto", cpu, get_host_cpu_features())
    if feats is not None:
        config.CPU_FEATURES = feats
        ll.set_option("illum", f"-force-vector-interleave={_INTERLEAVE}")


_configure_numba()


def _register_schemas() -> None:
    """Make USD know illum's schemas (usd_schemas: IllumLightAPI, IllumRenderSettingsAPI) for
    any stage this process opens, including the caller's own pxr code after ``import renderer``.

    USD must learn a schema plugin before its schema registry is first used. When pxr is not
    loaded yet, the plugin directory is put on PXR_PLUGINPATH_NAME, which USD reads when its
    plugin registry starts (so ``import renderer`` does not load pxr); when it is, the plugin
    is registered at once (``usd_schemas.register``).
    """
    import sys
    from importlib.util import find_spec

    if "pxr" in sys.modules:
        import usd_schemas  # noqa: F401  (registers on import)

        return
    spec = find_spec("usd_schemas")
    if spec is None or not spec.submodule_search_locations:
        return
    plugin_dir = os.path.abspath(list(spec.submodule_search_locations)[0])
    paths = [p for p in os.environ.get("PXR_PLUGINPATH_NAME", "").split(os.pathsep) if p]
    if plugin_dir not in paths:
        os.environ["PXR_PLUGINPATH_NAME"] = os.pathsep.join([plugin_dir, *paths])


_register_schemas()
