"""Confine user-supplied paths to the stage root, and store uploads under content-derived names.

A path from a request is resolved (``..`` collapsed, every symlink followed) and must land
inside the resolved stage root: ``../x``, an absolute path elsewhere, or a symlink pointing out
of the tree are all rejected. Names are never passed to a shell; only to ``open``/USD.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["InputError", "STAGE_EXTENSIONS", "IMAGE_EXTENSIONS", "resolve_in_root", "list_stages",
           "upload_name", "resolve_upload", "check_magic"]

STAGE_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")
# Sources a preconvolve job accepts (lat-long environment maps).
IMAGE_EXTENSIONS = (".exr", ".hdr", ".tx", ".tif", ".tiff", ".png")

_UPLOAD_ID = re.compile(r"^[0-9a-f]{16}-[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


class InputError(Exception):
    """A request value the server refuses. status: HTTP status; field: dotted request field."""

    def __init__(self, status: int, field: str, message: str):
        self.status = status
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}" if field else message)


def resolve_in_root(root: str, user_path: object, extensions: tuple[str, ...], field: str = "stage") -> tuple[str, str]:
    """Resolve ``user_path`` (relative to root, or absolute inside it) to (absolute real path,
    display path relative to the root). Raises InputError(400) when it escapes, is missing or has
    the wrong extension."""
    if not isinstance(user_path, str) or not user_path.strip():
        raise InputError(400, field, "must be a non-empty path relative to the stage root")
    if "\x00" in user_path or len(user_path) > 4096:
        raise InputError(400, field, "is not a valid path")
    root_real = Path(root).resolve(strict=True)
    cand = Path(user_path)
    if not cand.is_absolute():
        cand = root_real / cand
    real = cand.resolve(strict=False)
    if real != root_real and not real.is_relative_to(root_real):
        raise InputError(400, field, f"{user_path!r} is outside the stage root")
    if real.suffix.lower() not in extensions:
        raise InputError(400, field, f"{user_path!r} is not one of {', '.join(extensions)}")
    if not real.is_file():
        raise InputError(400, field, f"{user_path!r} does not exist under the stage root")
    return str(real), real.relative_to(root_real).as_posix()


def list_stages(root: str, extensions: tuple[str, ...] = STAGE_EXTENSIONS, limit: int = 2000) -> list[str]:
    """Stage files under root (relative POSIX paths, sorted), skipping hidden entries and any
    symlink that leads out of the root. At most ``limit`` entries."""
    root_real = Path(root).resolve(strict=True)
    found: list[str] = []
    for dirpath, dirnames, filenames in os.walk(root_real, followlinks=False):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(filenames):
            if name.startswith(".") or not name.lower().endswith(extensions):
                continue
            p = Path(dirpath) / name
            real = p.resolve()
            if not real.is_relative_to(root_real) or not real.is_file():
                continue
            found.append(p.relative_to(root_real).as_posix())
            if len(found) >= limit:
                return sorted(found)
    return sorted(found)


def upload_name(sha256_hex: str, filename: str) -> str:
    """The id an upload is stored under: 16 hex digits of its SHA-256, then a sanitised file
    name (the extension tells USD the format). Identical content and name give the same id."""
    base = os.path.basename(filename.replace("\\", "/"))
    stem, ext = os.path.splitext(base)
    if ext.lower() not in STAGE_EXTENSIONS:
        raise InputError(400, "filename", f"{filename!r} is not one of {', '.join(STAGE_EXTENSIONS)}")
    # The extension is split off first, so a name of only non-ASCII letters keeps it.
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip("._-") or "stage"
    safe = stem[: 100 - len(ext)] + ext.lower()
    return f"{sha256_hex[:16]}-{safe}"


def resolve_upload(uploads_dir: str, upload_id: object) -> tuple[str, str]:
    """(absolute path, display name) of a stored upload; InputError(400) when unknown."""
    if not isinstance(upload_id, str) or not _UPLOAD_ID.match(upload_id):
        raise InputError(400, "upload", "is not an upload id returned by POST /uploads")
    path = os.path.join(uploads_dir, upload_id)
    if not os.path.isfile(path):
        raise InputError(400, "upload", f"no upload {upload_id!r} on this server")
    return path, "upload:" + upload_id.split("-", 1)[1]


def check_magic(head: bytes, filename: str) -> None:
    """Reject uploads whose first bytes contradict their extension (a usdc that is not a crate
    file, a usdz that is not a zip). Content errors beyond this are the loader's to report."""
    ext = os.path.splitext(filename)[1].lower()
    if ext == ".usdc" and not head.startswith(b"PXR-USDC"):
        raise InputError(400, "filename", "a .usdc upload must be a USD crate file (starts with PXR-USDC)")
    if ext == ".usdz" and not head.startswith(b"PK\x03\x04"):
        raise InputError(400, "filename", "a .usdz upload must be a zip archive")
    if ext == ".usd" and not (head.startswith(b"PXR-USDC") or head.lstrip().startswith(b"#usda")):
        raise InputError(400, "filename", "a .usd upload must be a crate file or start with #usda")
