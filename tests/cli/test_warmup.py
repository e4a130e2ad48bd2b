"""Cold start (renderer/warmup.py): compiles are noticed, kept out of the time budget, and
`illum warmup` leaves a first render nothing to compile."""

import io
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from numba import njit

from renderer.warmup import CompileNotice, CompileWatch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STAGES = os.path.join(ROOT, "stages")


def _fresh_kernel():
    """A new dispatcher (no cache) calling another new one, so both compile on the first call:
    the outer kernel's typing compiles the inner one inside its own compile event."""

    @njit(cache=False)
    def inner(x):
        return x * 2.0

    @njit(cache=False)
    def outer(x):
        return inner(x) + 1.0

    return outer


def test_compile_watch_counts_real_compiles_once():
    outer = _fresh_kernel()
    with CompileWatch() as watch:
        t0 = time.perf_counter()
        assert outer(1.0) == 3.0
        wall = time.perf_counter() - t0
        assert watch.kernels == 2
        seconds = watch.seconds()
        # The nested compile is inside the outer one's interval: counted once, never summed.
        assert 0.0 < seconds <= wall
        assert outer(2.0) == 5.0  # compiled signature: no event
        assert watch.kernels == 2 and watch.seconds() == seconds
        assert outer(np.int64(2)) == 5.0  # a new signature compiles again (both kernels)
        assert watch.kernels == 4
    assert outer(np.float32(1.0)) == 3.0  # uninstalled: not counted
    assert watch.kernels == 4


def test_compile_notice_only_when_something_compiles():
    kernel = _fresh_kernel()
    out = io.StringIO()
    with CompileNotice(out):
        kernel(1.0)
    text = out.getvalue()
    assert text.startswith("illum: compiling kernels, first run only")
    assert "compiling tests.cli.test_warmup (1 kernels so far" in text  # the kernel's group, once
    assert text.count("compiling tests.cli.test_warmup") == 1
    assert text.splitlines()[-1].startswith("illum: compiled 2 kernels in ")

    warm = io.StringIO()
    with CompileNotice(warm):
        kernel(2.0)
    assert warm.getvalue() == ""


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_compile_notice_on_a_terminal_rewrites_one_line():
    outer = _fresh_kernel()
    term = _Terminal()
    with CompileNotice(term):
        outer(1.0)
    text = term.getvalue()
    # Two progress states on one line (carriage return + erase), then the summary on its own.
    assert text.count("\r\x1b[K") == 3 and text.count("\n") == 1
    assert "compiling kernels, first run only: 2 kernels" in text
    final = text.rsplit("\r\x1b[K", 1)[-1]
    assert final.startswith("illum: compiled 2 kernels in ") and final.endswith("later runs load them)\n")


def _illum(*args, env):
    return subprocess.run([sys.executable, "-m", "renderer.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, env=env, timeout=3600)


# Renders that follow `illum warmup`: the routes of the warm-up (fast and general path,
# estimators, light kinds, the irradiance table's kernels in a fresh ILLUM_CACHE_DIR).
WARM_CASES = [
    ("cornell_box.usda", "--res", 64, 64, "--spp", 1),
    ("talk/dome.usda", "--res", 32, 32, "--spp", 1, "--estimator", "controlVariate"),
    ("shaping/spotlights.usda", "--res", 32, 32, "--spp", 1),
    ("instanced.usda", "--res", 32, 32, "--spp", 1, "--no-fast-path", "--estimator", "*=ratio"),
    ("lux_extra/mesh_light_room.usda", "--res", 32, 32, "--spp", 1),
]


def _warmup_then_nothing_compiles(tmp_path, env):
    w = _illum("warmup", env=env)
    assert w.returncode == 0, w.stderr
    assert "routes rendered" in w.stderr and "illum preconvolve" in w.stderr
    for i, (stage, *args) in enumerate(WARM_CASES):
        stats = tmp_path / f"warm{i}.json"
        r = _illum("render", os.path.join(STAGES, stage), "-o", tmp_path / f"warm{i}.exr", *args,
                   "--stats", stats, env=env)
        assert r.returncode == 0, r.stderr
        assert "compiling" not in r.stderr, (stage, r.stderr)
        assert json.loads(stats.read_text())["kernels_compiled"] == 0, stage


def test_warmup_leaves_nothing_to_compile(tmp_path):
    """The reduced form of the cold test below, on the suite's own kernel cache (warm after the
    install's `illum warmup`, or made warm here by the warm-up under test)."""
    env = dict(os.environ, ILLUM_CACHE_DIR=str(tmp_path / "irradiance"))
    _warmup_then_nothing_compiles(tmp_path, env)


@pytest.mark.heavy
def test_cold_render_says_so_and_warmup_leaves_nothing_to_compile(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), ILLUM_CACHE_DIR=str(tmp_path / "irradiance"))
    cornell = os.path.join(STAGES, "cornell_box.usda")

    # A cold kernel cache: the render compiles, says so, and its time budget renders passes
    # after the compile instead of being spent on it.
    stats = tmp_path / "cold.json"
    r = _illum("render", cornell, "-o", tmp_path / "cold.exr", "--res", 64, 64, "--time-budget", 1,
               "--stats", stats, env=env)
    assert r.returncode == 0, r.stderr
    assert "compiling kernels, first run only" in r.stderr
    s = json.loads(stats.read_text())
    assert s["kernels_compiled"] > 0
    assert s["seconds"]["compile"] > 1.0  # the compile alone outlasts the budget ...
    assert s["spp"] > 1  # ... and still passes were rendered after it

    # Warm: the routes of the warm-up compile nothing and print nothing about compiling.
    _warmup_then_nothing_compiles(tmp_path, env)
