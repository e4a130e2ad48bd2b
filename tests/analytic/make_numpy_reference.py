"""Write tests/analytic/data/numpy_reference.npz: inputs and outputs of the numpy implementation
of renderer/lights/analytic.py as it was before the port to compiled row functions (commit
0332038), over randomised configurations of every light kind (test_compiled_rows.py compares the
compiled row functions against it).

    PYTHONPATH=$PWD .venv/bin/python tests/analytic/make_numpy_reference.py

The old module is read with ``git show 0332038:renderer/lights/analytic.py`` and imported from a
temporary file, so no second copy of the formulas lives in the tree. The configurations come from
configs.py (every placement and normal mode: grazing, in the plane, behind, near the rim or a
corner, far up to 1e12 sizes, normals straddling or tangent to the light; scales 1e-6..1e6), half
of them moved by a random rigid motion so that no axis is special.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))
    __package__ = "tests.analytic"

from tests.analytic.configs import (N_MODES, N_PERMS, N_UNIFORMS, P_MODES, S_MODES,  # noqa: E402
                                    planar_config, sphere_config)
from tests.analytic.test_properties import _random_rotation  # noqa: E402

OLD_COMMIT = "0332038"
OUT = Path(__file__).resolve().parent / "data" / "numpy_reference.npz"
N_PER_KIND = 800
SEED = 20261202


def old_module():
    src = subprocess.run(["git", "show", f"{OLD_COMMIT}:renderer/lights/analytic.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    tmp = Path(tempfile.mkdtemp()) / "analytic_numpy_0332038.py"
    tmp.write_text(src)
    spec = importlib.util.spec_from_file_location("analytic_numpy_0332038", tmp)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _motion(rng, cfg_scale):
    """(Q, T): identity for half of the rows, else a random rotation and a translation up to 100
    sizes (which rounds the world coordinates: the comparison sees the same rounded inputs)."""
    if rng.random() < 0.5:
        return np.eye(3), np.zeros(3)
    return _random_rotation(rng), rng.normal(size=3) * cfg_scale * 10.0 ** rng.uniform(-2, 2)


def planar_rows(kind, rng, n, k=4):
    rows = []
    for _ in range(n):
        cfg = planar_config(kind, int(rng.integers(len(P_MODES))), int(rng.integers(len(N_MODES))),
                            int(rng.integers(N_PERMS)), rng.random(N_UNIFORMS), k=k)
        Q, T = _motion(rng, cfg.scale)
        p, nrm, en = cfg.world()
        row = dict(p=Q @ p + T, nrm=Q @ nrm, en=Q @ en, scale=cfg.scale, mode=f"{cfg.p_mode}/{cfg.n_mode}")
        if kind == "rect":
            c, ex, ey = cfg.rect_world()
            row.update(c=Q @ c + T, ex=Q @ ex, ey=Q @ ey)
        elif kind == "disk":
            row.update(c=T.copy(), R=cfg.radius)
        elif kind == "ellipse":
            M = cfg.perm
            row.update(c=T.copy(), e1=Q @ (M @ np.array([cfg.radius, 0.0, 0.0])),
                       e2=Q @ (M @ np.array([0.0, cfg.radius_b, 0.0])))
        else:
            row.update(V=cfg.polygon_world() @ Q.T + T)
        rows.append(row)
    return {key: np.array([r[key] for r in rows]) for key in rows[0]}


def main():
    old = old_module()
    rng = np.random.default_rng(SEED)
    data = {}
    d = planar_rows("rect", rng, N_PER_KIND)
    d["G"] = old.projected_solid_angle_rect(d["p"], d["nrm"], d["c"], d["ex"], d["ey"], d["en"])
    data.update({f"rect_{k}": v for k, v in d.items()})
    d = planar_rows("disk", rng, N_PER_KIND)
    d["G"] = old.projected_solid_angle_disk(d["p"], d["nrm"], d["c"], d["en"], d["R"])
    data.update({f"disk_{k}": v for k, v in d.items()})
    d = planar_rows("ellipse", rng, N_PER_KIND)
    d["G"] = old.projected_solid_angle_ellipse(d["p"], d["nrm"], d["c"], d["e1"], d["e2"], d["en"])
    data.update({f"ellipse_{k}": v for k, v in d.items()})
    for k in (3, 5):                 # triangles (mesh lights) and pentagons, one- and two-sided
        d = planar_rows("polygon", rng, N_PER_KIND, k=k)
        d["G2"] = old.projected_solid_angle_polygon(d["p"], d["nrm"], d["V"])
        d["G1"] = old.projected_solid_angle_polygon(d["p"], d["nrm"], d["V"], e_n=d["en"])
        data.update({f"polygon{k}_{key}": v for key, v in d.items()})
    rows = []
    for _ in range(N_PER_KIND):
        cfg = sphere_config(int(rng.integers(len(S_MODES))), rng.random(N_UNIFORMS))
        Q, T = _motion(rng, cfg.r)
        rows.append((T, Q @ cfg.nrm, Q @ cfg.center + T, cfg.r, cfg.mode))
    data["sphere_p"] = np.array([r[0] for r in rows])
    data["sphere_nrm"] = np.array([r[1] for r in rows])
    data["sphere_c"] = np.array([r[2] for r in rows])
    data["sphere_R"] = np.array([r[3] for r in rows])
    data["sphere_mode"] = np.array([r[4] for r in rows])
    data["sphere_G"] = old.projected_solid_angle_sphere(data["sphere_p"], data["sphere_nrm"], data["sphere_c"],
                                                        data["sphere_R"])
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, **data)
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
