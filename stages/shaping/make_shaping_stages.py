#!/usr/bin/env python
"""Generate the UsdLux ShapingAPI / ShadowAPI stages and their IES profiles.

Usage (from the repository root)::

    .venv/bin/python stages/shaping/make_shaping_stages.py          # write stages + IES files, validate
    .venv/bin/python stages/shaping/make_shaping_stages.py --check  # only validate the committed files

Outputs (deterministic; committed):

* ``stages/ies/narrow_spot.ies`` (LM-63-2002), ``stages/ies/wallwash.ies`` (LM-63-2019) and
  ``stages/ies/quadrant.ies`` (LM-63-1995 with a TILT=INCLUDE block): small synthetic type C
  profiles written by this script from closed-form distributions (no real luminaire data);
* ``stages/shaping/spotlights.usda``: six featured shaped lights (a rect spot with a soft cone,
  a disk with focus and an orange focusTint, a sphere spot, a point light with an IES beam, a
  disk with an asymmetric IES and angleScale, a rect wall-washer with a quadrant-symmetric
  IES) plus a 6 x 6 grid of small coloured sphere spotlights hanging 3.6 m up, aimed at
  scattered floor points: 42 lights, so ``auto`` picks the light BVH, whose cone bounds
  matter here (bench/bench_shaping.py);
* ``stages/shaping/shadows.usda``: four identical sphere spotlights side by side, each over
  three small spheres floating 0.4, 0.75 and 1.5 m above the floor: A plain shadows,
  B ``shadow:enable = 0``, C ``shadow:color`` blue, D ``shadow:distance 0.8`` with
  ``falloff 0.5`` and ``falloffGamma 2`` (the low sphere's shadow is full, the middle one's
  faded to about 16 %, the high one's gone).

Stage conventions and helpers come from ``stages/make_stages.py`` (imported). Like it, this
script does not import ``renderer``.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
STAGES_DIR = os.path.dirname(HERE)
ROOT = os.path.dirname(STAGES_DIR)
IES_DIR = os.path.join(STAGES_DIR, "ies")
for p in (STAGES_DIR, ROOT):
    if p not in sys.path:
        sys.path.insert(0, p)

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux  # noqa: E402

import make_stages as ms  # noqa: E402

STAGE_FILES = ["spotlights.usda", "shadows.usda"]
IES_FILES = ["narrow_spot.ies", "wallwash.ies", "quadrant.ies"]
LENS = dict(focal=0.35, h_ap=0.36, v_ap=0.27, clip=(0.01, 1000.0))
DIFFUSE = dict(roughness=1.0, useSpecularWorkflow=1, specularColor=(0.0, 0.0, 0.0))


# --------------------------------------------------------------------------- IES profiles
def _numbers(values, per_line=10, fmt="{:g}"):
    vals = [fmt.format(v) for v in values]
    return "\n".join(" ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line))


def ies_text(header: list[str], tilt: list[str], multiplier: float, v_deg, h_deg, candela,
             second_factor: float = 1.0) -> str:
    """An IES LM-63 file: header lines, TILT lines, the numeric block. candela (H, V)."""
    lines = list(header) + list(tilt)
    lines.append(f"1 -1 {multiplier:g} {len(v_deg)} {len(h_deg)} 1 2 0 0 0")
    lines.append(f"1.0 {second_factor:g} 50")
    lines.append(_numbers(v_deg))
    lines.append(_numbers(h_deg))
    for row in np.asarray(candela):
        lines.append(_numbers(row, fmt="{:.1f}"))
    return "\r\n".join(lines) + "\r\n"   # IES files are traditionally CRLF


def narrow_spot():
    v = np.arange(0, 91, 5.0)
    c = np.where(v <= 40.0, 1000.0 * np.exp(-(v / 12.0) ** 2), 0.0)
    header = ["IESNA:LM-63-2002", "[TEST] illum synthetic profile", "[MANUFAC] illum",
              "[LUMINAIRE] narrow spot, rotationally symmetric, Gaussian beam sigma 8.5 deg, zero past 40 deg",
              "[ISSUEDATE] 2026-11-22"]
    return ies_text(header, ["TILT=NONE"], 1.0, v, [0.0], np.round(c[None, :], 1))


def wallwash():
    v = np.arange(0, 181, 15.0)
    h = np.arange(0, 361, 30.0)
    V, H = np.meshgrid(v, h)
    c = 60.0 + 500.0 * np.maximum(0.0, np.cos(np.radians(H))) ** 2 * np.exp(-((V - 50.0) / 25.0) ** 2)
    c = np.where(V > 90.0, 20.0, c)
    header = ["IES:LM-63-2019", "[TEST] illum synthetic profile", "[TESTLAB] illum", "[ISSUEDATE] 2026-11-22",
              "[MANUFAC] illum", "[LUMINAIRE] asymmetric wall washer: a lobe toward horizontal angle 0 at 50 deg",
              "[OTHER] full 0-360 horizontal table; a dim uplight above 90 deg"]
    # LM-63-2019: the second number of the ballast line is the file generation type (1.10000:
    # "accredited test lab, interpolated"), which is not a multiplier.
    return ies_text(header, ["TILT=NONE"], 0.5, v, h, np.round(c, 1), second_factor=1.1)


def quadrant():
    v = np.arange(0, 91, 10.0)
    h = np.array([0.0, 30.0, 60.0, 90.0])
    V, H = np.meshgrid(v, h)
    c = 300.0 * (1.0 + 0.5 * np.cos(np.radians(2.0 * H))) * np.cos(np.radians(V))
    header = ["IESNA:LM-63-1995", "[TEST] illum synthetic profile", "[MANUFAC] illum",
              "[LUMINAIRE] quadrant-symmetric downlight, brighter along the 0-180 plane"]
    tilt = ["TILT=INCLUDE", "1", "3", "0 45 90", "1.0 0.95 0.9"]
    # LM-63-1995: the second number is the ballast-lamp photometric factor (0.9), multiplied in.
    return ies_text(header, tilt, 2.0, v, h, np.round(np.maximum(c, 0.0), 1), second_factor=0.9)


def write_ies() -> None:
    os.makedirs(IES_DIR, exist_ok=True)
    for name, fn in (("narrow_spot.ies", narrow_spot), ("wallwash.ies", wallwash), ("quadrant.ies", quadrant)):
        path = os.path.join(IES_DIR, name)
        data = fn().encode("ascii")
        old = open(path, "rb").read() if os.path.exists(path) else None
        if old != data:
            with open(path, "wb") as fh:
                fh.write(data)
            print("wrote", os.path.relpath(path))
        else:
            print("unchanged", os.path.relpath(path))


# --------------------------------------------------------------------------- stage helpers
def new_stage(filename: str, doc: str) -> Usd.Stage:
    return ms.sub_stage(HERE, "stages/shaping/make_shaping_stages.py", filename, doc)


save = ms.save_if_changed


def down(xf, pos):
    """Local -Z pointing straight down (-Y): rotateX -90."""
    ms.place(xf, translate=pos, rotate_x=-90.0)








def shaping(light, *, angle=None, softness=None, focus=None, tint=None, ies=None, angle_scale=None,
            normalize=None):
    api = UsdLux.ShapingAPI.Apply(light.GetPrim())
    if angle is not None:
        api.CreateShapingConeAngleAttr(float(angle))
    if softness is not None:
        api.CreateShapingConeSoftnessAttr(float(softness))
    if focus is not None:
        api.CreateShapingFocusAttr(float(focus))
    if tint is not None:
        api.CreateShapingFocusTintAttr(Gf.Vec3f(*tint))
    if ies is not None:
        api.CreateShapingIesFileAttr(Sdf.AssetPath(ies))
    if angle_scale is not None:
        api.CreateShapingIesAngleScaleAttr(float(angle_scale))
    if normalize is not None:
        api.CreateShapingIesNormalizeAttr(bool(normalize))
    return api


# --------------------------------------------------------------------------- spotlights
def make_spotlights():
    doc = ("UsdLux ShapingAPI: six featured shaped lights and a 6 x 6 grid of small sphere spotlights (42 lights) "
           "over a grey floor and back wall. Featured: RectSpot (cone 22, softness 0.4) on the sphere at left; "
           "DiskFocus (focus 6, orange focusTint) in the middle front; SphereSpot (cone 30, softness 0.6) on the "
           "cube at right; PointIES (treatAsPoint, narrow_spot.ies, normalized) and DiskIES (wallwash.ies, "
           "angleScale 1.3, normalized) near the wall; WallWash (rect, quadrant.ies with TILT=INCLUDE, normalized) "
           "grazing the back wall. Expected: distinct pools of light with soft or hard edges, an orange rim around "
           "the focus pool, a narrow bright IES spot, an asymmetric lobe and a scallop on the wall, and many small "
           "coloured spots on the floor; no light outside the cones.")
    stage = new_stage("spotlights.usda", doc)
    grey = ms.material(stage, "Grey", diffuseColor=(0.5, 0.5, 0.5), **DIFFUSE)
    wall_m = ms.material(stage, "Wall", diffuseColor=(0.6, 0.6, 0.6), **DIFFUSE)
    blue = ms.material(stage, "Blue", diffuseColor=(0.2, 0.35, 0.7), roughness=0.4)
    tan = ms.material(stage, "Tan", diffuseColor=(0.7, 0.55, 0.35), **DIFFUSE)
    ms.bind(ms.quad(stage, "/World/Floor", 12.0, 10.0, doc="12 x 10 m diffuse floor."), grey)
    ms.wall(stage, "/World/BackWall", wall_m, 12.0, 4.0, -3.0)
    ms.sphere(stage, "/World/Ball", blue, (-1.5, 0.4, 0.0), 0.4)
    ms.cube(stage, "/World/Box", tan, translate=(1.2, 0.35, 0.3), scale=0.7, rotate_y=20)

    ies = lambda name: f"../ies/{name}"  # noqa: E731  (relative to this layer)
    rect = UsdLux.RectLight.Define(stage, "/World/Lights/RectSpot")
    ms.aimed(rect, (-2.5, 2.8, 0.8), (-1.5, 0.0, 0.0))
    rect.CreateWidthAttr(0.5)
    rect.CreateHeightAttr(0.5)
    rect.CreateIntensityAttr(120.0)
    shaping(rect, angle=22.0, softness=0.4)

    disk = UsdLux.DiskLight.Define(stage, "/World/Lights/DiskFocus")
    ms.aimed(disk, (0.0, 3.0, 1.5), (0.0, 0.0, 1.2))
    disk.CreateRadiusAttr(0.2)
    disk.CreateIntensityAttr(80.0)
    shaping(disk, focus=6.0, tint=(0.35, 0.12, 0.02))

    sph = UsdLux.SphereLight.Define(stage, "/World/Lights/SphereSpot")
    ms.aimed(sph, (2.3, 2.6, 0.5), (1.2, 0.0, 0.3))
    sph.CreateRadiusAttr(0.12)
    sph.CreateIntensityAttr(150.0)
    shaping(sph, angle=30.0, softness=0.6)

    pt = UsdLux.SphereLight.Define(stage, "/World/Lights/PointIES")
    down(pt, (-0.9, 2.5, -2.2))
    pt.CreateRadiusAttr(0.05)
    pt.CreateTreatAsPointAttr(True)
    pt.CreateIntensityAttr(100.0)
    shaping(pt, ies=ies("narrow_spot.ies"), normalize=True)

    dies = UsdLux.DiskLight.Define(stage, "/World/Lights/DiskIES")
    down(dies, (1.8, 2.6, -1.7))
    dies.CreateRadiusAttr(0.1)
    dies.CreateIntensityAttr(120.0)
    shaping(dies, ies=ies("wallwash.ies"), angle_scale=1.3, normalize=True)

    ww = UsdLux.RectLight.Define(stage, "/World/Lights/WallWash")
    ms.aimed(ww, (3.8, 3.3, -1.5), (3.8, 1.0, -3.0))
    ww.CreateWidthAttr(0.6)
    ww.CreateHeightAttr(0.15)
    ww.CreateIntensityAttr(40.0)
    shaping(ww, ies=ies("quadrant.ies"), normalize=True)

    rng = np.random.default_rng(2026)
    UsdGeom.Xform.Define(stage, "/World/Lights/Grid")
    colors = [(1.0, 0.85, 0.6), (0.6, 0.8, 1.0), (1.0, 0.6, 0.8), (0.7, 1.0, 0.7)]
    for i, x in enumerate(np.linspace(-4.5, 4.5, 6)):
        for j, z in enumerate(np.linspace(-2.0, 3.0, 6)):
            s = UsdLux.SphereLight.Define(stage, f"/World/Lights/Grid/Spot_{i}_{j}")
            target = (x + rng.uniform(-1.2, 1.2), 0.0, z + rng.uniform(-1.2, 1.2))
            ms.aimed(s, (float(x), 3.6, float(z)), target)
            s.CreateRadiusAttr(0.04)
            s.CreateIntensityAttr(float(round(rng.uniform(1500.0, 3000.0), 0)))
            s.CreateColorAttr(Gf.Vec3f(*colors[(i + j) % 4]))
            shaping(s, angle=float(round(rng.uniform(8.0, 16.0), 1)), softness=0.3)

    cam_pos, cam_target = (0.0, 2.4, 7.0), (0.0, 0.6, -0.5)
    yaw, pitch = ms.aim_angles(cam_pos, cam_target)
    ms.camera(stage, "/World/Camera", translate=cam_pos, rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
              doc="35 mm lens, 36 x 27 mm gate (4:3), in tenths of a metre.", **LENS)
    ms.render_settings(stage, "/World/Camera", (320, 240), "spotlights.exr")
    return save(stage)


# --------------------------------------------------------------------------- shadows
SHADOW_HEIGHTS = (0.4, 0.75, 1.5)
SHADOW_DISTANCE, SHADOW_FALLOFF, SHADOW_GAMMA = 0.8, 0.5, 2.0


def make_shadows():
    doc = ("UsdLux ShadowAPI: four identical SphereLight spots (cone 17 deg) 3 m above a grey floor, each over "
           "three 15 cm spheres floating 0.4, 0.75 and 1.5 m up. From left to right: A plain shadows; B "
           "shadow:enable = 0 (no shadows, the spheres are still lit); C shadow:color (0.15, 0.3, 0.9): blue "
           "shadows; D shadow:distance 0.8, falloff 0.5, falloffGamma 2: the low sphere (occluder ~0.25 m from the "
           "floor) casts a full shadow, the middle one (~0.6 m) a shadow faded to ((0.8-0.6)/0.5)^2 = 16 %, the "
           "high one none.")
    stage = new_stage("shadows.usda", doc)
    grey = ms.material(stage, "Grey", diffuseColor=(0.6, 0.6, 0.6), **DIFFUSE)
    red = ms.material(stage, "Red", diffuseColor=(0.7, 0.15, 0.1), **DIFFUSE)
    ms.bind(ms.quad(stage, "/World/Floor", 12.0, 6.0, doc="12 x 6 m diffuse floor."), grey)
    for label, x in zip("ABCD", (-3.0, -1.0, 1.0, 3.0)):
        light = UsdLux.SphereLight.Define(stage, f"/World/Lights/{label}")
        down(light, (x, 3.0, 0.0))
        light.CreateRadiusAttr(0.06)
        light.CreateIntensityAttr(1500.0)
        shaping(light, angle=17.0, softness=0.2)
        if label == "B":
            UsdLux.ShadowAPI.Apply(light.GetPrim()).CreateShadowEnableAttr(False)
        elif label == "C":
            UsdLux.ShadowAPI.Apply(light.GetPrim()).CreateShadowColorAttr(Gf.Vec3f(0.15, 0.3, 0.9))
        elif label == "D":
            api = UsdLux.ShadowAPI.Apply(light.GetPrim())
            api.CreateShadowDistanceAttr(SHADOW_DISTANCE)
            api.CreateShadowFalloffAttr(SHADOW_FALLOFF)
            api.CreateShadowFalloffGammaAttr(SHADOW_GAMMA)
        for k, (h, dx) in enumerate(zip(SHADOW_HEIGHTS, (-0.5, 0.0, 0.3))):
            ms.sphere(stage, f"/World/Occluders/{label}_{k}", red, (x + dx, h, 0.0), 0.15)
    cam_pos, cam_target = (0.0, 4.5, 6.0), (0.0, 0.2, 0.0)
    yaw, pitch = ms.aim_angles(cam_pos, cam_target)
    ms.camera(stage, "/World/Camera", translate=cam_pos, rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
              doc="35 mm lens, 36 x 27 mm gate (4:3), in tenths of a metre.", **LENS)
    ms.render_settings(stage, "/World/Camera", (400, 300), "shadows.exr")
    return save(stage)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only validate the existing files")
    args = ap.parse_args(argv)
    if not args.check:
        write_ies()
        make_spotlights()
        make_shadows()
    ok = ms.validate([os.path.join(HERE, f) for f in STAGE_FILES])
    for name in IES_FILES:
        path = os.path.join(IES_DIR, name)
        good = os.path.exists(path) and 0 < os.path.getsize(path) < 20_000
        print(f"[{'ok' if good else 'FAIL'}] {os.path.relpath(path)}")
        ok &= good
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
