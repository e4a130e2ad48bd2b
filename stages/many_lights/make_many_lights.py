#!/usr/bin/env python
"""Generate ``stages/many_lights/many_lights.usda``: 500 small sphere lights over a floor.

Usage (from the repository root)::

    .venv/bin/python stages/many_lights/make_many_lights.py            # write many_lights.usda
    .venv/bin/python stages/many_lights/make_many_lights.py --count 2000 --out /tmp/ml.usda

The lighting-service stage of the one-integrator issue: many small lights, each lighting only a
patch of floor near it, so the pick of a light for next-event estimation decides the noise.
Y-up, metres, 320x180, camera /World/Camera, RenderSettings /Render/Settings.

* 500 SphereLights under /World/Lights: radii 3-8 cm, random hues (HSV hue uniform, saturation
  0.3-0.9), 0.35-3 m above a 30 x 30 m floor; a third have ``normalize`` on (intensity is then
  power-like: the radiance scales with 1 / area), a third off, and a third ``treatAsPoint``
  (a delta light that only light sampling reaches). Intensities are chosen so that each
  class lights the floor below it to a similar level.
* A dozen boxes (0.4-1.6 m) stand on the floor and cast shadows from many lights at once.
* The camera looks over the floor from 4 m up so most lights are in frame, as bright points.

Deterministic (fixed seed); written with pxr only (no ``renderer`` import).
"""
from __future__ import annotations

import argparse
import colorsys
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # make_stages.py, which adds the repository root

from pxr import UsdGeom  # noqa: E402

import make_stages as ms  # noqa: E402

SEED = 500
RES = (320, 180)
HALF = 15.0   # the floor spans [-15, 15]^2
GAIN = 0.15   # irradiance one light gives the floor right below it, before its random factor
LENS = dict(focal=0.35, h_ap=0.36, v_ap=0.2025, clip=(0.01, 1000.0))


def make(out: str, count: int = 500) -> str:
    rng = np.random.default_rng(SEED)
    doc = (f"{count} small SphereLights (radius 3-8 cm, random hues; normalize on, off, and treatAsPoint in "
           "thirds) 0.35-3 m above a 30 x 30 m near-Lambertian floor with a dozen boxes. Each light lights a "
           "patch of floor near it, so the lighting service (illum:lightSampler) decides the noise.")
    stage = ms.sub_stage(os.path.dirname(os.path.abspath(out)), "stages/many_lights/make_many_lights.py",
                         os.path.basename(out), doc)
    floor_m = ms.material(stage, "Floor", diffuseColor=(0.6, 0.6, 0.6), roughness=0.8,
                          useSpecularWorkflow=1, specularColor=(0.02, 0.02, 0.02))
    box_m = ms.material(stage, "Box", diffuseColor=(0.55, 0.5, 0.45), roughness=0.6)
    ms.bind(ms.quad(stage, "/World/Floor", 2 * HALF, 2 * HALF, doc="30 x 30 m floor."), floor_m)
    UsdGeom.Xform.Define(stage, "/World/Boxes")
    for k in range(12):
        size = rng.uniform(0.4, 1.6, 3)
        x, z = rng.uniform(-0.7 * HALF, 0.7 * HALF, 2)
        ms.cube(stage, f"/World/Boxes/Box{k:02d}", box_m, translate=(round(x, 3), round(size[1] / 2, 3), round(z, 3)),
                scale=tuple(round(s, 3) for s in size), rotate_y=round(float(rng.uniform(0, 90)), 1))
    UsdGeom.Xform.Define(stage, "/World/Lights")
    lines = [light_line(i, rng) for i in range(count)]
    yaw, pitch = ms.aim_angles((0.0, 4.0, 17.0), (0.0, 0.0, 4.0))
    ms.camera(stage, "/World/Camera", translate=(0.0, 4.0, 17.0), rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
              doc="35 mm lens on a 16:9 gate, in tenths of a metre.", **LENS)
    ms.render_settings(stage, "/World/Camera", RES, "many_lights.exr")
    # pxr writes each light over nine lines; one line per light (statements separated by ';',
    # valid .usda) keeps the file small. Splice them into the exported text, then re-open.
    text = stage.GetRootLayer().ExportToString()
    empty = 'def Xform "Lights"\n    {\n    }'
    assert empty in text, "the Lights scope moved in pxr's output"
    text = text.replace(empty, 'def Xform "Lights"\n    {\n' + "".join(lines) + "    }")
    tmp = out + ".tmp.usda"
    with open(tmp, "w") as fh:
        fh.write(text)
    print(("wrote " if ms.replace_if_changed(tmp, out) else "unchanged ") + os.path.relpath(out))
    return out


def light_line(i: int, rng: np.random.Generator) -> str:
    """One SphereLight as a line of .usda: position, radius 3-8 cm, a random hue, and its class
    (i % 3: normalize on, normalize off, treatAsPoint) with an intensity that gives each class a
    similar irradiance on the floor below it."""
    pos = (rng.uniform(-HALF + 0.5, HALF - 0.5), rng.uniform(0.35, 3.0), rng.uniform(-HALF + 0.5, HALF - 0.5))
    radius = round(float(rng.uniform(0.03, 0.08)), 3)
    rgb = colorsys.hsv_to_rgb(float(rng.uniform()), float(rng.uniform(0.3, 0.9)), 1.0)
    # Radiance L of an unnormalised sphere giving E ~ GAIN x U(0.5, 2) on the floor below it:
    # E = L pi r^2 / h^2.
    L = GAIN * float(rng.uniform(0.5, 2.0)) * pos[1] ** 2 / (np.pi * radius * radius)
    kind = i % 3
    if kind == 0:      # normalize on: radiance = intensity / (4 pi r^2), the sphere's area
        extra, intensity = "bool inputs:normalize = 1; ", L * 4.0 * np.pi * radius * radius
    elif kind == 1:    # normalize off: radiance = intensity
        extra, intensity = "bool inputs:normalize = 0; ", L
    else:              # treatAsPoint: a delta light with the power of the sphere it replaces
        extra, intensity = "bool treatAsPoint = 1; ", L
    c = ", ".join(f"{x:.3f}" for x in rgb)
    t = ", ".join(f"{x:.3f}" for x in pos)
    return (f'        def SphereLight "L{i:04d}" {{ color3f inputs:color = ({c}); float inputs:intensity = '
            f'{intensity:.4g}; float inputs:radius = {radius}; {extra}double3 xformOp:translate = ({t}); '
            f'uniform token[] xformOpOrder = ["xformOp:translate"]; }}\n')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=500)
    ap.add_argument("--out", default=os.path.join(HERE, "many_lights.usda"))
    a = ap.parse_args(argv)
    path = make(a.out, a.count)
    return 0 if ms.validate([path]) else 1


if __name__ == "__main__":
    sys.exit(main())
