"""Polygon triangulation and primvar expansion for UsdGeom.Mesh topology (pure numpy).

Vocabulary (UsdGeom's):
* a *corner* is one entry of ``faceVertexIndices``; corner ``c`` of face ``f`` is at
  ``starts[f] + k``. Face-varying primvars have one element per corner.
* triangulation returns, per output triangle, its three corners and its face, so every primvar
  interpolation is a gather: vertex -> ``fvi[corner]``, faceVarying -> ``corner``, uniform ->
  ``face``, constant -> 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["triangulate", "expand_primvar", "primvar_element_count"]


# --------------------------------------------------------------------------------------
# Triangulation
# --------------------------------------------------------------------------------------
def _newell_normals(v: np.ndarray) -> np.ndarray:
    """(F, n, 3) polygon vertices -> (F, 3) Newell normals (length = 2 x polygon area)."""
    return np.cross(v, np.roll(v, -1, axis=1)).sum(axis=1)


def _fan(n: int) -> np.ndarray:
    """(n-2, 3) local corner indices of a fan from corner 0."""
    k = np.arange(1, n - 1)
    return np.stack([np.zeros_like(k), k, k + 1], axis=1)


def _ear_clip(p2: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear clipping of one simple polygon given counter-clockwise in 2D.

    p2: (n, 2) float64. Returns n-2 triangles of local vertex indices, counter-clockwise.
    Degenerate input (self-intersecting, all collinear) cannot stall: when no proper ear is
    left, the rest is fanned, which still covers the polygon's vertices.
    """
    idx = list(range(len(p2)))
    out: list[tuple[int, int, int]] = []
    scale = float(np.abs(p2 - p2.mean(axis=0)).max()) or 1.0
    eps = 1e-12 * scale * scale

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    while len(idx) > 3:
        m = len(idx)
        clipped = False
        # First pass wants strictly convex ears; the second accepts collinear ones, which only
        # exist when the polygon has vertices in the middle of straight edges.
        for min_area in (eps, -eps):
            for k in range(m):
                a, b, c = idx[k - 1], idx[k], idx[(k + 1) % m]
                pa, pb, pc = p2[a], p2[b], p2[c]
                if cross(pa, pb, pc) <= min_area:
                    continue
                others = [j for j in idx if j not in (a, b, c)]
                if others:
                    q = p2[others]
                    # strictly inside (all three edge functions positive) blocks this ear;
                    # points on the boundary (duplicates, touching vertices) do not.
                    d1 = (pb[0] - pa[0]) * (q[:, 1] - pa[1]) - (pb[1] - pa[1]) * (q[:, 0] - pa[0])
                    d2 = (pc[0] - pb[0]) * (q[:, 1] - pb[1]) - (pc[1] - pb[1]) * (q[:, 0] - pb[0])
                    d3 = (pa[0] - pc[0]) * (q[:, 1] - pc[1]) - (pa[1] - pc[1]) * (q[:, 0] - pc[0])
                    if np.any((d1 > eps) & (d2 > eps) & (d3 > eps)):
                        continue
                out.append((a, b, c))
                idx.pop(k)
                clipped = True
                break
            if clipped:
                break
        if not clipped:
            out.extend((idx[0], idx[i], idx[i + 1]) for i in range(1, len(idx) - 1))
            return out
    out.append((idx[0], idx[1], idx[2]))
    return out


