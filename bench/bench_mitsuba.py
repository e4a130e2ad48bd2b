"""illum against Mitsuba 3: (A) a converged-image cross-check, (B) equal-time relMSE.

    .venv/bin/python bench/bench_mitsuba.py [STAGES ...] --mitsuba-python /work/scratch/mitsuba-venv/bin/python \
        --out bench/results/mitsuba

Mitsuba is *not* a dependency of illum: it runs in its own Python (a scratch venv with
``pip install mitsuba numpy``), as a subprocess executing ``bench/mitsuba_side.py``. This script
(project venv) reads each stage with illum's own reader (``renderer.usd.load_stage`` ->
``SceneDescription``) and exports a neutral scene file (npz + json): world-space triangles per
mesh, a diffuse albedo per mesh, the lights in UsdLux conventions with their *final* radiance
computed by illum's radiometry (``renderer.lights.radiometry.emitted_radiance``), the camera
(USD camera-to-world, the conformed screen window, clip range, exposure) and illum's tabulated
pixel-filter inverse CDF. ``mitsuba_side.py`` converts that to a Mitsuba scene dict (see its
docstring for every convention mapping).

Which stages qualify
--------------------
Lambertian-equivalent only: every material is UsdPreviewSurface with ``useSpecularWorkflow = 1``,
``specularColor = 0``, ``roughness = 1``, no textures, opacity 1, no emission; lights are rect,
disk, sphere (not treatAsPoint) or a dome (constant, or a lat-long texture without portals), with
no ShapingAPI/ShadowAPI/linking and diffuse = specular = 1; the camera is a pinhole perspective
camera with a symmetric window. Any other stage is listed as skipped with the reason. By default
the script checks ``stages/cornell_box.usda`` and the four ``stages/talk`` stages (penumbra and
dome qualify; sphere_occluder and large_rect have glossy floors and are reported as skipped), plus
four variants of the Cornell box written to a temp dir
(``--no-variants`` to skip): a sphere light, a tilted normalized disk light, a tilted,
non-uniformly scaled normalized rect light, and the ceiling light plus a constant dome.

Such a material is still not exactly Lambertian in illum: its diffuse lobe is
rho/pi (1 - E(wo)) (1 - E(wi)) / (1 - E_avg) with E the albedo of the specular lobe, which with
F0 = 0 keeps Schlick's (1 - cos)^5 grazing term (renderer/bsdfs/preview_surface.py). So part A
renders illum twice: ``shipped`` (the renderer as it is) and ``lambert`` (the same renderer with
``renderer.materials.MaterialTable.bsdf`` swapped for ``LambertBSDF`` *inside this process only*).
``lambert`` against Mitsuba's ``diffuse`` tests transport, lights, camera and filter exactly;
``shipped`` against it shows what the material model adds.

(A) cross-check
---------------
Both renderers converge at the same resolution (``--xc-width``, aspect kept), max depth D (illum
``max_depth = D`` scattering events; Mitsuba ``max_depth = D + 1`` because it counts the camera
segment) and Russian-roulette start (illum ``rr_depth = 3``; Mitsuba ``rr_depth = 3``, both
counting scattering events). Pixel filter: Mitsuba's camera samples are drawn exactly as illum
draws its own (the same truncated Gaussian, radius 1.5 px, sigma 0.5 px, importance-sampled, each
sample with weight 1 in its pixel) in a custom loop around Mitsuba's sensor and ``path``
integrator, so both images converge to the same filtered image. Reported per stage and variant:

* mean-radiance ratio illum/Mitsuba per channel, with its standard error from both films;
* median |illum - Mitsuba| / Mitsuba over pixel channels with Mitsuba > 1e-3, next to the median
  that noise alone would give (0.674 sqrt(var_i + var_m) / Mitsuba);
* the fraction of pixel channels with |illum - Mitsuba| > 3 sigma, sigma^2 = var_i + var_m (both
  films' variance of the mean; illum's from ``film.variance_of_mean()``); about 0.3 % for pure
  Gaussian noise, somewhat more with Monte Carlo's heavy tails;
* the same over the pixels that do not see a light directly (a 2-px dilation of the pixels whose
  centre ray hits an emitter). Those pixels differ by construction at max depth 1: Mitsuba counts
  a crossing of a (null-BSDF, i.e. transparent) light as a path vertex and illum does not, so the
  surface behind a visible light gets direct light only in illum; and Mitsuba's ``path`` returns 0
  for a path that meets only null-BSDF surfaces before its depth limit (it treats it as an
  escaped ray), so at D = 1 a sphere light, whose far side is also a null surface, renders black
  in Mitsuba. The ratios in the table are therefore taken over the 'surf.' pixels.

(B) equal time
--------------
Cornell box at ``--et-res`` (256x256), max depth 8, 2 threads each, budgets ``--budgets``
(1,2,4,8 s). illum: ``render(RenderOptions(time_budget=b))`` after a 1-spp warm-up (numba), the
measured ``stats.seconds.render``. Mitsuba: ``mi.render`` with its own film and Gaussian filter
(stddev 0.5, radius 2); it is timed at 1 and 4 spp, spp is picked for each budget, each render
size is warmed up once (kernel compilation, reported) and then timed. References (long Mitsuba
renders): for Mitsuba's native runs the same native pipeline; for illum's runs the custom loop
with illum's filter (the two filters differ slightly, so each is scored against a reference with
its own filter). Mitsuba also runs through that custom loop at each budget: Mitsuba's film splats
each sample into ~3 pixels' worth of Gaussian footprint, which lowers per-pixel variance ~3x at
equal spp, so only the same-filter rows compare like with like. relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 1e-2); each table
also gives the reference's own expected relMSE (its noise floor). The illum/Mitsuba ratio at equal
time is relMSE_illum(t) / relMSE_mitsuba(t), with Mitsuba's relMSE interpolated log-log at illum's
measured time.

Outputs in ``--out``: results.md, results.csv, error_vs_time.png, crosscheck_<stage>.png.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from renderer.camera import Camera  # noqa: E402
from renderer.description import SceneDescription  # noqa: E402
from renderer.lights.light_set import KIND_CLASSES  # noqa: E402
from renderer.lights.radiometry import emitted_radiance  # noqa: E402
from renderer.render import RenderOptions, render  # noqa: E402
from renderer.usd import load_stage  # noqa: E402

SIDE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "mitsuba_side.py")
DEFAULT_STAGES = ["stages/cornell_box.usda", "stages/talk/penumbra.usda", "stages/talk/dome.usda",
                  "stages/talk/sphere_occluder.usda", "stages/talk/large_rect.usda"]
EPS_REL = 1e-2


# ------------------------------------------------------------------------------ stage variants
_VARIANT_LIGHTS = {
    "cornell_sphere": '''        def SphereLight "CeilingLight"
        {
            color3f inputs:color = (1, 0.85, 0.6)
            float inputs:intensity = 30
            float inputs:radius = 4
            double3 xformOp:translate = (10, 42, 5)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
''',
    "cornell_disk": '''        def DiskLight "CeilingLight"
        {
            color3f inputs:color = (0.9, 0.95, 1)
            float inputs:intensity = 6000
            bool inputs:normalize = 1
            float inputs:radius = 6
            float xformOp:rotateX = -75
            float xformOp:rotateZ = 20
            double3 xformOp:translate = (-8, 50, 0)
            uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateZ", "xformOp:rotateX"]
        }
''',
    "cornell_rect_tilted": '''        def RectLight "CeilingLight"
        {
            color3f inputs:color = (1, 0.8, 0.6)
            float inputs:intensity = 2000
            bool inputs:normalize = 1
            float inputs:width = 10
            float inputs:height = 6
            float xformOp:rotateX = -60
            float xformOp:rotateY = 35
            float3 xformOp:scale = (1.5, 0.8, 1)
            double3 xformOp:translate = (6, 45, -5)
            uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY", "xformOp:rotateX", "xformOp:scale"]
        }
''',
    "cornell_dome": None,  # the original ceiling light plus a constant dome
}
_DOME = '''        def DomeLight "Sky"
        {
            color3f inputs:color = (0.6, 0.8, 1)
            float inputs:intensity = 0.5
        }
'''


def make_variants(cornell: str, outdir: str) -> list[str]:
    """Write the Cornell-box light variants (text edits of the .usda) into outdir."""
    text = open(cornell).read()
    m = re.search(r'^        def RectLight "CeilingLight".*?^        }\n', text, flags=re.S | re.M)
    if m is None:
        raise RuntimeError(f"{cornell}: CeilingLight block not found; update make_variants")
    paths = []
    for name, block in _VARIANT_LIGHTS.items():
        if block is None:
            new = text[: m.end()] + _DOME + text[m.end():]
        else:
            new = text[: m.start()] + block + text[m.end():]
        p = os.path.join(outdir, f"{name}.usda")
        with open(p, "w") as fh:
            fh.write(new)
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------ export
def _const(inp, what: str, path: str, errors: list[str]):
    if inp.texture is not None:
        errors.append(f"{path}: {what} is textured")
    return inp.value


def _lambert_equivalent(mat) -> bool:
    """Specular workflow with an untextured specularColor of 0: illum's UsdPreviewSurface has no
    specular lobe then (only the Schlick grazing term on the diffuse lobe, see the docstring)."""
    return (mat.use_specular_workflow and mat.specular_color.texture is None and mat.specular_color.primvar is None
            and not any(float(x) != 0.0 for x in np.ravel(mat.specular_color.value)))


def eligibility(desc: SceneDescription, full: bool = False) -> list[str]:
    """Reasons why the stage cannot be exported ([] = fine).

    full=False: exactly Mitsuba ``diffuse`` + area lights (the cross-check, part A). full=True: the
    approximate mapping of ``material_record`` (UsdPreviewSurface -> diffuse / principled with
    bitmap textures, normal maps and cut-outs) and ``export_scene``'s light mapping (adds distant
    lights and treatAsPoint spheres), for equal-time comparisons where each renderer is scored
    against its own reference (bench_mitsuba_table.py).
    """
    why: list[str] = []
    for mat in desc.materials:
        p = mat.path or "<fallback material>"
        if not full:
            _const(mat.diffuse_color, "diffuseColor", p, why)
            spec = _const(mat.specular_color, "specularColor", p, why)
            rough = _const(mat.roughness, "roughness", p, why)
            op = _const(mat.opacity, "opacity", p, why)
            if not _lambert_equivalent(mat):
                why.append(f"{p}: not specular workflow with specularColor 0 (has a specular lobe)")
            if float(rough) != 1.0:
                why.append(f"{p}: roughness {rough} != 1")
            if float(op) != 1.0:
                why.append(f"{p}: opacity {op}")
            if mat.normal.texture is not None:
                why.append(f"{p}: normal map")
        else:
            for f in ("diffuse_color", "specular_color", "metallic", "roughness", "opacity", "normal"):
                inp = getattr(mat, f)
                if inp.primvar is not None:
                    why.append(f"{p}: {f} read from a primvar")
                if inp.texture is not None and inp.texture.st_transform:
                    why.append(f"{p}: {f} texture has a UsdTransform2d")
            if mat.specular_color.texture is not None:
                why.append(f"{p}: specularColor is textured")
        em = _const(mat.emissive_color, "emissiveColor", p, why)
        if any(float(x) != 0.0 for x in np.ravel(em)):
            why.append(f"{p}: emissive")
    kinds = ("rect", "disk", "sphere", "dome", "distant") if full else ("rect", "disk", "sphere", "dome")
    for lt in desc.lights:
        if lt.kind not in kinds:
            why.append(f"{lt.path}: {lt.kind} light not exported")
        if lt.texture_file and not (lt.kind == "dome" and lt.texture_format in ("automatic", "latlong")):
            why.append(f"{lt.path}: textured light")
        if lt.portals is not None:
            why.append(f"{lt.path}: dome portals")
        if lt.kind == "sphere" and lt.treat_as_point and not full:
            why.append(f"{lt.path}: treatAsPoint")
        if lt.shaping is not None or lt.shadow is not None:
            why.append(f"{lt.path}: ShapingAPI/ShadowAPI")
        if lt.light_link_excludes or lt.shadow_link_excludes:
            why.append(f"{lt.path}: light linking")
        if float(lt.diffuse) != 1.0 or float(lt.specular) != 1.0:
            why.append(f"{lt.path}: diffuse/specular multiplier")
    cam = desc.camera
    if cam.projection != "perspective" or (cam.f_stop > 0 and cam.focus_distance > 0):
        why.append(f"{cam.path}: not a pinhole perspective camera")
    if cam.horizontal_aperture_offset or cam.vertical_aperture_offset:
        why.append(f"{cam.path}: aperture offsets")
    if desc.settings.pixel_aspect_ratio != 1.0 or tuple(desc.settings.data_window_ndc) != (0.0, 0.0, 1.0, 1.0):
        why.append("RenderSettings: pixel aspect / data window")
    return why


class TextureExport:
    """Textures decoded by illum's own ``TextureCache`` (sourceColorSpace, row 0 = bottom = t 0) and
    stored in the scene file as float32 (H, W, C) arrays with the UsdUVTexture scale and bias
    applied (a bilinear lookup commutes with them), one array per distinct use. Mitsuba's
    ``bitmap`` puts row 0 at v = 0, so with the mesh's uv = st no flip is needed (measured with a
    row-indexed bitmap on Mitsuba 3.9). Wrap modes map one to one, except 'black' (no Mitsuba
    equivalent), which becomes 'clamp'."""

    def __init__(self, arrays: dict):
        from renderer.textures import TextureCache, output_channels

        self.cache = TextureCache()
        self.channels = output_channels
        self.arrays = arrays
        self.keys: dict = {}

    def add(self, tex, width: int, encode=None, threshold: float | None = None) -> dict:
        """A texture parameter record {"tex": array name, "wrap": mode, "nearest": bool} for ``tex``'s
        connected output, broadcast or cut to ``width`` channels. encode: 'normal' stores the
        tangent-space normal n = texel * scale + bias re-encoded as (n + 1) / 2 (Mitsuba's
        ``normalmap`` decodes 2 v - 1); threshold: a 0/1 cut-out map (value >= threshold),
        looked up nearest so that it stays binary."""
        key = (tex, width, encode, threshold)
        if key not in self.keys:
            px = self.cache.image(tex)
            if px is None:
                raise ValueError(f"{tex.file}: texture could not be read")
            ch = list(self.channels(tex.output))
            val = px[..., ch].astype(np.float64) * np.asarray(tex.scale)[ch] + np.asarray(tex.bias)[ch]
            if val.shape[-1] != width:
                val = np.repeat(val[..., :1], width, axis=-1) if val.shape[-1] == 1 else val[..., :width]
            if encode == "normal":
                val = 0.5 * (val + 1.0)
            if threshold is not None:
                val = (val >= threshold).astype(np.float64)
            name = f"tex{len(self.keys)}"
            self.arrays[name] = np.ascontiguousarray(val, dtype=np.float32)
            wraps = {m: ("clamp" if m == "black" else m) for m in self.cache.wrap_modes(tex)}
            if len(set(wraps.values())) != 1:
                raise ValueError(f"{tex.file}: different s and t wrap modes are not exported")
            self.keys[key] = {"tex": name, "wrap": next(iter(wraps.values())), "nearest": threshold is not None}
        return self.keys[key]

    def param(self, inp, width: int) -> dict:
        """{"value": constant} or a texture record for a MaterialInput."""
        if inp.texture is not None:
            return self.add(inp.texture, width)
        v = np.ravel(np.asarray(inp.value, dtype=np.float64))
        return {"value": (v[:width] if v.size >= width else np.repeat(v[:1], width)).tolist()}


def material_record(mat, tex: TextureExport) -> dict:
    """UsdPreviewSurface -> a Mitsuba BSDF description (mitsuba_side.material_bsdf builds it).

    * specular workflow with specularColor 0 (no specular lobe in illum): ``diffuse`` with the
      diffuseColor (constant or texture). Exact for the cross-check's untextured, roughness-1 stages.
    * otherwise ``principled`` (Mitsuba's Disney BSDF, GGX with alpha = roughness^2 as in
      UsdPreviewSurface): base_color = diffuseColor, roughness, metallic (0 in the specular
      workflow), eta = ior in the metallic workflow; in the specular workflow eta from the mean of
      specularColor taken as F0 (eta = (1 + sqrt F0) / (1 - sqrt F0)), the colour of F0 dropped.
      Not equal to illum's model (Disney diffuse with retro-reflection, no energy-conserving
      diffuse/specular coupling like illum's 1 - E terms), only comparable in look.
    * normal map: ``normalmap`` around it (tangent frame from dp/du, i.e. the st parametrisation).
    * opacity: a ``mask`` outermost; with opacityThreshold > 0 a binary cut-out map.
    Surfaces are ``twosided`` (illum shades both sides): mask(twosided(normalmap(bsdf))).
    """
    rec: dict = {}
    if _lambert_equivalent(mat):
        rec["type"] = "diffuse"
        rec["reflectance"] = tex.param(mat.diffuse_color, 3)
    else:
        rec["type"] = "principled"
        rec["base_color"] = tex.param(mat.diffuse_color, 3)
        rec["roughness"] = tex.param(mat.roughness, 1)
        if mat.use_specular_workflow:
            f0 = float(np.clip(np.mean(np.asarray(mat.specular_color.value, dtype=np.float64)), 1e-4, 0.95))
            rec["metallic"] = {"value": [0.0]}
            rec["eta"] = (1.0 + math.sqrt(f0)) / (1.0 - math.sqrt(f0))
        else:
            rec["metallic"] = tex.param(mat.metallic, 1)
            rec["eta"] = float(max(mat.ior, 1.0 + 1e-3))
    if mat.normal.texture is not None:
        rec["normalmap"] = tex.add(mat.normal.texture, 3, encode="normal")
    op = mat.opacity
    if op.texture is not None:
        thr = float(mat.opacity_threshold)
        rec["opacity"] = tex.add(op.texture, 1, threshold=thr if thr > 0.0 else None)
    else:
        o = float(np.ravel(op.value)[0])
        if mat.opacity_threshold > 0.0:
            o = 1.0 if o >= mat.opacity_threshold else 0.0
        if o < 1.0:
            rec["opacity"] = {"value": [o]}
    return rec


def _normal_dir(M: np.ndarray, v) -> np.ndarray:
    """World direction of the local normal v under the 4x4 M (inverse transpose), unit length."""
    A = M[:3, :3]
    n = np.linalg.inv(A).T @ np.asarray(v, dtype=np.float64)
    return n / np.linalg.norm(n)


def export_scene(desc: SceneDescription, width: int, height: int, path: str, opaque_emitters: bool = False) -> dict:
    """Write the neutral scene file (npz with a json string) and return the json dict.

    Light geometry is derived here from the LightDesc and the UsdLux text (rect: width x height
    in local XY, disk: radius in local XY, both emitting toward local -Z; sphere: radius, outward),
    independently of renderer/lights; the radiance is illum's ``emitted_radiance`` with illum's
    world area, and the area derived here is checked against it. opaque_emitters: Mitsuba's
    emitter shapes get a black diffuse BSDF instead of the null one (mitsuba_side.build_scene_dict).
    """
    arrays: dict[str, np.ndarray] = {}
    textures = TextureExport(arrays)
    materials = [material_record(mat, textures) for mat in desc.materials]
    meshes = []
    for i, m in enumerate(desc.meshes):
        tri = np.asarray(m.points, dtype=np.float64)[np.asarray(m.triangles)]
        arrays[f"mesh{i}_points"] = tri.reshape(-1, 3)
        if m.normals is not None:
            arrays[f"mesh{i}_normals"] = np.asarray(m.normals, dtype=np.float64).reshape(-1, 3)
        if m.st is not None:
            arrays[f"mesh{i}_st"] = np.asarray(m.st, dtype=np.float64).reshape(-1, 2)
        meshes.append({"path": m.path, "material": materials[m.material], "triangles": int(tri.shape[0])})
    lights = []
    for lt in desc.lights:
        M = np.asarray(lt.light_to_world, dtype=np.float64)
        A = M[:3, :3]
        c = M[:3, 3]
        illum_area = KIND_CLASSES[lt.kind].world_area(lt) if lt.kind not in ("dome", "distant") else 1.0
        L = emitted_radiance(lt, illum_area)
        rec = {"path": lt.path, "kind": lt.kind, "L": L.tolist(), "illum_world_area": float(illum_area)}
        if lt.kind == "rect":
            ex, ey = A @ [lt.width, 0.0, 0.0], A @ [0.0, lt.height, 0.0]
            area = float(np.linalg.norm(np.cross(ex, ey)))
            rec.update(center=c.tolist(), ex=ex.tolist(), ey=ey.tolist(), n=_normal_dir(M, [0, 0, -1]).tolist())
        elif lt.kind == "disk":
            e1, e2 = A @ [lt.radius, 0.0, 0.0], A @ [0.0, lt.radius, 0.0]
            if abs(np.dot(e1, e2)) > 1e-9 * np.linalg.norm(e1) * np.linalg.norm(e2):
                raise ValueError(f"{lt.path}: sheared disk not exported")
            area = float(np.pi * np.linalg.norm(e1) * np.linalg.norm(e2))
            rec.update(center=c.tolist(), e1=e1.tolist(), e2=e2.tolist(), n=_normal_dir(M, [0, 0, -1]).tolist())
        elif lt.kind == "sphere":
            s = np.linalg.svd(A, compute_uv=False)
            if s[0] - s[-1] > 1e-9 * s[0]:
                raise ValueError(f"{lt.path}: non-uniformly scaled sphere not exported")
            r = float(lt.radius * s[0])
            area = 4.0 * np.pi * r * r
            rec.update(center=c.tolist(), radius=r)
            if lt.treat_as_point:
                # A point light of intensity I = L pi r^2 (W/sr per unit colour), illum's own value.
                from renderer.lights.sphere import SphereLight

                area = illum_area
                rec.update(point=True, I=SphereLight.point_intensity(lt).tolist())
        elif lt.kind == "distant":
            from renderer.lights.distant import DistantLight
            from renderer.lights.radiometry import distant_size_factor

            # Mitsuba's ``directional`` is a delta light: its irradiance at normal incidence is the
            # cone's, L pi sin^2(theta_max) (radiometry's size factor; for angle 0 L already is it).
            area = illum_area
            E = L * (distant_size_factor(lt.angle) if lt.angle > 0.0 else 1.0)
            rec.update(direction=(-DistantLight.world_axis(lt)).tolist(), E=E.tolist(), angle=float(lt.angle))
        else:
            area = 1.0
            # The dome's frame: the rotation of its transform (polar decomposition), top pole local +Y.
            u, _, vt = np.linalg.svd(A)
            rec["rot"] = (u @ vt).tolist()
            if lt.texture_file:
                from renderer.lights.dome import DomeLight

                arrays[f"light{len(lights)}_latlong"] = np.asarray(DomeLight.load_latlong(lt), dtype=np.float64)
        rec["world_area"] = area
        if lt.kind != "dome" and not math.isclose(area, illum_area, rel_tol=1e-9):
            rec["area_mismatch"] = f"spec area {area:.9g} vs illum world_area {illum_area:.9g}"
        lights.append(rec)
    cam = Camera(desc.camera, width, height, desc.settings.pixel_aspect_ratio,
                 desc.settings.aspect_ratio_conform_policy)
    wx0, wx1, wy0, wy1 = cam.window
    if not (math.isclose(wx0, -wx1, rel_tol=1e-9) and math.isclose(wy0, -wy1, rel_tol=1e-9)):
        raise ValueError("asymmetric camera window not exported")
    if not math.isclose((wx1 - wx0) / (wy1 - wy0), width / height, rel_tol=1e-6):
        raise ValueError("window aspect != image aspect")
    scale = float(np.linalg.norm(cam.camera_to_world[:3, 2]))
    arrays["filter_x"] = np.asarray(cam.filter._x, dtype=np.float64)
    arrays["filter_cdf"] = np.asarray(cam.filter._cdf, dtype=np.float64)
    scene = {
        "source": desc.source, "resolution": [int(width), int(height)], "meshes": meshes, "lights": lights,
        "opaque_emitters": bool(opaque_emitters),
        "camera": {"path": desc.camera.path, "camera_to_world": cam.camera_to_world.tolist(),
                   "window": [wx0, wx1, wy0, wy1], "near": cam.near * scale, "far": cam.far * scale,
                   "exposure_scale": float(desc.camera.exposure_scale)},
        "filter": {"kind": "truncated gaussian, importance sampled", "radius": float(cam.filter.radius)},
    }
    np.savez_compressed(path, scene_json=np.array(json.dumps(scene)), **arrays)
    return scene


# ------------------------------------------------------------------------------ illum runs
@contextlib.contextmanager
def lambert_materials():
    """Swap illum's UsdPreviewSurface BSDF for LambertBSDF(diffuseColor) in this process only."""
    from renderer.bsdfs.lambert import LambertBSDF
    from renderer.materials import MaterialTable

    orig = MaterialTable.bsdf

    def lambert(self, mat, params=None):
        # Plain materials give no params (the integrator skips evaluate): read the table.
        rho = params.diffuse if params is not None else self.const["diffuse"][mat]
        return LambertBSDF(np.clip(rho, 0.0, 1.0))

    orig_packed = MaterialTable.packed_bsdf
    MaterialTable.bsdf = lambert
    # No packed UsdPreviewSurface rows: the compiled path vertex (which reads them) stands aside.
    MaterialTable.packed_bsdf = lambda self: None
    try:
        yield
    finally:
        MaterialTable.bsdf = orig
        MaterialTable.packed_bsdf = orig_packed


