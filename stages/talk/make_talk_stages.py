#!/usr/bin/env python
"""Generate the *Illumination 101* story stages (``stages/talk/*.usda``) and their texture.

Usage (from the repository root)::

    .venv/bin/python stages/talk/make_talk_stages.py            # write stages + texture, validate
    .venv/bin/python stages/talk/make_talk_stages.py --check    # only validate the committed files
    .venv/bin/python stages/talk/make_talk_stages.py --exposure # also print direct-lighting estimates

One stage per story of the talk, each small enough for the estimator benchmark
(``illum bench``, see bench/README.md) to converge a reference in about a minute:

* ``sphere_occluder.usda`` -- a small SphereLight, an occluder and a glossy floor
  (roughness 0.2): BSDF sampling is noisy in the highlight, light sampling is not;
* ``large_rect.usda`` -- a large RectLight over dark glossy surfaces: light sampling is noisy
  in the dark glossy reflections, BSDF sampling is not; MIS gets both right;
* ``penumbra.usda`` -- a diffuse floor, a large RectLight and raised occluders casting wide
  soft shadows: the control variate with alpha = average visibility (unbiased, 4 samples);
* ``dome.usda`` -- diffuse objects on a diffuse ground under a textured DomeLight
  (``textures/talk_sky.exr``): the control variate on the dome's convolution (irradiance).

Every light carries ``IllumLightAPI`` with the estimator the story is about; ``illum bench``
overrides the estimator per run, so the authored token is only the stage's default.

The stage conventions and helper functions are those of ``stages/make_stages.py`` (imported,
not copied): RenderSettings at /Render/Settings, a camera at /World/Camera, UsdPreviewSurface
materials under /World/Looks, ``subdivisionScheme = "none"`` on every Mesh. Output is
deterministic. Like make_stages.py this script does not import ``renderer``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
STAGES_DIR = os.path.dirname(HERE)
ROOT = os.path.dirname(STAGES_DIR)
TEX_DIR = os.path.join(HERE, "textures")
# make_stages.py (the shared helpers) lives one level up; usd_schemas at the repository root.
for p in (STAGES_DIR, ROOT):
    if p not in sys.path:
        sys.path.insert(0, p)

import usd_schemas  # noqa: E402,F401  (registers IllumLightAPI before any stage is opened)
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux  # noqa: E402

import make_stages as ms  # noqa: E402

STAGE_FILES = ["sphere_occluder.usda", "large_rect.usda", "penumbra.usda", "dome.usda", "furnace.usda", "disks.usda"]
SKY_FILE = "talk_sky.exr"
RES = (200, 150)
# 35 mm lens on a 36 x 27 mm (4:3) gate, written in tenths of a metre (USD camera units).
LENS = dict(focal=0.35, h_ap=0.36, v_ap=0.27, clip=(0.01, 1000.0))

# Near-Lambertian diffuse: the specular workflow with F0 = 0 and roughness 1 leaves only the
# Schlick grazing term, so the BSDF is as close to its control lobe as UsdPreviewSurface gets.
DIFFUSE = dict(roughness=1.0, useSpecularWorkflow=1, specularColor=(0.0, 0.0, 0.0))


# --------------------------------------------------------------------------- helpers
def new_stage(filename: str, doc: str) -> Usd.Stage:
    return ms.sub_stage(HERE, "stages/talk/make_talk_stages.py", filename, doc)


save = ms.save_if_changed


def illum_light_api(light, estimator: str, samples: int = 1, cv_alpha: str | None = None) -> None:
    """Apply IllumLightAPI and author the estimator the stage's story is about."""
    prim = light.GetPrim()
    prim.ApplyAPI("IllumLightAPI")
    prim.GetAttribute("illum:estimator").Set(estimator)
    if cv_alpha is not None:
        prim.GetAttribute("illum:cv:alpha").Set(cv_alpha)
    if samples != 1:
        prim.GetAttribute("illum:samples").Set(int(samples))


def aimed_camera(stage, pos, target, doc="35 mm lens, 36 x 27 mm gate (4:3), in tenths of a metre."):
    yaw, pitch = ms.aim_angles(pos, target)
    return ms.camera(stage, "/World/Camera", translate=pos, rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
                     doc=doc, **LENS)










