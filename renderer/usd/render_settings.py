"""UsdRender.Settings (+ its first RenderProduct) -> RenderSettingsDesc."""

from __future__ import annotations

from pxr import Sdf, Usd, UsdRender

from renderer.aov import DATA_TYPE_WIDTH, SOURCES, resolve_source
from renderer.description import RenderSettingsDesc, RenderVarDesc
from renderer.errors import SettingsError

from .common import ReadContext
from .estimator_api import read_adaptive, read_alpha_dome_transparent, read_default_estimator, read_light_sampler, read_pixel_filter

__all__ = ["find_settings_prim", "read_render_settings", "MAX_SIDE", "MAX_PIXELS"]

MAX_SIDE = 16384
MAX_PIXELS = 64 * 1024 * 1024
_CONFORM = ("expandAperture", "cropAperture", "adjustApertureWidth", "adjustApertureHeight",
            "adjustPixelAspectRatio")
_PURPOSES = ("default", "render", "proxy", "guide")


def find_settings_prim(ctx: ReadContext, requested: str | None) -> Usd.Prim | None:
    """The settings prim: ``settings`` argument, else the stage's ``renderSettingsPrimPath``
    metadata, else None (RenderSettingsDesc defaults)."""
    path = requested
    where = "settings"
    if not path:
        path = ctx.stage.GetMetadata("renderSettingsPrimPath") if ctx.stage.HasAuthoredMetadata(
            "renderSettingsPrimPath") else ""
        where = "renderSettingsPrimPath"
    if not path:
        # Like usdrecord: without a choice no RenderSettings applies; say so, since an
        # authored one being ignored is easy to miss. Only /Render, where UsdRender says render
        # prims live, is searched: a whole-stage traversal would cost a second pass.
        render_root = ctx.stage.GetPrimAtPath("/Render")
        found = [str(p.GetPath()) for p in Usd.PrimRange(render_root)
                 if p.IsA(UsdRender.Settings)] if render_root else []
        if found:
            ctx.warn("settings-unselected", f"RenderSettings {', '.join(found[:3])} ignored: no "
                                            "renderSettingsPrimPath metadata and no settings argument")
        return None
    if not Sdf.Path.IsValidPathString(path) or not Sdf.Path(path).IsAbsolutePath():
        raise ctx.error(f"'{path}' ({where}) is not an absolute prim path")
    prim = ctx.stage.GetPrimAtPath(path)
    if not prim:
        raise ctx.error(f"render settings prim does not exist ({where})", path)
    if not prim.IsA(UsdRender.Settings):
        raise ctx.error(f"prim is a '{prim.GetTypeName()}', not a RenderSettings ({where})", path)
    return prim


def _pick(name: str, settings: Usd.Prim, product: Usd.Prim | None):
    """(prim, attribute) holding the winning opinion: the product's where authored."""
    if product is not None:
        attr = product.GetAttribute(name)
        if attr and attr.HasAuthoredValue():
            return product, attr
    return settings, settings.GetAttribute(name)


