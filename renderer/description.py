"""Plain scene description: what `renderer/usd/` produces and the render core consumes.

This is the sync boundary (the way a Hydra delegate syncs): nothing here knows about USD.
Every array is numpy with the batch axis first. Geometry and frames are already in world
space, in scene units (the stage's own units; ``meters_per_unit`` is carried for reference).

Conventions
-----------
* Matrices are 4x4 float64 acting on column vectors: ``p_world = M @ [x, y, z, 1]``.
  (USD's Gf matrices are row-vector; the reader transposes.)
* Colours are linear Rec.709 RGB.
* A light's ``light_to_world`` is its full world transform; lights emit along local -Z
  (rect, disk, distant), outward (sphere, cylinder), and a dome's frame already contains
  the pole-axis correction, so local +Y is the dome's top pole.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Optional

import numpy as np


# --------------------------------------------------------------------------------------
# Textures and materials
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TextureDesc:
    """A UsdUVTexture feeding one material input.

    file: the image's resolved path: an absolute file path, or a package-relative identifier
        (``/a/pkg.usdz[maps/wood.png]``) whose bytes are ``data``.
    data: the image file's bytes when it is not a file on disk (inside a .usdz package, or
        served by a custom asset resolver), read by the reader through USD's asset resolver;
        None for files (renderer/assets.py). Not part of equality: ``file`` names the bytes.
    source_color_space: 'raw' | 'sRGB' | 'auto' ('auto' = sRGB for 8-bit files with 3 or 4
        channels, raw otherwise: the UsdPreviewSurface spec).
    wrap_s, wrap_t: 'black' | 'clamp' | 'repeat' | 'mirror' | 'useMetadata' (resolved when the
        file is loaded: its wrap metadata, else 'black' as the UsdPreviewSurface spec says).
    scale, bias, fallback: (4,) float64 per UsdUVTexture (out = texel * scale + bias).
    output: which output is connected: 'rgb' | 'r' | 'g' | 'b' | 'a'.
    st_primvar: name of the primvar read by the UsdPrimvarReader_float2 ('st' by default).
    st_transform: UsdTransform2d nodes between the reader and the texture, composed:
        (m00, m01, m10, m11, t0, t1) with st' = M st + t, or () for none.
    udim_tiles: for a UDIM path (``file`` then holds the pattern with ``<UDIM>``), the tiles
        found: ((tile number, file), ...), tile 1001 + u + 10 v covering st' in [u, u + 1) x
        [v, v + 1); () for a plain image. udim_data: each tile's bytes (or None), as ``data``.
    """

    file: str
    source_color_space: str = "auto"
    wrap_s: str = "repeat"
    wrap_t: str = "repeat"
    scale: tuple = (1.0, 1.0, 1.0, 1.0)
    bias: tuple = (0.0, 0.0, 0.0, 0.0)
    fallback: tuple = (0.0, 0.0, 0.0, 1.0)
    output: str = "rgb"
    st_primvar: str = "st"
    st_transform: tuple = ()
    data: Optional[bytes] = field(default=None, compare=False, repr=False)
    udim_tiles: tuple = ()
    udim_data: tuple = field(default=(), compare=False, repr=False)


@dataclass(frozen=True)
class PrimvarReaderDesc:
    """A UsdPrimvarReader_* feeding a material input directly: the gprim's primvar ``name``,
    interpolated at each hit as st is (constant, uniform, vertex, varying or faceVarying).

    width: its components (float 1, float2 2, float3 / normal / point / vector 3, float4 4,
        int 1 -- read as a float). fallback: (width,) float, the reader's ``fallback`` input,
        used where the gprim has no such primvar (the spec).
    """

    name: str
    width: int
    fallback: tuple


@dataclass(frozen=True)
class MaterialInput:
    """A constant value (float or RGB triple) optionally overridden per hit by a texture or by a
    primvar (``primvar``; ``value`` is then its fallback mapped to the input, as for a texture).
    A single-component source feeding a colour broadcasts; a float input fed by several
    components takes the first."""

    value: tuple | float
    texture: Optional[TextureDesc] = None
    primvar: Optional[PrimvarReaderDesc] = None


@dataclass(frozen=True)
class MaterialDesc:
    """A UsdPreviewSurface (or the displayColor / grey fallback), with Sdr defaults applied.

    path: the Material prim path ('' for a fallback material made from displayColor).
    source: which network the description was read from, for ``--stats``: 'UsdPreviewSurface',
        'mtlx:<surface node definition>' (an inline MaterialX network or a referenced .mtlx
        document, renderer/usd/mtlx.py), 'displayColor' or 'default'. Reporting only: not part
        of equality.
    normal: the tangent-space shading normal in [-1, 1]^3 (UsdPreviewSurface ``normal``; a
        texture's own scale/bias make the map's [0, 1] texels into that range). (0, 0, 1) leaves
        the interpolated normal as it is.
    """

    path: str
    diffuse_color: MaterialInput = MaterialInput((0.18, 0.18, 0.18))
    emissive_color: MaterialInput = MaterialInput((0.0, 0.0, 0.0))
    specular_color: MaterialInput = MaterialInput((0.0, 0.0, 0.0))
    use_specular_workflow: bool = False
    metallic: MaterialInput = MaterialInput(0.0)
    roughness: MaterialInput = MaterialInput(0.5)
    ior: float = 1.5
    opacity: MaterialInput = MaterialInput(1.0)
    opacity_threshold: float = 0.0
    opacity_mode: str = "transparent"
    normal: MaterialInput = MaterialInput((0.0, 0.0, 1.0))
    source: str = field(default="UsdPreviewSurface", compare=False)


def primvar_layout(materials: list[MaterialDesc]) -> dict[str, tuple[int, int]]:
    """{primvar name: (first column, width)} of the primvars ``materials`` read per hit, in the
    per-hit coordinates after st (columns 2..; renderer/materials.py): those UsdPrimvarReader
    nodes read, and the st primvars of their textures when there are several. A name read with
    several widths gets the largest."""
    widths: dict[str, int] = {}
    st_names: set[str] = set()
    for mat in materials:
        for f in fields(mat):
            inp = getattr(mat, f.name)
            pv = getattr(inp, "primvar", None)
            if pv is not None:
                widths[pv.name] = max(widths.get(pv.name, 0), int(pv.width))
            tex = getattr(inp, "texture", None)
            if tex is not None:
                st_names.add(tex.st_primvar)
    if len(st_names) > 1:  # several st sets: each texture reads its own (renderer/materials.py)
        for name in st_names:
            widths[name] = max(widths.get(name, 0), 2)
    layout, col = {}, 2
    for name in sorted(widths):
        layout[name] = (col, widths[name])
        col += widths[name]
    return layout


# --------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MeshDesc:
    """A triangulated, world-space mesh.

    path: prim path of the source gprim (instance proxies keep their proxy path). A mesh whose
        materialBind GeomSubsets bind other materials gives one MeshDesc per material, all with
        this path.
    points: (V, 3) float64 world-space vertex positions.
    triangles: (T, 3) int32 indices into ``points``, counter-clockwise seen from the front
        (leftHanded orientation has already been flipped by the reader).
    normals: (T, 3, 3) float32 world-space per-corner shading normals, or None (use face normals).
    st: (T, 3, 2) float32 per-corner texture coordinates, or None.
    material: index into ``SceneDescription.materials``.
    double_sided: UsdGeom doubleSided (informational: illum shades both sides of every surface,
        as hdEmbree and Cycles do).
    primvars: {name: (T, 3, k) float32 per-corner values} of the primvars its materials read
        per hit through UsdPrimvarReader nodes (PrimvarReaderDesc); a primvar the gprim lacks is
        absent (the reader's fallback applies).
    """

    path: str
    points: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray]
    st: Optional[np.ndarray]
    material: int
    double_sided: bool = False
    primvars: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------
# Camera and render settings
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraDesc:
    """A UsdGeom.Camera resolved at the render time.

    camera_to_world: (4, 4) float64; the camera looks down local -Z with +Y up, +X right.
    Lengths below are in scene units (USD's tenths of a scene unit already multiplied by 0.1).
    focus_distance is 0 and f_stop 0 when depth of field is off.
    exposure_scale: the linear image scale (2^exposure, times the exposure:* terms of
        UsdGeomCamera.ComputeLinearExposureScale where authored).
    clipping_planes: UsdGeomCamera clippingPlanes, a tuple of (a, b, c, d) in camera space:
        points with a x + b y + c z + d < 0 are cut off (camera rays only).
    """

    path: str
    camera_to_world: np.ndarray
    projection: str = "perspective"
    focal_length: float = 5.0
    horizontal_aperture: float = 2.0955
    vertical_aperture: float = 1.52908
    horizontal_aperture_offset: float = 0.0
    vertical_aperture_offset: float = 0.0
    clipping_range: tuple = (1.0, 1.0e6)
    f_stop: float = 0.0
    focus_distance: float = 0.0
    exposure_scale: float = 1.0
    clipping_planes: tuple = ()


@dataclass(frozen=True)
class RenderSettingsDesc:
    """UsdRender settings merged with the first RenderProduct (product opinions win where authored).

    resolution: (width, height) in pixels.
    data_window_ndc: (xmin, ymin, xmax, ymax), (0,0) bottom-left.
    product_name: default output path ('' when none).
    light_sampler: from IllumRenderSettingsAPI ('' when unauthored: the renderer picks by light count).
    estimator: IllumRenderSettingsAPI's stage-wide default estimator for lights whose own
        illum:estimator is unauthored ('' when unauthored: the schema fallback, mis).
    pixel_filter, pixel_filter_width, pixel_filter_mode: IllumRenderSettingsAPI's illum:pixelFilter
    (token), illum:pixelFilter:width (radius in pixels) and illum:pixelFilter:mode (token); ''
    or 0.0 when unauthored (renderer/pixel_filter.py's defaults apply).
    render_vars: the first product's orderedVars (RenderVarDesc), in order.
    alpha_dome_transparent: IllumRenderSettingsAPI illum:alpha:domeTransparent (renderer/aov.py).
    noise_threshold, adaptive_min_spp: IllumRenderSettingsAPI illum:adaptive:noiseThreshold and
    illum:adaptive:minSpp (renderer/adaptive.py); 0.0 / 0 when unauthored.
    """

    path: str = ""
    resolution: tuple = (640, 480)
    pixel_aspect_ratio: float = 1.0
    aspect_ratio_conform_policy: str = "expandAperture"
    data_window_ndc: tuple = (0.0, 0.0, 1.0, 1.0)
    camera: str = ""
    included_purposes: tuple = ("default", "render")
    material_binding_purposes: tuple = ("full", "")
    product_name: str = ""
    light_sampler: str = ""
    estimator: str = ""
    pixel_filter: str = ""
    pixel_filter_width: float = 0.0
    pixel_filter_mode: str = ""
    render_vars: tuple = ()
    alpha_dome_transparent: bool = False
    noise_threshold: float = 0.0
    adaptive_min_spp: int = 0


@dataclass(frozen=True)
class RenderVarDesc:
    """One RenderVar of the product's orderedVars.

    name: the layer name (the RenderVar prim's name); path: the prim; source_name, source_type
    (raw, primvar, lpe, intrinsic), data_type: as authored; source: the renderer/aov.py SOURCES
    key it computes, '' when illum does not support it (the reader warned once).
    """

    name: str
    path: str
    source_name: str
    source_type: str
    data_type: str
    source: str = ""


# --------------------------------------------------------------------------------------
# Lights
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EstimatorSettings:
    """IllumLightAPI opinions for one light (fallbacks equal the schema's fallbacks).
    estimator_authored: whether illum:estimator is authored; where it is not, the stage-wide
    default (IllumRenderSettingsAPI illum:estimator, or --estimator TOKEN) applies."""

    estimator: str = "mis"
    cv_alpha: str = "averageVisibilityUnbiased"
    samples: int = 1
    mis_heuristic: str = "power"
    dome_irradiance: str = ""
    estimator_authored: bool = False


@dataclass(frozen=True)
class ShapingDesc:
    """UsdLuxShapingAPI inputs of one light, validated by the reader (fallbacks = the schema's).

    cone_angle: degrees in [0, 180]; cone_softness: in [0, 1] (the reader clamps, as the doc
    says); focus: the authored exponent (values < 0 are ignored by the renderer, as the doc
    says); ies_file: absolute path or ''; ies_profile: the parsed IesProfile (the reader parses
    it so that a malformed file is reported against the prim), or None to parse on build.
    """

    focus: float = 0.0
    focus_tint: tuple = (0.0, 0.0, 0.0)
    cone_angle: float = 90.0
    cone_softness: float = 0.0
    ies_file: str = ""
    ies_angle_scale: float = 0.0
    ies_normalize: bool = False
    ies_profile: Optional[object] = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class ShadowDesc:
    """UsdLuxShadowAPI inputs of one light (fallbacks = the schema's).

    distance: world units, <= 0 means no limit; falloff: world units, <= 0 means no falloff
    zone (the reader clamps it to distance); falloff_gamma: >= 0.
    """

    enable: bool = True
    color: tuple = (0.0, 0.0, 0.0)
    distance: float = -1.0
    falloff: float = -1.0
    falloff_gamma: float = 1.0

    @property
    def is_default(self) -> bool:
        """True when shadows behave exactly as without the API (full, black, unlimited)."""
        return self.enable and not any(self.color) and not self.distance > 0.0


@dataclass(frozen=True)
class LightDesc:
    """One UsdLux light, with its raw radiometric inputs (the render core applies the spec formula).

    kind: 'rect' | 'disk' | 'sphere' | 'dome' | 'distant' | 'cylinder' | 'mesh'.
    light_to_world: (4, 4) float64; for domes it includes the poleAxis / up-axis correction.
    texture_file: resolved path ('' when none), as TextureDesc.file; texture_data its bytes when
    it is not a file on disk (TextureDesc.data); texture_format for domes.
    """

    path: str
    kind: str
    light_to_world: np.ndarray
    intensity: float = 1.0
    exposure: float = 0.0
    color: tuple = (1.0, 1.0, 1.0)
    enable_color_temperature: bool = False
    color_temperature: float = 6500.0
    normalize: bool = False
    diffuse: float = 1.0
    specular: float = 1.0
    width: float = 1.0
    height: float = 1.0
    radius: float = 0.5
    length: float = 1.0
    angle: float = 0.53
    treat_as_point: bool = False
    treat_as_line: bool = False
    texture_file: str = ""
    texture_format: str = "automatic"
    texture_data: Optional[bytes] = field(default=None, compare=False, repr=False)
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    # Light linking, resolved against the stage's gprims by the reader: None means "everything".
    light_link_excludes: Optional[frozenset] = None  # mesh paths NOT illuminated
    shadow_link_excludes: Optional[frozenset] = None  # mesh paths that cast NO shadow
    # UsdLux ShapingAPI / ShadowAPI opinions; None when the light has neither the API nor any
    # authored attribute of it (the light emits and shadows as if unshaped / by default).
    shaping: Optional["ShapingDesc"] = None
    shadow: Optional["ShadowDesc"] = None
    # Mesh lights (kind 'mesh': a gprim with LightAPI / MeshLightAPI). mesh_path names the
    # MeshDesc that is the light's geometry; mesh_triangles (T, 3, 3) float64 are exactly that
    # MeshDesc's world-space triangles (front = counter-clockwise); mesh_two_sided is the gprim's
    # doubleSided; material_sync_mode the resolved light:materialSyncMode token. ``color`` already
    # includes the material glow tint (materialGlowTintsLight).
    mesh_path: str = ""
    mesh_triangles: Optional[np.ndarray] = None
    mesh_two_sided: bool = False
    material_sync_mode: str = ""
    # Dome portals: (K, 4, 4) float64 world matrices of the targeted PortalLights with their
    # width and height folded in (local X/Y span [-1/2, 1/2]; light passes toward local -Z),
    # and their prim paths. None when the dome has no (usable) portals.
    portals: Optional[np.ndarray] = None
    portal_paths: tuple = ()


# --------------------------------------------------------------------------------------
# The whole scene
# --------------------------------------------------------------------------------------
@dataclass
class SceneDescription:
    """Everything the render core needs, with no USD types inside.

    stats: counters the reader fills (prims visited, pruned subtrees, points read, ...).
    warnings: human-readable warnings, each said once per stage.
    strict: the stage was read with ``--strict`` (every missing or unreadable asset is an
        error); the render core decodes its textures under the same policy.
    """

    source: str
    time_code: float
    meshes: list[MeshDesc]
    materials: list[MaterialDesc]
    lights: list[LightDesc]
    camera: CameraDesc
    settings: RenderSettingsDesc
    meters_per_unit: float = 0.01
    up_axis: str = "Y"
    warnings: list[str] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    strict: bool = False


# --------------------------------------------------------------------------------------
# Re-centring
# --------------------------------------------------------------------------------------
# Lights at infinity: only their frame's rotation matters, so re-centring leaves them alone.
INFINITE_LIGHT_KINDS = ("dome", "distant")


def _shift(m: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(..., 4, 4) column-vector matrices with ``offset`` added to their translation column."""
    out = np.array(m, dtype=np.float64, copy=True)
    out[..., :3, 3] += offset
    return out


def translated(desc: SceneDescription, offset) -> SceneDescription:
    """A copy of ``desc`` with every position moved by ``offset`` (3,) float64 scene units:
    mesh points, the camera, finite lights' frames, mesh lights' triangles and dome portals.

    Directions (normals, clipping planes in camera space) do not move, nor do infinite lights
    (dome, distant): only their rotation matters, and a translation column moved to 1e30 would
    be meaningless. Used by renderer/scene.py to re-centre the scene for float32 tracing."""
    from dataclasses import replace

    offset = np.asarray(offset, dtype=np.float64).reshape(3)
    meshes = [replace(m, points=np.asarray(m.points, dtype=np.float64) + offset) for m in desc.meshes]
    lights = []
    for ld in desc.lights:
        changes = {}
        if ld.kind not in INFINITE_LIGHT_KINDS:
            changes["light_to_world"] = _shift(ld.light_to_world, offset)
        if ld.mesh_triangles is not None:
            changes["mesh_triangles"] = np.asarray(ld.mesh_triangles, dtype=np.float64) + offset
        if ld.portals is not None:
            changes["portals"] = _shift(ld.portals, offset)
        lights.append(replace(ld, **changes) if changes else ld)
    camera = replace(desc.camera, camera_to_world=_shift(desc.camera.camera_to_world, offset))
    return replace(desc, meshes=meshes, lights=lights, camera=camera, warnings=list(desc.warnings),
                   stats=dict(desc.stats))
