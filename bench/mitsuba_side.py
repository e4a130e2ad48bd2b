"""Mitsuba 3 side of bench/bench_mitsuba.py. Runs in a *separate* Python (a scratch venv with
``mitsuba``), never in the project's venv: Mitsuba is not a dependency of illum.

    python mitsuba_side.py JOB.json

JOB.json: {"scene": "scene.npz", "variant": "llvm_ad_rgb", "threads": 2, "tasks": [...], "out": "result.npz"}.
The scene file is written by bench_mitsuba.py (``export_scene``): world-space triangles per mesh
(unshared vertices, optional per-corner shading normals), a diffuse albedo per mesh, the lights in
UsdLux conventions with their final radiance (computed by illum's radiometry), and the camera as
USD's camera-to-world matrix plus the conformed screen window. All conversions to Mitsuba's
conventions happen here:

* rect light: UsdLux spans width x height in local XY and emits toward local -Z, one-sided.
  Mitsuba's ``rectangle`` spans [-1, 1]^2 and emits toward its +Z normal, so to_world has columns
  (ex / 2, ey / 2, n, centre) with the pair (ex, ey) ordered so that ex x ey points along the
  emission normal n.
* disk light: same with Mitsuba's unit ``disk`` and columns (e1, e2, n, centre), e1/e2 the
  world radius vectors.
* sphere light: ``sphere`` (centre, radius), emits outward. treatAsPoint: ``point`` with illum's
  intensity L pi r^2.
* distant light: ``directional`` (a delta light: hard shadows where illum's cone of ``angle``
  gives soft ones) with the cone's irradiance at normal incidence, L pi sin^2(theta_max).
* constant dome: ``constant`` emitter. Lat-long dome: ``envmap`` whose bitmap (16x the source
  resolution) follows the UsdLux/OpenEXR convention with nearest-texel lookups, as illum does
  (``envmap_bitmap``); ``probe_envmap`` checks Mitsuba's radiance against that lookup.
* emitter shapes get the ``null`` BSDF (or, with ``opaque_emitters`` in the scene json, a black
  ``diffuse``, so that a light seen against the empty background is visible; see build_scene_dict): illum's lights are transparent to every ray (a ray
  crossing a light picks up its emission and continues), and Mitsuba's ``path`` integrator
  continues through null surfaces. Difference: Mitsuba counts that crossing as one path vertex
  (depth and Russian roulette), illum does not (bench_mitsuba.py reports pixels that see a
  light directly separately).
* camera: USD cameras look down -Z with +Y up and +X to the right of the image; Mitsuba's
  ``perspective`` looks down +Z with +Y up and +X to the image's *left*. A 180 degree turn about
  Y maps one onto the other: to_world = C @ diag(-1, 1, -1, 1). The window's horizontal extent
  gives the x field of view (only symmetric windows are exported).
* surfaces: ``twosided`` (illum shades both sides of every surface) around ``diffuse`` or, for
  materials with a specular lobe, ``principled``; textures as raw ``bitmap``s of illum's decoded
  texels, normal maps as ``normalmap``, cut-outs as ``mask`` (``material_bsdf``; the mapping is
  documented at bench_mitsuba.material_record).

Tasks
-----
* {"kind": "crosscheck", "spp": N, "pass_spp": k, "seed": s, "max_depth": D+1, "rr_depth": r, "name": ...}:
  a custom render loop that draws every camera sample's film position exactly as illum does
  (truncated Gaussian pixel filter importance-sampled from the tabulated inverse CDF exported
  with the scene, each sample counted with weight 1 in its own pixel), traces it with Mitsuba's
  own sensor and ``path`` integrator, and keeps per-pixel sums and sums of squares, so the
  result has a mean and a variance of the mean like illum's film.
* {"kind": "lightmask", "name": ...}: pixels whose centre ray hits an emitter shape.
* {"kind": "render", "spp": N, "seed": s, "max_depth": ..., "rr_depth": ..., "repeat": R, "name": ...}:
  ``mi.render`` with Mitsuba's own film and ``gaussian`` rfilter (stddev 0.5, radius 2), timed;
  the first call is a warm-up (kernel compilation) and is reported separately ("warmup": false skips it).

Serve mode ({"serve": true} in JOB.json, no "tasks"): ``render`` tasks read one per stdin line,
each answered "ok OUT.npz" (``serve``); bench/bench_film_mitsuba.py alternates them with illum's.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time

import numpy as np


def _write_ply(path: str, points: np.ndarray, normals: np.ndarray | None, uv: np.ndarray | None = None) -> None:
    """Binary little-endian PLY with unshared vertices (3 per triangle), optional normals and uv."""
    v = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    nv = v.shape[0]
    nf = nv // 3
    props = ["property float x", "property float y", "property float z"]
    cols = [v]
    if normals is not None:
        props += ["property float nx", "property float ny", "property float nz"]
        cols.append(np.asarray(normals, dtype=np.float32).reshape(-1, 3))
    if uv is not None:
        props += ["property float u", "property float v"]
        cols.append(np.asarray(uv, dtype=np.float32).reshape(-1, 2))
    header = "\n".join(["ply", "format binary_little_endian 1.0", f"element vertex {nv}", *props,
                        f"element face {nf}", "property list uchar int vertex_indices", "end_header"]) + "\n"
    vert = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    faces = np.zeros(nf, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = np.arange(nv, dtype=np.int32).reshape(nf, 3)
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(faces.tobytes())


def _texture(mi, param: dict, arrays: dict, raw: bool = True) -> dict | float:
    """A Mitsuba texture (or float) for an exported material parameter: {"value": [...]} is an
    ``rgb`` (3 values) or a float (1 value); {"tex": name, ...} a ``bitmap`` of the exported, already
    linear array (``raw``: no sRGB decode by Mitsuba)."""
    if "value" in param:
        v = [float(x) for x in param["value"]]
        return {"type": "rgb", "value": v} if len(v) == 3 else v[0]
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.asarray(arrays[param["tex"]], dtype=np.float32)), "raw": raw,
            "wrap_mode": param["wrap"], "filter_type": "nearest" if param.get("nearest") else "bilinear"}


def material_bsdf(mi, rec: dict, arrays: dict) -> dict:
    """The Mitsuba BSDF of an exported material record (bench_mitsuba.material_record documents the
    mapping): mask(twosided(normalmap(diffuse | principled)))."""
    if rec["type"] == "diffuse":
        bsdf = {"type": "diffuse", "reflectance": _texture(mi, rec["reflectance"], arrays)}
    else:
        bsdf = {"type": "principled", "base_color": _texture(mi, rec["base_color"], arrays),
                "roughness": _texture(mi, rec["roughness"], arrays), "metallic": _texture(mi, rec["metallic"], arrays),
                "eta": float(rec["eta"])}
    if "normalmap" in rec:
        bsdf = {"type": "normalmap", "normalmap": _texture(mi, rec["normalmap"], arrays), "bsdf": bsdf}
    bsdf = {"type": "twosided", "bsdf": bsdf}
    if "opacity" in rec:
        bsdf = {"type": "mask", "opacity": _texture(mi, rec["opacity"], arrays), "bsdf": bsdf}
    return bsdf


def _frame_to_world(mi, e1, e2, n, c):
    """Mitsuba to_world with columns (e1, e2, unit n, c), e1/e2 swapped if needed so e1 x e2 ~ +n."""
    e1, e2, n, c = (np.asarray(x, dtype=np.float64) for x in (e1, e2, n, c))
    if np.dot(np.cross(e1, e2), n) < 0.0:
        e1, e2 = e2, e1
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = e1, e2, n / np.linalg.norm(n), c
    return mi.ScalarTransform4f(M.tolist())


def build_scene_dict(mi, scene: dict, arrays: dict, tmpdir: str, max_depth: int, rr_depth: int,
                     rfilter: dict | None = None) -> dict:
    """The Mitsuba scene dict for an exported scene (see the module docstring)."""
    W, H = scene["resolution"]
    cam = scene["camera"]
    C = np.asarray(cam["camera_to_world"], dtype=np.float64)
    # Orthonormalise (a camera scale would only rescale clip distances, which we pass in world units).
    R = C[:3, :3] / np.linalg.norm(C[:3, :3], axis=0)
    flip = np.diag([-1.0, 1.0, -1.0])
    T = np.eye(4)
    T[:3, :3] = R @ flip
    T[:3, 3] = C[:3, 3]
    wx0, wx1, wy0, wy1 = cam["window"]
    fov_x = 2.0 * np.degrees(np.arctan(wx1))
    d = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": int(rr_depth)},
        "sensor": {
            "type": "perspective",
            "fov": float(fov_x),
            "fov_axis": "x",
            "near_clip": float(cam["near"]),
            "far_clip": float(cam["far"]),
            "to_world": mi.ScalarTransform4f(T.tolist()),
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {
                "type": "hdrfilm", "width": int(W), "height": int(H), "pixel_format": "rgb",
                "component_format": "float32",
                "rfilter": rfilter or {"type": "gaussian", "stddev": 0.5},
            },
        },
    }
    for i, m in enumerate(scene["meshes"]):
        ply = os.path.join(tmpdir, f"mesh{i}.ply")
        normals = arrays.get(f"mesh{i}_normals")
        _write_ply(ply, arrays[f"mesh{i}_points"], normals, arrays.get(f"mesh{i}_st"))
        shape = {"type": "ply", "filename": ply, "bsdf": material_bsdf(mi, m["material"], arrays)}
        if normals is None:
            shape["face_normals"] = True
        d[f"mesh{i}"] = shape
    # Transparent emitters by default, as illum's; but Mitsuba's ``path`` zeroes a camera path that
    # meets only null surfaces, so a light seen against the empty background renders black.
    # ``opaque_emitters`` (bench_mitsuba_table.py) makes them black diffuse: visible, opaque.
    emitter_bsdf = ({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
                    if scene.get("opaque_emitters") else {"type": "null"})
    for i, lt in enumerate(scene["lights"]):
        L = [float(x) for x in lt["L"]]
        em = {"type": "area", "radiance": {"type": "rgb", "value": L}}
        if lt["kind"] == "rect":
            d[f"light{i}"] = {"type": "rectangle", "emitter": em, "bsdf": emitter_bsdf,
                              "to_world": _frame_to_world(mi, np.asarray(lt["ex"]) / 2, np.asarray(lt["ey"]) / 2,
                                                          lt["n"], lt["center"])}
        elif lt["kind"] == "disk":
            d[f"light{i}"] = {"type": "disk", "emitter": em, "bsdf": emitter_bsdf,
                              "to_world": _frame_to_world(mi, lt["e1"], lt["e2"], lt["n"], lt["center"])}
        elif lt["kind"] == "sphere" and lt.get("point"):
            d[f"light{i}"] = {"type": "point", "position": [float(x) for x in lt["center"]],
                              "intensity": {"type": "rgb", "value": [float(x) for x in lt["I"]]}}
        elif lt["kind"] == "distant":
            d[f"light{i}"] = {"type": "directional", "direction": [float(x) for x in lt["direction"]],
                              "irradiance": {"type": "rgb", "value": [float(x) for x in lt["E"]]}}
        elif lt["kind"] == "sphere":
            d[f"light{i}"] = {"type": "sphere", "emitter": em, "bsdf": emitter_bsdf,
                              "center": [float(x) for x in lt["center"]], "radius": float(lt["radius"])}
        elif lt["kind"] == "dome" and f"light{i}_latlong" in arrays:
            img = envmap_bitmap(arrays[f"light{i}_latlong"], np.asarray(lt["rot"]), np.asarray(L),
                                int(lt.get("upsample", 16)))
            d[f"light{i}"] = {"type": "envmap", "bitmap": mi.Bitmap(img.astype(np.float32))}
        elif lt["kind"] == "dome":
            d[f"light{i}"] = {"type": "constant", "radiance": {"type": "rgb", "value": L}}
        else:
            raise ValueError(f"light kind {lt['kind']!r} is not exported")
    return d


def spec_latlong(img: np.ndarray, rot: np.ndarray, L: np.ndarray, d_world: np.ndarray) -> np.ndarray:
    """Radiance (n, 3) of a UsdLux lat-long dome toward world directions d (n, 3), nearest texel, from
    the OpenEXR convention that UsdLux cites: pixel (0, 0) at latitude +pi/2, longitude +pi; longitude 0
    is +Z, +pi/2 is +X; the top pole is the dome's local +Y (``rot`` is local-to-world)."""
    H, W = img.shape[:2]
    v = d_world @ rot  # world -> local (rot is orthonormal)
    lon = np.arctan2(v[:, 0], v[:, 2])
    lat = np.arcsin(np.clip(v[:, 1], -1.0, 1.0))
    col = np.floor((np.pi - lon) / (2.0 * np.pi) * W).astype(np.int64) % W
    row = np.clip(np.floor((np.pi / 2.0 - lat) / np.pi * H).astype(np.int64), 0, H - 1)
    return img[row, col] * L


