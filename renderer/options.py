"""Every render option, declared once.

``OPTIONS`` lists each option a user can set for a render: its ``RenderOptions`` field name, the
kind of value, the default, the bounds or allowed values, the help text, its ``illum render`` /
``illum submit`` flags and its name in the service's request body. Everything else is derived
from it:

- ``RenderOptions`` (renderer/render.py) and its ``validate()``;
- the flags of ``illum render`` and ``illum submit`` (``add_flags``, ``options_from_args``);
- the service's request model ``RenderSettings`` and the stored-settings <-> options mapping
  (service/models.py).

So a new option is one ``Option(...)`` entry here. The checks run the same code on every route;
a bad value fails with the same message from the CLI (``SettingsError`` naming the attribute,
exit 2) and from the HTTP API (422 naming ``settings.<name>``).

Flag spellings follow husk where husk has the option (``-p/--pixel-samples``, ``-c/--camera``,
``-s/--settings``, ``-f/--frame``, ``--res``, ``--purpose``, ``-j/--threads``); the spellings
illum had before stay accepted.

Per-light options (``kind="per_light"``) hold ``{light path: value}``, where the key ``""``
means every light. On the command line they are repeatable ``[/Path/To/Light=|*=]VALUE`` flags
(``*=VALUE``: every light); a plain ``VALUE`` also means every light, except where the option
names a ``plain_to`` option that a plain value sets instead (``--estimator TOKEN`` sets the
stage-wide default estimator, for lights whose illum:estimator is unauthored). In the request
body a bare value (every light) or an object ``{"/Path/To/Light": value, "": value}``.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass, field, make_dataclass
from typing import Any, Callable, Optional

from .errors import SettingsError
from .frames import MAX_FRAMES
from .pixel_filter import MAX_RADIUS, MIN_RADIUS

__all__ = ["Option", "OPTIONS", "RANGE_OPTIONS", "BY_NAME", "BY_API", "ROUTES", "make_options_class", "add_flags", "options_from_args",
           "check", "normalise", "to_json", "MAX_PER_LIGHT_ENTRIES"]

# The three ways a render option reaches render(): `illum render` flags, `illum submit` flags, and
# the service's HTTP request body (POST /jobs settings).
ROUTES = ("render", "submit", "api")
MAX_PER_LIGHT_ENTRIES = 4096
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
PRIM_PATH = r"^/[^\x00-\x1f\x7f]*$"                   # a NUL would cut the path short in C++
PRIM_PATH_OR_NAME = r"^(/[^\x00-\x1f\x7f]*|[A-Za-z_][A-Za-z0-9_]*)$"
PURPOSE_TOKEN = r"^[A-Za-z_][A-Za-z0-9_]*$"
_PATTERN_WORDS = {PRIM_PATH: "a prim path starting with '/'",
                  PRIM_PATH_OR_NAME: "a prim path starting with '/' or a prim name",
                  PURPOSE_TOKEN: "a purpose token such as default, render or proxy"}


def _estimator_tokens() -> tuple[str, ...]:
    from .estimators import TOKENS

    return tuple(TOKENS)


def _alpha_tokens() -> tuple[str, ...]:
    from .estimators import ALPHAS

    return tuple(ALPHAS)


def _light_samplers() -> tuple[str, ...]:
    from .light_samplers import SAMPLERS

    return ("auto", *sorted(SAMPLERS))


def _pixel_filters() -> tuple[str, ...]:
    from .pixel_filter import FILTERS

    return FILTERS


def _aov_names() -> tuple[str, ...]:
    from .aov import ALIASES, SOURCES

    return (*SOURCES, *ALIASES)


def _pixel_filter_modes() -> tuple[str, ...]:
    from .pixel_filter import MODES

    return MODES


def _parse_size(text: str) -> int:
    from .memory import parse_size

    return parse_size(text)


def _resolution_limits(v) -> None:
    """The renderer's own limits on image size (renderer.camera.check_resolution)."""
    from .camera import check_resolution

    try:
        check_resolution(int(v[0]), int(v[1]), "resolution")
    except SettingsError as e:
        raise ValueError(e.message) from None


