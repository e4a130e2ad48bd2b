"""Shared state and helpers of one stage read: errors, warnings, stats, matrices, assets."""

from __future__ import annotations

import math
import os
import re
import stat
from collections import OrderedDict

import numpy as np
from pxr import Ar, Gf, Sdf, Usd, UsdGeom

from renderer.errors import SpecialFileError, StageError
from renderer.memory import TEXEL_BYTES, TEXEL_DECODE_BYTES, MemoryBudget
from renderer.textures import probe_image

# UDIM tiles looked for: 1001 + u + 10 v for u, v in 0..9 (the 10 x 10 tiles Mari, Substance
# and Houdini lay out by default).
UDIM_FIRST = 1001
UDIM_TILES = 100


_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def special_file_problem(path: str) -> str:
    """'' unless ``path`` exists and is not a regular file, else why it is refused ("is a FIFO,
    not a regular file"): opening a FIFO without a writer blocks forever, and a device such as
    ``/dev/zero`` never ends. A package-relative or format-argument identifier is judged by its
    file; a missing path is left to the resolver and the missing-asset policy."""
    path = Sdf.Layer.SplitIdentifier(path)[0]
    if Ar.IsPackageRelativePath(path):
        path = Ar.SplitPackageRelativePathOuter(path)[0]
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return ""
    if stat.S_ISREG(mode):
        return ""
    return f"is {next((name for test, name in _KINDS if test(mode)), 'not a file')}, not a regular file"


def gf_matrix_to_np(m: Gf.Matrix4d) -> np.ndarray:
    """Gf row-vector matrix -> (4, 4) float64 column-vector matrix (``p' = M @ p``)."""
    return np.array(m, dtype=np.float64).reshape(4, 4).T.copy()


_TF_LOCATION = re.compile(r"Error in '[^']*' at line \d+ in file [^:]* : '(.*?)'(?=\s*(?:Error in '|$))", re.S)


def one_line(text: str) -> str:
    """A pxr error (Tf.ErrorException) as one line: the messages without C++ locations."""
    text = str(text)
    messages = _TF_LOCATION.findall(text)
    if messages:
        text = "; ".join(m.strip() for m in messages)
    return " ".join(text.split())


_TEXT_TYPES = ("token", "string", "asset")


def _value_shape(type_name: Sdf.ValueTypeName) -> tuple:
    """(array, text or number, components) of a value type: what must agree between an authored
    value and its schema for the reader to use it. Precision and role may differ (double for
    float, float3 for color3f, int for float: the values convert); shape may not (float2[] for
    point3f[], a scalar for an array)."""
    scalar = str(type_name.scalarType)
    if scalar in _TEXT_TYPES:
        return type_name.isArray, "text", 1
    digits = re.search(r"\d", scalar)
    return type_name.isArray, "number", int(digits.group()) if digits else 1


class WarningLog:
    """Warnings said once per stage.

    Each warning has a key; repeats of a key are counted, and the first message is reported
    with "(N more like it)" so a stage with 10,000 offending prims gives one line, not 10,000.
    """

    def __init__(self) -> None:
        self._first: OrderedDict[str, str] = OrderedDict()
        self._count: dict[str, int] = {}

    def add(self, key: str, message: str) -> None:
        if key not in self._first:
            self._first[key] = message
            self._count[key] = 0
        self._count[key] += 1

    def messages(self) -> list[str]:
        out = []
        for key, message in self._first.items():
            extra = self._count[key] - 1
            out.append(message if extra == 0 else f"{message} (and {extra} more like it)")
        return out


