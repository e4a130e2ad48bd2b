"""Subdivision surfaces: uniform refinement of a polygon mesh and projection to the limit surface.

What this module does (renderer/usd/stage_reader.py calls it for every UsdGeom.Mesh whose
``subdivisionScheme`` is not ``none``, before triangulation):

* ``refine`` subdivides a control mesh ``level`` times with the scheme's rules:
  - ``catmullClark``: any polygons; after the first level every face is a quad (a face of n
    corners gives n quads), so F quads become 4F at each further level;
  - ``loop``: triangles only; each triangle gives 4;
  - ``bilinear``: the Catmull-Clark topology with linear rules (face, edge and vertex points are
    the face centroid, the edge midpoint and the vertex itself).
  Then (catmullClark, loop) every vertex is pushed to its limit position and gets its limit
  normal (``limit``): exact masks for smooth vertices (Catmull-Clark: Halstead et al. 1993,
  Loop: Loop 1987), the cubic B-spline curve limit (a + 4 v + b) / 6 and its tangent on creases,
  the vertex itself on corners. The limit normal of a crease or corner vertex (the surface has
  none there) is the area-weighted mean of the refined faces around it.
* Creases and corners follow the semi-sharp rules of DeRose, Kass and Truong (1998) as
  OpenSubdiv uses them: an edge of sharpness s >= 1 uses the sharp (midpoint) rule, 0 < s < 1
  blends smooth and sharp by s; a vertex takes the corner rule with three or more sharp edges (or
  a corner sharpness), the crease rule (6 v + a + b) / 8 with two, and the smooth rule with one
  (a dart); the vertex's blend weight is the mean sharpness of its sharp edges (or its corner
  sharpness), clamped to 1. Child edges get Chaikin's decreasing sharpness: at an end with
  exactly two sharp edges, max(0, (3 s + s_other) / 4 - 1), otherwise max(0, s - 1). Corner
  sharpness decreases by 1 per level. Infinite sharpness (USD's 10 = SHARPNESS_INFINITE and
  above) never decreases.
* ``interpolateBoundary``: boundary edges are infinitely sharp (edgeOnly, edgeAndCorner);
  edgeAndCorner also makes a boundary vertex of one face a corner; ``none`` renders no face that
  touches a boundary vertex of the control mesh (OpenSubdiv's "boundary faces are holes").
  Non-manifold edges (three or more faces) are infinitely sharp.
* Face-varying data (st, and every primvar, which the reader brings to per-corner values first)
  is refined linearly per face: ``faceVaryingLinearInterpolation = all``. The default
  ``cornersPlus1`` (and the other modes, which smooth face-varying data away from its seams) is
  approximated by the same linear interpolation: a seam-free st set differs from the smooth one
  by well under a texel on a subdivided cage. Vertex and varying primvars are therefore also
  interpolated linearly, not subdivided with the points.

Level choice (``choose_level``): ``--subdiv-level N`` when given (0 = the control cage). By
default the level at which the mesh's median cage edge, seen at the mesh's nearest distance to
the camera, projects to at most ``TARGET_EDGE_PX`` pixels, between 1 and ``MAX_AUTO_LEVEL``, and
lowered while the refined mesh would exceed ``MAX_AUTO_FACES`` faces.

Arrays: points (V, k) float64 (any k: positions plus whatever else is refined with them);
counts (F,) and indices (C,) int64 as UsdGeom's faceVertexCounts and faceVertexIndices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

__all__ = ["SCHEMES", "Creases", "corner_tables", "Refinement", "refine", "refine_face_varying", "choose_level",
           "TARGET_EDGE_PX", "MAX_AUTO_LEVEL", "MAX_AUTO_FACES", "INFINITE_SHARPNESS"]

SCHEMES = ("catmullClark", "loop", "bilinear")
_SCHEME_ID = {"catmullClark": 0, "loop": 1, "bilinear": 2}
# UsdGeom / OpenSubdiv: sharpness >= 10 is infinitely sharp.
INFINITE_SHARPNESS = 10.0
TARGET_EDGE_PX = 4.0
MAX_AUTO_LEVEL = 4
MAX_AUTO_FACES = 2_000_000
_INF = math.inf


@dataclass(frozen=True)
class Creases:
    """Authored sharpness, already expanded: edges (K, 2) int64 vertex pairs with sharpness (K,),
    corner vertices (M,) int64 with sharpness (M,). Values >= INFINITE_SHARPNESS are infinite."""

    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    edge_sharpness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    corners: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    corner_sharpness: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class _Level:
    """One parent mesh's face-varying refinement recipe (see ``refine_face_varying``)."""

    scheme: int
    starts: np.ndarray
    counts: np.ndarray
    corner_face: np.ndarray
    nxt: np.ndarray
    prv: np.ndarray