# --------------------------------------------------------------------------- texture
SKY_W, SKY_H = 64, 32
SKY_SUN_DIR = np.array([-0.45, 0.62, 0.35])   # world (= dome-local, Y-up, no xformOps) direction
SKY_SUN_DIR = SKY_SUN_DIR / np.linalg.norm(SKY_SUN_DIR)
SKY_SUN_RADIUS_DEG = 14.0                       # a broad, soft "window": penumbrae several cm wide
SKY_SUN_E = 2.4                                 # irradiance the blob gives a surface facing it


def sky_radiance(w=SKY_W, h=SKY_H, sub=8):
    """(h, w, 3) float32 lat-long radiance in nits: a blue gradient sky, a warm soft blob and a
    dim ground-coloured lower hemisphere. Box-filtered from sub x sub supersamples."""
    d, lat = ms.latlong_dirs(w, h, sub)   # dome-local, Y-up: the stage frame for a plain DomeLight
    up = d[..., 1]
    zen = np.clip(up, 0.0, 1.0)[..., None]
    horizon = np.array([0.33, 0.36, 0.41])
    zenith = np.array([0.15, 0.24, 0.48])
    sky = np.where((up > 0)[..., None], horizon + (zenith - horizon) * zen, np.array([0.12, 0.11, 0.10]))
    ang = np.degrees(np.arccos(np.clip(d @ SKY_SUN_DIR, -1.0, 1.0)))
    blob = np.clip((SKY_SUN_RADIUS_DEG - ang) / 6.0, 0.0, 1.0)   # 6 degree soft edge
    dA = (2 * math.pi / (w * sub)) * (math.pi / (h * sub)) * np.cos(lat) * np.ones_like(up)
    cosn = np.clip(d @ SKY_SUN_DIR, 0.0, 1.0)
    blob_L = SKY_SUN_E / float(np.sum(blob * cosn * dA))
    sky = sky + blob[..., None] * blob_L * np.array([1.0, 0.9, 0.75])
    img = sky.reshape(h, sub, w, sub, 3).mean(axis=(1, 3))
    return img.astype(np.float32), blob_L


def write_sky(path: str) -> None:
    import OpenImageIO as oiio

    img, _ = sky_radiance()
    h, w = img.shape[:2]
    spec = oiio.ImageSpec(w, h, 3, oiio.FLOAT)
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "zip")
    spec.attribute("DateTime", "2026:11:22 00:00:00")  # fixed: regenerating must not change the bytes
    spec.attribute("ImageDescription", "illum talk dome: lat-long (OpenEXR convention), linear Rec.709 nits")
    tmp = path + ".tmp.exr"
    out = oiio.ImageOutput.create(tmp)
    assert out is not None and out.open(tmp, spec), oiio.geterror()
    out.write_image(img)
    out.close()
    ms.replace_if_changed(tmp, path)


# --------------------------------------------------------------------------- 1. sphere + occluder
def make_sphere_occluder():
    doc = ("Talk story 1 (BSDF sampling vs light sampling): a small SphereLight (radius 0.1 m) above and behind "
           "a glossy floor (UsdPreviewSurface roughness 0.2, specular F0 0.3) with a cube occluder. BSDF "
           "sampling rarely finds the small light, so its highlight on the floor is noisy; light sampling is "
           "clean there and gives a crisp shadow. IllumLightAPI: mis.")
    stage = new_stage("sphere_occluder.usda", doc)
    floor_m = ms.material(stage, "GlossyFloor", diffuseColor=(0.4, 0.4, 0.42), roughness=0.2,
                          useSpecularWorkflow=1, specularColor=(0.3, 0.3, 0.3),
                          doc="Glossy dielectric-like floor: roughness 0.2 (GGX alpha 0.04), F0 0.3.")
    wall_m = ms.material(stage, "Wall", diffuseColor=(0.6, 0.6, 0.6), **DIFFUSE)
    occ_m = ms.material(stage, "Occluder", diffuseColor=(0.7, 0.25, 0.12), roughness=0.5)
    ball_m = ms.material(stage, "Ball", diffuseColor=(0.15, 0.35, 0.7), roughness=0.35)

    ms.bind(ms.quad(stage, "/World/Floor", 10.0, 10.0, doc="10 x 10 m glossy floor, normal +Y."), floor_m)
    ms.wall(stage, "/World/BackWall", wall_m, 10.0, 4.0, -4.5, doc="Diffuse back wall 4.5 m behind the origin.")
    ms.cube(stage, "/World/Occluder", occ_m, translate=(0.35, 0.35, -0.2), scale=0.7, rotate_y=25,
         doc="70 cm cube between the light and the front of the floor: its shadow falls towards the camera.")
    ms.sphere(stage, "/World/Ball", ball_m, (-0.9, 0.3, 0.6), 0.3)

    light = UsdLux.SphereLight.Define(stage, "/World/Lights/Key")
    light.GetPrim().SetDocumentation(
        "Small sphere light, radius 0.1 m, 2 m up, 500 nits: ~3.9 units of irradiance on the floor below it. Its mirror "
        "image in the floor is seen by the camera, so the glossy highlight is in frame.")
    ms.place(light, translate=(0.6, 2.0, -1.4))
    light.CreateRadiusAttr(0.1)
    light.CreateIntensityAttr(500.0)
    light.CreateColorAttr(Gf.Vec3f(1.0, 0.92, 0.8))
    illum_light_api(light, "mis")

    aimed_camera(stage, (0.0, 1.1, 4.2), (0.0, 0.25, -0.6))
    ms.render_settings(stage, "/World/Camera", RES, "sphere_occluder.exr")
    return save(stage)