def illum_render(stage, variant, **kw):
    ctx = lambert_materials() if variant == "lambert" else contextlib.nullcontext()
    if variant == "lambert":
        kw["fast_path"] = False  # the fast path reads UsdPreviewSurface rows, not the swapped BSDF
    with ctx:
        t0 = time.process_time()
        res = render(stage, RenderOptions(**kw))
        cpu = time.process_time() - t0
    return res, cpu


def run_mitsuba(args, scene_npz: str, tasks: list[dict], tag: str) -> dict:
    job = {"scene": scene_npz, "variant": args.mitsuba_variant, "threads": args.threads, "tasks": tasks,
           "out": os.path.join(args.work, f"{tag}_mitsuba.npz")}
    jf = os.path.join(args.work, f"{tag}_job.json")
    with open(jf, "w") as fh:
        json.dump(job, fh)
    t0 = time.perf_counter()
    proc = subprocess.run([args.mitsuba_python, SIDE, jf], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"mitsuba_side failed ({tag}):\n{proc.stdout}\n{proc.stderr}")
    if not args.quiet:
        print(proc.stdout.strip(), f"[{time.perf_counter() - t0:.1f} s]", flush=True)
    d = np.load(job["out"])
    return {k: d[k] for k in d.files}


# ------------------------------------------------------------------------------ statistics
def compare(x: np.ndarray, vx: np.ndarray, ref: np.ndarray, vref: np.ndarray, mask: np.ndarray | None) -> dict:
    """Cross-check statistics of image x (illum) against ref (Mitsuba), both with variance of the mean."""
    if mask is not None:
        x, vx, ref, vref = x[mask], vx[mask], ref[mask], vref[mask]
    x, vx, ref, vref = (a.reshape(-1, 3).astype(np.float64) for a in (x, vx, ref, vref))
    n = x.shape[0]
    sx, sr = x.sum(axis=0), ref.sum(axis=0)
    ratio = sx / sr
    ratio_se = np.abs(ratio) * np.sqrt(vx.sum(axis=0) / sx ** 2 + vref.sum(axis=0) / sr ** 2)
    d = x - ref
    sig = np.sqrt(vx + vref)
    ok = ref > 1e-3
    rel = np.abs(d[ok]) / ref[ok]
    rel_noise = 0.6745 * sig[ok] / ref[ok]
    z = np.where(sig > 0, d / np.where(sig > 0, sig, 1.0), 0.0)
    return {
        "pixels": int(n),
        "ratio": ratio.tolist(), "ratio_se": ratio_se.tolist(),
        "ratio_z": ((ratio - 1.0) / np.maximum(ratio_se, 1e-300)).tolist(),
        "median_rel": float(np.median(rel)) if rel.size else float("nan"),
        "median_rel_noise": float(np.median(rel_noise)) if rel.size else float("nan"),
        "frac_3sigma": float(np.mean(np.abs(z) > 3.0)),
        "mean_z": float(np.mean(z)),
    }


