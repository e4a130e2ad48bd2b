"""UsdLux -> LightDesc: raw inputs, world frame, dome pole correction, light linking.

The reader does no radiometry (intensity * 2^exposure, normalize, colour temperature are
the render core's job); it only validates values and resolves frames, files and links.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pxr import Usd, UsdGeom, UsdLux

from renderer.description import LightDesc

from .common import ReadContext
from .estimator_api import read_estimator_settings

__all__ = ["read_light", "resolve_light_links", "POLE_Z_FROM_Y"]

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


def read_light(prim: Usd.Prim, ctx: ReadContext) -> LightDesc | None:
    """One light prim (already known to have LightAPI and to be visible) -> LightDesc.

    Returns None, with a warning, for light types illum does not render yet and for
    degenerate lights (zero size).
    """
    kind = _kind_of(prim)
    path = str(prim.GetPath())
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

    degenerate = ""
    if kind == "rect":
        fields["width"] = num("inputs:width", min_value=0.0)
        fields["height"] = num("inputs:height", min_value=0.0)
        if fields["width"] == 0.0 or fields["height"] == 0.0:
            degenerate = "zero width or height"
        fields["texture_file"] = ctx.resolve_asset(prim, "inputs:texture:file",
                                                   ctx.get(prim, "inputs:texture:file"))
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
        fields["texture_file"] = ctx.resolve_asset(prim, "inputs:texture:file",
                                                   ctx.get(prim, "inputs:texture:file"))

    if degenerate:
        ctx.warn(f"light-degenerate-{path}", f"{path}: {kind} light has {degenerate}; skipped")
        return None

    for api, label in ((UsdLux.ShapingAPI, "ShapingAPI"), (UsdLux.ShadowAPI, "ShadowAPI")):
        if prim.HasAPI(api):
            ctx.warn(f"light-{label}", f"{path}: UsdLux {label} is not supported yet and is ignored")
    filters = prim.GetRelationship("light:filters")
    if filters and filters.GetTargets():
        ctx.warn("light-filters", f"{path}: light filters are not supported yet and are ignored")

    to_world = ctx.finite_world(prim)
    if kind == "dome" and _pole_is_z(prim, ctx):
        to_world = to_world @ POLE_Z_FROM_Y

    return LightDesc(path=path, kind=kind, light_to_world=to_world,
                     estimator=read_estimator_settings(prim, ctx, is_dome=(kind == "dome")),
                     **fields)


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
    """Fill ``light_link_excludes`` / ``shadow_link_excludes`` of each light."""
    if not mesh_paths:
        return lights
    unique = list(dict.fromkeys(mesh_paths))
    out = []
    for light in lights:
        api = UsdLux.LightAPI(light_prims[light.path])
        link = _excluded_paths(api.GetLightLinkCollectionAPI(), unique)
        shadow = _excluded_paths(api.GetShadowLinkCollectionAPI(), unique)
        if link is None and shadow is None:
            out.append(light)
            continue
        out.append(dataclasses.replace(light, light_link_excludes=link, shadow_link_excludes=shadow))
    return out
