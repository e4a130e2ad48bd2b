"""Print the maximum error of renderer.lights.analytic against the quadrature references.

    .venv/bin/python tests/analytic/report_errors.py [N_PER_KIND] [SEED]

Draws N random configurations per light kind (rect, disk, polygon, ellipse, sphere; all
placement/normal modes, scales 1e-6..1e6, distance/size ratios 1e-12..1e12; see configs.py),
compares with reference.py and prints, per kind, the max relative error over the
well-conditioned configurations and the max |error|/tolerance over all (harness.py).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    __package__ = "tests.analytic"

from tests.analytic import harness  # noqa: E402
from tests.analytic.configs import N_MODES, N_PERMS, N_UNIFORMS, P_MODES, S_MODES, planar_config, sphere_config  # noqa: E402


def main(n: int = 2000, seed: int = 12345) -> int:
    rng = np.random.default_rng(seed)
    failures = []
    t0 = time.perf_counter()
    for kind in ("rect", "disk", "polygon", "ellipse"):
        for _ in range(n):
            k = int(rng.integers(3, 8))
            cfg = planar_config(kind, int(rng.integers(len(P_MODES))), int(rng.integers(len(N_MODES))),
                                int(rng.integers(N_PERMS)), rng.random(N_UNIFORMS), k=k)
            ok, msg = harness.run_planar(cfg)
            if not ok:
                failures.append(msg)
    for _ in range(n):
        cfg = sphere_config(int(rng.integers(len(S_MODES))), rng.random(N_UNIFORMS))
        ok, msg = harness.run_sphere(cfg)
        if not ok:
            failures.append(msg)
    dt = time.perf_counter() - t0
    print(f"analytic integrals vs quadrature, {n} configurations per kind, seed {seed} ({dt:.1f} s)")
    for line in harness.summary_lines():
        print("  " + line)
    print(f"  acceptance: |err| <= {harness.REL_TOL:g}*G_ref + {harness.FLOOR:g}*Omega + {harness.POS:g}*eps*X*B "
          f"(harness.py); failures: {len(failures)}")
    for msg in failures[:20]:
        print("   FAIL " + msg)
    return 1 if failures else 0


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    sys.exit(main(*args))
