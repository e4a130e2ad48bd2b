"""Count calls of chosen functions without replacing anything (no mocks).

``CallCounter`` installs a profile hook (``sys.setprofile`` and ``threading.setprofile``) that
counts the Python-level 'call' events whose code object is one of the watched functions'. The
watched functions run unchanged; the counter only observes them. Renders under it should use
``threads=1`` so that every call happens on a thread the hook sees.

    with CallCounter(LightSet.le_escaped, PathIntegrator._add_escaped) as calls:
        render(...)
    assert calls[LightSet.le_escaped] == 0
"""

from __future__ import annotations

import sys
import threading


class CallCounter:
    """counts[f]: calls of each watched f. capture={f: "arg"}: also keep a copy of argument
    ``arg`` of every call of f in ``captured[f]`` (read from the new frame, nothing altered)."""

    def __init__(self, *functions, capture: dict | None = None):
        self._capture = {}
        self.captured = {}
        for f, name in (capture or {}).items():
            code = getattr(f, "__code__", None)
            self._capture[code] = (f, name)
            self.captured[f] = []
        self._codes = {}
        for f in functions:
            code = getattr(f, "__code__", None) or getattr(getattr(f, "__func__", None), "__code__", None)
            if code is None:
                raise TypeError(f"{f!r} is not a Python function")
            self._codes[code] = f
        self.counts = {f: 0 for f in functions}

    def _hook(self, frame, event, arg):
        if event == "call":
            f = self._codes.get(frame.f_code)
            if f is not None:
                self.counts[f] += 1
            cap = self._capture.get(frame.f_code)
            if cap is not None:
                import copy

                self.captured[cap[0]].append(copy.deepcopy(frame.f_locals.get(cap[1])))

    def __enter__(self):
        for code, (f, _) in self._capture.items():
            if f not in self.counts:
                self._codes[code] = f
                self.counts[f] = 0
        self._old = sys.getprofile()
        self._old_thread = threading.getprofile() if hasattr(threading, "getprofile") else None
        threading.setprofile(self._hook)
        sys.setprofile(self._hook)
        return self.counts

    def __exit__(self, *exc):
        sys.setprofile(self._old)
        threading.setprofile(self._old_thread)
        return False
