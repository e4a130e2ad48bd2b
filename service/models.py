"""Request bodies, their validation against the server's limits, and the mapping of job settings
onto ``renderer.render.RenderOptions``.

Settings are validated once, at submission, and stored normalised (e.g. ``"estimator": "mis"``
becomes ``{"": "mis"}``), so the worker's mapping cannot fail on shape, and an idempotent
resubmission compares equal however the client spelled it.
"""

from __future__ import annotations

import hashlib
import json
from typing import Literal, Optional, Union

from pydantic import (BaseModel, ConfigDict, Field, StrictBool, StrictInt, ValidationError, ValidationInfo,
                      create_model, field_validator)

from renderer import options

from .config import Limits
from .paths import InputError

__all__ = ["JobCreate", "JobPatch", "JobRequeue", "STAGE_SEARCH_MAX", "check_stage_search", "RenderSettings", "PreconvolveSettings", "validate_settings", "render_options",
           "request_hash", "DEFAULT_SPP", "job_frames", "range_settings"]

DEFAULT_SPP = 64


def _annotation(o):
    """The pydantic type of option ``o``'s request value (strict: JSON "4" is not an integer)."""
    one = {"int": StrictInt, "float": float, "bool": StrictBool, "str": str}
    if o.kind == "int_pair":
        t = list[StrictInt]  # the check wants two; a list, as the job stores it (JSON)
    elif o.kind == "str_list":
        t = list[str]
    elif o.kind == "per_light":
        t = Union[one[o.item], dict[str, one[o.item]]]
    else:
        t = one[o.kind]
    return Optional[t] if o.default is None else t


def _schema(o) -> dict:
    """Bounds and allowed values for the OpenAPI page (the check itself is the declaration's)."""
    extra: dict = {}
    if o.lo is not None:
        extra["exclusiveMinimum" if o.lo_open else "minimum"] = o.lo
    if o.hi is not None and o.kind not in ("str_list",):
        extra["maximum"] = o.hi
    if o.choices is not None:
        extra["enum"] = list(o.choices())
    if o.example is not None:
        extra["examples"] = [options.to_json(o, o.example)]
    return extra


def _check_option(cls, v, info: ValidationInfo):
    """Every field: normalise as RenderOptions holds it, check against the declaration, and
    return the JSON form the job stores."""
    o = options.BY_API[info.field_name]
    value = options.normalise(o, v)
    options.check(o, value)  # ValueError -> 422 naming settings.<field>
    return options.to_json(o, value)


def _request_model():
    """The ``render`` job settings model: one field per option renderer/options.py offers on the
    HTTP API, named as the declaration's ``api`` name."""
    api = [o for o in (*options.OPTIONS, *options.RANGE_OPTIONS) if "api" in o.routes and o.api_name]
    fields = {}
    for o in api:
        default = Field(default_factory=o.default_value) if isinstance(o.default, dict) else Field(o.default)
        default.description = o.help
        default.json_schema_extra = _schema(o)
        fields[o.api_name] = (_annotation(o), default)
    validator = field_validator(*(o.api_name for o in api))(_check_option)
    model = create_model("RenderSettings", __config__=ConfigDict(extra="forbid"), __module__=__name__,
                         __validators__={"_check_option": validator}, **fields)
    model.__doc__ = ("Settings of a ``render`` job; each is a render option declared in renderer/options.py, "
                     "the same as an ``illum render`` flag.")
    return model


RenderSettings = _request_model()


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


class JobPatch(BaseModel):
    """Body of ``PATCH /jobs/{id}``: what may change on a queued or running job."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"priority": 80}]})

    priority: StrictInt = Field(..., ge=0, le=100, description="0-100, higher runs first")


class JobRequeue(BaseModel):
    """Optional body of ``POST /jobs/{id}/requeue``."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [{"priority": 90}]})

    priority: Optional[StrictInt] = Field(None, ge=0, le=100, description="a new priority for the new run")


STAGE_SEARCH_MAX = 256  # characters of a stage search (GET /jobs?stage=)


