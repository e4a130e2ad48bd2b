"""Authoring ``illum:dome:irradiance`` on a DomeLight for `illum preconvolve --stage --light`.

The edit goes through Sdf, in exactly one layer, and touches exactly one attribute spec:

* the layer is the one holding the prim's defining spec (``def``) when that layer is in the
  stage's own layer stack (root layer or a sublayer); otherwise (the light comes through a
  reference or payload, or is only ``over``-ed locally) the root layer, where an ``over`` is
  added if the prim has no spec there;
* the value is an ``asset`` anchored to that layer: ``./relative/path.exr`` when the irradiance
  file can be expressed relative to the layer's directory, else the absolute path;
* nothing else is authored — not even ``apiSchemas``: the reader takes ``illum:dome:irradiance``
  from any authored value (renderer/usd/estimator_api.py). The attribute is written as
  ``custom`` unless IllumLightAPI is applied to the prim (then the schema defines it).

The layer is saved with ``SdfLayer.Save``; its other opinions are unchanged, as is its text for
layers in canonical ``.usda`` form (Sdf re-serialises the file, so hand formatting and ``#``
comments of a hand-written file are normalised).
"""

from __future__ import annotations

import os

from pxr import Sdf, Usd, UsdLux

from renderer.errors import StageError

from .estimator_api import has_light_api

ATTRIBUTE = "illum:dome:irradiance"


def _layer_stack_ids(stage: Usd.Stage) -> set:
    return {layer.identifier for layer in stage.GetLayerStack(includeSessionLayers=False)}


def _asset_value(layer: Sdf.Layer, target: str) -> str:
    """The asset path to author in layer for the file target (absolute)."""
    target = os.path.abspath(target)
    real = layer.realPath
    if not real or layer.anonymous:
        return target
    try:
        rel = os.path.relpath(target, os.path.dirname(os.path.abspath(real)))
    except ValueError:  # another drive (Windows)
        return target
    rel = rel.replace(os.sep, "/")
    return rel if rel.startswith("../") else "./" + rel


def open_dome(stage_path: str, light_path: str):
    """(Usd.Stage, Usd.Prim) of DomeLight light_path in stage_path; StageError if the stage cannot
    be opened or the prim is missing or not a DomeLight / DomeLight_1."""
    if not os.path.isfile(stage_path):
        raise StageError("file not found", file=stage_path)
    try:
        stage = Usd.Stage.Open(stage_path)
    except Exception as e:  # pxr raises Tf.ErrorException with a multi-line text
        raise StageError(f"cannot open stage: {str(e).strip().splitlines()[-1]}", file=stage_path) from None
    if not Sdf.Path.IsValidPathString(light_path) or not Sdf.Path(light_path).IsAbsolutePath():
        raise StageError("--light must be an absolute prim path", file=stage_path, prim=light_path)
    prim = stage.GetPrimAtPath(light_path)
    if not prim or not prim.IsValid():
        raise StageError("no such prim", file=stage_path, prim=light_path)
    dome_1 = getattr(UsdLux, "DomeLight_1", None)
    if not (prim.IsA(UsdLux.DomeLight) or (dome_1 is not None and prim.IsA(dome_1))):
        raise StageError(f"not a DomeLight (type '{prim.GetTypeName()}')", file=stage_path, prim=light_path)
    return stage, prim


def author_dome_irradiance(stage_path: str, light_path: str, irradiance_file: str, source_hash: str = "") -> dict:
    """Author ``illum:dome:irradiance = @irradiance_file@`` on DomeLight light_path of stage_path.

    Returns {'layer': layer file, 'value': authored asset path, 'prim_spec': spec path in that
    layer, 'warnings': [...]}. StageError if the stage cannot be opened, the prim is missing or
    is not a DomeLight / DomeLight_1, or the layer cannot be saved. source_hash (sha256 hex of
    the map that was convolved) adds a warning when the dome's own texture differs.
    """
    stage, prim = open_dome(stage_path, light_path)
    warnings = []
    if source_hash:
        tex = prim.GetAttribute("inputs:texture:file").Get()
        resolved = getattr(tex, "resolvedPath", "") if tex is not None else ""
        if resolved and os.path.isfile(resolved):
            from renderer.preconvolve import file_sha256

            if file_sha256(resolved) != source_hash:
                warnings.append(f"{light_path}: its inputs:texture:file '{tex.path}' is not the map that was "
                                f"convolved; the renderer will find the irradiance stale")

    # The layer that defines the prim (strongest def in the stage's own layer stack), else root.
    local = _layer_stack_ids(stage)
    layer, spec_path = None, None
    for spec in prim.GetPrimStack():
        if spec.specifier == Sdf.SpecifierDef and spec.layer.identifier in local:
            layer, spec_path = spec.layer, spec.path
            break
    if layer is None:
        layer, spec_path = stage.GetRootLayer(), prim.GetPath()
    prim_spec = layer.GetPrimAtPath(spec_path)
    if prim_spec is None:
        prim_spec = Sdf.CreatePrimInLayer(layer, spec_path)  # an 'over' (specifier defaults to over)

    value = _asset_value(layer, irradiance_file)
    attr = prim_spec.attributes.get(ATTRIBUTE) if prim_spec.attributes else None
    if attr is None:
        attr = Sdf.AttributeSpec(prim_spec, ATTRIBUTE, Sdf.ValueTypeNames.Asset,
                                 declaresCustom=not has_light_api(prim))
    attr.default = Sdf.AssetPath(value)
    if layer.realPath and not layer.Save():
        raise StageError("cannot save the layer", file=layer.realPath or stage_path)
    # A stronger opinion elsewhere (e.g. the root layer over a sublayer's def) would mask it.
    composed = prim.GetAttribute(ATTRIBUTE).Get()
    if getattr(composed, "path", composed) != value:
        strongest = next((s.layer.identifier for s in prim.GetAttribute(ATTRIBUTE).GetPropertyStack()), "?")
        warnings.append(f"{light_path}: {ATTRIBUTE} authored in {layer.identifier} is overridden by a "
                        f"stronger opinion in {strongest}")
    return {"layer": layer.realPath or layer.identifier, "value": value, "prim_spec": str(spec_path),
            "warnings": warnings}