@dataclass(frozen=True)
class Option:
    """One render option.

    kind: "int", "float", "bool", "str", "int_pair" (W H), "str_list" (repeatable tokens) or
      "per_light" (``{light path or "": value}``; ``item`` is the value's kind, "int" or "str").
    default: the RenderOptions default (None: the stage's RenderSettings or the renderer decide).
    lo / hi: inclusive bounds of numbers (of each item for per_light and int_pair); lo_open makes
      lo exclusive. choices: a function returning the allowed strings (called only when checking,
      so building a parser imports no kernels). pattern: a regex a string must match.
    flags: CLI spellings, canonical first (a bool option's first flag gets its --no- form too).
    api: the field name in the service's request body (default: name); None: not on the API.
    routes: the routes the option is offered on; off_route: why it is absent from the others.
    example: a valid non-default value (the route tests and the docs table use it).
    plain_to: per_light only: the option a plain command-line VALUE (no '=') sets instead of
      every light (which is then spelled ``*=VALUE``).
    parse: how a command-line word becomes the value, when not by its kind (raises ValueError).
    """

    name: str
    kind: str
    default: Any
    help: str
    flags: tuple[str, ...] = ()
    metavar: Any = None
    api: Optional[str] = ""
    lo: Optional[float] = None
    hi: Optional[float] = None
    lo_open: bool = False
    choices: Optional[Callable[[], tuple[str, ...]]] = None
    pattern: Optional[str] = None
    max_length: int = 1024
    item: str = "str"
    extra_check: Optional[Callable[[Any], None]] = None
    routes: tuple[str, ...] = ROUTES
    off_route: str = ""
    example: Any = None
    plain_to: Optional[str] = None
    parse: Optional[Callable[[str], Any]] = None  # a command-line word -> the value (e.g. "8G" -> bytes)

    @property
    def api_name(self) -> Optional[str]:
        return None if self.api is None else (self.api or self.name)

    @property
    def value_kind(self) -> str:
        """The kind of one value: the item kind of per_light / int_pair / str_list options."""
        return {"per_light": self.item, "int_pair": "int", "str_list": "str"}.get(self.kind, self.kind)

    def default_value(self):
        return dict(self.default) if isinstance(self.default, dict) else self.default

    def bounds_text(self) -> str:
        """The allowed values in words, for help text and error messages."""
        if self.choices is not None:
            return "one of " + ", ".join(self.choices())
        if self.pattern is not None:
            return _PATTERN_WORDS.get(self.pattern, "of the form " + self.pattern)
        lo, hi = _num(self.lo), _num(self.hi)
        if self.lo is not None and self.hi is not None:
            return f"in {'(' if self.lo_open else '['}{lo}, {hi}]"
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {lo}"
        return "" if self.hi is None else f"<= {hi}"


def _num(x) -> str:
    """A bound as a user writes it: 1000000, not 1e+06."""
    if x is None:
        return ""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


