#!/usr/bin/env python
"""Generate ``stages/fireflies/fireflies.usda``: thousands of fireflies over a night meadow.

Usage (from the repository root)::

    .venv/bin/python stages/fireflies/make_fireflies.py               # write fireflies.usda
    .venv/bin/python stages/fireflies/make_fireflies.py --count 20000 --out /tmp/ff.usda

In the spirit of the ~6000 on-camera fireflies of The Good Dinosaur (Pixar's "Illumination
101" talk): a many-light scene where the only light comes from small SphereLights, so which
light a shading point connects to decides the noise. Y-up, metres. The fireflies swarm in
clusters around low trees and rocks on a gently rolling meadow, mostly 0.2-1.5 m above the
ground (none inside a canopy or a rock: those are pushed out sideways). Each has a radius of
1.2-3 cm, a warm yellow-green, amber or (rarely) pale blue colour and a radiance drawn
log-uniformly in [15, 400] nits, so the ground is lit in pools under the swarms. No dome and
no moon: everything you see is lit by fireflies.

Deterministic (fixed seed). The scene is authored with pxr; the lights, one prim each under
/World/Fireflies with only translate, radius, intensity and color (values rounded), are
written one per line (statements separated by ';', which .usda allows) and spliced into the
exported text, then the file is re-opened with pxr and checked. That keeps the 5000 lights
at 1.4 MB. Depends on pxr and numpy only (not on ``renderer``).
"""
from __future__ import annotations

import argparse
import math
import os

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_OUT = os.path.join(HERE, "fireflies.usda")
SEED = 20151125          # The Good Dinosaur's release date
DEFAULT_COUNT = 5000     # the talk's shot had ~6000 on camera; --count 6000 writes that (1.6 MB)
RESOLUTION = (480, 270)


# --------------------------------------------------------------------------- helpers
def r(x, nd=3):
    v = round(float(x), nd)
    return 0.0 if v == 0 else v


def material(stage, name, **inputs) -> UsdShade.Material:
    """UsdPreviewSurface at /World/Looks/<name>; tuple inputs become color3f."""
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


def mesh(stage, path, points, faces, normals=None, doc=None) -> UsdGeom.Mesh:
    """Polygon mesh, faces (F, k) counter-clockwise seen from outside; subdivisionScheme none,
    extent; points and normals rounded to 1 cm / 0.01."""
    m = UsdGeom.Mesh.Define(stage, path)
    if doc:
        m.GetPrim().SetDocumentation(doc)
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    pts = np.asarray(points, float)
    faces = np.asarray(faces)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*(r(v, 2) for v in q)) for q in pts]))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([faces.shape[1]] * len(faces)))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in faces.ravel()]))
    if normals is not None:
        m.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(*(r(v, 2) for v in q)) for q in np.asarray(normals, float)]))
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    lo, hi = pts.min(0), pts.max(0)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    return m


def ground_height(x, z):
    """Gently rolling meadow (metres): a few long sine waves, 0 at the camera."""
    return (0.35 * np.sin(0.21 * x + 0.7) * np.sin(0.17 * z + 0.3) + 0.25 * np.sin(0.09 * x - 0.13 * z)
            - 0.35 * math.sin(0.7) * math.sin(0.3 + 0.17 * 6.0) - 0.25 * math.sin(-0.78))


