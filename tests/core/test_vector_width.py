"""ILLUM_VECTOR_WIDTH: which numba CPU feature string the package sets at import (renderer/__init__.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from renderer import _vector_width_features

HOST = "+64bit,+avx,+avx2,+avx512f,+avx512vl,+fma"
NO_512 = "+64bit,+avx,+avx2,-avx512f,+fma"
WIDE = HOST + ",-prefer-256-bit,-prefer-128-bit"


def test_auto_prefers_512_bit_vectors_on_cpus_that_keep_their_clock():
    assert _vector_width_features("auto", "sapphirerapids", HOST) == WIDE
    assert _vector_width_features("auto", "znver4", HOST) == WIDE


def test_auto_keeps_llvm_default_on_downclocking_or_avx2_only_cpus():
    assert _vector_width_features("auto", "skylake-avx512", HOST) is None
    assert _vector_width_features("auto", "cascadelake", HOST) is None
    assert _vector_width_features("auto", "haswell", NO_512) is None


def test_explicit_widths():
    assert _vector_width_features("512", "skylake-avx512", HOST) == WIDE
    assert _vector_width_features("512", "haswell", NO_512) is None  # nothing to widen to
    assert _vector_width_features("256", "sapphirerapids", HOST) is None


def test_a_bad_value_names_the_variable():
    with pytest.raises(ValueError, match="ILLUM_VECTOR_WIDTH"):
        _vector_width_features("1024", "sapphirerapids", HOST)


def test_numba_cpu_features_set_by_the_user_wins():
    """With NUMBA_CPU_FEATURES set, importing the package leaves numba's features alone."""
    env = dict(os.environ, NUMBA_CPU_FEATURES="+64bit,+sse2", ILLUM_VECTOR_WIDTH="512")
    out = subprocess.run([sys.executable, "-c", "import renderer; from numba.core import config; "
                          "print(config.CPU_FEATURES)"], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "+64bit,+sse2"


def test_a_bad_environment_value_warns_and_renders_with_the_default():
    """Importing the package with ILLUM_VECTOR_WIDTH=1024 warns, naming the variable, and keeps
    going with auto (a performance setting must not stop a render)."""
    env = dict(os.environ, ILLUM_VECTOR_WIDTH="1024")
    env.pop("NUMBA_CPU_FEATURES", None)
    out = subprocess.run([sys.executable, "-c", "import renderer; print('imported')"], env=env,
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "imported"
    assert "ILLUM_VECTOR_WIDTH" in out.stderr and "using auto" in out.stderr