# --------------------------------------------------------------------------- 2. large rect
def make_large_rect():
    doc = ("Talk story 2 (light sampling vs BSDF sampling): a large 4 x 1.5 m RectLight facing the scene over "
           "dark glossy surfaces (near-black diffuse, F0 0.3, roughness 0.12). Light sampling picks points "
           "uniformly on the big rectangle, which rarely fall inside the narrow glossy lobe: the reflections "
           "of the light in the dark glossy floor and sphere are noisy. BSDF sampling is clean there. "
           "IllumLightAPI: mis.")
    stage = new_stage("large_rect.usda", doc)
    dark = dict(diffuseColor=(0.02, 0.02, 0.025), useSpecularWorkflow=1, specularColor=(0.3, 0.3, 0.3))
    floor_m = ms.material(stage, "DarkGlossyFloor", roughness=0.12, doc="Near-black glossy floor.", **dark)
    ball_m = ms.material(stage, "DarkGlossyBall", roughness=0.08, doc="Near-black glossy sphere.", **dark)
    box_m = ms.material(stage, "GreyBox", diffuseColor=(0.55, 0.55, 0.55), **DIFFUSE)

    ms.bind(ms.quad(stage, "/World/Floor", 10.0, 10.0, doc="10 x 10 m dark glossy floor."), floor_m)
    ms.sphere(stage, "/World/Ball", ball_m, (-0.7, 0.5, 0.0), 0.5)
    ms.cube(stage, "/World/Box", box_m, translate=(0.85, 0.4, 0.3), scale=(0.6, 0.8, 0.6), rotate_y=-20)

    light = UsdLux.RectLight.Define(stage, "/World/Lights/Panel")
    light.GetPrim().SetDocumentation(
        "Large 4 x 1.5 m panel, 2.2 m up and 2 m behind the objects, tilted to face the scene (local -Z aimed "
        "at (0, 0, 0.8)); 1.5 nits, normalize off. The camera sees its reflection in the floor.")
    ms.aimed(light, (0.0, 2.2, -2.0), (0.0, 0.0, 0.8))
    light.CreateWidthAttr(4.0)
    light.CreateHeightAttr(1.5)
    light.CreateIntensityAttr(1.5)
    light.CreateNormalizeAttr(False)
    illum_light_api(light, "mis")

    aimed_camera(stage, (0.0, 1.3, 4.5), (0.0, 0.35, -0.5))
    ms.render_settings(stage, "/World/Camera", RES, "large_rect.exr")
    return save(stage)