# ---------------------------------------------------------------------------------- the options
OPTIONS: tuple[Option, ...] = (
    Option("spp", "int", None, "samples per pixel (default 64, or the time budget alone when one is given)",
           flags=("--spp", "-p", "--pixel-samples"), metavar="N", lo=1, hi=1_000_000, example=3),
    Option("time_budget", "float", None, "seconds of rendering (load and BVH build excluded)",
           flags=("--time-budget",), metavar="SECONDS", lo=0, lo_open=True, hi=1e9, example=600.0),
    Option("resolution", "int_pair", None, "resolution override, width and height in pixels",
           flags=("--res",), metavar=("W", "H"), lo=1, extra_check=_resolution_limits, example=(12, 8)),
    Option("camera", "str", None, "camera prim path, or a unique camera prim name (default: the RenderSettings "
           "camera, else the first camera)", flags=("--camera", "-c"), pattern=PRIM_PATH_OR_NAME),
    Option("settings", "str", None, "RenderSettings prim path (default: the stage's renderSettingsPrimPath)",
           flags=("--settings", "-s"), api="settings_prim", pattern=PRIM_PATH),
    Option("frame", "float", None, "time code to render", flags=("--frame", "-f"), example=1.0),
    Option("purposes", "str_list", None, "purposes to render (repeatable or comma-separated; default: the "
           "RenderSettings includedPurposes)", flags=("--purpose",), metavar="PURPOSE[,PURPOSE]",
           pattern=PURPOSE_TOKEN, max_length=64, hi=16, example=("default", "render")),
    # Below 2^31: the EXR records it as an int attribute. The Ray backend's per-block streams
    # ((seed << 20) + 1 + block, service/ray_backend.py) reach render() as its stream_seed instead.
    Option("seed", "int", 0, "random seed; passes continue its streams", flags=("--seed",), lo=0, hi=2**31 - 1,
           example=5),
    Option("threads", "int", None, "render threads (default: all cores)", flags=("--threads", "-j"), lo=1,
           hi=256, routes=("render",), api=None, example=1,
           off_route="a service's workers use the server's `illum serve --threads`"),
    Option("max_depth", "int", 8, "scattering events: 0 = emitters only, 1 = direct lighting (pbrt's maxdepth)",
           flags=("--max-depth",), lo=0, hi=1024, example=3),
    Option("rr_depth", "int", 3, "scattering events before Russian roulette may end a path",
           flags=("--rr-depth",), lo=0, hi=1024, example=2),
    Option("light_sampler", "str", "auto", "lighting service (auto: by light count)", flags=("--light-sampler",),
           choices=_light_samplers, max_length=64, example="power"),
    Option("emitter_samples", "int", 0, "camera rays per pixel and pass that see emitters directly (one continues "
           "as the path): anti-aliases small bright lights on screen; 0 = auto (2 where subpixel lights touch "
           ">= 1% of the pixels, else 1)", flags=("--emitter-samples",), metavar="K", lo=0, hi=64, example=2),
    Option("fast_path", "bool", True, "the compiled path vertex where the scene qualifies; --no-fast-path always "
           "uses the general integrator (stats 'fast_path' says whether it ran and why not)",
           flags=("--fast-path",), example=False),
    Option("sampler", "str", "sobol", "the numbers of each bounce: sobol (each pixel's own scrambled "
           "low-discrepancy sequence: lower noise at equal samples) or independent (uncorrelated random numbers)",
           flags=("--sampler",), metavar="NAME", choices=lambda: ("sobol", "independent"), max_length=64,
           example="independent"),
    Option("estimator", "per_light", {}, "direct-lighting estimator: TOKEN is the default for lights whose "
           "illum:estimator is not authored (as --default-estimator), *=TOKEN forces every light, /Light=TOKEN "
           "one light (repeatable)", flags=("--estimator",), metavar="[/Light=|*=]TOKEN",
           choices=_estimator_tokens, max_length=64, example={"": "mis"}, plain_to="default_estimator"),
    Option("default_estimator", "str", None, "the stage-wide default estimator, for lights whose illum:estimator "
           "is not authored (default: RenderSettings illum:estimator through IllumRenderSettingsAPI, else mis)",
           flags=("--default-estimator",), metavar="TOKEN", choices=_estimator_tokens, max_length=64,
           example="auto"),
    Option("cv_alpha", "per_light", {}, "the control variate's alpha for all lights, or /Light=TOKEN for one "
           "(repeatable)", flags=("--cv-alpha",), metavar="[/Light=|*=]TOKEN", choices=_alpha_tokens,
           max_length=64, example={"": "one"}),
    Option("pixel_filter", "str", None, "pixel reconstruction filter (default: RenderSettings illum:pixelFilter, "
           "else gaussian)", flags=("--pixel-filter",), metavar="NAME", choices=_pixel_filters, max_length=64,
           example="blackman-harris"),
    Option("pixel_filter_width", "float", None, "pixel filter radius in pixels (default: the filter's own, 1.5 for "
           "gaussian and blackman-harris, 0.5 for box)", flags=("--pixel-filter-width",), metavar="PX",
           lo=MIN_RADIUS, hi=MAX_RADIUS, example=2.0),
    Option("pixel_filter_mode", "str", None, "splat: each sample adds filter-weighted radiance to every pixel under "
           "the filter; importance: samples drawn from the filter add to their own pixel (default: RenderSettings "
           "illum:pixelFilter:mode, else splat)", flags=("--pixel-filter-mode",), metavar="MODE",
           choices=_pixel_filter_modes, max_length=64, example="importance"),
    Option("strict", "bool", False, "make every missing or unreadable asset (texture, light texture, IES file, "
           "sublayer, reference, payload) and a sublayer cycle an error naming the layer, prim and attribute "
           "(default: one warning per file, and the texture's fallback, an untextured or unshaped light, or the "
           "arc skipped)", flags=("--strict",), example=True),
    Option("subdiv_level", "int", None, "subdivision level of every catmullClark, loop and bilinear mesh (0: "
           "the control cage; default: per mesh, from its projected edge length, renderer/subdiv.py)",
           flags=("--subdiv-level",), metavar="N", lo=0, hi=8, example=2),
    Option("max_memory", "int", None, "refuse, before allocating, a render whose meshes, images and film would need "
           "more than SIZE bytes (8G, 512M; binary units), naming what is too big (default: 80% of the memory "
           "available; a service job is also held to the server's --max-job-memory)", flags=("--max-memory",),
           metavar="SIZE", lo=2**20, example=2**33, parse=_parse_size),
    Option("load_timeout", "float", 600.0, "seconds opening the stage, reading it and decoding its images may take "
           "before the render is refused (a file that never finishes reading: a FIFO value clip, a hung network "
           "mount)", flags=("--load-timeout",), metavar="SECONDS", lo=0, lo_open=True, hi=1e6, example=300.0),
    Option("aov", "str_list", None, "render passes to write as layers of the EXR, for stages whose RenderProduct "
           "authors no orderedVars (repeatable or comma-separated; renderer/aov.py lists them)",
           flags=("--aov",), metavar="NAME[,NAME]", choices=_aov_names, max_length=64, hi=32,
           example=("albedo", "N")),
    Option("alpha", "bool", False, "write RGBA: premultiplied alpha, the filtered coverage of camera rays by "
           "geometry (cut-outs transparent)", flags=("--alpha",), example=True),
    Option("alpha_dome_transparent", "bool", None, "the dome seen directly is transparent: out of the beauty's "
           "RGB and of alpha (implies --alpha; default: RenderSettings illum:alpha:domeTransparent, else false)",
           flags=("--alpha-dome-transparent",), example=True),
    Option("denoise", "bool", False, "also write an OIDN-denoised beauty (layer 'denoised' of the EXR, or "
           "NAME_denoised.EXT), guided by first-hit albedo and normal; needs the pyoidn package "
           "(pip install 'illum[denoise]'); the raw beauty is kept", flags=("--denoise",), example=True),
    Option("noise_threshold", "float", None, "adaptive sampling: after --adaptive-min-spp samples, a pixel stops "
           "receiving samples once the relative standard error of its mean luminance falls below T (0.01 = 1%), "
           "estimated from 1 in 4 of its samples, which are kept out of the image so that the image stays unbiased "
           "(docs/adaptive.md); --spp (default 64) or --time-budget still caps every pixel; needs "
           "--pixel-filter-mode importance (its default then); 0 = off (default: RenderSettings "
           "illum:adaptive:noiseThreshold, else off)",
           flags=("--noise-threshold",), metavar="T", lo=0, hi=1, example=0.05),
    Option("adaptive_min_spp", "int", None, "adaptive sampling: samples every pixel takes before it may stop "
           "(default: RenderSettings illum:adaptive:minSpp, else 32)", flags=("--adaptive-min-spp",), metavar="N",
           lo=1, hi=1_000_000, example=8),
    Option("light_samples", "per_light", {}, "light samples per shading point for all lights, or /Light=N for "
           "one (repeatable)", flags=("--light-samples",), metavar="[/Light=|*=]N", item="int", lo=1, hi=4096,
           example={"": 2}),
)
BY_NAME = {o.name: o for o in OPTIONS}


