"""Composition problems (missing or unreadable sublayers, references, payloads; sublayer cycles)
located at the layer, prim and field that author them.

USD composes a stage even when an arc cannot be opened: the arc is skipped and the problem is
recorded (``Usd.Stage.GetCompositionErrors``). Under the missing-asset policy
(``ReadContext.asset_unusable``) each one is a warning, or under ``--strict`` a StageError.
Pcp's Python errors carry only a message, so the arc is found again in the layers the stage
uses: the authored asset path the message quotes (``@path@``), or, for a sublayer cycle, the
layer whose subLayers entry closes the cycle (a depth-first walk from the root layer).
"""

from __future__ import annotations

import re

from pxr import Ar, Pcp, Sdf, Tf, Usd

from renderer.errors import SpecialFileError, StageError

from .common import ReadContext, one_line, special_file_problem

__all__ = ["check_composition", "locate_arc", "open_layers_refusing_special_files"]

_QUOTED = re.compile(r"@([^@]+)@")
_MAX_WARNINGS = 10


def locate_arc(layer: Sdf.Layer, asset: str) -> tuple[str, str]:
    """(prim path, field) of the arc in ``layer`` that authors ``asset``."""
    if asset in list(layer.subLayerPaths):
        return "", "subLayers"
    found: list[tuple[str, str]] = []

    def visit(path: Sdf.Path) -> None:
        if found or not (path.IsPrimPath() or path.IsPrimVariantSelectionPath()):
            return
        spec = layer.GetPrimAtPath(path)
        if spec is None:
            return
        for name, proxy in (("references", spec.referenceList), ("payload", spec.payloadList)):
            for kind in ("explicitItems", "addedItems", "prependedItems", "appendedItems", "orderedItems",
                         "deletedItems"):
                if any(item.assetPath == asset for item in getattr(proxy, kind)):
                    found.append((str(path.StripAllVariantSelections()), name))
                    return

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found[0] if found else ("", "references")


def _anchored(asset: str, layer: Sdf.Layer) -> str:
    """``asset`` as authored in ``layer``, anchored to it (the identifier Pcp quotes)."""
    anchor = layer.resolvedPath.GetPathString() if layer.resolvedPath else ""
    return Ar.GetResolver().CreateIdentifier(asset, Ar.ResolvedPath(anchor)) if anchor else asset


def _arc_of(stage: Usd.Stage, quoted: str) -> tuple[str, str, str, str] | None:
    """(layer, prim, field, authored asset) of the arc whose asset path Pcp quoted, or None."""
    for layer in stage.GetUsedLayers():
        if layer.anonymous:
            continue
        for authored in layer.GetCompositionAssetDependencies():
            if quoted in (authored, _anchored(authored, layer)):
                prim, field = locate_arc(layer, authored)
                return layer.identifier, prim, field, authored
    return None


def _sublayer_cycle(stage: Usd.Stage) -> tuple[str, str] | None:
    """(layer, authored sublayer path) of the subLayers entry that closes a cycle, or None."""
    on_path: list[str] = []

    def walk(layer: Sdf.Layer):
        on_path.append(layer.identifier)
        for authored in layer.subLayerPaths:
            sub = Sdf.Layer.FindOrOpen(_anchored(authored, layer))
            if sub is None:
                continue
            if sub.identifier in on_path:
                return layer.identifier, authored
            hit = walk(sub)
            if hit is not None:
                return hit
        on_path.pop()
        return None

    return walk(stage.GetRootLayer())


def _locate(stage: Usd.Stage, error) -> tuple[str, str, str, str]:
    """(layer, prim, field, asset) of one Pcp composition error ('' where unknown)."""
    if isinstance(error, Pcp.ErrorSublayerCycle):
        hit = _sublayer_cycle(stage)
        if hit is not None:
            return hit[0], "", "subLayers", hit[1]
    for quoted in _QUOTED.findall(str(error)):
        hit = _arc_of(stage, quoted)
        if hit is not None:
            return hit
    return "", "", "", ""


def _readable_mtlx(quoted: str) -> bool:
    """Whether an asset path Pcp quoted is a .mtlx document that resolves."""
    path = quoted.split(":SDF_FORMAT_ARGS")[0]
    return path.rstrip("]").lower().endswith(".mtlx") and bool(Ar.GetResolver().Resolve(path))


def check_composition(ctx: ReadContext) -> None:
    """Apply the missing-asset policy to every composition error of the stage: under
    ``ctx.strict`` the first is a StageError naming the layer, prim and field that author the
    arc; otherwise each is a warning saying the same (the arc is skipped, as USD does)."""
    # A reference to a .mtlx document that exists cannot compose either (usd-core has no
    # MaterialX file format): renderer/usd/mtlx.py reads the document itself. A missing one is
    # a missing asset like any other.
    errors = [e for e in ctx.stage.GetCompositionErrors()
              if not any(_readable_mtlx(q) for q in _QUOTED.findall(str(e)))]
    for k, error in enumerate(errors):
        if not ctx.strict and k >= _MAX_WARNINGS:
            ctx.warn("composition-more", f"{len(errors) - _MAX_WARNINGS} more composition errors")
            return
        layer, prim, field, _asset = _locate(ctx.stage, error)
        message = one_line(error)
        if ctx.strict:
            raise StageError(f"composition error: {message}", file=layer or ctx.file, prim=prim, attribute=field)
        where = ": ".join(x for x in (layer, f"{prim}.{field}" if prim else field) if x)
        ctx.warn(f"composition-{k}", f"{where + ': ' if where else ''}composition error: {message}; skipped")


def open_layers_refusing_special_files(path: str) -> list[Sdf.Layer]:
    """Open the layer at ``path`` and, depth first, every layer its subLayers, references and
    payloads name (in every variant, since which are selected is known only once composed),
    refusing any that is not a regular file before anything opens it: StageError naming the
    layer, prim and field that author it. Returns the opened layers: held while
    ``Usd.Stage.Open`` runs, it reuses them rather than reading them again.

    Layers that cannot be opened are left to composition (``check_composition``). Value clips
    are not walked (they are opened while composing); the load timeout covers them."""
    problem = special_file_problem(path)
    if problem:
        raise SpecialFileError(f"the stage {problem}", file=path)
    held: list[Sdf.Layer] = []
    seen: set[str] = set()
    todo = [path]
    while todo:
        ident = todo.pop()
        if ident in seen:
            continue
        seen.add(ident)
        try:
            layer = Sdf.Layer.FindOrOpen(ident)
        except Tf.ErrorException:
            layer = None
        if layer is None:
            continue
        held.append(layer)
        variables = dict(layer.expressionVariables or {})
        for authored in layer.GetCompositionAssetDependencies():
            asset = authored
            if Sdf.VariableExpression.IsExpression(authored):
                result = Sdf.VariableExpression(authored).Evaluate(variables)
                if result.errors or not isinstance(result.value, str) or not result.value:
                    continue
                asset = result.value
            anchored = _anchored(asset, layer)
            resolved = str(Ar.GetResolver().Resolve(anchored)) or anchored
            problem = special_file_problem(resolved)
            if problem:
                prim, field = locate_arc(layer, authored)
                raise SpecialFileError(f"'{asset}' {problem}", file=layer.identifier, prim=prim, attribute=field)
            todo.append(resolved)
    return held
