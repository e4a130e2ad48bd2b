"""illum's codeless USD schemas: IllumLightAPI and IllumRenderSettingsAPI.

Importing this package registers the plugin in this directory with USD's plugin registry.
That must happen before anything first uses ``Usd.SchemaRegistry`` (creating or opening a
stage does), otherwise USD never learns the schema types; ``renderer.usd`` imports this
package first for that reason. The renderer never depends on the registration for correct
results: it reads ``illum:*`` attributes with built-in fallbacks equal to the schema's.

Source of truth: ``schema.usda``. ``generatedSchema.usda`` and ``plugInfo.json`` are produced by
``python -m pxr.Usd.usdGenSchema usd_schemas/schema.usda usd_schemas`` (plugInfo.json then
hand-edited once: no "LibraryPath", "ResourcePath" and "Root" set to "."; regenerating keeps it).
"""

from __future__ import annotations

import os

from pxr import Plug

__all__ = ["PLUGIN_DIR", "LIGHT_API", "RENDER_SETTINGS_API", "register"]

PLUGIN_DIR = os.path.dirname(os.path.abspath(__file__))
LIGHT_API = "IllumLightAPI"
RENDER_SETTINGS_API = "IllumRenderSettingsAPI"

_registered = False


def register() -> None:
    """Register the plugin with ``Plug.Registry()``; calling it again does nothing."""
    global _registered
    if _registered:
        return
    # RegisterPlugins is itself idempotent per path, but the flag saves the plugInfo re-read.
    Plug.Registry().RegisterPlugins(PLUGIN_DIR)
    _registered = True


register()
