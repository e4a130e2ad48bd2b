"""Frame ranges as husk spells them, and output file names per frame.

* ``--frame F --frame-count N --frame-inc I``: N frames F, F + I, ... (husk's -f / -n / -i);
* ``--frames SPEC``: a comma-separated list of ``A``, ``A-B`` or ``A-BxS`` items (``1-100x2``:
  1, 3, ..., 99), in the order given.

Output names substitute the frame (Houdini's variables): ``$F`` the integer frame, ``$F4`` (any
digit) zero-padded to that width, ``${F4}`` the same, ``$FF`` the frame as a decimal (``12.5``),
and a run of ``#`` zero-padded to its length (``####`` = ``$F4``). A fractional frame rounds to
the nearest integer in the integer forms (two frames landing on one name is refused by the CLI).
"""

from __future__ import annotations

import math
import re

from .errors import SettingsError

__all__ = ["frame_list", "parse_frames", "frame_range", "has_frame_token", "frame_name", "MAX_FRAMES"]

MAX_FRAMES = 100_000
_NUM = r"-?\d+(?:\.\d+)?"
_ITEM = re.compile(rf"^\s*({_NUM})(?:\s*-\s*({_NUM})(?:\s*x\s*(\d+(?:\.\d+)?))?)?\s*$")
_TOKEN = re.compile(r"\$FF|\$\{F(\d?)\}|\$F(\d?)|(#+)")


def frame_range(start: float, count: int, inc: float = 1.0, attribute: str = "--frame-count") -> list[float]:
    """``count`` frames from ``start`` by ``inc`` (husk's -f / -n / -i)."""
    if not (isinstance(count, int) and 1 <= count <= MAX_FRAMES):
        raise SettingsError(f"must be an integer in [1, {MAX_FRAMES}], got {count!r}", attribute=attribute)
    if not (math.isfinite(inc) and inc > 0.0):
        raise SettingsError(f"must be a number > 0, got {inc!r}", attribute="--frame-inc")
    if not math.isfinite(start):
        raise SettingsError(f"must be finite, got {start!r}", attribute="--frame")
    return [start + k * inc for k in range(count)]


def parse_frames(spec: str) -> list[float]:
    """``--frames`` SPEC -> the frames, in order (module docstring); SettingsError naming
    --frames for anything else."""
    frames: list[float] = []
    for item in (spec or "").split(","):
        m = _ITEM.match(item)
        if m is None:
            raise SettingsError(f"expected A, A-B or A-BxSTEP items separated by commas (e.g. 1-100x2), got "
                                f"{item.strip()!r}", attribute="--frames")
        a = float(m.group(1))
        b = float(m.group(2)) if m.group(2) is not None else a
        step = float(m.group(3)) if m.group(3) is not None else 1.0
        if b < a:
            raise SettingsError(f"range {item.strip()!r} ends before it starts", attribute="--frames")
        if step <= 0.0:
            raise SettingsError(f"range {item.strip()!r} has a step of 0", attribute="--frames")
        n = int(math.floor((b - a) / step + 1e-9)) + 1
        if len(frames) + n > MAX_FRAMES:
            raise SettingsError(f"more than {MAX_FRAMES} frames", attribute="--frames")
        frames += frame_range(a, n, step, attribute="--frames")
    return frames


def frame_list(frame: float | None, frame_count: int | None, frame_inc: float | None, frames: str | None) -> list:
    """The frames a range renders, from the range options (renderer/options.py RANGE_OPTIONS):
    ``frames`` SPEC, or ``frame`` with ``frame_count`` / ``frame_inc``; ``[frame]`` for one frame.
    Without ``frame`` the start is the stage's start time code, known only once the stage is read:
    the list is then ``[None, (1, inc), (2, inc), ...]``, offsets from that start. SettingsError
    naming the flag for a bad combination or value."""
    if frames is not None:
        if frame is not None or frame_count is not None or frame_inc is not None:
            raise SettingsError("cannot be combined with --frame, --frame-count or --frame-inc", attribute="--frames")
        return parse_frames(frames)
    if frame_count is None and frame_inc is None:
        return [frame]
    count = 1 if frame_count is None else frame_count
    inc = 1.0 if frame_inc is None else frame_inc
    listed = frame_range(0.0 if frame is None else frame, count, inc)
    return listed if frame is not None else [None] + [(k, inc) for k in range(1, count)]


def has_frame_token(template: str) -> bool:
    return _TOKEN.search(template or "") is not None


def frame_name(template: str, frame: float) -> str:
    """``template`` with every frame token replaced by ``frame`` (module docstring)."""
    def sub(m: re.Match) -> str:
        if m.group(0) == "$FF":
            return f"{frame:g}"
        width = len(m.group(3)) if m.group(3) else int(m.group(1) or m.group(2) or 0)
        n = math.floor(frame + 0.5)   # half up (Python's round() would send 2.5 to 2)
        return f"-{abs(n):0{max(width - 1, 0)}d}" if n < 0 else f"{n:0{width}d}"

    return _TOKEN.sub(sub, template)