def check_stage_search(text: Optional[str]) -> Optional[str]:
    """The ``stage`` search of ``GET /jobs``: plain text of at most STAGE_SEARCH_MAX characters
    without control characters (it is matched literally, never as a pattern or SQL). Returns
    the text with surrounding blanks removed (None when empty); raises InputError (422)."""
    if text is None:
        return None
    if len(text) > STAGE_SEARCH_MAX:
        raise InputError(422, "query.stage", f"{len(text)} characters exceed the limit of {STAGE_SEARCH_MAX}")
    if any(ord(c) < 32 or 127 <= ord(c) < 160 or 0xD800 <= ord(c) < 0xE000 for c in text):
        raise InputError(422, "query.stage", "must not contain control characters")
    return text.strip() or None


def _validation_error(prefix: str, err: ValidationError) -> InputError:
    e = err.errors()[0]
    loc = ".".join(str(p) for p in (prefix, *e["loc"]))
    # A declaration's check (renderer/options.py) says the same words as on the command line.
    msg = e["msg"].removeprefix("Value error, ")
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
        frames = job_frames(out)
        if frames is not None and len(frames) > limits.max_frames:
            field = "frames" if out.get("frames") is not None else "frame_count"
            raise InputError(422, f"settings.{field}", f"{len(frames)} frames exceed the server limit of "
                                                       f"{limits.max_frames}")
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


def job_frames(settings: dict) -> list[float] | None:
    """The frames of a render job whose settings ask for a range (``frames``, ``frame_count`` or
    ``frame_inc``; renderer/frames.py frame_list, as ``illum render`` reads them), else None: the
    job is one render. Raises InputError (422) naming the setting."""
    from renderer.errors import SettingsError
    from renderer.frames import frame_list

    if all(settings.get(o.api_name) is None for o in options.RANGE_OPTIONS):
        return None
    try:
        frames = frame_list(settings.get("frame"), settings.get("frame_count"), settings.get("frame_inc"),
                            settings.get("frames"))
    except SettingsError as e:
        names = {"--frames": "frames", "--frame-count": "frame_count", "--frame-inc": "frame_inc", "--frame": "frame"}
        raise InputError(422, f"settings.{names.get(e.attribute, 'frames')}", e.message) from None
    if frames[0] is None:
        # The workers could read the stage's start frame, but the job's tasks are made here, at
        # submission, and the server never opens a stage.
        raise InputError(422, "settings.frame", "a frame range (frame_count, frame_inc) needs its first frame here")
    return [float(f) for f in frames]


def range_settings(a) -> dict:
    """Parsed ``illum submit`` range flags (RANGE_OPTIONS) -> their request settings."""
    return {o.api_name: options.to_json(o, getattr(a, o.name)) for o in options.RANGE_OPTIONS
            if getattr(a, o.name, None) is not None}


def request_hash(kind: str, stage_name: str, settings: dict, priority: int, max_attempts: int) -> str:
    """Digest of a normalised request: an idempotency key replays only for an equal request."""
    blob = json.dumps([kind, stage_name, settings, priority, max_attempts], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def render_options(settings: dict, *, threads: int | None = None, max_time: float | None = None,
                   max_memory: int | None = None):
    """Stored (normalised) settings -> RenderOptions. ``max_time`` caps the time budget, so a
    job with only an spp target still cannot run forever; ``max_memory`` (the server's per-job
    cap) caps the memory a request asks for. A setting a stored job lacks (one from before the
    option existed) takes the declaration's default."""
    from renderer.render import RenderOptions

    kw = {o.name: options.normalise(o, settings.get(o.api_name)) for o in options.OPTIONS
          if "api" in o.routes and o.api_name}
    budget = kw.get("time_budget")
    if max_time is not None:
        kw["time_budget"] = min(budget, max_time) if budget is not None else max_time
    if max_memory is not None:
        asked = kw.get("max_memory")
        kw["max_memory"] = min(asked, max_memory) if asked is not None else max_memory
    return RenderOptions(threads=threads, **kw)


def settings_from_options(opt) -> dict:
    """RenderOptions (e.g. from ``illum submit`` flags) -> a settings dict for POST /jobs,
    leaving out what equals the default so the server's defaults apply."""
    out: dict = {}
    for o in options.OPTIONS:
        if "api" not in o.routes or not o.api_name:
            continue
        v = getattr(opt, o.name)
        if v != o.default_value():
            out[o.api_name] = options.to_json(o, v)
    return out