class ReadContext:
    """Everything one ``load_stage`` call shares between the reader modules.

    file: the stage path as the user gave it (used in every error message).
    time: the Usd.TimeCode all values are read at.
    strict: every missing or unreadable asset is a StageError (``--strict``); otherwise one
        warning per file and the consumer's fallback (``asset_unusable``).
    xform_cache: one UsdGeom.XformCache(time) for the whole read.
    memory: the render's renderer.memory.MemoryBudget: meshes and images are charged to it as
        they are met, before their arrays are built (a MemoryLimitError names the prim).
    """

    def __init__(self, stage: Usd.Stage, file: str, time: Usd.TimeCode, strict: bool = False,
                 memory: MemoryBudget | None = None):
        self.stage = stage
        self.file = file
        self.time = time
        self.strict = strict
        self.memory = memory if memory is not None else MemoryBudget(None)
        self._assets: dict[str, tuple[str, bytes | None] | str] = {}
        self._image_problems: dict[str, tuple] = {}
        self.xform_cache = UsdGeom.XformCache(time)
        self.warnings = WarningLog()
        self.stats: dict[str, int] = {
            "prims_visited": 0,
            "prims_pruned": 0,
            "points_read": 0,
            "meshes": 0,
            "implicit_prims": 0,
            "triangles": 0,
            "instancers": 0,
            "instances": 0,
            "instanced_lights": 0,  # LightDescs made from PointInstancer prototype lights
            "lights": 0,
            "materials": 0,
            "subdivided_meshes": 0,  # meshes refined (renderer/subdiv.py)
            "subdivided_faces": 0,  # their refined faces
            "skinned_meshes": 0,  # meshes deformed by UsdSkel (renderer/usd/skinning.py)
        }
        self.up_axis = str(UsdGeom.GetStageUpAxis(stage))

    # ---- errors and warnings ---------------------------------------------------------
    def error(self, message: str, prim: Usd.Prim | str | None = None, attribute: str = "") -> StageError:
        """A StageError located at this file (and prim/attribute when given); raise it."""
        prim_path = ""
        if prim is not None:
            prim_path = str(prim.GetPath()) if isinstance(prim, Usd.Prim) else str(prim)
        return StageError(message, file=self.file, prim=prim_path, attribute=attribute)

    def warn(self, key: str, message: str) -> None:
        self.warnings.add(key, message)

    # ---- transforms ------------------------------------------------------------------
    def local_to_world(self, prim: Usd.Prim) -> np.ndarray:
        """(4, 4) column-vector world matrix of ``prim`` at the read time."""
        return gf_matrix_to_np(self.xform_cache.GetLocalToWorldTransform(prim))

    def finite_world(self, prim: Usd.Prim, limit: float = 1e30) -> np.ndarray:
        """World matrix that must be finite and of sane magnitude (a light or a camera with a
        NaN transform would otherwise vanish silently or render black)."""
        m = self.local_to_world(prim)
        if not np.all(np.isfinite(m)) or np.abs(m).max() > limit:
            raise self.error("world transform is not finite (or exceeds 1e30)", prim, "xformOpOrder")
        return m

    def relative_transform(self, prim: Usd.Prim, ancestor: Usd.Prim) -> np.ndarray:
        """(4, 4) column-vector transform from ``prim``'s local space to ``ancestor``'s."""
        m, _reset = self.xform_cache.ComputeRelativeTransform(prim, ancestor)
        return gf_matrix_to_np(m)

    # ---- values ----------------------------------------------------------------------
    def get(self, prim: Usd.Prim, name: str, default=None):
        """Value of attribute ``name`` at the read time (schema fallback if unauthored), or default."""
        attr = prim.GetAttribute(name)
        if not attr:
            return default
        value = self.get_attr(attr)
        return default if value is None else value

    def get_attr(self, attr: Usd.Attribute):
        """``attr``'s value at the read time, after checking its authored type against the
        schema's (``check_type``)."""
        self.check_type(attr)
        return attr.Get(self.time)

    def check_type(self, attr: Usd.Attribute) -> None:
        """StageError naming the attribute when its strongest opinion is authored with another
        value type than its schema declares (``float2[] points``): USD composes the value as
        authored, which would otherwise fail later with an unrelated message."""
        stack = attr.GetPropertyStack(self.time)
        if not stack:
            return
        definition = attr.GetPrim().GetPrimDefinition().GetAttributeDefinition(attr.GetName())
        authored = stack[0].typeName
        if definition and authored and _value_shape(authored) != _value_shape(definition.GetTypeName()):
            raise self.error(f"authored as {authored} in {stack[0].layer.identifier}, but the schema "
                             f"declares {definition.GetTypeName()}", attr.GetPrim(), attr.GetName())

    def finite_float(self, prim: Usd.Prim, name: str, value, *, min_value: float | None = None,
                     positive: bool = False) -> float:
        """Validate a scalar: finite, and >= min_value or > 0 as asked; else StageError."""
        v = float(value)
        if not math.isfinite(v):
            raise self.error(f"value is {v} (must be finite)", prim, name)
        if positive and v <= 0.0:
            raise self.error(f"value is {v:g} (must be > 0)", prim, name)
        if min_value is not None and v < min_value:
            raise self.error(f"value is {v:g} (must be >= {min_value:g})", prim, name)
        return v

    def finite_tuple(self, prim: Usd.Prim, name: str, value) -> tuple:
        """Validate a vector value (colour, float4, ...) as all-finite; return it as a float tuple."""
        t = tuple(float(x) for x in value)
        if not all(math.isfinite(x) for x in t):
            raise self.error(f"value {t} is not finite", prim, name)
        return t

    # ---- assets ----------------------------------------------------------------------
    def authoring_layer(self, prim: Usd.Prim, name: str) -> str:
        """Identifier of the layer whose opinion gives attribute ``name`` its value ('' if none)."""
        attr = prim.GetAttribute(name)
        stack = attr.GetPropertyStack(self.time) if attr else []
        return stack[0].layer.identifier if stack else ""

    def asset_unusable(self, prim: Usd.Prim, name: str, asset: str, problem: str, consequence: str) -> None:
        """The one policy for an asset that is missing or cannot be read (textures, light
        textures, IES profiles): under ``strict`` a StageError naming the authoring layer, the
        prim and the attribute; otherwise one warning per asset (further prims using it are
        counted) saying what illum does instead (``consequence``)."""
        layer = self.authoring_layer(prim, name) or self.file
        if self.strict:
            raise StageError(f"{problem}: '{asset}'", file=layer, prim=str(prim.GetPath()), attribute=name)
        self.warn(f"asset-{asset}", f"{layer}: {prim.GetPath()}.{name}: {problem}: '{asset}'; {consequence}")

    def read_asset(self, prim: Usd.Prim, name: str, value, consequence: str) -> tuple[str, bytes | None] | None:
        """(resolved path, bytes or None) of an asset-valued attribute, or None when unauthored,
        missing or unreadable (``asset_unusable`` has applied the policy, with ``consequence``).

        Resolution goes through USD's asset resolver (Ar), so paths inside a ``.usdz`` package
        (``pkg.usdz[maps/wood.png]``) and a custom resolver's identifiers work. A file on disk
        is returned by path (bytes None); anything else is read through ``ArAsset`` and its
        bytes are returned with its identifier (renderer/assets.py). Each asset is read once.
        """
        resolved = self.resolve_asset(prim, name, value, consequence)
        if not resolved:
            return None
        cached = self._assets.get(resolved)
        if cached is None:
            problem = special_file_problem(resolved)
            if problem:  # reading a FIFO or a device would block or never end: never a fallback
                raise SpecialFileError(f"'{resolved}' {problem}", file=self.authoring_layer(prim, name) or self.file,
                                 prim=str(prim.GetPath()), attribute=name)
            if os.path.isfile(resolved):
                cached = (resolved, None)
            else:
                asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
                buffer = asset.GetBuffer() if asset else None
                cached = (resolved, bytes(buffer)) if buffer is not None else "cannot read asset"
            self._assets[resolved] = cached
        if isinstance(cached, str):
            self.asset_unusable(prim, name, resolved, cached, consequence)
            return None
        return cached

    def read_image_asset(self, prim: Usd.Prim, name: str, value,
                         consequence: str) -> tuple[str, bytes | None] | None:
        """``read_asset`` for an image: also None (after the policy) when OpenImageIO cannot
        open it (its header is read once per file; decoding happens in the render core)."""
        asset = self.read_asset(prim, name, value, consequence)
        if asset is None:
            return None
        first = asset[0] not in self._image_problems
        if first:
            self._image_problems[asset[0]] = probe_image(*asset)
        problem, size = self._image_problems[asset[0]]
        if problem:
            self.asset_unusable(prim, name, asset[0], f"cannot read image ({problem})", consequence)
            return None
        if first:  # each file is decoded once: its texels, and the peak while decoding it
            width, height, depth = size
            texels = width * height * depth
            what = f"the {width}x{height}{f'x{depth}' if depth > 1 else ''} image '{asset[0]}'"
            where = dict(file=self.authoring_layer(prim, name) or self.file, prim=str(prim.GetPath()), attribute=name)
            self.memory.need(texels * TEXEL_DECODE_BYTES, f"decoding {what}", transient=True, **where)
            self.memory.need(texels * TEXEL_BYTES, what, **where)
        return asset

    def udim_tiles(self, where: Usd.Prim, where_name: str, authored: str,
                    consequence: str) -> tuple[str, tuple, tuple] | None:
        """The tiles of a UDIM path (``<UDIM>`` replaced by 1001 + u + 10 v, u in 0..9, v in
        0..9) authored on ``where``.``where_name``: (the anchored pattern, ((tile, file), ...),
        (bytes or None, ...)), or None when no tile resolves (the missing-asset policy applied).
        Each tile is resolved through Ar like any asset, so tiles inside a .usdz work too."""
        ctx = self
        # A .mtlx document's file input names no USD attribute: its path is anchored already.
        attr = where.GetAttribute(where_name)
        stack = attr.GetPropertyStack(ctx.time) if attr else []
        anchor = (lambda p: stack[0].layer.ComputeAbsolutePath(p)) if stack else (lambda p: p)
        resolver = Ar.GetResolver()
        tiles, data = [], []
        for tile in range(UDIM_FIRST, UDIM_FIRST + UDIM_TILES):
            path = authored.replace("<UDIM>", str(tile))
            resolved = str(resolver.Resolve(anchor(path)))
            if not resolved:
                continue
            asset = ctx.read_image_asset(where, where_name, Sdf.AssetPath(path, resolved), consequence)
            if asset is not None:
                tiles.append((tile, asset[0]))
                data.append(asset[1])
        if not tiles:
            ctx.asset_unusable(where, where_name, authored,
                               f"no UDIM tile found ({UDIM_FIRST}-{UDIM_FIRST + UDIM_TILES - 1})", consequence)
            return None
        return anchor(authored), tuple(tiles), tuple(data)

    def resolve_asset(self, prim: Usd.Prim, name: str, value, consequence: str = "") -> str:
        """Resolved path of an asset-valued attribute ('' when unauthored or empty).

        The asset resolver anchors relative paths to the layer that authored them. A path that
        does not resolve is the missing-asset policy's (``asset_unusable``; it returns ''), or,
        when the caller has no fallback (no ``consequence``), always a StageError naming the
        prim and attribute.
        """
        if value is None:
            return ""
        if isinstance(value, Sdf.AssetPath):
            authored, resolved = value.path, value.resolvedPath
        else:  # a plain string (hand-written files sometimes use string for asset paths)
            authored, resolved = str(value), ""
        if not authored:
            return ""
        if not resolved and os.path.isabs(authored) and os.path.exists(authored):
            resolved = authored
        if not resolved:
            if not consequence:
                raise self.error(f"file not found: '{authored}'", prim, name)
            self.asset_unusable(prim, name, authored, "file not found", consequence)
            return ""
        return os.path.abspath(resolved) if os.path.exists(resolved) else resolved