@dataclass
class Refinement:
    """The refined mesh.

    points (V', k) float64 (limit positions for catmullClark and loop); normals (V', 3) float64
    unit limit normals (front = counter-clockwise faces), or None for bilinear; counts (F',) and
    indices (C',) int64; face_parent (F',) int64 the control face each face comes from;
    drop (F',) bool faces not to render (interpolateBoundary none).
    """

    points: np.ndarray
    normals: np.ndarray | None
    counts: np.ndarray
    indices: np.ndarray
    face_parent: np.ndarray
    drop: np.ndarray
    levels: list = field(default_factory=list, repr=False)


# --------------------------------------------------------------------------------------
# Topology helpers (numpy)
# --------------------------------------------------------------------------------------
def corner_tables(counts: np.ndarray):
    """starts (F,), corner_face (C,), next and previous corner in the same face (C,)."""
    starts = np.cumsum(counts) - counts
    corner_face = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    local = np.arange(int(counts.sum()), dtype=np.int64) - starts[corner_face]
    n = counts[corner_face]
    nxt = starts[corner_face] + (local + 1) % n
    prv = starts[corner_face] + (local - 1) % n
    return starts, corner_face, nxt, prv


def _edge_keys(a: np.ndarray, b: np.ndarray, n_vertices: int) -> np.ndarray:
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return lo * np.int64(n_vertices) + hi


