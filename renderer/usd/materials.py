"""UsdShade -> MaterialDesc: binding resolution, UsdPreviewSurface inputs, UsdUVTexture chains.

A Material's ``mtlx`` render context (inline MaterialX networks) is preferred over its
universal UsdPreviewSurface, and a Material (or a binding target) inside a referenced .mtlx
document is read from the document: both in renderer/usd/mtlx.py (docs/materials.md).

Inputs are resolved with ``UsdShadeInput.GetValueProducingAttributes``, which follows
connections through NodeGraph outputs and Material/NodeGraph interface inputs to either a
shader output (a texture) or an attribute holding a value. Unauthored inputs take their
defaults from the Sdr node definitions shipped with usd-core.

Fallback when a gprim has no bound material (or a material without a UsdPreviewSurface):
``primvars:displayColor`` as diffuse colour -- a constant (possibly inherited) value, or on a
mesh a uniform / vertex / faceVarying one read per hit (PrimvarReaderDesc) -- else
UsdPreviewSurface's own default grey (0.18).

UsdPrimvarReader_float, _float2, _float3, _float4, _int, _normal, _point and _vector connected
to a UsdPreviewSurface input (directly or through NodeGraphs) are read per hit
(``MaterialInput.primvar``); a float2 cannot feed a colour. A UsdPrimvarReader_float2 (through
UsdTransform2d nodes) feeds UsdUVTexture.st, any varname. Other nodes, and any node feeding an
input illum reads as a constant (UsdUVTexture file, scale, bias, ...; UsdPrimvarReader_string),
give one warning each and the input's default.
"""

from __future__ import annotations

import numpy as np
from pxr import Ar, Sdf, Sdr, Usd, UsdGeom, UsdShade

from renderer.description import MaterialDesc, MaterialInput, PrimvarReaderDesc, TextureDesc

from .common import ReadContext
from .mtlx import is_mtlx_id, mtlx_reference, read_mtlx_material, read_usd_network

__all__ = ["MaterialTable"]

_SURFACE_ID = "UsdPreviewSurface"
_TEXTURE_ID = "UsdUVTexture"
_WRAP_MODES = ("black", "clamp", "repeat", "mirror")
_COLOR_SPACES = ("raw", "sRGB", "auto")
_OUTPUT_CHANNELS = {"rgb": slice(0, 3), "r": 0, "g": 1, "b": 2, "a": 3}
# UsdPrimvarReader nodes read per hit (PrimvarReaderDesc) -> components; int reads as a float.
_READER_PREFIX = "UsdPrimvarReader_"
_READER_WIDTHS = {"UsdPrimvarReader_float": 1, "UsdPrimvarReader_float2": 2, "UsdPrimvarReader_float3": 3,
                  "UsdPrimvarReader_normal": 3, "UsdPrimvarReader_point": 3, "UsdPrimvarReader_vector": 3,
                  "UsdPrimvarReader_float4": 4, "UsdPrimvarReader_int": 1}
# MaterialDesc field -> (UsdPreviewSurface input, kind); kind 'color' | 'float' | 'vector'
# ('vector': three components like a colour, e.g. the tangent-space normal3f ``normal``).
_TEXTURABLE = {
    "diffuse_color": ("diffuseColor", "color"),
    "emissive_color": ("emissiveColor", "color"),
    "specular_color": ("specularColor", "color"),
    "metallic": ("metallic", "float"),
    "roughness": ("roughness", "float"),
    "opacity": ("opacity", "float"),
    "normal": ("normal", "vector"),
}


def _affine(m: np.ndarray) -> tuple:
    """TextureDesc.st_transform of a (3, 3) 2D affine: () for the identity."""
    if np.array_equal(m, np.eye(3)):
        return ()
    return (float(m[0, 0]), float(m[0, 1]), float(m[1, 0]), float(m[1, 1]), float(m[0, 2]), float(m[1, 2]))


def _sdr_defaults(identifier: str) -> dict:
    node = Sdr.Registry().GetShaderNodeByIdentifier(identifier)
    if not node:
        return {}
    return {name: node.GetShaderInput(name).GetDefaultValue() for name in node.GetShaderInputNames()}


