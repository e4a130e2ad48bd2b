"""A deadline for work that can block in C++: opening a stage, reading and decoding its assets.

USD and OpenImageIO read files in C++, where Python cannot interrupt them: a layer on a hung
network mount, or a value-clip layer that is a FIFO, would block ``Usd.Stage.Open`` forever
(FIFOs and devices named as the stage, a sublayer, reference, payload or texture are refused
before anything opens them: renderer/usd). ``deadline(seconds, what)`` watches a block from a
helper thread. When time is up it raises ``LoadTimeout`` (exit 2, one line naming the file) in
the blocked thread, which takes effect as soon as that thread runs Python again; if it has not
left the block GRACE seconds later it is stuck in C++, and the process's stuck handler runs:
by default the message on stderr and exit code 2 (``illum render``); a service worker installs
one that fails its job first (service/worker.py).
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from contextlib import contextmanager
from typing import Callable, Iterator

from .errors import IllumError

__all__ = ["LoadTimeout", "deadline", "set_stuck_handler", "GRACE"]

GRACE = 2.0  # seconds the blocked thread has to leave the block once LoadTimeout is raised in it


class LoadTimeout(IllumError):
    """Opening or reading a stage took longer than its deadline."""


def _exit_stuck(message: str) -> None:
    print(f"illum: error: {message}", file=sys.stderr, flush=True)
    os._exit(2)


_on_stuck: Callable[[str], None] = _exit_stuck


def set_stuck_handler(handler: Callable[[str], None]) -> None:
    """What this process does when a thread stays blocked past its deadline (the message names
    the file and the deadline); it must not return normally (the thread cannot be freed)."""
    global _on_stuck
    _on_stuck = handler


def _raise_in(thread_id: int, exc: type | None) -> None:
    """Raise ``exc`` in the thread at its next Python instruction (None: withdraw a pending one)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id),
                                               ctypes.py_object(exc) if exc is not None else None)


@contextmanager
def deadline(seconds: float | None, what: str, *, file: str = "", option: str = "--load-timeout") -> Iterator[None]:
    """Run the ``with`` block under a deadline of ``seconds`` (None or 0: none). ``what`` says
    what was under way ("opening the stage"), ``file`` which file, ``option`` how to allow more."""
    if not seconds:
        yield
        return
    message = str(LoadTimeout(f"{what} did not finish within {seconds:g} s ({option}); a file that never "
                               f"finishes reading (a FIFO, a hung network mount)?", file=file))
    timeout = type("LoadTimeout", (LoadTimeout,), {"__init__": lambda self: LoadTimeout.__init__(
        self, message.removeprefix(f"{file}: ") if file else message, file=file)})
    target = threading.get_ident()
    lock = threading.Lock()
    state = {"done": False, "raised": False}
    finished = threading.Event()

    def watch() -> None:
        if finished.wait(seconds):
            return
        with lock:
            if state["done"]:
                return
            state["raised"] = True
            _raise_in(target, timeout)
        if not finished.wait(GRACE):
            _on_stuck(message)

    watcher = threading.Thread(target=watch, name="illum-deadline", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        with lock:
            state["done"] = True
            if state["raised"]:
                _raise_in(target, None)  # not delivered inside the block: it must not land outside
        finished.set()
