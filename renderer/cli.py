"""`illum` command line: render (husk/usdrecord style) and the project's other tools.

Exit codes: 0 success, 2 a user error (bad stage, bad flag, bad value: one line naming the
file, prim and attribute), 1 an internal error. Tracebacks only with --debug.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from .errors import IllumError


def add_render_flags(p: argparse.ArgumentParser, route: str = "render", ranges: bool = False) -> None:
    """The render flags of `illum render` (route "render") or `illum submit` (route "submit"):
    every option renderer/options.py declares for that route; ``ranges``: the frame-range
    options (RANGE_OPTIONS) instead."""
    from .options import OPTIONS, RANGE_OPTIONS, add_flags

    add_flags(p, route, RANGE_OPTIONS if ranges else OPTIONS)


def options_from_args(a, route: str = "render") -> "RenderOptions":
    """Parsed render flags -> a validated RenderOptions (SettingsError, exit 2, on a bad value)."""
    from .options import options_from_args as from_args

    return from_args(a, route)


class _Progress:
    """A tqdm bar on a TTY; `ALF_PROGRESS nn%` lines otherwise (the render-farm convention), or
    always with ``alfred`` (husk's ``-V`` suffix ``a``)."""

    def __init__(self, quiet: bool, before_bar=None, alfred: bool = False):
        self.quiet = quiet
        self.before_bar = before_bar  # ends a compile notice's line before the bar takes over
        self.tty = sys.stderr.isatty() and not alfred
        self.bar = None
        self.last = -1

    def __call__(self, done: int, target, fraction: float) -> None:
        if self.quiet:
            return
        pct = int(fraction * 100)
        if self.tty:
            if self.bar is None:
                from tqdm import tqdm

                if self.before_bar is not None:
                    self.before_bar()
                self.bar = tqdm(total=100, unit="%", desc="render", file=sys.stderr)
            self.bar.n = pct
            self.bar.set_postfix(spp=done)
            self.bar.refresh()
        elif pct != self.last:
            print(f"ALF_PROGRESS {pct}%", file=sys.stdout, flush=True)
            self.last = pct

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


# husk's -V LEVEL: a digit, optionally followed by "a" (Alfred-style ALF_PROGRESS lines even on
# a terminal). What each level prints (the README says it too):
VERBOSITY = {0: "errors only (as --quiet)", 1: "warnings and one line per file written",
             2: "and progress (the default)", 3: "and each frame's load, build, render and write seconds",
             4: "and each frame's rays, samples/s and per-light estimators"}
DEFAULT_VERBOSITY = 2


def _verbosity(text: str) -> tuple[int, bool]:
    """-V LEVEL -> (level 0..9, alfred progress)."""
    import re

    m = re.fullmatch(r"(\d)?(a)?", text or "")
    if not text or m is None:
        raise argparse.ArgumentTypeError(f"-V expects a level 0-9, optionally followed by 'a', got {text!r}")
    return int(m.group(1) or DEFAULT_VERBOSITY), bool(m.group(2))


def _check_outputs(a, paths: list[tuple[str, str, object]]) -> None:
    """Refuse, before anything is read or rendered, every output that cannot be written
    (renderer/output.py check_output_path): (argument, path, allowed extensions) triples."""
    from .errors import SettingsError
    from .output import DISPLAY_EXTENSIONS, check_output_path, display_encode

    probed: set = set()
    seen: dict = {}
    for argument, path, extensions in paths:
        check_output_path(path, argument, extensions=extensions, inputs=(a.stage,),
                          make_dirs=a.make_output_path, probed=probed)
        key = os.path.realpath(path)
        if key in seen:
            raise SettingsError(f"{path} is also the {seen[key]} output", attribute=argument)
        seen[key] = argument
    if os.environ.get("OCIO") and any(os.path.splitext(p)[1].lower() in DISPLAY_EXTENSIONS for _, p, _ in paths):
        import numpy as np

        display_encode(np.zeros((1, 1, 3), np.float32))  # a config OCIO cannot use fails here, not after


def _frames(a, opts) -> list:
    """The frames to render (renderer/frames.py frame_list)."""
    from .frames import frame_list

    return frame_list(opts.frame, a.frame_count, a.frame_inc, a.frames)


class _Range:
    """Progress over a frame range: the render callback's fraction of the current frame becomes
    the range's (ALF_PROGRESS lines, or the bar on a terminal, count the whole range) and the
    bar names the frame."""

    def __init__(self, prog: _Progress, count: int):
        self.prog, self.count, self.index, self.frame = prog, count, 0, None

    def __call__(self, done: int, target, fraction: float) -> None:
        if self.prog.bar is not None and self.count > 1:
            self.prog.bar.set_description(f"frame {self.frame:g} [{self.index + 1}/{self.count}]")
        self.prog(done, target, (self.index + fraction) / self.count)


def cmd_render(a) -> int:
    import dataclasses
    from contextlib import nullcontext

    from .errors import SettingsError
    from .frames import frame_name, has_frame_token
    from .output import DISPLAY_EXTENSIONS, IMAGE_EXTENSIONS
    from .render import render, write_json, write_outputs
    from .usd.stage_reader import open_stage
    from .warmup import CompileNotice

    level, alfred = a.verbosity if a.verbosity is not None else (DEFAULT_VERBOSITY, False)
    if a.quiet:
        level = 0
    opts = options_from_args(a)
    frames = _frames(a, opts)
    many = len(frames) > 1
    given = [(arg, t, ext) for arg, t, ext in (("--output", a.output, IMAGE_EXTENSIONS),
                                               ("--preview", a.preview, DISPLAY_EXTENSIONS)) if t]
    # One --stats file for a range without a frame token holds every frame's statistics.
    stats_per_frame = bool(a.stats) and (not many or has_frame_token(a.stats))
    if a.stats and stats_per_frame:
        given.append(("--stats", a.stats, None))
    elif a.stats:
        _check_outputs(a, [("--stats", a.stats, None)])

    def check_names(templates, known_frames) -> None:
        """Every frame's output names, before any frame renders: writable, and distinct."""
        for arg, template, _ in templates:
            if many and not has_frame_token(template):
                raise SettingsError(f"{template} names no frame ($F, $F4, ####): each of the {len(frames)} "
                                    f"frames would overwrite it", attribute=arg)
        _check_outputs(a, [(arg, frame_name(t, f), ext) for f in known_frames for arg, t, ext in templates])

    if frames[0] is not None:
        check_names(given, frames)
    templates = list(given)

    def on_loaded(desc) -> None:
        """First frame only: the stage's start frame, and the productName (else STAGE.exr)."""
        nonlocal frames, templates
        if frames[0] is None:
            t0 = desc.time_code
            frames = [t0] + [t0 + k * inc for k, inc in frames[1:]]
        if not a.output:
            product = desc.settings.product_name
            name = product or os.path.splitext(os.path.basename(a.stage))[0] + ("_$F4" if many else "") + ".exr"
            templates = [("productName" if product else "--output", name, IMAGE_EXTENSIONS)] + templates
        check_names(templates, frames)

    # A range composes the stage once and decodes each texture once (render(shared=...)).
    if many:
        from .deadline import deadline

        with deadline(opts.load_timeout, "opening the stage", file=a.stage):
            shared = {"stage": open_stage(a.stage)}
    else:
        shared = None
    # Says "compiling kernels, first run only" with progress if the kernel cache is cold.
    notice = nullcontext() if level < 2 else CompileNotice(sys.stderr)
    prog = _Progress(level < 2, before_bar=getattr(notice, "finish", None), alfred=alfred)
    progress = _Range(prog, len(frames))
    all_stats = []
    t_range = time.perf_counter()
    try:
        for k in range(len(frames)):
            progress.index = k
            progress.frame = frames[k] if frames[k] is not None else 0.0
            frame_opts = dataclasses.replace(opts, frame=frames[k])
            with notice if k == 0 else nullcontext():
                result = render(a.stage, frame_opts, progress=progress, shared=shared,
                                on_loaded=on_loaded if k == 0 else None)
            f = result.metadata["illum:frame"]
            names = {arg: frame_name(t, f) for arg, t, _ in templates}
            result.stats["frame"] = f
            out = names.get("productName") or names["--output"]
            write_outputs(result, exr=out, png=names.get("--preview"), stats_json=names.get("--stats"),
                          compression=a.exr_compression, half=a.half)
            if a.stats and not stats_per_frame:
                all_stats.append(result.stats)
                write_json(a.stats, {"frames": all_stats, "range": _range_summary(all_stats, t_range)})
            _report(level, result, out, names.get("--preview"), k, len(frames), prog)
    finally:
        prog.close()
    if level >= 1 and many:
        r = _range_summary(all_stats or [None] * len(frames), t_range)
        print(f"illum: {r['frames']} frames in {r['wall_seconds']:.1f} s ({r['frames_per_minute']:.1f} frames/min)",
              file=sys.stderr)
    return 0


def _range_summary(stats: list, t_start: float) -> dict:
    wall = time.perf_counter() - t_start
    return {"frames": len(stats), "wall_seconds": wall, "frames_per_minute": 60.0 * len(stats) / max(wall, 1e-9)}


def _report(level: int, result, out: str, preview, k: int, count: int, prog: _Progress) -> None:
    """What -V LEVEL prints after a frame (VERBOSITY)."""
    if level < 1:
        return
    lines = [f"illum: warning: {w}" for w in result.warnings] if k == 0 else []
    s = result.stats
    head = f"illum: frame {s['frame']:g} [{k + 1}/{count}]: " if count > 1 else "illum: "
    lines.append(f"{head}wrote {out} ({s['resolution'][0]}x{s['resolution'][1]}, {s['spp']} spp, "
                 f"{s['seconds']['render']:.1f} s, {s['samples_per_second'] / 1e3:.0f} ksamples/s)")
    if preview:
        lines.append(f"{head}wrote {preview}")
    if level >= 3:
        lines.append(head + ", ".join(f"{phase} {sec:.2f} s" for phase, sec in s["seconds"].items()))
    if level >= 4:
        lines.append(f"{head}rays {json.dumps(s['rays'])}, {s['mrays_per_second']:.2f} Mrays/s, lights " +
                     ", ".join(f"{li['path']}={li['estimator']}" for li in s["lights"]))
    write = prog.bar.write if prog.bar is not None else (lambda t: print(t, file=sys.stderr))
    for line in lines:
        write(line)


# Modules exposing register_cli(subparsers): each adds its subcommand(s) with set_defaults(func=...).
_SUBCOMMAND_MODULES = ("renderer.preconvolve", "renderer.bench", "renderer.warmup", "service.cli")


def build_parser() -> argparse.ArgumentParser:
    from .output import EXR_COMPRESSIONS
    from .render import VERSION

    p = argparse.ArgumentParser(prog="illum", description="USD-native path tracer")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument("--version", action="version", version=f"illum {VERSION}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a USD stage to EXR")
    r.add_argument("stage", help=".usda/.usdc/.usdz stage")
    r.add_argument("-o", "--output", help="output image: .exr, or display-referred .png/.jpg/.tif; $F, $F4, #### "
                   "become the frame (default: the RenderProduct's productName, else STAGE.exr)")
    add_render_flags(r, "render")
    add_render_flags(r, "render", ranges=True)
    r.add_argument("--preview", metavar="OUT.png", help="also write a display-referred preview (.png, .jpg, .tif)")
    r.add_argument("--stats", metavar="OUT.json", help="write render statistics as JSON")
    r.add_argument("--make-output-path", action="store_true",
                   help="create missing output directories (else a missing directory is an error)")
    r.add_argument("--exr-compression", choices=EXR_COMPRESSIONS, default="zip",
                   help="EXR compression (default zip; dwaa is lossy)")
    r.add_argument("--half", action="store_true", help="write the EXR's pixels as 16-bit half floats")
    r.add_argument("-V", "--verbose", dest="verbosity", type=_verbosity, metavar="LEVEL",
                   help="verbosity 0-9 as husk's -V (0 errors only, 1 warnings and files written, 2 progress "
                        "(default), 3 per-frame phase times, 4 per-frame ray and light statistics); a trailing "
                        "'a' prints ALF_PROGRESS lines even on a terminal")
    r.add_argument("--quiet", action="store_true", help="as -V 0")
    r.add_argument("--version", action="version", version=f"illum {VERSION}")
    # SUPPRESS: an unset subcommand flag must not overwrite `illum --debug render ...`.
    r.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")
    r.set_defaults(func=cmd_render)

    # Other tools register their own subcommands (each module owns its flags and handler).
    import importlib

    for module in _SUBCOMMAND_MODULES:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name != module:
                raise
            continue
        mod.register_cli(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    try:
        return int(a.func(a) or 0)
    except IllumError as e:
        if a.debug:
            raise
        print(f"illum: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("illum: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # an internal error: one line unless --debug
        if a.debug:
            raise
        print(f"illum: internal error: {type(e).__name__}: {e} (rerun with --debug for a traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
