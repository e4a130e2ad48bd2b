"""Process lifetime: the server's children die with it, even on ``kill -9``."""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def die_with_parent(expected_parent: int | None = None) -> None:
    """Ask Linux to SIGKILL this process when the thread that spawned it exits (the server's
    long-lived supervisor or checker thread, so in effect the server). Then, because the parent
    may have died before the request took effect, exit at once if the parent is no longer
    ``expected_parent`` (when given). Elsewhere than Linux only that check is made."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except OSError:
            pass
    if expected_parent is not None and os.getppid() != expected_parent:
        os._exit(3)
