"""Tracing from compiled code: native Embree single rays and packets against embreex batches.

For every stage, three batches of float32 rays (renderer.bench.raw_ray_batches plus shadow rays):
* camera: the camera's rays over the frame (several per pixel, >= --rays rays);
* bounce: one cosine-distributed ray from each camera hit (closest hit);
* shadow: from each camera hit toward a uniform random point of the scene's bounding box, ending
  just short of it (occlusion).
Each batch is traced by
* native-1: a numba nogil loop calling rtcIntersect1 / rtcOccluded1 per ray (Accel, backend native);
* native-8 / native-16: the same loop filling SOA packets for rtcIntersect8/16, rtcOccluded8/16;
* embreex: embreex's batch calls (Accel, backend embreex);
all through ``Accel.intersect_prepared`` / ``occluded_prepared`` (float32 in, no conversions), and
``api``: the float64 ``Accel.intersect`` / ``occluded`` that the integrators call, native and embreex.
1 and 2 threads (the Accel's pool over chunks). The variants run alternately, round after round
(the machine is shared), and the table gives the median Mrays/s and each variant's ratio to
embreex within the same run. Every variant's hits are checked against embreex's (prim identical,
max |dt|; occlusion identical).

    PYTHONPATH=. .venv/bin/python bench/bench_embree_native.py [--stages stages/*.usda ...] [--rays 131072]
        [--rounds 7] [--threads 1 2] [--out bench/results/embree_native]
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

VARIANTS = ("native-1", "native-8", "native-16", "embreex")


def stage_batches(stage: str, rays: int, seed: int = 0):
    """(accel-building triangles, {"camera": (o, d, t), "bounce": ..., "shadow": ...}): float32 rays."""
    from renderer.bench import raw_ray_batches
    from renderer.camera import Camera
    from renderer.geometry import offset_origin
    from renderer.scene import build_scene
    from renderer.usd import load_stage

    desc = load_stage(stage)
    w, h = 128, 128
    scene = build_scene(desc, threads=2)
    try:
        tris = scene.geometry.vertices
        cam = Camera(scene.desc.camera, w, h, desc.settings.pixel_aspect_ratio, desc.settings.aspect_ratio_conform_policy)
        b = raw_ray_batches(scene, cam, w, h, seed, min_rays=rays)
        o_cam, d_cam = b["camera"]
        hits = scene.accel.intersect(o_cam, d_cam)
        hit = hits.hit
        p = o_cam[hit] + d_cam[hit] * hits.t[hit][:, None]
        ng = scene.geometry.face_normal[hits.prim[hit]]
        rng = np.random.default_rng(seed + 1)
        lo, hi = scene.accel.bounds
        q = lo + rng.random(p.shape) * (hi - lo)
        to_q = q - p
        dist = np.linalg.norm(to_q, axis=1)
        wi = to_q / np.maximum(dist, 1e-30)[:, None]
        ng = np.where((np.sum(ng * wi, axis=1) < 0.0)[:, None], -ng, ng)
        o_s = offset_origin(p, ng, wi, scene.accel.ray_epsilon(p, hits.prim[hit]))
        t_s = np.linalg.norm(q - o_s, axis=1) * (1 - 1e-4)
    finally:
        scene.close()
    inf = np.full(o_cam.shape[0], 1e37)
    out = {"camera": (o_cam, d_cam, inf), "bounce": (*b["bounce"], np.full(b["bounce"][0].shape[0], 1e37)),
           "shadow": (o_s, wi, t_s)}
    f32 = {k: tuple(np.ascontiguousarray(x, dtype=np.float32) for x in v) for k, v in out.items()}
    return tris, out, f32


def run_variant(accel, variant: str, kind: str, o32, d32, t32):
    """Trace one batch; returns (seconds, answer) with answer prim/t for closest hits, bool for shadow."""
    width = int(variant.split("-")[1]) if variant.startswith("native") else 1
    t = t32.copy()
    t0 = time.perf_counter()
    if kind == "shadow":
        ans = accel.occluded_prepared(o32, d32, t, width=width)
    else:
        prim, _, _ = accel.intersect_prepared(o32, d32, t, width=width)
        ans = (prim, t)
    return time.perf_counter() - t0, ans


def run_api(accel, kind: str, o, d, t):
    t0 = time.perf_counter()
    if kind == "shadow":
        accel.occluded(o, d, t)
    else:
        accel.intersect(o, d, t if kind != "camera" else None)
    return time.perf_counter() - t0


def bench_stage(stage: str, rays: int, rounds: int, threads: list[int]) -> list[dict]:
    from renderer.accel import Accel

    tris, b64, b32 = stage_batches(stage, rays)
    rows = []
    for th in threads:
        acc = {be: Accel(tris, threads=th, backend=be) for be in ("native", "embreex")}
        try:
            for kind, (o32, d32, t32) in b32.items():
                n = o32.shape[0]
                if n == 0:
                    continue
                secs = {v: [] for v in VARIANTS + ("api-native", "api-embreex")}
                answers = {}
                for r in range(rounds + 1):  # round 0 warms up (compiles) and is not counted
                    order = VARIANTS if r % 2 == 0 else VARIANTS[::-1]
                    for v in order:
                        s, ans = run_variant(acc["native" if v.startswith("native") else "embreex"], v, kind, o32, d32,
                                             t32)
                        answers[v] = ans
                        if r:
                            secs[v].append(s)
                    for be in ("native", "embreex") if r % 2 == 0 else ("embreex", "native"):
                        s = run_api(acc[be], kind, *b64[kind])
                        if r:
                            secs[f"api-{be}"].append(s)
                ref = answers["embreex"]
                row = {"stage": os.path.relpath(stage, ROOT), "threads": th, "batch": kind, "rays": n,
                       "triangles": int(tris.shape[0])}
                for v, ss in secs.items():
                    row[v] = n / float(np.median(ss)) / 1e6
                diffs = []
                for v in VARIANTS[:-1]:
                    a = answers[v]
                    if kind == "shadow":
                        diffs.append(f"{int(np.sum(a != ref))} differ")
                    else:
                        both = (a[0] >= 0) & (ref[0] >= 0)
                        dt = float(np.max(np.abs(a[1][both] - ref[1][both]))) if both.any() else 0.0
                        diffs.append(f"{int(np.sum(a[0] != ref[0]))} prim differ, max|dt| {dt:.1e}")
                row["agreement"] = "; ".join(sorted(set(diffs)))
                row["hit_fraction"] = float(np.mean(answers["embreex"] if kind == "shadow" else ref[0] >= 0))
                rows.append(row)
                print(f"{row['stage']:42s} {th}t {kind:6s} {n:7d} rays: " + "  ".join(
                    f"{v} {row[v]:6.2f}" for v in secs) + f"  [{row['agreement']}]", flush=True)
        finally:
            for a in acc.values():
                a.close()
    return rows


def write_md(rows: list[dict], path: str, cmd: str, load: tuple) -> None:
    from renderer.bench import machine_info

    info = machine_info()
    lines = ["# Native Embree from numba against embreex batches", "",
             f"Command: `{cmd}`", "",
             f"Machine: {info.get('cpu', '?')}, {os.cpu_count()} cores, shared with other agents' jobs "
             "(the variants run alternately, round after round; ratios are measured within one run). "
             f"1-minute load average {load[0]:.1f} at the start and {load[1]:.1f} at the end: with more runnable "
             "jobs than cores, a second thread finds no free core, so the 2-thread rows measure the route's cost "
             "under contention, not its scaling.", "",
             "Mrays/s (median of the rounds). `native-W`: numba nogil loop calling rtcIntersectW / rtcOccludedW "
             "(W = 1: single rays) on float32 batches; `embreex`: its batch call on the same float32 rays; "
             "`api-*`: the float64 `Accel.intersect` / `occluded` the integrators call. Ratios are to `embreex` "
             "(or `api-embreex`) of the same row.", "",
             "| stage | thr | batch | rays | native-1 | native-8 | native-16 | embreex | n1/ex | n8/ex | n16/ex "
             "| api-native | api-embreex | api n/ex | agreement with embreex |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ex = r["embreex"]
        lines.append(f"| {r['stage']} | {r['threads']} | {r['batch']} | {r['rays']} | {r['native-1']:.2f} | "
                     f"{r['native-8']:.2f} | {r['native-16']:.2f} | {ex:.2f} | {r['native-1'] / ex:.2f} | "
                     f"{r['native-8'] / ex:.2f} | {r['native-16'] / ex:.2f} | {r['api-native']:.2f} | "
                     f"{r['api-embreex']:.2f} | {r['api-native'] / r['api-embreex']:.2f} | {r['agreement']} |")
    lines += ["", "## Summary (geometric means of the ratios over stages and batches)", "",
              "| threads | n1/ex | n8/ex | n16/ex | api n/ex | native-1 2t/1t |", "|---|---|---|---|---|---|"]

    def gm(x):
        return float(np.exp(np.mean(np.log(x)))) if len(x) else float("nan")

    for th in sorted({r["threads"] for r in rows}):
        rs = [r for r in rows if r["threads"] == th]
        scale = ""
        if th != 1:
            one = {(r["stage"], r["batch"]): r for r in rows if r["threads"] == 1}
            sc = [r["native-1"] / one[(r["stage"], r["batch"])]["native-1"] for r in rs
                  if (r["stage"], r["batch"]) in one]
            scale = f"{gm(sc):.2f}"
        lines.append(f"| {th} | {gm([r['native-1'] / r['embreex'] for r in rs]):.2f} | "
                     f"{gm([r['native-8'] / r['embreex'] for r in rs]):.2f} | "
                     f"{gm([r['native-16'] / r['embreex'] for r in rs]):.2f} | "
                     f"{gm([r['api-native'] / r['api-embreex'] for r in rs]):.2f} | {scale} |")
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stages", nargs="+",
                    default=sorted(glob.glob(os.path.join(ROOT, "stages", "**", "*.usda"), recursive=True)))
    ap.add_argument("--rays", type=int, default=131072)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "embree_native"))
    a = ap.parse_args()
    rows = []
    load0 = os.getloadavg()[0]
    for st in a.stages:
        rows += bench_stage(st, a.rays, a.rounds, a.threads)
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_embree_native.py " + " ".join(sys.argv[1:])
    write_md(rows, os.path.join(a.out, "results.md"), cmd.strip(), (load0, os.getloadavg()[0]))
    print(f"wrote {os.path.join(a.out, 'results.md')}")


if __name__ == "__main__":
    main()
