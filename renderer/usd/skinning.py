"""UsdSkel: skinned points (and authored normals) of meshes at the render time, with usd-core's own
UsdSkel implementation (UsdSkel.Cache, SkeletonQuery, SkinningQuery, BlendShapeQuery), so the
result is the one UsdSkel.BakeSkinning writes.

Order, as UsdSkel specifies and BakeSkinning does: blend shapes (with in-betweens) on the rest
points, then joint skinning (linear blend or dual quaternion, the prim's skinningMethod) by the
skeleton's skinning transforms at the render time. Skinned points are in the skeleton's space;
they are brought back into the mesh's own space (skinned gprims ignore their own transform, as
UsdSkel says) so that the reader places them like any other mesh.
"""

from __future__ import annotations

import numpy as np
from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

from .common import gf_matrix_to_np

__all__ = ["Skinning"]


class Skinning:
    """One per stage read: the UsdSkel cache, each SkelRoot populated when its first bound prim
    is read (no extra traversal for stages without skinning)."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.cache = UsdSkel.Cache()
        self.populated: set = set()

    def _bound(self, prim: Usd.Prim) -> bool:
        """Whether the prim is bound to skinning under a SkelRoot (populating that root once)."""
        if not prim.HasAPI(UsdSkel.BindingAPI):
            return False
        root = UsdSkel.Root.Find(prim)
        if not root:
            return False
        key = root.GetPrim().GetPath()
        if key not in self.populated:
            self.cache.Populate(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
            self.populated.add(key)
        return True

    def _query(self, prim: Usd.Prim):
        """(skinning query, skeleton query) of a skinned prim, else None."""
        if not self._bound(prim):
            return None
        sq = self.cache.GetSkinningQuery(prim)
        if not sq:
            return None
        skel = UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
        skq = self.cache.GetSkelQuery(skel) if skel else None
        if not skq:
            self.ctx.warn(f"skel-noskeleton-{prim.GetPath()}", f"{prim.GetPath()}: skel binding without a valid "
                                                               "Skeleton; rendered in its rest pose")
            return None
        return sq, skq

    def warn_unsupported(self, prim: Usd.Prim) -> None:
        """A skinned gprim that is not a Mesh (UsdSkel skins points-based prims only)."""
        if self._bound(prim) and self.cache.GetSkinningQuery(prim):
            self.ctx.warn(f"skel-gprim-{prim.GetPath()}", f"{prim.GetPath()}: skinning of a {prim.GetTypeName()} "
                                                          "is not supported (only Mesh points); rendered unskinned")

    def deform_mesh(self, prim: Usd.Prim, mesh: UsdGeom.Mesh, points: np.ndarray):
        """(points, normals) of a Mesh at the render time: points (V, 3) float64 in its own space,
        skinned when it is; normals (values, interpolation) of its skinned authored ``normals``,
        or None when they were not skinned (read them as authored)."""
        if self._query(prim) is None:
            return points, None
        authored = None
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        if pv and pv.HasAuthoredValue():
            self.ctx.warn(f"skel-normals-{prim.GetPath()}", f"{prim.GetPath()}: primvars:normals of a skinned mesh "
                                                            "are not skinned; they keep their rest pose")
        elif mesh.GetNormalsAttr().HasAuthoredValue():
            raw = self.ctx.get_attr(mesh.GetNormalsAttr())
            if raw is not None:
                authored = (np.asarray(raw, dtype=np.float64), str(mesh.GetNormalsInterpolation()))
        points, normals = self.deform(prim, points, authored)
        return points, (None if normals is authored else normals)

    def deform(self, prim: Usd.Prim, points: np.ndarray, normals: tuple | None = None):
        """Skinned points (V, 3) float64 in the mesh's own space, or ``points`` unchanged when the
        prim is not skinned. normals: (values (N, 3), interpolation) authored normals to skin too
        (vertex / varying ones; others are returned as they are); returns (points, normals)."""
        q = self._query(prim)
        if q is None:
            return points, normals
        sq, skq = q
        t = self.ctx.time
        pts = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, dtype=np.float32))
        anim = skq.GetAnimQuery()
        if sq.HasBlendShapes() and anim:
            weights = anim.ComputeBlendShapeWeights(t)
            mapper = sq.GetBlendShapeMapper()
            if mapper and not mapper.IsNull() and not mapper.IsIdentity():
                weights = mapper.Remap(weights)
            if weights is not None and len(weights):
                bq = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(prim))
                sub_w, shape_i, sub_i = bq.ComputeSubShapeWeights(weights)
                bq.ComputeDeformedPoints(sub_w, shape_i, sub_i, bq.ComputeBlendShapePointIndices(),
                                         bq.ComputeSubShapePointOffsets(), pts)
        xforms = skq.ComputeSkinningTransforms(t)
        if xforms is None:
            self.ctx.warn(f"skel-xforms-{prim.GetPath()}", f"{prim.GetPath()}: the skeleton's skinning transforms "
                                                           "cannot be computed; rendered in its rest pose")
            return points, normals
        skinned_normals = normals
        if sq.IsRigidlyDeformed():
            m = sq.ComputeSkinnedTransform(xforms, t)
            if m is None:
                return points, normals
            rigid = gf_matrix_to_np(m)
            p = np.asarray(pts, dtype=np.float64)
            skel_pts = p @ rigid[:3, :3].T + rigid[:3, 3]
            if normals is not None:  # rigid[:3, :3] acts on column vectors: row normals use its inverse
                skinned_normals = (np.asarray(normals[0], dtype=np.float64) @ np.linalg.inv(rigid[:3, :3]),
                                   normals[1])
        else:
            if not sq.ComputeSkinnedPoints(xforms, pts, t):
                self.ctx.warn(f"skel-points-{prim.GetPath()}", f"{prim.GetPath()}: skinning failed (joint "
                                                               "influences do not match the points); rendered in "
                                                               "its rest pose")
                return points, normals
            skel_pts = np.asarray(pts, dtype=np.float64)
            if normals is not None:
                skinned_normals = self._normals(prim, sq, xforms, normals, len(points))
        # skeleton space -> world -> the mesh's own space (row vectors: p' = p A^T + t)
        to_world = self.ctx.local_to_world(skq.GetPrim())
        mesh_to_world = self.ctx.local_to_world(prim)
        world = skel_pts @ to_world[:3, :3].T + to_world[:3, 3]
        inv = np.linalg.inv(mesh_to_world)
        local = world @ inv[:3, :3].T + inv[:3, 3]
        if skinned_normals is not None and skinned_normals is not normals:
            # normals by the inverse transpose of the same chain: n' = n A^-1 per step
            skinned_normals = (skinned_normals[0] @ np.linalg.inv(to_world[:3, :3]) @ mesh_to_world[:3, :3],
                               skinned_normals[1])
        self.ctx.stats["skinned_meshes"] += 1
        return local, skinned_normals

    def _normals(self, prim, sq, xforms, normals, n_points):
        """Authored vertex/varying normals skinned by UsdSkel.SkinNormals (the inverse transposes
        of the skinning transforms, as UsdSkel documents); other interpolations unchanged."""
        values, interp = normals
        if interp not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) or len(values) != n_points:
            self.ctx.warn(f"skel-normals-{prim.GetPath()}", f"{prim.GetPath()}: {interp} normals of a skinned mesh "
                                                            "are not skinned; they keep their rest pose")
            return normals
        mapper = sq.GetJointMapper()
        if mapper and not mapper.IsNull() and not mapper.IsIdentity():
            xforms = mapper.RemapTransforms(xforms)
        blocks = np.array(xforms, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
        inv_t = Vt.Matrix3dArray.FromNumpy(np.ascontiguousarray(np.linalg.inv(blocks).transpose(0, 2, 1)))
        geom_bind = np.array(sq.GetGeomBindTransform(), dtype=np.float64)[:3, :3]
        bind = Gf.Matrix3d(*np.linalg.inv(geom_bind).T.ravel().tolist())
        indices, weights = sq.ComputeJointInfluences(self.ctx.time)
        n = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, dtype=np.float32))
        ok = UsdSkel.SkinNormals(sq.GetSkinningMethod(), bind, inv_t, indices, weights,
                                 sq.GetNumInfluencesPerComponent(), n)
        if not ok:
            return normals
        return np.asarray(n, dtype=np.float64), interp
