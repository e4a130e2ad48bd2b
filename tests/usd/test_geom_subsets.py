"""GeomSubset material bindings (UsdShade: familyName "materialBind", elementType "face").

A subset's bound material applies to its faces; faces in no bound subset keep the mesh's own
material (UsdShadeMaterialBindingAPI::GetMaterialBindSubsets / ComputeBoundMaterial)."""

from __future__ import annotations

import numpy as np
from pxr import UsdGeom, UsdLux, UsdShade, Vt

from .helpers import COLOR3, add_mesh, bind, new_stage, preview_material, read


def _strip(stage, path="/Strip"):
    """Three unit quads side by side along X: faces 0, 1, 2 (face f spans x in [f, f+1])."""
    pts = [(x, y, 0.0) for x in range(4) for y in (0, 1)]  # vertex 2x + y
    idx = []
    for f in range(3):
        idx += [2 * f, 2 * f + 2, 2 * f + 3, 2 * f + 1]
    return add_mesh(stage, path, pts, [4, 4, 4], idx)


def _subset(mesh, name, faces):
    api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    return api.CreateMaterialBindSubset(name, Vt.IntArray(faces), UsdGeom.Tokens.face)


def _colour_of_face(d, path, n_faces=3):
    """{face index (from the triangle's x position): diffuse colour} over every MeshDesc of path."""
    out = {}
    for m in (m for m in d.meshes if m.path == path):
        colour = d.materials[m.material].diffuse_color.value
        for tri in m.triangles:
            f = int(np.floor(m.points[tri].mean(axis=0)[0]))
            assert out.get(f, colour) == colour, f"face {f} has two materials"
            out[f] = colour
    assert sorted(out) == list(range(n_faces)), out
    return out


def test_subset_materials_override_the_mesh_binding(stage):
    mesh = _strip(stage)
    green, _ = preview_material(stage, "/Looks/Green", diffuseColor=(COLOR3, (0, 1, 0)))
    red, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (1, 0, 0)))
    blue, _ = preview_material(stage, "/Looks/Blue", diffuseColor=(COLOR3, (0, 0, 1)))
    bind(mesh, green)
    bind(_subset(mesh, "red", [1]), red)
    bind(_subset(mesh, "blue", [2]), blue)
    d = read(stage)
    assert _colour_of_face(d, "/Strip") == {0: (0, 1, 0), 1: (1, 0, 0), 2: (0, 0, 1)}


def test_subset_without_binding_keeps_the_mesh_material_and_display_color(stage):
    mesh = _strip(stage)
    mesh.CreateDisplayColorAttr([(0.2, 0.4, 0.6)])
    red, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (1, 0, 0)))
    bind(_subset(mesh, "red", [0]), red)
    _subset(mesh, "unbound", [2])  # no binding: the mesh's own (displayColor) look
    d = read(stage)
    grey = tuple(float(np.float32(c)) for c in (0.2, 0.4, 0.6))  # displayColor is color3f
    assert _colour_of_face(d, "/Strip") == {0: (1, 0, 0), 1: grey, 2: grey}


def test_subsets_survive_instancing_and_mirroring(stage):
    """A PointInstancer prototype with subsets, one instance mirrored: each piece keeps its
    material and its front-facing winding."""
    proto = _strip(stage, "/Inst/Protos/Strip")
    red, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (1, 0, 0)))
    green, _ = preview_material(stage, "/Looks/Green", diffuseColor=(COLOR3, (0, 1, 0)))
    bind(proto, green)
    bind(_subset(proto, "red", [1]), red)
    pi = UsdGeom.PointInstancer.Define(stage, "/Inst")
    pi.CreatePrototypesRel().SetTargets([proto.GetPath()])
    pi.CreateProtoIndicesAttr([0, 0])
    pi.CreatePositionsAttr([(0, 0, 0), (0, 0, 5)])
    pi.CreateScalesAttr([(1, 1, 1), (1, 1, -1)])
    d = read(stage)
    pieces = [m for m in d.meshes if m.path == "/Inst/Protos/Strip"]
    assert sum(len(m.triangles) for m in pieces) == 2 * 3 * 2
    for m in pieces:
        colour = d.materials[m.material].diffuse_color.value
        for tri in m.triangles:
            p = m.points[tri]
            face = int(np.floor(p.mean(axis=0)[0]))
            assert colour == ((1, 0, 0) if face == 1 else (0, 1, 0))
            n = np.cross(p[1] - p[0], p[2] - p[0])
            # front = image of local +Z: +Z for the plain instance (z = 0), -Z for the mirror (z = 5)
            assert np.sign(n[2]) == (1.0 if p[0, 2] < 2.5 else -1.0)


def test_subset_indices_out_of_range_warn(stage):
    mesh = _strip(stage)
    red, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (1, 0, 0)))
    bind(_subset(mesh, "red", [1, 7]), red)
    d = read(stage)
    assert _colour_of_face(d, "/Strip")[1] == (1, 0, 0)
    assert any("GeomSubset" in w and "7" in w for w in d.warnings), d.warnings


def test_mesh_light_with_subsets_stays_one_piece(stage):
    mesh = _strip(stage)
    red, _ = preview_material(stage, "/Looks/Red", diffuseColor=(COLOR3, (1, 0, 0)))
    bind(_subset(mesh, "red", [1]), red)
    UsdLux.MeshLightAPI.Apply(mesh.GetPrim())
    d = read(stage)
    assert len([m for m in d.meshes if m.path == "/Strip"]) == 1
    assert len(d.lights) == 1 and d.lights[0].mesh_triangles.shape[0] == 6
    assert any("GeomSubset" in w for w in d.warnings), d.warnings