# --------------------------------------------------------------------------- 3. penumbra
def make_penumbra():
    doc = ("Talk story 3 (control variates, alpha = average visibility): a near-Lambertian floor lit by one "
           "1 x 1 m RectLight 4.2 m up, under occluders hanging 1.25-1.5 m above it (a slab, a sphere, a "
           "thin bar): penumbrae 0.4-0.5 m wide around the umbrae of the slab and the sphere, and a faint "
           "all-penumbra shadow of the bar, between fully lit floor. The camera is low (1.05 m) "
           "and looks down at the floor: the occluders and the light are above the top of the frame and the "
           "floor fills it, so there is no silhouette in view and the image error measures the direct-"
           "lighting estimator, not the pixel filter's antialiasing noise at edges. The unshadowed integral "
           "F of the rect is exact (polygonal Lambert), so the control variate with alpha = v_bar leaves "
           "noise only in the penumbrae. IllumLightAPI: controlVariate, cv:alpha averageVisibilityUnbiased, "
           "samples 4.")
    stage = new_stage("penumbra.usda", doc)
    floor_m = ms.material(stage, "Floor", diffuseColor=(0.7, 0.7, 0.68), **DIFFUSE)
    red = ms.material(stage, "Red", diffuseColor=(0.65, 0.15, 0.1), **DIFFUSE)
    blue = ms.material(stage, "Blue", diffuseColor=(0.15, 0.3, 0.65), **DIFFUSE)
    grey = ms.material(stage, "Grey", diffuseColor=(0.5, 0.5, 0.5), **DIFFUSE)

    ms.bind(ms.quad(stage, "/World/Floor", 40.0, 40.0,
                    doc="40 x 40 m near-Lambertian floor: its far edge is beyond the top of the frame."), floor_m)
    UsdGeom.Xform.Define(stage, "/World/Occluders").GetPrim().SetDocumentation(
        "Hanging above the camera's eye height (1.05 m), so out of frame; only their shadows are seen.")
    ms.cube(stage, "/World/Occluders/Slab", red, translate=(-0.35, 1.35, 1.0), scale=(0.9, 0.05, 0.6),
         doc="A slab 1.35 m up: an umbra about 0.85 m across inside a 0.5 m penumbra.")
    ms.sphere(stage, "/World/Occluders/Ball", blue, (0.45, 1.5, 1.2), 0.25,
           doc="A sphere 1.5 m up: a small umbra (about 0.2 m) in a wide penumbra.")
    ms.cube(stage, "/World/Occluders/Bar", grey, translate=(0.0, 1.25, 1.6), scale=(1.4, 0.06, 0.06), rotate_y=35,
         doc="A thin bar 1.25 m up: a long, faint shadow that is all penumbra.")

    light = UsdLux.RectLight.Define(stage, "/World/Lights/Area")
    light.GetPrim().SetDocumentation(
        "1 x 1 m RectLight 4.2 m above the floor facing down (rotateX -90 maps local -Z to world -Y), "
        "40 nits: about 2.3 units of irradiance on the floor below it, so lit floor (albedo 0.7) is ~0.5.")
    ms.place(light, translate=(0.0, 4.2, 0.6), rotate_x=-90)
    light.CreateWidthAttr(1.0)
    light.CreateHeightAttr(1.0)
    light.CreateIntensityAttr(40.0)
    light.CreateNormalizeAttr(False)
    illum_light_api(light, "controlVariate", samples=4, cv_alpha="averageVisibilityUnbiased")

    aimed_camera(stage, (0.0, 1.05, 3.6), (0.0, 0.0, 1.4))
    ms.render_settings(stage, "/World/Camera", RES, "penumbra.exr")
    return save(stage)