def relmse(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + EPS_REL)))


def dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    H, W = mask.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            sh = np.zeros_like(mask)
            ys, yd = (slice(max(dy, 0), H), slice(0, H - max(dy, 0))) if dy >= 0 else (slice(0, H + dy), slice(-dy, H))
            xs, xd = (slice(max(dx, 0), W), slice(0, W - max(dx, 0))) if dx >= 0 else (slice(0, W + dx), slice(-dx, W))
            sh[yd, xd] = mask[ys, xs]
            out |= sh
    return out


# ------------------------------------------------------------------------------ part A
def crosscheck_stage(args, stage: str, name: str, rows: list, notes: list) -> None:
    desc = load_stage(stage)
    why = eligibility(desc)
    if why:
        notes.append(f"**{name}** skipped: " + "; ".join(sorted(set(why))[:6]))
        print(f"[A] {name}: skipped ({why[0]})", flush=True)
        return
    W0, H0 = desc.settings.resolution
    W = min(args.xc_width, W0)
    H = max(1, int(round(H0 * W / W0)))
    npz = os.path.join(args.work, f"{name}_scene.npz")
    scene = export_scene(desc, W, H, npz)
    for lt in scene["lights"]:
        if "area_mismatch" in lt:
            notes.append(f"**{name}** {lt['path']}: {lt['area_mismatch']}")
    depths = [int(x) for x in args.depths.split(",")]
    tasks = [{"kind": "lightmask", "name": "mask"}]
    for D in depths:
        tasks.append({"kind": "crosscheck", "name": f"D{D}", "spp": args.xc_spp_mitsuba, "pass_spp": args.pass_spp,
                      "seed": 17 + D, "max_depth": D + 1, "rr_depth": args.rr_depth})
    mres = run_mitsuba(args, npz, tasks, name)
    mask_light = dilate(mres["mask/mask"].astype(bool), 2)
    probe = {k.split("/", 1)[1]: float(v) for k, v in mres.items() if k.startswith(f"D{depths[0]}/env_")}
    if probe:
        notes.append(f"**{name}** lat-long dome as a Mitsuba envmap (16x finer bitmap laid out so that Mitsuba's bilinear "
                     f"lookup follows the UsdLux/OpenEXR nearest-texel lookup up to thin edge-centred bands; see "
                     f"mitsuba_side.envmap_bitmap): at 200k random directions Mitsuba's radiance / the spec lookup = "
                     f"{probe['env_mean_ratio']:.4f} on average, median relative difference {probe['env_median_rel']:.2e}, "
                     f"{100 * probe['env_frac_rel_gt_5pct']:.2f} % of directions differ by > 5 % (texel-edge bands).")
    variants = args.illum_variants.split(",")
    figs = []
    for D in depths:
        ref, vref = mres[f"D{D}/mean"], mres[f"D{D}/var"]
        for var in variants:
            res, cpu = illum_render(stage, var, spp=args.xc_spp_illum, resolution=(W, H), max_depth=D,
                                    rr_depth=args.rr_depth, threads=args.threads, seed=5)
            x = res.film.mean().astype(np.float64)
            vx = res.film.variance_of_mean()
            s_all = compare(x, vx, ref, vref, None)
            s_surf = compare(x, vx, ref, vref, ~mask_light) if mask_light.any() else s_all
            row = {"stage": name, "max_depth": D, "illum": var, "res": f"{W}x{H}",
                   "spp_illum": res.stats["spp"], "spp_mitsuba": int(mres[f"D{D}/spp"]),
                   "illum_s": round(res.stats["seconds"]["render"], 1),
                   "mitsuba_s": round(float(mres[f"D{D}/seconds"]), 1),
                   "light_px": int(mask_light.sum()), "all": s_all, "surf": s_surf}
            rows.append(row)
            figs.append((f"{name} D={D} {var}", x, ref, vx, vref))
            print(f"[A] {name} D={D} {var}: ratio surf {np.round(s_surf['ratio'], 4)} ± {np.round(s_surf['ratio_se'], 4)}, "
                  f">3σ {100 * s_all['frac_3sigma']:.2f}% (surf {100 * s_surf['frac_3sigma']:.2f}%), "
                  f"median rel {s_all['median_rel']:.4f} (noise {s_all['median_rel_noise']:.4f})", flush=True)
    _crosscheck_figure(os.path.join(args.out, f"crosscheck_{name}.png"), figs)


