"""`illum` command line: render (husk/usdrecord style) and the project's other tools.

Exit codes: 0 success, 2 a user error (bad stage, bad flag, bad value: one line naming the
file, prim and attribute), 1 an internal error. Tracebacks only with --debug.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .errors import IllumError, SettingsError


def _positive_int(name):
    def conv(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} expects an integer, got {s!r}")
        return v
    return conv


def _float(name):
    def conv(s):
        try:
            return float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} expects a number, got {s!r}")
    return conv


def _overrides(values: list[str] | None, flag: str) -> dict:
    """Parse repeatable `TOKEN` (all lights) or `/Path/To/Light=TOKEN` (one light) flags."""
    out: dict = {}
    for v in values or []:
        if "=" in v:
            path, token = v.split("=", 1)
            if not path.startswith("/"):
                raise SettingsError(f"expected /Path/To/Light=VALUE, got {v!r}", attribute=flag)
            out[path] = token
        else:
            out[""] = v
    return out


def add_render_flags(p: argparse.ArgumentParser) -> None:
    """Render flags shared by `illum render` and `illum submit`."""
    p.add_argument("--spp", type=_positive_int("spp"), help="samples per pixel (default 64, or the time budget)")
    p.add_argument("--time-budget", type=_float("time-budget"), metavar="SECONDS",
                   help="stop after this many seconds of rendering")
    p.add_argument("--res", nargs=2, type=_positive_int("res"), metavar=("W", "H"), help="resolution override")
    p.add_argument("--camera", help="camera prim path (default: RenderSettings camera, else the first camera)")
    p.add_argument("--settings", help="RenderSettings prim path (default: the stage's renderSettingsPrimPath)")
    p.add_argument("--frame", type=_float("frame"), help="time code to render")
    p.add_argument("--seed", type=_positive_int("seed"), default=0)
    p.add_argument("--max-depth", type=_positive_int("max-depth"), default=8,
                   help="scattering events: 0 = emitters only, 1 = direct lighting (pbrt's maxdepth)")
    p.add_argument("--light-sampler", default="auto", help="lighting service: auto, exhaustive, uniform, power, bvh (auto: by light count)")
    p.add_argument("--emitter-samples", type=_positive_int("emitter-samples"), default=0, metavar="K",
                   help="camera rays per pixel and pass that see emitters directly (one continues as the "
                        "path): anti-aliases small bright lights on screen; 0 = auto (2 where subpixel "
                        "lights touch >= 1%% of the pixels, else 1)")
    p.add_argument("--no-fast-path", dest="fast_path", action="store_false",
                   help="always use the general integrator, even where the scene qualifies for the compiled "
                        "path vertex (stats 'fast_path' says whether it ran and why not)")
    p.add_argument("--estimator", action="append", metavar="[/Light=]TOKEN",
                   help="direct-lighting estimator for all lights, or /Path=TOKEN for one (repeatable)")
    p.add_argument("--cv-alpha", action="append", metavar="[/Light=]TOKEN")
    p.add_argument("--light-samples", action="append", metavar="[/Light=]N")
    p.add_argument("--purpose", action="append", help="purposes to render (default: RenderSettings includedPurposes)")


def options_from_args(a) -> "RenderOptions":
    from .render import RenderOptions

    samples = {}
    for k, v in _overrides(a.light_samples, "light-samples").items():
        try:
            samples[k] = int(v)
        except ValueError:
            raise SettingsError(f"expected an integer, got {v!r}", attribute="light-samples")
    return RenderOptions(
        spp=a.spp,
        time_budget=a.time_budget,
        resolution=tuple(a.res) if a.res else None,
        camera=a.camera,
        settings=a.settings,
        frame=a.frame,
        purposes=tuple(a.purpose) if a.purpose else None,
        seed=a.seed,
        threads=getattr(a, "threads", None),
        max_depth=a.max_depth,
        light_sampler=a.light_sampler,
        emitter_samples=a.emitter_samples,
        fast_path=a.fast_path,
        estimator=_overrides(a.estimator, "estimator"),
        cv_alpha=_overrides(a.cv_alpha, "cv-alpha"),
        light_samples=samples,
    )


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
    add_render_flags(r)
    r.add_argument("--threads", type=_positive_int("threads"), help="worker threads (default: all cores)")
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