def _mitsuba_envmap_dirs(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World directions (len(v), len(u), 3) of Mitsuba envmap lookup coordinates (to_world =
    identity), inverting its lookup uv = (atan2(x, -z) / 2pi, acos(y) / pi)."""
    phi, theta = np.meshgrid(2.0 * np.pi * u, np.pi * v)
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), -st * np.cos(phi)], axis=-1)


def envmap_bitmap(img: np.ndarray, rot: np.ndarray, L: np.ndarray, k: int) -> np.ndarray:
    """A Mitsuba envmap bitmap whose bilinear reconstruction follows the UsdLux dome's nearest-texel
    radiance (illum's lookup) except in thin, symmetric bands along the source texel edges.

    Where Mitsuba samples its bitmap (measured on Mitsuba 3.9 with a bitmap holding its own row and
    column indices): columns at texel centres, u = (i + 0.5) / wb; rows corner-aligned,
    v = j / (hb - 1), row 0 on the +Y pole. With wb = k W and hb = k H + 1, every source column
    edge falls midway between two bitmap columns and every source row edge falls on a bitmap row,
    which gets the mean of the two source rows; so each edge's interpolation ramp is centred on the
    edge and the error in any smooth integral (irradiance) is second order in 1/k.
    ``probe_envmap`` compares the result with the spec lookup on every run.
    """
    H, W = img.shape[:2]
    hb, wb = k * H + 1, k * W
    u = (np.arange(wb) + 0.5) / wb
    v = np.arange(hb) / (hb - 1)
    half = 0.25 / (k * H)  # a quarter of a bitmap row: safely inside the neighbouring source rows
    lo = _mitsuba_envmap_dirs(u, np.clip(v - half, 0.0, 1.0)).reshape(-1, 3)
    hi = _mitsuba_envmap_dirs(u, np.clip(v + half, 0.0, 1.0)).reshape(-1, 3)
    edge = (np.arange(hb) % k == 0)[:, None, None]
    val_lo = spec_latlong(img, rot, L, lo).reshape(hb, wb, 3)
    val_hi = spec_latlong(img, rot, L, hi).reshape(hb, wb, 3)
    mid = spec_latlong(img, rot, L, _mitsuba_envmap_dirs(u, v).reshape(-1, 3)).reshape(hb, wb, 3)
    return np.where(edge, 0.5 * (val_lo + val_hi), mid)


def probe_envmap(mi, sc, scene, arrays, n: int = 200000, seed: int = 5) -> dict:
    """Compare Mitsuba's envmap radiance with the spec lookup at random directions."""
    for i, lt in enumerate(scene["lights"]):
        if lt["kind"] == "dome" and f"light{i}_latlong" in arrays:
            break
    else:
        return {}
    env = sc.environment()
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(mi.Float(-d[:, 0]), mi.Float(-d[:, 1]), mi.Float(-d[:, 2]))
    val = env.eval(si)
    got = np.stack([np.array(val[c], dtype=np.float64) for c in range(3)], axis=1)
    want = spec_latlong(arrays[f"light{i}_latlong"], np.asarray(lt["rot"]), np.asarray(lt["L"]), d)
    rel = np.abs(got - want).sum(axis=1) / np.maximum(want.sum(axis=1), 1e-12)
    return {"env_mean_ratio": got.mean() / want.mean(), "env_median_rel": float(np.median(rel)),
            "env_frac_rel_gt_5pct": float(np.mean(rel > 0.05))}


def crosscheck(mi, dr, scene, arrays, task, tmpdir):
    """Mitsuba's sensor and ``path`` integrator with illum's pixel-filter sampling, accumulated per pixel
    (sum and sum of squares) on the Dr.Jit side; see the module docstring."""
    W, H = scene["resolution"]
    d = build_scene_dict(mi, scene, arrays, tmpdir, task["max_depth"], task["rr_depth"])
    sc = mi.load_dict(d)
    probe = probe_envmap(mi, sc, scene, arrays)
    sensor = sc.sensors()[0]
    integrator = sc.integrator()
    sampler = mi.load_dict({"type": "independent"})
    # illum's filter: x = np.interp(u, cdf, xs) on a uniform grid xs, i.e. a piecewise-constant pdf
    # with bin masses diff(cdf): pick the bin, then place u's remainder linearly inside it.
    xs, cdf = np.asarray(arrays["filter_x"]), np.asarray(arrays["filter_cdf"])
    dx = float(xs[1] - xs[0])
    if not np.allclose(np.diff(xs), dx, rtol=1e-9, atol=0.0):
        raise ValueError("the exported filter table is not on a uniform grid")
    bins = mi.DiscreteDistribution(mi.Float(np.diff(cdf).astype(np.float32)))
    x0 = float(xs[0])
    npix = W * H
    pass_spp = int(task["pass_spp"])
    passes = max(1, int(np.ceil(task["spp"] / pass_spp)))
    n_pass = npix * pass_spp
    s = dr.zeros(mi.Float, 3 * npix)
    s2 = dr.zeros(mi.Float, 3 * npix)
    t0, c0 = time.perf_counter(), time.process_time()
    for p in range(passes):
        sampler.seed((int(task["seed"]) * 1_000_003 + p) % 2**32, n_pass)
        pix = dr.arange(mi.UInt32, n_pass) % npix
        u = sampler.next_2d()
        ix, rx = bins.sample_reuse(u.x)
        iy, ry = bins.sample_reuse(u.y)
        fx = mi.Float(pix % W) + 0.5 + x0 + (mi.Float(ix) + rx) * dx
        fy = mi.Float(pix // W) + 0.5 + x0 + (mi.Float(iy) + ry) * dx
        ray, w = sensor.sample_ray(0.0, 0.5, mi.Point2f(fx / W, fy / H), mi.Point2f(0.5, 0.5))
        spec, _, _ = integrator.sample(sc, sampler, mi.RayDifferential3f(ray))
        spec = spec * w
        for c in range(3):
            dr.scatter_reduce(dr.ReduceOp.Add, s, spec[c], pix * 3 + c)
            dr.scatter_reduce(dr.ReduceOp.Add, s2, spec[c] * spec[c], pix * 3 + c)
        dr.eval(s, s2)
    s_np = np.array(s, dtype=np.float64).reshape(npix, 3)
    s2_np = np.array(s2, dtype=np.float64).reshape(npix, 3)
    secs = time.perf_counter() - t0
    cpu = time.process_time() - c0
    n = passes * pass_spp
    mean = s_np / n
    var = np.maximum(s2_np / n - mean ** 2, 0.0) * n / (n - 1) / n
    expo = float(scene["camera"]["exposure_scale"])
    return {"mean": (mean * expo).reshape(H, W, 3), "var": (var * expo * expo).reshape(H, W, 3),
            "spp": n, "seconds": secs, "cpu_seconds": cpu, **probe}


def lightmask(mi, dr, scene, arrays, task, tmpdir):
    W, H = scene["resolution"]
    sc = mi.load_dict(build_scene_dict(mi, scene, arrays, tmpdir, 2, 5))
    sensor = sc.sensors()[0]
    pix = np.arange(W * H)
    pos = mi.Point2f(mi.Float(((pix % W) + 0.5) / W), mi.Float(((pix // W) + 0.5) / H))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    si = sc.ray_intersect(ray)
    hit = np.array(si.is_valid() & (si.emitter(sc) != None), dtype=bool)  # noqa: E711 (drjit compare)
    return {"mask": hit.reshape(H, W)}


def render(mi, dr, scene, arrays, task, tmpdir, cache=None):
    """mi.render with Mitsuba's own film and Gaussian filter; time each call. With a ``cache`` dict
    (serve mode) the loaded scene is kept per (max_depth, rr_depth)."""
    key = (task["max_depth"], task["rr_depth"])
    sc = cache.get(key) if cache is not None else None
    if sc is None:
        sc = mi.load_dict(build_scene_dict(mi, scene, arrays, tmpdir, task["max_depth"], task["rr_depth"]))
        if cache is not None:
            cache[key] = sc
    out = {}
    spp = int(task["spp"])
    seed = int(task["seed"])
    expo = float(scene["camera"]["exposure_scale"])
    if task.get("warmup", True):
        t0 = time.perf_counter()
        img = np.array(mi.render(sc, spp=spp, seed=seed + 99991), dtype=np.float64)  # warm-up: compiles kernels
        out["warmup_seconds"] = time.perf_counter() - t0
    times, cpu = [], []
    acc = None
    for r in range(int(task.get("repeat", 1))):
        t0, c0 = time.perf_counter(), time.process_time()
        img = np.array(mi.render(sc, spp=spp, seed=seed + r), dtype=np.float64)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)  # all of Dr.Jit's worker threads are in this process
        acc = img if acc is None else acc + img
        if task.get("keep_each"):
            out[f"image{r}"] = img[..., :3] * expo
    out["image"] = acc[..., :3] / int(task.get("repeat", 1)) * expo
    out["seconds"] = np.array(times)
    out["cpu_seconds"] = np.array(cpu)
    out["spp"] = spp
    return out


def serve(mi, dr, scene, arrays, tmpdir) -> int:
    """Serve mode ({"serve": true} in JOB.json): one ``render`` task per stdin line (JSON, with an
    "out" npz path), answered by one stdout line "ok <out>", so a driver can alternate Mitsuba's
    runs with another renderer's while the loaded scene and Dr.Jit's compiled kernels stay warm."""
    cache: dict = {}
    print("ready", mi.__version__, dr.__version__, mi.variant(), flush=True)
    for line in sys.stdin:
        if not line.strip():
            continue
        task = json.loads(line)
        res = render(mi, dr, scene, arrays, task, tmpdir, cache)
        np.savez(task["out"], **{k: np.asarray(v) for k, v in res.items()})
        print("ok", task["out"], flush=True)
    return 0


def main() -> int:
    job = json.load(open(sys.argv[1]))
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(job.get("variant", "llvm_ad_rgb"))
    if job.get("threads"):
        dr.set_thread_count(int(job["threads"]))
    data = np.load(job["scene"], allow_pickle=False)
    scene = json.loads(str(data["scene_json"]))
    arrays = {k: data[k] for k in data.files if k != "scene_json"}
    results = {"mitsuba_version": np.array(mi.__version__), "drjit_version": np.array(dr.__version__),
               "variant": np.array(mi.variant())}
    with tempfile.TemporaryDirectory() as tmpdir:
        if job.get("serve"):
            return serve(mi, dr, scene, arrays, tmpdir)
        for task in job["tasks"]:
            fn = {"crosscheck": crosscheck, "lightmask": lightmask, "render": render}[task["kind"]]
            res = fn(mi, dr, scene, arrays, task, tmpdir)
            for k, v in res.items():
                results[f"{task['name']}/{k}"] = np.asarray(v)
            print(f"mitsuba_side: {task['name']} done", {k: (float(v) if np.ndim(v) == 0 else np.shape(v))
                                                         for k, v in res.items()}, flush=True)
    np.savez_compressed(job["out"], **results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