def _edges(indices: np.ndarray, nxt: np.ndarray, n_vertices: int):
    """Unique edges: corner_edge (C,) id of the edge from each corner to the next one,
    edge_v (E, 2) its vertices, edge_key (E,) sorted keys."""
    keys = _edge_keys(indices, indices[nxt], n_vertices)
    edge_key, corner_edge = np.unique(keys, return_inverse=True)
    edge_v = np.stack([edge_key // n_vertices, edge_key % n_vertices], axis=1)
    return corner_edge.astype(np.int64), edge_v, edge_key


def _lookup(edge_key: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Edge ids of ``keys`` (-1 where the edge does not exist)."""
    pos = np.searchsorted(edge_key, keys)
    pos = np.minimum(pos, len(edge_key) - 1)
    return np.where(edge_key[pos] == keys, pos, -1)


# --------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------
@njit(cache=True)
def _vertex_sharp_edges(edge_v, edge_sharp, n_vertices):
    """Per vertex: number of incident edges, of sharp ones, the sum of their (finite) sharpness
    with an infinite flag, and the first two sharp edges."""
    n_edges = np.zeros(n_vertices, np.int64)
    n_sharp = np.zeros(n_vertices, np.int64)
    s_sum = np.zeros(n_vertices)
    sharp1 = np.full(n_vertices, -1, np.int64)
    sharp2 = np.full(n_vertices, -1, np.int64)
    for e in range(edge_v.shape[0]):
        for side in range(2):
            v = edge_v[e, side]
            n_edges[v] += 1
            s = edge_sharp[e]
            if s > 0.0:
                n_sharp[v] += 1
                s_sum[v] += s
                if sharp1[v] < 0:
                    sharp1[v] = e
                elif sharp2[v] < 0:
                    sharp2[v] = e
    return n_edges, n_sharp, s_sum, sharp1, sharp2


@njit(cache=True)
def _refine_points(P, starts, counts, indices, corner_edge, edge_v, edge_sharp, vert_sharp, scheme):
    """New points of one level: [vertex points (V)][edge points (E)][face points (F), Catmull-Clark
    and bilinear only]. scheme 0 catmullClark, 1 loop, 2 bilinear. Also returns, per edge, the
    Chaikin sharpness of its two child edges (at edge_v[e, 0] and at edge_v[e, 1]).
    Written with scalar loops over the k columns: no temporaries per element."""
    V, k = P.shape
    F = counts.shape[0]
    E = edge_v.shape[0]
    quads = scheme != 1
    n_out = V + E + (F if quads else 0)
    out = np.zeros((n_out, k))
    fp = out[V + E:]  # face points (empty for Loop)
    if quads:
        for f in range(F):
            inv = 1.0 / counts[f]
            for j in range(counts[f]):
                c = indices[starts[f] + j]
                for d in range(k):
                    fp[f, d] += P[c, d] * inv
    # Per edge: the sum of its faces' points (CC) or opposite vertices (Loop), and face count.
    e_acc = np.zeros((E, k))
    e_nf = np.zeros(E, np.int64)
    for f in range(F):
        n = counts[f]
        for j in range(n):
            e = corner_edge[starts[f] + j]
            e_nf[e] += 1
            if quads:
                for d in range(k):
                    e_acc[e, d] += fp[f, d]
            else:
                o = indices[starts[f] + (j + 2) % n]
                for d in range(k):
                    e_acc[e, d] += P[o, d]
    n_edges, n_sharp, s_sum, sharp1, sharp2 = _vertex_sharp_edges(edge_v, edge_sharp, V)

    ep = out[V:V + E]
    for e in range(E):
        a = edge_v[e, 0]
        b = edge_v[e, 1]
        s = edge_sharp[e]
        sharp = scheme == 2 or e_nf[e] != 2 or s >= 1.0
        w = 1.0 if sharp else max(s, 0.0)  # weight of the midpoint
        for d in range(k):
            mid = 0.5 * (P[a, d] + P[b, d])
            if sharp:
                ep[e, d] = mid
                continue
            if quads:
                smooth = 0.25 * (P[a, d] + P[b, d] + e_acc[e, d])
            else:
                smooth = 0.375 * (P[a, d] + P[b, d]) + 0.125 * e_acc[e, d]
            ep[e, d] = (1.0 - w) * smooth + w * mid

    # Vertex points: sums of incident face points (CC) and of edge midpoints (CC) or neighbours (Loop).
    q_acc = np.zeros((V, k))
    n_faces = np.zeros(V, np.int64)
    if quads:
        for f in range(F):
            for j in range(counts[f]):
                v = indices[starts[f] + j]
                n_faces[v] += 1
                for d in range(k):
                    q_acc[v, d] += fp[f, d]
    r_acc = np.zeros((V, k))
    for e in range(E):
        a = edge_v[e, 0]
        b = edge_v[e, 1]
        for d in range(k):
            if quads:
                mid = 0.5 * (P[a, d] + P[b, d])
                r_acc[a, d] += mid
                r_acc[b, d] += mid
            else:
                r_acc[a, d] += P[b, d]
                r_acc[b, d] += P[a, d]
    vp = out[:V]
    for v in range(V):
        n = n_edges[v]
        if scheme == 2 or n == 0:
            for d in range(k):
                vp[v, d] = P[v, d]
            continue
        ns = n_sharp[v]
        w_sharp = min(s_sum[v] / ns, 1.0) if ns >= 2 else 0.0
        o1 = -1
        o2 = -1
        if ns == 2:
            e1 = sharp1[v]
            e2 = sharp2[v]
            o1 = edge_v[e1, 1] if edge_v[e1, 0] == v else edge_v[e1, 0]
            o2 = edge_v[e2, 1] if edge_v[e2, 0] == v else edge_v[e2, 0]
        w_corner = min(vert_sharp[v], 1.0) if vert_sharp[v] > 0.0 else 0.0
        beta = 0.0
        if not quads:
            c0 = 0.375 + 0.25 * math.cos(2.0 * math.pi / n)
            beta = (0.625 - c0 * c0) / n
        interior = n_faces[v] == n
        for d in range(k):
            if quads:
                if interior:
                    smooth = (q_acc[v, d] / n + 2.0 * r_acc[v, d] / n + (n - 3.0) * P[v, d]) / n
                else:  # a boundary vertex whose boundary edges are not sharp cannot occur; be safe
                    smooth = P[v, d]
            else:
                smooth = (1.0 - n * beta) * P[v, d] + beta * r_acc[v, d]
            pos = smooth
            if ns >= 2:
                if ns == 2:
                    sharp_rule = (6.0 * P[v, d] + P[o1, d] + P[o2, d]) / 8.0
                else:
                    sharp_rule = P[v, d]
                pos = (1.0 - w_sharp) * smooth + w_sharp * sharp_rule
            vp[v, d] = (1.0 - w_corner) * pos + w_corner * P[v, d]

    # Chaikin child sharpness.
    child = np.zeros((E, 2))
    for e in range(E):
        s = edge_sharp[e]
        if s <= 0.0:
            continue
        for side in range(2):
            v = edge_v[e, side]
            if math.isinf(s):
                child[e, side] = s
            elif n_sharp[v] == 2:
                other = sharp2[v] if sharp1[v] == e else sharp1[v]
                so = edge_sharp[other]
                if math.isinf(so):
                    so = s
                child[e, side] = max(0.0, (3.0 * s + so) / 4.0 - 1.0)
            else:
                child[e, side] = max(0.0, s - 1.0)
    return out, child


@njit(cache=True)
def _limit(P, indices, starts, counts, corner_edge, edge_v, edge_sharp, vert_sharp, is_loop):
    """Limit positions (V, 3+) and normals (V, 3) of an all-quad (Catmull-Clark) or all-triangle
    (Loop) mesh. normals are zero where no mask applies (creases, corners, boundaries,
    non-manifold rings): the caller fills those from the refined faces."""
    V, k = P.shape
    C = indices.shape[0]
    n_edges, n_sharp, s_sum, sharp1, sharp2 = _vertex_sharp_edges(edge_v, edge_sharp, V)
    # corners incident to each vertex (CSR)
    deg = np.zeros(V + 1, np.int64)
    for c in range(C):
        deg[indices[c] + 1] += 1
    for v in range(V):
        deg[v + 1] += deg[v]
    fill = deg[:V].copy()
    inc = np.empty(C, np.int64)
    corner_local = np.empty(C, np.int64)
    for f in range(counts.shape[0]):
        for j in range(counts[f]):
            c = starts[f] + j
            v = indices[c]
            inc[fill[v]] = c
            fill[v] += 1
            corner_local[c] = j
    LP = P.copy()
    N = np.zeros((V, 3))
    m = 3 if is_loop else 4
    max_n = 0
    for v in range(V):
        max_n = max(max_n, n_edges[v])
    # per-vertex scratch, allocated once (this loop runs over every refined vertex)
    ring_e = np.empty(max_n, np.int64)
    ring_f = np.empty(max_n, np.int64)  # Catmull-Clark: the diagonal vertex of face i
    used = np.zeros(max_n, np.bool_)
    acc = np.empty(k)
    t1 = np.empty(3)
    t2 = np.empty(3)
    for v in range(V):
        n = n_edges[v]
        nf = deg[v + 1] - deg[v]
        if n == 0:
            continue
        if vert_sharp[v] > 0.0 or n_sharp[v] >= 3:
            continue  # corner: the vertex itself
        if n_sharp[v] == 2:
            e1 = sharp1[v]
            e2 = sharp2[v]
            o1 = edge_v[e1, 1] if edge_v[e1, 0] == v else edge_v[e1, 0]
            o2 = edge_v[e2, 1] if edge_v[e2, 0] == v else edge_v[e2, 0]
            for d in range(k):
                LP[v, d] = (P[o1, d] + 4.0 * P[v, d] + P[o2, d]) / 6.0
            continue
        if nf != n:
            continue
        # Order the ring: face i's "next" corner vertex is e_i, its "previous" one is e_{i+1}.
        for q in range(n):
            used[q] = False
        cur = inc[deg[v]]
        used[0] = True
        ok = True
        for i in range(n):
            f_start = cur - corner_local[cur]
            jl = corner_local[cur]
            ring_e[i] = indices[f_start + (jl + 1) % m]
            ring_f[i] = indices[f_start + (jl + 2) % m]
            prev_v = indices[f_start + (jl + m - 1) % m]
            if i == n - 1:
                ok = prev_v == ring_e[0]
                break
            found = -1
            for q in range(n):
                cq = inc[deg[v] + q]
                if used[q]:
                    continue
                if indices[cq - corner_local[cq] + (corner_local[cq] + 1) % m] == prev_v:
                    found = q
                    break
            if found < 0:
                ok = False
                break
            used[found] = True
            cur = inc[deg[v] + found]
        if not ok:
            continue
        for d in range(3):
            t1[d] = 0.0
            t2[d] = 0.0
        if is_loop:
            c0 = 0.375 + 0.25 * math.cos(2.0 * math.pi / n)
            beta = (0.625 - c0 * c0) / n
            chi = 1.0 / (n + 3.0 / (8.0 * beta))
            for d in range(k):
                acc[d] = 0.0
            for i in range(n):
                th = 2.0 * math.pi * i / n
                ct, sn = math.cos(th), math.sin(th)
                for d in range(k):
                    acc[d] += P[ring_e[i], d]
                for d in range(3):
                    t1[d] += ct * P[ring_e[i], d]
                    t2[d] += sn * P[ring_e[i], d]
            for d in range(k):
                LP[v, d] = (1.0 - n * chi) * P[v, d] + chi * acc[d]
        else:
            for d in range(k):
                acc[d] = n * n * P[v, d]
            a_n = 1.0 + math.cos(2.0 * math.pi / n) + math.cos(math.pi / n) * math.sqrt(
                2.0 * (9.0 + math.cos(2.0 * math.pi / n)))
            for i in range(n):
                th0 = 2.0 * math.pi * i / n
                th1 = 2.0 * math.pi * (i + 1) / n
                ce, se = a_n * math.cos(th0), a_n * math.sin(th0)
                cf, sf = math.cos(th0) + math.cos(th1), math.sin(th0) + math.sin(th1)
                for d in range(k):
                    acc[d] += 4.0 * P[ring_e[i], d] + P[ring_f[i], d]
                for d in range(3):
                    t1[d] += ce * P[ring_e[i], d] + cf * P[ring_f[i], d]
                    t2[d] += se * P[ring_e[i], d] + sf * P[ring_f[i], d]
            for d in range(k):
                LP[v, d] = acc[d] / (n * (n + 5.0))
        nx = t1[1] * t2[2] - t1[2] * t2[1]
        ny = t1[2] * t2[0] - t1[0] * t2[2]
        nz = t1[0] * t2[1] - t1[1] * t2[0]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            N[v, 0] = nx / ln
            N[v, 1] = ny / ln
            N[v, 2] = nz / ln
    return LP, N


# --------------------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------------------
def _sharpness(creases: Creases, edge_key: np.ndarray, edge_nf: np.ndarray, n_vertices: int,
               boundary_sharp: bool) -> np.ndarray:
    """(E,) sharpness of the control edges: authored creases (the largest where repeated),
    boundary and non-manifold edges infinite."""
    s = np.zeros(len(edge_key))
    if len(creases.edges):
        ids = _lookup(edge_key, _edge_keys(creases.edges[:, 0], creases.edges[:, 1], n_vertices))
        ok = ids >= 0
        np.maximum.at(s, ids[ok], creases.edge_sharpness[ok])
    s[s >= INFINITE_SHARPNESS] = _INF
    if boundary_sharp:
        s[edge_nf == 1] = _INF
    s[edge_nf > 2] = _INF
    return s


def _edge_face_counts(corner_edge: np.ndarray, n_edges: int) -> np.ndarray:
    return np.bincount(corner_edge, minlength=n_edges)


def _boundary_corners(indices, corner_edge, edge_nf, n_vertices) -> np.ndarray:
    """(V,) bool: boundary vertices used by exactly one face (edgeAndCorner makes them corners)."""
    faces_at = np.bincount(indices, minlength=n_vertices)
    on_boundary = np.zeros(n_vertices, bool)
    boundary_edges = np.nonzero(edge_nf == 1)[0]
    if len(boundary_edges):
        on_boundary[indices[np.isin(corner_edge, boundary_edges)]] = True
    return on_boundary & (faces_at == 1)


def refine(points: np.ndarray, counts: np.ndarray, indices: np.ndarray, scheme: str, level: int,
           creases: Creases | None = None, interpolate_boundary: str = "edgeAndCorner",
           project: bool = True) -> Refinement:
    """Subdivide ``level`` (>= 1) times with ``scheme`` and (catmullClark, loop, when ``project``)
    push the vertices to the limit. loop needs every face to be a triangle (the caller checks). Faces with fewer than 3
    corners must have been removed by the caller."""
    sid = _SCHEME_ID[scheme]
    creases = creases or Creases()
    P = np.ascontiguousarray(points, dtype=np.float64)
    counts = np.asarray(counts, np.int64)
    indices = np.asarray(indices, np.int64)
    V = len(P)
    starts, corner_face, nxt, prv = corner_tables(counts)
    corner_edge, edge_v, edge_key = _edges(indices, nxt, V)
    edge_nf = _edge_face_counts(corner_edge, len(edge_v))
    boundary_sharp = sid != 2
    edge_sharp = _sharpness(creases, edge_key, edge_nf, V, boundary_sharp)
    vert_sharp = np.zeros(V)
    if len(creases.corners):
        ok = (creases.corners >= 0) & (creases.corners < V)
        np.maximum.at(vert_sharp, creases.corners[ok], creases.corner_sharpness[ok])
    vert_sharp[vert_sharp >= INFINITE_SHARPNESS] = _INF
    if interpolate_boundary == "edgeAndCorner" and sid != 2:
        vert_sharp[_boundary_corners(indices, corner_edge, edge_nf, V)] = _INF
    drop_face = np.zeros(len(counts), bool)
    if interpolate_boundary == "none" and sid != 2:
        boundary_v = np.zeros(V, bool)
        boundary_v[edge_v[edge_nf == 1].ravel()] = True
        drop_face = np.add.reduceat(boundary_v[indices].astype(np.int64), starts) > 0 if len(counts) else drop_face
    face_parent = np.arange(len(counts), dtype=np.int64)
    levels: list[_Level] = []
    for _ in range(level):
        levels.append(_Level(sid, starts, counts, corner_face, nxt, prv))
        newP, child_sharp = _refine_points(P, starts, counts, indices, corner_edge, edge_v, edge_sharp,
                                           vert_sharp, sid)
        E, F = len(edge_v), len(counts)
        vp = indices
        ep = V + corner_edge
        if sid == 1:
            # corner k of triangle f: (v_k, e_k, e_{k-1}); then the middle (e_0, e_1, e_2)
            corner_tris = np.stack([vp, ep, ep[prv]], axis=1)
            mid = ep.reshape(-1, 3)
            new_idx = np.concatenate([corner_tris.reshape(-1, 3, 3), mid[:, None, :]], axis=1).reshape(-1)
            new_counts = np.full(4 * F, 3, np.int64)
            new_parent = np.repeat(face_parent, 4)
        else:
            fpid = V + E + corner_face
            new_idx = np.stack([vp, ep, fpid, ep[prv]], axis=1).reshape(-1)
            new_counts = np.full(len(indices), 4, np.int64)
            new_parent = face_parent[corner_face]
            drop_face = drop_face[corner_face]
        if sid == 1:
            drop_face = np.repeat(drop_face, 4)
        nV = len(newP)
        new_starts, new_corner_face, new_nxt, new_prv = corner_tables(new_counts)
        new_corner_edge, new_edge_v, new_edge_key = _edges(new_idx, new_nxt, nV)
        new_nf = _edge_face_counts(new_corner_edge, len(new_edge_v))
        new_sharp = np.zeros(len(new_edge_v))
        creased = np.nonzero(edge_sharp > 0.0)[0]
        if len(creased):
            for side in range(2):
                keys = _edge_keys(edge_v[creased, side], V + creased, nV)
                ids = _lookup(new_edge_key, keys)
                new_sharp[ids] = np.maximum(new_sharp[ids], child_sharp[creased, side])
        if boundary_sharp:
            new_sharp[new_nf == 1] = _INF
        new_sharp[new_nf > 2] = _INF
        new_vert_sharp = np.zeros(nV)
        new_vert_sharp[:V] = np.maximum(vert_sharp - 1.0, 0.0)
        P, V = newP, nV
        counts, indices, face_parent = new_counts, new_idx, new_parent
        starts, corner_face, nxt, prv = new_starts, new_corner_face, new_nxt, new_prv
        corner_edge, edge_v, edge_key, edge_sharp, vert_sharp = (new_corner_edge, new_edge_v, new_edge_key,
                                                                 new_sharp, new_vert_sharp)
    normals = None
    if sid != 2 and level > 0 and project:
        P, N = _limit(P, indices, starts, counts, corner_edge, edge_v, edge_sharp, vert_sharp, sid == 1)
        normals = _fill_normals(P[:, :3], N, counts, indices, corner_face)
    return Refinement(points=P, normals=normals, counts=counts, indices=indices, face_parent=face_parent,
                      drop=drop_face, levels=levels)


def _fill_normals(P: np.ndarray, N: np.ndarray, counts, indices, corner_face) -> np.ndarray:
    """Where the limit mask gave no normal (creases, corners, boundaries), the area-weighted mean
    of the faces around the vertex (faces are planar-enough quads or triangles at this level)."""
    missing = ~np.any(N != 0.0, axis=1)
    if not missing.any():
        return N
    nxt = corner_tables(counts)[2]
    # Newell's normal of each face: the sum over its corners of p_c x p_next.
    cross = np.cross(P[indices], P[indices[nxt]])
    face_n = np.stack([np.bincount(corner_face, weights=cross[:, i], minlength=len(counts)) for i in range(3)], 1)
    vn = np.stack([np.bincount(indices, weights=face_n[corner_face, i], minlength=len(P)) for i in range(3)], 1)
    length = np.linalg.norm(vn, axis=1, keepdims=True)
    vn = vn / np.where(length > 0.0, length, 1.0)
    out = N.copy()
    out[missing] = vn[missing]
    return out


def refine_face_varying(ref: Refinement, values: np.ndarray) -> np.ndarray:
    """(C, k) per-corner values of the control mesh -> (C', k) per-corner values of the refined
    mesh, interpolated linearly within each face (faceVaryingLinearInterpolation ``all``)."""
    fv = np.asarray(values, dtype=np.float64)
    for lv in ref.levels:
        mid_next = 0.5 * (fv + fv[lv.nxt])
        mid_prev = 0.5 * (fv + fv[lv.prv])
        if lv.scheme == 1:
            tri = np.stack([fv, mid_next, mid_prev], axis=1)  # (C, 3, k): corner triangles
            middle = mid_next.reshape(-1, 3, fv.shape[1])  # edge midpoints e_0, e_1, e_2
            fv = np.concatenate([tri.reshape(-1, 3, 3, fv.shape[1]), middle[:, None]], axis=1).reshape(-1, fv.shape[1])
        else:
            sums = np.add.reduceat(fv, lv.starts, axis=0) if len(fv) else fv
            centre = (sums / lv.counts[:, None])[lv.corner_face]
            fv = np.stack([fv, mid_next, centre, mid_prev], axis=1).reshape(-1, fv.shape[1])
    return fv


def choose_level(requested: int | None, scheme: str, n_faces: int, edge_px: float | None) -> int:
    """The refinement level of one mesh (see the module docstring).

    requested: --subdiv-level (None: automatic); edge_px: the median cage edge's projected
    length in pixels at the mesh's nearest point (None without a camera: level 2)."""
    if requested is not None:
        level = int(requested)
    elif edge_px is None:
        level = 2
    else:
        level = int(np.clip(math.ceil(math.log2(max(edge_px, 1e-9) / TARGET_EDGE_PX)), 1, MAX_AUTO_LEVEL))
    if requested is None:
        # Catmull-Clark: n-gons give n quads at level 1, then x4; Loop and quads: x4 per level.
        while level > 1 and n_faces * 4 ** level > MAX_AUTO_FACES:
            level -= 1
    return level
