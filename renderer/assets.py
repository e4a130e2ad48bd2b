"""Asset files the render core reads: plain files, or bytes the stage reader handed over.

A stage's assets (textures, light textures, IES profiles) are resolved by USD's asset resolver
in ``renderer/usd``. Most resolve to a file on disk, which is read by path. An asset inside a
``.usdz`` package (``/shots/pkg.usdz[textures/wood.png]``), or one a custom resolver serves,
has no such file: the reader reads its bytes through the resolver (``ArAsset``) and passes them
along with the resolved identifier (``TextureDesc.data``, ``LightDesc.texture_data``). The
helpers here read either form, so no consumer needs to know which it has.

OpenImageIO's Python binding (3.2) has no in-memory reader (its IOProxy is C++ only), so
``local_file`` gives OIIO a private temporary copy of in-memory bytes, named with the asset's
own extension (the format hint), and removes it when the image has been read.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from contextlib import contextmanager
from typing import Iterator, Optional

__all__ = ["asset_bytes", "asset_sha256", "display_name", "extension", "local_file"]


def extension(path: str) -> str:
    """The file extension of a resolved asset, for package-relative ones that of the innermost
    file: ``/a/pkg.usdz[maps/wood.png]`` -> ``.png``."""
    if path.endswith("]") and "[" in path:
        path = path.rsplit("[", 1)[1].rstrip("]")
    return os.path.splitext(path)[1]


def display_name(path: str) -> str:
    """The asset's last path component (package-relative paths keep their package's name)."""
    if path.endswith("]") and "[" in path:
        outer = path.split("[", 1)[0]
        return os.path.basename(outer) + path[len(outer):]
    return os.path.basename(path)


def asset_bytes(path: str, data: Optional[bytes] = None) -> bytes:
    """The asset's bytes: ``data`` when the reader supplied them, else the file at ``path``
    (OSError when it cannot be read)."""
    if data is not None:
        return data
    with open(path, "rb") as fh:
        return fh.read()


def asset_sha256(path: str, data: Optional[bytes] = None) -> str:
    """Hex sha256 of the asset's bytes (streamed from disk when they are a file)."""
    h = hashlib.sha256()
    if data is not None:
        h.update(data)
        return h.hexdigest()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


@contextmanager
def local_file(path: str, data: Optional[bytes] = None) -> Iterator[str]:
    """A filesystem path holding the asset, valid inside the ``with`` block: ``path`` itself when
    the asset is a file, else a private temporary file (same extension) with ``data``."""
    if data is None:
        yield path
        return
    fd, tmp = tempfile.mkstemp(prefix="illum-asset-", suffix=extension(path))
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        yield tmp
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass
