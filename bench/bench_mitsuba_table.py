"""illum against Mitsuba 3 at equal time on the issue-23 scenes: the side-by-side table.

    PYTHONPATH=. .venv/bin/python bench/bench_mitsuba_table.py --mitsuba-python /work/scratch/mitsuba-venv/bin/python
    PYTHONPATH=. .venv/bin/python bench/bench_mitsuba_table.py --mitsuba-python ... --illum-only   # after new kernels

Scenes (``SCENES``): the Cornell box, a sphere light with an occluder, three disk lights with
penumbrae, a white furnace, the 500-light stage, a textured lat-long dome and the plant (a textured
asset with normal maps and cut-out leaves). Each is exported to Mitsuba by
``bench_mitsuba.export_scene`` with ``eligibility(full=True)``: UsdPreviewSurface -> ``diffuse`` or
``principled`` with ``bitmap`` textures, ``normalmap`` and ``mask`` cut-outs
(``bench_mitsuba.material_record`` documents the mapping), rect/disk/sphere lights as emitting
shapes, treatAsPoint spheres as ``point``, distant lights as ``directional`` (a delta light: harder
shadows than illum's 0.53 degree cone), domes as ``constant`` / ``envmap``
(``mitsuba_side.build_scene_dict``). The materials are not the same BRDFs, only comparable in look:
each renderer is scored against its *own* converged reference, so the table compares how fast each
converges on its own image, not the images.

Setup (the issue's): ``--res`` 256 x 256 (each stage's camera window conformed to it),
illum ``max_depth`` 7 against Mitsuba ``max_depth`` 8 (Mitsuba counts the camera segment), Russian
roulette from ``--rr-depth`` 3 scattering events in both, ``--threads`` 2 each, budgets 4 and 16 s.
Mitsuba out of the box: ``mi.render`` with its ``hdrfilm`` and ``gaussian`` rfilter (stddev 0.5 px),
``independent`` sampler, ``path`` integrator (``bench_film_mitsuba.MitsubaServer`` keeps one warm
``mitsuba_side.py`` process per stage). illum: ``render(RenderOptions(time_budget=...))`` with its
Gaussian filter of radius 1.5 px (sigma 0.5 px), after a 1-spp warm-up per configuration.

illum configurations (one column each):

* ``stage``: the stage as authored: each light's IllumLightAPI estimator and sample count, the
  RenderSettings' stage-wide default for the rest (the schema fallback, mis, when none). On a stage
  that authors nothing it is the same render as ``mis``; it is then not run twice and the table
  says "= mis".
* ``mis``: every light forced to ``mis`` with 1 light sample (``estimator={"": "mis"}``,
  ``light_samples={"": 1}``, i.e. ``--estimator '*=mis' --light-samples '*=1'``): what Mitsuba's
  ``path`` does.

Runs are alternated: for each seed and budget every renderer runs once, in an order rotated from
one run to the next, so load changes on the shared machine hit all alike.

Error and efficiency (as bench_film_mitsuba.py): relMSE = mean((x - ref)^2 / (ref^2 + 0.01)) over
pixels and channels; each reference's noise floor (illum: ``film.variance_of_mean()``; Mitsuba: the
spread of ``--ref-repeats`` renders) is subtracted. Wall-clock figure: corrected relMSE x wall s /
budget (relMSE at exactly the budget, relMSE ~ 1/t); CPU figure: corrected relMSE x CPU s of the
rendering process (all its threads): on a machine shared with other jobs, CPU time is what each
renderer actually got. Ratios are illum / Mitsuba: < 1 means illum converges faster; the issue's
target is <= 0.5 on every scene.

Cache (``--cache``, default /work/scratch/mitsuba-table): per scene, keyed by the stage file's bytes
and the setup, the exported scene, both references and Mitsuba's runs. A rerun reuses the
references; ``--illum-only`` also reuses Mitsuba's timed runs (measured earlier, under that run's
load) and renders only illum (compare its CPU-second ratios: the wall-clock ones then mix two
loads); ``--fresh-illum-ref`` re-renders illum's reference.

Outputs in ``--out``: table.md (command, versions, load averages, tables), table.json (every run).
"""

from __future__ import annotations

import argparse
import hashlib
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

from bench_film_mitsuba import MitsubaClock, MitsubaServer, add_setup_args, floor  # noqa: E402
from bench_mitsuba import _cpu, _versions, eligibility, export_scene, relmse  # noqa: E402

from renderer.render import RenderOptions, render  # noqa: E402
from renderer.usd import load_stage  # noqa: E402

