"""Stage-building helpers shared by the USD reader tests."""

from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

from renderer.description import MeshDesc, SceneDescription
from renderer.usd import read_stage


def new_stage(up: str = "Y", camera: bool = True) -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, up)
    if camera:
        UsdGeom.Camera.Define(stage, "/Cam")
    return stage


def read(stage: Usd.Stage, **kw) -> SceneDescription:
    return read_stage(stage, source="mem.usda", **kw)


def add_mesh(stage: Usd.Stage, path: str, points, counts, indices, **attrs) -> UsdGeom.Mesh:
    """A Mesh with subdivisionScheme none (so no cage warning) and the given topology."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, dtype=np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr("none")
    for name, value in attrs.items():
        mesh.GetPrim().GetAttribute(name).Set(value)
    return mesh


def add_quad(stage: Usd.Stage, path: str, z: float = 0.0, size: float = 1.0) -> UsdGeom.Mesh:
    """Unit quad in the XY plane at height z, counter-clockwise seen from +Z."""
    s = size
    return add_mesh(stage, path, [(0, 0, z), (s, 0, z), (s, s, z), (0, s, z)], [4], [0, 1, 2, 3])


def grid(n: int, z: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points, counts, indices) of an n x n vertex grid of quads: 2 (n-1)^2 triangles."""
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    pts = np.c_[g, np.full(len(g), z)].astype(np.float32)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij"))
    quads = np.stack([i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1], 1)
    return pts, np.full(len(quads), 4), quads.ravel()


def translate(xformable, x=0.0, y=0.0, z=0.0):
    UsdGeom.Xformable(xformable).AddTranslateOp().Set(Gf.Vec3d(x, y, z))


def mesh(desc: SceneDescription, path: str) -> MeshDesc:
    found = [m for m in desc.meshes if m.path == path]
    assert len(found) == 1, f"{path}: {[m.path for m in desc.meshes]}"
    return found[0]


def face_normals(m: MeshDesc) -> np.ndarray:
    """(T, 3) unit geometric normals from the winding."""
    p = m.points[m.triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def preview_material(stage: Usd.Stage, path: str, **inputs) -> tuple[UsdShade.Material, UsdShade.Shader]:
    """Material with a UsdPreviewSurface; inputs given as name=(sdf type, value)."""
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PBR")
    shader.CreateIdAttr("UsdPreviewSurface")
    for name, (vtype, value) in inputs.items():
        shader.CreateInput(name, vtype).Set(value)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat, shader


def bind(prim_or_schema, material: UsdShade.Material, purpose: str = "") -> None:
    prim = prim_or_schema.GetPrim() if hasattr(prim_or_schema, "GetPrim") else prim_or_schema
    api = UsdShade.MaterialBindingAPI.Apply(prim)
    api.Bind(material, UsdShade.Tokens.weakerThanDescendants, purpose or UsdShade.Tokens.allPurpose)


COLOR3 = Sdf.ValueTypeNames.Color3f
FLOAT = Sdf.ValueTypeNames.Float
