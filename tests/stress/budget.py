"""Work budgets of the stress suite under the two hypothesis profiles (see tests/conftest.py).

``make test`` loads the ``default`` profile: few examples and small sample counts, so the
whole stress suite stays within ~90 s on 2 cores. ``make stress`` loads ``long``
(ILLUM_HYPOTHESIS_PROFILE=long) and runs the slow-marked tests with many examples.
"""

from __future__ import annotations

import os

from hypothesis import Phase, settings

LONG = os.environ.get("ILLUM_HYPOTHESIS_PROFILE", "default") == "long"


# Shrinking replays a failing example hundreds of times; for render- and estimator-sized
# examples that takes minutes, so the stress tests report the first failing example as found
# (its description is in the assertion message) instead of a minimal one.
NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate, Phase.target)


def examples(default: int, long: int) -> settings:
    """A hypothesis settings decorator with ``default`` examples (or ``long`` under the long
    profile), without shrinking."""
    return settings(max_examples=long if LONG else default, phases=NO_SHRINK)


def size(default: int, long: int) -> int:
    """A sample count: ``default`` normally, ``long`` under the long profile."""
    return long if LONG else default