def _frames_spec(v) -> None:
    """A --frames SPEC must parse (renderer/frames.py), with the parser's own words."""
    from .frames import parse_frames

    try:
        parse_frames(v)
    except SettingsError as e:
        raise ValueError(e.message) from None


# Which frames a command or a service job renders (renderer/frames.py). Not RenderOptions fields
# (each frame's render gets its own ``frame``): ``illum render`` renders them in one process,
# ``illum submit`` and the request body make them one job with a task per frame. Declared here
# so that every route takes the same spellings, bounds and messages.
RANGE_OPTIONS: tuple[Option, ...] = (
    Option("frame_count", "int", None, "render N frames from --frame", flags=("--frame-count", "-n"), metavar="N",
           lo=1, hi=MAX_FRAMES, example=3),
    Option("frame_inc", "float", None, "frame step of --frame-count (default 1)", flags=("--frame-inc", "-i"),
           metavar="I", lo=0, lo_open=True, hi=1e9, example=2.0),
    Option("frames", "str", None, "frames to render: A, A-B or A-BxSTEP, comma-separated (e.g. 1-100x2); the stage "
           "is loaded once", flags=("--frames",), metavar="SPEC", max_length=4096, extra_check=_frames_spec,
           example="1-3"),
)
BY_API = {o.api_name: o for o in (*OPTIONS, *RANGE_OPTIONS) if o.api_name}


