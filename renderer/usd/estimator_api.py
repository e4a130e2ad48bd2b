"""Reading illum's own schema attributes (usd_schemas/schema.usda).

The fallbacks below equal the schema's, and values are read with ``GetAttribute`` +
``HasAuthoredValue``: whether or not the plugin got registered in this process, a stage renders
the same. ``allowedTokens`` is only metadata to USD, so the reader enforces it.
"""

from __future__ import annotations

from pxr import Usd, UsdLux

from renderer.description import EstimatorSettings
from renderer.errors import SettingsError
from renderer.pixel_filter import DEFAULT_FILTER, DEFAULT_MODE, FILTERS, MODES, check_filter

from .common import ReadContext

__all__ = [
    "LIGHT_API",
    "RENDER_SETTINGS_API",
    "ESTIMATORS",
    "CV_ALPHAS",
    "MIS_HEURISTICS",
    "LIGHT_SAMPLERS",
    "read_estimator_settings",
    "read_light_sampler",
    "read_default_estimator",
    "read_pixel_filter",
    "read_alpha_dome_transparent",
    "read_adaptive",
    "has_light_api",
    "check_light_api_target",
]

LIGHT_API = "IllumLightAPI"
RENDER_SETTINGS_API = "IllumRenderSettingsAPI"

ESTIMATORS = ("mis", "lightSampling", "bsdfSampling", "controlVariate", "ratio", "auto")
CV_ALPHAS = ("one", "averageVisibility", "averageVisibilityUnbiased")
MIS_HEURISTICS = ("power", "balance")
LIGHT_SAMPLERS = ("auto", "exhaustive", "uniform", "power", "bvh")

_ESTIMATOR = ("illum:estimator", "mis", ESTIMATORS)
_CV_ALPHA = ("illum:cv:alpha", "averageVisibilityUnbiased", CV_ALPHAS)
_MIS_HEURISTIC = ("illum:mis:heuristic", "power", MIS_HEURISTICS)
_SAMPLES = "illum:samples"
_DOME_IRRADIANCE = "illum:dome:irradiance"
_LIGHT_SAMPLER = ("illum:lightSampler", "auto", LIGHT_SAMPLERS)
_PIXEL_FILTER = ("illum:pixelFilter", DEFAULT_FILTER, FILTERS)
_PIXEL_FILTER_MODE = ("illum:pixelFilter:mode", DEFAULT_MODE, MODES)
_PIXEL_FILTER_WIDTH = "illum:pixelFilter:width"
_ALPHA_DOME_TRANSPARENT = "illum:alpha:domeTransparent"
_NOISE_THRESHOLD = "illum:adaptive:noiseThreshold"
_ADAPTIVE_MIN_SPP = "illum:adaptive:minSpp"


def _authored(prim: Usd.Prim, name: str, ctx: ReadContext):
    """Authored value of ``name`` at the read time, or None."""
    attr = prim.GetAttribute(name)
    if attr and attr.HasAuthoredValue():
        return attr.Get(ctx.time)
    return None


def _token(prim: Usd.Prim, ctx: ReadContext, spec: tuple[str, str, tuple[str, ...]]) -> tuple[str, bool]:
    name, fallback, allowed = spec
    value = _authored(prim, name, ctx)
    if value is None:
        return fallback, False
    value = str(value)
    if value not in allowed:
        raise ctx.error(f"'{value}' is not one of {', '.join(allowed)}", prim, name)
    return value, True


def has_light_api(prim: Usd.Prim) -> bool:
    """Is IllumLightAPI applied, in the composed schema list or (plugin unregistered) in the
    authored ``apiSchemas`` list op?"""
    if LIGHT_API in prim.GetAppliedSchemas():
        return True
    if prim.HasAuthoredMetadata("apiSchemas"):
        op = prim.GetMetadata("apiSchemas")
        if op is not None and LIGHT_API in op.ApplyOperations([]):
            return True
    return False


def check_light_api_target(prim: Usd.Prim, ctx: ReadContext) -> None:
    """StageError when IllumLightAPI sits on a prim that is not a light."""
    if not prim.HasAPI(UsdLux.LightAPI) and has_light_api(prim):
        raise ctx.error(f"{LIGHT_API} is applied to a prim that is not a light "
                        f"(type '{prim.GetTypeName()}', no UsdLuxLightAPI)", prim, "apiSchemas")


