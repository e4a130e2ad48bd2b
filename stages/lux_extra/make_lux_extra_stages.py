#!/usr/bin/env python
"""Generate the mesh-light / cylinder-light and window-portal stages (``stages/lux_extra``).

Usage (from the repository root)::

    .venv/bin/python stages/lux_extra/make_lux_extra_stages.py          # write stages + sky, validate
    .venv/bin/python stages/lux_extra/make_lux_extra_stages.py --check  # only validate the committed files

Outputs (deterministic; committed):

* ``mesh_light_room.usda`` -- a small open-fronted room (Y-up, metres) lit by two mesh lights
  and a CylinderLight:
  - ``/World/Neon``: a pink neon ring on the back wall, a torus of 48 x 8 quads (768 triangles,
    so it gets its own embree BVH) with MeshLightAPI (materialSyncMode fallback
    ``materialGlowTintsLight``): its light colour is inputs:color (white) times the bound
    material's emissiveColor (1, 0.25, 0.6), intensity 10 nits;
  - ``/World/Lamp/Shade``: a warm lampshade on a stand, an open truncated cone of 24 quads
    (48 triangles: exact float64 brute-force intersection), ``doubleSided`` so
    it emits inside and out, ``materialSyncMode = "independent"``: the light is inputs:color
    (1, 0.8, 0.55) x 6 nits, and the shade's material keeps its faint own glow
    (emissiveColor 0.05) as ordinary surface emission;
  - ``/World/Lights/Tube``: a ceiling fluorescent tube, a CylinderLight (length 1.2 m,
    radius 0.03 m, 25 nits) with ``light:filters`` targeting ``/World/Lights/Filters/BarnDoor``
    (a LightFilter): illum ignores the filter and says so in one warning naming both prims.
* ``window_portal.usda`` -- a closed room (4 x 2.8 x 4 m) whose only opening is a 1.4 x 1.2 m
  window in the +X wall, lit only by a textured DomeLight (``textures/window_sky.exr``: a blue
  gradient sky and a sun of 2 deg radius giving 6 lux-units of irradiance normal to it, 40 deg
  up from the +X side) whose ``portals`` targets ``/World/Window/Portal``, a PortalLight filling
  the window opening and facing into the room (its local -Z is world -X). A table stands in
  the sun patch. Expected image: a bright sun patch on the floor and table, the sky-lit window
  wall, everything else lit indirectly; illum draws half of the dome samples through the
  portal (renderer/lights/dome.py).

Stage conventions and helpers come from ``stages/make_stages.py`` (imported). Like it, this
script does not import ``renderer``.
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
for p in (STAGES_DIR, ROOT):
    if p not in sys.path:
        sys.path.insert(0, p)

import usd_schemas  # noqa: E402,F401  (registers IllumLightAPI before any stage is opened)
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux  # noqa: E402

import make_stages as ms  # noqa: E402

STAGE_FILES = ["mesh_light_room.usda", "window_portal.usda"]
SKY_FILE = "window_sky.exr"
RES = (320, 240)
LENS = dict(focal=0.24, h_ap=0.36, v_ap=0.27, clip=(0.01, 1000.0))
DIFFUSE = dict(roughness=1.0, useSpecularWorkflow=1, specularColor=(0.0, 0.0, 0.0))

SUN_DIR = np.array([math.cos(math.radians(40.0)) * 0.94, math.sin(math.radians(40.0)), 0.0])
SUN_DIR = SUN_DIR / np.linalg.norm(SUN_DIR)     # toward the sun (dome-local = world: plain DomeLight)
SUN_RADIUS_DEG = 2.0
SUN_E = 6.0


# --------------------------------------------------------------------------- helpers
def new_stage(filename: str, doc: str) -> Usd.Stage:
    return ms.sub_stage(HERE, "stages/lux_extra/make_lux_extra_stages.py", filename, doc)


save = ms.save_if_changed


def aimed_camera(stage, pos, target):
    yaw, pitch = ms.aim_angles(pos, target)
    return ms.camera(stage, "/World/Camera", translate=pos, rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
                     doc="24 mm lens on a 36 x 27 mm gate (4:3), in tenths of a metre.", **LENS)


def box(stage, path, mat, center, size, doc=None):
    pts, counts, idx = ms.unit_cube_mesh()
    m = ms.mesh(stage, path, pts, counts, idx, doc=doc)
    ms.place(m, translate=center, scale=size)
    ms.bind(m, mat)
    return m


def panel(stage, path, mat, corners, doc=None):
    """One quad from 4 corners, counter-clockwise seen from its front."""
    m = ms.mesh(stage, path, corners, [4], [0, 1, 2, 3], doc=doc)
    ms.bind(m, mat)
    return m


def torus(major: float, minor: float, nu: int, nv: int):
    """Torus about local +Z (ring in the XY plane): points, quad counts, indices (outward, CCW)."""
    pts = []
    for i in range(nu):
        a = 2 * math.pi * i / nu
        c, s = math.cos(a), math.sin(a)
        for j in range(nv):
            b = 2 * math.pi * j / nv
            rr = major + minor * math.cos(b)
            pts.append((rr * c, rr * s, minor * math.sin(b)))
    idx = []
    for i in range(nu):
        for j in range(nv):
            i1, j1 = (i + 1) % nu, (j + 1) % nv
            idx += [i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1]
    return pts, [4] * (nu * nv), idx


def frustum(r_bottom: float, r_top: float, height: float, n: int):
    """Open truncated cone about +Y from y = 0 to height: points, quads (normals outward)."""
    pts = []
    for k in range(n):
        a = 2 * math.pi * k / n
        pts.append((r_bottom * math.cos(a), 0.0, -r_bottom * math.sin(a)))
    for k in range(n):
        a = 2 * math.pi * k / n
        pts.append((r_top * math.cos(a), height, -r_top * math.sin(a)))
    idx = []
    for k in range(n):
        k1 = (k + 1) % n
        idx += [k, k1, n + k1, n + k]
    return pts, [4] * n, idx


def room_shell(stage, mat_walls, mat_floor, lo, hi, skip=()):
    """Inward-facing floor, ceiling and walls of the box [lo, hi] (names in skip are left out)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    faces = {
        "Floor": ([(x0, y0, z1), (x1, y0, z1), (x1, y0, z0), (x0, y0, z0)], mat_floor),
        "Ceiling": ([(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], mat_walls),
        "BackWall": ([(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], mat_walls),
        "FrontWall": ([(x1, y0, z1), (x0, y0, z1), (x0, y1, z1), (x1, y1, z1)], mat_walls),
        "LeftWall": ([(x0, y0, z1), (x0, y0, z0), (x0, y1, z0), (x0, y1, z1)], mat_walls),
        "RightWall": ([(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)], mat_walls),
    }
    for name, (corners, mat) in faces.items():
        if name not in skip:
            panel(stage, f"/World/Room/{name}", mat, corners)


# --------------------------------------------------------------------------- 1. mesh lights + cylinder
def make_mesh_light_room() -> str:
    doc = ("Mesh lights and a cylinder light in a small open-fronted room (Y-up, metres). A pink neon ring "
           "(MeshLightAPI, materialGlowTintsLight: light colour = inputs:color x the material's emissiveColor) "
           "on the back wall, a warm double-sided lampshade (MeshLightAPI, materialSyncMode independent) on a "
           "stand at the right, and a fluorescent ceiling tube (CylinderLight, with an unsupported light filter "
           "that illum ignores with one warning). Expected image: pink light around the ring on the back wall, "
           "a warm pool under and above the shade, soft cool light from the ceiling tube over the whole floor, "
           "shadows of the two blocks.")
    stage = new_stage("mesh_light_room.usda", doc)
    ms.render_settings(stage, "/World/Camera", RES, "mesh_light_room.exr")
    aimed_camera(stage, (0.0, 1.35, 3.4), (0.0, 1.0, -1.0))
    walls = ms.material(stage, "Walls", diffuseColor=(0.62, 0.62, 0.6), **DIFFUSE)
    floor = ms.material(stage, "Floor", diffuseColor=(0.45, 0.4, 0.35), roughness=0.6)
    blocks = ms.material(stage, "Blocks", diffuseColor=(0.3, 0.45, 0.6), **DIFFUSE)
    neon = ms.material(stage, "NeonGlow", doc="Glow (1, 0.25, 0.6): tints the neon mesh light.",
                       diffuseColor=(0.1, 0.1, 0.1), emissiveColor=(1.0, 0.25, 0.6), roughness=0.3)
    shade = ms.material(stage, "Shade", doc="A faint own glow, kept as surface emission (independent mode).",
                        diffuseColor=(0.8, 0.75, 0.65), emissiveColor=(0.05, 0.04, 0.03), **DIFFUSE)
    metal = ms.material(stage, "Stand", diffuseColor=(0.2, 0.2, 0.2), metallic=1.0, roughness=0.35)
    UsdGeom.Xform.Define(stage, "/World/Room")
    room_shell(stage, walls, floor, (-2.0, 0.0, -2.0), (2.0, 2.6, 2.0), skip=("FrontWall",))
    box(stage, "/World/BlockA", blocks, (-0.7, 0.25, -0.6), (0.5, 0.5, 0.5))
    box(stage, "/World/BlockB", blocks, (0.2, 0.15, 0.4), (0.8, 0.3, 0.35))

    pts, counts, idx = torus(0.45, 0.025, 48, 8)
    ring = ms.mesh(stage, "/World/Neon", pts, counts, idx,
                   doc="Neon ring: 768 triangles, MeshLightAPI with the default materialGlowTintsLight.")
    ms.place(ring, translate=(-0.6, 1.55, -1.9))
    ms.bind(ring, neon)
    UsdLux.MeshLightAPI.Apply(ring.GetPrim())
    api = UsdLux.LightAPI(ring.GetPrim())
    api.CreateIntensityAttr(10.0)

    UsdGeom.Xform.Define(stage, "/World/Lamp")
    ms.place(UsdGeom.Xform(stage.GetPrimAtPath("/World/Lamp")), translate=(1.2, 0.0, -1.1))
    box(stage, "/World/Lamp/Pole", metal, (0.0, 0.6, 0.0), (0.03, 1.2, 0.03))
    box(stage, "/World/Lamp/Base", metal, (0.0, 0.02, 0.0), (0.35, 0.04, 0.35))
    pts, counts, idx = frustum(0.3, 0.17, 0.32, 24)
    shade_mesh = ms.mesh(stage, "/World/Lamp/Shade", pts, counts, idx, double_sided=True,
                         doc="Lampshade: 48 triangles, doubleSided (emits inside and out), independent mode.")
    ms.place(shade_mesh, translate=(0.0, 1.05, 0.0))
    ms.bind(shade_mesh, shade)
    UsdLux.MeshLightAPI.Apply(shade_mesh.GetPrim())
    api = UsdLux.LightAPI(shade_mesh.GetPrim())
    api.CreateIntensityAttr(6.0)
    api.CreateColorAttr(Gf.Vec3f(1.0, 0.8, 0.55))
    shade_mesh.GetPrim().GetAttribute("light:materialSyncMode").Set("independent")

    tube = UsdLux.CylinderLight.Define(stage, "/World/Lights/Tube")
    tube.GetPrim().SetDocumentation("Ceiling fluorescent tube along X; its light filter is ignored (warned).")
    tube.CreateLengthAttr(1.2)
    tube.CreateRadiusAttr(0.03)
    tube.CreateIntensityAttr(25.0)
    tube.CreateColorAttr(Gf.Vec3f(0.9, 0.95, 1.0))
    ms.place(tube, translate=(0.0, 2.45, -0.3))
    UsdGeom.Scope.Define(stage, "/World/Lights/Filters")
    UsdLux.LightFilter.Define(stage, "/World/Lights/Filters/BarnDoor")
    tube.GetFiltersRel().SetTargets([Sdf.Path("/World/Lights/Filters/BarnDoor")])
    return save(stage)


# --------------------------------------------------------------------------- 2. window portal
def sky_radiance(w=128, h=64, sub=8):
    """(h, w, 3) float32 lat-long radiance (nits): a blue gradient sky, a dim ground and a sun of
    SUN_RADIUS_DEG giving SUN_E irradiance normal to it. Box-filtered from sub x sub samples."""
    d, lat = ms.latlong_dirs(w, h, sub)
    up = d[..., 1]
    zen = np.clip(up, 0.0, 1.0)[..., None]
    horizon = np.array([1.1, 1.2, 1.35])
    zenith = np.array([0.45, 0.7, 1.4])
    sky = np.where((up > 0)[..., None], horizon + (zenith - horizon) * zen, np.array([0.25, 0.23, 0.2]))
    ang = np.degrees(np.arccos(np.clip(d @ SUN_DIR, -1.0, 1.0)))
    disk = np.clip((SUN_RADIUS_DEG + 0.5 - ang) / 1.0, 0.0, 1.0)
    dA = (2 * math.pi / (w * sub)) * (math.pi / (h * sub)) * np.cos(lat) * np.ones_like(up)
    cosn = np.clip(d @ SUN_DIR, 0.0, 1.0)
    sun_L = SUN_E / float(np.sum(disk * cosn * dA))
    sky = sky + disk[..., None] * sun_L * np.array([1.0, 0.92, 0.8])
    return sky.reshape(h, sub, w, sub, 3).mean(axis=(1, 3)).astype(np.float32)


def write_sky(path: str) -> None:
    import OpenImageIO as oiio

    os.makedirs(os.path.dirname(path), exist_ok=True)
    img = sky_radiance()
    h, w = img.shape[:2]
    spec = oiio.ImageSpec(w, h, 3, oiio.FLOAT)
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "zip")
    spec.attribute("DateTime", "2026:11:22 00:00:00")  # fixed: regenerating must not change the bytes
    spec.attribute("ImageDescription", "illum window_portal sky: lat-long (OpenEXR convention), linear Rec.709 nits")
    out = oiio.ImageOutput.create(path)
    assert out is not None and out.open(path, spec), oiio.geterror()
    out.write_image(img)
    out.close()
    print("wrote", os.path.relpath(path))


def make_window_portal() -> str:
    doc = ("An interior lit through a window portal (Y-up, metres). A closed 4 x 2.8 x 4 m room whose only "
           "opening is a 1.4 x 1.2 m window in the +X wall; a textured DomeLight (blue sky, a sun 40 deg up "
           "beyond the window) whose portals rel targets the PortalLight filling the window, facing into the "
           "room. Expected image: a sharp sun patch on the floor and the table, a sky-lit window wall and a "
           "softly lit room; without the portal the image is the same, only noisier.")
    stage = new_stage("window_portal.usda", doc)
    ms.render_settings(stage, "/World/Camera", RES, "window_portal.exr")
    aimed_camera(stage, (-1.7, 1.5, 1.7), (0.8, 0.7, -0.6))
    walls = ms.material(stage, "Walls", diffuseColor=(0.7, 0.7, 0.68), **DIFFUSE)
    floor = ms.material(stage, "Floor", diffuseColor=(0.5, 0.38, 0.28), roughness=0.5)
    wood = ms.material(stage, "Table", diffuseColor=(0.55, 0.35, 0.2), **DIFFUSE)
    UsdGeom.Xform.Define(stage, "/World/Room")
    lo, hi = (-2.0, 0.0, -2.0), (2.0, 2.8, 2.0)
    room_shell(stage, walls, floor, lo, hi, skip=("RightWall",))
    # The +X wall around the window opening y in [1.0, 2.2], z in [-1.0, 0.4] (four quads facing -X).
    x = 2.0
    y0, y1, z0, z1 = 1.0, 2.2, -1.0, 0.4
    parts = {
        "Below": [(x, 0.0, -2.0), (x, 0.0, 2.0), (x, y0, 2.0), (x, y0, -2.0)],
        "Above": [(x, y1, -2.0), (x, y1, 2.0), (x, 2.8, 2.0), (x, 2.8, -2.0)],
        "Back": [(x, y0, -2.0), (x, y0, z0), (x, y1, z0), (x, y1, -2.0)],
        "Front": [(x, y0, z1), (x, y0, 2.0), (x, y1, 2.0), (x, y1, z1)],
    }
    UsdGeom.Xform.Define(stage, "/World/Room/WindowWall")
    for name, corners in parts.items():
        panel(stage, f"/World/Room/WindowWall/{name}", walls, corners)
    box(stage, "/World/TableTop", wood, (0.2, 0.75, -0.2), (1.0, 0.05, 0.7))
    for k, (dx, dz) in enumerate(((-0.45, -0.3), (0.45, -0.3), (-0.45, 0.3), (0.45, 0.3))):
        box(stage, f"/World/TableLeg{k}", wood, (0.2 + dx, 0.37, -0.2 + dz), (0.05, 0.74, 0.05))

    UsdGeom.Xform.Define(stage, "/World/Window")
    portal = UsdLux.PortalLight.Define(stage, "/World/Window/Portal")
    portal.GetPrim().SetDocumentation("Fills the window opening; rotateY 90 maps its -Z (the transmit "
                                      "direction) to world -X, into the room; width runs along world -Z.")
    portal.CreateWidthAttr(z1 - z0)
    portal.CreateHeightAttr(y1 - y0)
    ms.place(portal, translate=(x, 0.5 * (y0 + y1), 0.5 * (z0 + z1)), rotate_y=90.0)
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath(f"./textures/{SKY_FILE}"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    dome.CreatePortalsRel().SetTargets([portal.GetPath()])
    return save(stage)


def validate(paths) -> bool:
    ok = ms.validate(paths)
    sky = os.path.join(TEX_DIR, SKY_FILE)
    size = os.path.getsize(sky) if os.path.exists(sky) else -1
    good = 0 < size < 100_000
    print(f"[{'ok' if good else 'FAIL'}] {os.path.relpath(sky)}: {size / 1024:.1f} KB")
    return ok and good


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only validate the committed files")
    args = ap.parse_args(argv)
    if not args.check:
        write_sky(os.path.join(TEX_DIR, SKY_FILE))
        make_mesh_light_room()
        make_window_portal()
    return 0 if validate([os.path.join(HERE, f) for f in STAGE_FILES]) else 1


if __name__ == "__main__":
    sys.exit(main())