def _tonemap(img):
    return np.clip(np.power(np.clip(img, 0, None) / (1 + np.clip(img, 0, None)), 1 / 2.2), 0, 1)


def _crosscheck_figure(path, figs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(figs), 4, figsize=(13, 3.1 * len(figs)), squeeze=False)
    for r, (title, x, ref, vx, vref) in enumerate(figs):
        z = (x - ref) / np.sqrt(np.maximum(vx + vref, 1e-30))
        rel = (x - ref) / (np.abs(ref) + 1e-2)
        axes[r, 0].imshow(_tonemap(x))
        axes[r, 0].set_title(f"illum  {title}", fontsize=8)
        axes[r, 1].imshow(_tonemap(ref))
        axes[r, 1].set_title("Mitsuba 3", fontsize=8)
        im = axes[r, 2].imshow(rel.mean(axis=2), cmap="RdBu_r", vmin=-0.05, vmax=0.05)
        axes[r, 2].set_title("(illum - Mitsuba) / (Mitsuba + 0.01), RGB mean", fontsize=8)
        fig.colorbar(im, ax=axes[r, 2], fraction=0.046)
        im = axes[r, 3].imshow(z.mean(axis=2), cmap="RdBu_r", vmin=-4, vmax=4)
        axes[r, 3].set_title("z = Δ / σ (RGB mean)", fontsize=8)
        fig.colorbar(im, ax=axes[r, 3], fraction=0.046)
        for a in axes[r]:
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    import io

    from PIL import Image  # matplotlib's own dependency

    buf = io.BytesIO()
    fig.savefig(buf, dpi=80, format="png")
    plt.close(fig)
    # A 256-colour palette keeps the committed figures ~3x smaller at no visible cost.
    img = Image.open(io.BytesIO(buf.getvalue())).convert("RGB")
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(path, optimize=True)


