#!/usr/bin/env python
"""Generate ``stages/anim/turntable.usda``: ten frames of a small animation for frame ranges.

Usage (from the repository root)::

    .venv/bin/python stages/anim/make_anim.py

Frames 1-10 (24 fps). What moves, so that a frame range exercises everything the reader takes
at the frame's time code:
* an animated transform: the ball rolls across the floor (translate samples per frame) and the
  camera dollies in (translate);
* animated points: the flag, a 6 x 4 grid mesh, waves (points samples per frame);
* animated light parameters: the key RectLight's intensity ramps up and its colour warms.
A Y-up, metres stage with a near-Lambertian floor and a constant grey dome for fill. Written
with pxr only (no ``renderer`` import), through make_stages.py's helpers.
"""
from __future__ import annotations

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # make_stages.py, which adds the repository root

from pxr import Gf, UsdGeom, UsdLux  # noqa: E402

import make_stages as ms  # noqa: E402

FRAMES = range(1, 11)
RES = (160, 90)
GRID = (6, 4)  # flag vertices along x and y


def flag_points(frame: int) -> list:
    """A 1.2 x 0.8 m flag in the plane z = -1, waving along x with a phase per frame."""
    nx, ny = GRID
    pts = []
    for j in range(ny):
        for i in range(nx):
            x = -0.6 + 1.2 * i / (nx - 1)
            wave = 0.12 * (i / (nx - 1)) * math.sin(2.0 * math.pi * (i / (nx - 1) - frame / 10.0))
            pts.append((round(x, 4), round(0.6 + 0.8 * j / (ny - 1), 4), round(-1.0 + wave, 4)))
    return pts


def make(out: str) -> str:
    doc = ("Ten frames (1-10, 24 fps): a red ball rolls left to right across a grey floor, a blue flag "
           "waves behind it (animated points), the camera dollies in, and the key light brightens and warms "
           "(animated intensity and colour). For frame ranges: illum render --frames 1-10.")
    stage = ms.sub_stage(os.path.dirname(os.path.abspath(out)), "stages/anim/make_anim.py",
                         os.path.basename(out), doc)
    stage.SetStartTimeCode(FRAMES[0])
    stage.SetEndTimeCode(FRAMES[-1])
    stage.SetTimeCodesPerSecond(24.0)
    stage.SetFramesPerSecond(24.0)
    floor_m = ms.material(stage, "Floor", diffuseColor=(0.5, 0.5, 0.5), roughness=1.0, useSpecularWorkflow=1,
                          specularColor=(0.0, 0.0, 0.0))
    ball_m = ms.material(stage, "Ball", diffuseColor=(0.7, 0.12, 0.1), roughness=0.5)
    flag_m = ms.material(stage, "Flag", diffuseColor=(0.1, 0.2, 0.6), roughness=0.9)
    ms.bind(ms.quad(stage, "/World/Floor", 6.0, 6.0, doc="6 x 6 m floor."), floor_m)

    ball = ms.sphere(stage, "/World/Ball", ball_m, (-1.0, 0.3, 0.0), 0.3, doc="Rolls from x = -1 to x = 1.")
    op = ball.GetOrderedXformOps()[0]
    for f in FRAMES:
        op.Set(Gf.Vec3d(round(-1.0 + 2.0 * (f - 1) / 9.0, 4), 0.3, 0.0), f)

    nx, ny = GRID
    idx = [j * nx + i for j in range(ny - 1) for i in range(nx - 1)]
    faces = [[k, k + 1, k + 1 + nx, k + nx] for k in idx]
    flag = ms.mesh(stage, "/World/Flag", flag_points(FRAMES[0]), [4] * len(faces), [v for q in faces for v in q],
                   doc="A 6 x 4 grid whose points wave per frame.")
    flag.CreateDoubleSidedAttr(True)
    for f in FRAMES:
        flag.GetPointsAttr().Set([Gf.Vec3f(*p) for p in flag_points(f)], f)
    ms.bind(flag, flag_m)

    key = UsdLux.RectLight.Define(stage, "/World/Lights/Key")
    key.CreateWidthAttr(1.0)
    key.CreateHeightAttr(1.0)
    ms.place(key, translate=(0.5, 2.5, 1.0), rotate_x=-90.0)
    for f in FRAMES:
        t = (f - 1) / 9.0
        key.CreateIntensityAttr().Set(round(8.0 + 8.0 * t, 3), f)
        key.CreateColorAttr().Set(Gf.Vec3f(1.0, round(1.0 - 0.2 * t, 3), round(1.0 - 0.4 * t, 3)), f)
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Fill")
    dome.CreateIntensityAttr(0.15)

    yaw, pitch = ms.aim_angles((0.0, 1.2, 4.0), (0.0, 0.5, 0.0))
    cam = ms.camera(stage, "/World/Camera", focal=0.35, h_ap=0.36, v_ap=0.2025, clip=(0.01, 100.0),
                    translate=(0.0, 1.2, 4.0), rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
                    doc="Dollies in from z = 4 to z = 3.")
    op = cam.GetOrderedXformOps()[0]
    for f in FRAMES:
        op.Set(Gf.Vec3d(0.0, 1.2, round(4.0 - (f - 1) / 9.0, 4)), f)
    ms.render_settings(stage, "/World/Camera", RES, "turntable.$F4.exr")
    return ms.save_if_changed(stage)


def main() -> int:
    path = make(os.path.join(HERE, "turntable.usda"))
    return 0 if ms.validate([path]) else 1


if __name__ == "__main__":
    sys.exit(main())
