"""Keep freed memory in the process between bounces (glibc malloc tuning), once per process.

A wavefront bounce allocates and frees dozens of numpy temporaries of 0.1-3 MB (16384 rays x
a few float64 columns). With glibc's defaults, freeing them shrinks the heap (the top chunk
above M_TRIM_THRESHOLD, 128 KiB by default, is given back to the kernel) and the next bounce
page-faults the same memory back in, zeroed. Measured on the Cornell box (256^2, depth 8, one
thread, CPU time, alternated runs): 290-380 k samples/CPU-s with the defaults, 400-420 k with
the trim threshold at 512 MiB and 64 MiB of top padding. The cost is that a process keeps up to
512 MiB of freed heap instead of returning it to the system: fine for a render process or a
render-service worker; ILLUM_MALLOC_TUNING=0 turns it off (e.g. when illum runs inside a DCC
that manages its memory tightly). Applied by ``render()``; it changes nothing but speed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading

M_TRIM_THRESHOLD = -1  # <malloc.h>
M_TOP_PAD = -2
TRIM_THRESHOLD = 512 * 1024 * 1024
TOP_PAD = 64 * 1024 * 1024

_lock = threading.Lock()
_state: dict = {}


def tune_allocator() -> bool:
    """Apply the tuning once (later calls return the first answer). True if glibc accepted it;
    False where it is off (ILLUM_MALLOC_TUNING=0) or not glibc (macOS, musl: nothing to do)."""
    with _lock:
        if "applied" in _state:
            return _state["applied"]
        ok = False
        if os.environ.get("ILLUM_MALLOC_TUNING", "1") != "0":
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                mallopt = libc.mallopt
                mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
                ok = bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)) and bool(mallopt(M_TOP_PAD, TOP_PAD))
            except (OSError, AttributeError):
                ok = False
        _state["applied"] = ok
        return ok
