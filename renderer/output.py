"""Output files: where a render may write (checked before any work), and writing images there.

* ``check_output_path`` refuses, before the stage is even read, a path that cannot be written:
  an unsupported extension, a directory, the input stage itself, a missing directory (unless
  the caller may create it: husk's ``--make-output-path``), a directory that refuses a new file.
* ``AtomicFiles`` writes every file of a render under a temporary name in its final directory
  and renames them all only once each is complete, so a failure never leaves a partial file, nor
  an EXR without the preview that was asked for. Files get the mode a plain ``open()`` would
  give (0666 minus the umask), not mkstemp's 0600, so a farm process running as another user
  can read them.
* ``write_image`` writes a beauty image by extension: ``.exr`` scene-linear float (or half),
  with a chosen compression and metadata; ``.png``, ``.jpg``, ``.tif`` display-referred: the OCIO
  config's default display and view when ``$OCIO`` is set, else the sRGB transfer function
  (``srgb_encode``), 8 bits (16 for TIFF), with straight alpha where the format has alpha.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager

import numpy as np

from .errors import SettingsError

__all__ = ["IMAGE_EXTENSIONS", "DISPLAY_EXTENSIONS", "EXR_COMPRESSIONS", "check_output_path", "file_mode",
           "AtomicFiles", "joining", "write_image", "srgb_encode", "display_encode"]

# extension -> OpenImageIO format name
IMAGE_EXTENSIONS = {".exr": "openexr", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff",
                    ".tiff": "tiff"}
DISPLAY_EXTENSIONS = {k: v for k, v in IMAGE_EXTENSIONS.items() if v != "openexr"}
EXR_COMPRESSIONS = ("zip", "piz", "dwaa", "none")


# ---------------------------------------------------------------------------------- checks
def check_output_path(path: str, argument: str, *, extensions=IMAGE_EXTENSIONS, inputs=(),
                      make_dirs: bool = False, probed: set | None = None) -> None:
    """Raise SettingsError (attribute ``argument``, e.g. "--output") unless ``path`` can be
    written: its extension is one of ``extensions`` (None: any), it is neither a directory nor
    one of ``inputs`` (the stage), and its directory exists (or, with ``make_dirs``, its nearest
    existing ancestor is a writable directory) and accepts a new file (probed by creating and
    removing one: permission bits say nothing to root, and a read-only mount refuses anyway).
    probed: directories already probed (frame ranges check many names in few directories)."""
    if not path:
        raise SettingsError("is empty", attribute=argument)
    if os.path.isdir(path):
        raise SettingsError(f"{path} is a directory", attribute=argument)
    if os.path.exists(path) and not os.path.isfile(path):
        raise SettingsError(f"{path} exists and is not a regular file", attribute=argument)
    for src in inputs:
        if src and (os.path.realpath(src) == os.path.realpath(path)
                    or os.path.exists(src) and os.path.exists(path) and os.path.samefile(src, path)):
            raise SettingsError(f"{path} is the input stage; refusing to overwrite it", attribute=argument)
    ext = os.path.splitext(path)[1].lower()
    if extensions is not None and ext not in extensions:
        raise SettingsError(f"{path}: unsupported extension {ext or '(none)'!r}; use one of "
                            f"{', '.join(extensions)}", attribute=argument)
    d = os.path.dirname(os.path.abspath(path))
    if probed is not None and d in probed:
        return
    if not os.path.isdir(d):
        if os.path.exists(d):
            raise SettingsError(f"{d} is not a directory", attribute=argument)
        if not make_dirs:
            raise SettingsError(f"directory {d} does not exist (pass --make-output-path to create it)",
                                attribute=argument)
        parent = d
        while not os.path.exists(parent):
            parent = os.path.dirname(parent)
        if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
            raise SettingsError(f"cannot create directory {d}: {parent} is not a writable directory",
                                attribute=argument)
    else:
        try:
            fd, probe = tempfile.mkstemp(prefix=".illum-probe.", dir=d)
        except OSError as e:
            raise SettingsError(f"cannot write in directory {d}: {e.strerror}", attribute=argument) from None
        os.close(fd)
        os.unlink(probe)
    if probed is not None:
        probed.add(d)


# ---------------------------------------------------------------------------------- atomic files
def file_mode() -> int:
    """The mode open() gives a new file: 0o666 without the process umask's bits."""
    try:  # Linux >= 4.7 reports it without changing it (os.umask would, briefly, for every thread)
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


