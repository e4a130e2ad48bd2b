"""Example counts for the hypothesis tests of tests/analytic.

ILLUM_HYPOTHESIS_PROFILE=long raises every count (the tests marked ``slow`` get the big
budget); the default profile keeps the whole package under ~1 minute while still drawing
more than 1000 configurations per light kind.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

PROFILE = os.environ.get("ILLUM_HYPOTHESIS_PROFILE", "default").strip().lower()
LONG = PROFILE == "long"


def n_examples(default: int, long: int) -> int:
    return long if LONG else default


def hyp_settings(default: int, long: int):
    """Reproducible settings: derandomized, no example database, no deadline."""
    return settings(max_examples=n_examples(default, long), deadline=None, derandomize=True,
                    database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])
