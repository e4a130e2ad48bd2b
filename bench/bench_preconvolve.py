"""Benchmark `illum preconvolve` (issue #6): time and peak memory per input size, plus accuracy.

    .venv/bin/python bench/bench_preconvolve.py [--sizes 512x256 1024x512 2048x1024 4096x2048]
                                                [--out-size 128] [--accuracy] [--tmp /tmp/illum-bench]

Each input is a synthetic lat-long EXR written to --tmp (sky gradient + noise + a 1e5 sun of a few
texels). Each run is a fresh subprocess so its peak RSS (resource.getrusage ru_maxrss) is its
own; tracemalloc's peak counts numpy/Python allocations only (not OIIO's internal buffers).
"512²" in the issue is read as the 2:1 map 512x256 (a 512x512 map is run with --force too).

--accuracy also checks both methods against brute force (Σ_t L_t Ω_t max(0, n·ω_t) over every
texel) on (a) the 2048x1024 sun map and (b) a constant map, over all output normals.
This is a script, not a timed test: the numbers depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def synthetic_map(path: str, w: int, h: int, sun: float = 1e5, seed: int = 0) -> str:
    """Sky (brighter up, bluish) + 20 % noise + a sun of radiance `sun` covering ~2x2 texels
    per 1k of width, written as float32 EXR."""
    import OpenImageIO as oiio

    from renderer.preconvolve import latlong_directions

    if os.path.exists(path):
        return path
    rng = np.random.default_rng(seed)
    d = latlong_directions(h, w)
    sky = 1.0 + 0.6 * np.clip(d[..., 1:2], 0, None) * np.array([0.6, 0.8, 1.2]) + 0.2 * rng.random((h, w, 3))
    img = sky.astype(np.float32)
    s = max(1, w // 1024)
    r, c = int(h * 0.3), int(w * 0.35)
    img[r:r + 2 * s, c:c + 2 * s] = sun
    assert oiio.ImageBuf(np.ascontiguousarray(img)).write(path)
    return path


def _child(src: str, out: str, size: int, method: str, force: bool) -> None:
    """Run one preconvolve and print a JSON line (in a fresh process)."""
    import resource
    import tracemalloc

    from renderer.preconvolve import preconvolve

    tracemalloc.start()
    cpu0 = resource.getrusage(resource.RUSAGE_SELF)
    t = time.perf_counter()
    rep = preconvolve(src, out, size=size, method=method, force=force)
    wall = time.perf_counter() - t
    _, peak = tracemalloc.get_traced_memory()
    ru = resource.getrusage(resource.RUSAGE_SELF)
    rss = ru.ru_maxrss * 1024  # Linux: KiB
    cpu = (ru.ru_utime - cpu0.ru_utime) + (ru.ru_stime - cpu0.ru_stime)
    print(json.dumps({"wall": wall, "cpu": cpu, "compute": rep["compute_seconds"], "tracemalloc_peak": peak,
                      "maxrss": rss}))


def run_one(src, out, size, method, force=False) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--child", src, out, str(size), method]
    cmd += ["--force"] if force else []
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if res.returncode:
        raise RuntimeError(res.stderr)
    return json.loads(res.stdout.strip().splitlines()[-1])


def baseline_rss() -> int:
    """Peak RSS of a process that imported everything and ran the kernels once on a tiny map."""
    code = ("import resource, numpy as np, renderer.preconvolve as pc;"
            "pc.exact_irradiance(np.ones((8, 16, 3)), np.eye(3));"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)")
    return int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT).stdout)


def _dense_texel(h, w, r, c, normals, K=48) -> np.ndarray:
    """(N,) ∫_texel max(0, n·ω) dω by K x K midpoint sub-samples (numpy, independent of the module)."""
    from renderer.lights.dome import latlong_texel_solid_angles

    j = (np.arange(K) + 0.5) / K
    zt, zb = np.cos(np.pi * r / h), np.cos(np.pi * (r + 1) / h)
    z = zt - j * (zt - zb)
    lon = np.pi - 2.0 * np.pi * (c + j) / w
    s = np.sqrt(1 - z * z)[:, None]
    d = np.stack([s * np.sin(lon)[None], np.broadcast_to(z[:, None], (K, K)), s * np.cos(lon)[None]], -1)
    d = d.reshape(-1, 3).T
    out = np.empty(normals.shape[0])
    for k in range(0, normals.shape[0], 512):
        out[k:k + 512] = np.maximum(0.0, normals[k:k + 512] @ d).mean(axis=1)
    return out * latlong_texel_solid_angles(h, w)[r]


def accuracy(tmp: str, out_size: int) -> None:
    """Both methods against brute force on the 2048x1024 sun map and a constant map.

    Brute force 1 ("centre sum", the issue's): Σ_t L_t Ω_t max(0, n·ω_t) over every texel.
    Brute force 2 ("dense sun"): the same for the sky plus 48x48 sub-samples in each sun texel,
    because a sun texel cut by the horizon is all-or-nothing for the centre sum.
    """
    import OpenImageIO as oiio

    from renderer.preconvolve import latlong_directions, midpoint_irradiance, preconvolve

    oh, ow = out_size // 2, out_size
    n = latlong_directions(oh, ow).reshape(-1, 3)
    const = os.path.join(tmp, "const_2048x1024.exr")
    if not os.path.exists(const):
        oiio.ImageBuf(np.full((1024, 2048, 3), [1.0, 0.5, 2.0], np.float32)).write(const)
    cases = [("sun 2048x1024", synthetic_map(os.path.join(tmp, "env_2048x1024.exr"), 2048, 1024)),
             ("constant 2048x1024", const)]
    print(f"\naccuracy, all {ow}x{oh} output normals: relative error max / mean (over normals and RGB)")
    for name, path in cases:
        img = oiio.ImageBuf(path).get_pixels(oiio.FLOAT).astype(np.float64)
        h, w = img.shape[:2]
        t = time.perf_counter()
        refs = {"centre sum": midpoint_irradiance(img, n)}
        t_ref = time.perf_counter() - t
        sun = np.argwhere(img.max(axis=2) > 1e3)
        if len(sun):
            sky = img.copy()
            sky[sun[:, 0], sun[:, 1]] = 0.0
            dense = midpoint_irradiance(sky, n)
            for r, c in sun:
                dense += _dense_texel(h, w, r, c, n)[:, None] * img[r, c]
            refs["dense sun"] = dense
        else:
            refs["pi L (analytic)"] = np.broadcast_to(np.pi * img[0, 0], (n.shape[0], 3))
        print(f"  {name}: {len(sun)} sun texels; centre-sum brute force took {t_ref:.1f} s")
        if len(refs) == 2:
            a, b = refs.values()
            rel = np.abs(a / b - 1)
            print(f"    {'centre sum vs ' + list(refs)[1]:<30} {rel.max():10.2e} / {rel.mean():.2e}")
        for method in ("exact", "sh"):
            out = os.path.join(tmp, f"acc_{method}.exr")
            preconvolve(path, out, size=out_size, method=method)
            E = oiio.ImageBuf(out).get_pixels(oiio.FLOAT).astype(np.float64).reshape(-1, 3)
            for rname, ref in refs.items():
                rel = np.abs(E / ref - 1.0)
                print(f"    {method + ' vs ' + rname:<30} {rel.max():10.2e} / {rel.mean():.2e}")


def main(argv=None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if argv and argv[0] == "--child":
        _child(argv[1], argv[2], int(argv[3]), argv[4], "--force" in argv)
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="*", default=["512x256", "512x512", "1024x512", "2048x1024", "4096x2048"],
                    help="input maps WxH (none: skip the timing table)")
    ap.add_argument("--out-size", type=int, default=128)
    ap.add_argument("--methods", nargs="+", default=["exact", "sh"])
    ap.add_argument("--accuracy", action="store_true")
    ap.add_argument("--tmp", default="/tmp/illum-bench")
    a = ap.parse_args(argv)
    os.makedirs(a.tmp, exist_ok=True)
    # Warm numba's on-disk cache so no row pays compilation.
    warm = synthetic_map(os.path.join(a.tmp, "env_64x32.exr"), 64, 32)
    run_one(warm, os.path.join(a.tmp, "warm.exr"), 16, "exact")
    base = baseline_rss()
    print(f"illum preconvolve -> {a.out_size}x{a.out_size // 2}; {os.cpu_count()} CPUs; "
          f"load average {os.getloadavg()[0]:.1f}; baseline RSS after imports {base / 2**20:.0f} MiB")
    print(f"{'input':<11} {'method':<6} {'wall s':>7} {'CPU s':>7} {'compute s':>9} {'peak RSS MiB':>12} "
          f"{'RSS-baseline':>12} {'tracemalloc MiB':>15}")
    for size in a.sizes:
        w, h = (int(v) for v in size.split("x"))
        src = synthetic_map(os.path.join(a.tmp, f"env_{w}x{h}.exr"), w, h)
        for method in a.methods:
            out = os.path.join(a.tmp, f"out_{w}x{h}_{method}.exr")
            r = run_one(src, out, a.out_size, method, force=(w != 2 * h))
            print(f"{size:<11} {method:<6} {r['wall']:7.2f} {r['cpu']:7.2f} {r['compute']:9.2f} "
                  f"{r['maxrss'] / 2**20:12.0f} "
                  f"{(r['maxrss'] - base) / 2**20:12.0f} {r['tracemalloc_peak'] / 2**20:15.1f}", flush=True)
    if a.accuracy:
        accuracy(a.tmp, a.out_size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