def grid_mesh(x0, x1, z0, z1, nx, nz):
    """Heightfield grid: points (V, 3), quads (Q, 4) facing +Y, vertex normals (V, 3)."""
    xs, zs = np.linspace(x0, x1, nx + 1), np.linspace(z0, z1, nz + 1)
    X, Z = np.meshgrid(xs, zs)
    Y = ground_height(X, Z)
    pts = np.stack([X, Y, Z], -1).reshape(-1, 3)
    e = 1e-3
    dx = (ground_height(X + e, Z) - ground_height(X - e, Z)) / (2 * e)
    dz = (ground_height(X, Z + e) - ground_height(X, Z - e)) / (2 * e)
    nrm = np.stack([-dx, np.ones_like(dx), -dz], -1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    quads = []
    for j in range(nz):
        for i in range(nx):
            a = j * (nx + 1) + i
            # Counter-clockwise seen from +Y (x right, z toward the viewer).
            quads.append((a, a + nx + 1, a + nx + 2, a + 1))
    return pts, np.array(quads), nrm


def icosphere(subdiv=1):
    """Unit icosphere: points (V, 3), outward CCW triangles (T, 3)."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7),
         (9, 8, 1)]
    pts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdiv):
        cache, nf = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = pts[a] + pts[b]
                pts.append(m / np.linalg.norm(m))
                cache[key] = len(pts) - 1
            return cache[key]

        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return np.array(pts), np.array(f)


def cone(radius, height, sides=10, base_y=0.0):
    """Closed low-poly cone about +Y (points, outward CCW triangles)."""
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([radius * np.cos(ang), np.full(sides, base_y), -radius * np.sin(ang)], -1)
    pts = np.vstack([ring, [(0, base_y + height, 0)], [(0, base_y, 0)]])
    apex, bottom = sides, sides + 1
    tris = []
    for i in range(sides):
        j = (i + 1) % sides
        tris.append((i, j, apex))      # side, counter-clockwise seen from outside
        tris.append((j, i, bottom))    # base, facing -Y
    return pts, np.array(tris)


def merge(parts):
    pts, tris, off = [], [], 0
    for p, t in parts:
        pts.append(p)
        tris.append(t + off)
        off += len(p)
    return np.vstack(pts), np.vstack(tris)


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


# --------------------------------------------------------------------------- scene
def fireflies(rng, count, trees):
    """Positions (count, 3), radii, colours (count, 3), intensities: 93 % in swarms around
    cluster centres (a third of them at trees), the rest scattered over the meadow."""
    n_clusters = 56
    cx = rng.uniform(-16, 16, n_clusters)
    cz = rng.uniform(-36, 3, n_clusters)
    at_tree = rng.random(n_clusters) < 0.35
    pick = rng.integers(0, len(trees), n_clusters)
    cx = np.where(at_tree, trees[pick, 0] + rng.normal(0, 1.0, n_clusters), cx)
    cz = np.where(at_tree, trees[pick, 1] + rng.normal(0, 1.0, n_clusters), cz)
    spread = rng.uniform(0.5, 1.8, n_clusters)
    lift = rng.uniform(0.2, 0.6, n_clusters)       # mean height scale of a swarm
    weight = rng.uniform(0.5, 1.5, n_clusters)
    n_swarm = int(round(0.93 * count))
    k = rng.choice(n_clusters, n_swarm, p=weight / weight.sum())
    x = cx[k] + rng.normal(0, 1, n_swarm) * spread[k]
    z = cz[k] + rng.normal(0, 1, n_swarm) * spread[k]
    h = 0.1 + rng.gamma(2.0, 1.0, n_swarm) * lift[k]
    n_free = count - n_swarm
    x = np.concatenate([x, rng.uniform(-20, 20, n_free)])
    z = np.concatenate([z, rng.uniform(-45, 4, n_free)])
    h = np.concatenate([h, rng.uniform(0.3, 2.8, n_free)])
    h = np.minimum(h, 2.8)
    y = ground_height(x, z) + h
    pos = np.stack([x, y, z], -1)
    radius = rng.uniform(0.012, 0.03, count)
    palette = np.array([[0.75, 1.0, 0.25], [0.9, 1.0, 0.35], [1.0, 0.72, 0.2], [1.0, 0.85, 0.35], [0.6, 0.85, 1.0]])
    pal_p = np.array([0.35, 0.25, 0.2, 0.17, 0.03])
    col = palette[rng.choice(len(palette), count, p=pal_p)] * rng.uniform(0.85, 1.0, (count, 1))
    intensity = np.exp(rng.uniform(math.log(15.0), math.log(400.0), count))
    return pos, radius, col, intensity


def push_out(pos, radius, solids):
    """Move fireflies that would sit inside a canopy cone or a rock (bounded by a cone too) out
    sideways, 5 cm clear of its surface: a light inside a closed mesh lights nothing outside.
    solids: (x, z, base y, base radius, height) of upright cones."""
    pos = pos.copy()
    for x, z, yb, rad, hgt in solids:
        rel = pos[:, [0, 2]] - (x, z)
        dist = np.linalg.norm(rel, axis=1)
        t = (pos[:, 1] - yb) / hgt
        allowed = rad * (1.0 - t) + radius + 0.05          # cone radius at that height, plus clearance
        inside = (t > -0.05) & (t < 1.0) & (dist < allowed)
        if np.any(inside):
            dirs = rel[inside] / np.maximum(dist[inside], 1e-9)[:, None]
            dirs[dist[inside] < 1e-9] = (1.0, 0.0)
            new = np.array((x, z)) + dirs * allowed[inside][:, None]
            pos[inside, 0], pos[inside, 2] = new[:, 0], new[:, 1]
    # Stay at least 10 cm above the (rolling) ground where they landed.
    pos[:, 1] = np.maximum(pos[:, 1], ground_height(pos[:, 0], pos[:, 2]) + 0.1)
    return pos


def build(out: str, count: int = DEFAULT_COUNT) -> str:
    rng = np.random.default_rng(SEED)
    doc = (f"Fireflies: {count} small SphereLights (radius 1.2-3 cm, 15-400 nits, warm yellow-green / amber, a few "
           "pale blue) swarming over a rolling night meadow with low trees and rocks. Y-up, metres. The only light "
           "comes from the fireflies (no dome, no moon), so the lighting service decides the noise. Generated by "
           "stages/fireflies/make_fireflies.py; edit the script and re-run.")
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    stage.SetMetadata("comment", "Generated by stages/fireflies/make_fireflies.py; edit the script and re-run.")
    layer.documentation = doc
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Looks")
    near_lambert = dict(roughness=0.9, useSpecularWorkflow=1, specularColor=(0.02, 0.02, 0.02))
    grass = material(stage, "Grass", diffuseColor=(0.16, 0.22, 0.09), **near_lambert)
    rock = material(stage, "Rock", diffuseColor=(0.32, 0.3, 0.27), **near_lambert)
    bark = material(stage, "Bark", diffuseColor=(0.2, 0.14, 0.09), **near_lambert)
    leaves = material(stage, "Leaves", diffuseColor=(0.09, 0.2, 0.08), **near_lambert)

    # ---- meadow ---------------------------------------------------------------------------
    pts, quads, nrm = grid_mesh(-40.0, 40.0, -70.0, 10.0, 40, 40)
    g = mesh(stage, "/World/Meadow", pts, quads, nrm, doc="80 x 80 m rolling heightfield (40 x 40 quads, 2 m).")
    bind(g.GetPrim(), grass)

    # ---- trees: trunk cone + two stacked canopy cones, merged into two meshes --------------
    n_trees = 14
    tx = rng.uniform(-16, 16, n_trees)
    tz = rng.uniform(-40, -4, n_trees)
    trees = np.stack([tx, tz], -1)
    UsdGeom.Xform.Define(stage, "/World/Trees").GetPrim().SetDocumentation(
        "Low-poly conifers: a trunk cone and two canopy cones each (merged meshes).")
    trunks, crowns, solids = [], [], []
    for x, z in trees:
        y0 = float(ground_height(x, z)) - 0.1
        s = rng.uniform(0.7, 1.4)
        p, t = cone(0.18 * s, 2.2 * s, 8)
        trunks.append((p + (x, y0, z), t))
        for base, rad, hgt in ((1.2, 1.6, 2.6), (2.4, 1.15, 2.2)):
            p, t = cone(rad * s, hgt * s, 10, base * s)
            crowns.append((p + (x, y0, z), t))
            solids.append((x, z, y0 + base * s, rad * s, hgt * s))
    p, t = merge(trunks)
    bind(mesh(stage, "/World/Trees/Trunks", p, t).GetPrim(), bark)
    p, t = merge(crowns)
    bind(mesh(stage, "/World/Trees/Crowns", p, t).GetPrim(), leaves)

    # ---- rocks: squashed, jittered icospheres ---------------------------------------------
    ip, it = icosphere(1)
    rocks = []
    for _ in range(22):
        x, z = rng.uniform(-18, 18), rng.uniform(-42, 2)
        sc = rng.uniform(0.25, 0.9) * np.array([1.0, rng.uniform(0.45, 0.8), rng.uniform(0.7, 1.2)])
        jit = ip * (1 + rng.uniform(-0.12, 0.12, (len(ip), 1)))
        a = rng.uniform(0, 2 * np.pi)
        rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        p = (jit * sc) @ rot.T + (x, float(ground_height(x, z)) + 0.25 * sc[1], z)
        rocks.append((p, it))
        solids.append((x, z, float(ground_height(x, z)) - 0.5 * sc[1], 1.2 * max(sc[0], sc[2]), 2.0 * sc[1]))
    p, t = merge(rocks)
    bind(mesh(stage, "/World/Rocks", p, t, doc="22 jittered, squashed icospheres (80 triangles each).").GetPrim(),
         rock)

    # ---- fireflies ------------------------------------------------------------------------
    pos, radius, col, intensity = fireflies(rng, count, trees)
    pos = push_out(pos, radius, solids)
    UsdGeom.Xform.Define(stage, "/World/Fireflies").GetPrim().SetDocumentation(FIREFLIES_DOC)

    # ---- camera and render settings -------------------------------------------------------
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.GetPrim().SetDocumentation("Eye height 1.6 m above the meadow at z = 6, looking down -Z, 9 deg down.")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    cam.CreateFocalLengthAttr(24.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(20.25)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 500.0))
    cam.AddTranslateOp().Set(Gf.Vec3d(0.0, r(float(ground_height(0.0, 6.0)) + 1.6), 6.0))
    cam.AddRotateXOp().Set(-9.0)
    render_settings(stage, "/World/Camera", RESOLUTION, "fireflies.exr")

    # pxr writes each light over nine lines (~300 bytes); the same specs written one light per
    # line, statements separated by ';' (valid .usda), take ~190. Splice them into the
    # exported text, then re-open the file with pxr and check every light.
    text = stage.GetRootLayer().ExportToString()
    head = f'def Xform "Fireflies" (\n        doc = "{FIREFLIES_DOC}"\n    )\n    {{\n'
    at = text.index(head) + len(head)
    assert text[at:].startswith("    }"), "expected an empty /World/Fireflies"
    lines = [firefly_line(i, pos[i], radius[i], intensity[i], col[i]) for i in range(count)]
    text = text[:at] + "".join(lines) + text[at:]
    with open(out, "w") as fh:
        fh.write(text)
    check(out, count, pos, radius, intensity, col)
    return out


FIREFLIES_DOC = ("SphereLights written one per line: translate, radius (m), intensity (nits) and color only; "
                 "normalize off.")


def firefly_line(i, p, radius, intensity, c) -> str:
    """One SphereLight spec on one line (values rounded: 1 cm, 1 mm, whole nits, 2-digit colour)."""
    return (f'        def SphereLight "F{i}" {{ color3f inputs:color = ({r(c[0], 2)}, {r(c[1], 2)}, {r(c[2], 2)}); '
            f'float inputs:intensity = {int(round(intensity))}; float inputs:radius = {r(radius, 3)}; '
            f'double3 xformOp:translate = ({r(p[0], 2)}, {r(p[1], 2)}, {r(p[2], 2)}); '
            f'uniform token[] xformOpOrder = ["xformOp:translate"]; }}\n')


def check(path, count, pos, radius, intensity, col) -> None:
    """Re-open the written stage: every firefly is a SphereLight with the intended values."""
    stage = Usd.Stage.Open(path)
    lights = [p for p in stage.GetPrimAtPath("/World/Fireflies").GetChildren() if p.IsA(UsdLux.SphereLight)]
    assert len(lights) == count, (len(lights), count)
    for i in (0, count // 2, count - 1):
        light = UsdLux.SphereLight(stage.GetPrimAtPath(f"/World/Fireflies/F{i}"))
        t = light.ComputeLocalToWorldTransform(Usd.TimeCode.Default()).ExtractTranslation()
        assert np.allclose(t, pos[i], atol=0.006), (i, t, pos[i])
        assert abs(light.GetRadiusAttr().Get() - radius[i]) < 6e-4
        assert abs(light.GetIntensityAttr().Get() - intensity[i]) <= 0.5
        assert np.allclose(light.GetColorAttr().Get(), col[i], atol=0.006)
    assert stage.GetMetadata("renderSettingsPrimPath") == "/Render/Settings"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=DEFAULT_COUNT)
    ap.add_argument("--out", default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    path = build(args.out, args.count)
    print(f"wrote {path} ({os.path.getsize(path) / 1e6:.2f} MB, {args.count} fireflies)")


if __name__ == "__main__":
    main()