class AtomicFiles:
    """Files written under temporary names next to their final names, renamed together by
    ``commit()`` (or on leaving a ``with`` block without an exception); ``discard()`` (or an
    exception) removes the temporaries. The renames come only after every file is complete."""

    def __init__(self):
        self._pending: list[tuple[str, str]] = []

    def temp(self, path: str) -> str:
        """A new temporary file name in ``path``'s directory (created if missing), same extension
        (OpenImageIO chooses the format by it)."""
        d = os.path.dirname(os.path.abspath(path)) or "."
        os.makedirs(d, exist_ok=True)
        base, ext = os.path.splitext(os.path.basename(path))
        fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=ext, dir=d)
        os.close(fd)
        self._pending.append((tmp, path))
        return tmp

    def commit(self) -> None:
        mode = file_mode()
        try:
            for tmp, _ in self._pending:
                os.chmod(tmp, mode)
            for tmp, final in self._pending:
                os.replace(tmp, final)
        finally:
            self.discard()

    def discard(self) -> None:
        for tmp, _ in self._pending:
            if os.path.exists(tmp):
                os.unlink(tmp)
        self._pending = []

    def __enter__(self) -> "AtomicFiles":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


@contextmanager
def joining(files: AtomicFiles | None):
    """The AtomicFiles a writer writes into: ``files`` (whose owner commits or discards it), or
    for None a new one, committed on success and discarded on an exception."""
    if files is not None:
        yield files
        return
    with AtomicFiles() as own:
        yield own


# ---------------------------------------------------------------------------------- display
def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function on [0,1]-clamped linear values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def display_encode(rgb: np.ndarray) -> np.ndarray:
    """Scene-linear Rec.709 (h, w, 3) -> display values in [0, 1]: the default display and view
    of the OCIO config named by ``$OCIO`` (its scene_linear role as the source), else sRGB."""
    config = os.environ.get("OCIO")
    if not config:
        return srgb_encode(rgb)
    import OpenImageIO as oiio

    src = oiio.ImageBuf(np.ascontiguousarray(rgb, dtype=np.float32))
    out = oiio.ImageBufAlgo.ociodisplay(src, "", "", fromspace="scene_linear", colorconfig=config)
    if out.has_error:
        raise SettingsError(f"OCIO display transform failed: {out.geterror()}", attribute="OCIO")
    return np.clip(out.get_pixels(oiio.FLOAT)[:, :, :3], 0.0, 1.0)


# ---------------------------------------------------------------------------------- writing
def _set_attr(spec, key: str, value) -> None:
    import OpenImageIO as oiio

    if isinstance(value, np.ndarray) and value.shape == (4, 4):
        # EXR matrices are row-vector (Imath); ours are column-vector, so store the transpose.
        spec.attribute(key, oiio.TypeDesc("matrix"), np.ascontiguousarray(value.T, dtype=np.float32).ravel())
    elif isinstance(value, (bool, int, np.integer)):
        spec.attribute(key, int(value))
    elif isinstance(value, (float, np.floating)):
        spec.attribute(key, float(value))
    elif isinstance(value, str):
        spec.attribute(key, value)
    else:
        spec.attribute(key, json.dumps(value, sort_keys=True))


