"""The USD reading layer: the only package of illum that imports ``pxr``.

``load_stage(path, ...)`` opens a stage and returns a ``renderer.description.SceneDescription``
of plain numpy dataclasses; ``read_stage(stage, ...)`` does the same for an open ``Usd.Stage``.

Modules: ``stage_reader`` (traversal, pruning, meshes, implicit prims, instancing),
``mesh`` (triangulation, primvar expansion), ``implicit`` (tessellation), ``camera``,
``render_settings``, ``materials``, ``lux`` (lights, linking), ``estimator_api`` (illum schema),
``confine`` (the render service's check that a stage reads no file outside its stage root).

What is read and what is not (each unsupported feature gives one warning per stage):
* Subdivision meshes render as their control cage; BasisCurves, Points, NURBS and other
  non-mesh, non-implicit gprims are skipped.
* Lights: Rect, Disk, Sphere, Cylinder, Distant, DomeLight, DomeLight_1, mesh lights (a Mesh
  or implicit gprim with MeshLightAPI / LightAPI, with light:materialSyncMode) and the
  PortalLights a dome's ``portals`` targets. GeometryLight, PluginLight, VolumeLightAPI
  emission and light filters (one warning per light) are skipped or ignored. Lights inside
  PointInstancer prototypes give one light per instance, named ``<prototype light path>[id]``
  (one ``[id]`` per instancer level; ``stage_reader``); mesh lights and PortalLights there are
  skipped with a warning. ShapingAPI and ShadowAPI are read by ``lux_shaping``.
* Materials: UsdPreviewSurface (universal render context) with UsdUVTexture, UsdTransform2d
  and UsdPrimvarReader_* (numeric readers on any UsdPreviewSurface input are read per hit;
  ``materials``); materialBind GeomSubsets split a mesh by material; displacement, clearcoat
  and occlusion inputs are ignored; a ``<UDIM>`` file path reads its tiles 1001-1100
  (``MaterialReader._udim_tiles``). MaterialX (``mtlx``): inline
  networks of ND_* shaders (preferred over a UsdPreviewSurface on the same Material) and
  referenced .mtlx documents, folded onto the same description (docs/materials.md); a node
  that cannot fold gives one warning naming it and the material.
* displayColor fallback: ``primvars:displayColor`` per hit on meshes (constant, uniform, vertex,
  faceVarying; a constant one may be inherited from an ancestor, UsdGeom primvar inheritance).
* Assets (textures, light textures, IES profiles) resolve through Ar, so files inside ``.usdz``
  packages are read from the package (``ReadContext.read_asset``). A missing or unreadable
  asset, sublayer, reference or payload, or a sublayer cycle, gives one warning per file and its
  fallback; ``strict=True`` (``--strict``) makes each an error naming layer, prim and attribute.
* A FIFO, device or directory named as the stage, a sublayer, reference, payload or asset is
  refused before anything opens it (``composition.open_layers_refusing_special_files``,
  ``ReadContext.read_asset``): a SpecialFileError naming the layer, prim and field.
* Memory: each mesh (from faceVertexCounts, before triangulating; then triangles x instances)
  and image (from its header) is charged to the caller's ``renderer.memory.MemoryBudget``.
* No lights: a warning. No camera: usdrecord's framing camera, with a warning.
* Time: one time code, no motion blur (velocities and multiple samples are not read); without
  a frame it is ``stage.GetStartTimeCode()`` (0.0 when unauthored), as usdrecord uses.
* Camera: clippingPlanes clip camera rays; dataWindowNDC overscan beyond [0, 1] is not
  rendered (warning).
* Purpose: a subtree whose authored (or inherited) purpose is excluded is pruned whole, even
  if a descendant authors an included purpose.
"""

# usd_schemas registers illum's schema plugin; that must precede any use of
# Usd.SchemaRegistry (first stage open), so it is imported before everything else here.
import usd_schemas  # noqa: F401  (isort: skip)

from .stage_reader import load_stage, read_stage  # noqa: E402

__all__ = ["load_stage", "read_stage"]