# (label, stage, illum reference seconds): the plant runs on illum's slow general path today, so
# its reference gets more time.
SCENES = (
    ("Cornell box", "stages/cornell_box.usda", 90),
    ("sphere light + occluder", "stages/talk/sphere_occluder.usda", 90),
    ("three disk lights, penumbrae", "stages/talk/disks.usda", 90),
    ("white furnace", "stages/talk/furnace.usda", 90),
    ("500 sphere lights", "stages/many_lights/many_lights.usda", 90),
    ("textured lat-long dome", "stages/talk/dome.usda", 90),
    ("plant (textures, normal maps, cut-outs)", "stages/plant/plant.usda", 150),
)
EXPORT_VERSION = 2  # bump when export_scene / mitsuba_side change what Mitsuba renders
MIS = {"estimator": {"": "mis"}, "light_samples": {"": 1}}


def stage_estimators(desc) -> tuple[str, bool]:
    """What the ``stage`` column renders, in words, and whether that is exactly the ``mis`` column
    (every light on mis with 1 sample, authored or by the stage-wide default)."""
    from renderer.description import EstimatorSettings

    default = desc.settings.estimator or EstimatorSettings().estimator
    parts: dict[str, int] = {}
    for lt in desc.lights:
        est = lt.estimator.estimator if lt.estimator.estimator_authored else default
        how = "authored" if lt.estimator.estimator_authored else "stage default"
        key = f"{est}" + (f" x{lt.estimator.samples}" if lt.estimator.samples != 1 else "") + f" ({how})"
        parts[key] = parts.get(key, 0) + 1
    same = all(k.startswith("mis (") for k in parts)
    words = ", ".join(f"{k}: {n} light{'s' * (n > 1)}" if len(parts) > 1 else k for k, n in parts.items())
    return words, same


def cache_dir(a, stage: str) -> str:
    h = hashlib.sha1()
    with open(stage, "rb") as fh:
        h.update(fh.read())
    h.update(json.dumps([EXPORT_VERSION, a.res, a.max_depth, a.rr_depth, a.filter_width, a.mitsuba_variant]).encode())
    d = os.path.join(a.cache, f"{os.path.splitext(os.path.basename(stage))[0]}-{h.hexdigest()[:12]}")
    os.makedirs(d, exist_ok=True)
    return d


def _save(path: str, **kw) -> None:
    tmp = path + ".tmp.npz"
    np.savez_compressed(tmp, **{k: np.asarray(v) for k, v in kw.items()})
    os.replace(tmp, path)


def _load(path: str) -> dict | None:
    if not os.path.exists(path):
        return None
    d = np.load(path)
    return {k: (d[k] if d[k].ndim else d[k].item()) for k in d.files}


def _score(img, ref: dict, secs: float, cpu: float, budget: float, spp: int, npix: int) -> dict:
    e = relmse(img, ref["image"])
    corr = e - float(ref["floor"])
    return {"seconds": secs, "cpu_s": cpu, "spp": int(spp), "samples_per_s": npix * spp / secs,
            "samples_per_cpu_s": npix * spp / max(cpu, 1e-9), "relmse": e, "relmse_corr": corr,
            "at_budget": corr * secs / budget, "at_cpu": corr * cpu,
            "mean_ratio": float(img.mean() / ref["image"].mean()), "load": os.getloadavg()[0]}