def write_image(path: str, pixels: np.ndarray, metadata: dict | None = None, *, files: AtomicFiles | None = None,
                origin: tuple[int, int] = (0, 0), full: tuple[int, int] | None = None,
                compression: str = "zip", half: bool = False, channels: tuple[str, ...] | None = None) -> None:
    """Write (h, w, 3) scene-linear RGB or (h, w, 4) RGBA with premultiplied alpha, as the
    extension of ``path`` says (module docstring).

    channels: an EXR's channel names (h, w, C) in OpenImageIO's layer.channel convention
    ("albedo.R", renderer/aov.py), the beauty's R, G, B (and A, the alpha channel) first;
    default R, G, B(, A). Display formats take RGB(A) only.

    files: the AtomicFiles this file joins (renamed when it commits); None writes and renames
    this file alone. origin/full: the data window's position in the display window of size
    ``full`` (width, height); display formats get the data window alone. metadata: str/int/float
    values become attributes; (4, 4) arrays matrices; dicts/lists JSON strings. compression and
    half apply to EXR only.
    """
    import OpenImageIO as oiio

    fmt = IMAGE_EXTENSIONS.get(os.path.splitext(path)[1].lower())
    if fmt is None:
        raise SettingsError(f"{path}: unsupported extension; use one of {', '.join(IMAGE_EXTENSIONS)}",
                            attribute="output")
    if compression not in EXR_COMPRESSIONS:
        raise SettingsError(f"must be one of {', '.join(EXR_COMPRESSIONS)}, got {compression!r}",
                            attribute="exr_compression")
    pixels = np.asarray(pixels, dtype=np.float32)
    h, w, nc = pixels.shape
    if fmt == "openexr":
        spec = oiio.ImageSpec(w, h, nc, oiio.HALF if half else oiio.FLOAT)
        spec.x, spec.y = origin
        spec.full_x, spec.full_y = 0, 0
        spec.full_width, spec.full_height = full or (w, h)
        spec.attribute("compression", compression)
        spec.attribute("oiio:ColorSpace", "lin_rec709")
        data = pixels
    else:
        rgb, alpha = pixels[:, :, :3], (pixels[:, :, 3:4] if nc == 4 else None)
        keep_alpha = alpha is not None and fmt != "jpeg"
        if keep_alpha:  # straight alpha for PNG / TIFF: the display encoding applies to colour
            rgb = np.where(alpha > 0.0, rgb / np.where(alpha > 0.0, alpha, 1.0), 0.0)
        display = display_encode(rgb)
        if keep_alpha:
            display = np.concatenate([display, np.clip(alpha, 0.0, 1.0)], axis=2)
        depth, scale = (oiio.UINT16, 65535.0) if fmt == "tiff" else (oiio.UINT8, 255.0)
        data = np.round(display * scale).astype(np.uint16 if fmt == "tiff" else np.uint8)
        spec = oiio.ImageSpec(w, h, data.shape[2], depth)
        if not os.environ.get("OCIO"):
            spec.attribute("oiio:ColorSpace", "srgb_rec709_scene")
        if keep_alpha:
            spec.attribute("oiio:UnassociatedAlpha", 1)  # already straight: no second division
    if channels is not None and fmt == "openexr":
        if len(channels) != data.shape[2]:
            raise ValueError(f"{len(channels)} channel names for {data.shape[2]} channels")
        spec.channelnames = tuple(channels)
        if "A" in channels:
            spec.alpha_channel = channels.index("A")
        if "Z" in channels:
            spec.z_channel = channels.index("Z")
    else:
        spec.channelnames = ("R", "G", "B", "A")[:data.shape[2]]
        if data.shape[2] == 4:
            spec.alpha_channel = 3
    for key, value in (metadata or {}).items():
        _set_attr(spec, key, value)
    with joining(files) as f:
        tmp = f.temp(path)
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise OSError(f"cannot open {path} for writing: {oiio.geterror()}")
        ok = out.write_image(np.ascontiguousarray(data))
        ok = out.close() and ok
        if not ok:
            raise OSError(f"cannot write {path}: {out.geterror()}")
