"""Build the render-side scene once from a SceneDescription: flat triangle tables, the embree
BVH, the material table, the light set and the lighting service.

Nothing here knows about USD; ``renderer/usd`` produced the description.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .accel import Accel
from .description import SceneDescription
from .geometry import normalize


@dataclass
class GeometryTables:
    """Per-triangle data, indexed by embree's primID.

    vertices: (T, 3, 3) float64; normals: (T, 3, 3) float64 unit per-corner shading normals
    (face normals where the mesh had none); st: (T, 3, 2) float64 (zeros where none);
    face_normal: (T, 3) unit geometric normals (front = counter-clockwise winding);
    material: (T,) int32; mesh: (T,) int32 index into ``mesh_paths``.
    """

    vertices: np.ndarray
    normals: np.ndarray
    st: np.ndarray
    face_normal: np.ndarray
    material: np.ndarray
    mesh: np.ndarray
    mesh_paths: list[str]

    @property
    def count(self) -> int:
        return self.vertices.shape[0]


def build_geometry(desc: SceneDescription) -> GeometryTables:
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
        sts.append(np.zeros((tri.shape[0], 3, 2)) if m.st is None else np.asarray(m.st, dtype=np.float64))
        mats.append(np.full(tri.shape[0], m.material, dtype=np.int32))
        owners.append(np.full(tri.shape[0], i, dtype=np.int32))
    if not verts:
        z3 = np.zeros((0, 3, 3))
        return GeometryTables(z3, z3, np.zeros((0, 3, 2)), np.zeros((0, 3)), np.zeros(0, np.int32),
                              np.zeros(0, np.int32), [m.path for m in desc.meshes])
    vertices = np.concatenate(verts)
    face_normal = normalize(np.cross(vertices[:, 1] - vertices[:, 0], vertices[:, 2] - vertices[:, 0]))
    return GeometryTables(
        vertices=vertices,
        normals=np.concatenate(norms),
        st=np.concatenate(sts),
        face_normal=face_normal,
        material=np.concatenate(mats),
        mesh=np.concatenate(owners),
        mesh_paths=[m.path for m in desc.meshes],
    )


@dataclass
class Scene:
    """Everything the integrators need, built once per render.

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
    warnings: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    build_seconds: float = 0.0
    # Light linking (UsdLux collection:lightLink / collection:shadowLink), resolved per light:
    # illuminates: (count, meshes) bool or None when every light lights everything;
    # shadow_accel: (count,) int index into shadow_accels (-1: the full scene BVH).
    illuminates: np.ndarray | None = None
    shadow_group: np.ndarray | None = None
    shadow_accels: list = field(default_factory=list)

    def close(self) -> None:
        self.accel.close()
        if self.light_accel is not None:
            self.light_accel.close()
        for a in self.shadow_accels:
            a.close()


# Brute-force exact light intersection is cheaper than a proxy BVH for a handful of lights.
BRUTE_FORCE_LIGHTS = 16


def build_scene(desc: SceneDescription, *, threads: int | None = None, light_sampler: str = "auto") -> Scene:
    """Flatten geometry, build the BVH, materials, lights and the light sampler."""
    import time

    from .light_samplers import make_light_sampler
    from .lights.light_set import LightSet
    from .materials import MaterialTable
    from .textures import TextureCache

    t0 = time.perf_counter()
    geo = build_geometry(desc)
    accel = Accel(geo.vertices, threads=threads)
    lo, hi = accel.bounds
    finite_pts = [geo.vertices.reshape(-1, 3)] if geo.count else []
    for ld in desc.lights:
        if ld.kind not in ("dome", "distant"):
            finite_pts.append(np.asarray(ld.light_to_world)[:3, 3][None, :])
    if finite_pts:
        allp = np.concatenate(finite_pts)
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = float(max(0.5 * np.linalg.norm(hi - lo), 1e-6))
    else:
        center, radius = np.zeros(3), 1.0
    textures = TextureCache()
    materials = MaterialTable.build(desc.materials, textures)
    lights = LightSet.build(desc.lights, center, radius)
    warnings = list(desc.warnings) + list(getattr(lights, "warnings", [])) + list(getattr(textures, "warnings", []))
    skipped = []
    for path in getattr(lights, "dropped", []):
        skipped.append(f"light {path}: emits nothing or is degenerate; dropped before the lighting services")
    light_accel = None
    light_owner = None
    finite = np.nonzero(~lights.is_infinite)[0] if lights.count else np.zeros(0, np.int64)
    if finite.size > BRUTE_FORCE_LIGHTS:
        tris, owner = lights.proxy_triangles()
        light_accel = Accel(tris, threads=threads)
        light_owner = owner
    if lights.count == 0:
        skipped.append("no lights: next-event estimation disabled")
    if not np.any(lights.is_infinite) if lights.count else True:
        skipped.append("no dome or distant light: escaped rays do no environment work")
    illuminates, shadow_group, shadow_accels = build_linking(lights, geo, threads)
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
        warnings=warnings,
        skipped=skipped,
        illuminates=illuminates,
        shadow_group=shadow_group,
        shadow_accels=shadow_accels,
    )
    scene.build_seconds = time.perf_counter() - t0
    return scene


def build_linking(lights, geo: GeometryTables, threads: int | None):
    """Resolve UsdLux light linking into render-side tables.

    lightLink: ``illuminates[light, mesh]`` is False where the light's collection excludes the
    mesh (None when no light restricts anything -- the common case costs nothing).
    shadowLink: geometry a light's shadowLink excludes casts no shadow from that light, so each
    distinct excluded set gets its own BVH without those meshes; ``shadow_group[light]`` picks it
    (-1: the full scene). Lights sharing an excluded set share the BVH.
    """
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
    groups: dict[frozenset, int] = {}
    for i, d in enumerate(descs):
        ex = d.shadow_link_excludes
        if not ex:
            continue
        key = frozenset(ex)
        if key not in groups:
            casts = ~mesh_mask(key)[geo.mesh]  # per triangle
            groups[key] = len(accels)
            accels.append(Accel(geo.vertices[casts], threads=threads))
        shadow_group[i] = groups[key]
    return illuminates, (shadow_group if accels else None), accels
