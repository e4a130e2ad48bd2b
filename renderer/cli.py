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
    """A tqdm bar on a TTY; `ALF_PROGRESS nn%` lines otherwise (the render-farm convention)."""

    def __init__(self, quiet: bool, before_bar=None):
        self.quiet = quiet
        self.before_bar = before_bar  # ends a compile notice's line before the bar takes over
        self.tty = sys.stderr.isatty()
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


def cmd_render(a) -> int:
    from contextlib import nullcontext

    from .render import render, write_outputs
    from .warmup import CompileNotice

    opts = options_from_args(a)
    # Says "compiling kernels, first run only" with progress if the kernel cache is cold.
    notice = nullcontext() if a.quiet else CompileNotice(sys.stderr)
    prog = _Progress(a.quiet, before_bar=getattr(notice, "finish", None))
    try:
        with notice:
            result = render(a.stage, opts, progress=prog)
    finally:
        prog.close()
    out = a.output or result.stats.get("product_name") or None
    if out is None:
        base = os.path.splitext(os.path.basename(a.stage))[0]
        out = base + ".exr"
    write_outputs(result, exr=out, png=a.preview, stats_json=a.stats)
    if not a.quiet:
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
    p = argparse.ArgumentParser(prog="illum", description="USD-native path tracer")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a USD stage to EXR")
    r.add_argument("stage", help=".usda/.usdc/.usdz stage")
    r.add_argument("-o", "--output", help="output EXR (default: the RenderProduct's productName, else STAGE.exr)")
    add_render_flags(r, "render")
    r.add_argument("--preview", metavar="OUT.png", help="also write an sRGB PNG preview")
    r.add_argument("--stats", metavar="OUT.json", help="write render statistics as JSON")
    r.add_argument("--quiet", action="store_true")
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
