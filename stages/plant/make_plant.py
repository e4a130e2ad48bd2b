#!/usr/bin/env python
"""Generate ``stages/plant/plant.usda``: a small tree with cut-out leaves and normal-mapped bark.

Usage (from the repository root)::

    .venv/bin/python stages/plant/make_plant.py      # write plant.usda and textures/

The textured-asset stage of the one-integrator issue (#23: "a textured asset with normal maps
and cut-outs"). Y-up, metres, 320x240, camera /World/Camera, RenderSettings /Render/Settings.
About 900 triangles:

* /World/Ground: a 6 x 6 m grid of 8 x 8 quads, st repeating 3 times, normal-mapped with
  ``textures/ground_normal.png`` (round pebbles), a soil colour.
* /World/Trunk: a tapered 12-sided cylinder of 6 rings with smooth vertex normals, st around
  (u) and up (v), normal-mapped with ``textures/bark_normal.png`` (vertical grooves).
* /World/Leaves: 300 leaf cards (one quad each, doubleSided) around the crown, their diffuse
  colour and opacity from ``textures/leaf.png`` (RGBA: a leaf with a midrib; alpha 0 outside the
  leaf) with opacityThreshold 0.5, so camera, bounce and shadow rays pass through the card
  around each leaf.
* A constant pale-blue DomeLight and a DistantLight sun (angle 2 degrees) from the upper left.

The normal maps are 8-bit raw PNGs holding (n + 1) / 2, decoded by the UsdUVTexture's
scale (2, 2, 2, 1) and bias (-1, -1, -1, 0) as studio assets author them. Deterministic (fixed
seed); written with pxr and OpenImageIO only (no ``renderer`` import).
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # make_stages.py, which adds the repository root

from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade  # noqa: E402

import make_stages as ms  # noqa: E402

SEED = 23
RES = (320, 240)
TEX = os.path.join(HERE, "textures")
N_LEAVES = 300
LENS = dict(focal=0.35, h_ap=0.36, v_ap=0.27, clip=(0.01, 1000.0))


# --------------------------------------------------------------------------- textures
def _write_png(name, img, srgb=False):
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(np.ascontiguousarray(img, dtype=np.float32))
    if srgb:
        buf.specmod().attribute("oiio:ColorSpace", "sRGB")
    path = os.path.join(TEX, name)
    assert buf.write(path, oiio.UINT8), oiio.geterror()
    return path


def _normal_map(height, strength):
    """A tangent-space normal map (x along +u = image columns, y along +v = up the image rows)
    of a periodic height field (rows top to bottom), encoded as (n + 1) / 2."""
    # Row 0 is the top of the image, where v = 1: the height's v-derivative flips sign.
    dhdu = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) / 2.0
    dhdv = -(np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) / 2.0
    n = np.stack([-strength * dhdu, -strength * dhdv, np.ones_like(height)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return (n + 1.0) / 2.0


def write_textures():
    os.makedirs(TEX, exist_ok=True)
    n = 64
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    # Leaf: an almond shape along v (alpha), green darkening toward the edge, a pale midrib.
    x = (xx - 0.5) * 2.0
    y = yy * 2.0 - 1.0
    half_width = 0.62 * np.sqrt(np.clip(1.0 - y * y, 0.0, 1.0)) * (1.0 - 0.35 * y)
    inside = np.abs(x) < half_width
    edge = np.clip(np.abs(x) / np.maximum(half_width, 1e-3), 0.0, 1.0)
    green = np.array([0.28, 0.55, 0.16])[None, None, :] * (1.0 - 0.35 * edge[..., None])
    rib = (np.abs(x) < 0.05)[..., None]
    rgb = np.where(rib, np.array([0.62, 0.75, 0.40]), green)
    leaf = np.concatenate([rgb, inside[..., None].astype(float)], axis=-1)
    _write_png("leaf.png", leaf, srgb=True)
    # Bark: vertical grooves (along v), 6 across the texture, with a slow wobble.
    u, v = np.meshgrid(np.arange(n) / n, np.arange(n) / n)
    bark_h = np.abs(np.sin(math.pi * (6.0 * u + 0.15 * np.sin(2.0 * math.pi * v))))
    _write_png("bark_normal.png", _normal_map(bark_h, 12.0))
    # Ground: round pebbles on a 4 x 4 lattice.
    cu, cv = (u * 4.0) % 1.0 - 0.5, (v * 4.0) % 1.0 - 0.5
    ground_h = np.sqrt(np.clip(0.16 - cu * cu - cv * cv, 0.0, None))
    _write_png("ground_normal.png", _normal_map(ground_h, 10.0))


# --------------------------------------------------------------------------- geometry
def _textured_material(stage, name, file, *, color_space, normal=False, cutout=False, **inputs):
    """A UsdPreviewSurface reading ``textures/<file>`` through st: into ``normal`` (scale/bias
    decoding (n + 1) / 2), or into diffuseColor (rgb) and opacity (a) with opacityThreshold 0.5."""
    mat = ms.material(stage, name, **inputs)
    tex = ms.texture_chain(stage, mat, f"./textures/{file}", color_space)
    pbr = ms.surface_shader(mat)
    if normal:
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
        tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
        tex.GetInput("fallback").Set(Gf.Vec4f(0.5, 0.5, 1.0, 1.0))
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        pbr.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    if cutout:
        tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        tex.CreateOutput("a", Sdf.ValueTypeNames.Float)
        pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
        pbr.CreateInput("opacity", Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "a")
        pbr.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
    return mat


def ground(stage, mat, half=3.0, cells=8, repeat=3.0):
    pts, st = [], []
    for j in range(cells + 1):
        for i in range(cells + 1):
            x, z = -half + 2 * half * i / cells, half - 2 * half * j / cells
            pts.append((x, 0.0, z))
            st.append((repeat * i / cells, repeat * j / cells))
    idx = []
    for j in range(cells):
        for i in range(cells):
            a = j * (cells + 1) + i
            idx += [a, a + 1, a + cells + 2, a + cells + 1]  # counter-clockwise seen from +Y
    m = ms.mesh(stage, "/World/Ground", pts, [4] * (cells * cells), idx, normals=[(0, 1, 0)] * len(pts), st=st,
                doc="6 x 6 m ground, pebble normal map.")
    ms.bind(m, mat)


def trunk(stage, mat, sides=12, rings=6, height=1.6, r0=0.12, r1=0.06):
    pts, nrm, st = [], [], []
    slope = (r0 - r1) / height
    for j in range(rings + 1):
        v = j / rings
        rad = r0 + (r1 - r0) * v
        for i in range(sides + 1):  # a seam column repeats the first, for st
            a = 2.0 * math.pi * i / sides
            c, s = math.cos(a), math.sin(a)
            pts.append((rad * c, height * v, -rad * s))
            nn = np.array([c, slope, -s])
            nrm.append(tuple(nn / np.linalg.norm(nn)))
            st.append((2.0 * i / sides, 1.5 * v))
    idx = []
    for j in range(rings):
        for i in range(sides):
            a = j * (sides + 1) + i
            idx += [a, a + 1, a + sides + 2, a + sides + 1]  # outward: u turns counter-clockwise seen from +Y
    m = ms.mesh(stage, "/World/Trunk", pts, [4] * (rings * sides), idx, normals=nrm, st=st,
                doc="Tapered trunk, bark normal map (grooves along its length).")
    ms.bind(m, mat)


def leaves(stage, mat, rng, count=N_LEAVES, center=(0.0, 1.75, 0.0), radii=(0.75, 0.55, 0.75)):
    pts, idx, st = [], [], []
    for k in range(count):
        # A point in the crown's ellipsoid, a random tilt around a mostly outward facing.
        while True:
            q = rng.uniform(-1.0, 1.0, 3)
            if q @ q <= 1.0:
                break
        c = np.asarray(center) + q * radii
        out = q / max(np.linalg.norm(q), 1e-3) + rng.normal(0.0, 0.6, 3)
        nrm = out / np.linalg.norm(out)
        axis = np.cross(nrm, rng.normal(size=3))
        axis /= np.linalg.norm(axis)   # the leaf's length (v)
        side = np.cross(axis, nrm)     # its width (u); side x axis = nrm (counter-clockwise)
        length, width = rng.uniform(0.16, 0.26), rng.uniform(0.08, 0.12)
        base = len(pts)
        for du, dv in ((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)):
            pts.append(tuple(c + side * width * 2 * du + axis * length * 2 * dv))
            st.append((du + 0.5, dv + 0.5))
        idx += [base, base + 1, base + 2, base + 3]
    m = ms.mesh(stage, "/World/Leaves", pts, [4] * count, idx, st=st, st_interp="vertex", double_sided=True,
                doc=f"{count} leaf cards; the leaf texture's alpha cuts each card to its leaf (opacityThreshold 0.5).")
    ms.bind(m, mat)


def make(out: str) -> str:
    rng = np.random.default_rng(SEED)
    write_textures()
    doc = ("A small tree (~900 triangles) on a pebbled ground: 300 leaf cards whose texture alpha cuts them to "
           "leaves (opacityThreshold 0.5), a trunk and ground with tangent-space normal maps, under a pale-blue "
           "dome and a low sun from the upper left. Expected image: a green crown with sky and ground visible "
           "between the leaves, dappled leaf shadows on a bumpy ground, grooved bark.")
    stage = ms.sub_stage(os.path.dirname(os.path.abspath(out)), "stages/plant/make_plant.py",
                         os.path.basename(out), doc)
    ground_m = _textured_material(stage, "Ground", "ground_normal.png", color_space="raw", normal=True,
                                  diffuseColor=(0.42, 0.33, 0.24), roughness=0.85)
    bark_m = _textured_material(stage, "Bark", "bark_normal.png", color_space="raw", normal=True,
                                diffuseColor=(0.30, 0.22, 0.15), roughness=0.7)
    leaf_m = _textured_material(stage, "Leaf", "leaf.png", color_space="sRGB", cutout=True, roughness=0.45)
    ground(stage, ground_m)
    trunk(stage, bark_m)
    leaves(stage, leaf_m, rng)
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    sky.CreateIntensityAttr(0.35)
    sky.CreateColorAttr(Gf.Vec3f(0.6, 0.75, 1.0))
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateAngleAttr(2.0)
    sun.CreateIntensityAttr(2.5 / (2.0 * math.pi * (1.0 - math.cos(math.radians(1.0)))))
    ms.place(sun, rotate_y=-35.0, rotate_x=-50.0)
    yaw, pitch = ms.aim_angles((0.5, 1.3, 3.0), (0.0, 1.15, 0.0))
    ms.camera(stage, "/World/Camera", translate=(0.5, 1.3, 3.0), rotate_y=round(yaw, 2), rotate_x=round(pitch, 2),
              doc="35 mm lens on a 4:3 gate, in tenths of a metre.", **LENS)
    ms.render_settings(stage, "/World/Camera", RES, "plant.exr")
    return ms.save_if_changed(stage)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(HERE, "plant.usda"))
    a = ap.parse_args(argv)
    path = make(a.out)
    return 0 if ms.validate([path]) else 1


if __name__ == "__main__":
    sys.exit(main())
