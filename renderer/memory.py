"""Memory a render will need, estimated before it is allocated, against a cap.

A small file can ask for a lot: a 62 KB PNG whose header says 60000 x 60000 decodes to tens of
GB, and an 80 KB usdc holds 10 M triangles (hundreds of bytes each once placed, tabled and in
the BVH). Rather than discover that as a MemoryError (or the OOM killer) minutes into a load,
the stage reader charges each mesh and each image to a ``MemoryBudget`` as soon as their counts
and headers are known, before their arrays are built, and render() charges the film before it
allocates it. Going over the cap raises ``MemoryLimitError`` (exit 2) naming what is too big.

The cap is ``--max-memory`` (``RenderOptions.max_memory``, bytes), else DEFAULT_FRACTION of
the memory this process may still allocate (``available_memory``). A service worker runs each
job under the server's per-job cap and under a hard address-space limit as well (service/).

The per-item costs were measured (machine shared with other jobs, 2 cores):
* a placed triangle: ~560 B at peak (a 980 k-triangle grid, ``illum render --spp 1 -j 1``:
  737 MB max RSS against 190 MB for the imported renderer): TRIANGLE_BYTES;
* a decoded texel: 32 B kept (float32 RGBA, and its sRGB-decoded copy) and ~48 B more while
  decoding (OpenImageIO's buffer, the float copy, the flip): TEXEL_BYTES, TEXEL_DECODE_BYTES.
"""

from __future__ import annotations

import re

from .errors import IllumError

__all__ = ["MemoryBudget", "MemoryLimitError", "available_memory", "default_cap", "format_size", "parse_size",
           "TRIANGLE_BYTES", "TEXEL_BYTES", "TEXEL_DECODE_BYTES", "DEFAULT_FRACTION"]

TRIANGLE_BYTES = 600          # per placed triangle: mesh arrays, scene tables, BVH
TEXEL_BYTES = 32              # per texel of every image kept (RGBA float32 + its decoded copy)
TEXEL_DECODE_BYTES = 64       # per texel of the largest image, while it is decoded
DEFAULT_FRACTION = 0.8        # of available_memory(), without --max-memory

_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_SIZE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([KMGT]?)(?:i?B)?\s*$", re.IGNORECASE)


class MemoryLimitError(IllumError):
    """What a render would allocate exceeds the memory cap (a user error: exit 2, never retried)."""


def parse_size(text: str) -> int:
    """'8G', '512M', '1.5GiB', '4096' (bytes) -> bytes (binary units). ValueError when malformed."""
    m = _SIZE.match(str(text))
    if m is None:
        raise ValueError(f"expected a size such as 8G, 512M or a number of bytes, got {text!r}")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def format_size(n: float) -> str:
    """Bytes as a user reads them: '2.7 GiB', '640.0 MiB'."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if abs(n) >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} B"


def available_memory() -> int | None:
    """Bytes this process may still allocate: the least of the machine's available memory, the
    room left under an address-space limit (RLIMIT_AS) and under a cgroup v2 memory limit.
    None when none of them can be read."""
    import resource

    room = []
    info = _proc_fields("/proc/meminfo", ("MemAvailable:",))
    if "MemAvailable:" in info:
        room.append(info["MemAvailable:"])
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        size = _proc_fields("/proc/self/status", ("VmSize:",)).get("VmSize:", 0)
        room.append(soft - size)
    try:
        with open("/sys/fs/cgroup/memory.max") as fh:
            limit = fh.read().strip()
        if limit != "max":
            with open("/sys/fs/cgroup/memory.current") as fh:
                room.append(int(limit) - int(fh.read()))
    except (OSError, ValueError):
        pass
    return min(room) if room else None


def resident_memory() -> tuple[int, int] | None:
    """(resident set size, its high-water mark) of this process in bytes, from
    /proc/self/status (Linux); None where that cannot be read."""
    f = _proc_fields("/proc/self/status", ("VmRSS:", "VmHWM:"))
    if "VmRSS:" not in f:
        return None
    return f["VmRSS:"], f.get("VmHWM:", f["VmRSS:"])


def _proc_fields(path: str, names: tuple[str, ...]) -> dict:
    """{name: bytes} of ``name  N kB`` lines of a /proc file (missing file: {})."""
    out = {}
    try:
        with open(path) as fh:
            for line in fh:
                parts = line.split()
                if parts and parts[0] in names:
                    out[parts[0]] = int(parts[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return out


def default_cap() -> int | None:
    """The cap without --max-memory: DEFAULT_FRACTION of available_memory() (None: unknown)."""
    room = available_memory()
    return None if room is None else max(int(room * DEFAULT_FRACTION), 0)


class MemoryBudget:
    """A running estimate of a render's allocations against ``cap`` bytes (None: no cap).

    ``need(nbytes, what, ...)`` adds an allocation that stays; ``need(..., transient=True)`` one
    that is freed again (an image being decoded): only the largest transient counts. Either
    raises MemoryLimitError naming ``what`` (and file / prim / attribute) when the total would
    exceed the cap; the message says whether the cap is --max-memory or the default.
    """

    def __init__(self, cap: int | None, explicit: bool = True):
        self.cap = cap
        self.explicit = explicit
        self.kept = 0
        self.transient = 0

    @classmethod
    def for_options(cls, max_memory: int | None) -> "MemoryBudget":
        """--max-memory when given, else the default cap."""
        return cls(int(max_memory), True) if max_memory else cls(default_cap(), False)

    @property
    def total(self) -> int:
        return self.kept + self.transient

    def need(self, nbytes: float, what: str, *, file: str = "", prim: str = "", attribute: str = "",
             transient: bool = False, commit: bool = True) -> None:
        """Add ``nbytes`` for ``what`` (``commit=False``: only check that they would fit)."""
        nbytes = int(nbytes)
        kept = self.kept + (0 if transient else nbytes)
        peak = max(self.transient, nbytes) if transient else self.transient
        if self.cap is not None and kept + peak > self.cap:
            cap = (f"--max-memory {format_size(self.cap)}" if self.explicit
                   else f"the default cap of {format_size(self.cap)} ({DEFAULT_FRACTION:.0%} of the memory "
                        f"available; raise it with --max-memory)")
            others = kept + peak - nbytes
            raise MemoryLimitError(f"{what} needs about {format_size(nbytes)}"
                                   + (f" (with {format_size(others)} for the rest of the scene)" if others > 0 else "")
                                   + f", more than {cap}", file=file, prim=prim, attribute=attribute)
        if commit:
            self.kept, self.transient = kept, peak
