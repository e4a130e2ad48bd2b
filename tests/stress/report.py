"""Run the stress checks on N random configurations and print the case counts and largest errors.

    .venv/bin/python tests/stress/report.py [N] [SEED]

Draws N LightCases (cases.random_case: rect/disk/sphere lights of size 1e-6..1e6, points
1e-4..1e7 away in every placement) and runs on each the sample_li/pdf_li contract, the
irradiance-vs-quadrature check, and every estimator (finite, sign, shadow-ray count); on the
moderate ones (0.1..20 light sizes away) also the Lambert z-test against the quadrature.
Failures are listed (up to 20) instead of stopping the run. Exit status 1 if any check failed.
The pytest form of the same checks is tests/stress/test_*.py (``make stress`` for many cases).
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    __package__ = "tests.stress"

from tests.stress.cases import check_irradiance, check_sampling, random_case  # noqa: E402
from tests.stress.estimator_cases import ALL, NON_NEGATIVE, UNBIASED, reference_lambert, rig_for, z_score  # noqa: E402
from tests.stress.record import note, summary_lines  # noqa: E402

Z_MAX = 5.3


def estimator_checks(case, rng) -> None:
    rig = rig_for(case, 64, bsdf="preview" if rng.random() < 0.5 else "lambert",
                  clip_dir=rng.normal(size=3) if rng.random() < 0.5 else None, wo_tilt=0.9 * rng.random())
    for token, alpha, heuristic, n_min in ALL:
        for N in sorted({n_min, 2}):
            Ld, reported, traced = rig.estimate(token, N, alpha, heuristic, seed=N)
            assert np.all(np.isfinite(Ld)), f"{token}/{alpha}: non-finite estimate: {case.label()}"
            if token in NON_NEGATIVE:
                assert np.all(Ld >= 0.0), f"{token}: negative estimate: {case.label()}"
            assert reported == traced, f"{token}: reported {reported} rays, traced {traced}: {case.label()}"
    note("estimators finite at extremes (cases)", 0.0)


def unbiased_checks(case, rng, n=4000) -> None:
    case = replace(case, placement=("free", "near")[rng.integers(2)], dist=case.size * 10.0 ** rng.uniform(-1, 1.3))
    if case.build()[5] <= 1e-3 * case.size:
        return
    clip = None if case.kind == "sphere" or rng.random() < 0.5 else rng.normal(size=3)
    rig = rig_for(case, n, rho=0.7, clip_dir=clip, wo_tilt=0.9 * rng.random())
    ref = reference_lambert(case, rig, 0.7)
    for token, alpha, heuristic, n_min in UNBIASED:
        N = max(n_min, 2)
        Ld, _, _ = rig.estimate(token, N, alpha, heuristic, seed=17 + N)
        if token == "bsdfSampling" and ref > 0 and n * N * ref / 0.7 < 300:
            continue
        z = z_score(Ld[:, 0], ref)
        note(f"estimator |z| vs quadrature ({token}/{alpha})", abs(z), case.label())
        assert abs(z) < Z_MAX, f"{token}/{alpha}: z = {z:.2f}: {case.label()}"


def main(n: int = 300, seed: int = 2024) -> int:
    rng = np.random.default_rng(seed)
    failures: list[str] = []
    t0 = time.perf_counter()
    for _ in range(n):
        case = random_case(rng)
        for check in (check_sampling, check_irradiance, lambda c: estimator_checks(c, rng),
                      lambda c: unbiased_checks(c, rng)):
            try:
                check(case)
            except AssertionError as exc:
                failures.append(str(exc).splitlines()[0])
    dt = time.perf_counter() - t0
    print(f"illum stress report: {n} random configurations, seed {seed} ({dt:.1f} s)")
    for line in summary_lines():
        print(line)
    print(f"failures: {len(failures)}")
    for msg in failures[:20]:
        print("  FAIL " + msg)
    return 1 if failures else 0


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:3]]
    sys.exit(main(*args))