class MaterialTable:
    """Deduplicated table of MaterialDesc, filled as gprims are read.

    ``index_for(prim)`` returns (material index, st primvar name or None when untextured).
    """

    def __init__(self, ctx: ReadContext, binding_purposes: tuple[str, ...]):
        self.ctx = ctx
        self.purposes = tuple(binding_purposes) or ("full", "")
        self.materials: list[MaterialDesc] = []
        self._index: dict[MaterialDesc, int] = {}
        self._by_path: dict[str, tuple[int, str | None] | None] = {}
        self._surface_defaults = _sdr_defaults(_SURFACE_ID)
        self._reader_defaults: dict[str, dict] = {}
        # Readers evaluated per gprim (_reader_on_gprim): the gprim being read, the primvars read
        # from it so far, and per material path the primvars its description depends on.
        self._gprim: Usd.Prim | None = None
        self._gprim_reads: dict[str, object] = {}
        self._per_gprim: dict[str, tuple[str, ...]] = {}
        self._texture_defaults = _sdr_defaults(_TEXTURE_ID)
        self._transform_defaults = {"rotation": 0.0, "scale": (1.0, 1.0), "translation": (0.0, 0.0),
                                    **_sdr_defaults("UsdTransform2d")}

    # ---- table -----------------------------------------------------------------------
    def _add(self, desc: MaterialDesc) -> int:
        idx = self._index.get(desc)
        if idx is None:
            idx = len(self.materials)
            self.materials.append(desc)
            self._index[desc] = idx
        return idx

    def add(self, desc: MaterialDesc) -> int:
        """Index of ``desc`` in the table, adding it when new (e.g. a mesh light's material
        after light:materialSyncMode, usd/lux.py)."""
        return self._add(desc)

    def index_for(self, prim: Usd.Prim) -> tuple[int, str | None]:
        """Material of a gprim: bound material by purpose order, else displayColor, else grey."""
        hit = self._bound_index(prim)
        if hit is not None:
            return hit
        return self._add(self._fallback(prim)), None

    def index_for_subset(self, subset: Usd.Prim, mesh_hit: tuple[int, str | None]) -> tuple[int, str | None]:
        """Material of a materialBind GeomSubset: its bound material (ComputeBoundMaterial also
        walks up to the mesh and its ancestors), else -- nothing bound, or an unusable material
        -- the mesh's own ``mesh_hit`` (so a displayColor fallback stays the mesh's)."""
        hit = self._bound_index(subset)
        return mesh_hit if hit is None else hit

    def _bound_index(self, prim: Usd.Prim) -> tuple[int, str | None] | None:
        material = self._bound_material(prim)
        if material is None:
            return self._bound_mtlx(prim)
        path = str(material.GetPath())
        # Subsets carry no primvars: a reader evaluated per gprim reads the subset's mesh.
        gprim = prim.GetParent() if prim.IsA(UsdGeom.Subset) else prim
        names = self._per_gprim.get(path, ())
        key = (path, tuple(self._gprim_value(gprim, name) for name in names))
        if key not in self._by_path:
            # Read each material once (once per distinct value of the primvars it reads per
            # gprim); an unusable one is remembered as None so that it is neither re-read nor
            # re-warned for every prim bound to it.
            self._gprim, self._gprim_reads = gprim, {}
            try:
                desc, st_name = self._read_material(material)
            finally:
                self._gprim = None
            if self._gprim_reads:
                self._per_gprim[path] = names = tuple(sorted(self._gprim_reads))
                key = (path, tuple(self._gprim_reads[name] for name in names))
            self._by_path[key] = None if desc is None else (self._add(desc), st_name)
        return self._by_path[key]

    # ---- primvar readers evaluated per gprim -------------------------------------------
    def _varname(self, reader: UsdShade.Shader) -> str:
        """The primvar a UsdPrimvarReader reads ('' when unauthored or connected). Some
        exporters write the full attribute name; the primvar's name is what is read."""
        attr = self._producing_attribute(reader, "varname")
        name = attr.Get(self.ctx.time) if attr is not None and not UsdShade.Output.IsOutput(attr) else None
        name = str(name or "")
        return name[len("primvars:"):] if name.startswith("primvars:") else name

    def _gprim_value(self, gprim: Usd.Prim, varname: str):
        """The value of primvar ``varname`` on ``gprim`` (inherited constants included) as a
        hashable value: its first element when it is not constant (with a warning), None when
        the gprim has none."""
        pv = UsdGeom.PrimvarsAPI(gprim).FindPrimvarWithInheritance(varname)
        if not pv or not pv.HasValue():
            return None
        values = pv.ComputeFlattened(self.ctx.time)
        if values is None:
            return None
        if pv.GetTypeName().isArray:
            if len(values) == 0:
                return None
            if len(values) > 1 or pv.GetInterpolation() != UsdGeom.Tokens.constant:
                self.ctx.warn(f"gprim-primvar-{varname}",
                              f"{gprim.GetPath()}: primvars:{varname} ({pv.GetInterpolation()}) feeds a material "
                              f"input illum evaluates once per gprim; its first value is used")
            values = values[0]
        return values if isinstance(values, (str, int, float)) else tuple(float(x) for x in values)

    def _reader_on_gprim(self, reader: UsdShade.Shader):
        """A UsdPrimvarReader_* feeding an input illum reads as a constant (a UsdUVTexture's
        file, scale, bias, fallback; a UsdTransform2d's inputs; ...), evaluated on the gprim
        being read: its primvar's (first) value, else the reader's fallback. The material is
        then read once per distinct value (``_bound_index``)."""
        reader_id = str(reader.GetIdAttr().Get())
        varname = self._varname(reader)
        value = self._gprim_value(self._gprim, varname) if varname else None
        if varname:
            self._gprim_reads[varname] = value
        if value is not None:
            return value
        if reader_id not in self._reader_defaults:
            self._reader_defaults[reader_id] = _sdr_defaults(reader_id)
        return self._constant_input(reader, "fallback", self._reader_defaults[reader_id])

    def _bound_mtlx(self, prim: Usd.Prim) -> tuple[int, str | None] | None:
        """A binding to a material inside a referenced .mtlx document (``def "MaterialX"
        (references = @x.mtlx@</MaterialX>)`` bound at ``/MaterialX/Materials/Name``): the
        target prim does not exist, since the reference cannot compose, so the binding's
        target path is mapped into the document (renderer/usd/mtlx.py)."""
        target = None
        walk = prim
        while target is None and walk and not walk.IsPseudoRoot():
            api = UsdShade.MaterialBindingAPI(walk)
            for purpose in self.purposes:
                rel = api.GetDirectBindingRel(purpose)
                targets = rel.GetTargets() if rel else []
                if targets:
                    target = targets[0]
                    break
            walk = walk.GetParent()
        if target is None:
            return None
        key = (str(target), ())
        if key not in self._by_path:
            desc = st_name = None
            holder = target
            while holder != Sdf.Path.absoluteRootPath:
                held = self.ctx.stage.GetPrimAtPath(holder)
                ref = mtlx_reference(held) if held else None
                if ref is not None:
                    inner = Sdf.Path(ref[2] or "/MaterialX")
                    if holder != target:
                        inner = inner.AppendPath(target.MakeRelativePath(holder))
                    desc, st_name = read_mtlx_material(self.ctx, held, str(target), str(inner))
                    break
                holder = holder.GetParentPath()
            self._by_path[key] = None if desc is None else (self._add(desc), st_name)
        return self._by_path[key]

    def _bound_material(self, prim: Usd.Prim) -> UsdShade.Material | None:
        api = UsdShade.MaterialBindingAPI(prim)
        for purpose in self.purposes:
            material, _rel = api.ComputeBoundMaterial(purpose)
            if material:
                return material
        return None

    def _fallback(self, prim: Usd.Prim) -> MaterialDesc:
        # UsdGeom primvar inheritance: a constant primvar authored on an ancestor applies to
        # every descendant gprim that does not author its own.
        pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayColor")
        if pv and pv.HasValue():
            values = pv.ComputeFlattened(self.ctx.time)
            if values is not None and len(values) > 0:
                color = self.ctx.finite_tuple(prim, "primvars:displayColor", values[0])
                if pv.GetInterpolation() != UsdGeom.Tokens.constant and prim.IsA(UsdGeom.Mesh):
                    # Per-face or per-vertex colours: read per hit, as a UsdPrimvarReader_float3
                    # of displayColor would (Hydra's fallback material does the same).
                    return MaterialDesc(path="", source="displayColor", diffuse_color=MaterialInput(
                        color, primvar=PrimvarReaderDesc("displayColor", 3, color)))
                return MaterialDesc(path="", source="displayColor", diffuse_color=MaterialInput(color))
        return MaterialDesc(path="", source="default")

    # ---- UsdPreviewSurface -----------------------------------------------------------
    def _read_material(self, material: UsdShade.Material) -> tuple[MaterialDesc | None, str | None]:
        ctx = self.ctx
        # The mtlx render context first (MaterialX is preferred where a material has both),
        # else the universal surface output.
        shader, _out, _kind = material.ComputeSurfaceSource("mtlx")
        if shader and is_mtlx_id(shader.GetIdAttr().Get()):
            desc, st_name = read_usd_network(ctx, material, shader)
            if desc is not None:
                return desc, st_name
            shader, _out, _kind = material.ComputeSurfaceSource()
            if not shader or is_mtlx_id(shader.GetIdAttr().Get()):
                return None, None
        if not shader and mtlx_reference(material.GetPrim()) is not None:
            # A .mtlx document referenced onto the Material prim (usd-core cannot compose it).
            ref_target = mtlx_reference(material.GetPrim())[2]
            return read_mtlx_material(ctx, material.GetPrim(), str(material.GetPath()),
                                      ref_target or material.GetPrim().GetName())
        if not shader:
            ctx.warn("material-no-surface",
                     f"{material.GetPath()}: material has no universal surface output; using displayColor/grey")
            return None, None
        shader_id = shader.GetIdAttr().Get()
        if shader_id != _SURFACE_ID:
            ctx.warn(f"material-shader-{shader_id}",
                     f"{shader.GetPath()}: surface shader '{shader_id}' is not supported "
                     f"(only {_SURFACE_ID}); using displayColor/grey")
            return None, None

        fields: dict = {"path": str(material.GetPath())}
        st_names: list[str] = []
        for field, (name, kind) in _TEXTURABLE.items():
            fields[field] = self._texturable_input(shader, name, kind, st_names)
        fields["use_specular_workflow"] = bool(int(self._constant_input(shader, "useSpecularWorkflow")))
        fields["ior"] = float(self._constant_input(shader, "ior"))
        fields["opacity_threshold"] = float(self._constant_input(shader, "opacityThreshold"))
        fields["opacity_mode"] = str(self._constant_input(shader, "opacityMode"))
        for unsupported in ("displacement", "clearcoat", "occlusion"):
            inp = shader.GetInput(unsupported)
            if inp and (inp.HasConnectedSource() or inp.GetAttr().HasAuthoredValue()):
                ctx.warn(f"preview-{unsupported}",
                         f"{shader.GetPath()}: UsdPreviewSurface input '{unsupported}' is ignored by illum")
        # The mesh's st columns hold the first; textures reading others read their own
        # (description.primvar_layout).
        st_name = st_names[0] if st_names else None
        return MaterialDesc(**fields), st_name

    def _producing_attribute(self, shader: UsdShade.Shader, name: str):
        """The attribute that produces input ``name``'s value (after connections), or None."""
        inp = shader.GetInput(name)
        if not inp:
            return None
        attrs = inp.GetValueProducingAttributes()
        return attrs[0] if attrs else None

    def _constant_input(self, shader: UsdShade.Shader, name: str, defaults: dict | None = None):
        attr = self._producing_attribute(shader, name)
        defaults = self._surface_defaults if defaults is None else defaults
        if attr is not None and UsdShade.Output.IsOutput(attr):
            source = UsdShade.Shader(attr.GetPrim())
            if self._gprim is not None and source and str(source.GetIdAttr().Get()).startswith(_READER_PREFIX):
                value = self._reader_on_gprim(source)
                if value is not None:
                    return value
            else:
                self._unsupported_source(attr, shader, name)
        elif attr is not None:
            value = attr.Get(self.ctx.time)
            if value is not None:
                return value
        return defaults.get(name)

    def _unsupported_source(self, output: Usd.Attribute, shader: UsdShade.Shader, name: str) -> None:
        """One warning per (source shader id, input): a node illum does not evaluate feeds an
        input it reads as a constant; the input's default is used."""
        source = UsdShade.Shader(output.GetPrim())
        source_id = source.GetIdAttr().Get() if source else None
        self.ctx.warn(f"input-source-{source_id}-{name}",
                      f"{output.GetPrim().GetPath()}: shader '{source_id}' feeding {shader.GetPath()}.inputs:{name} "
                      f"is not supported there (illum reads that input as a constant); using the default value")

    def _texturable_input(self, shader: UsdShade.Shader, name: str, kind: str,
                          st_names: list[str]) -> MaterialInput:
        ctx = self.ctx
        attr = self._producing_attribute(shader, name)
        where, attr_name = shader.GetPrim(), f"inputs:{name}"
        if attr is not None and UsdShade.Output.IsOutput(attr):
            source = UsdShade.Shader(attr.GetPrim())
            source_id = source.GetIdAttr().Get() if source else None
            if source_id == _TEXTURE_ID:
                output = UsdShade.Output(attr).GetBaseName()
                tex = self._texture(source, output)
                if tex is None:  # no file authored: UsdUVTexture outputs its fallback
                    fb = self._texture_value(source, "fallback")
                    return MaterialInput(self._channel_value(fb, output, kind))
                st_names.append(tex.st_primvar)
                return MaterialInput(self._channel_value(tex.fallback, output, kind), tex)
            if source_id in _READER_WIDTHS:
                reader = self._primvar_input(source, str(source_id), shader, name, kind)
                if reader is not None:
                    return reader
                return MaterialInput(self._default_value(shader, name, kind))
            ctx.warn(f"input-source-{source_id}",
                     f"{attr.GetPrim().GetPath()}: shader '{source_id}' feeding "
                     f"{shader.GetPath()}.inputs:{name} is not supported; using the default value")
            value = self._surface_defaults.get(name)
        elif attr is not None and attr.Get(ctx.time) is not None:
            value = attr.Get(ctx.time)
            where, attr_name = attr.GetPrim(), attr.GetName()
        else:
            value = self._surface_defaults.get(name)
        if kind != "float":
            return MaterialInput(ctx.finite_tuple(where, attr_name, value))
        return MaterialInput(ctx.finite_float(where, attr_name, value))

    def _default_value(self, shader: UsdShade.Shader, name: str, kind: str):
        value = self._surface_defaults.get(name)
        if kind != "float":
            return self.ctx.finite_tuple(shader.GetPrim(), f"inputs:{name}", value)
        return self.ctx.finite_float(shader.GetPrim(), f"inputs:{name}", value)

    def _primvar_input(self, reader: UsdShade.Shader, reader_id: str, shader: UsdShade.Shader, name: str,
                       kind: str) -> MaterialInput | None:
        """A UsdPrimvarReader_* feeding UsdPreviewSurface input ``name``: the primvar read per hit
        (PrimvarReaderDesc) with the reader's fallback as the input's value; None (after a
        warning) where illum cannot map it."""
        ctx = self.ctx
        width = _READER_WIDTHS[reader_id]
        k = 1 if kind == "float" else 3
        if width == 2 and k == 3:
            ctx.warn(f"reader-width-{reader.GetPath()}-{name}",
                     f"{reader.GetPath()}: {reader_id} (2 components) cannot feed the 3-component "
                     f"{shader.GetPath()}.inputs:{name}; using its default value")
            return None
        varname = self._varname(reader)
        if reader_id not in self._reader_defaults:
            self._reader_defaults[reader_id] = _sdr_defaults(reader_id)
        raw = self._constant_input(reader, "fallback", self._reader_defaults[reader_id])
        fallback = ctx.finite_tuple(reader.GetPrim(), "inputs:fallback", np.atleast_1d(
            np.asarray(raw if raw is not None else np.zeros(width), dtype=np.float64)).ravel())
        if len(fallback) < width:
            raise ctx.error(f"fallback has {len(fallback)} components, {reader_id} reads {width}",
                            reader.GetPrim(), "inputs:fallback")
        fallback = fallback[:width]
        value = fallback[0] if k == 1 else (fallback[:1] * 3 if width == 1 else fallback[:3])
        if not varname:  # reads no primvar: always its fallback (the spec)
            return MaterialInput(value)
        return MaterialInput(value, primvar=PrimvarReaderDesc(varname, width, fallback))

    @staticmethod
    def _channel_value(value4: tuple, output: str, kind: str):
        """The part of a float4 (e.g. a texture fallback) that an output name selects."""
        sel = _OUTPUT_CHANNELS.get(output, slice(0, 3))
        if isinstance(sel, slice):
            rgb = tuple(float(x) for x in value4[sel])
            return rgb if kind != "float" else rgb[0]
        v = float(value4[sel])
        return (v, v, v) if kind != "float" else v

    # ---- UsdUVTexture ----------------------------------------------------------------
    def _texture_value(self, tex: UsdShade.Shader, name: str):
        return self._constant_input(tex, name, self._texture_defaults)

    def _texture(self, tex: UsdShade.Shader, output: str) -> TextureDesc | None:
        ctx = self.ctx
        prim = tex.GetPrim()
        file_attr = self._producing_attribute(tex, "file")
        if file_attr is not None and UsdShade.Output.IsOutput(file_attr):
            return self._texture_from_gprim(tex, file_attr, output)
        raw = file_attr.Get(ctx.time) if file_attr is not None else None
        authored = getattr(raw, "path", raw) or ""
        if not authored:
            ctx.warn("texture-no-file", f"{prim.GetPath()}: UsdUVTexture has no inputs:file; using its fallback")
            return None
        # The attribute that holds the path (a Material interface input, when connected).
        return self._texture_desc(tex, output, file_attr.GetPrim(), file_attr.GetName(), raw)

    def _texture_from_gprim(self, tex: UsdShade.Shader, file_attr, output: str) -> TextureDesc | None:
        """UsdUVTexture.file fed by a UsdPrimvarReader_string: the gprim's string primvar, a path
        anchored to the layer that authored the primvar (one material per distinct file)."""
        source = UsdShade.Shader(file_attr.GetPrim())
        if self._gprim is None or not source or str(source.GetIdAttr().Get()) != "UsdPrimvarReader_string":
            self._unsupported_source(file_attr, tex, "file")
            return None
        value = self._reader_on_gprim(source)
        if not value:
            self.ctx.warn(f"texture-no-file-{tex.GetPath()}", f"{tex.GetPath()}: the UsdPrimvarReader_string feeding "
                                                              "inputs:file gives no path; using its fallback")
            return None
        pv = UsdGeom.PrimvarsAPI(self._gprim).FindPrimvarWithInheritance(self._varname(source))
        where, where_name = (pv.GetAttr().GetPrim(), pv.GetAttr().GetName()) if pv else (source.GetPrim(),
                                                                                           "inputs:fallback")
        stack = pv.GetAttr().GetPropertyStack(self.ctx.time) if pv else []
        anchored = stack[0].layer.ComputeAbsolutePath(str(value)) if stack else str(value)
        raw = Sdf.AssetPath(str(value), str(Ar.GetResolver().Resolve(anchored)))
        return self._texture_desc(tex, output, where, where_name, raw)

    def _texture_desc(self, tex: UsdShade.Shader, output: str, where: Usd.Prim, where_name: str,
                      raw) -> TextureDesc | None:
        """The TextureDesc of UsdUVTexture ``tex`` reading image ``raw`` (authored on
        ``where``.``where_name``), or None where the missing-asset policy gives its fallback."""
        ctx = self.ctx
        prim = tex.GetPrim()
        fallback_note = f"{prim.GetPath()} uses its inputs:fallback"
        authored = getattr(raw, "path", raw) or ""
        tiles, tile_data = (), ()
        if "<UDIM>" in authored:
            udim = ctx.udim_tiles(where, where_name, authored, fallback_note)
            if udim is None:
                return None
            (path, tiles, tile_data), data = udim, None
        else:
            asset = ctx.read_image_asset(where, where_name, raw, fallback_note)
            if asset is None:
                return None
            path, data = asset

        def wrap(name: str) -> str:
            mode = str(self._texture_value(tex, name))
            if mode == "useMetadata":
                return mode  # the file's metadata, else black: resolved at load (renderer/textures.py)
            if mode not in _WRAP_MODES:
                raise ctx.error(f"unknown wrap mode '{mode}' (allowed: {', '.join(_WRAP_MODES)}, useMetadata)",
                                prim, f"inputs:{name}")
            return mode

        space = str(self._texture_value(tex, "sourceColorSpace"))
        if space not in _COLOR_SPACES:
            raise ctx.error(f"unknown colour space '{space}' (allowed: {', '.join(_COLOR_SPACES)})",
                            prim, "inputs:sourceColorSpace")
        if output not in _OUTPUT_CHANNELS:
            raise ctx.error(f"unknown UsdUVTexture output '{output}'", prim, f"outputs:{output}")
        st_name, st_transform = self._st_primvar(tex)
        return TextureDesc(
            file=path,
            source_color_space=space,
            wrap_s=wrap("wrapS"),
            wrap_t=wrap("wrapT"),
            scale=ctx.finite_tuple(prim, "inputs:scale", self._texture_value(tex, "scale")),
            bias=ctx.finite_tuple(prim, "inputs:bias", self._texture_value(tex, "bias")),
            fallback=ctx.finite_tuple(prim, "inputs:fallback", self._texture_value(tex, "fallback")),
            output=output,
            st_primvar=st_name,
            st_transform=st_transform,
            data=data,
            udim_tiles=tiles,
            udim_data=tile_data,
        )

    def _st_primvar(self, tex: UsdShade.Shader) -> tuple[str, tuple]:
        """(primvar name read by the UsdPrimvarReader_float2 feeding ``inputs:st`` ('st' if none),
        the UsdTransform2d nodes on the way composed as TextureDesc.st_transform, () if none)."""
        attr = self._producing_attribute(tex, "st")
        m = np.eye(3)  # homogeneous 2D affine, the node nearest the texture applied last
        seen = 0
        while attr is not None and UsdShade.Output.IsOutput(attr) and seen < 8:
            seen += 1
            src = UsdShade.Shader(attr.GetPrim())
            src_id = str(src.GetIdAttr().Get()) if src else ""
            if src_id.startswith("UsdPrimvarReader"):
                return self._varname(src) or "st", _affine(m)
            if src_id == "UsdTransform2d":
                m = m @ self._transform2d(src)
                attr = self._producing_attribute(src, "in")
                continue
            break
        return "st", _affine(m)

    def _transform2d(self, node: UsdShade.Shader) -> np.ndarray:
        """(3, 3) homogeneous matrix of a UsdTransform2d: "result = in * scale * rotate +
        translation" (UsdPreviewSurface spec), rotation counter-clockwise in degrees."""
        prim = node.GetPrim()

        def value(name):
            return self.ctx.finite_tuple(prim, f"inputs:{name}", np.atleast_1d(
                self._constant_input(node, name, self._transform_defaults)))

        sx, sy = value("scale")[:2]
        (angle,) = value("rotation")[:1]
        tx, ty = value("translation")[:2]
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        return np.array([[c * sx, -s * sy, tx], [s * sx, c * sy, ty], [0.0, 0.0, 1.0]])