def read_estimator_settings(prim: Usd.Prim, ctx: ReadContext, *, is_dome: bool) -> EstimatorSettings:
    """IllumLightAPI opinions of one light prim (schema fallbacks where unauthored)."""
    estimator, estimator_authored = _token(prim, ctx, _ESTIMATOR)
    cv_alpha, alpha_authored = _token(prim, ctx, _CV_ALPHA)
    heuristic, _ = _token(prim, ctx, _MIS_HEURISTIC)

    samples = 1
    raw = _authored(prim, _SAMPLES, ctx)
    if raw is not None:
        try:
            samples = int(raw)
        except (TypeError, ValueError):
            raise ctx.error(f"'{raw}' is not an integer", prim, _SAMPLES) from None
        if samples < 1:
            raise ctx.error(f"value is {samples} (must be >= 1)", prim, _SAMPLES)

    if (samples < 2 and cv_alpha in ("averageVisibility", "averageVisibilityUnbiased")
            and (estimator == "controlVariate" or alpha_authored)):
        ctx.warn("cv-alpha-one-sample",
                 f"{prim.GetPath()}: illum:cv:alpha '{cv_alpha}' needs illum:samples >= 2; "
                 "with 1 sample the renderer uses alpha = 1")

    irradiance = ""
    raw = _authored(prim, _DOME_IRRADIANCE, ctx)
    if raw is not None:
        if is_dome:
            irradiance = ctx.resolve_asset(prim, _DOME_IRRADIANCE, raw)
        elif getattr(raw, "path", raw):
            ctx.warn("dome-irradiance-not-dome",
                     f"{prim.GetPath()}: {_DOME_IRRADIANCE} is only meaningful on DomeLights; ignored")

    return EstimatorSettings(estimator=estimator, estimator_authored=estimator_authored, cv_alpha=cv_alpha,
                             samples=samples,
                             mis_heuristic=heuristic, dome_irradiance=irradiance)


def _authored_token(prim: Usd.Prim, ctx: ReadContext, spec: tuple[str, str, tuple[str, ...]]) -> str:
    """The validated token where authored, else '' (the renderer applies the schema fallback)."""
    value, authored = _token(prim, ctx, spec)
    return value if authored else ""


def read_light_sampler(prim: Usd.Prim, ctx: ReadContext) -> str:
    """IllumRenderSettingsAPI ``illum:lightSampler``: '' when unauthored (the renderer chooses,
    as the schema fallback 'auto' says), else the validated token."""
    return _authored_token(prim, ctx, _LIGHT_SAMPLER)


def read_default_estimator(prim: Usd.Prim, ctx: ReadContext) -> str:
    """IllumRenderSettingsAPI ``illum:estimator``, the stage-wide default for lights whose own
    estimator is unauthored: '' when unauthored (the schema fallback), else the validated token."""
    return _authored_token(prim, ctx, _ESTIMATOR)
def read_pixel_filter(prim: Usd.Prim, ctx: ReadContext) -> tuple[str, float, str]:
    """IllumRenderSettingsAPI ``illum:pixelFilter``, ``illum:pixelFilter:width`` and
    ``illum:pixelFilter:mode``: (filter, radius in pixels, mode), '' / 0.0 where unauthored (the
    renderer's defaults, renderer/pixel_filter.py, apply), else validated."""
    name = _authored_token(prim, ctx, _PIXEL_FILTER)
    width = 0.0
    raw = _authored(prim, _PIXEL_FILTER_WIDTH, ctx)
    if raw is not None:
        try:
            _, width = check_filter(name or DEFAULT_FILTER, raw)
        except SettingsError as e:
            raise ctx.error(e.message, prim, _PIXEL_FILTER_WIDTH) from None
    return name, width, _authored_token(prim, ctx, _PIXEL_FILTER_MODE)


def read_alpha_dome_transparent(prim: Usd.Prim, ctx: ReadContext) -> bool:
    """IllumRenderSettingsAPI ``illum:alpha:domeTransparent`` (fallback False): whether the dome
    seen directly is transparent in the beauty's alpha (renderer/aov.py)."""
    raw = _authored(prim, _ALPHA_DOME_TRANSPARENT, ctx)
    if raw is None:
        return False
    if not isinstance(raw, bool):
        raise ctx.error(f"must be a bool, got {raw!r}", prim, _ALPHA_DOME_TRANSPARENT)
    return raw


def read_adaptive(prim: Usd.Prim, ctx: ReadContext) -> tuple[float, int]:
    """IllumRenderSettingsAPI ``illum:adaptive:noiseThreshold`` and ``illum:adaptive:minSpp``:
    (threshold, min spp), 0.0 / 0 where unauthored (adaptive sampling off; the renderer's
    default minimum, renderer/adaptive.py), else validated: a threshold in [0, 1], a min spp >= 1."""
    threshold = _authored(prim, _NOISE_THRESHOLD, ctx)
    if threshold is None:
        threshold = 0.0
    elif isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 <= threshold <= 1.0:
        raise ctx.error(f"must be a number in [0, 1], got {threshold!r}", prim, _NOISE_THRESHOLD)
    min_spp = _authored(prim, _ADAPTIVE_MIN_SPP, ctx)
    if min_spp is None:
        min_spp = 0
    elif isinstance(min_spp, bool) or not isinstance(min_spp, int) or min_spp < 1:
        raise ctx.error(f"must be an integer >= 1, got {min_spp!r}", prim, _ADAPTIVE_MIN_SPP)
    return float(threshold), int(min_spp)
