#!/usr/bin/env python
"""Generate ``stages/city_lights/city_lights.usda``: a night street of neon signs and lamps.

Usage (from the repository root)::

    .venv/bin/python stages/city_lights/make_city_lights.py            # write city_lights.usda
    .venv/bin/python stages/city_lights/make_city_lights.py --out /tmp/city.usda

"Car lights, neon signs and city luminaires" (Pixar's "Illumination 101", The Blue Umbrella):
a few hundred lights, most of them one-sided and facing the street, which is where the
orientation bounds of a light BVH pay off. Y-up, metres. A 12 m wide street runs down -Z
(asphalt road x in [-4, 4], sidewalks to x = +-6) between two rows of box buildings. On the
facades: neon RectLights (pink, cyan, violet, red, green, amber; tubes and panels 0.3-2.5 m
wide, 20-300 nits, thin tubes brightest) and lit windows (warm RectLights, 4-12 nits); over the sidewalks, street
lamps: DiskLights (radius 0.22 m, 900 nits) facing down on 5 m poles every 12 m. No dome.

Deterministic (fixed seed); written with pxr only (no ``renderer`` import). RectLights and
DiskLights emit along their local -Z: ``rotateY = 90`` turns a light on the right-hand
facade (x = +6) toward -X, the street; ``rotateY = -90`` does the left one; ``rotateX = -90``
points a lamp down.
"""
from __future__ import annotations

import argparse
import os

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_OUT = os.path.join(HERE, "city_lights.usda")
SEED = 2013            # The Blue Umbrella
RESOLUTION = (480, 270)
STREET_HALF = 6.0      # facades at x = +-6
Z_NEAR, Z_FAR = 6.0, -90.0

NEON = {  # linear Rec.709 colours (saturated, as neon reads at night)
    "pink": (1.0, 0.08, 0.45), "cyan": (0.05, 0.85, 1.0), "violet": (0.55, 0.1, 1.0),
    "red": (1.0, 0.06, 0.03), "green": (0.15, 1.0, 0.25), "amber": (1.0, 0.55, 0.05),
}


def r(x, nd=3):
    v = round(float(x), nd)
    return 0.0 if v == 0 else v


def material(stage, name, **inputs) -> UsdShade.Material:
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/PreviewSurface")
    sh.CreateIdAttr("UsdPreviewSurface")
    for k, v in inputs.items():
        if isinstance(v, tuple):
            sh.CreateInput(k, Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*v))
        elif k == "useSpecularWorkflow":
            sh.CreateInput(k, Sdf.ValueTypeNames.Int).Set(int(v))
        else:
            sh.CreateInput(k, Sdf.ValueTypeNames.Float).Set(float(v))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def bind(prim, mat) -> None:
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def boxes_mesh(stage, path, boxes, doc=None) -> UsdGeom.Mesh:
    """One mesh of axis-aligned boxes [(lo, hi), ...], quads counter-clockwise from outside."""
    pts, idx = [], []
    corner = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    quads = [(4, 5, 6, 7), (1, 0, 3, 2), (5, 1, 2, 6), (0, 4, 7, 3), (3, 7, 6, 2), (0, 1, 5, 4)]
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        base = len(pts)
        pts.extend(lo + corner * (hi - lo))
        idx.extend(base + i for q in quads for i in q)
    m = UsdGeom.Mesh.Define(stage, path)
    if doc:
        m.GetPrim().SetDocumentation(doc)
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*(r(v, 3) for v in p)) for p in pts]))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([4] * (len(idx) // 4)))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in idx]))
    p = np.array(pts)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p.min(0))), Gf.Vec3f(*map(float, p.max(0)))]))
    return m


def rect_light(stage, path, pos, rot_y, width, height, intensity, color, doc=None):
    light = UsdLux.RectLight.Define(stage, path)
    if doc:
        light.GetPrim().SetDocumentation(doc)
    light.AddTranslateOp().Set(Gf.Vec3d(*(r(v) for v in pos)))
    light.AddRotateYOp().Set(float(rot_y))
    light.CreateWidthAttr(r(width))
    light.CreateHeightAttr(r(height))
    light.CreateIntensityAttr(r(intensity, 1))
    light.CreateColorAttr(Gf.Vec3f(*(r(c) for c in color)))
    return light


