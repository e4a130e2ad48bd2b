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
  constants (thresholds) are passed in as arguments instead.
"""