def _project_ccw(v: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(n, 3) polygon and its Newell normal -> (n, 2) coordinates in its plane, counter-clockwise."""
    nz = normal / (np.linalg.norm(normal) or 1.0)
    helper = np.array([1.0, 0.0, 0.0]) if abs(nz[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, nz)
    u /= np.linalg.norm(u)
    w = np.cross(nz, u)  # (u, w, nz) right-handed, so the polygon winds counter-clockwise
    return np.stack([v @ u, v @ w], axis=1)


def triangulate(points: np.ndarray, counts: np.ndarray, indices: np.ndarray,
                holes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate polygons, keeping each face's winding.

    points: (V, 3) positions; counts: (F,) faceVertexCounts; indices: (N,) faceVertexIndices
    (already validated: sum(counts) == N, indices in range). holes: face ids to drop.
    Faces with fewer than 3 corners are dropped.

    Returns (tri_corners (T, 3) int64 corner ids, tri_face (T,) int64 face ids), sorted by face.
    Triangles: direct. Quads: split along whichever diagonal keeps both halves facing the
    polygon's normal (correct for a concave quad). n > 4: fan when convex (vectorised test per
    face size), ear clipping in the face's projected plane otherwise.
    """
    counts = np.asarray(counts, dtype=np.int64)
    n_faces = len(counts)
    starts = np.cumsum(counts) - counts
    keep = counts >= 3
    if holes is not None and len(holes):
        h = np.asarray(holes, dtype=np.int64)
        keep[h[(h >= 0) & (h < n_faces)]] = False

    corner_parts: list[np.ndarray] = []
    face_parts: list[np.ndarray] = []

    faces = np.nonzero(keep & (counts == 3))[0]
    if len(faces):
        corner_parts.append(starts[faces][:, None] + np.arange(3))
        face_parts.append(faces)

    faces = np.nonzero(keep & (counts == 4))[0]
    if len(faces):
        c = starts[faces][:, None] + np.arange(4)  # (Q, 4) corners
        v = points[indices[c]].astype(np.float64)  # (Q, 4, 3)
        # A quad's Newell normal is the cross product of its diagonals (2 x area vector).
        nrm = np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 1])
        # Diagonal 0-2 is valid iff triangles (0,1,2) and (0,2,3) both face the quad's normal;
        # otherwise the reflex corner is 1 or 3 and diagonal 1-3 is the valid one.
        a012 = np.einsum("ij,ij->i", np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), nrm)
        a023 = np.einsum("ij,ij->i", np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 0]), nrm)
        use02 = (a012 > 0.0) & (a023 > 0.0) | ~((a012 > 0.0) | (a023 > 0.0))
        t0 = np.where(use02[:, None], c[:, [0, 1, 2]], c[:, [1, 2, 3]])
        t1 = np.where(use02[:, None], c[:, [0, 2, 3]], c[:, [1, 3, 0]])
        corner_parts.append(np.stack([t0, t1], axis=1).reshape(-1, 3))
        face_parts.append(np.repeat(faces, 2))

    big = keep & (counts > 4)
    for n in np.unique(counts[big]):
        n = int(n)
        faces = np.nonzero(big & (counts == n))[0]
        c = starts[faces][:, None] + np.arange(n)  # (F, n)
        v = points[indices[c]].astype(np.float64)  # (F, n, 3)
        nrm = _newell_normals(v)
        edges = np.roll(v, -1, axis=1) - v
        turn = np.einsum("fkj,fj->fk", np.cross(edges, np.roll(edges, -1, axis=1)), nrm)
        scale = np.einsum("fkj,fkj->fk", edges, edges).max(axis=1) * np.linalg.norm(nrm, axis=1)
        convex = np.all(turn >= -1e-9 * scale[:, None], axis=1)
        fan = _fan(n)
        cf = faces[convex]
        if len(cf):
            corner_parts.append(c[convex][:, fan].reshape(-1, 3))
            face_parts.append(np.repeat(cf, n - 2))
        for row in np.nonzero(~convex)[0]:
            # The one Python loop: concave n-gons with n > 4, rare in production meshes.
            p2 = _project_ccw(v[row], nrm[row])
            local = np.asarray(_ear_clip(p2), dtype=np.int64)
            corner_parts.append(c[row][local])
            face_parts.append(np.full(len(local), faces[row], dtype=np.int64))

    if not corner_parts:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    tri_corners = np.concatenate(corner_parts).astype(np.int64, copy=False)
    tri_face = np.concatenate(face_parts).astype(np.int64, copy=False)
    if len(corner_parts) > 1:
        # Keep the source face order: neighbouring faces stay neighbours in memory.
        order = np.argsort(tri_face, kind="stable")
        tri_corners, tri_face = tri_corners[order], tri_face[order]
    return tri_corners, tri_face


# --------------------------------------------------------------------------------------
# Primvars
# --------------------------------------------------------------------------------------
def primvar_element_count(interpolation: str, n_points: int, n_faces: int, n_corners: int) -> int:
    """Number of elements a (flattened) primvar with this interpolation must have on a Mesh."""
    return {
        "constant": 1,
        "uniform": n_faces,
        "vertex": n_points,
        "varying": n_points,
        "faceVarying": n_corners,
    }.get(interpolation, -1)


def expand_primvar(values: np.ndarray, interpolation: str, tri_corners: np.ndarray,
                   tri_face: np.ndarray, face_vertex_indices: np.ndarray,
                   element_indices: np.ndarray | None = None) -> np.ndarray:
    """Gather a primvar to triangle corners.

    values: (E, k) primvar values; element_indices: optional (M,) primvar indices (indexed
    primvar: element i of the primvar is ``values[element_indices[i]]``).
    Returns (T, 3, k) values per triangle corner.
    """
    if interpolation in ("vertex", "varying"):
        elem = face_vertex_indices[tri_corners]
    elif interpolation == "faceVarying":
        elem = tri_corners
    elif interpolation == "uniform":
        elem = np.broadcast_to(tri_face[:, None], tri_corners.shape)
    else:  # constant
        elem = np.zeros(tri_corners.shape, dtype=np.int64)
    if element_indices is not None:
        elem = element_indices[elem]
    return values[elem]
