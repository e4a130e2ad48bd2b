"""A session-wide record of the stress cases run and the largest errors seen.

Every stress check calls ``note(name, error, case)`` (error: a non-negative number, the
quantity that the check bounds; case: a short description to replay it). At the end of the
pytest session ``tests/stress/conftest.py`` prints ``summary_lines()``; ``report.py`` prints
the same table after its own run.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field


@dataclass
class Entry:
    cases: int = 0
    max_error: float = 0.0
    worst: str = ""
    failures: int = field(default=0)


_LOCK = threading.Lock()
RECORD: dict[str, Entry] = {}


def count(name: str, n: int = 1) -> None:
    """Count n cases of ``name`` that have no error measure (pass/fail checks)."""
    with _LOCK:
        RECORD.setdefault(name, Entry()).cases += n


def note(name: str, error: float, case: str = "") -> None:
    """Record one case of check ``name`` with its error (NaN/inf count as failures)."""
    with _LOCK:
        e = RECORD.setdefault(name, Entry())
        e.cases += 1
        err = float(error)
        if not math.isfinite(err):
            e.failures += 1
            e.worst = case
            e.max_error = math.inf
        elif err > e.max_error:
            e.max_error = err
            e.worst = case


def summary_lines() -> list[str]:
    with _LOCK:
        items = sorted(RECORD.items())
    if not items:
        return []
    total = sum(e.cases for _, e in items)
    out = [f"stress: {total} cases in {len(items)} checks"]
    for name, e in items:
        line = f"  {name:<44} cases {e.cases:>7}   max {e.max_error:.3g}"
        if e.worst and e.max_error > 0:
            line += f"   worst: {e.worst}"
        out.append(line)
    return out


def reset() -> None:
    with _LOCK:
        RECORD.clear()