# ------------------------------------------------------------------------------ part B
def equal_time(args, results: dict) -> None:
    stage = os.path.join(ROOT, "stages/cornell_box.usda")
    W, H = args.et_res
    D = 8
    desc = load_stage(stage)
    npz = os.path.join(args.work, "et_scene.npz")
    export_scene(desc, W, H, npz)
    budgets = [float(b) for b in args.budgets.split(",")]

    # Mitsuba: throughput from 1- and 4-spp renders, then one timed render per budget. The same for
    # the custom loop with illum's pixel filter (16 and 64 spp probes, the first one warms it up).
    xc = dict(max_depth=D + 1, rr_depth=args.rr_depth)
    probe = run_mitsuba(args, npz, [
        {"kind": "render", "name": "p1", "spp": 1, "seed": 1000, "repeat": 3, **xc},
        {"kind": "render", "name": "p4", "spp": 4, "seed": 2000, "repeat": 3, **xc},
        {"kind": "crosscheck", "name": "w16", "spp": 16, "pass_spp": 16, "seed": 2500, **xc},
        {"kind": "crosscheck", "name": "q16", "spp": 16, "pass_spp": 16, "seed": 3000, **xc},
        {"kind": "crosscheck", "name": "q64", "spp": 64, "pass_spp": 64, "seed": 4000, **xc},
    ], "et_probe")
    t1 = float(np.median(probe["p1/seconds"]))
    t4 = float(np.median(probe["p4/seconds"]))
    per_spp = max((t4 - t1) / 3.0, 1e-4)
    fixed = max(t1 - per_spp, 0.0)
    spps = [max(1, int(round((b - fixed) / per_spp))) for b in budgets]
    q16, q64 = float(probe["q16/seconds"]), float(probe["q64/seconds"])
    per_spp_if = max((q64 - q16) / 48.0, 1e-4)
    fixed_if = max(q16 - 16 * per_spp_if, 0.0)
    spps_if = []
    for b in budgets:
        n = max(1, int(round((b - fixed_if) / per_spp_if)))
        spps_if.append(n if n <= 64 else 64 * max(1, int(round(n / 64))))
    tasks = [{"kind": "render", "name": f"b{i}", "spp": s, "seed": 100 * (i + 1), "repeat": 1, **xc}
             for i, s in enumerate(spps)]
    tasks.append({"kind": "crosscheck", "name": "wif", "spp": 16, "pass_spp": 16, "seed": 5000, **xc})  # warm-up
    tasks += [{"kind": "crosscheck", "name": f"f{i}", "spp": s, "pass_spp": min(s, 64), "seed": 200 * (i + 1), **xc}
              for i, s in enumerate(spps_if)]
    ref_n = args.ref_repeats
    tasks.append({"kind": "render", "name": "ref", "spp": args.ref_spp, "seed": 777000, "max_depth": D + 1,
                  "rr_depth": args.rr_depth, "repeat": ref_n, "keep_each": True})
    tasks.append({"kind": "crosscheck", "name": "ref_if", "spp": args.ref_spp * ref_n, "pass_spp": args.pass_spp,
                  "seed": 888, "max_depth": D + 1, "rr_depth": args.rr_depth})
    load_before = os.getloadavg()
    mres = run_mitsuba(args, npz, tasks, "et")
    ref_m = mres["ref/image"]
    each = np.stack([mres[f"ref/image{r}"] for r in range(ref_n)])
    var_ref_m = each.var(axis=0, ddof=1) / ref_n
    ref_i, var_ref_i = mres["ref_if/mean"], mres["ref_if/var"]
    floor_m = float(np.mean(var_ref_m / (ref_m ** 2 + EPS_REL)))
    floor_i = float(np.mean(var_ref_i / (ref_i ** 2 + EPS_REL)))
    runs = []
    for i, b in enumerate(budgets):
        img = mres[f"b{i}/image"]
        secs = float(mres[f"b{i}/seconds"][0])
        runs.append({"renderer": "mitsuba", "config": f"path (mi.render, {args.mitsuba_variant})", "budget": b,
                     "seconds": secs, "cpu_s": float(mres[f"b{i}/cpu_seconds"][0]), "spp": spps[i], "samples_per_s": W * H * spps[i] / secs,
                     "relmse": relmse(img, ref_m), "warmup_s": float(mres[f"b{i}/warmup_seconds"]),
                     "mean_ratio": float(img.mean() / ref_m.mean())})
    for i, b in enumerate(budgets):
        img = mres[f"f{i}/mean"]
        secs = float(mres[f"f{i}/seconds"])
        runs.append({"renderer": "mitsuba", "config": "path, illum's pixel filter (custom loop)", "budget": b,
                     "seconds": secs, "cpu_s": float(mres[f"f{i}/cpu_seconds"]), "spp": spps_if[i],
                     "samples_per_s": W * H * spps_if[i] / secs, "relmse": relmse(img, ref_i),
                     "mean_ratio": float(img.mean() / ref_i.mean())})

    # illum configurations.
    configs = [("mis (default)", "shipped", {}), ("mis, Lambert BSDF (bench swap)", "lambert", {})]
    for cfg in args.illum_configs.split(";"):
        cfg = cfg.strip()
        if not cfg:
            continue
        est, n = cfg.split(":")
        configs.append((f"{est}, --light-samples {n}", "shipped",
                        {"estimator": {"": est}, "light_samples": {"": int(n)}}))
    for label, var, extra in configs:
        cache: dict = {}
        with (lambert_materials() if var == "lambert" else contextlib.nullcontext()):
            render(stage, RenderOptions(spp=1, resolution=(W, H), max_depth=D, rr_depth=args.rr_depth,
                                        threads=args.threads, seed=99, **extra), scene_cache=cache)  # warm-up
            for i, b in enumerate(budgets):
                t0 = time.process_time()
                res = render(stage, RenderOptions(time_budget=b, resolution=(W, H), max_depth=D, rr_depth=args.rr_depth,
                                                  threads=args.threads, seed=10 + i, **extra), scene_cache=cache)
                cpu = time.process_time() - t0
                img = res.film.mean().astype(np.float64)
                secs = res.stats["seconds"]["render"]
                runs.append({"renderer": "illum", "config": label, "budget": b, "seconds": secs, "cpu_s": cpu,
                             "spp": res.stats["spp"], "samples_per_s": res.stats["samples_per_second"],
                             "relmse": relmse(img, ref_i), "relmse_vs_native_ref": relmse(img, ref_m),
                             "mean_ratio": float(img.mean() / ref_i.mean())})
                print(f"[B] illum {label} {b}s: {res.stats['spp']} spp, relMSE {runs[-1]['relmse']:.4g}", flush=True)
    load_after = os.getloadavg()
    results["equal_time"] = {"res": [W, H], "max_depth": D, "budgets": budgets, "runs": runs,
                             "mitsuba_probe": {"t1": t1, "t4": t4, "per_spp": per_spp, "fixed": fixed,
                                               "warmup_1spp": float(probe["p1/warmup_seconds"])},
                             "floor_native": floor_m, "floor_illum_filter": floor_i,
                             "ref_spp": args.ref_spp * ref_n,
                             "ref_filters_relmse": relmse(ref_m, ref_i),
                             "load_before": load_before, "load_after": load_after}
    for r in runs:
        if r["renderer"] == "mitsuba":
            print(f"[B] mitsuba {r['budget']}s: {r['spp']} spp in {r['seconds']:.2f}s, relMSE {r['relmse']:.4g}", flush=True)