# --------------------------------------------------------------------------- 4. dome
def make_dome():
    doc = ("Talk story 4 (control variates on a dome's convolution texture): diffuse objects on a diffuse "
           "ground under a textured DomeLight (textures/talk_sky.exr, 64 x 32 lat-long: a blue gradient sky, "
           "a soft warm 14-degree blob up and to the left, a dim lower hemisphere). The control variate uses "
           "the dome's preconvolved irradiance as F (illum:dome:irradiance unauthored: the renderer computes "
           "it). IllumLightAPI: controlVariate, samples 4.")
    stage = new_stage("dome.usda", doc)
    ground_m = ms.material(stage, "Ground", diffuseColor=(0.6, 0.58, 0.55), **DIFFUSE)
    white = ms.material(stage, "White", diffuseColor=(0.75, 0.75, 0.75), **DIFFUSE)
    orange = ms.material(stage, "Orange", diffuseColor=(0.75, 0.35, 0.1), **DIFFUSE)
    teal = ms.material(stage, "Teal", diffuseColor=(0.1, 0.45, 0.45), **DIFFUSE)

    ms.bind(ms.quad(stage, "/World/Ground", 60.0, 60.0, doc="60 x 60 m ground: hides most of the lower "
                                                                "hemisphere."), ground_m)
    ms.sphere(stage, "/World/Ball", white, (-0.8, 0.5, 0.0), 0.5)
    ms.cube(stage, "/World/Box", orange, translate=(0.7, 0.45, -0.3), scale=0.9, rotate_y=30)
    ms.cube(stage, "/World/Arch/Top", teal, translate=(0.0, 1.0, 1.2), scale=(1.4, 0.1, 0.4))
    ms.cube(stage, "/World/Arch/Left", teal, translate=(-0.65, 0.5, 1.2), scale=(0.1, 1.0, 0.4))
    ms.cube(stage, "/World/Arch/Right", teal, translate=(0.65, 0.5, 1.2), scale=(0.1, 1.0, 0.4))

    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    dome.GetPrim().SetDocumentation(
        "Plain DomeLight on a Y-up stage, no xformOps: texture top row = world +Y, image centre = world +Z. "
        "Values are radiance in nits (intensity 1). The blob direction is (-0.45, 0.62, 0.35) normalised.")
    dome.CreateTextureFileAttr(Sdf.AssetPath(f"./textures/{SKY_FILE}"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    illum_light_api(dome, "controlVariate", samples=4)

    # Looking down enough that the ground fills the frame: no sky/ground horizon edge, whose
    # antialiasing noise would be the same for every estimator and blur the comparison.
    aimed_camera(stage, (0.3, 2.6, 4.2), (0.0, 0.3, 0.0))
    ms.render_settings(stage, "/World/Camera", RES, "dome.exr")
    return save(stage)

# --------------------------------------------------------------------------- 5. white furnace
def make_furnace():
    doc = ("The white furnace, the control variate's canonical case: a white near-Lambertian sphere (albedo 1) "
           "inside a constant DomeLight of radiance 1. Every point of the convex sphere sees the whole upper "
           "hemisphere of the dome, so at the first vertex the control variate with alpha = v_bar returns the "
           "exact F with no noise, and every pixel converges to 1 (the sphere is energy-conserving up to the "
           "Schlick grazing term). IllumLightAPI: controlVariate, samples 4.")
    stage = new_stage("furnace.usda", doc)
    white = ms.material(stage, "White", diffuseColor=(1.0, 1.0, 1.0), **DIFFUSE)
    ms.sphere(stage, "/World/Ball", white, (0.0, 0.0, 0.0), 1.0)
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Furnace")
    dome.GetPrim().SetDocumentation("Constant DomeLight, radiance 1 nit in every direction.")
    dome.CreateIntensityAttr(1.0)
    illum_light_api(dome, "controlVariate", samples=4)
    aimed_camera(stage, (0.0, 0.0, 3.2), (0.0, 0.0, 0.0))
    ms.render_settings(stage, "/World/Camera", RES, "furnace.exr")
    return save(stage)


# --------------------------------------------------------------------------- 6. three disks
def make_disks():
    doc = ("Three DiskLights of different sizes and hues 2.4-3 m above a near-Lambertian floor, with a hanging "
           "slab and a sphere between them and the floor: three overlapping soft shadows, each lit by some "
           "disks and shadowed from others, so most of the floor is penumbra of at least one light. Each disk "
           "has an exact unshadowed integral (polygonal Lambert on the disk), so the control variate applies "
           "per light. IllumLightAPI: controlVariate, cv:alpha averageVisibilityUnbiased, samples 4.")
    stage = new_stage("disks.usda", doc)
    floor_m = ms.material(stage, "Floor", diffuseColor=(0.7, 0.7, 0.68), **DIFFUSE)
    grey = ms.material(stage, "Grey", diffuseColor=(0.5, 0.5, 0.5), **DIFFUSE)
    ms.bind(ms.quad(stage, "/World/Floor", 40.0, 40.0, doc="40 x 40 m near-Lambertian floor."), floor_m)
    UsdGeom.Xform.Define(stage, "/World/Occluders").GetPrim().SetDocumentation(
        "Hanging above the camera's eye height, so out of frame; only their shadows are seen.")
    ms.cube(stage, "/World/Occluders/Slab", grey, translate=(-0.3, 1.3, 1.0), scale=(0.8, 0.05, 0.5),
            doc="A slab 1.3 m up.")
    ms.sphere(stage, "/World/Occluders/Ball", grey, (0.5, 1.4, 1.3), 0.22, doc="A sphere 1.4 m up.")
    for name, pos, radius, colour, intensity in (
            ("Warm", (-1.0, 3.0, 0.6), 0.35, (1.0, 0.75, 0.5), 30.0),
            ("Cool", (1.1, 2.6, 0.9), 0.25, (0.5, 0.7, 1.0), 45.0),
            ("White", (0.1, 2.4, 2.0), 0.15, (1.0, 1.0, 1.0), 90.0)):
        light = UsdLux.DiskLight.Define(stage, f"/World/Lights/{name}")
        light.GetPrim().SetDocumentation(f"Disk of radius {radius} m facing down (rotateX -90).")
        ms.place(light, translate=pos, rotate_x=-90)
        light.CreateRadiusAttr(radius)
        light.CreateColorAttr(Gf.Vec3f(*colour))
        light.CreateIntensityAttr(intensity)
        illum_light_api(light, "controlVariate", samples=4, cv_alpha="averageVisibilityUnbiased")
    aimed_camera(stage, (0.0, 1.05, 3.6), (0.0, 0.0, 1.4))
    ms.render_settings(stage, "/World/Camera", RES, "disks.exr")
    return save(stage)


# --------------------------------------------------------------------------- validation
def validate(paths) -> bool:
    """make_stages' validator (diagnostics, UsdValidation, bindings, textures, sizes) plus our
    own checks: every light has IllumLightAPI with an authored estimator, resolution 200x150."""
    ok = True
    for path in paths:
        stage = Usd.Stage.Open(path)
        problems = []
        for prim in stage.Traverse():
            if prim.HasAPI(UsdLux.LightAPI):
                if "IllumLightAPI" not in prim.GetAppliedSchemas():
                    problems.append(f"{prim.GetPath()}: no IllumLightAPI")
                elif not prim.GetAttribute("illum:estimator").HasAuthoredValue():
                    problems.append(f"{prim.GetPath()}: illum:estimator not authored")
        from pxr import UsdRender

        rs = UsdRender.Settings.GetStageRenderSettings(stage)
        if tuple(rs.GetResolutionAttr().Get()) != RES:
            problems.append(f"resolution is not {RES}")
        for p in problems:
            print(f"[FAIL] {os.path.relpath(path)}: {p}")
        ok &= not problems
    # make_stages' validator also lists its own textures (stages/textures); harmless here.
    ok &= ms.validate(paths)
    sky = os.path.join(TEX_DIR, SKY_FILE)
    size = os.path.getsize(sky) if os.path.exists(sky) else -1
    good = 0 < size < 100_000
    print(f"[{'ok' if good else 'FAIL'}] {os.path.relpath(sky)}: {size / 1024:.1f} KB")
    return ok and good


EXPOSURE_PROBES = {
    "sphere_occluder.usda": [("floor below the light", (0.6, 0, -1.4), (0, 1, 0)),
                             ("floor in front", (0, 0, 1.5), (0, 1, 0))],
    "large_rect.usda": [("floor centre", (0, 0, 0.5), (0, 1, 0)), ("box side facing +Z", (0.85, 0.4, 0.6), (0, 0, 1))],
    "penumbra.usda": [("floor below the light", (0.0, 0, 0.6), (0, 1, 0)), ("floor front", (0, 0, 2.6), (0, 1, 0))],
    "dome.usda": [("ground", (0, 0, 2.5), (0, 1, 0)), ("box side facing +Z", (0.7, 0.45, 0.2), (0, 0, 1))],
    "disks.usda": [("floor under the warm disk", (-1.0, 0, 0.6), (0, 1, 0)), ("floor front", (0, 0, 2.6), (0, 1, 0))],
}


def exposure_report() -> None:
    print("\nUnoccluded direct lighting -> outgoing radiance of a white Lambertian surface, E/pi:")
    for f, probes in EXPOSURE_PROBES.items():
        stage = Usd.Stage.Open(os.path.join(HERE, f))
        for label, p, n in probes:
            total, _ = ms.direct_irradiance(stage, p, n)
            print(f"  {f:22s} {label:28s} E/pi = {np.round(total / math.pi, 3).tolist()}")
    _, blob_L = sky_radiance()
    print(f"  dome sky: blob radiance {blob_L:.1f} nits, direction {np.round(SKY_SUN_DIR, 3).tolist()}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only validate the existing files")
    ap.add_argument("--exposure", action="store_true", help="print direct-lighting estimates")
    args = ap.parse_args(argv)
    if not args.check:
        os.makedirs(TEX_DIR, exist_ok=True)
        write_sky(os.path.join(TEX_DIR, SKY_FILE))
        for fn in (make_sphere_occluder, make_large_rect, make_penumbra, make_dome, make_furnace, make_disks):
            fn()
    ok = validate([os.path.join(HERE, f) for f in STAGE_FILES])
    if args.exposure:
        exposure_report()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
