"""Suite-wide configuration.

Hypothesis profiles (property-based tests, e.g. tests/stress):

* ``default`` -- what ``make test`` runs: derandomized (the same examples on every run, so the
  suite is reproducible), no per-example deadline (renders and numba compiles vary in time),
  and a modest number of examples so the whole suite stays within its time budget;
* ``long`` -- what ``make stress`` runs (``ILLUM_HYPOTHESIS_PROFILE=long pytest -m 'slow or heavy'``):
  many more examples, still derandomized so a failure can be replayed.

Markers: ``slow`` tests run in every suite, with the reduced budget of the default profile;
``heavy`` tests are the full forms (cold compiles, large sample counts) of tests whose reduced
form runs by default, and are skipped unless the ``-m`` expression names them (``make stress``)
or ILLUM_SLOW=1 is set, so that ``make test`` stays within its ~10-minute budget.

The profile is chosen by the ILLUM_HYPOTHESIS_PROFILE environment variable (default: default).
"""

from __future__ import annotations

import os

import pytest
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


def pytest_collection_modifyitems(config, items):
    """Skip the ``heavy`` tests unless asked for (module docstring)."""
    markexpr = config.getoption("-m") or ""
    if "heavy" in markexpr or "slow" in markexpr or os.environ.get("ILLUM_SLOW"):
        return
    skip = pytest.mark.skip(reason="heavy: its reduced form runs by default; run with `make stress` or ILLUM_SLOW=1")
    for item in items:
        if "heavy" in item.keywords:
            item.add_marker(skip)