# ---------------------------------------------------------------------------------- checks
def _is_int(v) -> bool:
    import numpy as np

    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _check_one(o: Option, kind: str, v) -> None:
    """Check one scalar value of option ``o``; raises ValueError with the reason."""
    if kind == "int":
        if not _is_int(v):
            raise ValueError(f"must be an integer, got {v!r}")
    elif kind == "float":
        if not (_is_int(v) or isinstance(v, float)) or isinstance(v, bool):
            raise ValueError(f"must be a number, got {v!r}")
        if not math.isfinite(v):
            raise ValueError(f"must be finite, got {v!r}")
    elif kind == "bool":
        if not isinstance(v, bool):
            raise ValueError(f"must be true or false, got {v!r}")
        return
    elif kind == "str":
        if not isinstance(v, str):
            raise ValueError(f"must be a string, got {v!r}")
        _check_text(v)
        if o.choices is not None:
            if v not in o.choices():
                raise ValueError(f"must be {o.bounds_text()}, got {v!r}")
            return
        if len(v) > o.max_length:
            raise ValueError(f"is longer than {o.max_length} characters")
        if o.pattern and not re.match(o.pattern, v):
            raise ValueError(f"must be {o.bounds_text()}, got {v!r}")
        return
    if kind in ("int", "float"):
        too_low = o.lo is not None and (v <= o.lo if o.lo_open else v < o.lo)
        if too_low or (o.hi is not None and v > o.hi):
            raise ValueError(f"must be {'an integer' if kind == 'int' else 'a number'} {o.bounds_text()}, "
                             f"got {v!r}")


def _check_text(v: str) -> None:
    """A string must be UTF-8 text: a lone surrogate (JSON "\\ud800") can become neither a file
    name, a prim path nor a database string."""
    try:
        v.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("must be valid UTF-8 text (it holds a lone surrogate)") from None