def _interp_loglog(t, ts, ys):
    lt, lts, lys = np.log(t), np.log(ts), np.log(ys)
    order = np.argsort(lts)
    lts, lys = lts[order], lys[order]
    if lt <= lts[0] or lt >= lts[-1]:  # extrapolate along the end segment
        i = 0 if lt <= lts[0] else len(lts) - 2
    else:
        i = int(np.searchsorted(lts, lt)) - 1
    s = (lys[i + 1] - lys[i]) / (lts[i + 1] - lts[i])
    return float(np.exp(lys[i] + s * (lt - lts[i])))


# ------------------------------------------------------------------------------ reporting
def _versions(args, mres_versions) -> dict:
    import importlib.metadata as md

    v = {}
    for pkg in ("numpy", "embreex", "usd-core", "OpenImageIO", "numba", "matplotlib"):
        try:
            v[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            v[pkg] = "-"
    v.update(mres_versions)
    return v


def _cpu() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def git_state() -> str:
    """HEAD and whether renderer/ had uncommitted edits when the run started (others may edit it)."""
    try:
        head = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "renderer"], capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" + uncommitted changes in renderer/" if dirty else "")


def mitsuba_versions(args) -> dict:
    out = subprocess.run([args.mitsuba_python, "-c",
                          "import mitsuba as mi, drjit as dr, numpy, platform; mi.set_variant(%r); "
                          "print(mi.__version__, dr.__version__, numpy.__version__, platform.python_version())"
                          % args.mitsuba_variant], capture_output=True, text=True, check=True).stdout.split()
    llvm = ""
    with contextlib.suppress(Exception):
        llvm = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "libllvm19"], capture_output=True,
                              text=True).stdout.strip()
    return {"mitsuba": out[0], "drjit": out[1], "mitsuba-venv numpy": out[2], "mitsuba-venv python": out[3],
            "libllvm19 (Debian)": llvm or "-"}


