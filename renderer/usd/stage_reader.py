"""Stage traversal: pruning, meshes, implicit prims, instancing, and the SceneDescription.

Pruning rules (a pruned subtree's geometry is never read; ``stats`` proves it):
* inactive prims and abstract (``class``) prims: ``Usd.PrimDefaultPredicate``;
* invisible prims at the render time. The traversal checks each imageable prim's own
  ``visibility`` on the way down, which equals ``ComputeVisibility(t)`` because an invisible
  ancestor has already pruned the subtree;
* an authored (or inherited authored) purpose not in the included purposes. A prim whose purpose
  is only the fallback 'default' is skipped if 'default' is excluded, but its children are still
  visited, since they may author an included purpose;
* PointInstancer children (prototypes are drawn only through the instancer), Material/Shader
  subtrees.

Instanceable references are flattened through ``Usd.TraverseInstanceProxies``; each proxy keeps
its proxy path. PointInstancer instances become one world-space MeshDesc per prototype gprim
(all visible instances merged), named by that prototype gprim's path.

A UsdLux light inside a PointInstancer prototype is read once and becomes one LightDesc per
visible instance, placed by the same instance matrices as the geometry (``_instancer_items``:
positions, orientations / orientationsf, scales, the prototype root's xform, protoIndices,
invisibleIds / inactiveIds, nested instancers), so ``normalize`` sees each instance's world
area. Its path is the prototype light's path with one ``[id]`` per instancer level, outermost
first: ``/World/Lamps/Protos/Lamp/Bulb[17]``, the id being the instancer's authored ``ids``
entry (the number ``invisibleIds`` uses), else the instance index; a prototype outside the
instancer's namespace (it may be shared) names the instancer too: ``/Protos/Lamp/Bulb[/World/Lamps:17]``.
Instances share the prototype light's settings and light/shadow linking collections.
Zero-scale instances are hidden, lights included.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from pxr import Ar, Tf, Usd, UsdGeom, UsdLux, UsdShade

from renderer.description import LightDesc, MeshDesc, SceneDescription, primvar_layout
from renderer.errors import StageError
from renderer.memory import TRIANGLE_BYTES, MemoryBudget

from . import implicit
from .camera import find_camera, framing_camera, read_camera
from .common import ReadContext, one_line
from .composition import check_composition, open_layers_refusing_special_files
from .estimator_api import check_light_api_target
from .lux import read_geometry_light, read_light, resolve_light_links, warn_unused_portals
from .materials import MaterialTable
from .mesh import expand_primvar, primvar_element_count, triangulate
from .skinning import Skinning
from .subdiv_mesh import SubdivPolicy, read_subdivided
from .render_settings import find_settings_prim, read_render_settings

__all__ = ["load_stage", "read_stage"]

_MAX_INSTANCER_DEPTH = 8
_PROTOTYPE_PREDICATE = Usd.TraverseInstanceProxies(Usd.PrimIsActive & Usd.PrimIsLoaded & Usd.PrimIsDefined)
_IMPLICIT_TYPES = (UsdGeom.Sphere, UsdGeom.Cube, UsdGeom.Cylinder, UsdGeom.Cylinder_1, UsdGeom.Cone,
                   UsdGeom.Capsule, UsdGeom.Capsule_1, UsdGeom.Plane)


# --------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------
def load_stage(path: str, *, camera: str | None = None, settings: str | None = None,
               frame: float | None = None, purposes: tuple[str, ...] | None = None,
               strict: bool = False, subdiv_level: int | None = None,
               memory: MemoryBudget | None = None) -> SceneDescription:
    """Open a USD stage file and read it into a SceneDescription.

    camera: camera prim path (or a unique camera prim name); default: the RenderSettings
        camera, else the first camera in traversal order.
    settings: RenderSettings prim path; default: the stage's ``renderSettingsPrimPath``.
    frame: time code to read at; default: ``stage.GetStartTimeCode()`` (0.0 when unauthored),
        the time usdrecord and usdview render at.
    purposes: included purposes, replacing RenderSettings.includedPurposes.
    strict: every missing or unreadable asset (texture, light texture, IES profile, sublayer,
        reference, payload) and a sublayer cycle is a StageError naming the layer, prim and
        attribute; by default each gives one warning and its fallback (a UsdUVTexture's
        ``fallback``, an untextured or unshaped light, a skipped arc).
    subdiv_level: refinement level of subdivision meshes (0: the control cage); None: chosen
        per mesh from its projected size (renderer/subdiv.py, ``choose_level``).
    memory: a renderer.memory.MemoryBudget each mesh (triangles x instances) and image (from
        its header) is charged to before it is built or decoded: MemoryLimitError naming it.

    Raises StageError (file, prim, attribute in the message) for unreadable stages and for
    values that cannot be rendered.
    """
    return read_stage(open_stage(path), source=path, camera=camera, settings=settings, frame=frame,
                      purposes=purposes, strict=strict, subdiv_level=subdiv_level,
                      memory=memory)


def open_stage(path: str) -> Usd.Stage:
    """Open a stage file with every payload loaded; StageError naming the file if it cannot be."""
    # Resolve through Ar rather than os.path so that a custom asset resolver's identifiers work.
    if not Ar.GetResolver().Resolve(path):
        raise StageError("stage file not found", file=path)
    # A FIFO or device as the stage or one of its layers would block Stage.Open forever.
    held = open_layers_refusing_special_files(path)  # noqa: F841 (kept open for Stage.Open to reuse)
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise StageError(f"cannot open stage: {one_line(exc)}", file=path) from None
    if stage is None:
        raise StageError("cannot open stage", file=path)
    return stage


def read_stage(stage: Usd.Stage, *, source: str = "", camera: str | None = None, settings: str | None = None,
               frame: float | None = None, purposes: tuple[str, ...] | None = None,
               strict: bool = False, subdiv_level: int | None = None,
               memory: MemoryBudget | None = None) -> SceneDescription:
    """Read an already open stage (same options as ``load_stage``; ``source`` names it in errors)."""
    source = source or stage.GetRootLayer().identifier
    if frame is not None:
        if not math.isfinite(float(frame)):
            raise StageError(f"frame {frame} is not finite", file=source)
        time = Usd.TimeCode(float(frame))
    else:
        # usdrecord / usdview (UsdAppUtils.framesArgs) use GetStartTimeCode(), 0.0 when unauthored,
        # never the Default time code: at Default, USD ignores time samples, so an animated camera
        # or mesh would resolve to its default value (often none) instead of its held first sample.
        time = Usd.TimeCode(stage.GetStartTimeCode())
    ctx = ReadContext(stage, source, time, strict=strict, memory=memory)
    if frame is None and not stage.HasAuthoredMetadata("startTimeCode") and any(
            layer.ListAllTimeSamples() for layer in stage.GetUsedLayers()):
        ctx.warn("default-time", f"the stage has time samples but no startTimeCode: read at time "
                                 f"{time.GetValue():g} (the startTimeCode fallback, as usdrecord does)")
    try:
        return _read(ctx, camera, settings, purposes, subdiv_level)
    except Tf.ErrorException as exc:  # anything pxr itself refuses, as one line naming the file
        raise ctx.error(one_line(exc)) from None


def _read(ctx: ReadContext, camera: str | None, settings: str | None,
          purposes: tuple[str, ...] | None, subdiv_level: int | None = None) -> SceneDescription:
    # Missing sublayers/references still give a stage; say so (or fail under strict).
    check_composition(ctx)
    settings_prim = find_settings_prim(ctx, settings)
    settings_desc, dof_off = read_render_settings(ctx, settings_prim, purposes)
    view = None
    if subdiv_level is None:  # the automatic subdivision level needs the render camera up front
        pre = find_camera(ctx, camera, settings_desc.camera, settings_desc.path, None)
        if pre is not None:
            view = (read_camera(pre, ctx), int(settings_desc.resolution[0]))
    reader = _Traversal(ctx, settings_desc.included_purposes, settings_desc.material_binding_purposes,
                        SubdivPolicy(subdiv_level, view))
    reader.run()
    cam_prim = find_camera(ctx, camera, settings_desc.camera, settings_desc.path, reader.first_camera)
    if cam_prim is None:
        camera_desc = framing_camera(ctx, settings_desc.included_purposes)
        ctx.warn("no-camera", "the stage has no camera: rendering through a default camera (GfCamera's 50 mm lens "
                              "and 20.955 mm aperture) that frames the stage's bounding box, as usdrecord does; "
                              "pass --camera or add a UsdGeom.Camera")
    else:
        camera_desc = read_camera(cam_prim, ctx)
    if dof_off:
        camera_desc = dataclasses.replace(camera_desc, f_stop=0.0)
    warn_unused_portals(reader.portal_paths, reader.lights, ctx)
    lights = resolve_light_links(reader.light_prims, reader.lights, [m.path for m in reader.meshes])
    if not lights:
        ctx.warn("no-lights", "the stage has no lights (no prim with UsdLux LightAPI that emits): only "
                              "emissive surfaces light it, and without them the image is black")
    ctx.stats["meshes"] = len(reader.meshes)
    ctx.stats["lights"] = len(lights)
    ctx.stats["materials"] = len(reader.materials.materials)
    return SceneDescription(
        source=ctx.file,
        time_code=float(ctx.time.GetValue()),
        meshes=reader.meshes,
        materials=reader.materials.materials,
        lights=lights,
        camera=camera_desc,
        settings=settings_desc,
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(ctx.stage)),
        up_axis=ctx.up_axis,
        warnings=ctx.warnings.messages(),
        stats=dict(ctx.stats),
        strict=ctx.strict,
    )


# --------------------------------------------------------------------------------------
# Local geometry (before placement)
# --------------------------------------------------------------------------------------
@dataclass
class _LocalMesh:
    """A gprim triangulated in its own local space, winding already front-facing (CCW).

    points (V, 3) float64; triangles (T, 3) int64; normals (T, 3, 3) float64 or None;
    st (T, 3, 2) float32 or None; tri_material (T,) int64 per-triangle material from
    materialBind GeomSubsets, or None when every triangle has ``material``.
    """

    path: str
    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None
    st: np.ndarray | None
    material: int
    double_sided: bool
    tri_material: np.ndarray | None = None
    primvars: dict = dataclasses.field(default_factory=dict)  # MeshDesc.primvars, local


@dataclass
class _ProtoLight:
    """A UsdLux light inside a PointInstancer prototype, read once for all its instances.

    desc: its LightDesc with ``light_to_world`` the light's frame in its own prim space (read
    with the identity; see ``lux.read_light``); prim: the prototype light prim, whose
    collections (light / shadow linking) apply to every instance.
    """

    prim: Usd.Prim
    desc: LightDesc


# Instance keys of an item placed directly in a prototype: no PointInstancer level below it.
_NO_KEYS = np.zeros((1, 0), dtype=np.int64)


def _instance_light_path(light_path: str, key: np.ndarray, qualifier: str) -> str:
    """Path of one instance of a prototype light: the prototype light's path and one ``[id]``
    per PointInstancer level, outermost first (``/W/PI/Protos/Lamp/Light[17]``). ids are the
    instancer's ``ids`` when authored (the numbers ``invisibleIds`` uses), else the instance
    indices. ``qualifier`` (the top instancer's path and ':') is set when the prototype lies
    outside that instancer's namespace, where another instancer may share it."""
    return light_path + f"[{qualifier}" + "][".join(str(int(k)) for k in key) + "]"


def _smooth_vertex_normals(points: np.ndarray, tris: np.ndarray, tri_face: np.ndarray,
                           counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(T, 3, 3) per-corner normals: at each vertex the area-weighted mean of the normals of the
    *faces* using it (each face counted once, however it was triangulated; front =
    counter-clockwise triangles (T, 3) of faces tri_face (T,)). Vertices whose normals cancel get
    a zero normal, which the scene build replaces by the face normal."""
    p = points[tris]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # |fn| = 2 area: area weighting
    n_faces = len(counts)
    face_n = np.stack([np.bincount(tri_face, weights=fn[:, k], minlength=n_faces) for k in range(3)], axis=1)
    corner_face = np.repeat(np.arange(n_faces), counts)  # face of each faceVertexIndices entry
    vn = np.stack([np.bincount(indices, weights=face_n[corner_face, k], minlength=len(points))
                   for k in range(3)], axis=1)
    length = np.linalg.norm(vn, axis=1, keepdims=True)
    vn = vn / np.where(length > 0.0, length, 1.0)
    return vn[tris]


def _split_by_material(desc: MeshDesc, tri_material: np.ndarray) -> list[MeshDesc]:
    """One MeshDesc per material of ``tri_material`` (T,), each with only its triangles and
    the points they use; all keep the gprim's path (light linking matches them all)."""
    out = []
    for m in np.unique(tri_material):
        sel = tri_material == m
        tris = desc.triangles[sel]
        used, remap = np.unique(tris, return_inverse=True)
        out.append(dataclasses.replace(
            desc, points=desc.points[used], triangles=remap.reshape(tris.shape).astype(np.int32),
            normals=None if desc.normals is None else desc.normals[sel],
            st=None if desc.st is None else desc.st[sel], material=int(m),
            primvars={name: v[sel] for name, v in desc.primvars.items()}))
    return out


def _place(lm: _LocalMesh, mats: np.ndarray) -> MeshDesc:
    """Transform a local mesh by N (4, 4) column-vector matrices into one world-space MeshDesc.

    A matrix with negative determinant mirrors the geometry, which turns the winding
    clockwise as seen from the front, so its triangles get two corners swapped. Normals use the
    inverse transpose, which is already correct under mirroring.
    """
    n_inst, n_pts, n_tri = len(mats), len(lm.points), len(lm.triangles)
    rot = mats[:, :3, :3]
    pts = np.einsum("nij,vj->nvi", rot, lm.points) + mats[:, None, :3, 3]
    tris = lm.triangles[None, :, :] + (np.arange(n_inst, dtype=np.int64) * n_pts)[:, None, None]
    flip = np.linalg.det(rot) < 0.0
    swap = [0, 2, 1]
    if flip.any():
        tris[flip] = tris[flip][:, :, swap]
    normals = None
    if lm.normals is not None:
        inv_t = np.linalg.inv(rot).transpose(0, 2, 1)
        nw = np.einsum("nij,tcj->ntci", inv_t, lm.normals)
        length = np.sqrt(np.einsum("...i,...i->...", nw, nw))[..., None]
        nw = nw / np.where(length > 0.0, length, 1.0)
        if flip.any():
            nw[flip] = nw[flip][:, :, swap]
        normals = nw.reshape(n_inst * n_tri, 3, 3).astype(np.float32)
    def corners(values: np.ndarray) -> np.ndarray:
        """Per-corner values (T, 3, k) repeated for each instance, corners swapped as the winding."""
        out = np.broadcast_to(values, (n_inst,) + values.shape).copy()
        if flip.any():
            out[flip] = out[flip][:, :, swap]
        return out.reshape((n_inst * n_tri,) + values.shape[1:]).astype(np.float32, copy=False)

    st = None if lm.st is None else corners(lm.st)
    return MeshDesc(
        path=lm.path,
        points=pts.reshape(-1, 3),
        triangles=tris.reshape(-1, 3).astype(np.int32),
        normals=normals,
        st=st,
        material=lm.material,
        double_sided=lm.double_sided,
        primvars={name: corners(v) for name, v in lm.primvars.items()},
    )


class _Traversal:
    """One pass over the stage collecting meshes, lights and the first camera."""

    def __init__(self, ctx: ReadContext, included: tuple[str, ...], binding_purposes: tuple[str, ...],
                 subdiv_policy: SubdivPolicy | None = None):
        self.ctx = ctx
        self.subdiv = subdiv_policy or SubdivPolicy(None, None)
        self.skinning = Skinning(ctx)
        self.included = frozenset(included)
        self.materials = MaterialTable(ctx, binding_purposes)
        self.meshes: list[MeshDesc] = []
        self.lights = []
        self.portal_paths: list[str] = []
        self.light_prims: dict[str, Usd.Prim] = {}
        self.first_camera: str | None = None

    # ---- pruning ---------------------------------------------------------------------
    def _classify(self, prim: Usd.Prim, parent_info):
        """-> (render_this, prune_subtree, purpose_info) for one prim."""
        if not prim.IsA(UsdGeom.Imageable):
            if prim.IsA(UsdShade.Material) or prim.IsA(UsdShade.Shader) or prim.IsA(UsdShade.NodeGraph):
                return False, True, parent_info
            return True, False, parent_info
        im = UsdGeom.Imageable(prim)
        if im.GetVisibilityAttr().Get(self.ctx.time) == UsdGeom.Tokens.invisible:
            return False, True, None
        info = im.ComputePurposeInfo(parent_info) if parent_info is not None else im.ComputePurposeInfo()
        if info.purpose not in self.included:
            # authored/inherited purposes exclude the subtree; the bare fallback only this prim
            return False, bool(info.isInheritable), info
        return True, False, info

    # ---- main traversal --------------------------------------------------------------
    def run(self) -> None:
        ctx = self.ctx
        infos: dict = {}
        it = iter(ctx.stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
        for prim in it:
            ctx.stats["prims_visited"] += 1
            render, prune, info = self._classify(prim, infos.get(prim.GetPath().GetParentPath()))
            if prune:
                ctx.stats["prims_pruned"] += 1
                it.PruneChildren()
                continue
            infos[prim.GetPath()] = info
            if prim.HasAuthoredMetadata("apiSchemas"):
                check_light_api_target(prim, ctx)
            if prim.IsA(UsdGeom.PointInstancer):
                it.PruneChildren()
                if render:
                    self._top_instancer(prim, info)
                continue
            if not render:
                continue
            if prim.HasAPI(UsdLux.LightAPI):
                light = read_light(prim, ctx)
                if light is not None:
                    self.lights.append(light)
                    self.light_prims[light.path] = prim
                if prim.IsA(UsdLux.PortalLight):
                    self.portal_paths.append(str(prim.GetPath()))
            if prim.IsA(UsdGeom.Camera):
                if self.first_camera is None:
                    self.first_camera = str(prim.GetPath())
            elif prim.IsA(UsdGeom.Gprim):
                lm = self._local_geometry(prim)
                if lm is not None:
                    mesh = self._emit(lm, ctx.local_to_world(prim)[None])
                    if mesh is not None and prim.HasAPI(UsdLux.LightAPI):
                        self._geometry_light(prim, mesh)
                if (prim.HasAPI(UsdLux.LightAPI) and not prim.HasAPI(UsdLux.VolumeLightAPI)
                        and (lm is None or mesh is None)):
                    ctx.warn(f"light-degenerate-{prim.GetPath()}",
                             f"{prim.GetPath()}: mesh light has no surface to emit from; skipped")

    def _geometry_light(self, prim: Usd.Prim, mesh: MeshDesc) -> None:
        """A gprim with LightAPI (MeshLightAPI): its just-emitted MeshDesc is also a light."""
        light, material = read_geometry_light(prim, self.ctx, mesh, self.materials.materials[mesh.material])
        if material is not None:
            # materialSyncMode changed what the surface itself does (lux.read_geometry_light).
            self.meshes[-1] = dataclasses.replace(mesh, material=self.materials.add(material))
        if light is not None:
            self.lights.append(light)
            self.light_prims[light.path] = prim

    def _emit(self, lm: _LocalMesh, mats: np.ndarray) -> MeshDesc | None:
        finite = np.isfinite(mats).all(axis=(1, 2))
        if not finite.all():
            raise self.ctx.error("world transform is not finite", lm.path, "xformOpOrder")
        # Zero-scale instances (a common way to hide some) have no surface: drop them.
        mats = mats[np.abs(np.linalg.det(mats[:, :3, :3])) > 0.0]
        if len(mats) == 0 or len(lm.triangles) == 0:
            return None
        n = len(lm.triangles)
        self.ctx.memory.need(n * len(mats) * TRIANGLE_BYTES, f"{n} triangles" + (f" x {len(mats)} instances"
                             if len(mats) > 1 else ""), file=self.ctx.file, prim=lm.path)
        desc = _place(lm, mats)
        if lm.tri_material is None:
            self.meshes.append(desc)
        else:  # GeomSubset materials: one MeshDesc per material (instances share the pattern)
            self.meshes.extend(_split_by_material(desc, np.tile(lm.tri_material, len(mats))))
        self.ctx.stats["triangles"] += len(desc.triangles)
        return desc

    # ---- point instancers ------------------------------------------------------------
    def _top_instancer(self, prim: Usd.Prim, info) -> None:
        """Place every prototype gprim and light of a PointInstancer that is not itself inside
        a prototype: gprims as one merged MeshDesc each, lights one LightDesc per instance."""
        groups: dict[int, tuple[_LocalMesh, list[np.ndarray]]] = {}
        world = self.ctx.local_to_world(prim)
        for item, mats, keys in self._instancer_items(prim, info, 0):
            if isinstance(item, _ProtoLight):
                self._instanced_lights(prim, item, np.einsum("ij,njk->nik", world, mats), keys)
            else:
                groups.setdefault(id(item), (item, []))[1].append(mats)
        for lm, mats_list in groups.values():
            self._emit(lm, np.einsum("ij,njk->nik", world, np.concatenate(mats_list)))

    def _instanced_lights(self, instancer: Usd.Prim, pl: _ProtoLight, mats: np.ndarray,
                          keys: np.ndarray) -> None:
        """One LightDesc per instance of a prototype light.

        mats: (N, 4, 4) light-prim-local -> world matrices (instancer world @ instance @ the
        light's transform within the prototype); keys: (N, L) instance ids, one column per
        PointInstancer level. The prototype's radiometry inputs are shared; the frame, and so
        the world-space area ``normalize`` divides by, is each instance's own.
        """
        ctx = self.ctx
        frames = np.einsum("nij,jk->nik", mats, pl.desc.light_to_world)
        bad = ~np.isfinite(frames).all(axis=(1, 2)) | (np.abs(frames).max(axis=(1, 2), initial=0.0) > 1e30)
        if bad.any():
            raise ctx.error(f"the world transform of {pl.desc.path} in instance "
                            f"{keys[int(np.argmax(bad))].tolist()} is not finite (or exceeds 1e30)",
                            instancer, "positions")
        # A zero instance scale (the usual way to hide instances, which hides geometry in
        # _emit) must hide its lamps too: a normalized point light would otherwise still shine.
        # Only an all-zero linear part counts, since a flat light with zero Z scale is valid.
        live = np.any(frames[:, :3, :3] != 0.0, axis=(1, 2))
        instancer_path = instancer.GetPath()
        qualifier = "" if pl.prim.GetPath().HasPrefix(instancer_path) else f"{instancer_path}:"
        for frame, key in zip(frames[live], keys[live]):
            path = _instance_light_path(pl.desc.path, key, qualifier)
            self.lights.append(dataclasses.replace(pl.desc, path=path, light_to_world=frame.copy()))
            self.light_prims[path] = pl.prim
        ctx.stats["instanced_lights"] += int(live.sum())

    def _instancer_items(self, prim: Usd.Prim, info, depth: int) -> list[tuple]:
        """(item, (N, 4, 4) item-local -> instancer-local matrices, (N, L) int64 instance keys)
        for every prototype gprim (item a _LocalMesh) and light (a _ProtoLight).

        This is the one place instance matrices are made, for geometry and lights alike.
        keys: per matrix, the instance id at this instancer then at each nested one (L levels);
        ids are the authored ``ids`` when they are one per instance and distinct, else indices.
        """
        ctx = self.ctx
        if depth > _MAX_INSTANCER_DEPTH:
            raise ctx.error(f"PointInstancers nested deeper than {_MAX_INSTANCER_DEPTH} (a cycle?)",
                            prim, "prototypes")
        pi = UsdGeom.PointInstancer(prim)
        protos = pi.GetPrototypesRel().GetForwardedTargets()
        raw = pi.GetProtoIndicesAttr().Get(ctx.time)
        proto_indices = np.asarray(raw if raw is not None else [], dtype=np.int64)
        ctx.stats["instancers"] += 1
        if len(proto_indices) == 0:
            return []
        if proto_indices.min() < 0 or proto_indices.max() >= len(protos):
            raise ctx.error(f"protoIndices must be in [0, {len(protos)}) (the number of prototypes)",
                            prim, "protoIndices")
        xforms = pi.ComputeInstanceTransformsAtTime(ctx.time, ctx.time, UsdGeom.PointInstancer.IncludeProtoXform,
                                                    UsdGeom.PointInstancer.IgnoreMask)
        if len(xforms) != len(proto_indices):
            raise ctx.error(f"positions/orientations/scales do not match the {len(proto_indices)} protoIndices",
                            prim, "positions")
        mats = np.array(xforms, dtype=np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)
        if not np.isfinite(mats).all():
            raise ctx.error("instance transforms are not finite", prim, "positions")
        keep = np.ones(len(proto_indices), dtype=bool)
        mask = pi.ComputeMaskAtTime(ctx.time)  # invisibleIds / inactiveIds; empty when none
        if mask is not None and len(mask):
            keep = np.asarray(mask, dtype=bool)
        ctx.stats["instances"] += int(keep.sum())
        ids, ids_usable = self._instance_ids(pi, len(proto_indices))
        items: list[tuple] = []
        for k in np.unique(proto_indices[keep]):
            chosen = np.nonzero(keep & (proto_indices == k))[0]
            sel = mats[chosen]
            proto = ctx.stage.GetPrimAtPath(protos[int(k)])
            if not proto:
                raise ctx.error(f"prototype {protos[int(k)]} does not exist", prim, "prototypes")
            for item, rel, rel_keys in self._prototype_items(proto, info, depth):
                # instance-major order: matrix s * R + r is instance s placing item copy r
                both = np.einsum("sij,rjk->srik", sel, rel).reshape(-1, 4, 4)
                keys = np.concatenate([np.repeat(ids[chosen], len(rel))[:, None],
                                       np.tile(rel_keys, (len(chosen), 1))], axis=1)
                items.append((item, both, keys))
        if not ids_usable and any(isinstance(item, _ProtoLight) for item, _m, _k in items):
            ctx.warn(f"instancer-ids-{prim.GetPath()}",
                     f"{prim.GetPath()}: ids are not one distinct id per instance; its instanced lights "
                     "are named by instance index instead")
        return items

    def _instance_ids(self, pi: UsdGeom.PointInstancer, n: int) -> tuple[np.ndarray, bool]:
        """(n,) int64 ids naming the instances (authored ``ids`` if one distinct id each, else
        0..n-1) and False when ids are authored but unusable (so they were replaced)."""
        raw = pi.GetIdsAttr().Get(self.ctx.time)
        if raw is None or len(raw) == 0:
            return np.arange(n, dtype=np.int64), True
        ids = np.asarray(raw, dtype=np.int64)
        if len(ids) != n or len(np.unique(ids)) != n:
            return np.arange(n, dtype=np.int64), False
        return ids, True

    def _prototype_items(self, root: Usd.Prim, info, depth: int) -> list[tuple]:
        """Gprims (_LocalMesh) and lights (_ProtoLight) under a prototype root, each with
        (K, 4, 4) item-local -> root-local matrices and (K, L) keys of the nested instancers'
        instances (L = 0 for items directly in the prototype).

        Visibility and purpose are judged from the root down (the root's ancestors often hide
        the prototypes on purpose); nested instancers recurse.
        """
        ctx = self.ctx
        out: list[tuple] = []
        infos: dict = {root.GetPath().GetParentPath(): info}
        it = iter(Usd.PrimRange(root, _PROTOTYPE_PREDICATE))
        for prim in it:
            render, prune, pinfo = self._classify(prim, infos.get(prim.GetPath().GetParentPath()))
            if prune:
                ctx.stats["prims_pruned"] += 1
                it.PruneChildren()
                continue
            infos[prim.GetPath()] = pinfo
            if prim.HasAuthoredMetadata("apiSchemas"):
                check_light_api_target(prim, ctx)
            if not render:
                continue
            rel = ctx.relative_transform(prim, root) if prim != root else np.eye(4)
            is_light = prim.HasAPI(UsdLux.LightAPI)
            if prim.IsA(UsdGeom.PointInstancer):
                it.PruneChildren()
                for item, mats, keys in self._instancer_items(prim, pinfo, depth + 1):
                    out.append((item, np.einsum("ij,njk->nik", rel, mats), keys))
            elif is_light and prim.IsA(UsdGeom.Gprim) and not prim.HasAPI(UsdLux.VolumeLightAPI):
                ctx.warn("instanced-mesh-light", f"{prim.GetPath()}: mesh lights inside PointInstancer "
                                                 "prototypes are not supported; skipped")
            else:
                if is_light and prim.IsA(UsdLux.PortalLight):
                    ctx.warn("instanced-portal", f"{prim.GetPath()}: PortalLights inside PointInstancer "
                                                 "prototypes are not instanced; ignored")
                elif is_light:
                    # Read once; every instance shares these inputs (_instanced_lights).
                    desc = read_light(prim, ctx, to_world=np.eye(4))
                    if desc is not None:
                        out.append((_ProtoLight(prim, desc), rel[None], _NO_KEYS))
                if prim.IsA(UsdGeom.Gprim):  # a VolumeLightAPI gprim still renders its surface
                    lm = self._local_geometry(prim)
                    if lm is not None:
                        out.append((lm, rel[None], _NO_KEYS))
        return out

    # ---- gprims ----------------------------------------------------------------------
    def _local_geometry(self, prim: Usd.Prim) -> _LocalMesh | None:
        if prim.IsA(UsdGeom.Mesh):
            material, st_name = self.materials.index_for(prim)
            subsets = self._material_subsets(prim, (material, st_name))
            if subsets and st_name is None:
                st_name = next((st for _p, _f, _m, st in subsets if st), None)
            return self._read_mesh(prim, material, st_name or "st", subsets)
        if any(prim.IsA(t) for t in _IMPLICIT_TYPES):
            material, _st = self.materials.index_for(prim)
            self.skinning.warn_unsupported(prim)
            return self._read_implicit(prim, material)
        self.ctx.warn(f"gprim-{prim.GetTypeName()}",
                      f"{prim.GetPath()}: {prim.GetTypeName()} prims are not supported; skipped")
        return None

    def _material_subsets(self, prim: Usd.Prim, mesh_hit) -> list[tuple[str, np.ndarray, int, str | None]]:
        """(subset path, face ids, material, st primvar name) of each materialBind GeomSubset
        whose bound material differs from the mesh's (UsdShade: a subset's binding applies to its
        faces; faces in no such subset keep the mesh's material)."""
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        if not subsets:
            return []
        path = prim.GetPath()
        if prim.HasAPI(UsdLux.LightAPI):
            # A mesh light is one emitter with one colour (usd/lux.read_geometry_light).
            self.ctx.warn(f"subset-light-{path}", f"{path}: GeomSubset material bindings on a mesh light "
                                                  "are ignored; the mesh's own material is used")
            return []
        out = []
        for subset in subsets:
            if subset.GetElementTypeAttr().Get() != UsdGeom.Tokens.face:
                continue
            material, st_name = self.materials.index_for_subset(subset.GetPrim(), mesh_hit)
            if material == mesh_hit[0]:
                continue
            raw = subset.GetIndicesAttr().Get(self.ctx.time)
            faces = np.asarray(raw if raw is not None else [], dtype=np.int64)
            # A subset material reading another st primvar than the mesh's reads its own
            # (description.primvar_layout).
            out.append((str(subset.GetPath()), faces, material, st_name))
        return out

    def _read_mesh(self, prim: Usd.Prim, material: int, st_name: str,
                   subsets: list | None = None) -> _LocalMesh | None:
        ctx, t = self.ctx, self.ctx.time
        mesh = UsdGeom.Mesh(prim)
        raw_points = ctx.get_attr(mesh.GetPointsAttr())
        if raw_points is None or len(raw_points) == 0:
            return None
        points = np.asarray(raw_points, dtype=np.float64)
        ctx.stats["points_read"] += len(points)
        if not np.isfinite(points).all():
            bad = int(np.nonzero(~np.isfinite(points).all(axis=1))[0][0])
            raise ctx.error(f"point {bad} is not finite ({tuple(points[bad])})", prim, "points")
        # UsdSkel: blend shapes and joints at the render time (the rest pose when not skinned).
        points, skinned_normals = self.skinning.deform_mesh(prim, mesh, points)
        raw = ctx.get_attr(mesh.GetFaceVertexCountsAttr())
        counts = np.asarray(raw if raw is not None else [], dtype=np.int64)
        # Refused before the indices are read and triangulated (charged, per instance, in _emit).
        n_tri = int(np.maximum(counts - 2, 0).sum())
        ctx.memory.need(n_tri * TRIANGLE_BYTES, f"{n_tri} triangles", file=ctx.file, prim=str(prim.GetPath()),
                        attribute="faceVertexCounts", commit=False)
        raw = ctx.get_attr(mesh.GetFaceVertexIndicesAttr())
        indices = np.asarray(raw if raw is not None else [], dtype=np.int64)
        if len(counts) and counts.min() < 0:
            raise ctx.error("negative face vertex count", prim, "faceVertexCounts")
        if int(counts.sum()) != len(indices):
            raise ctx.error(f"faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                            f"{len(indices)} entries", prim, "faceVertexCounts")
        if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
            bad = int(indices.max() if indices.max() >= len(points) else indices.min())
            raise ctx.error(f"index {bad} is out of range for {len(points)} points", prim, "faceVertexIndices")
        if len(counts) and counts.min() < 3:
            ctx.warn("mesh-small-faces", f"{prim.GetPath()}: faces with fewer than 3 vertices are skipped")

        scheme = str(mesh.GetSubdivisionSchemeAttr().Get(t))
        holes = mesh.GetHoleIndicesAttr().Get(t)
        holes = np.asarray(holes, dtype=np.int64) if holes is not None and len(holes) else None
        sub = read_subdivided(self, prim, mesh, scheme, points, counts, indices, holes)
        if sub is not None:  # refined: the limit surface, its normals and refined primvars
            triangles, _corners, normals, corners_of, tri_face_control, points = sub
            st = corners_of(st_name, 2)
            primvars = {}
            for name, width in self._primvars_read(material, subsets).items():
                values = corners_of(name, width)
                if values is not None:
                    primvars[name] = values.astype(np.float32)
            return _LocalMesh(
                path=str(prim.GetPath()), points=points, triangles=triangles, normals=normals,
                st=None if st is None else st.astype(np.float32), material=material,
                double_sided=bool(mesh.GetDoubleSidedAttr().Get(t)),
                tri_material=self._triangle_materials(subsets, material, len(counts), tri_face_control),
                primvars=primvars)

        tri_corners, tri_face = triangulate(points, counts, indices, holes)
        if mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded:
            tri_corners = tri_corners[:, [0, 2, 1]]  # front faces wind clockwise: make them CCW
        sizes = (len(points), len(counts), len(indices))
        if skinned_normals is not None:
            normals = self._expand(prim, "normals", skinned_normals[0], None, skinned_normals[1], tri_corners,
                                   tri_face, indices, sizes, 3)
        else:
            normals = self._mesh_normals(prim, mesh, tri_corners, tri_face, indices, sizes)
        if normals is None and scheme in (UsdGeom.Tokens.catmullClark, UsdGeom.Tokens.loop):
            # UsdGeom: a subdivided mesh is a smooth surface whose normals the subdivision defines
            # ("normals should not be authored on any Mesh that is subdivided"). Rendering the
            # cage, take the area-weighted vertex normals Hydra's delegates (Storm, hdEmbree)
            # use at refine level 0, not flat facets; bilinear and none stay faceted.
            normals = _smooth_vertex_normals(points, indices[tri_corners], tri_face, counts, indices)
        st = self._primvar_corners(prim, st_name, tri_corners, tri_face, indices, sizes, width=2)
        reads = self._primvars_read(material, subsets)
        primvars = {}
        for name, width in reads.items():
            values = self._primvar_corners(prim, name, tri_corners, tri_face, indices, sizes, width=width)
            if values is not None:
                primvars[name] = values.astype(np.float32)
        return _LocalMesh(
            path=str(prim.GetPath()),
            points=points,
            triangles=indices[tri_corners],
            normals=normals,
            st=None if st is None else st.astype(np.float32),
            material=material,
            double_sided=bool(mesh.GetDoubleSidedAttr().Get(t)),
            tri_material=self._triangle_materials(subsets, material, len(counts), tri_face),
            primvars=primvars,
        )

    def _primvars_read(self, material: int, subsets: list | None) -> dict[str, int]:
        """{name: width} of the primvars the gprim's materials (its own and its subsets') read
        per hit through UsdPrimvarReader nodes."""
        used = [material] + [m for _p, _f, m, _st in (subsets or [])]
        layout = primvar_layout([self.materials.materials[i] for i in used])
        return {name: width for name, (_col, width) in layout.items()}

    def _triangle_materials(self, subsets, material, n_faces, tri_face) -> np.ndarray | None:
        """(T,) material per triangle from the subsets' face ids (the first subset listing a face
        wins; out-of-range ids are skipped with a warning), or None if all are ``material``."""
        if not subsets:
            return None
        face_material = np.full(n_faces, material, dtype=np.int64)
        for path, faces, m, _st in reversed(subsets):
            bad = (faces < 0) | (faces >= n_faces)
            if bad.any():
                self.ctx.warn(f"subset-indices-{path}", f"{path}: GeomSubset face indices "
                                                        f"{faces[bad][:5].tolist()} are out of range for "
                                                        f"{n_faces} faces; ignored")
            face_material[faces[~bad]] = m
        tri_material = face_material[tri_face]
        return None if np.all(tri_material == material) else tri_material

    def _mesh_normals(self, prim, mesh, tri_corners, tri_face, indices, sizes):
        """Per-corner local normals: ``primvars:normals`` wins over ``normals``; None if neither."""
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        if pv and pv.HasAuthoredValue():
            return self._primvar_corners(prim, "normals", tri_corners, tri_face, indices, sizes, width=3)
        attr = mesh.GetNormalsAttr()
        if not attr.HasAuthoredValue():
            return None
        values = self.ctx.get_attr(attr)
        if values is None:
            return None
        return self._expand(prim, "normals", np.asarray(values, dtype=np.float64), None,
                            str(mesh.GetNormalsInterpolation()), tri_corners, tri_face, indices, sizes, 3)

    def _primvar_corners(self, prim, name, tri_corners, tri_face, indices, sizes, width):
        """(T, 3, width) float64 corners of primvar ``name`` or None when absent/unusable."""
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if not pv or not pv.HasValue():
            return None
        values = pv.Get(self.ctx.time)
        if values is None:
            return None
        values = np.asarray(values, dtype=np.float64)
        element_indices = None
        if pv.IsIndexed():
            raw = pv.GetIndices(self.ctx.time)
            element_indices = np.asarray(raw if raw is not None else [], dtype=np.int64)
        return self._expand(prim, f"primvars:{name}", values, element_indices, str(pv.GetInterpolation()),
                            tri_corners, tri_face, indices, sizes, width)

    def _expand(self, prim, attr_name, values, element_indices, interpolation, tri_corners, tri_face,
                indices, sizes, width):
        ctx = self.ctx
        path = prim.GetPath()
        if values.ndim == 1 and width == 1:  # a scalar primvar (float[], int[])
            values = values[:, None]
        if values.ndim != 2 or values.shape[1] < width:
            ctx.warn(f"primvar-type-{attr_name}", f"{path}: {attr_name} does not hold {width}-vectors; ignored")
            return None
        values = values[:, :width]
        need = primvar_element_count(interpolation, *sizes)
        have = len(element_indices) if element_indices is not None else len(values)
        if need < 0 or have < need:
            ctx.warn(f"primvar-size-{attr_name}",
                     f"{path}: {attr_name} has {have} elements but {interpolation} interpolation needs "
                     f"{max(need, 0)}; ignored")
            return None
        if element_indices is not None and len(element_indices) and (
                element_indices.min() < 0 or element_indices.max() >= len(values)):
            ctx.warn(f"primvar-indices-{attr_name}", f"{path}: {attr_name} indices are out of range; ignored")
            return None
        if not np.isfinite(values).all():
            ctx.warn(f"primvar-nan-{attr_name}", f"{path}: {attr_name} has non-finite values; ignored")
            return None
        return expand_primvar(values, interpolation, tri_corners, tri_face, indices, element_indices)

    def _read_implicit(self, prim: Usd.Prim, material: int) -> _LocalMesh | None:
        ctx = self.ctx

        def size(name: str) -> float:
            return ctx.finite_float(prim, name, ctx.get(prim, name), min_value=0.0)

        def axis() -> str:
            a = str(ctx.get(prim, "axis", "Z"))
            if a not in ("X", "Y", "Z"):
                raise ctx.error(f"axis '{a}' is not X, Y or Z", prim, "axis")
            return a

        if prim.IsA(UsdGeom.Sphere):
            pts, tris, nrm = implicit.sphere(size("radius"))
        elif prim.IsA(UsdGeom.Cube):
            pts, tris, nrm = implicit.cube(size("size"))
        elif prim.IsA(UsdGeom.Cylinder):
            r = size("radius")
            pts, tris, nrm = implicit.cylinder(r, r, size("height"), axis())
        elif prim.IsA(UsdGeom.Cylinder_1):
            pts, tris, nrm = implicit.cylinder(size("radiusBottom"), size("radiusTop"), size("height"), axis())
        elif prim.IsA(UsdGeom.Cone):
            pts, tris, nrm = implicit.cone(size("radius"), size("height"), axis())
        elif prim.IsA(UsdGeom.Capsule):
            r = size("radius")
            pts, tris, nrm = implicit.capsule(r, r, size("height"), axis())
        elif prim.IsA(UsdGeom.Capsule_1):
            pts, tris, nrm = implicit.capsule(size("radiusBottom"), size("radiusTop"), size("height"), axis())
        else:  # Plane
            pts, tris, nrm = implicit.plane(size("width"), size("length"), axis())
        ctx.stats["implicit_prims"] += 1
        if (np.ptp(pts, axis=0) > 0.0).sum() < 2:
            return None  # a zero radius/size leaves no surface to render
        corner_normals = nrm[tris]
        if ctx.get(prim, "orientation") == UsdGeom.Tokens.leftHanded:
            # leftHanded declares the inside to be the front: flip both winding and normals.
            tris = tris[:, [0, 2, 1]]
            corner_normals = -corner_normals[:, [0, 2, 1]]
        return _LocalMesh(
            path=str(prim.GetPath()),
            points=pts,
            triangles=tris,
            normals=corner_normals,
            st=None,
            material=material,
            double_sided=bool(ctx.get(prim, "doubleSided", False)),
            primvars=self._constant_primvars(prim, material, len(tris)),
        )

    def _constant_primvars(self, prim: Usd.Prim, material: int, n_tri: int) -> dict:
        """The primvars an implicit gprim's material reads, for its n_tri triangles: implicit
        prims have no topology, so only a constant (or inherited constant) primvar applies."""
        out = {}
        for name, width in self._primvars_read(material, None).items():
            pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
            if not pv or not pv.HasValue():
                continue
            if pv.GetInterpolation() != UsdGeom.Tokens.constant:
                self.ctx.warn(f"implicit-primvar-{name}",
                              f"{prim.GetPath()}: primvars:{name} is {pv.GetInterpolation()}, but an implicit "
                              f"{prim.GetTypeName()} has no topology to interpolate it on; its first value is used")
            values = pv.ComputeFlattened(self.ctx.time)
            v = np.atleast_1d(np.asarray(values[0] if values is not None and len(values) else [], dtype=np.float64))
            if v.size < width or not np.isfinite(v).all():
                continue
            out[name] = np.broadcast_to(v[:width].astype(np.float32), (n_tri, 3, width)).copy()
        return out
