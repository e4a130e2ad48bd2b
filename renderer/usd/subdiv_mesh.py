"""Reading a subdivision UsdGeom.Mesh: its creases, corners and boundary rule, the level, and the
refined limit surface with its primvars (the refinement itself is renderer/subdiv.py).

Primvars of every interpolation are first brought to one value per control corner (as if
faceVarying), then refined linearly per face (renderer/subdiv.py explains the approximation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from pxr import UsdGeom

from renderer import subdiv
from renderer.memory import TRIANGLE_BYTES

from .mesh import triangulate

__all__ = ["SubdivPolicy", "read_subdivided"]


@dataclass(frozen=True)
class SubdivPolicy:
    """level: --subdiv-level (None: automatic); view: (CameraDesc, image width in pixels) of the
    render camera for the automatic level, or None without a camera."""

    level: int | None
    view: tuple | None

    def edge_pixels(self, world_points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> float | None:
        """Projected length in pixels of the median cage edge at the mesh's nearest distance."""
        if self.view is None or len(indices) == 0:
            return None
        cam, width = self.view
        nxt = subdiv.corner_tables(counts)[2]
        length = float(np.median(np.linalg.norm(world_points[indices] - world_points[indices[nxt]], axis=1)))
        if cam.projection == "orthographic":
            return length * width / cam.horizontal_aperture
        eye = cam.camera_to_world[:3, 3]
        lo, hi = world_points.min(axis=0), world_points.max(axis=0)
        dist = float(np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0)))
        dist = max(dist, float(cam.clipping_range[0]))
        return length * width * cam.focal_length / (cam.horizontal_aperture * dist)


def _creases(ctx, prim, mesh: UsdGeom.Mesh, n_points: int) -> subdiv.Creases:
    """Authored creases and corners, expanded; malformed ones are skipped with one warning."""
    t, path = ctx.time, prim.GetPath()

    def arr(attr, dtype):
        v = ctx.get_attr(attr)
        return np.asarray(v if v is not None else [], dtype=dtype)

    ci, cl = arr(mesh.GetCreaseIndicesAttr(), np.int64), arr(mesh.GetCreaseLengthsAttr(), np.int64)
    cs = arr(mesh.GetCreaseSharpnessesAttr(), np.float64)
    edges, sharp = np.zeros((0, 2), np.int64), np.zeros(0)
    if len(cl):
        n_edges = int(np.maximum(cl - 1, 0).sum())
        ok = (cl.min() >= 2 and int(cl.sum()) == len(ci) and len(cs) in (len(cl), n_edges)
              and (len(ci) == 0 or (ci.min() >= 0 and ci.max() < n_points)) and np.isfinite(cs).all())
        if not ok:
            ctx.warn(f"subdiv-creases-{path}", f"{path}: creaseIndices / creaseLengths / creaseSharpnesses do not "
                                               "agree (or index missing points); creases ignored")
        else:
            starts = np.cumsum(cl) - cl
            chain = np.repeat(np.arange(len(cl)), cl - 1)
            first = np.concatenate([starts[i] + np.arange(n - 1) for i, n in enumerate(cl)]).astype(np.int64)
            edges = np.stack([ci[first], ci[first + 1]], axis=1)
            sharp = cs[chain] if len(cs) == len(cl) else cs
    k_i = arr(mesh.GetCornerIndicesAttr(), np.int64)
    k_s = arr(mesh.GetCornerSharpnessesAttr(), np.float64)
    if len(k_i) != len(k_s) or (len(k_i) and (k_i.min() < 0 or k_i.max() >= n_points)) or not np.isfinite(k_s).all():
        ctx.warn(f"subdiv-corners-{path}", f"{path}: cornerIndices and cornerSharpnesses do not agree (or index "
                                           "missing points); corners ignored")
        k_i, k_s = np.zeros(0, np.int64), np.zeros(0)
    del t
    return subdiv.Creases(edges, sharp, k_i, k_s)


