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


_GUARD_FD: int | None = None


def guard_process_group() -> None:
    """Start a watcher that SIGKILLs this process's whole process group once this process has
    exited, however it exited (``kill -9`` included).

    For a worker the supervisor starts as the leader of its own process group: a local Ray
    cluster the worker starts (GCS, raylet, and the raylet's DashboardAgent and RuntimeEnvAgent,
    which outlive a killed raylet) stays in that group, so nothing the worker started survives
    it. The watcher is ``sh`` blocked reading a pipe whose only write end is this process's (the
    descriptor is not inheritable, so Ray's children never hold it): end of file means this
    process is gone. Does nothing outside Linux or when this process does not lead its group."""
    global _GUARD_FD
    if _GUARD_FD is not None or not sys.platform.startswith("linux") or os.getpgid(0) != os.getpid():
        return
    import subprocess

    r, w = os.pipe()
    try:
        subprocess.Popen(["/bin/sh", "-c", f'read -r _ <&{r}; kill -KILL -"$1"', "illum-group-guard",
                          str(os.getpid())], pass_fds=(r,), stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        os.close(w)
        return
    finally:
        os.close(r)
    _GUARD_FD = w


def limit_resources(memory_bytes: int, cpu_seconds: int = 0) -> None:
    """Hard limits for this process and its children: address space (RLIMIT_AS; an allocation
    beyond it fails with MemoryError instead of waking the OOM killer) and CPU seconds. 0 leaves
    a limit as it is; a limit the system does not allow (or a non-POSIX system) is skipped."""
    try:
        import resource

        if memory_bytes > 0:
            resource.setrlimit(resource.RLIMIT_AS, (int(memory_bytes), int(memory_bytes)))
        if cpu_seconds > 0:
            resource.setrlimit(resource.RLIMIT_CPU, (cpu_seconds, cpu_seconds))
    except (ImportError, ValueError, OSError):  # not POSIX, or the hard limit is lower already
        pass