def run_scene(a, label: str, stage: str, illum_ref_s: float) -> dict:
    desc = load_stage(stage)
    why = eligibility(desc, full=True)
    if why:
        raise SystemExit(f"{stage}: not exportable to Mitsuba: {'; '.join(why[:4])}")
    W = H = a.res
    npix = W * H
    cdir = cache_dir(a, stage)
    npz = os.path.join(cdir, "scene.npz")
    if not os.path.exists(npz):
        export_scene(desc, W, H, npz, opaque_emitters=True)
    authored, same = stage_estimators(desc)
    configs = {"mis": MIS} if same else {"stage": {}, "mis": MIS}
    base = dict(resolution=(W, H), max_depth=a.max_depth, rr_depth=a.rr_depth, threads=a.threads,
                pixel_filter="gaussian", pixel_filter_width=a.filter_width)
    out = {"label": label, "stage": stage, "authored": authored, "cache": cdir, "load_start": os.getloadavg()}
    caches = {name: {} for name in configs}

    def illum(name: str, **kw):
        c0 = time.process_time()
        r = render(stage, RenderOptions(**base, **configs[name], **kw), scene_cache=caches[name])
        return r, time.process_time() - c0

    for name in configs:  # warm-ups: numba kernels, stage load
        illum(name, spp=1, seed=99)

    # illum's reference: the stage's own configuration (every estimator converges to the same image).
    ref_path = os.path.join(cdir, "illum_ref.npz")
    ref_i = None if a.fresh_illum_ref else _load(ref_path)
    if ref_i is None:
        # Independent numbers: the floor (film.variance_of_mean) assumes independent passes; for
        # the default sampler's stratified passes it would overstate the reference's own error.
        r, cpu = illum(next(iter(configs)), time_budget=illum_ref_s * a.ref_scale, seed=1000, sampler="independent")
        img = r.film.mean().astype(np.float64)
        ref_i = {"image": img, "floor": floor(img, r.film.variance_of_mean()), "spp": r.stats["spp"],
                 "seconds": r.stats["seconds"]["render"], "cpu_s": cpu}
        _save(ref_path, **ref_i)
    print(f"{label}: illum reference {ref_i['spp']} spp, floor {ref_i['floor']:.2e}", flush=True)

    mpath = os.path.join(cdir, "mitsuba.json")
    mref_path = os.path.join(cdir, "mitsuba_ref.npz")
    mcached = json.load(open(mpath)) if os.path.exists(mpath) else None
    runs = []
    srv = clock = None
    if a.illum_only:
        if mcached is None or _load(mref_path) is None:
            raise SystemExit(f"{stage}: --illum-only needs Mitsuba's cached runs in {cdir}; run once without it")
        ref_m = _load(mref_path)
        out["mitsuba"] = mcached["info"]
        runs += [r for r in mcached["runs"] if r["budget"] in a.budgets and r["seed"] <= a.seeds]
    else:
        work = tempfile.mkdtemp(prefix="illum-mitsuba-table-")
        srv = MitsubaServer(a.mitsuba_python, npz, a.mitsuba_variant, a.threads, work)
        clock = MitsubaClock(srv, dict(max_depth=a.max_depth + 1, rr_depth=a.rr_depth))
        ref_m = _load(mref_path)
        if ref_m is None:
            per = clock.spp_for(a.mitsuba_ref_s * a.ref_scale / a.ref_repeats)
            ref_m = clock.reference(per, a.ref_repeats)
            _save(mref_path, **ref_m)
        out["mitsuba"] = {"banner": srv.banner, "probe": clock.probe(), "ref_spp": int(ref_m["spp"]),
                          "ref_floor": float(ref_m["floor"]), "ref_seconds": float(ref_m["seconds"])}
        print(f"{label}: Mitsuba {srv.banner}; reference {ref_m['spp']} spp, floor {ref_m['floor']:.2e}", flush=True)
    out["illum_ref"] = {k: float(v) for k, v in ref_i.items() if k != "image"}

    who_all = [*configs, *([] if a.illum_only else ["mitsuba"])]
    k = 0
    try:
        for seed in range(1, a.seeds + 1):
            for b in a.budgets:
                order = who_all[k % len(who_all):] + who_all[:k % len(who_all)]
                k += 1
                for who in order:
                    if who == "mitsuba":
                        img, secs, cpu, spp = clock.run(b, seed * 1000 + int(b * 10))
                        ref = ref_m
                    else:
                        r, cpu = illum(who, time_budget=b, seed=seed * 100 + int(b * 10))
                        img, secs, spp = r.film.mean().astype(np.float64), r.stats["seconds"]["render"], r.stats["spp"]
                        ref = ref_i
                    run = {"renderer": who, "budget": b, "seed": seed, **_score(img, ref, secs, cpu, b, spp, npix)}
                    runs.append(run)
                    print(f"  {who:8s} {b:g} s seed {seed}: {spp} spp in {secs:.2f} s (CPU {cpu:.2f} s), relMSE "
                          f"{run['relmse']:.3e} (corr. {run['relmse_corr']:.3e}), load {run['load']:.1f}", flush=True)
    finally:
        if srv is not None:
            srv.close()
    if not a.illum_only:
        with open(mpath, "w") as fh:
            json.dump({"info": out["mitsuba"], "runs": [r for r in runs if r["renderer"] == "mitsuba"],
                       "measured": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())}, fh, indent=1)
    out["mitsuba_measured"] = (mcached or {}).get("measured") if a.illum_only else "this run"
    out["runs"] = runs
    out["load_end"] = os.getloadavg()
    return out