def read_subdivided(reader, prim, mesh: UsdGeom.Mesh, scheme: str, points: np.ndarray, counts: np.ndarray,
                    indices: np.ndarray, holes: np.ndarray | None):
    """The refined mesh, or None to read the control mesh as it is (scheme none, level 0).

    Returns (triangles (T, 3) vertex ids, tri_corners (T, 3) refined corners, normals (T, 3, 3)
    or None, corners_of(name, width) -> (T, 3, width) float64 or None, tri_face_control (T,) the
    control face of each triangle, points (V', 3)) -- see stage_reader._read_mesh.
    """
    ctx, t, path = reader.ctx, reader.ctx.time, prim.GetPath()
    if scheme == UsdGeom.Tokens.none:
        return None
    if scheme not in subdiv.SCHEMES:
        ctx.warn(f"subdiv-scheme-{path}", f"{path}: subdivisionScheme '{scheme}' is unknown; rendered as its "
                                          "control cage")
        return None
    keep = counts >= 3
    if not keep.any():
        return None
    kept_faces = np.nonzero(keep)[0]
    corner_keep = np.repeat(keep, counts)
    c_counts, c_indices = counts[keep], indices[corner_keep]
    if scheme == UsdGeom.Tokens.loop and np.any(c_counts != 3):
        ctx.warn(f"subdiv-loop-{path}", f"{path}: subdivisionScheme 'loop' needs triangles only; this mesh has "
                                        "other polygons and is subdivided with catmullClark instead")
        scheme = "catmullClark"
    world = ctx.local_to_world(prim)
    world_points = points @ world[:3, :3].T + world[:3, 3]
    level = subdiv.choose_level(reader.subdiv.level, scheme, len(c_counts),
                                reader.subdiv.edge_pixels(world_points, c_counts, c_indices))
    if level == 0:
        return None
    rule = str(mesh.GetTriangleSubdivisionRuleAttr().Get(t))
    if rule == "smooth" and scheme == "catmullClark":
        ctx.warn("subdiv-triangle-rule", f"{path}: triangleSubdivisionRule 'smooth' is not supported; the "
                                         "Catmull-Clark rule is used on triangles")
    boundary = str(mesh.GetInterpolateBoundaryAttr().Get(t))
    if boundary not in ("none", "edgeOnly", "edgeAndCorner"):
        ctx.warn(f"subdiv-boundary-{path}", f"{path}: interpolateBoundary '{boundary}' is unknown; "
                                            "edgeAndCorner is used")
        boundary = "edgeAndCorner"
    pv_normals = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
    if mesh.GetNormalsAttr().HasAuthoredValue() or (pv_normals and pv_normals.HasAuthoredValue()):
        ctx.warn(f"subdiv-normals-{path}", f"{path}: normals are authored on a subdivided mesh; the limit "
                                           "surface's normals are used instead (UsdGeom: normals should not be "
                                           "authored on subdivided meshes)")
    # Refused before refining (charged for good, per instance, when the mesh is emitted): Loop
    # splits each triangle in 4 per level; Catmull-Clark and bilinear make one quad per face
    # corner at the first level, then 4 per quad, 2 triangles each.
    n_tri = (len(c_counts) * 4 ** level if scheme == UsdGeom.Tokens.loop
             else 2 * int(c_counts.sum()) * 4 ** (level - 1))
    ctx.memory.need(n_tri * TRIANGLE_BYTES, f"{n_tri} triangles after {level} subdivision levels", file=ctx.file,
                    prim=str(path), attribute="subdivisionScheme", commit=False)
    ref = subdiv.refine(points, c_counts, c_indices, scheme, level, _creases(ctx, prim, mesh, len(points)),
                        boundary)
    ctx.stats["subdivided_meshes"] += 1
    ctx.stats["subdivided_faces"] += len(ref.counts)
    face_control = kept_faces[ref.face_parent]
    drop = ref.drop.copy()
    if holes is not None:
        drop |= np.isin(face_control, holes)
    tri_corners, tri_face = triangulate(ref.points[:, :3], ref.counts, ref.indices, np.nonzero(drop)[0])
    left = mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded
    if left:
        tri_corners = tri_corners[:, [0, 2, 1]]
    triangles = ref.indices[tri_corners]
    normals = None
    if ref.normals is not None:
        normals = ref.normals[triangles] * (-1.0 if left else 1.0)
    n_corners = len(indices)
    one_corner = np.arange(n_corners, dtype=np.int64)[:, None]
    corner_face = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    sizes = (len(points), len(counts), n_corners)
    fvli = str(mesh.GetFaceVaryingLinearInterpolationAttr().Get(t))

    def corners_of(name: str, width: int) -> np.ndarray | None:
        values = reader._primvar_corners(prim, name, one_corner, corner_face, indices, sizes, width=width)
        if values is None:
            return None
        interp = str(UsdGeom.PrimvarsAPI(prim).GetPrimvar(name).GetInterpolation())
        if interp == UsdGeom.Tokens.faceVarying and fvli != "all":
            ctx.warn("subdiv-face-varying", f"{path}: faceVaryingLinearInterpolation '{fvli}' is approximated "
                                            f"by linear interpolation of primvars:{name} (as 'all')")
        elif interp == UsdGeom.Tokens.vertex:
            ctx.warn("subdiv-vertex-primvar", f"{path}: vertex primvar primvars:{name} is interpolated linearly "
                                              "over the subdivided mesh, not with the subdivision rules")
        return subdiv.refine_face_varying(ref, values[corner_keep, 0])[tri_corners]

    return triangles, tri_corners, normals, corners_of, face_control[tri_face], ref.points[:, :3].copy()
