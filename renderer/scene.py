"""Build the render-side scene once from a SceneDescription: flat triangle tables, the embree
BVH, the material table, the light set and the lighting service.

Nothing here knows about USD; ``renderer/usd`` produced the description.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .accel import Accel
from .description import INFINITE_LIGHT_KINDS, SceneDescription, primvar_layout, translated
from .errors import StageError
from .geometry import normalize, uv_tangents


@dataclass
class GeometryTables:
    """Per-triangle data, indexed by embree's primID.

    vertices: (T, 3, 3) float64; normals: (T, 3, 3) float64 unit per-corner shading normals
    (face normals where the mesh had none); st: (T, 3, 2 + K) float64: st (zeros where none),
    then the K primvar components materials read per hit, laid out by
    ``materials.primvar_layout`` (NaN where a mesh lacks the primvar: the reader's fallback);
    face_normal: (T, 3) unit geometric normals (front = counter-clockwise winding);
    material: (T,) int32; mesh: (T,) int32 index into ``mesh_paths``.
    tangent: (T, 3) unit dp/du and handed: (T,) UV handedness (+1, -1; 0 = no frame) for
    normal maps (geometry.uv_tangents), only on triangles of normal-mapped materials (zeros
    elsewhere); both None when no material of the scene is normal-mapped.
    """

    vertices: np.ndarray
    normals: np.ndarray
    st: np.ndarray
    face_normal: np.ndarray
    material: np.ndarray
    mesh: np.ndarray
    mesh_paths: list[str]
    tangent: np.ndarray | None = None
    handed: np.ndarray | None = None

    @property
    def count(self) -> int:
        return self.vertices.shape[0]


def build_geometry(desc: SceneDescription) -> GeometryTables:
    layout = primvar_layout(desc.materials)
    columns = 2 + sum(w for _c, w in layout.values())
    verts, norms, sts, mats, owners = [], [], [], [], []
    for i, m in enumerate(desc.meshes):
        tri = m.triangles
        if tri.size == 0:
            continue
        v = np.asarray(m.points, dtype=np.float64)[tri]  # (T, 3, 3)
        verts.append(v)
        fn = normalize(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))
        if m.normals is not None:
            nrm = np.asarray(m.normals, dtype=np.float64)
            length = np.linalg.norm(nrm, axis=2, keepdims=True)
            # Zero or non-finite authored normals fall back to the face normal, corner by corner.
            good = np.isfinite(length) & (length > 0.0)
            nrm = np.where(good, nrm / np.where(good, length, 1.0), fn[:, None, :])
        else:
            nrm = np.repeat(fn[:, None, :], 3, axis=1)
        norms.append(nrm)
        st = np.zeros((tri.shape[0], 3, columns))
        if m.st is not None:
            st[:, :, :2] = m.st
        for name, (col, width) in layout.items():
            values = m.primvars.get(name)
            if values is None:
                st[:, :, col:col + width] = np.nan
            else:
                w = min(width, values.shape[2])
                st[:, :, col:col + w] = values[:, :, :w]
                st[:, :, col + w:col + width] = np.nan
        sts.append(st)
        mats.append(np.full(tri.shape[0], m.material, dtype=np.int32))
        owners.append(np.full(tri.shape[0], i, dtype=np.int32))
    if not verts:
        z3 = np.zeros((0, 3, 3))
        return GeometryTables(z3, z3, np.zeros((0, 3, columns)), np.zeros((0, 3)), np.zeros(0, np.int32),
                              np.zeros(0, np.int32), [m.path for m in desc.meshes])
    vertices = np.concatenate(verts)
    face_normal = normalize(np.cross(vertices[:, 1] - vertices[:, 0], vertices[:, 2] - vertices[:, 0]))
    st = np.concatenate(sts)
    material = np.concatenate(mats)
    tangent = handed = None
    mapped = _normal_mapped_materials(desc)
    if mapped.any():
        # Built once, and only for the triangles that need a frame.
        tangent, handed = np.zeros((vertices.shape[0], 3)), np.zeros(vertices.shape[0])
        rows = np.nonzero(mapped[material])[0]
        tangent[rows], handed[rows] = uv_tangents(vertices[rows], st[rows][:, :, :2])
    return GeometryTables(
        vertices=vertices,
        normals=np.concatenate(norms),
        st=st,
        face_normal=face_normal,
        material=material,
        mesh=np.concatenate(owners),
        mesh_paths=[m.path for m in desc.meshes],
        tangent=tangent,
        handed=handed,
    )


def _normal_mapped_materials(desc: SceneDescription) -> np.ndarray:
    """(materials,) bool: the material bends shading normals (materials.normal_mapped)."""
    from .materials import normal_mapped

    return np.array([normal_mapped(m) for m in desc.materials], dtype=bool)


def normal_map_warnings(desc: SceneDescription) -> list[str]:
    """One warning per mesh whose material has a normal map but which has no texture
    coordinates: without st there is no tangent frame, so its normals stay unperturbed."""
    mapped = _normal_mapped_materials(desc)
    out: list[str] = []
    for m in desc.meshes:
        if m.st is None and mapped.size and mapped[m.material] and m.triangles.size:
            msg = (f"{m.path}: material {desc.materials[m.material].path} has a normal map (inputs:normal) "
                   f"but the mesh has no st primvar; its normals are not perturbed")
            if msg not in out:
                out.append(msg)
    return out


def wrap_warnings(desc: SceneDescription, textures) -> list[str]:
    """One warning per texture file whose wrap mode 'useMetadata' falls back to black (the file
    declares no wrap modes: the UsdPreviewSurface spec's rule) on an axis along which some
    mesh's st, after the texture's st transform, leaves [0, 1]. Those lookups are black, where
    usdview repeats: said once, before rendering, instead of a silently black surface."""
    from .materials import texture_inputs

    out: dict[str, str] = {}
    for m in desc.meshes:
        if not m.triangles.size:
            continue
        for name, tex in texture_inputs(desc.materials[m.material]):
            if tex.udim_tiles or tex.file in out or "useMetadata" not in (tex.wrap_s, tex.wrap_t):
                continue
            st = m.st if tex.st_primvar == "st" else m.primvars.get(tex.st_primvar, m.st)
            if st is None:
                continue
            st = np.asarray(st, dtype=np.float64).reshape(-1, st.shape[-1])[:, :2]
            if tex.st_transform:
                m00, m01, m10, m11, t0, t1 = tex.st_transform
                st = np.stack([m00 * st[:, 0] + m01 * st[:, 1] + t0, m10 * st[:, 0] + m11 * st[:, 1] + t1], axis=1)
            resolved = textures.wrap_modes(tex)
            for axis, (authored, mode, wrap) in enumerate(zip((tex.wrap_s, tex.wrap_t), resolved, ("S", "T"))):
                c = st[:, axis][np.isfinite(st[:, axis])]
                if authored == "useMetadata" and mode == "black" and c.size and (c.min() < 0.0 or c.max() > 1.0):
                    out[tex.file] = (
                        f"{m.path}: material {desc.materials[m.material].path} {name}: texture '{tex.file}' has "
                        f"inputs:wrap{wrap} = useMetadata and the file declares no wrap mode, so it is black "
                        f"outside [0, 1] (the UsdPreviewSurface spec; usdview repeats there); this mesh's "
                        f"{'st'[axis]} spans [{c.min():.3g}, {c.max():.3g}]. Author wrap{wrap} = repeat to tile it")
                    break
    return list(out.values())


@dataclass
class Scene:
    """Everything the integrators need, built once per render.

    desc: the description as traced: re-centred, every position moved by -origin (recentre).
    origin: (3,) float64 world position of the traced coordinates' zero: p_world = p + origin.
    Everything built here (BVHs, light tables, center, the camera of desc) is in those
    re-centred coordinates; what reports world positions (the EXR's worldToCamera/worldToNDC,
    a position AOV) adds origin back.
    center, radius: bounding sphere of geometry and finite lights (scene units), used by
    infinite lights and for ray offsets.
    skipped: what the build decided not to do, for the stats JSON.
    """

    desc: SceneDescription
    geometry: GeometryTables
    accel: Accel
    materials: object
    lights: object
    light_accel: Accel | None
    light_owner: np.ndarray | None
    light_sampler: object
    center: np.ndarray
    radius: float
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    warnings: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    build_seconds: float = 0.0
    # Light linking (UsdLux collection:lightLink / collection:shadowLink), resolved per light:
    # illuminates: (count, meshes) bool or None when every light lights everything;
    # shadow_accel: (count,) int index into shadow_accels (-1: the full scene BVH).
    # shadow_params: per shadow group, the UsdLux ShadowAPI ray behaviour (None: plain rays).
    illuminates: np.ndarray | None = None
    # light_spheres: (centre (count, 3), radius (count,)) bounding spheres of every light, from
    # the proxy triangles (built with light_accel, else None; infinite lights: inf centre).
    light_spheres: tuple | None = None
    shadow_group: np.ndarray | None = None
    shadow_accels: list = field(default_factory=list)
    shadow_params: list = field(default_factory=list)
    # Mesh lights (lights/mesh.py) are geometry: tri_light (T,) int64 is the global light index
    # of each triangle that is part of one (-1 elsewhere), tri_absorb (T,) bool marks those whose
    # materialSyncMode is noMaterialResponse (the surface reflects nothing). None without mesh lights.
    tri_light: np.ndarray | None = None
    tri_absorb: np.ndarray | None = None
    # The `auto` estimator's pilot decisions (integrators/auto.py), kept with the loaded scene so
    # that re-renders of it (a resident worker, the bench's timed runs) do not pilot again.
    pilot_cache: dict = field(default_factory=dict)

    def close(self) -> None:
        self.accel.close()
        if self.light_accel is not None:
            self.light_accel.close()
        for a in self.shadow_accels:
            a.close()


# Brute-force exact light intersection is cheaper than a proxy BVH for a handful of lights.
BRUTE_FORCE_LIGHTS = 16


def build_scene(desc: SceneDescription, *, threads: int | None = None, light_sampler: str = "auto",
                textures=None, resolution: tuple | None = None) -> Scene:
    """Re-centre the description on its camera (recentre), then flatten geometry, build the
    BVH, materials, lights and the light sampler.

    textures: a TextureCache to load image files into and reuse (a frame range decodes each
    texture once for all its frames); None: a new one.
    resolution: (width, height) the render will use, for the precision check's pixel footprint;
    None: the description's RenderSettings resolution."""
    import time

    from .light_samplers import make_light_sampler
    from .lights.light_set import LightSet
    from .materials import MaterialTable
    from .textures import TextureCache

    t0 = time.perf_counter()
    desc, origin, far_warnings = recentre(desc, resolution)
    geo = build_geometry(desc)
    accel = Accel(geo.vertices, threads=threads)
    lo, hi = accel.bounds
    finite_pts = [geo.vertices.reshape(-1, 3)] if geo.count else []
    for ld in _finite_lights(desc):
        finite_pts.append(np.asarray(ld.light_to_world)[:3, 3][None, :])
    if finite_pts:
        allp = np.concatenate(finite_pts)
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = float(max(0.5 * np.linalg.norm(hi - lo), 1e-6))
    else:
        center, radius = np.zeros(3), 1.0
    # The reader has applied the missing-asset policy already; a file that vanished since, or
    # that decodes badly past its header, follows the same policy here.
    if textures is None:
        textures = TextureCache(missing="error" if desc.strict else "fallback", strict=desc.strict)
    materials = MaterialTable.build(desc.materials, textures)
    lights = LightSet.build(desc.lights, center, radius)
    tri_light, tri_absorb = mesh_light_tables(lights, geo)
    warnings = list(desc.warnings) + list(getattr(lights, "warnings", [])) + list(getattr(textures, "warnings", []))
    warnings += normal_map_warnings(desc) + wrap_warnings(desc, textures) + far_warnings
    skipped = []
    for path in getattr(lights, "dropped", []):
        skipped.append(f"light {path}: emits nothing or is degenerate; dropped before the lighting services")
    light_accel = None
    light_owner = None
    light_spheres = None
    # Mesh lights are in the scene BVH already: no proxies, no light BVH for them.
    finite = np.nonzero(~lights.is_infinite & ~lights.is_geometry)[0] if lights.count else np.zeros(0, np.int64)
    if finite.size > BRUTE_FORCE_LIGHTS:
        tris, owner = lights.proxy_triangles()
        light_accel = Accel(tris, threads=threads)
        light_owner = owner
        light_spheres = _bounding_spheres(tris, owner, lights.count)
    if lights.count == 0:
        skipped.append("no lights: next-event estimation disabled")
    if not np.any(lights.is_infinite) if lights.count else True:
        skipped.append("no dome or distant light: escaped rays do no environment work")
    illuminates, shadow_group, shadow_accels, shadow_params = build_linking(lights, geo, threads, accel)
    if illuminates is None and not shadow_accels:
        skipped.append("no light linking: one shared BVH for every shadow ray, no per-light masks")
    sampler_name = light_sampler if light_sampler not in ("", "auto") else (desc.settings.light_sampler or "auto")
    sampler = make_light_sampler(sampler_name, lights)
    scene = Scene(
        desc=desc,
        geometry=geo,
        accel=accel,
        materials=materials,
        lights=lights,
        light_accel=light_accel,
        light_owner=light_owner,
        light_sampler=sampler,
        center=center,
        radius=radius,
        origin=origin,
        warnings=warnings,
        skipped=skipped,
        illuminates=illuminates,
        light_spheres=light_spheres,
        shadow_group=shadow_group,
        shadow_accels=shadow_accels,
        shadow_params=shadow_params,
        tri_light=tri_light,
        tri_absorb=tri_absorb,
    )
    scene.build_seconds = time.perf_counter() - t0
    return scene


# Warn when the coordinates' rounding step exceeds this fraction of a pixel's footprint.
PRECISION_FRACTION = 0.25
_F32_MAX = float(np.finfo(np.float32).max)


def _finite_lights(desc: SceneDescription):
    """The lights with a position (not INFINITE_LIGHT_KINDS)."""
    return [ld for ld in desc.lights if ld.kind not in INFINITE_LIGHT_KINDS]


def recentre(desc: SceneDescription, resolution: tuple | None = None) -> tuple[SceneDescription, np.ndarray, list[str]]:
    """(desc moved by -origin, origin (3,) float64, warnings): the scene re-centred on the
    camera's position for float32 tracing (Embree), after checking that it can be represented.

    Why the camera: a float32 coordinate at distance D from the origin is rounded to ~D 2^-24,
    and a pixel's footprint at distance D is D times the pixel's angle, so with the origin at
    the eye the rounding stays the same small fraction of a pixel at every distance: near
    geometry keeps fine precision and far geometry needs no more. The centre of the bounds
    would serve a compact scene as well but starve the camera's surroundings in a large one
    (a terrain seen from one corner).

    What re-centring cannot fix: the description's float64 world coordinates were already
    rounded to spacing(|p|) when the reader composed the transforms. When that step reaches
    the scene's extent (1e30 units out for a box of a few metres) the geometry has collapsed
    and a StageError (exit 2) names the extent; when it, or the float32 step at the largest
    re-centred distance, exceeds PRECISION_FRACTION of a pixel's footprint (at the distance of
    the bounds' centre, at least half the extent), one warning names the extent. Positions that
    are not finite, or re-centred distances beyond float32's range, are a StageError too.
    """
    cam = desc.camera
    c2w = np.asarray(cam.camera_to_world, dtype=np.float64)
    if not np.all(np.isfinite(c2w)):
        raise StageError("the camera's transform is not finite", file=desc.source, prim=cam.path)
    origin = c2w[:3, 3].copy()
    lows, highs = [], []
    for m in desc.meshes:
        if m.triangles.size:
            pts = np.asarray(m.points, dtype=np.float64).reshape(-1, 3)
            lows.append(pts.min(axis=0))
            highs.append(pts.max(axis=0))
    meshes = len(lows)
    for ld in _finite_lights(desc):
        pos = np.asarray(ld.light_to_world, dtype=np.float64)[:3, 3]
        lows.append(pos)
        highs.append(pos)
    if not lows:
        return translated(desc, -origin), origin, []
    lo, hi = np.min(lows, axis=0), np.max(highs, axis=0)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise StageError("geometry or light positions are not finite", file=desc.source)
    with np.errstate(over="ignore", invalid="ignore"):
        extent = float(np.linalg.norm(hi - lo))
        rel = np.abs(np.stack([lo - origin, hi - origin]))
    world = float(max(np.abs(origin).max(), np.abs(lo).max(), np.abs(hi).max()))
    where = f"the scene's extent of {extent:.4g} units around {_fmt(0.5 * (lo + hi))} (camera at {_fmt(origin)})"
    far = float(rel.max())
    if not np.isfinite(extent) or not np.isfinite(far) or far >= _F32_MAX:
        raise StageError(f"{where} does not fit float32 tracing even re-centred on the camera "
                         f"(distances beyond {_F32_MAX:.3g}); nothing can be rendered", file=desc.source)
    step64 = float(np.spacing(world))
    mesh_extent = float(np.linalg.norm(np.max(highs[:meshes], axis=0) - np.min(lows[:meshes], axis=0))) if meshes else 0.0
    # Every triangle within one rounding step: all are degenerate (1e30 units out, a box of a
    # few metres is a single point), so no geometry can be rendered.
    if meshes and mesh_extent <= step64:
        raise StageError(f"{where} lies {world:.4g} units from the world origin, where coordinates are "
                         f"{step64:.3g} units apart: the geometry has collapsed to a point and nothing can "
                         f"be rendered (move the scene nearer the origin)", file=desc.source)
    warnings = []
    width, height = resolution or desc.settings.resolution
    pixel = max(cam.horizontal_aperture / max(int(width), 1), cam.vertical_aperture / max(int(height), 1))
    if cam.projection == "orthographic":
        footprint = pixel
    else:
        distance = max(float(np.linalg.norm(0.5 * ((lo - origin) + (hi - origin)))), 0.5 * extent)
        footprint = pixel / max(cam.focal_length, 1e-300) * distance
    step = max(step64, float(np.spacing(np.float32(far))))
    if extent > 0.0 and step > PRECISION_FRACTION * footprint:
        warnings.append(f"{where}: coordinates are rounded to {step:.3g} units, {step / footprint:.2g} of a "
                        f"pixel's footprint ({footprint:.3g} units); expect faceting, light leaks or "
                        f"shadow acne (move the scene nearer the origin)")
    return translated(desc, -origin), origin, warnings


def _fmt(p: np.ndarray) -> str:
    """A point with every digit float64 keeps (a scene 1e16 units out differs past the 15th)."""
    return "(" + ", ".join(f"{x:.17g}" for x in p) + ")"


def mesh_light_tables(lights, geo: GeometryTables):
    """(tri_light (T,) int64, tri_absorb (T,) bool) for the mesh lights, or (None, None).

    A mesh light names its MeshDesc (LightDesc.mesh_path); the reader gave it exactly that
    mesh's triangles, so every triangle of that mesh belongs to the light.
    """
    geometry = np.nonzero(getattr(lights, "is_geometry", np.zeros(0, bool)))[0]
    if not geometry.size or not geo.count:
        return None, None
    mesh_light = np.full(len(geo.mesh_paths), -1, dtype=np.int64)
    by_path = {lights.descs[g].mesh_path: g for g in geometry}
    for i, path in enumerate(geo.mesh_paths):
        mesh_light[i] = by_path.get(path, -1)
    tri_light = mesh_light[geo.mesh]
    if not np.any(tri_light >= 0):
        return None, None
    absorbing = np.array([lights.descs[g].material_sync_mode == "noMaterialResponse" for g in range(lights.count)])
    tri_absorb = np.where(tri_light >= 0, absorbing[np.maximum(tri_light, 0)], False)
    return tri_light, tri_absorb


def build_linking(lights, geo: GeometryTables, threads: int | None, accel: Accel | None = None):
    """Resolve UsdLux light linking into render-side tables.

    lightLink: ``illuminates[light, mesh]`` is False where the light's collection excludes the
    mesh (None when no light restricts anything -- the common case costs nothing).
    shadowLink: geometry a light's shadowLink excludes casts no shadow from that light, so each
    distinct excluded set gets its own BVH without those meshes; ``shadow_group[light]`` picks it
    (-1: the full scene). Lights sharing an excluded set share the BVH.
    ShadowAPI: lights whose shadow rays differ (shadow:enable off, shadow:distance/falloff) get
    a group of their own key (excluded set, ShadowParams); ``shadow_params[group]`` holds the
    params (None for plain rays) and a group without excluded meshes reuses ``accel``, the
    scene BVH. Returns (illuminates, shadow_group or None, shadow_accels, shadow_params).
    """
    from .integrators.shadow_api import shadow_params as params_of

    descs = getattr(lights, "descs", [])
    n_mesh = len(geo.mesh_paths)
    index_of: dict[str, list[int]] = {}
    for i, path in enumerate(geo.mesh_paths):
        index_of.setdefault(path, []).append(i)

    def mesh_mask(paths) -> np.ndarray:
        mask = np.zeros(n_mesh, dtype=bool)
        for p in paths:
            mask[index_of.get(p, [])] = True
        return mask

    illuminates = None
    if any(d.light_link_excludes for d in descs):
        illuminates = np.ones((len(descs), n_mesh), dtype=bool)
        for i, d in enumerate(descs):
            if d.light_link_excludes:
                illuminates[i] = ~mesh_mask(d.light_link_excludes)
    shadow_group = np.full(len(descs), -1, dtype=np.int64)
    accels: list[Accel] = []
    params: list = []
    groups: dict[tuple, int] = {}
    built: dict[frozenset, Accel] = {}
    for i, d in enumerate(descs):
        ex = frozenset(d.shadow_link_excludes) if d.shadow_link_excludes else None
        sp = params_of(getattr(d, "shadow", None))
        if ex is None and sp is None:
            continue
        key = (ex, sp)
        if key not in groups:
            if ex is None:
                bvh = accel if accel is not None else Accel(geo.vertices, threads=threads)
            elif ex in built:
                bvh = built[ex]
            else:
                casts = ~mesh_mask(ex)[geo.mesh]  # per triangle
                # tri_index: cut-out shadow rays look up the material at a hit (integrators/path.py
                # _visible_through_cutouts).
                bvh = built[ex] = Accel(geo.vertices[casts], threads=threads, tri_index=np.nonzero(casts)[0])
            groups[key] = len(accels)
            accels.append(bvh)
            params.append(sp)
        shadow_group[i] = groups[key]
    return illuminates, (shadow_group if accels else None), accels, params


def _bounding_spheres(tris: np.ndarray, owner: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Per light: (centre (count, 3), radius (count,)) of the sphere around the AABB of its proxy
    triangles tris (T, 3, 3) with owner (T,); lights without proxies get inf / 0."""
    lo, hi = np.full((count, 3), np.inf), np.full((count, 3), -np.inf)
    np.minimum.at(lo, owner, tris.min(axis=1))
    np.maximum.at(hi, owner, tris.max(axis=1))
    has = np.all(np.isfinite(lo), axis=1)
    lo, hi = np.where(has[:, None], lo, 0.0), np.where(has[:, None], hi, 0.0)  # no inf - inf
    centre = np.where(has[:, None], 0.5 * (lo + hi), np.inf)
    return centre, 0.5 * np.linalg.norm(hi - lo, axis=1)