def read_render_settings(ctx: ReadContext, settings: Usd.Prim | None,
                         purposes: tuple[str, ...] | None) -> tuple[RenderSettingsDesc, bool]:
    """Merge RenderSettings with its first RenderProduct.

    Returns (desc, disable_depth_of_field). ``purposes`` (the CLI's) replaces includedPurposes.
    """
    if settings is None:
        desc = RenderSettingsDesc()
        if purposes is not None:
            desc = RenderSettingsDesc(included_purposes=_check_purposes(ctx, tuple(purposes), None, ""))
        return desc, False

    product = None
    rel = settings.GetRelationship("products")
    targets = rel.GetForwardedTargets() if rel else []
    if targets:
        product = ctx.stage.GetPrimAtPath(targets[0])
        if not product or not product.IsA(UsdRender.Product):
            raise ctx.error(f"first product target {targets[0]} is not a RenderProduct", settings, "products")
        if len(targets) > 1:
            ctx.warn("render-products", f"{settings.GetPath()}: {len(targets)} RenderProducts; "
                                        f"illum renders only the first, {targets[0]}")

    def value(name: str):
        prim, attr = _pick(name, settings, product)
        return prim, (attr.Get(ctx.time) if attr else None)

    prim, res = value("resolution")
    w, h = int(res[0]), int(res[1])
    if w <= 0 or h <= 0 or w > MAX_SIDE or h > MAX_SIDE or w * h > MAX_PIXELS:
        raise ctx.error(f"resolution {w}x{h} is out of range (1..{MAX_SIDE} per side, "
                        f"at most {MAX_PIXELS // (1024 * 1024)} Mpixel)", prim, "resolution")

    prim, par = value("pixelAspectRatio")
    par = ctx.finite_float(prim, "pixelAspectRatio", par, positive=True)

    prim, conform = value("aspectRatioConformPolicy")
    conform = str(conform)
    if conform not in _CONFORM:
        raise ctx.error(f"'{conform}' is not one of {', '.join(_CONFORM)}", prim, "aspectRatioConformPolicy")

    prim, window = value("dataWindowNDC")
    window = ctx.finite_tuple(prim, "dataWindowNDC", window)
    if not (window[0] < window[2] and window[1] < window[3]):
        raise ctx.error(f"data window {window} is empty (need xmin < xmax and ymin < ymax)", prim, "dataWindowNDC")
    if min(window) < 0.0 or max(window) > 1.0:
        ctx.warn("overscan", f"{prim.GetPath()}: dataWindowNDC {window} extends outside [0, 1] (overscan); "
                             "illum renders only the part inside the image")

    camera = ""
    for p in (product, settings):
        crel = p.GetRelationship("camera") if p is not None else None
        if crel and crel.HasAuthoredTargets():
            cams = crel.GetForwardedTargets()
            if cams:
                camera = str(cams[0])
                break

    if purposes is not None:
        included = _check_purposes(ctx, tuple(purposes), None, "")
    else:
        included = _check_purposes(ctx, tuple(str(x) for x in settings.GetAttribute("includedPurposes").Get() or ()),
                                   settings, "includedPurposes")
    binding = tuple(str(x) for x in (settings.GetAttribute("materialBindingPurposes").Get() or ()))
    for b in binding:
        if b not in ("full", "preview", ""):
            raise ctx.error(f"'{b}' is not a material binding purpose (full, preview, '')",
                            settings, "materialBindingPurposes")

    product_name = ""
    if product is not None:
        name = product.GetAttribute("productName").Get(ctx.time)
        product_name = str(name or "")

    _prim, dof_off = value("disableDepthOfField")
    space = settings.GetAttribute("renderingColorSpace")
    if space and space.HasAuthoredValue() and str(space.Get()) not in ("lin_rec709", "lin_rec709_scene"):
        ctx.warn("rendering-color-space", f"{settings.GetPath()}: renderingColorSpace '{space.Get()}' is "
                                          "ignored; illum renders linear Rec.709")

    pixel_filter, pixel_filter_width, pixel_filter_mode = read_pixel_filter(settings, ctx)
    render_vars = read_render_vars(ctx, product) if product is not None else ()
    noise_threshold, adaptive_min_spp = read_adaptive(settings, ctx)
    desc = RenderSettingsDesc(
        path=str(settings.GetPath()),
        resolution=(w, h),
        pixel_aspect_ratio=par,
        aspect_ratio_conform_policy=conform,
        data_window_ndc=window,
        camera=camera,
        included_purposes=included,
        material_binding_purposes=binding,
        product_name=product_name,
        light_sampler=read_light_sampler(settings, ctx),
        estimator=read_default_estimator(settings, ctx),
        pixel_filter=pixel_filter,
        pixel_filter_width=pixel_filter_width,
        pixel_filter_mode=pixel_filter_mode,
        render_vars=render_vars,
        alpha_dome_transparent=read_alpha_dome_transparent(settings, ctx),
        noise_threshold=noise_threshold,
        adaptive_min_spp=adaptive_min_spp,
    )
    return desc, bool(dof_off)


def read_render_vars(ctx: ReadContext, product: Usd.Prim) -> tuple[RenderVarDesc, ...]:
    """The product's orderedVars as RenderVarDesc, in order. A target that is not a RenderVar,
    or a dataType whose component count differs from what the source gives, is an error naming
    the prim; a var illum does not compute (an LPE, an arbitrary primvar, an unknown name) gets
    one warning naming it and is left out of the file."""
    rel = product.GetRelationship("orderedVars")
    out = []
    for target in (rel.GetForwardedTargets() if rel else []):
        var = ctx.stage.GetPrimAtPath(target)
        if not var or not var.IsA(UsdRender.Var):
            raise ctx.error(f"orderedVars target {target} is not a RenderVar", product, "orderedVars")
        rv = UsdRender.Var(var)
        source_name = str(rv.GetSourceNameAttr().Get() or "")
        source_type = str(rv.GetSourceTypeAttr().Get() or "raw")
        data_type = str(rv.GetDataTypeAttr().Get() or "")
        source = resolve_source(source_name, source_type) or ""
        if not source:
            ctx.warn(f"render-var:{target}", f"{target}: RenderVar {source_type} '{source_name}' is not supported "
                                             f"(illum computes {', '.join(SOURCES)}); it is not written")
        elif source in ("color", "alpha") or data_type not in DATA_TYPE_WIDTH:
            pass  # the beauty's own channels; unknown data types are written as float
        elif DATA_TYPE_WIDTH[data_type] != len(SOURCES[source]):
            raise ctx.error(f"dataType {data_type} has {DATA_TYPE_WIDTH[data_type]} components, but "
                            f"'{source_name}' gives {len(SOURCES[source])}", var, "dataType")
        out.append(RenderVarDesc(name=var.GetName(), path=str(target), source_name=source_name,
                                 source_type=source_type, data_type=data_type, source=source))
    return tuple(out)


def _check_purposes(ctx: ReadContext, purposes: tuple[str, ...], prim, attr: str) -> tuple[str, ...]:
    """Validate purpose tokens; a bad CLI value (prim None) is a SettingsError, not a stage one."""
    for p in purposes:
        if p not in _PURPOSES:
            message = f"'{p}' is not a purpose ({', '.join(_PURPOSES)})"
            if prim is None:
                raise SettingsError(message, attribute="purposes")
            raise ctx.error(message, prim, attr)
    return purposes
