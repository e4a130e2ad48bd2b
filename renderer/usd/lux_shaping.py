"""UsdLux ShapingAPI and ShadowAPI -> ShapingDesc / ShadowDesc (validated), and light filters.

A light is read as shaped when it has ShapingAPI applied *or* authors any ``inputs:shaping:*``
attribute (the UsdLux user doc's own CylinderLight example authors ``shaping:cone:angle``
without applying the API); unauthored inputs take the schema's fallbacks. The same rule holds
for ShadowAPI and ``inputs:shadow:*``.

Validation (errors name the prim and the attribute; warnings are said once per light):

* any NaN or infinite value: error.
* ``shaping:cone:angle`` outside [0, 180] degrees: error (an off-axis angle cannot exceed 180).
* ``shaping:cone:softness`` outside [0, 1]: clamped with a warning ("Values outside of the
  [0, 1] range are clamped to the range", the doc).
* ``shaping:focus`` < 0: ignored with a warning ("Values < 0 are ignored", the doc).
* ``shaping:focusTint`` and ``shadow:color`` with a negative component: error.
* ``shaping:ies:file``: resolved like every asset; a missing file, or a malformed or
  unsupported IES file, is an error naming the file and its line (renderer/lights/ies.py).
* ``shadow:falloffGamma`` < 0: error; ``shadow:falloff`` larger than ``shadow:distance``:
  clamped to it with a warning ("The falloff zone cannot exceed the maximum shadow distance");
  a falloff without a distance limit has no effect (warning).
* ShapingAPI on DistantLight / DomeLight: ignored with a warning (no emission point).
"""

from __future__ import annotations

from pxr import Usd, UsdLux

from renderer.description import ShadowDesc, ShapingDesc

from .common import ReadContext

__all__ = ["read_shaping", "read_shadow", "warn_light_filters"]

_SHAPING_PREFIX = "inputs:shaping:"
_SHADOW_PREFIX = "inputs:shadow:"


def _authored_with_prefix(prim: Usd.Prim, prefix: str) -> bool:
    return any(a.GetName().startswith(prefix) and a.HasAuthoredValue() for a in prim.GetAttributes())


def read_shaping(prim: Usd.Prim, ctx: ReadContext, kind: str) -> ShapingDesc | None:
    """The light's ShapingDesc, or None when it has no ShapingAPI and no shaping input."""
    if not (prim.HasAPI(UsdLux.ShapingAPI) or _authored_with_prefix(prim, _SHAPING_PREFIX)):
        return None
    path = str(prim.GetPath())
    if kind in ("distant", "dome"):
        ctx.warn(f"shaping-infinite-{path}",
                 f"{path}: ShapingAPI on a {kind} light is ignored (it has no emission point to shape)")
        return None

    def num(name: str, fallback: float) -> float:
        return ctx.finite_float(prim, name, ctx.get(prim, name, fallback))

    focus = num("inputs:shaping:focus", 0.0)
    if focus < 0.0:
        ctx.warn(f"shaping-focus-{path}", f"{path}: shaping:focus {focus:g} < 0 is ignored (UsdLux: "
                                          f"values < 0 are ignored)")
    tint = ctx.finite_tuple(prim, "inputs:shaping:focusTint",
                            ctx.get(prim, "inputs:shaping:focusTint", (0.0, 0.0, 0.0)))
    if any(c < 0.0 for c in tint):
        raise ctx.error(f"value {tint} has a negative component", prim, "inputs:shaping:focusTint")
    angle = num("inputs:shaping:cone:angle", 90.0)
    if not 0.0 <= angle <= 180.0:
        raise ctx.error(f"cone angle {angle:g} degrees is outside [0, 180]", prim, "inputs:shaping:cone:angle")
    softness = num("inputs:shaping:cone:softness", 0.0)
    if not 0.0 <= softness <= 1.0:
        clamped = min(max(softness, 0.0), 1.0)
        ctx.warn(f"shaping-softness-{path}", f"{path}: shaping:cone:softness {softness:g} is clamped to "
                                             f"{clamped:g} (UsdLux: values outside [0, 1] are clamped)")
        softness = clamped
    ies_attr = "inputs:shaping:ies:file"
    ignored = "the light is not IES-shaped"
    asset = ctx.read_asset(prim, ies_attr, ctx.get(prim, ies_attr), ignored)
    ies_file, profile = "", None
    if asset is not None:
        from renderer.lights.ies import IesError, load_ies

        try:
            profile = load_ies(*asset)
            ies_file = asset[0]
        except IesError as exc:
            ctx.asset_unusable(prim, ies_attr, asset[0], f"cannot read IES profile ({exc.message})", ignored)
    scale = num("inputs:shaping:ies:angleScale", 0.0)
    normalize = bool(ctx.get(prim, "inputs:shaping:ies:normalize", False))
    return ShapingDesc(focus=focus, focus_tint=tint, cone_angle=angle, cone_softness=softness,
                       ies_file=ies_file, ies_angle_scale=scale, ies_normalize=normalize, ies_profile=profile)


