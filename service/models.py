"""Request bodies, their validation against the server's limits, and the mapping of job settings
onto ``renderer.render.RenderOptions``.

Settings are validated once, at submission, and stored normalised (e.g. ``"estimator": "mis"``
becomes ``{"": "mis"}``), so the worker's mapping cannot fail on shape, and an idempotent
resubmission compares equal however the client spelled it.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from typing import Annotated, Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, StrictInt, StringConstraints, ValidationError, field_validator

from .config import Limits
from .paths import InputError

__all__ = ["JobCreate", "RenderSettings", "PreconvolveSettings", "validate_settings", "render_options",
           "request_hash", "DEFAULT_SPP"]

DEFAULT_SPP = 64
_LIGHT_KEY = "a light prim path starting with '/', or '' for all lights"
MAX_PER_LIGHT_ENTRIES = 4096
# A prim path: starts with '/', no control characters (a NUL would cut the path short in C++).
PRIM_PATH = r"^/[^\x00-\x1f\x7f]*$"
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def _per_light(value, field: str, check) -> dict:
    """`TOKEN` (all lights) or {"/Light": TOKEN, "": TOKEN} -> dict, each value checked."""
    table = value if isinstance(value, dict) else {"": value}
    if len(table) > MAX_PER_LIGHT_ENTRIES:
        raise ValueError(f"has {len(table)} entries, more than the limit of {MAX_PER_LIGHT_ENTRIES}")
    out = {}
    for key, v in table.items():
        if (not isinstance(key, str) or (key and not key.startswith("/")) or len(key) > 1024
                or _CONTROL.search(key)):
            raise ValueError(f"key {key!r} must be {_LIGHT_KEY}")
        out[key] = check(v)
    return out


class RenderSettings(BaseModel):
    """Settings of a ``render`` job; each maps onto the ``illum render`` flag of the same name."""

    model_config = ConfigDict(extra="forbid")

    spp: Optional[StrictInt] = Field(None, ge=1, description="samples per pixel (default 64 unless time_budget is given)")
    time_budget: Optional[float] = Field(None, gt=0, description="seconds of rendering (load and BVH build excluded)")
    resolution: Optional[tuple[StrictInt, StrictInt]] = Field(None, description="[width, height] override")
    camera: Optional[str] = Field(None, max_length=1024, pattern=PRIM_PATH, description="camera prim path")
    settings_prim: Optional[str] = Field(None, max_length=1024, pattern=PRIM_PATH,
                                         description="RenderSettings prim path")
    frame: Optional[float] = Field(None, description="time code")
    purposes: Optional[list[Annotated[str, StringConstraints(max_length=64, pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]]] = \
        Field(None, max_length=16, description="included purposes (tokens such as default, render, proxy)")
    seed: StrictInt = Field(0, ge=0, le=2**31 - 1)
    max_depth: StrictInt = Field(8, ge=0, le=256)
    rr_depth: StrictInt = Field(3, ge=0, le=256)
    light_sampler: str = Field("auto", max_length=64, description="auto, or a lighting service the renderer has "
                                                                  "(renderer.light_samplers.SAMPLERS)")
    estimator: Union[str, dict[str, str]] = Field(default_factory=dict,
                                                  description="token for all lights, or {light path: token}")
    cv_alpha: Union[str, dict[str, str]] = Field(default_factory=dict)
    light_samples: Union[StrictInt, dict[str, StrictInt]] = Field(default_factory=dict)

    @field_validator("frame", "time_budget")
    @classmethod
    def _finite(cls, v):
        if v is not None and not math.isfinite(v):
            raise ValueError("must be finite")
        return v

    @field_validator("resolution")
    @classmethod
    def _positive(cls, v):
        if v is not None and (v[0] < 1 or v[1] < 1):
            raise ValueError("width and height must be positive")
        return v

    @field_validator("light_sampler")
    @classmethod
    def _sampler(cls, v):
        from renderer.light_samplers import SAMPLERS

        names = ("auto", *sorted(SAMPLERS))
        if v not in names:
            raise ValueError(f"{v!r} is not one of {', '.join(names)}")
        return v

    @field_validator("estimator")
    @classmethod
    def _estimator(cls, v):
        from renderer.estimators import TOKENS

        def check(t):
            if t not in TOKENS:
                raise ValueError(f"{t!r} is not one of {', '.join(TOKENS)}")
            return t
        return _per_light(v, "estimator", check)

    @field_validator("cv_alpha")
    @classmethod
    def _alpha(cls, v):
        from renderer.estimators import ALPHAS

        def check(t):
            if t not in ALPHAS:
                raise ValueError(f"{t!r} is not one of {', '.join(ALPHAS)}")
            return t
        return _per_light(v, "cv_alpha", check)

    @field_validator("light_samples")
    @classmethod
    def _samples(cls, v):
        def check(n):
            if not isinstance(n, int) or not 1 <= n <= 4096:
                raise ValueError(f"{n!r} must be an integer in [1, 4096]")
            return n
        return _per_light(v, "light_samples", check)


class PreconvolveSettings(BaseModel):
    """Settings of a ``preconvolve`` job (renderer.preconvolve: dome texture → irradiance map)."""

    model_config = ConfigDict(extra="forbid")

    size: StrictInt = Field(128, ge=4, description="output width in texels, even (the map is size x size/2)")
    method: Literal["exact", "sh"] = Field("exact", description="exact: the analytic cosine convolution; "
                                                                 "sh: the order-2 spherical-harmonics approximation")
    sanitize: bool = Field(False, description="clamp NaN/negative/infinite texels instead of failing")

    @field_validator("size")
    @classmethod
    def _even(cls, v):
        if v % 2:
            raise ValueError("must be even (the output is size x size/2)")
        return v


class JobCreate(BaseModel):
    """Body of ``POST /jobs``. Exactly one of ``stage`` (a path under the stage root) and
    ``upload`` (an id from ``POST /uploads``)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{
        "kind": "render", "stage": "cornell_box.usda",
        "settings": {"spp": 64, "resolution": [640, 360], "time_budget": 30}, "priority": 50,
        "idempotency_key": "shot010-v3"}]})

    kind: Literal["render", "preconvolve"] = "render"
    stage: Optional[str] = Field(None, max_length=4096)
    upload: Optional[str] = Field(None, max_length=200)
    settings: dict = Field(default_factory=dict)
    priority: StrictInt = Field(50, ge=0, le=100, description="0-100, higher runs first")
    idempotency_key: Optional[str] = Field(None, min_length=1, max_length=255,
                                           description="same key and body -> the same job, never a duplicate")
    max_attempts: Optional[StrictInt] = Field(None, ge=1, le=16)


