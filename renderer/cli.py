"""`illum` command line: render (husk/usdrecord style) and the project's other tools.

Exit codes: 0 success, 2 a user error (bad stage, bad flag, bad value: one line naming the
file, prim and attribute), 1 an internal error. Tracebacks only with --debug.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .errors import IllumError


def add_render_flags(p: argparse.ArgumentParser, route: str = "render") -> None:
    """The render flags of `illum render` (route "render") or `illum submit` (route "submit"):
    every option renderer/options.py declares for that route."""
    from .options import add_flags

    add_flags(p, route)


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


def cmd_render(a) -> int:
    from contextlib import nullcontext

    from .output import DISPLAY_EXTENSIONS, IMAGE_EXTENSIONS
    from .render import render, write_outputs
    from .warmup import CompileNotice

    level, alfred = a.verbosity if a.verbosity is not None else (DEFAULT_VERBOSITY, False)
    if a.quiet:
        level = 0
    opts = options_from_args(a)
    wanted = [("--output", a.output, IMAGE_EXTENSIONS), ("--preview", a.preview, DISPLAY_EXTENSIONS),
              ("--stats", a.stats, None)]
    _check_outputs(a, [w for w in wanted if w[1]])
    out = a.output

    def on_loaded(desc) -> None:
        nonlocal out
        if out is None:  # the RenderProduct's productName, else STAGE.exr, checked before rendering
            out = desc.settings.product_name or os.path.splitext(os.path.basename(a.stage))[0] + ".exr"
            argument = "productName" if desc.settings.product_name else "--output"
            _check_outputs(a, [(argument, out, IMAGE_EXTENSIONS)] + [w for w in wanted if w[1]])

    # Says "compiling kernels, first run only" with progress if the kernel cache is cold.
    notice = nullcontext() if level < 2 else CompileNotice(sys.stderr)
    prog = _Progress(level < 2, before_bar=getattr(notice, "finish", None), alfred=alfred)
    try:
        with notice:
            result = render(a.stage, opts, progress=prog, on_loaded=on_loaded)
    finally:
        prog.close()
    write_outputs(result, exr=out, png=a.preview, stats_json=a.stats, compression=a.exr_compression,
                  half=a.half)
    if level >= 1:
        for w in result.warnings:
            print(f"illum: warning: {w}", file=sys.stderr)
        s = result.stats
        print(f"illum: wrote {out} ({s['resolution'][0]}x{s['resolution'][1]}, {s['spp']} spp, "
              f"{s['seconds']['render']:.1f} s, {s['samples_per_second'] / 1e3:.0f} ksamples/s)", file=sys.stderr)
        if a.preview:
            print(f"illum: wrote {a.preview}", file=sys.stderr)
    return 0


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
    r.add_argument("-o", "--output", help="output EXR (default: the RenderProduct's productName, else STAGE.exr)")
    add_render_flags(r, "render")
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
