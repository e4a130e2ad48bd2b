#!/usr/bin/env python
"""Write a large benchmark stage (not committed; generate it where you need it).

    python bench/make_big_stage.py                              # /tmp/illum_big_stage.usda, ~1M triangles
    python bench/make_big_stage.py OUT.usda --triangles 1000000
    python bench/make_big_stage.py OUT.usdc --triangles 4000000 --shape spheres

Shapes:
  terrain  (default) one displaced height-field grid, n x n quads split into 2 n^2
           triangles (n = ceil(sqrt(T / 2))), 40 x 40 m, smooth vertex normals;
  spheres  many small UV spheres merged into ONE mesh (lots of small, separate
           objects inside a single BVH).

Output layout:
  OUT.usda  a small, readable top layer (camera, lights, material, RenderSettings)
            that references the heavy mesh stored next to it as OUT_geom.usdc
            (binary crate: fast to write, read and memory-map);
  OUT.usdc  everything in one binary file.

The stage is Y-up, metersPerUnit 1, with /Render/Settings referenced by the
stage metadata renderSettingsPrimPath (like the stages in stages/).  All faces
are triangles and subdivisionScheme is "none", so the triangle count is exact.
Only pxr and numpy are used (nothing from renderer/).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

SIZE = 40.0  # metres, side of the terrain / scatter area


# --------------------------------------------------------------------------- geometry
def terrain(triangles: int, seed: int):
    n = max(1, math.ceil(math.sqrt(triangles / 2.0)))
    rng = np.random.default_rng(seed)
    t = np.linspace(-SIZE / 2, SIZE / 2, n + 1, dtype=np.float64)
    x, z = np.meshgrid(t, t)  # row = z, column = x
    # a few octaves of random sinusoids: smooth, deterministic, cheap
    h = np.zeros_like(x)
    amp, freq = 1.6, 0.12
    for _ in range(6):
        for _ in range(3):
            k = rng.normal(size=2)
            k = k / np.linalg.norm(k) * freq * 2 * math.pi
            h += amp * np.sin(k[0] * x + k[1] * z + rng.uniform(0, 2 * math.pi)) / 3
        amp *= 0.5
        freq *= 2.1
    pts = np.stack([x, h, z], -1).reshape(-1, 3).astype(np.float32)

    # normals from central differences of the height field
    dx = t[1] - t[0]
    gz, gx = np.gradient(h, dx)
    nrm = np.stack([-gx, np.ones_like(h), -gz], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    nrm = nrm.reshape(-1, 3).astype(np.float32)

    i, j = np.meshgrid(np.arange(n), np.arange(n))  # i = column (x), j = row (z)
    a = (j * (n + 1) + i).ravel()
    b = a + 1
    c = a + (n + 1) + 1
    d = a + (n + 1)
    # counter-clockwise seen from +Y: (a, d, c) and (a, c, b)
    # (a at (x, z), d at (x, z + dz), c at (x + dx, z + dz), b at (x + dx, z))
    tri = np.stack([np.stack([a, d, c], 1), np.stack([a, c, b], 1)], 1).reshape(-1, 3)
    return pts, nrm, tri.astype(np.int32)


def uv_sphere(nu=16, nv=8):
    """Unit UV sphere, triangles only, counter-clockwise from outside."""
    verts = [(0.0, 1.0, 0.0)]
    for j in range(1, nv):
        th = math.pi * j / nv
        for i in range(nu):
            ph = 2 * math.pi * i / nu
            verts.append((math.sin(th) * math.sin(ph), math.cos(th), math.sin(th) * math.cos(ph)))
    verts.append((0.0, -1.0, 0.0))
    v = np.array(verts)
    ring = lambda j, i: 1 + (j - 1) * nu + (i % nu)
    tris = []
    south = len(verts) - 1
    for i in range(nu):
        tris.append((0, ring(1, i), ring(1, i + 1)))
        tris.append((south, ring(nv - 1, i + 1), ring(nv - 1, i)))
    for j in range(1, nv - 1):
        for i in range(nu):
            a, b, c, d = ring(j, i), ring(j, i + 1), ring(j + 1, i + 1), ring(j + 1, i)
            tris += [(a, d, c), (a, c, b)]
    return v, np.array(tris, np.int64)


def spheres(triangles: int, seed: int):
    sv, st = uv_sphere()
    count = max(1, round(triangles / len(st)))
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(count))
    cell = SIZE / side
    k = np.arange(count)
    cx = (k % side + 0.5) * cell - SIZE / 2 + rng.uniform(-0.2, 0.2, count) * cell
    cz = (k // side + 0.5) * cell - SIZE / 2 + rng.uniform(-0.2, 0.2, count) * cell
    rad = cell * rng.uniform(0.2, 0.45, count)
    centres = np.stack([cx, rad, cz], 1)
    pts = (sv[None, :, :] * rad[:, None, None] + centres[:, None, :]).reshape(-1, 3).astype(np.float32)
    nrm = np.broadcast_to(sv[None], (count,) + sv.shape).reshape(-1, 3).astype(np.float32)
    tri = (st[None, :, :] + (np.arange(count) * len(sv))[:, None, None]).reshape(-1, 3).astype(np.int32)
    return pts, nrm, tri


# --------------------------------------------------------------------------- authoring
def author_mesh(stage, path, pts, nrm, tri, normals: bool):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tri), 3, np.int32)))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(tri.ravel())))
    if normals:
        m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(nrm))
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    lo, hi = pts.min(0), pts.max(0)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    return m


def author_scene(stage, mesh_prim_path, n_tris, shape, res):
    layer = stage.GetRootLayer()
    layer.documentation = (f"illum benchmark stage: {shape}, {n_tris} triangles in one Mesh, lit by one RectLight "
                           f"and a dim DomeLight. Generated by bench/make_big_stage.py.")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = stage.GetPrimAtPath("/World") or UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)

    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Xform.Define(stage, "/World/Lights")
    mat = UsdShade.Material.Define(stage, "/World/Looks/Ground")
    sh = UsdShade.Shader.Define(stage, "/World/Looks/Ground/PreviewSurface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.55, 0.5, 0.42))
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(mesh_prim_path)).Bind(mat)

    # 10 x 10 m RectLight 14 m up, facing down (rotateX -90 maps local -Z to world -Y).
    # Radiance 6 nits over ~0.4 sr gives E ~ 2.4 under it: diffuse 0.55 -> ~0.4.
    key = UsdLux.RectLight.Define(stage, "/World/Lights/Key")
    key.AddTranslateOp().Set(Gf.Vec3d(-4, 14, 4))
    key.AddRotateXOp().Set(-90.0)
    key.CreateWidthAttr(10.0)
    key.CreateHeightAttr(10.0)
    key.CreateIntensityAttr(6.0)
    key.CreateColorAttr(Gf.Vec3f(1.0, 0.95, 0.88))
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    sky.CreateIntensityAttr(0.1)
    sky.CreateColorAttr(Gf.Vec3f(0.6, 0.75, 1.0))

    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(0.35)  # 35 mm lens, tenths of a metre
    cam.CreateHorizontalApertureAttr(0.36)
    cam.CreateVerticalApertureAttr(0.36 * res[1] / res[0])
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 10000.0))
    pos, tgt = np.array([24.0, 16.0, 24.0]), np.array([0.0, 0.0, 0.0])
    d = (tgt - pos) / np.linalg.norm(tgt - pos)
    cam.AddTranslateOp().Set(Gf.Vec3d(*pos))
    cam.AddRotateYOp().Set(round(math.degrees(math.atan2(-d[0], -d[2])), 3))
    cam.AddRotateXOp().Set(round(math.degrees(math.asin(d[1])), 3))

    UsdGeom.Scope.Define(stage, "/Render")
    rs = UsdRender.Settings.Define(stage, "/Render/Settings")
    rs.CreateCameraRel().SetTargets([cam.GetPath()])
    rs.CreateResolutionAttr(Gf.Vec2i(*res))
    rs.CreatePixelAspectRatioAttr(1.0)
    rs.CreateRenderingColorSpaceAttr("lin_rec709_scene")
    prod = UsdRender.Product.Define(stage, "/Render/Beauty")
    prod.CreateProductNameAttr("big_stage.exr")
    rs.CreateProductsRel().SetTargets([prod.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", nargs="?", default="/tmp/illum_big_stage.usda",
                    help="output .usda (small top layer + sidecar _geom.usdc) or .usdc (default: %(default)s)")
    ap.add_argument("--triangles", "-t", type=int, default=1_000_000, help="target triangle count (default 1e6)")
    ap.add_argument("--shape", choices=["terrain", "spheres"], default="terrain")
    ap.add_argument("--no-normals", dest="normals", action="store_false", help="do not author vertex normals")
    ap.add_argument("--res", type=int, nargs=2, default=(960, 540), metavar=("W", "H"))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)

    out = os.path.abspath(args.out)
    ext = os.path.splitext(out)[1].lower()
    if ext not in (".usda", ".usdc", ".usd"):
        ap.error("OUT must end in .usda, .usdc or .usd")
    os.makedirs(os.path.dirname(out), exist_ok=True)

    t0 = time.perf_counter()
    pts, nrm, tri = (terrain if args.shape == "terrain" else spheres)(args.triangles, args.seed)
    t1 = time.perf_counter()

    if ext == ".usda":
        geom_path = os.path.splitext(out)[0] + "_geom.usdc"
        gstage = Usd.Stage.CreateNew(geom_path)
        UsdGeom.SetStageUpAxis(gstage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(gstage, 1.0)
        root = UsdGeom.Xform.Define(gstage, "/Geom")
        gstage.SetDefaultPrim(root.GetPrim())
        author_mesh(gstage, "/Geom/Mesh", pts, nrm, tri, args.normals)
        gstage.GetRootLayer().Save()

        stage = Usd.Stage.CreateNew(out)
        UsdGeom.Xform.Define(stage, "/World")
        big = UsdGeom.Xform.Define(stage, "/World/Big")
        big.GetPrim().GetReferences().AddReference("./" + os.path.basename(geom_path))
        mesh_path = "/World/Big/Mesh"
        files = [out, geom_path]
    else:
        stage = Usd.Stage.CreateNew(out)
        UsdGeom.Xform.Define(stage, "/World")
        UsdGeom.Xform.Define(stage, "/World/Big")
        author_mesh(stage, "/World/Big/Mesh", pts, nrm, tri, args.normals)
        mesh_path = "/World/Big/Mesh"
        files = [out]
    author_scene(stage, mesh_path, len(tri), args.shape, tuple(args.res))
    stage.GetRootLayer().Save()
    t2 = time.perf_counter()

    sizes = ", ".join(f"{os.path.basename(f)} {os.path.getsize(f) / 1e6:.1f} MB" for f in files)
    print(f"{args.shape}: {len(tri):,} triangles, {len(pts):,} points; generated in {t1 - t0:.2f}s, "
          f"written in {t2 - t1:.2f}s ({sizes})")
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