def _validation_error(prefix: str, err: ValidationError) -> InputError:
    e = err.errors()[0]
    loc = ".".join(str(p) for p in (prefix, *e["loc"]))
    msg = e["msg"]
    return InputError(422, loc, msg)


def validate_settings(kind: str, settings: dict, limits: Limits) -> dict:
    """Validate and normalise a job's settings against the schema and the server's limits.
    Returns the canonical dict stored in the job; raises InputError (422, field named)."""
    if kind == "render":
        try:
            s = RenderSettings.model_validate(settings)
        except ValidationError as err:
            raise _validation_error("settings", err) from None
        if s.spp is not None and s.spp > limits.max_spp:
            raise InputError(422, "settings.spp", f"{s.spp} exceeds the server limit of {limits.max_spp}")
        if s.time_budget is not None and s.time_budget > limits.max_time_budget:
            raise InputError(422, "settings.time_budget",
                             f"{s.time_budget:g} s exceeds the server limit of {limits.max_time_budget:g} s")
        if s.resolution is not None:
            w, h = s.resolution
            if w > limits.max_side or h > limits.max_side:
                raise InputError(422, "settings.resolution",
                                 f"{w}x{h} exceeds the server limit of {limits.max_side} pixels per side")
            if w * h > limits.max_pixels:
                raise InputError(422, "settings.resolution",
                                 f"{w}x{h} exceeds the server limit of {limits.max_pixels} pixels")
        out = s.model_dump()
        if out["spp"] is None and out["time_budget"] is None:
            out["spp"] = DEFAULT_SPP
        out["resolution"] = list(out["resolution"]) if out["resolution"] else None
        return out
    if kind == "preconvolve":
        try:
            p = PreconvolveSettings.model_validate(settings)
        except ValidationError as err:
            raise _validation_error("settings", err) from None
        if p.size > limits.max_preconvolve_size:
            raise InputError(422, "settings.size",
                             f"{p.size} exceeds the server limit of {limits.max_preconvolve_size}")
        return p.model_dump()
    raise InputError(422, "kind", f"unknown kind {kind!r}")


def request_hash(kind: str, stage_name: str, settings: dict, priority: int, max_attempts: int) -> str:
    """Digest of a normalised request: an idempotency key replays only for an equal request."""
    blob = json.dumps([kind, stage_name, settings, priority, max_attempts], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def render_options(settings: dict, *, threads: int | None = None, max_time: float | None = None):
    """Stored (normalised) settings -> RenderOptions. ``max_time`` caps the time budget, so a
    job with only an spp target still cannot run forever."""
    from renderer.render import RenderOptions

    budget = settings.get("time_budget")
    if max_time is not None:
        budget = min(budget, max_time) if budget is not None else max_time
    res = settings.get("resolution")
    return RenderOptions(
        spp=settings.get("spp"),
        time_budget=budget,
        resolution=(int(res[0]), int(res[1])) if res else None,
        camera=settings.get("camera"),
        settings=settings.get("settings_prim"),
        frame=settings.get("frame"),
        purposes=tuple(settings["purposes"]) if settings.get("purposes") else None,
        seed=int(settings.get("seed", 0)),
        threads=threads,
        max_depth=int(settings.get("max_depth", 8)),
        rr_depth=int(settings.get("rr_depth", 3)),
        light_sampler=settings.get("light_sampler", "auto"),
        estimator=dict(settings.get("estimator") or {}),
        cv_alpha=dict(settings.get("cv_alpha") or {}),
        light_samples={k: int(v) for k, v in (settings.get("light_samples") or {}).items()},
    )


def settings_from_options(opt) -> dict:
    """RenderOptions (e.g. from ``illum submit`` flags) -> a settings dict for POST /jobs,
    leaving out what equals the default so the server's defaults apply."""
    out: dict = {}
    if opt.spp is not None:
        out["spp"] = int(opt.spp)
    if opt.time_budget is not None:
        out["time_budget"] = float(opt.time_budget)
    if opt.resolution is not None:
        out["resolution"] = [int(opt.resolution[0]), int(opt.resolution[1])]
    if opt.camera:
        out["camera"] = opt.camera
    if opt.settings:
        out["settings_prim"] = opt.settings
    if opt.frame is not None:
        out["frame"] = float(opt.frame)
    if opt.purposes:
        out["purposes"] = list(opt.purposes)
    if opt.seed:
        out["seed"] = int(opt.seed)
    if opt.max_depth != 8:
        out["max_depth"] = int(opt.max_depth)
    if opt.rr_depth != 3:
        out["rr_depth"] = int(opt.rr_depth)
    if opt.light_sampler and opt.light_sampler != "auto":
        out["light_sampler"] = opt.light_sampler
    for name in ("estimator", "cv_alpha", "light_samples"):
        table = getattr(opt, name)
        if table:
            out[name] = dict(table)
    return out