def summarise(res: dict, budgets) -> dict:
    """{budget: {renderer: means over seeds}} plus the illum / Mitsuba ratios."""
    s = {}
    for b in budgets:
        per = {}
        for who in ("stage", "mis", "mitsuba"):
            rs = [r for r in res["runs"] if r["renderer"] == who and r["budget"] == b]
            if rs:
                per[who] = {key: float(np.mean([r[key] for r in rs])) for key in rs[0] if key not in ("renderer", "seed")}
                per[who]["n"] = len(rs)
        m = per["mitsuba"]
        for who in ("stage", "mis"):
            if who in per:
                per[who]["ratio"] = per[who]["at_budget"] / m["at_budget"]
                per[who]["ratio_cpu"] = per[who]["at_cpu"] / m["at_cpu"]
        s[b] = per
    return s


def _ratio(per: dict, who: str, key: str) -> str:
    if who not in per:
        return "= mis"
    v = per[who][key]
    return f"**{v:.2f}**" if v <= 0.5 else f"{v:.2f}"


def write_md(a, results: list[dict], cmd: str, versions: dict) -> str:
    B = a.budgets
    loads = [r.get("load", 0.0) for res in results for r in res.get("runs", [])]
    peak = max(loads, default=0.0)
    if peak <= a.threads + 0.75:
        machine = (f"**Measured on a quiet machine**: the load average stayed at or below {peak:.1f} on "
                   f"{os.cpu_count()} cores, i.e. the renderer under test and little else. Both renderers ran with "
                   f"{a.threads} threads, alternated run by run.")
    else:
        machine = (f"**Measured on a loaded machine**: load averages up to {peak:.1f} on {os.cpu_count()} cores "
                   "(below). Both renderers ran with the same threads, alternated run by run, but their wall-clock "
                   "times include waiting for the CPU; the CPU-seconds tables divide that out.")
    md = ["# illum against Mitsuba 3 at equal time (issue 23, 'Measure and report')", "", machine, "",
          f"    {cmd}", "",
          f"Date {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {platform.platform()}, {_cpu()}, "
          f"{os.cpu_count()} CPUs. Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()) + ".", "",
          f"Setup: {a.res}x{a.res}; illum max_depth {a.max_depth}, Mitsuba `path` max_depth {a.max_depth + 1} (it counts "
          f"the camera segment); Russian roulette from {a.rr_depth} scattering events in both; {a.threads} threads "
          f"each; Mitsuba's own `hdrfilm` + `gaussian` rfilter (stddev 0.5 px), illum's Gaussian of radius "
          f"{a.filter_width:g} px (sigma {a.filter_width / 3:g} px); {a.seeds} seed(s) per budget. Each renderer is "
          "scored against its own converged reference with that reference's noise floor subtracted "
          "(bench/bench_mitsuba_table.py docstring). Materials are mapped, not identical "
          "(bench_mitsuba.material_record): the scenes are comparable in look, the error is each renderer's own.", "",
          "Columns: `stage` = the stage's authored IllumLightAPI estimators (stage-wide default where unauthored; "
          "'= mis' where that is mis with 1 sample on every light, so both columns are one render); `mis` = every light on mis with "
          "1 light sample, as Mitsuba's path tracer. Entries are relMSE ratios illum / Mitsuba: below 1 illum "
          "converges faster; the issue's target is <= 0.5 (bold).", ""]
    if any(r.get("mitsuba_measured") not in (None, "this run") for r in results):
        md += ["**--illum-only rerun**: Mitsuba's runs and both references come from the cache, measured "
               + ", ".join(sorted({str(r["mitsuba_measured"]) for r in results})) + " under that run's load, so the "
               "wall-clock ratios mix two loads: read the CPU-seconds table (a Cornell-box check: wall 2.4x -> 1.5x "
               "when the load fell from 15 to 8, CPU 2.6x -> 2.8x).", ""]
    for key, title in (("ratio", "Equal wall-clock time"), ("ratio_cpu", "Equal CPU time (relMSE x CPU-seconds)")):
        md += [f"## {title}: relMSE ratio illum / Mitsuba", "",
               "| scene | stage's estimators | " + " | ".join(f"{b:g} s stage | {b:g} s mis" for b in B) + " |",
               "|---|---|" + "---|---|" * len(B)]
        for r in results:
            cells = []
            for b in B:
                per = r["summary"][b]
                cells += [_ratio(per, "stage", key), _ratio(per, "mis", key)]
            md.append(f"| {r['label']} | {r['authored']} | " + " | ".join(cells) + " |")
        md.append("")
    md += ["## Per scene", "",
           "| scene | budget | renderer | wall s | CPU s | spp | Msamples/s | Msamples/CPU-s | relMSE | − floor | "
           "at budget | mean/ref | load |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for b in B:
            for who, v in r["summary"][b].items():
                md.append(f"| {r['label']} | {b:g} | {who} | {v['seconds']:.2f} | {v['cpu_s']:.2f} | {v['spp']:.0f} | "
                          f"{v['samples_per_s'] / 1e6:.3f} | {v['samples_per_cpu_s'] / 1e6:.3f} | {v['relmse']:.3e} | "
                          f"{v['relmse_corr']:.3e} | {v['at_budget']:.3e} | {v['mean_ratio']:.3f} | {v['load']:.1f} |")
    md += ["", "| scene | illum ref spp | illum floor | Mitsuba ref spp | Mitsuba floor | load at start / end |",
           "|---|---|---|---|---|---|"]
    for r in results:
        m = r["mitsuba"]
        md.append(f"| {r['label']} | {r['illum_ref']['spp']:.0f} | {r['illum_ref']['floor']:.2e} | {m['ref_spp']} | "
                  f"{m['ref_floor']:.2e} | {r['load_start'][0]:.1f} / {r['load_end'][0]:.1f} |")
    md += ["", "'at budget' = (relMSE − floor) × wall s / budget; mean/ref = the image mean over its reference's "
           "(a bias check: ~1 within noise). Msamples = camera samples (pixels × spp)."]
    return "\n".join(md) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", help="stage paths (default: the seven of SCENES)")
    ap.add_argument("--mitsuba-python", default="/work/scratch/mitsuba-venv/bin/python")
    add_setup_args(ap, budgets="4,16")
    ap.add_argument("--mitsuba-ref-s", type=float, default=90.0, help="Mitsuba reference seconds per scene")
    ap.add_argument("--ref-scale", type=float, default=1.0, help="scales both references' seconds")
    ap.add_argument("--ref-repeats", type=int, default=8, help="Mitsuba reference renders averaged")
    ap.add_argument("--illum-only", action="store_true", help="reuse Mitsuba's cached runs and references")
    ap.add_argument("--fresh-illum-ref", action="store_true")
    ap.add_argument("--cache", default="/work/scratch/mitsuba-table")
    ap.add_argument("--out", default="bench/results/mitsuba")
    ap.add_argument("--from-json", action="store_true", help="only rewrite table.md from --out's table.json")
    a = ap.parse_args(argv)
    a.budgets = [float(x) for x in a.budgets.split(",")]
    if a.from_json:
        data = json.load(open(os.path.join(a.out, "table.json")))
        for r in data["results"]:
            r["summary"] = {float(b): v for b, v in r["summary"].items()}
            r["authored"] = stage_estimators(load_stage(os.path.join(ROOT, r["stage"])))[0]
        with open(os.path.join(a.out, "table.md"), "w") as fh:
            fh.write(write_md(a, data["results"], data["command"], data["versions"]))
        return 0
    scenes = [s for s in SCENES if not a.scenes or s[1] in a.scenes]
    cmd = "PYTHONPATH=. .venv/bin/python bench/bench_mitsuba_table.py " + " ".join(argv if argv is not None else sys.argv[1:])
    os.makedirs(a.out, exist_ok=True)
    commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    results = []
    for label, stage, ref_s in scenes:
        res = run_scene(a, label, os.path.join(ROOT, stage), ref_s)
        res["stage"] = stage
        res["summary"] = summarise(res, a.budgets)
        results.append(res)
        banner = next((r["mitsuba"].get("banner", "") for r in results if r["mitsuba"].get("banner")), "")
        parts = banner.split()  # "ready MITSUBA DRJIT VARIANT" (mitsuba_side.serve)
        mv = {"mitsuba": parts[1], "drjit": parts[2], "variant": parts[3]} if len(parts) == 4 else {"mitsuba": banner}
        versions = {"illum": commit, **_versions(a, mv)}
        with open(os.path.join(a.out, "table.json"), "w") as fh:
            json.dump({"command": cmd, "versions": versions, "results": results}, fh, indent=1, default=str)
        with open(os.path.join(a.out, "table.md"), "w") as fh:
            fh.write(write_md(a, results, cmd, versions))
    print(open(os.path.join(a.out, "table.md")).read())
    return 0


if __name__ == "__main__":
    sys.exit(main())
