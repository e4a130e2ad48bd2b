"""BSDFs: the contract (base.py), Lambert, and the UsdPreviewSurface BSDF.

All BSDFs work in the local shading frame (z = shading normal) on batches of points, reflection
only; see base.py for the contract and preview_surface.py for the model and its energy split.
"""

from renderer.bsdfs.base import BSDF, BSDFSample, SupportsDiffuseControlVariate
from renderer.bsdfs.lambert import LambertBSDF
from renderer.bsdfs.preview_surface import LOBE_DIFFUSE, LOBE_SPECULAR, PreviewSurfaceBSDF

__all__ = [
    "BSDF",
    "BSDFSample",
    "SupportsDiffuseControlVariate",
    "LambertBSDF",
    "PreviewSurfaceBSDF",
    "LOBE_DIFFUSE",
    "LOBE_SPECULAR",
]
