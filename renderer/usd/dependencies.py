"""Files a stage depends on: its layers (sublayers, references, payloads) and assets (textures).

Used to key caches by content (the bench's references) and, later, to confine a service job's
assets to its stage root.
"""

from __future__ import annotations

import os

from pxr import Sdf, UsdUtils


def stage_dependencies(stage_path: str) -> tuple[list[str], list[str]]:
    """(absolute paths of the stage and every resolved dependency, unresolved asset paths)."""
    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(os.path.abspath(stage_path)))
    files = {os.path.abspath(stage_path)}
    files.update(layer.realPath for layer in layers if layer.realPath)
    files.update(a for a in assets if a)
    return sorted(files), sorted(unresolved)