def check(o: Option, v) -> None:
    """Check a RenderOptions value of ``o`` (None is allowed where the default is None).
    Raises ValueError with a message that does not repeat the option's name."""
    if v is None:
        if o.default is None:
            return
        raise ValueError("must be given")
    if o.kind == "int_pair":
        if not isinstance(v, (tuple, list)) or len(v) != 2:
            raise ValueError(f"must be two integers (width, height), got {v!r}")
        for x in v:
            _check_one(o, "int", x)
    elif o.kind == "str_list":
        if not isinstance(v, (tuple, list)) or not v:
            raise ValueError(f"must be a non-empty list of strings, got {v!r}")
        if o.hi is not None and len(v) > o.hi:
            raise ValueError(f"has {len(v)} entries, more than the limit of {_num(o.hi)}")
        for x in v:
            _check_one(o, "str", x)
    elif o.kind == "per_light":
        if not isinstance(v, dict):
            raise ValueError(f"must map light paths to values, got {v!r}")
        if len(v) > MAX_PER_LIGHT_ENTRIES:
            raise ValueError(f"has {len(v)} entries, more than the limit of {MAX_PER_LIGHT_ENTRIES}")
        for key, x in v.items():
            if (not isinstance(key, str) or (key and not key.startswith("/")) or len(key) > 1024
                    or _CONTROL.search(key)):
                raise ValueError(f"key {key!r} must be a light prim path starting with '/', or '' for all lights")
            _check_text(key)
            try:
                _check_one(o, o.item, x)
            except ValueError as e:
                raise ValueError(f"{key or 'all lights'}: {e}") from None
    else:
        _check_one(o, o.kind, v)
    if o.extra_check is not None:
        o.extra_check(v)


def normalise(o: Option, v):
    """A value as a request body or a stored job spells it -> the RenderOptions value: a bare
    per-light value means every light, lists become tuples. Unchecked: call check() after."""
    if v is None:
        return o.default_value()
    if o.kind == "per_light":
        return dict(v) if isinstance(v, dict) else {"": v}
    if o.kind in ("int_pair", "str_list") and isinstance(v, list):
        return tuple(v)
    return v


def to_json(o: Option, v):
    """A RenderOptions value -> its JSON form (tuples become lists, numpy scalars Python ones)."""
    if v is None:
        return None
    if o.kind in ("int_pair", "str_list"):
        return [int(x) if o.kind == "int_pair" else str(x) for x in v]
    if o.kind == "per_light":
        return {str(k): (int(x) if o.item == "int" else str(x)) for k, x in v.items()}
    if o.kind == "int":
        return int(v)
    if o.kind == "float":
        return float(v)
    return v


# ---------------------------------------------------------------------------------- RenderOptions
def _validate(self) -> None:
    """Check every option against its declaration (renderer/options.py); raises SettingsError
    naming the attribute."""
    for o in OPTIONS:
        try:
            check(o, getattr(self, o.name))
        except ValueError as e:
            raise SettingsError(str(e), attribute=o.name) from None


def _as_json(self) -> dict:
    """Every option as JSON values (the render's stats record them)."""
    return {o.name: to_json(o, getattr(self, o.name)) for o in OPTIONS}


_PY_TYPES = {"int": int, "float": float, "bool": bool, "str": str, "int_pair": tuple, "str_list": tuple,
             "per_light": dict}


def make_options_class(module: str, qualname: str = "RenderOptions", doc: str = "") -> type:
    """The RenderOptions dataclass: one field per declared option, with validate() and as_json()."""
    spec = []
    for o in OPTIONS:
        typ = _PY_TYPES[o.kind] if o.default is not None else Optional[_PY_TYPES[o.kind]]
        if isinstance(o.default, dict):
            spec.append((o.name, typ, field(default_factory=o.default_value)))
        else:
            spec.append((o.name, typ, field(default=o.default)))
    cls = make_dataclass(qualname, spec, namespace={"validate": _validate, "as_json": _as_json})
    cls.__module__ = module  # pickling (the Ray backend ships options to actors) finds it there
    cls.__qualname__ = qualname
    cls.__doc__ = doc
    return cls


