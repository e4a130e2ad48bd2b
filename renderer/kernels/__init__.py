"""numba kernels for the per-point hot paths (lights; the BSDF kernels live in renderer.bsdfs).

Conventions shared by every kernel here:

* ``@njit(cache=True, nogil=True)`` (fastmath stays off, numba's default): compiled once per
  machine (the cache sits in ``__pycache__``; a cold compile of all light kernels takes a few
  seconds, loading them from the cache a fraction of one), the GIL is released so the
  integrator's render threads run kernels concurrently, and IEEE semantics are kept so results
  match the numpy formulas they replace to rounding. Never ``parallel=True``: numba's threading
  layer is not safe to enter from several Python threads at once, and the integrator already
  parallelises over pixel chunks.
* One loop over rows with scalar maths: no (n,)-sized temporaries. The Python wrappers allocate
  the outputs and pass C-contiguous float64 / int64 arrays.
* Kernels never import numba functions or constants from other modules: numba's on-disk cache
  is keyed on the defining file only, so a kernel that inlined a function (or froze a global)
  from another file would silently keep a stale copy after that file changed. Tunable
  constants (thresholds) are passed in as arguments instead. The exception is a module that
  calls ``guard_cache`` (below) with the files it inlines from: the fused path vertex
  (renderer/integrators/_vertex_kernels.py), and the users of ``vmath`` (this package's
  vectorisable sin, cos and atan: kernels/lights.py, bsdfs/_preview_kernels.py).
"""

from __future__ import annotations

import hashlib
import os

from numba.core.compiler import Compiler

class NoAliasCompiler(Compiler):
    """numba's standard pipeline with every array argument's pointers marked ``noalias`` (numba's
    own ``Flags.noalias``, which @njit does not expose). Without it LLVM must assume a table read
    at a computed index (a triangle's vertices, a material row, the albedo tables) may alias the
    block state the loop writes, cannot bound that with a runtime check, and leaves the loop
    scalar. Only for kernels whose array arguments never share memory (the fast path's vertex passes,
    the camera's pinhole kernel): use as ``@njit(pipeline_class=NoAliasCompiler)``."""

    def __init__(self, typingctx, targetctx, library, args, return_type, flags, locals):
        flags = flags.copy()
        flags.noalias = True
        super().__init__(typingctx, targetctx, library, args, return_type, flags, locals)


_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def module_dispatchers(namespace: dict) -> list:
    """Every numba dispatcher defined in a module (pass its ``globals()``), for guard_cache."""
    from numba.core.registry import CPUDispatcher

    name = namespace.get("__name__")
    return [v for v in namespace.values() if isinstance(v, CPUDispatcher) and v.py_func.__module__ == name]


# The sources each guard_cache call named, by module: a module whose kernels call another
# module's kernels (their code is linked into the caller's cache) guards on those too.
GUARDED: dict[str, list[str]] = {}


def guarded_sources(*modules: str) -> list[str]:
    """The files the kernels of ``modules`` (dotted names of modules that called guard_cache)
    depend on: each module's own file and the sources its guard_cache named."""
    out: list[str] = []
    for m in modules:
        for rel in [m.replace(".", "/") + ".py", *GUARDED[m]]:
            if rel not in out:
                out.append(rel)
    return out


def guard_cache(module: str, dispatchers: list, sources: list[str]) -> None:
    """Let the kernels of ``module`` inline numba functions from the files ``sources`` (paths
    relative to the repository root) safely: numba keys a kernel's on-disk cache on its own
    file only, so when any of ``sources`` changed since the cache was written (a digest of
    their contents, stored next to the cache), the dispatchers' cached code is flushed and
    compiles afresh. Call it at the end of the module, after the kernels are defined."""
    GUARDED[module] = list(sources)
    h = hashlib.sha256()
    for rel in sources:
        with open(os.path.join(_ROOT, rel), "rb") as fh:
            h.update(rel.encode() + b"\0" + fh.read() + b"\0")
    digest = h.hexdigest()
    caches = [d._cache for d in dispatchers if getattr(d, "_cache", None) is not None
              and hasattr(d._cache, "_cache_path")]
    if not caches:
        return
    stamp = os.path.join(caches[0]._cache_path, f"{module.rsplit('.', 1)[-1]}.deps")
    try:
        with open(stamp) as fh:
            if fh.read().strip() == digest:
                return
    except OSError:
        pass
    for c in caches:
        c.flush()
    try:
        os.makedirs(os.path.dirname(stamp), exist_ok=True)
        with open(stamp, "w") as fh:
            fh.write(digest)
    except OSError:
        pass  # a read-only cache: the kernels compile in every process, still correct
