"""Suite-wide configuration.

Hypothesis profiles (property-based tests, e.g. tests/stress):

* ``default`` -- what ``make test`` runs: derandomized (the same examples on every run, so the
  suite is reproducible), no per-example deadline (renders and numba compiles vary in time),
  and a modest number of examples so the whole suite stays within its time budget;
* ``long`` -- what ``make stress`` runs (``ILLUM_HYPOTHESIS_PROFILE=long pytest -m slow``):
  many more examples, still derandomized so a failure can be replayed.

The profile is chosen by the ILLUM_HYPOTHESIS_PROFILE environment variable (default: default).
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "default",
    derandomize=True,
    deadline=None,
    max_examples=12,
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.register_profile(
    "long",
    derandomize=True,
    deadline=None,
    max_examples=400,
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.load_profile(os.environ.get("ILLUM_HYPOTHESIS_PROFILE", "default"))


# The renderer caches computed dome irradiance by content hash; keep the suite's cache out of
# the user's ~/.cache (one directory per test session, removed by pytest's tmp retention).
if "ILLUM_CACHE_DIR" not in os.environ:
    import tempfile

    os.environ["ILLUM_CACHE_DIR"] = tempfile.mkdtemp(prefix="illum-test-cache-")