def write_report(args, results: dict, rows: list, notes: list, cmd: str) -> None:
    os.makedirs(args.out, exist_ok=True)
    md = []
    md.append("# illum vs Mitsuba 3\n")
    md.append(f"Command: `{cmd}`\n")
    m = results["machine"]
    md.append(f"Machine: {m['cpu']}, {m['cores']} cores, {m['platform']}, Python {m['python']}. "
              f"Load average (1/5/15 min) at start {m['load_start']}, before part B {m.get('load_before_B', '-')}, "
              f"at end {m.get('load_end', '-')}. The machine is shared with other agents: prefer the ratios.\n")
    if m.get("earlier_run"):
        e = m["earlier_run"]
        md.append(f"This report merges two runs (`--update`); the earlier run: working tree {e.get('git')}, load average "
                  f"at start {e.get('load_start')}, before part B {e.get('load_before_B')}, at end {e.get('load_end')}.\n")
    md.append(f"illum working tree: {m.get('git', 'unknown')}.\n")
    md.append("Versions: " + ", ".join(f"{k} {v}" for k, v in m["versions"].items()) +
              f"; Mitsuba variant `{args.mitsuba_variant}`; threads {args.threads} for both renderers.\n")
    if rows:
        md.append("## A. Cross-check (converged images)\n")
        md.append(f"illum {args.xc_spp_illum} spp, Mitsuba {args.xc_spp_mitsuba} spp, rr_depth {args.rr_depth} (both), "
                  "Mitsuba max_depth = D + 1, same pixel filter (illum's, see the script docstring). "
                  "`shipped` = illum as it is; `lambert` = illum with its BSDF swapped for LambertBSDF in the bench process. "
                  "'surf.' = the pixels that do not see a light directly (2-px dilation of the light pixels removed; "
                  "at D = 1 Mitsuba's light pixels differ by construction, see the script docstring). "
                  "ratio = Σillum/ΣMitsuba per channel ± 1 s.e.; z of the ratio = (ratio − 1)/s.e.; median rel = median |Δ|/Mitsuba "
                  "(noise-only expectation in brackets); >3σ = fraction of pixel channels with |Δ| > 3σ "
                  "(σ² = both films' variance of the mean).\n")
        md.append("| stage | D | illum | res | spp i/M | ratio R (surf.) | ratio G (surf.) | ratio B (surf.) | z of ratio (R,G,B) | ratio all px (R,G,B) | median rel surf. (noise) | >3σ surf. | >3σ all | mean z surf. |")
        md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            a, s = r["all"], r["surf"]
            md.append(f"| {r['stage']} | {r['max_depth']} | {r['illum']} | {r['res']} | {r['spp_illum']}/{r['spp_mitsuba']} | "
                      + " | ".join(f"{s['ratio'][c]:.4f} ± {s['ratio_se'][c]:.4f}" for c in range(3))
                      + f" | {', '.join(f'{z:+.1f}' for z in s['ratio_z'])} | {', '.join(f'{x:.4f}' for x in a['ratio'])} | "
                      f"{s['median_rel']:.4f} ({s['median_rel_noise']:.4f}) | "
                      f"{100 * s['frac_3sigma']:.2f} % | {100 * a['frac_3sigma']:.2f} % | {s['mean_z']:+.3f} |")
        md.append("")
    for n in notes:
        md.append(f"* {n}")
    if notes:
        md.append("")
    et = results.get("equal_time")
    if et:
        md.append("## B. Equal time (Cornell box)\n")
        W, H = et["res"]
        md.append(f"{W}x{H}, max depth {et['max_depth']}, {args.threads} threads each. Mitsuba probe: 1 spp {et['mitsuba_probe']['t1']:.3f} s, "
                  f"4 spp {et['mitsuba_probe']['t4']:.3f} s (first-call compile of the 1-spp kernel {et['mitsuba_probe']['warmup_1spp']:.2f} s, "
                  "not counted). References: Mitsuba, "
                  f"{et['ref_spp']} spp each; noise floor (the reference's own expected relMSE) {et['floor_native']:.2e} (native filter, "
                  f"for Mitsuba's runs) and {et['floor_illum_filter']:.2e} (illum's filter, for illum's runs); relMSE between the two "
                  f"references (the filter difference) {et['ref_filters_relmse']:.2e}. Load average before/after B: "
                  f"{tuple(round(x, 2) for x in et['load_before'])} / {tuple(round(x, 2) for x in et['load_after'])}.\n")
        native = [r for r in et["runs"] if r["renderer"] == "mitsuba" and "custom" not in r["config"]]
        same_f = [r for r in et["runs"] if r["renderer"] == "mitsuba" and "custom" in r["config"]]
        curves = {"native": (np.array([r["seconds"] for r in native]), np.array([r["relmse"] for r in native])),
                  "same_filter": (np.array([r["seconds"] for r in same_f]), np.array([r["relmse"] for r in same_f]))}
        md.append("Pixel filters: Mitsuba's own film *splats* every sample into all pixels within its Gaussian's radius "
                  "(stddev 0.5 px, radius 2 px), so each pixel averages about 4πσ² ≈ 3 samples' worth per spp (with noise "
                  "correlated between neighbours); illum draws each sample's position from its Gaussian and adds it to one "
                  "pixel. Per-pixel relMSE therefore favours splatting about 3x at equal samples. The row 'illum's pixel filter "
                  "(custom loop)' runs Mitsuba's sensor and `path` integrator with illum's filter sampling (the bench's "
                  "cross-check loop, accumulating on the Dr.Jit side; its samples/s match mi.render's): that is the "
                  "like-for-like comparison.\n")
        md.append("relMSE ratio = relMSE_illum / relMSE_Mitsuba at illum's measured wall time (Mitsuba interpolated log-log), "
                  "against Mitsuba with illum's filter (and, in brackets, against Mitsuba's native pipeline); "
                  "efficiency = 1/(relMSE × seconds), and the CPU column uses process CPU seconds (all threads), "
                  "which is less sensitive to the other agents' load.\n")
        md.append("| renderer | config | budget s | measured s | CPU s | spp | samples/s | samples/CPU-s | relMSE | relMSE ratio vs Mitsuba at equal time | efficiency | efficiency (CPU) | mean/ref |")
        md.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in et["runs"]:
            ratio = ""
            if r["renderer"] == "illum" and len(native) >= 2:
                r["ratio_vs_mitsuba_native"] = r["relmse"] / _interp_loglog(r["seconds"], *curves["native"])
                ratio = f"({r['ratio_vs_mitsuba_native']:.1f})"
                if len(same_f) >= 2:
                    r["ratio_vs_mitsuba_same_filter"] = r["relmse"] / _interp_loglog(r["seconds"], *curves["same_filter"])
                    ratio = f"{r['ratio_vs_mitsuba_same_filter']:.1f} " + ratio
            npx = W * H * r["spp"]
            md.append(f"| {r['renderer']} | {r['config']} | {r['budget']:g} | {r['seconds']:.2f} | {r['cpu_s']:.2f} | {r['spp']} | "
                      f"{r['samples_per_s']:.3g} | {npx / r['cpu_s']:.3g} | {r['relmse']:.3e} | {ratio} | "
                      f"{1 / (r['relmse'] * r['seconds']):.3g} | {1 / (r['relmse'] * r['cpu_s']):.3g} | {r['mean_ratio']:.4f} |")
        md.append("")
    with open(os.path.join(args.out, "results.md"), "w") as fh:
        fh.write("\n".join(md) + "\n")
    with open(os.path.join(args.out, "results.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["part", "stage", "max_depth", "renderer", "config", "budget_s", "seconds", "spp", "samples_per_s",
                    "relmse", "ratio_r", "ratio_g", "ratio_b", "ratio_se_r", "ratio_se_g", "ratio_se_b",
                    "median_rel", "median_rel_noise", "frac_3sigma", "frac_3sigma_surf"])
        for r in rows:
            a, s = r["all"], r["surf"]
            w.writerow(["A", r["stage"], r["max_depth"], "illum", r["illum"], "", r["illum_s"], r["spp_illum"], "", "",
                        *[f"{x:.6f}" for x in a["ratio"]], *[f"{x:.6f}" for x in a["ratio_se"]],
                        f"{a['median_rel']:.6f}", f"{a['median_rel_noise']:.6f}", f"{a['frac_3sigma']:.6f}",
                        f"{s['frac_3sigma']:.6f}"])
        if et:
            for r in et["runs"]:
                w.writerow(["B", "cornell_box", et["max_depth"], r["renderer"], r["config"], r["budget"],
                            f"{r['seconds']:.4f}", r["spp"], f"{r['samples_per_s']:.1f}", f"{r['relmse']:.6e}"]
                           + [""] * 10)
    if et:
        _plot(et, os.path.join(args.out, "error_vs_time.png"))
    with open(os.path.join(args.out, "results.json"), "w") as fh:
        json.dump({"crosscheck": rows, "notes": notes, "command": cmd, **results}, fh, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


def _plot(et, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    groups = {}
    for r in et["runs"]:
        groups.setdefault(f"{r['renderer']}: {r['config']}", []).append(r)
    for label, rs in groups.items():
        rs = sorted(rs, key=lambda r: r["seconds"])
        ax.loglog([r["seconds"] for r in rs], [r["relmse"] for r in rs], "o-", label=label)
    ax.axhline(et["floor_illum_filter"], ls="--", c="grey", lw=0.8, label="reference noise floor (illum's filter)")
    ax.set_xlabel("render seconds (measured)")
    ax.set_ylabel("relMSE")
    W, H = et["res"]
    ax.set_title(f"Cornell box {W}x{H}, max depth {et['max_depth']}, 2 threads")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _merge(old: dict, rows: list, notes: list, cmd: str, results: dict):
    """--update: the old run's rows/notes for the stages not run now, then the new ones; the old
    part B unless it was run now. The machine section and command record both runs."""
    fresh = {r["stage"] for r in rows} | {n.split("**")[1] for n in notes if n.startswith("**")}
    keep_rows = [r for r in old.get("crosscheck", []) if r["stage"] not in fresh]
    keep_notes = [n for n in old.get("notes", []) if not (n.startswith("**") and n.split("**")[1] in fresh)]
    if "equal_time" not in results and "equal_time" in old:
        results["equal_time"] = old["equal_time"]
    m_old = old.get("machine", {})
    results["machine"]["earlier_run"] = {k: m_old.get(k) for k in ("load_start", "load_before_B", "load_end", "git")}
    for k in ("load_before_B",):
        if k not in results["machine"] and k in m_old:
            results["machine"][k] = m_old[k]
    old_cmd = old.get("command", "")
    cmd = (old_cmd + "` and, updating the stages " + ", ".join(sorted(fresh)) + ", `" + cmd) if old_cmd else cmd
    return keep_rows + rows, keep_notes + notes, cmd


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stages", nargs="*", help=f"stages to cross-check (default: {' '.join(DEFAULT_STAGES)})")
    ap.add_argument("--mitsuba-python", required=True, help="python of a venv with mitsuba installed")
    ap.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    ap.add_argument("--out", default="bench/results/mitsuba")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rr-depth", type=int, default=3)
    ap.add_argument("--no-variants", action="store_true", help="skip the generated Cornell-box light variants")
    ap.add_argument("--skip-crosscheck", action="store_true")
    ap.add_argument("--skip-equal-time", action="store_true")
    ap.add_argument("--depths", default="8,1", help="max depths (illum convention) for part A")
    ap.add_argument("--illum-variants", default="shipped,lambert")
    ap.add_argument("--xc-width", type=int, default=128, help="part A image width (aspect kept)")
    ap.add_argument("--xc-spp-illum", type=int, default=512)
    ap.add_argument("--xc-spp-mitsuba", type=int, default=4096)
    ap.add_argument("--pass-spp", type=int, default=64, help="Mitsuba custom loop: samples per pixel per wavefront")
    ap.add_argument("--et-res", type=int, nargs=2, default=(256, 256))
    ap.add_argument("--budgets", default="1,2,4,8")
    ap.add_argument("--ref-spp", type=int, default=256, help="part B reference: spp per Mitsuba render")
    ap.add_argument("--ref-repeats", type=int, default=16, help="part B reference: number of renders averaged")
    ap.add_argument("--illum-configs", default="controlVariate:4;auto:4",
                    help="extra illum configs for part B, 'estimator:lightSamples' separated by ';'")
    ap.add_argument("--work", default=None, help="scratch dir (default: a temp dir)")
    ap.add_argument("--update", action="store_true",
                    help="merge into OUT/results.json: replace the rows of the stages run now, keep the others "
                         "(and part B when --skip-equal-time)")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    cmd = " ".join(["python bench/bench_mitsuba.py"] + (argv if argv is not None else sys.argv[1:]))
    os.makedirs(args.out, exist_ok=True)
    tmp = tempfile.TemporaryDirectory(prefix="illum-mitsuba-")
    args.work = args.work or tmp.name
    os.makedirs(args.work, exist_ok=True)

    results = {"machine": {"cpu": _cpu(), "cores": os.cpu_count(), "platform": platform.platform(),
                           "python": platform.python_version(),
                           "load_start": tuple(round(x, 2) for x in os.getloadavg()), "git": git_state(),
                           "versions": _versions(args, mitsuba_versions(args))}}
    rows: list = []
    notes: list = []
    old = None
    if args.update and os.path.exists(os.path.join(args.out, "results.json")):
        with open(os.path.join(args.out, "results.json")) as fh:
            old = json.load(fh)
    if not args.skip_crosscheck:
        stages = [(os.path.abspath(s), os.path.splitext(os.path.basename(s))[0])
                  for s in (args.stages or [os.path.join(ROOT, s) for s in DEFAULT_STAGES])]
        if not args.no_variants:
            stages += [(p, os.path.splitext(os.path.basename(p))[0])
                       for p in make_variants(os.path.join(ROOT, "stages/cornell_box.usda"), args.work)]
        for stage, name in stages:
            crosscheck_stage(args, stage, name, rows, notes)
            write_report(args, results, rows, notes, cmd)
    if not args.skip_equal_time:
        results["machine"]["load_before_B"] = tuple(round(x, 2) for x in os.getloadavg())
        equal_time(args, results)
    results["machine"]["load_end"] = tuple(round(x, 2) for x in os.getloadavg())
    if old is not None:
        rows, notes, cmd = _merge(old, rows, notes, cmd, results)
    write_report(args, results, rows, notes, cmd)
    print(f"wrote {args.out}/results.md", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
