"""Cold start: fill numba's kernel cache ahead of time (`illum warmup`), and notice compiles.

Every kernel is ``@njit(cache=True)``: it compiles on its first call for each argument-type
signature (tens of seconds for the whole renderer) and is then written to numba's on-disk cache
(``__pycache__`` beside its module, or ``$NUMBA_CACHE_DIR``), from which later processes load it
in a fraction of that. ``warmup`` makes that first call for every route a render can take, so
that a user's first render (or a service job) compiles nothing:

* it renders the repository's example stages (``stages/``) at a tiny resolution with the
  options that steer each route: the fast path and the general path, every light kind (rect,
  disk, sphere, distant, dome constant and textured, cylinder, mesh lights, portals, ShapingAPI
  and IES, ShadowAPI), every estimator token, the light BVH, direct lighting only, several
  emitter samples, depth of field, textured materials;
* the dome irradiance table (renderer/preconvolve.py) is computed afresh, into a temporary
  ``$ILLUM_CACHE_DIR``, so its kernels compile too (a render that finds the table cached
  needs none of them), and ``illum preconvolve`` runs on a small map with each method.

``CompileWatch`` listens to numba's ``numba:compile`` event, which numba fires only when it
really compiles (a signature neither in memory nor in the disk cache): a warm render triggers
none, so watching costs nothing there. ``render`` uses one to keep compile time out of the time
budget; ``CompileNotice`` uses one to tell the user ("compiling kernels, first run only").
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

from numba.core import event

__all__ = ["CompileWatch", "COMPILES", "CompileNotice", "ROUTES", "warmup", "is_warm", "kernel_coverage",
           "cache_location"]

# The repository root: the example stages live in <root>/stages (as guard_cache's sources do).
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_STAGES = os.path.join(_ROOT, "stages")


class CompileWatch(event.Listener):
    """Counts numba compiles and the wall time they take while installed (``with`` block).

    ``seconds()`` is the union of the intervals during which at least one compile ran, so a
    kernel compiling its callees (nested events) or two render threads waiting on numba's
    compiler lock are counted once. ``on_compile(watch, dispatcher)`` is called at the start of
    each compile (from the compiling thread, under numba's compiler lock)."""

    KIND = "numba:compile"

    def __init__(self, on_compile: Optional[Callable] = None):
        self.on_compile = on_compile
        self.kernels = 0
        self._seconds = 0.0
        self._depth = 0
        self._since = 0.0
        self._lock = threading.Lock()

    def on_start(self, ev) -> None:
        with self._lock:
            if self._depth == 0:
                self._since = time.perf_counter()
            self._depth += 1
            self.kernels += 1
        if self.on_compile is not None:
            self.on_compile(self, (ev.data or {}).get("dispatcher"))

    def on_end(self, ev) -> None:
        with self._lock:
            self._depth -= 1
            if self._depth == 0:
                self._seconds += time.perf_counter() - self._since

    def seconds(self) -> float:
        """Compile wall time so far (seconds), including a compile still running."""
        with self._lock:
            running = time.perf_counter() - self._since if self._depth else 0.0
            return self._seconds + running

    def __enter__(self) -> "CompileWatch":
        event.register(self.KIND, self)
        return self

    def __exit__(self, *exc) -> None:
        event.unregister(self.KIND, self)


# Every compile of the process, from this module's import on (render() reads its deltas: a
# listener costs nothing until numba compiles, and one that stays installed needs no teardown).
COMPILES = CompileWatch().__enter__()


def _group(dispatcher) -> str:
    """A kernel's group for progress lines: its module without the package prefix."""
    mod = getattr(getattr(dispatcher, "py_func", None), "__module__", None) or "kernels"
    return mod.removeprefix("renderer.")


class CompileNotice:
    """Tells the user, on ``stream``, that kernels are compiling, with progress: nothing at all
    unless a compile happens. On a terminal one line is rewritten (kernels compiled, seconds,
    the current group); otherwise one line per kernel group as it starts compiling. ``finish()``
    ends with a summary line. Use as ``with CompileNotice(sys.stderr) as notice: ...``."""

    HEADER = "compiling kernels, first run only"

    def __init__(self, stream=None, prefix: str = "illum: "):
        self.stream = stream if stream is not None else sys.stderr
        self.prefix = prefix
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.watch = CompileWatch(self._on_compile)
        self.groups: list[str] = []
        self.open_line = False
        self.done = False

    def _write(self, text: str) -> None:
        self.stream.write(text)
        self.stream.flush()

    def _on_compile(self, watch: CompileWatch, dispatcher) -> None:
        group = _group(dispatcher)
        first = watch.kernels == 1
        if self.tty:
            if self.done:
                return  # finish() handed the line to the render's progress bar
            self._write(f"\r\x1b[K{self.prefix}{self.HEADER}: {watch.kernels} kernels, "
                        f"{watch.seconds():.0f} s ({group})")
            self.open_line = True
        else:
            if first:
                self._write(f"{self.prefix}{self.HEADER} (illum warmup does this ahead of time)\n")
            if group not in self.groups:
                self._write(f"{self.prefix}  compiling {group} ({watch.kernels} kernels so far, "
                            f"{watch.seconds():.0f} s)\n")
        if group not in self.groups:
            self.groups.append(group)

    def finish(self) -> None:
        """End the progress line with a summary (only if anything compiled; idempotent)."""
        if self.done or self.watch.kernels == 0:
            return
        self.done = True
        end = "\r\x1b[K" if self.open_line else ""
        self._write(f"{end}{self.prefix}compiled {self.watch.kernels} kernels in {self.watch.seconds():.1f} s "
                    f"(cached: later runs load them)\n")

    def __enter__(self) -> "CompileNotice":
        self.watch.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.watch.__exit__(*exc)
        self.finish()


@dataclass(frozen=True)
class Route:
    """One warm-up render: a stage under stages/, the RenderOptions fields that steer it, and
    what it exercises."""

    stage: str
    options: tuple = ()
    what: str = ""


# Every route a render can take. Options other than these stay at RenderOptions' defaults (the
# auto estimator, the auto light sampler, max depth 8), so the default route of each stage runs.
_ESTIMATORS = ("mis", "lightSampling", "bsdfSampling", "controlVariate", "ratio")
ROUTES: tuple[Route, ...] = (
    Route("cornell_box.usda", (), "fast path, rect light, film, pinhole camera"),
    Route("cornell_box.usda", (("fast_path", False),), "general path, rect light"),
    Route("cornell_box.usda", (("max_depth", 1),), "direct lighting only"),
    Route("cornell_box.usda", (("emitter_samples", 2),), "emitter samples"),
    *(Route("instanced.usda", (("fast_path", False), ("estimator", {"": e})), f"{e}: disk and sphere lights")
      for e in _ESTIMATORS),
    # The uniform, power and exhaustive samplers are numpy (compiled nothing here on a cold cache).
    Route("instanced.usda", (("light_sampler", "bvh"),), "light BVH"),
    Route("instanced.usda", (), "auto estimator, instancing"),
    Route("textured.usda", (), "textured materials, meshes with primvars"),
    Route("textured.usda", (("fast_path", False),), "textured materials, general path"),
    Route("plant/plant.usda", (), "normal maps and cut-outs, fast path (compiled cut-out walks)"),
    Route("plant/plant.usda", (("fast_path", False),), "normal maps and cut-outs, general path"),
    Route("zup_dome.usda", (), "textured dome light, metal"),
    Route("zup_dome.usda", (("fast_path", False),), "textured dome light, general path"),
    Route("dof.usda", (), "thin-lens camera, distant and constant dome lights"),
    Route("dof.usda", (("fast_path", False),), "distant and constant dome lights, general path"),
    *(Route("talk/dome.usda", (("estimator", {"": e}),), f"{e}: textured dome, irradiance table")
      for e in _ESTIMATORS),
    Route("talk/dome.usda", (), "authored control variate on a textured dome"),
    Route("talk/penumbra.usda", (), "control variate, alpha = v_bar, 4 samples"),
    Route("talk/sphere_occluder.usda", (), "sphere light, authored estimator"),
    Route("talk/large_rect.usda", (), "large rect light, glossy"),
    Route("shaping/spotlights.usda", (), "ShapingAPI, IES profiles, light BVH"),
    Route("shaping/shadows.usda", (), "ShadowAPI"),
    Route("lux_extra/mesh_light_room.usda", (), "cylinder and mesh lights"),
    Route("lux_extra/window_portal.usda", (), "dome portals"),
    *(Route(s, (("estimator", {"": e}),), f"{e}: cylinder, mesh lights, portals")
      for s in ("lux_extra/mesh_light_room.usda", "lux_extra/window_portal.usda") for e in _ESTIMATORS),
)

WARMUP_RES = (16, 16)
WARMUP_SPP = 2


def cache_location() -> str:
    """Where numba writes the kernel cache: $NUMBA_CACHE_DIR, else __pycache__ beside each module."""
    from numba.core import config

    return config.CACHE_DIR or os.path.join(os.path.dirname(os.path.abspath(__file__)), "**", "__pycache__")


def _stamp_path() -> str:
    """The file that records a finished warm-up, beside the kernels it warmed."""
    from numba.core import config

    base = config.CACHE_DIR or os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    return os.path.join(base, "illum-warmup.stamp")


def _stamp_key() -> str:
    """What numba's cached code depends on: numba's version, the CPU and its feature string
    (renderer/__init__.py may set it), and every renderer source file's size and mtime (numba
    invalidates a module's cache when its file changes) and ROUTES."""
    import hashlib

    import numba
    from numba.core import config

    h = hashlib.sha256()
    h.update(f"{numba.__version__}|{config.CPU_NAME}|{config.CPU_FEATURES}|{ROUTES!r}|".encode())
    pkg = os.path.dirname(os.path.abspath(__file__))
    for d, dirs, files in sorted(os.walk(pkg)):
        dirs.sort()
        for f in sorted(files):
            if f.endswith(".py"):
                st = os.stat(os.path.join(d, f))
                h.update(f"{os.path.relpath(os.path.join(d, f), pkg)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def is_warm() -> bool:
    """True when a finished warm-up is recorded for this numba, CPU and source tree (a stamp
    file beside the cache): a cheap check, no kernel is loaded."""
    try:
        with open(_stamp_path()) as fh:
            return fh.read().strip() == _stamp_key()
    except OSError:
        return False


def _write_stamp() -> None:
    path = _stamp_path()
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as fh:
            fh.write(_stamp_key())
    except OSError:
        pass  # a read-only cache: every warm-up runs in full, still correct


@contextlib.contextmanager
def _fresh_irradiance_cache():
    """A temporary $ILLUM_CACHE_DIR, so the dome irradiance tables compute (and their kernels
    compile) instead of loading from the user's cache."""
    old = os.environ.get("ILLUM_CACHE_DIR")
    with tempfile.TemporaryDirectory(prefix="illum-warmup-") as d:
        os.environ["ILLUM_CACHE_DIR"] = d
        try:
            yield
        finally:
            if old is None:
                os.environ.pop("ILLUM_CACHE_DIR", None)
            else:
                os.environ["ILLUM_CACHE_DIR"] = old


def warmup(report: Optional[Callable[[str], None]] = None, threads: Optional[int] = None,
           routes: tuple[Route, ...] = ROUTES, cancel: Optional[Callable[[], bool]] = None,
           if_needed: bool = False) -> dict:
    """Render every route once (``ROUTES``: WARMUP_RES pixels, WARMUP_SPP samples) so that each
    kernel is compiled into numba's on-disk cache. ``report`` gets one line per route; ``cancel``
    is asked before each route (a worker told to stop while it warms). if_needed: return at once
    (``{"skipped": True}``) when ``is_warm()``; a finished warm-up of ROUTES records that.

    Returns {"skipped", "seconds", "kernels_compiled", "compile_seconds", "routes"}: the wall
    time and the number of compiles (0 on a warm cache). kernel_coverage() then lists the
    kernels no route called (on a cold cache only: a kernel loaded from the cache does not load
    the helpers compiled into it)."""
    from .errors import SettingsError

    if if_needed and is_warm():
        return {"skipped": True}
    from .render import RenderOptions, render

    missing = [r.stage for r in routes if not os.path.exists(os.path.join(_STAGES, r.stage))]
    if missing:
        raise SettingsError(f"warm-up stages not found under {_STAGES}: {', '.join(sorted(set(missing)))} "
                            f"(illum warmup needs the source checkout's stages/)", attribute="warmup")
    say = report or (lambda line: None)

    @contextlib.contextmanager
    def step(name: str, what: str):
        t0, k0, c0 = time.perf_counter(), COMPILES.kernels, COMPILES.seconds()
        yield
        say(f"{name:34s} {what:52s} {time.perf_counter() - t0:6.1f} s, "
            f"{COMPILES.kernels - k0:3d} compiled ({COMPILES.seconds() - c0:.1f} s)")

    t_start = time.perf_counter()
    caches: dict[str, dict] = {}
    k_start, c_start = COMPILES.kernels, COMPILES.seconds()
    with _fresh_irradiance_cache():
        for r in routes:
            if cancel is not None and cancel():
                say("stopped")
                break
            opts = RenderOptions(resolution=WARMUP_RES, spp=WARMUP_SPP, threads=threads, **dict(r.options))
            path = os.path.join(_STAGES, r.stage)
            with step(r.stage, r.what):
                render(path, opts, scene_cache=caches.setdefault(path, {}))
        for cache in caches.values():
            for desc, scene in cache.values():
                scene.close()
    if cancel is None or not cancel():
        # `illum preconvolve` (its streamed scan of the source) with each method, at 16x8.
        from .preconvolve import METHODS, preconvolve

        with step("illum preconvolve", f"{', '.join(METHODS)} methods"), \
                tempfile.TemporaryDirectory(prefix="illum-warmup-") as d:
            for m in METHODS:
                preconvolve(os.path.join(_STAGES, "textures", "sky_latlong.exr"), os.path.join(d, f"{m}.exr"),
                            size=16, method=m)
    if routes is ROUTES and (cancel is None or not cancel()):
        _write_stamp()
    return {"skipped": False, "seconds": time.perf_counter() - t_start, "kernels_compiled": COMPILES.kernels - k_start,
            "compile_seconds": COMPILES.seconds() - c_start, "routes": len(routes)}


def kernel_coverage() -> tuple[int, list[str]]:
    """(the number of renderer kernels with a compiled signature in this process, the names of
    those without one). Imports every renderer module first, so a kernel no route reached shows
    up as not exercised. Kernels inlined into their callers (``inline="always"``) have no code of
    their own and are left out."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import renderer

    for info in pkgutil.walk_packages(renderer.__path__, "renderer."):
        importlib.import_module(info.name)
    ready, missed = 0, []
    for name, mod in sorted(sys.modules.items()):
        if not name.startswith("renderer.") or mod is None:
            continue
        for attr, v in vars(mod).items():
            if (isinstance(v, CPUDispatcher) and v.py_func.__module__ == name
                    and v.targetoptions.get("inline") != "always"):
                if v.signatures:
                    ready += 1
                else:
                    missed.append(f"{name}.{attr}")
    return ready, missed


def register_cli(sub) -> None:
    """`illum warmup`: fill the kernel cache (see the module docstring)."""
    p = sub.add_parser("warmup", help="compile every kernel into numba's cache ahead of the first render")
    p.add_argument("--threads", type=int, default=None, help="render threads (default: all cores)")
    p.add_argument("--verbose", action="store_true", help="also list the kernels no warm-up route calls")
    p.add_argument("--quiet", action="store_true", help="print only the summary line")
    p.add_argument("--if-needed", action="store_true",
                   help="do nothing if a warm-up already finished for this numba, CPU and source tree")
    p.set_defaults(func=cmd_warmup)


def cmd_warmup(a) -> int:
    out = sys.stderr
    t_start = time.perf_counter()
    if a.if_needed and is_warm():
        print(f"illum warmup: the kernel cache is warm ({_stamp_path()})", file=out)
        return 0
    if not a.quiet:
        print(f"illum warmup: rendering {len(ROUTES)} routes at {WARMUP_RES[0]}x{WARMUP_RES[1]}, "
              f"{WARMUP_SPP} spp; kernel cache: {cache_location()}", file=out, flush=True)
    res = warmup(report=None if a.quiet else (lambda line: print(f"  {line}", file=out, flush=True)),
                 threads=a.threads)
    # (How many kernels the process holds is no measure of coverage on a warm cache: a kernel
    # loaded from it brings the helpers compiled into it without loading them.)
    print(f"illum warmup: {res['routes']} routes rendered, {res['kernels_compiled']} kernels compiled "
          f"({res['compile_seconds']:.1f} s), {time.perf_counter() - t_start:.1f} s in all", file=out)
    if a.verbose and res["kernels_compiled"] == 0:
        print("illum warmup: the cache was warm; with a fresh NUMBA_CACHE_DIR --verbose lists the kernels "
              "no route calls", file=out)
    elif a.verbose:
        missed = kernel_coverage()[1]
        print(f"illum warmup: {len(missed)} kernels no route calls (tests and tools only):", file=out)
        for name in missed:
            print(f"  {name}", file=out)
    return 0