def read_shadow(prim: Usd.Prim, ctx: ReadContext) -> ShadowDesc | None:
    """The light's ShadowDesc, or None when shadows are the default (full, black, unlimited)."""
    if not (prim.HasAPI(UsdLux.ShadowAPI) or _authored_with_prefix(prim, _SHADOW_PREFIX)):
        return None
    path = str(prim.GetPath())

    def num(name: str, fallback: float) -> float:
        return ctx.finite_float(prim, name, ctx.get(prim, name, fallback))

    enable = bool(ctx.get(prim, "inputs:shadow:enable", True))
    color = ctx.finite_tuple(prim, "inputs:shadow:color", ctx.get(prim, "inputs:shadow:color", (0.0, 0.0, 0.0)))
    if any(c < 0.0 for c in color):
        raise ctx.error(f"value {color} has a negative component", prim, "inputs:shadow:color")
    distance = num("inputs:shadow:distance", -1.0)
    falloff = num("inputs:shadow:falloff", -1.0)
    gamma = num("inputs:shadow:falloffGamma", 1.0)
    if gamma < 0.0:
        raise ctx.error(f"falloffGamma {gamma:g} is negative", prim, "inputs:shadow:falloffGamma")
    if falloff > 0.0 and not distance > 0.0:
        ctx.warn(f"shadow-falloff-{path}", f"{path}: shadow:falloff {falloff:g} has no effect without a "
                                           f"shadow:distance limit")
        falloff = -1.0
    elif falloff > distance > 0.0:
        ctx.warn(f"shadow-falloff-{path}", f"{path}: shadow:falloff {falloff:g} exceeds shadow:distance "
                                           f"{distance:g} and is clamped to it")
        falloff = distance
    desc = ShadowDesc(enable=enable, color=color, distance=distance, falloff=falloff, falloff_gamma=gamma)
    return None if desc.is_default else desc


def _filter_type(target: Usd.Prim) -> str:
    """A light filter's type name for messages ('missing prim' when the target does not exist)."""
    if not target:
        return "missing prim"
    return target.GetTypeName() or "untyped prim"


def warn_light_filters(prim: Usd.Prim, ctx: ReadContext) -> None:
    """``light:filters`` are read; illum renders no filter type yet, so each light with filters
    gets one warning naming them (never a silent difference)."""
    rel = prim.GetRelationship("light:filters")
    targets = rel.GetTargets() if rel else []
    if targets:
        path = str(prim.GetPath())
        # Each filter with its type, so the warning says what would have changed the light.
        names = ", ".join(f"{t} ({_filter_type(prim.GetStage().GetPrimAtPath(t))})" for t in targets)
        ctx.warn(f"light-filters-{path}", f"{path}: light filters are not supported and are ignored: {names}")
