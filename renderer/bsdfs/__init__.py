"""BSDFs: the contract (base.py), Lambert, and the UsdPreviewSurface BSDF."""
