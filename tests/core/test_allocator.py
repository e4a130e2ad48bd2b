"""The glibc malloc tuning (renderer/allocator.py): applied once, and off when asked."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

CODE = "from renderer.allocator import tune_allocator as t; print(t(), t())"


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
@pytest.mark.parametrize("env, expect", [({}, "True True"), ({"ILLUM_MALLOC_TUNING": "0"}, "False False")])
def test_tuning_applies_once_and_honours_the_opt_out(env, expect):
    import os

    full = {k: v for k, v in os.environ.items() if k != "ILLUM_MALLOC_TUNING"}
    full.update(env)
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, env=full, check=True)
    assert out.stdout.strip() == expect