def render_settings(stage, cam_path, res, product):
    UsdGeom.Scope.Define(stage, "/Render")
    rs = UsdRender.Settings.Define(stage, "/Render/Settings")
    rs.CreateCameraRel().SetTargets([Sdf.Path(cam_path)])
    rs.CreateResolutionAttr(Gf.Vec2i(*res))
    rs.CreatePixelAspectRatioAttr(1.0)
    rs.CreateAspectRatioConformPolicyAttr(UsdRender.Tokens.expandAperture)
    rs.CreateRenderingColorSpaceAttr("lin_rec709_scene")
    prod = UsdRender.Product.Define(stage, "/Render/Beauty")
    prod.CreateProductNameAttr(product)
    prod.CreateProductTypeAttr(UsdRender.Tokens.raster)
    rs.CreateProductsRel().SetTargets([prod.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")


def buildings(rng, side):
    """Box buildings along one side (side = +1 right, -1 left): [(lo, hi)], facade at x = side*6."""
    out, z = [], Z_NEAR + 4.0
    while z > Z_FAR:
        depth = rng.uniform(7.0, 15.0)
        height = rng.uniform(7.0, 26.0)
        back = rng.uniform(8.0, 14.0)
        x0, x1 = sorted((side * STREET_HALF, side * (STREET_HALF + back)))
        out.append(((x0, 0.0, z - depth), (x1, height, z)))
        z -= depth + rng.choice([0.0, 0.0, 1.5, 3.0])   # some alleys
    return out


def build(out: str) -> str:
    rng = np.random.default_rng(SEED)
    doc = ("City lights: a night street between box buildings, lit by ~200 neon RectLights on the facades, "
           "~85 lit windows (warm RectLights) and 16 street-lamp DiskLights facing down. Y-up, metres; no "
           "dome. Generated by stages/city_lights/make_city_lights.py; edit the script and re-run.")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    stage.SetMetadata("comment", "Generated by stages/city_lights/make_city_lights.py; edit the script and re-run.")
    layer.documentation = doc
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Looks")
    asphalt = material(stage, "Asphalt", diffuseColor=(0.07, 0.07, 0.075), roughness=0.45,
                       useSpecularWorkflow=1, specularColor=(0.04, 0.04, 0.04))
    paving = material(stage, "Paving", diffuseColor=(0.3, 0.29, 0.27), roughness=0.8,
                      useSpecularWorkflow=1, specularColor=(0.03, 0.03, 0.03))
    walls = [material(stage, f"Wall{i}", diffuseColor=c, roughness=0.85, useSpecularWorkflow=1,
                      specularColor=(0.02, 0.02, 0.02))
             for i, c in enumerate([(0.3, 0.28, 0.25), (0.2, 0.22, 0.24), (0.32, 0.22, 0.18)])]
    metal = material(stage, "PoleMetal", diffuseColor=(0.1, 0.1, 0.1), roughness=0.4, metallic=1.0)

    # ---- street -----------------------------------------------------------------------------
    UsdGeom.Xform.Define(stage, "/World/Street")
    bind(boxes_mesh(stage, "/World/Street/Road", [((-4.0, -0.2, Z_FAR - 20), (4.0, 0.0, Z_NEAR + 10))],
                    doc="8 m wide asphalt road, slightly glossy (roughness 0.45).").GetPrim(), asphalt)
    bind(boxes_mesh(stage, "/World/Street/Sidewalks",
                    [((-STREET_HALF, -0.2, Z_FAR - 20), (-4.0, 0.15, Z_NEAR + 10)),
                     ((4.0, -0.2, Z_FAR - 20), (STREET_HALF, 0.15, Z_NEAR + 10))],
                    doc="2 m sidewalks, 15 cm kerbs.").GetPrim(), paving)

    # ---- buildings ----------------------------------------------------------------------------
    UsdGeom.Xform.Define(stage, "/World/Buildings")
    blds = [(b, s) for s in (1, -1) for b in buildings(rng, s)]
    groups = [[], [], []]
    for i, (b, _) in enumerate(blds):
        groups[i % 3].append(b)
    for i, g in enumerate(groups):
        bind(boxes_mesh(stage, f"/World/Buildings/Block{i}", g).GetPrim(), walls[i])

    # ---- lights -------------------------------------------------------------------------------
    UsdGeom.Xform.Define(stage, "/World/Lights")
    UsdGeom.Xform.Define(stage, "/World/Lights/Neon")
    UsdGeom.Xform.Define(stage, "/World/Lights/Windows")
    UsdGeom.Xform.Define(stage, "/World/Lights/Lamps")
    n_neon = n_win = 0
    names = list(NEON)
    for (lo, hi), side in blds:
        facade_x = side * STREET_HALF - side * 0.02      # 2 cm in front of the wall
        rot = 90.0 if side > 0 else -90.0                # emit toward the street (-X / +X)
        z0, z1, top = lo[2], hi[2], hi[1]
        # Neon: shop signs at 2.6-4.5 m plus vertical blade signs and tubes higher up.
        for _ in range(rng.integers(8, 17)):
            w, h = rng.choice([(rng.uniform(1.0, 2.5), rng.uniform(0.25, 0.6)),   # panel
                               (rng.uniform(0.8, 2.2), rng.uniform(0.04, 0.08)),  # horizontal tube
                               (rng.uniform(0.05, 0.09), rng.uniform(0.8, 2.0)),  # vertical tube
                               (rng.uniform(0.3, 0.6), rng.uniform(1.2, 3.0))])   # blade sign
            y = rng.uniform(2.6, min(top - 0.5, 4.5) if rng.random() < 0.6 else top - 1.0)
            z = rng.uniform(z0 + w / 2 + 0.3, z1 - w / 2 - 0.3) if z1 - z0 > w + 0.6 else 0.5 * (z0 + z1)
            c = NEON[names[rng.integers(len(names))]]
            # Thin tubes are brighter than panels: radiance ~ 1/sqrt(area), 20-300 nits.
            inten = min(300.0, rng.uniform(0.6, 1.6) * 30.0 / np.sqrt(w * h))
            rect_light(stage, f"/World/Lights/Neon/N{n_neon}", (facade_x, y, z), rot, w, h, inten, c)
            n_neon += 1
        # Windows: a few lit ones per building, warm, on upper floors.
        floors = int((top - 4.0) // 3.2)
        for _ in range(rng.integers(3, 9)):
            if floors < 1:
                break
            y = 4.0 + 3.2 * rng.integers(0, floors) + 1.3
            z = rng.uniform(z0 + 1.0, z1 - 1.0)
            warm = (1.0, rng.uniform(0.62, 0.8), rng.uniform(0.3, 0.5))
            rect_light(stage, f"/World/Lights/Windows/W{n_win}", (facade_x, y, z), rot, 1.2, 1.5,
                       rng.uniform(4.0, 12.0), warm)
            n_win += 1

    poles = []
    n_lamp = 0
    for k, z in enumerate(np.arange(Z_NEAR - 2.0, Z_FAR, -12.0)):
        for side in (1, -1):
            x = side * 4.6
            zz = z - (6.0 if side < 0 else 0.0)
            poles.append(((x - 0.06, 0.15, zz - 0.06), (x + 0.06, 5.05, zz + 0.06)))
            poles.append(((x - side * 1.3 - 0.25 if side > 0 else x - 0.05, 5.0, zz - 0.25),
                          (x + 0.05 if side > 0 else x + 1.3 + 0.25, 5.12, zz + 0.25)))
            lamp = UsdLux.DiskLight.Define(stage, f"/World/Lights/Lamps/L{n_lamp}")
            lamp.AddTranslateOp().Set(Gf.Vec3d(r(x - side * 1.0), 4.98, r(zz)))
            lamp.AddRotateXOp().Set(-90.0)
            lamp.CreateRadiusAttr(0.22)
            lamp.CreateIntensityAttr(900.0)
            lamp.CreateColorAttr(Gf.Vec3f(1.0, 0.82, 0.6))
            n_lamp += 1
    bind(boxes_mesh(stage, "/World/Street/LampPoles", poles,
                    doc="Street-lamp poles and heads (thin boxes); the DiskLight sits 2 cm under each head.").GetPrim(),
         metal)
    stage.GetPrimAtPath("/World/Lights").SetDocumentation(
        f"{n_neon} neon RectLights and {n_win} window RectLights on the facades (2 cm in front, emitting toward "
        f"the street), {n_lamp} street-lamp DiskLights facing down (rotateX -90).")

    # ---- camera and render settings -----------------------------------------------------------
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.GetPrim().SetDocumentation("Pedestrian view from the road: 1.6 m high, looking down the street (-Z).")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(20.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(20.25)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 500.0))
    cam.AddTranslateOp().Set(Gf.Vec3d(-1.2, 1.6, Z_NEAR + 2.0))
    cam.AddRotateYOp().Set(-4.0)
    cam.AddRotateXOp().Set(4.0)
    render_settings(stage, "/World/Camera", RESOLUTION, "city_lights.exr")
    stage.GetRootLayer().Export(out)
    check(out)
    return out


def check(path) -> None:
    """Re-open the stage: every lamp points down and every facade light toward the street."""
    stage = Usd.Stage.Open(path)
    n = 0
    for prim in stage.Traverse():
        if not prim.HasAPI(UsdLux.LightAPI):
            continue
        n += 1
        m = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        emit = m.TransformDir(Gf.Vec3d(0, 0, -1))
        pos = m.ExtractTranslation()
        if prim.IsA(UsdLux.DiskLight):
            assert (emit - Gf.Vec3d(0, -1, 0)).GetLength() < 1e-9, prim.GetPath()
        else:
            assert emit[0] * pos[0] < 0 and abs(emit[1]) < 1e-9, (prim.GetPath(), emit, pos)
    assert 200 <= n <= 600, n
    assert stage.GetMetadata("renderSettingsPrimPath") == "/Render/Settings"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    path = build(args.out)
    stage = Usd.Stage.Open(path)
    n = sum(1 for p in stage.Traverse() if p.HasAPI(UsdLux.LightAPI))
    print(f"wrote {path} ({os.path.getsize(path) / 1e6:.2f} MB, {n} lights)")


if __name__ == "__main__":
    main()
