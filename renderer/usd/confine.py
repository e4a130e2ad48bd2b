"""Which files a stage would make the renderer read outside a set of allowed directories.

The CLI renders whatever a stage references. The render service must not: a stage under its
stage root could otherwise pull in ``/etc/...`` or ``../../`` files as layers or textures and
show them in a render or an error message. ``find_escapes(stage, roots)`` opens the stage as the
reader does (``Usd.Stage.Open``, everything loaded) and lists every asset path that leads out of
``roots``:

* **composition arcs** (subLayers, references, payloads) authored in every layer the stage
  uses, each anchored to the layer that authored it. These come from the layer itself, so arcs
  in unselected variants and arcs that fail to open count too. Variable expressions are
  evaluated with the layer's and the root layer's ``expressionVariables``;
* **every layer the composed stage opened** (value-clip layers included): the backstop for arcs
  whose expressions take variables from elsewhere;
* **value-clip** asset paths and manifests;
* **asset-valued attributes** (``asset`` and ``asset[]``) on every prim, prototypes included,
  at the default time and at every time sample; and ``string``/``token`` ``inputs:*`` and
  ``illum:dome:irradiance`` values that hold an absolute path, because the reader takes a
  plain string that names an existing file as that file (``ReadContext.resolve_asset``);
* **string primvars** (``string``/``token``, arrays too), anchored to their layer: a
  UsdPrimvarReader_string can make one a texture's file (renderer/usd/materials.py);
* **referenced .mtlx documents** (which the reader reads itself, renderer/usd/mtlx.py) and every
  filename input in them, resolved against the document.

An asset inside the roots that is a FIFO, a device or a directory raises SpecialFileError (the
reader refuses those too). A path is judged by where it points, never by whether the file is there, so the answer gives
away nothing about files outside the roots. Resolved paths are followed through symlinks
(``os.path.realpath``). A path that does not resolve is judged by its anchored location when it
is absolute or climbs with ``..``; other unresolved relative paths stay inside the authoring
layer's directory (or name nothing that can be read) and pass.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Callable, Iterable

from pxr import Ar, Sdf, Tf, Usd

from renderer.errors import SpecialFileError, StageError

from .common import one_line, special_file_problem
from .composition import locate_arc
from .mtlx import document_files
from .stage_reader import open_stage

__all__ = ["Escape", "ConfinementReport", "find_escapes"]

# Non-asset attributes whose string value the reader opens as a file (see resolve_asset).
_STRING_ASSET_PREFIXES = ("inputs:",)
_STRING_ASSET_NAMES = ("illum:dome:irradiance",)
_ASSET_TYPES = (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray)
_STRING_TYPES = (Sdf.ValueTypeNames.String, Sdf.ValueTypeNames.Token)
_STRING_PRIMVAR_TYPES = _STRING_TYPES + (Sdf.ValueTypeNames.StringArray, Sdf.ValueTypeNames.TokenArray)


@dataclass(frozen=True)
class Escape:
    """One asset path that leads outside the allowed directories.

    layer: absolute path of the layer that authored it ('' when only composition knows).
    prim: prim path ('' for a layer-level field such as subLayers).
    field: attribute name, or 'subLayers', 'references', 'payload', 'clips', 'layer'.
    asset: the path as authored (an expression's value when it was one).
    """

    layer: str
    prim: str
    field: str
    asset: str

    def error(self, display: Callable[[str], str] = lambda p: p, where: str = "the allowed directories",
              more: int = 0) -> StageError:
        """A StageError naming layer, prim and field; ``display`` turns server paths into the
        names users know (e.g. relative to the stage root)."""
        if self.field == "layer":
            msg = f"the stage uses layer '{self.asset}', which is outside {where}"
        else:
            msg = f"asset path '{self.asset}' leads outside {where}"
        if more:
            msg += f" (and {more} more asset path{'s' if more > 1 else ''} outside it)"
        return StageError(msg, file=display(self.layer) if self.layer else "", prim=self.prim,
                          attribute=self.field)


@dataclass
class ConfinementReport:
    """escapes: what leads outside (deduplicated, in discovery order). layers: resolved paths
    of the layers the stage uses inside the roots; assets: resolved paths of asset files inside
    the roots (symlinks not followed, so a cache keyed on them notices a retargeted link)."""

    escapes: list[Escape] = field(default_factory=list)
    layers: list[str] = field(default_factory=list)
    assets: list[str] = field(default_factory=list)


class _Roots:
    def __init__(self, roots: Iterable[str]):
        self.roots = [os.path.realpath(r) for r in roots]
        if not self.roots:
            raise ValueError("at least one allowed directory is needed")

    def contains(self, path: str) -> bool:
        """True if ``path`` (a file path, a package-relative path or an identifier with format
        arguments) lies inside a root once symlinks are followed."""
        path = _file_of(path)
        if not os.path.isabs(path):
            return False
        real = os.path.realpath(path)
        return any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in self.roots)


def _file_of(path: str) -> str:
    """The file behind an identifier: format arguments and package-relative parts removed."""
    path = Sdf.Layer.SplitIdentifier(path)[0]
    if Ar.IsPackageRelativePath(path):
        path = Ar.SplitPackageRelativePathOuter(path)[0]
    return path


def _climbs(path: str) -> bool:
    return ".." in path.replace("\\", "/").split("/")


def _target(asset: str, anchor: str) -> str | None:
    """Where ``asset``, authored in the layer at ``anchor``, points: the resolved path, else the
    anchored identifier when that can be judged without the file (absolute, or climbing with
    ``..``), else None (an unresolved relative path below the layer: nothing to read)."""
    resolver = Ar.GetResolver()
    ident = resolver.CreateIdentifier(asset, Ar.ResolvedPath(anchor)) if anchor else asset
    resolved = str(resolver.Resolve(ident)) if ident else ""
    if resolved:
        return resolved
    path = Sdf.Layer.SplitIdentifier(ident or asset)[0]
    if os.path.isabs(path):
        return path
    if _climbs(asset) and anchor:
        return os.path.normpath(os.path.join(os.path.dirname(_file_of(anchor)), asset))
    return None


def _evaluate(asset: str, variables: dict) -> str | None:
    """The value of an asset-path variable expression, None when it cannot be evaluated here."""
    if not Sdf.VariableExpression.IsExpression(asset):
        return asset
    result = Sdf.VariableExpression(asset).Evaluate(variables)
    return result.value if not result.errors and isinstance(result.value, str) else None


class _Scan:
    def __init__(self, stage: Usd.Stage, roots: _Roots):
        self.stage = stage
        self.roots = roots
        self.report = ConfinementReport()
        self._seen_escapes: set = set()
        self._seen_targets: set[str] = set()
        self._assets: set[str] = set()

    def escape(self, layer: str, prim: str, field_: str, asset: str, target: str) -> None:
        key = (layer, prim, field_, asset)
        if key not in self._seen_escapes:
            self._seen_escapes.add(key)
            self._seen_targets.add(os.path.realpath(_file_of(target)))
            self.report.escapes.append(Escape(layer, prim, field_, asset))

    def judge(self, layer: str, prim: str, field_: str, asset: str, target: str | None) -> None:
        if target is None:
            return
        if self.roots.contains(target):
            problem = special_file_problem(target)
            if problem:  # the reader would refuse it (ReadContext.read_asset): refuse it now
                raise SpecialFileError(f"'{asset}' {problem}", file=layer, prim=prim, attribute=field_)
            self._assets.add(_file_of(target))
        else:
            self.escape(layer, prim, field_, asset, target)

    # ---- composition -----------------------------------------------------------------
    def arcs(self) -> None:
        root_vars = dict(self.stage.GetRootLayer().expressionVariables or {})
        for layer in self.stage.GetUsedLayers(includeClipLayers=True):
            if layer.anonymous:
                continue
            anchor = layer.resolvedPath.GetPathString() if layer.resolvedPath else layer.realPath
            variables = {**dict(layer.expressionVariables or {}), **root_vars}
            for authored in layer.GetCompositionAssetDependencies():
                asset = _evaluate(authored, variables)
                if not asset:
                    continue  # left to the used-layers backstop
                target = _target(asset, anchor)
                if target is not None and not self.roots.contains(target):
                    prim, field_ = locate_arc(layer, authored)
                    self.escape(layer.realPath, prim, field_, asset, target)
                elif target is not None and asset.lower().endswith(".mtlx") and os.path.isfile(target):
                    self.mtlx_document(layer.realPath, authored, target)

    def mtlx_document(self, layer: str, authored: str, path: str) -> None:
        """A referenced .mtlx document (read by renderer/usd/mtlx.py, not composed): it and the
        files its filename inputs name."""
        prim, field_ = locate_arc(Sdf.Layer.FindOrOpen(layer), authored)
        self.judge(layer, prim, field_, authored, path)
        for element, value, target in document_files(path):
            self.judge(path, element, "file", value, target)

    def used_layers(self) -> None:
        for layer in self.stage.GetUsedLayers(includeClipLayers=True):
            if layer.anonymous or not layer.realPath:
                continue
            real = layer.realPath
            if self.roots.contains(real):
                self.report.layers.append(_file_of(real))
            elif os.path.realpath(_file_of(real)) not in self._seen_targets:
                self.escape("", "", "layer", layer.identifier, real)

    # ---- prims -----------------------------------------------------------------------
    def prims(self) -> None:
        pred = Usd.PrimAllPrimsPredicate
        ranges = [Usd.PrimRange.Stage(self.stage, pred)]
        ranges += [Usd.PrimRange(proto, pred) for proto in self.stage.GetPrototypes()]
        for prim_range in ranges:
            for prim in prim_range:
                if prim.HasAuthoredMetadata("clips"):
                    self.clips(prim)
                for attr in prim.GetAuthoredAttributes():
                    type_name = attr.GetTypeName()
                    if type_name in _ASSET_TYPES:
                        self.asset_attribute(prim, attr)
                    elif type_name in _STRING_TYPES:
                        name = attr.GetName()
                        if name.startswith(_STRING_ASSET_PREFIXES) or name in _STRING_ASSET_NAMES:
                            self.string_attribute(prim, attr)
                    if attr.GetName().startswith("primvars:") and type_name in _STRING_PRIMVAR_TYPES:
                        self.string_primvar(prim, attr)

    def _values(self, attr: Usd.Attribute):
        yield attr.Get(Usd.TimeCode.Default())
        for t in attr.GetTimeSamples():
            yield attr.Get(t)

    def _where(self, prim: Usd.Prim, attr: Usd.Attribute) -> tuple[str, str, list[str]]:
        """(authoring layer, prim path users can find, anchors of every opinion)."""
        stack = attr.GetPropertyStack()
        layer = stack[0].layer.realPath if stack else ""
        prim_path = str(prim.GetPath())
        if prim.IsInPrototype() and stack:
            prim_path = str(stack[0].path.GetPrimPath())  # the authored spec, not /__Prototype_N
        anchors = [spec.layer.resolvedPath.GetPathString() or spec.layer.realPath for spec in stack]
        return layer, prim_path, anchors

    def asset_attribute(self, prim: Usd.Prim, attr: Usd.Attribute) -> None:
        where = None
        for value in self._values(attr):
            if value is None:
                continue
            items = [value] if isinstance(value, Sdf.AssetPath) else list(value)
            for ap in items:
                if not isinstance(ap, Sdf.AssetPath):
                    continue
                authored = ap.evaluatedPath or ap.path
                if not authored:
                    continue
                if where is None:
                    where = self._where(prim, attr)
                layer, prim_path, anchors = where
                if ap.resolvedPath:
                    self.judge(layer, prim_path, attr.GetName(), authored, ap.resolvedPath)
                elif os.path.isabs(authored) or _climbs(authored):
                    for anchor in anchors or [""]:
                        self.judge(layer, prim_path, attr.GetName(), authored, _target(authored, anchor))

    def string_attribute(self, prim: Usd.Prim, attr: Usd.Attribute) -> None:
        for value in self._values(attr):
            if isinstance(value, str) and os.path.isabs(value):
                layer, prim_path, _anchors = self._where(prim, attr)
                self.judge(layer, prim_path, attr.GetName(), value, value)

    def string_primvar(self, prim: Usd.Prim, attr: Usd.Attribute) -> None:
        """A string primvar may name a texture file (UsdPrimvarReader_string feeding a
        UsdUVTexture's file: the reader anchors it to the primvar's layer), so every value is
        judged like an asset path."""
        where = None
        for value in self._values(attr):
            items = [value] if isinstance(value, str) else list(value or [])
            for text in items:
                if not isinstance(text, str) or not text:
                    continue
                if where is None:
                    where = self._where(prim, attr)
                layer, prim_path, anchors = where
                for anchor in anchors or [""]:
                    self.judge(layer, prim_path, attr.GetName(), text, _target(text, anchor))

    def clips(self, prim: Usd.Prim) -> None:
        api = Usd.ClipsAPI(prim)
        clips = api.GetClips() or {}
        layer = ""
        stack = prim.GetPrimStack()
        if stack:
            layer = stack[0].layer.realPath
        for clip_set in clips.keys():
            paths = list(api.ComputeClipAssetPaths(clip_set))
            manifest = api.GetClipManifestAssetPath(clip_set)
            if manifest:
                paths.append(manifest)
            for ap in paths:
                if ap.resolvedPath:
                    self.judge(layer, str(prim.GetPath()), "clips", ap.path, ap.resolvedPath)
                elif os.path.isabs(ap.path) or _climbs(ap.path):
                    self.judge(layer, str(prim.GetPath()), "clips", ap.path, _target(ap.path, layer))

    def run(self) -> ConfinementReport:
        self.arcs()
        self.prims()           # may open clip layers: before the used-layers backstop
        self.used_layers()
        self.report.layers = sorted(set(self.report.layers))
        self.report.assets = sorted(self._assets - set(self.report.layers))
        return self.report


def find_escapes(stage_path: str, roots: Iterable[str]) -> ConfinementReport:
    """Open ``stage_path`` (everything loaded, as ``load_stage`` does) and report every file it
    would make the renderer read outside ``roots`` (see the module docstring).

    Raises StageError when the stage cannot be opened.
    """
    allowed = _Roots(roots)
    path = os.path.abspath(stage_path)
    if not allowed.contains(path):
        return ConfinementReport(escapes=[Escape("", "", "layer", stage_path)])
    try:
        stage = open_stage(path)
    except SpecialFileError:
        raise  # it names the layer that authors the FIFO or device
    except StageError as exc:
        raise StageError(exc.message, file=stage_path) from None  # name the file as the caller gave it
    try:
        return _Scan(stage, allowed).run()
    except Tf.ErrorException as exc:
        raise StageError(one_line(exc), file=stage_path) from None