# ---------------------------------------------------------------------------------- CLI
def _conv(o: Option, kind: str, flag: str):
    def conv(s):
        if o.parse is not None:
            try:
                return o.parse(s)
            except ValueError as e:
                raise argparse.ArgumentTypeError(f"{flag} {e}") from None
        try:
            return int(s) if kind == "int" else float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{flag} expects {'an integer' if kind == 'int' else 'a number'}, got {s!r}") from None
    return conv


def _help(o: Option) -> str:
    h = o.help
    if o.default not in (None, {}) and o.kind != "bool":
        h += f" (default {o.default})"
    return h.replace("%", "%%")


def add_flags(p: argparse.ArgumentParser, route: str, declared: tuple[Option, ...] = OPTIONS) -> None:
    """Add the flags of every option of ``declared`` (OPTIONS, or RANGE_OPTIONS) offered on
    ``route`` ("render" or "submit") to ``p``. Each flag's dest is the option's name; a flag left
    out parses as None (see options_from_args)."""
    for o in declared:
        if route not in o.routes or not o.flags:
            continue
        kw: dict = {"dest": o.name, "default": None, "help": _help(o)}
        if o.metavar is not None:
            kw["metavar"] = o.metavar
        if o.kind == "bool":
            p.add_argument(*o.flags, action=argparse.BooleanOptionalAction, **kw)
            continue
        if o.kind in ("str_list", "per_light"):
            kw["action"] = "append"
        if o.kind == "int_pair":
            kw["nargs"] = 2
        if o.value_kind in ("int", "float") and o.kind != "per_light":
            kw["type"] = _conv(o, o.value_kind, o.flags[0])
        p.add_argument(*o.flags, **kw)


def _per_light_arg(o: Option, values: list[str]) -> tuple[dict, Optional[str]]:
    """Repeatable ``TOKEN`` / ``*=TOKEN`` (all lights) or ``/Path/To/Light=TOKEN`` (one light)
    flags -> (dict, the last plain TOKEN where the option sends plain values to ``plain_to``)."""
    flag = o.flags[0].lstrip("-")
    out: dict = {}
    plain = None
    for v in values:
        if "=" not in v and o.plain_to:
            plain = v
            continue
        path, token = v.split("=", 1) if "=" in v else ("", v)
        if path == "*":
            path = ""
        elif path and not path.startswith("/"):
            raise SettingsError(f"expected /Path/To/Light=VALUE or *=VALUE, got {v!r}", attribute=flag)
        if o.item == "int":
            try:
                token = int(token)
            except ValueError:
                raise SettingsError(f"expected an integer, got {token!r}", attribute=flag) from None
        out[path] = token
    return out, plain


def options_from_args(a, route: str):
    """Parsed flags (from add_flags) -> a validated RenderOptions; flags not given keep the
    declaration's defaults."""
    from .render import RenderOptions

    kw = {}
    for o in OPTIONS:
        if route not in o.routes or not o.flags:
            continue
        v = getattr(a, o.name, None)
        if v is None:
            continue
        if o.kind == "per_light":
            v, plain = _per_light_arg(o, v)
            if plain is not None:
                kw[o.plain_to] = plain
        elif o.kind == "str_list":
            v = tuple(t for item in v for t in item.split(",") if t)
        elif o.kind == "int_pair":
            v = tuple(v)
        kw[o.name] = v
    opts = RenderOptions(**kw)
    opts.validate()
    return opts


def routes_of(o: Option) -> dict:
    """{route: the spelling on that route, or None} (for the docs table)."""
    flags = ", ".join((*o.flags, *("--no-" + f[2:] for f in o.flags if f.startswith("--"))) if o.kind == "bool"
                      else o.flags)
    return {"render": flags if "render" in o.routes else None,
            "submit": flags if "submit" in o.routes else None,
            "api": f"settings.{o.api_name}" if "api" in o.routes and o.api_name else None}

