"""illum's two films (splat, filter importance sampling) against Mitsuba 3's own Gaussian film at equal time.

    PYTHONPATH=. .venv/bin/python bench/bench_film_mitsuba.py --mitsuba-python /work/scratch/mitsuba-venv/bin/python \
        [STAGES ...] [--res 256] [--budgets 2,8] [--seeds 2] [--out bench/results/film]

Per stage (default: the Cornell box and the textured lat-long dome ``stages/talk/dome.usda``, both
exportable to Mitsuba by bench_mitsuba.export_scene) three renderers, each scored against its *own*
converged render at its own filter:

* illum ``--pixel-filter-mode splat`` and ``importance``, Gaussian of radius ``--filter-width``
  (default 1.5 px: sigma = radius / 3 = 0.5 px, renderer/pixel_filter.py), ``max_depth`` D,
  the stage's own estimators, ``time_budget`` = the budget (in this process, after a warm-up);
* Mitsuba's ``mi.render`` out of the box: its sensor's ``hdrfilm`` with the ``gaussian`` rfilter
  (stddev 0.5 px, radius 4 stddev = 2 px; splatting), its ``independent`` sampler and ``path``
  integrator with ``max_depth`` D + 1 (it counts the camera segment). Mitsuba takes a sample
  count, not a time: spp is picked from the seconds per spp measured so far (a 1- and 4-spp
  probe, then every run), and the run's measured time is reported.

Mitsuba runs in its own Python (a scratch venv, never a dependency) as one long-lived
``mitsuba_side.py`` serve process, so the loaded scene and Dr.Jit's kernels stay warm and its runs
can alternate with illum's: for each seed and budget, the three renderers run back to back, in an
order rotated from one run to the next, so the shared machine's load changes hit all alike.

Like-for-like filter: Mitsuba's Gaussian cannot be truncated at 3 sigma nor illum's at 4, so the
sigma is matched (0.5 px): illum radius 1.5 px. Effective samples averaged per pixel and per spp,
(int f)^2 / int f^2 in 2-D: Mitsuba 3.13, illum 2.97 (illum radius 2.0 px would give sigma 0.67 px
and 5.28, a blurrier image). The filters' standard deviations: 0.499 and 0.479 px.

Error: relMSE = mean((x - ref)^2 / (ref^2 + 0.01)) over pixels and channels. Each reference's own
expected relMSE (its noise floor: illum's ``film.variance_of_mean()``, Mitsuba's spread between
its repeated reference renders) is reported and subtracted (x and ref are independent, so the
expected relMSE is the sum). Equal time: corrected relMSE x measured seconds / budget (relMSE
falls as 1/t), averaged over seeds; its ratio to Mitsuba's is the figure reported. CPU seconds are
process CPU time (all threads) of the process that rendered (illum: this one; Mitsuba: the server).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_mitsuba import EPS_REL, SIDE, eligibility, export_scene, relmse  # noqa: E402

from renderer.render import RenderOptions, render  # noqa: E402
from renderer.usd import load_stage  # noqa: E402

STAGES = ("stages/cornell_box.usda", "stages/talk/dome.usda")
RENDERERS = ("illum splat", "illum importance", "mitsuba gaussian film")


class MitsubaServer:
    """mitsuba_side.py in serve mode: one render task per call, the scene and kernels kept warm."""

    def __init__(self, python: str, npz: str, variant: str, threads: int, work: str):
        self.work = work
        job = os.path.join(work, "serve_job.json")
        with open(job, "w") as fh:
            json.dump({"scene": npz, "variant": variant, "threads": threads, "serve": True}, fh)
        self.proc = subprocess.Popen([python, SIDE, job], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, bufsize=1)
        self.banner = self._line()
        self.n = 0

    def _line(self) -> str:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"mitsuba_side serve exited with {self.proc.wait()}")
        return line.strip()

    def render(self, **task) -> dict:
        self.n += 1
        task = {"kind": "render", "out": os.path.join(self.work, f"m{self.n}.npz"), **task}
        self.proc.stdin.write(json.dumps(task) + "\n")
        self.proc.stdin.flush()
        line = self._line()
        if not line.startswith("ok"):
            raise RuntimeError(f"mitsuba_side: {line}")
        d = np.load(task["out"])
        return {k: d[k] for k in d.files}

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


class MitsubaClock:
    """Mitsuba takes a sample count, not a time: its seconds per spp, measured on a serve process
    (a warm-up render, which compiles Dr.Jit's kernels, then 1- and 4-spp renders, three each), and
    kept up to date by every timed run so that the next spp follows the shared machine's load.
    ``mx``: the render task's integrator settings (max_depth, rr_depth)."""

    def __init__(self, srv: MitsubaServer, mx: dict):
        self.srv, self.mx = srv, mx
        w = srv.render(spp=1, seed=5, repeat=1, warmup=True, **mx)
        p1 = srv.render(spp=1, seed=7, repeat=3, warmup=False, **mx)
        p4 = srv.render(spp=4, seed=9, repeat=3, warmup=False, **mx)
        self.t1, self.t4 = float(np.median(p1["seconds"])), float(np.median(p4["seconds"]))
        self.per_spp = max((self.t4 - self.t1) / 3.0, 1e-4)
        self.fixed = max(self.t1 - self.per_spp, 0.0)
        self.warmup_s = float(w["warmup_seconds"])

    def probe(self) -> dict:
        return {"warmup_s": self.warmup_s, "t1": self.t1, "t4": self.t4, "fixed": self.fixed}

    def spp_for(self, seconds: float) -> int:
        return max(1, int(round((seconds - self.fixed) / self.per_spp)))

    def run(self, budget: float, seed: int) -> tuple[np.ndarray, float, float, int]:
        """One timed ``mi.render`` of about ``budget`` seconds: (image, wall s, CPU s, spp). The
        seconds per spp then follow the ones just measured (the load changes)."""
        spp = self.spp_for(budget)
        m = self.srv.render(spp=spp, seed=seed, repeat=1, warmup=False, **self.mx)
        secs, cpu = float(m["seconds"][0]), float(m["cpu_seconds"][0])
        self.per_spp = 0.5 * self.per_spp + 0.5 * max((secs - self.fixed) / spp, 1e-4)
        return m["image"], secs, cpu, spp

    def reference(self, spp: int, repeats: int) -> dict:
        """``repeats`` renders of ``spp`` averaged: image, its noise floor (the spread between the
        repeats), spp, wall and CPU seconds."""
        t0 = time.perf_counter()
        m = self.srv.render(spp=spp, seed=777000, repeat=repeats, warmup=False, keep_each=True, **self.mx)
        each = np.stack([m[f"image{i}"] for i in range(repeats)])
        return {"image": m["image"], "floor": floor(m["image"], each.var(axis=0, ddof=1) / repeats),
                "spp": spp * repeats, "seconds": time.perf_counter() - t0, "cpu_s": float(np.sum(m["cpu_seconds"]))}


def floor(ref: np.ndarray, var_of_mean: np.ndarray) -> float:
    """The reference's own expected relMSE."""
    return float(np.mean(var_of_mean / (ref ** 2 + EPS_REL)))


def run_stage(a, stage: str, ref_spp_illum: int, server_work: str) -> dict:
    desc = load_stage(stage)
    why = eligibility(desc)
    if why:
        raise SystemExit(f"{stage}: not exportable to Mitsuba: {'; '.join(why[:4])}")
    W = H = a.res
    npz = os.path.join(server_work, "scene.npz")
    export_scene(desc, W, H, npz)
    D = a.max_depth
    base = dict(resolution=(W, H), max_depth=D, rr_depth=a.rr_depth, threads=a.threads,
                pixel_filter="gaussian", pixel_filter_width=a.filter_width)
    mx = dict(max_depth=D + 1, rr_depth=a.rr_depth)
    cache: dict = {}
    out = {"stage": stage, "res": [W, H], "load_start": os.getloadavg()}
    srv = MitsubaServer(a.mitsuba_python, npz, a.mitsuba_variant, a.threads, server_work)
    try:
        # Warm-ups (illum: numba kernels, stage load; Mitsuba: scene load, Dr.Jit kernels), then Mitsuba's probe.
        for mode in ("splat", "importance"):
            render(stage, RenderOptions(spp=1, seed=99, pixel_filter_mode=mode, **base), scene_cache=cache)
        clock = MitsubaClock(srv, mx)
        t1, t4 = clock.t1, clock.t4
        out["mitsuba_probe"] = clock.probe()
        print(f"{stage}: Mitsuba {srv.banner}; 1 spp {t1:.3f} s, 4 spp {t4:.3f} s", flush=True)

        # References, each with its own filter and film.
        refs = {}
        for mode in ("splat", "importance"):
            t0, c0 = time.perf_counter(), time.process_time()
            r = render(stage, RenderOptions(spp=ref_spp_illum, seed=1000, pixel_filter_mode=mode, **base),
                       scene_cache=cache)
            img = r.film.mean().astype(np.float64)
            refs[f"illum {mode}"] = (img, floor(img, r.film.variance_of_mean()), ref_spp_illum,
                                     time.perf_counter() - t0, time.process_time() - c0)
        m = clock.reference(a.ref_spp_mitsuba, a.ref_repeats)
        refs["mitsuba gaussian film"] = (m["image"], m["floor"], m["spp"], m["seconds"], m["cpu_s"])
        out["refs"] = {k: {"spp": v[2], "seconds": v[3], "cpu_s": v[4], "floor": v[1], "mean": float(v[0].mean())}
                       for k, v in refs.items()}
        for k, v in out["refs"].items():
            print(f"  reference {k}: {v['spp']} spp in {v['seconds']:.0f} s, floor {v['floor']:.2e}", flush=True)

        runs = []
        k = 0
        for seed in range(1, a.seeds + 1):
            for b in a.budgets:
                order = RENDERERS[k % 3:] + RENDERERS[:k % 3]
                k += 1
                for who in order:
                    if who.startswith("illum"):
                        mode = who.split()[1]
                        c0 = time.process_time()
                        r = render(stage, RenderOptions(time_budget=b, seed=seed * 100 + int(b * 10),
                                                        pixel_filter_mode=mode, **base), scene_cache=cache)
                        cpu = time.process_time() - c0
                        img, secs, spp = r.film.mean().astype(np.float64), r.stats["seconds"]["render"], r.stats["spp"]
                    else:
                        img, secs, cpu, spp = clock.run(b, seed * 1000 + int(b * 10))
                    ref, fl = refs[who][0], refs[who][1]
                    e = relmse(img, ref)
                    run = {"renderer": who, "budget": b, "seed": seed, "seconds": secs, "cpu_s": cpu, "spp": int(spp),
                           "samples_per_s": W * H * spp / secs, "samples_per_cpu_s": W * H * spp / max(cpu, 1e-9),
                           "relmse": e, "relmse_corr": e - fl, "relmse_at_budget": (e - fl) * secs / b,
                           "mean_ratio": float(img.mean() / ref.mean()), "load": os.getloadavg()[0]}
                    runs.append(run)
                    print(f"  {who:22s} {b:g} s seed {seed}: {spp} spp in {secs:.2f} s (CPU {cpu:.2f} s), "
                          f"relMSE {e:.3e} (corr. {e - fl:.3e})", flush=True)
        out["runs"] = runs
    finally:
        srv.close()
    out["load_end"] = os.getloadavg()
    return out


def summarise(res: dict, budgets) -> list[dict]:
    rows = []
    for b in budgets:
        per = {}
        for who in RENDERERS:
            rs = [r for r in res["runs"] if r["renderer"] == who and r["budget"] == b]
            per[who] = {key: float(np.mean([r[key] for r in rs]))
                        for key in ("seconds", "cpu_s", "spp", "samples_per_s", "samples_per_cpu_s", "relmse",
                                    "relmse_corr", "relmse_at_budget", "mean_ratio")}
            per[who]["n"] = len(rs)
        mref = per["mitsuba gaussian film"]["relmse_at_budget"]
        for who in RENDERERS:
            rows.append({"budget": b, "renderer": who, **per[who], "ratio_vs_mitsuba": per[who]["relmse_at_budget"] / mref})
    return rows


def write_md(a, results: list[dict], cmd: str) -> str:
    md = ["# Film: illum splat vs illum filter importance sampling vs Mitsuba 3's Gaussian film, equal time", "",
          f"    {cmd}", "",
          f"{a.res}x{a.res}; illum max_depth {a.max_depth}, Mitsuba max_depth {a.max_depth + 1} (it counts the camera "
          f"segment); Russian roulette from depth {a.rr_depth} in both; {a.threads} threads each; illum Gaussian radius "
          f"{a.filter_width:g} px (sigma {a.filter_width / 3:g} px), Mitsuba `gaussian` (stddev 0.5 px, radius 2 px). "
          f"{a.seeds} seeds per budget, renderers alternated. Machine: {platform.platform()}, {os.cpu_count()} CPUs, "
          "**shared with other jobs (load averages below)**; CPU seconds are "
          "given beside wall seconds.", ""]
    for res in results:
        md += [f"## {res['stage']}", "",
               f"Load average (1 min) at start {res['load_start'][0]:.1f}, at end {res['load_end'][0]:.1f}. "
               f"Mitsuba probe: 1 spp {res['mitsuba_probe']['t1']:.3f} s, 4 spp {res['mitsuba_probe']['t4']:.3f} s "
               f"(first-call compile {res['mitsuba_probe']['warmup_s']:.1f} s, not counted).", "",
               "| reference | spp | wall s | CPU s | noise floor (its own relMSE) |", "|---|---|---|---|---|"]
        for k, v in res["refs"].items():
            md.append(f"| {k} | {v['spp']} | {v['seconds']:.0f} | {v['cpu_s']:.0f} | {v['floor']:.2e} |")
        md += ["", "| budget s | renderer | wall s | CPU s | spp | Msamples/s | Msamples/CPU-s | relMSE | relMSE − floor | "
               "at budget | ratio to Mitsuba | mean/ref |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in res["summary"]:
            md.append(f"| {r['budget']:g} | {r['renderer']} | {r['seconds']:.2f} | {r['cpu_s']:.2f} | {r['spp']:.1f} | "
                      f"{r['samples_per_s'] / 1e6:.3f} | {r['samples_per_cpu_s'] / 1e6:.3f} | {r['relmse']:.3e} | "
                      f"{r['relmse_corr']:.3e} | {r['relmse_at_budget']:.3e} | **{r['ratio_vs_mitsuba']:.2f}** | "
                      f"{r['mean_ratio']:.4f} |")
        md.append("")
    md += ["Columns: means over seeds. 'at budget' = (relMSE − floor) × wall s / budget, i.e. the corrected relMSE "
           "moved to exactly the budget assuming relMSE ∝ 1/t (Mitsuba's spp is picked ahead and lands off the budget); "
           "'ratio to Mitsuba' = that figure over Mitsuba's (lower is better, < 1 beats Mitsuba). mean/ref = image mean "
           "over its reference's (bias check)."]
    return "\n".join(md) + "\n"


def add_setup_args(ap: argparse.ArgumentParser, budgets: str) -> None:
    """The equal-time setup flags shared with bench_mitsuba_table.py."""
    ap.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--max-depth", type=int, default=7, help="illum's; Mitsuba gets one more")
    ap.add_argument("--rr-depth", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--filter-width", type=float, default=1.5, help="illum's Gaussian radius (sigma = radius / 3)")
    ap.add_argument("--budgets", default=budgets)
    ap.add_argument("--seeds", type=int, default=2)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stages", nargs="*", default=list(STAGES))
    ap.add_argument("--mitsuba-python", required=True)
    add_setup_args(ap, budgets="2,8")
    ap.add_argument("--ref-spp-illum", default="512", help="per stage, comma-separated (one value: all stages)")
    ap.add_argument("--ref-spp-mitsuba", type=int, default=256, help="per reference render")
    ap.add_argument("--ref-repeats", type=int, default=8, help="Mitsuba reference renders averaged")
    ap.add_argument("--out", default="bench/results/film")
    a = ap.parse_args(argv)
    a.budgets = [float(x) for x in a.budgets.split(",")]
    ref_spp = [int(x) for x in a.ref_spp_illum.split(",")]
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_film_mitsuba.py " + " ".join(argv if argv is not None else sys.argv[1:])
    os.makedirs(a.out, exist_ok=True)
    results = []
    for i, stage in enumerate(a.stages):
        with tempfile.TemporaryDirectory(prefix="illum-film-mitsuba-") as work:
            res = run_stage(a, stage, ref_spp[min(i, len(ref_spp) - 1)], work)
        res["summary"] = summarise(res, a.budgets)
        results.append(res)
        write_results(a.out, "mitsuba.json", "mitsuba_table.md", cmd, results, write_md(a, results, cmd))
    print(write_md(a, results, cmd))
    return 0


def write_results(out: str, json_name: str, md_name: str, cmd: str, results: list, md: str) -> None:
    """A benchmark's outputs in the folder out: json_name ({"command", "results"}) and the
    markdown table md_name."""
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, json_name), "w") as fh:
        json.dump({"command": cmd, "results": results}, fh, indent=1)
    with open(os.path.join(out, md_name), "w") as fh:
        fh.write(md)


if __name__ == "__main__":
    sys.exit(main())
