"""UsdLux -> LightDesc: raw inputs, world frame, dome pole correction, light linking.

The reader does no radiometry (intensity * 2^exposure, normalize, colour temperature are
the render core's job); it only validates values and resolves frames, files and links.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pxr import Usd, UsdGeom, UsdLux

from renderer.description import LightDesc, MaterialDesc, MaterialInput, MeshDesc

from .common import ReadContext
from .estimator_api import read_estimator_settings
from .lux_shaping import read_shadow, read_shaping, warn_light_filters

__all__ = ["read_light", "read_geometry_light", "read_portals", "warn_unused_portals", "resolve_light_links",
           "POLE_Z_FROM_Y"]

# rotateX(+90 deg), column-vector: local +Y -> +Z, local +Z -> -Y. Composed on the right of a
# DomeLight_1's world matrix when its pole is Z, so texture lat0/lon0 (local +Z) -> world -Y.
POLE_Z_FROM_Y = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

_SUPPORTED_FORMATS = ("automatic", "latlong")

# Concrete light types, most specific first; kind as in LightDesc.kind.
_KINDS = (
    (UsdLux.RectLight, "rect"),
    (UsdLux.DiskLight, "disk"),
    (UsdLux.SphereLight, "sphere"),
    (UsdLux.CylinderLight, "cylinder"),
    (UsdLux.DistantLight, "distant"),
    (UsdLux.DomeLight_1, "dome"),
    (UsdLux.DomeLight, "dome"),
)


def _kind_of(prim: Usd.Prim) -> str | None:
    for schema, kind in _KINDS:
        if prim.IsA(schema):
            return kind
    return None


def _exposure(prim, ctx: ReadContext, value: float) -> float:
    if abs(value) > 128.0:
        raise ctx.error(f"exposure {value:g} is outside [-128, 128] stops", prim, "inputs:exposure")
    return value


def _light_api_fields(prim: Usd.Prim, ctx: ReadContext) -> dict:
    """The LightAPI inputs every light has, validated, as LightDesc fields."""

    def num(name: str, *, min_value: float | None = None) -> float:
        return ctx.finite_float(prim, name, ctx.get(prim, name), min_value=min_value)

    def flag(name: str) -> bool:
        return bool(ctx.get(prim, name, False))

    fields: dict = {
        "intensity": num("inputs:intensity", min_value=0.0),
        # Negative exposure is a legitimate dimming; beyond ±128 stops 2^exposure leaves the
        # float32 range the film stores, so it can only be a mistake.
        "exposure": _exposure(prim, ctx, num("inputs:exposure")),
        "color": ctx.finite_tuple(prim, "inputs:color", ctx.get(prim, "inputs:color")),
        "enable_color_temperature": flag("inputs:enableColorTemperature"),
        "color_temperature": num("inputs:colorTemperature", min_value=0.0),
        "normalize": flag("inputs:normalize"),
        "diffuse": num("inputs:diffuse", min_value=0.0),
        "specular": num("inputs:specular", min_value=0.0),
    }
    if any(c < 0.0 for c in fields["color"]):
        raise ctx.error(f"value {fields['color']} has a negative component", prim, "inputs:color")
    return fields


def _light_texture(prim: Usd.Prim, ctx: ReadContext) -> tuple[str, bytes | None]:
    """(resolved path, bytes when not a file) of inputs:texture:file, ('', None) when unauthored
    or, under the missing-asset policy, missing or unreadable (the light renders untextured)."""
    name = "inputs:texture:file"
    asset = ctx.read_image_asset(prim, name, ctx.get(prim, name), "the light renders untextured (its color only)")
    return asset if asset is not None else ("", None)


def read_light(prim: Usd.Prim, ctx: ReadContext, to_world: np.ndarray | None = None) -> LightDesc | None:
    """One light prim (already known to have LightAPI and to be visible) -> LightDesc.

    to_world: (4, 4) column-vector matrix to use instead of the prim's world transform. A
    PointInstancer prototype light is read once with the identity, so its ``light_to_world`` is
    the light's frame in its own prim space (the DomeLight_1 pole turn, else identity), and each
    instance composes its matrix on the left (``stage_reader._Traversal._instanced_lights``).

    Returns None, with a warning, for light types illum does not render yet and for
    degenerate lights (zero size); silently for geometry lights (gprims with LightAPI, read by
    ``read_geometry_light`` together with their MeshDesc) and PortalLights (read through the
    DomeLight that targets them).
    """
    kind = _kind_of(prim)
    path = str(prim.GetPath())
    geometry_light = prim.IsA(UsdGeom.Gprim) and not prim.HasAPI(UsdLux.VolumeLightAPI)
    if kind is None and (geometry_light or prim.IsA(UsdLux.PortalLight)):
        return None
    if kind is None:
        if prim.HasAPI(UsdLux.MeshLightAPI):
            label = "MeshLightAPI"
        elif prim.HasAPI(UsdLux.VolumeLightAPI):
            label = "VolumeLightAPI"
        else:
            label = prim.GetTypeName() or "untyped prim"
        ctx.warn(f"light-unsupported-{label}",
                 f"{path}: {label} lights are not supported yet; the light is skipped")
        return None

    def num(name: str, *, min_value: float | None = None, positive: bool = False) -> float:
        return ctx.finite_float(prim, name, ctx.get(prim, name), min_value=min_value, positive=positive)

    def flag(name: str) -> bool:
        return bool(ctx.get(prim, name, False))

    fields = _light_api_fields(prim, ctx)

    degenerate = ""
    if kind == "rect":
        fields["width"] = num("inputs:width", min_value=0.0)
        fields["height"] = num("inputs:height", min_value=0.0)
        if fields["width"] == 0.0 or fields["height"] == 0.0:
            degenerate = "zero width or height"
        fields["texture_file"], fields["texture_data"] = _light_texture(prim, ctx)
    elif kind == "disk":
        fields["radius"] = num("inputs:radius", min_value=0.0)
        if fields["radius"] == 0.0:
            degenerate = "zero radius"
    elif kind == "sphere":
        fields["radius"] = num("inputs:radius", min_value=0.0)
        fields["treat_as_point"] = flag("treatAsPoint")
        if fields["radius"] == 0.0 and not fields["treat_as_point"]:
            degenerate = "zero radius (set treatAsPoint for a point light)"
    elif kind == "cylinder":
        fields["radius"] = num("inputs:radius", min_value=0.0)
        fields["length"] = num("inputs:length", min_value=0.0)
        fields["treat_as_line"] = flag("treatAsLine")
        if fields["length"] == 0.0 or (fields["radius"] == 0.0 and not fields["treat_as_line"]):
            degenerate = "zero length or radius"
    elif kind == "distant":
        fields["angle"] = num("inputs:angle", min_value=0.0)
    elif kind == "dome":
        fmt = str(ctx.get(prim, "inputs:texture:format", "automatic"))
        if fmt not in _SUPPORTED_FORMATS:
            raise ctx.error(f"texture format '{fmt}' is not supported (use latlong or automatic)",
                            prim, "inputs:texture:format")
        fields["texture_format"] = fmt
        fields["texture_file"], fields["texture_data"] = _light_texture(prim, ctx)
        fields["portals"], fields["portal_paths"] = read_portals(prim, ctx)

    if degenerate:
        ctx.warn(f"light-degenerate-{path}", f"{path}: {kind} light has {degenerate}; skipped")
        return None

    # ShapingAPI / ShadowAPI (renderer/usd/lux_shaping.py); unsupported light filters warn per light.
    fields["shaping"] = read_shaping(prim, ctx, kind)
    fields["shadow"] = read_shadow(prim, ctx)
    warn_light_filters(prim, ctx)

    to_world = ctx.finite_world(prim) if to_world is None else np.asarray(to_world, dtype=np.float64)
    if kind == "dome" and _pole_is_z(prim, ctx):
        to_world = to_world @ POLE_Z_FROM_Y

    return LightDesc(path=path, kind=kind, light_to_world=to_world,
                     estimator=read_estimator_settings(prim, ctx, is_dome=(kind == "dome")),
                     **fields)


# --------------------------------------------------------------------------------------
# Dome portals
# --------------------------------------------------------------------------------------
def read_portals(dome: Usd.Prim, ctx: ReadContext) -> tuple[np.ndarray | None, tuple]:
    """The DomeLight's ``portals`` targets -> ((K, 4, 4) world frames with width/height folded
    in, or None; their paths). A target that is missing or not a PortalLight is a StageError on
    the dome's ``portals``; a negative size is a StageError on the portal; a zero-size or
    invisible portal is skipped with a warning naming it."""
    rel = dome.GetRelationship("portals")
    targets = rel.GetForwardedTargets() if rel else []
    frames, paths = [], []
    for target in targets:
        portal = ctx.stage.GetPrimAtPath(target)
        if not portal:
            raise ctx.error(f"portal target <{target}> does not exist", dome, "portals")
        if not portal.IsA(UsdLux.PortalLight):
            kind = portal.GetTypeName() or "untyped prim"
            raise ctx.error(f"portal target <{target}> is a {kind}, not a PortalLight", dome, "portals")
        if not portal.IsActive():
            ctx.warn(f"portal-inactive-{target}", f"{dome.GetPath()}: portal {target} is inactive; ignored")
            continue
        if UsdGeom.Imageable(portal).ComputeVisibility(ctx.time) == UsdGeom.Tokens.invisible:
            ctx.warn(f"portal-invisible-{target}", f"{dome.GetPath()}: portal {target} is invisible; ignored")
            continue
        w = ctx.finite_float(portal, "inputs:width", ctx.get(portal, "inputs:width"), min_value=0.0)
        h = ctx.finite_float(portal, "inputs:height", ctx.get(portal, "inputs:height"), min_value=0.0)
        if w == 0.0 or h == 0.0:
            ctx.warn(f"portal-degenerate-{target}",
                     f"{dome.GetPath()}: portal {target} has zero width or height; ignored")
            continue
        frames.append(ctx.finite_world(portal) @ np.diag([w, h, 1.0, 1.0]))
        paths.append(str(target))
    if not frames:
        return None, ()
    return np.stack(frames), tuple(paths)


def warn_unused_portals(portal_paths: list[str], lights: list[LightDesc], ctx: ReadContext) -> None:
    """PortalLights no DomeLight targets guide nothing: say so (they emit nothing either way)."""
    used = {p for d in lights for p in d.portal_paths}
    for path in portal_paths:
        if path not in used:
            ctx.warn(f"portal-unused-{path}", f"{path}: PortalLight is not a target of any DomeLight's "
                                              f"portals; it has no effect")


# --------------------------------------------------------------------------------------
# Geometry (mesh) lights
# --------------------------------------------------------------------------------------
_SYNC_MODES = ("materialGlowTintsLight", "independent", "noMaterialResponse")


def read_geometry_light(prim: Usd.Prim, ctx: ReadContext, mesh: MeshDesc,
                        material: MaterialDesc) -> tuple[LightDesc | None, MaterialDesc | None]:
    """A gprim with LightAPI (MeshLightAPI) -> (LightDesc of kind 'mesh', replacement material).

    ``mesh`` is the gprim's world-space MeshDesc (its triangles become the light's, so light and
    surface are one shape); ``material`` its bound material. light:materialSyncMode (UsdLux):

    * materialGlowTintsLight (MeshLightAPI's fallback): the light's colour is inputs:color times
      the material's emissiveColor ("the color feeding the emission/glow input"). The glow is
      then *the light's* emission, seen by every ray (camera, BSDF and light samples alike: a
      path tracer needs one emission for MIS), so the material's own emission is removed to
      count it once. A material without emission (black emissiveColor, or none bound) leaves
      the colour untinted; a textured emissiveColor cannot tint a single-colour light: warned,
      untinted.
    * independent: the light's colour is inputs:color alone, and the material keeps its glow as
      ordinary surface emission: both add up (RenderMan's picture of this mode).
    * noMaterialResponse: the surface has no diffuse, specular or transmissive response and no
      glow: a black, opaque emitter (the renderer ends paths there).

    Returns (None, None) with a warning for a light with no triangles.
    """
    path = str(prim.GetPath())
    mode = str(ctx.get(prim, "light:materialSyncMode", "noMaterialResponse"))
    if mode not in _SYNC_MODES:
        raise ctx.error(f"'{mode}' is not one of {', '.join(_SYNC_MODES)}", prim, "light:materialSyncMode")
    tris = np.asarray(mesh.points, dtype=np.float64)[np.asarray(mesh.triangles, dtype=np.int64)]
    if tris.shape[0] == 0:
        ctx.warn(f"light-degenerate-{path}", f"{path}: mesh light has no triangles; skipped")
        return None, None
    fields = _light_api_fields(prim, ctx)
    new_material = None
    glow = material.emissive_color
    if mode == "materialGlowTintsLight":
        if glow.texture is not None:
            ctx.warn(f"mesh-light-textured-glow-{path}",
                     f"{path}: the bound material's emissiveColor is textured; a mesh light has one colour, "
                     f"so materialGlowTintsLight does not tint it (the texture's glow is dropped)")
        elif any(float(c) > 0.0 for c in glow.value):
            fields["color"] = tuple(float(a) * float(b) for a, b in zip(fields["color"], glow.value))
        if glow.texture is not None or any(float(c) != 0.0 for c in glow.value):
            new_material = dataclasses.replace(material, emissive_color=MaterialInput((0.0, 0.0, 0.0)))
    elif mode == "noMaterialResponse":
        new_material = MaterialDesc(path=f"{path}#noMaterialResponse", diffuse_color=MaterialInput((0.0, 0.0, 0.0)))
    fields["shaping"] = read_shaping(prim, ctx, "mesh")
    fields["shadow"] = read_shadow(prim, ctx)
    warn_light_filters(prim, ctx)
    light = LightDesc(path=path, kind="mesh", light_to_world=ctx.finite_world(prim),
                      estimator=read_estimator_settings(prim, ctx, is_dome=False),
                      mesh_path=mesh.path, mesh_triangles=tris, mesh_two_sided=bool(mesh.double_sided),
                      material_sync_mode=mode, **fields)
    return light, new_material


def _pole_is_z(prim: Usd.Prim, ctx: ReadContext) -> bool:
    """DomeLight keeps +Y as its pole on every stage; DomeLight_1 follows ``poleAxis``."""
    if not prim.IsA(UsdLux.DomeLight_1):
        return False
    pole = str(ctx.get(prim, "poleAxis", "scene"))
    if pole == "Z":
        return True
    if pole == "scene":
        return ctx.up_axis == str(UsdGeom.Tokens.z)
    return False


# --------------------------------------------------------------------------------------
# Light linking
# --------------------------------------------------------------------------------------
def _excluded_paths(collection: Usd.CollectionAPI, mesh_paths: list[str]) -> frozenset | None:
    """Mesh paths the collection does NOT include; None when it includes everything."""
    include_root = collection.GetIncludeRootAttr().Get()
    excludes = collection.GetExcludesRel().GetTargets() if collection.GetExcludesRel() else []
    if include_root and not excludes and collection.IsInRelationshipsMode():
        return None  # the default: everything, decided without touching any mesh path
    query = collection.ComputeMembershipQuery()
    out = frozenset(p for p in mesh_paths if not query.IsPathIncluded(p))
    return out or None


def resolve_light_links(light_prims: dict[str, Usd.Prim], lights: list[LightDesc],
                        mesh_paths: list[str]) -> list[LightDesc]:
    """Fill ``light_link_excludes`` / ``shadow_link_excludes`` of each light.

    light_prims: light path -> the prim whose collections apply (for the instances of a
    PointInstancer prototype light, that one prototype prim).
    """
    if not mesh_paths:
        return lights
    unique = list(dict.fromkeys(mesh_paths))
    out = []
    # Every instance of a PointInstancer prototype light maps to the same prim, whose
    # collections apply to all of them: resolve each prim once.
    resolved: dict[str, tuple] = {}
    for light in lights:
        prim = light_prims[light.path]
        key = str(prim.GetPath())
        if key not in resolved:
            api = UsdLux.LightAPI(prim)
            resolved[key] = (_excluded_paths(api.GetLightLinkCollectionAPI(), unique),
                             _excluded_paths(api.GetShadowLinkCollectionAPI(), unique))
        link, shadow = resolved[key]
        if link is None and shadow is None:
            out.append(light)
            continue
        out.append(dataclasses.replace(light, light_link_excludes=link, shadow_link_excludes=shadow))
    return out
