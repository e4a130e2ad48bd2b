"""MaterialX networks -> MaterialDesc: inline UsdShade networks of MaterialX nodes and .mtlx documents.

Two sources give the same description:

* inline networks in USD: UsdShade shaders whose ``info:id`` is a MaterialX node definition
  (``ND_standard_surface_surfaceshader``, ``ND_image_color3``, ...), usually behind a Material's
  ``outputs:mtlx:surface`` (the ``mtlx`` render context);
* ``.mtlx`` documents referenced from USD (usd-core has no .mtlx file-format plugin, so such a
  reference does not compose): read with the ``MaterialX`` package (``MtlxDocument``).

Node definitions, input types and defaults come from MaterialX's own standard libraries
(``MaterialX.loadLibraries``), as UsdPreviewSurface's come from Sdr. A library node implemented
as a node graph (tiledimage, place2d, UsdUVTexture, UsdTransform2d, ...) is evaluated through
that graph.

Evaluation stays in the renderer's material machinery (a MaterialInput is a constant, or one
texture with per-channel scale and bias and an st transform, renderer/materials.py), so a
network is folded at read time into values of the form ``out = A x + b``: x the components of
one source (a texture's RGBA texels, or the st coordinates) and A, b constants (``_Lin``).
Every linear node folds (multiply or divide by a constant, add, subtract, mix with a constant
weight, invert, remap, normalmap, convert, extract/separate/combine, rotate2d, ...), and
every node folds when all its inputs are constant (clamp, power, min, max, ...). A node that
cannot be folded -- an unknown node, a nonlinear node of a texture, two textures combined, a
normal map feeding anything but a surface's normal -- gives one warning naming the node and the
material, and the surface input it feeds takes its default. docs/materials.md gives the
surface mappings (UsdPreviewSurface exactly; standard_surface and open_pbr_surface as an
approximation onto illum's UsdPreviewSurface BSDF) with their formulas and what is lost.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from pxr import Ar, Sdf, Usd, UsdShade

from renderer.description import MaterialDesc, MaterialInput, PrimvarReaderDesc, TextureDesc

from .common import ReadContext

__all__ = ["document_files", "is_mtlx_id", "mtlx_reference", "read_mtlx_material", "read_usd_network"]

_WIDTH = {"float": 1, "integer": 1, "boolean": 1, "color3": 3, "color4": 4, "vector2": 2, "vector3": 3,
          "vector4": 4}
# MaterialX address modes -> TextureDesc wrap modes ('constant' gives black, not the image's
# default, outside [0, 1]: docs/materials.md).
_ADDRESS = {"constant": "black", "clamp": "clamp", "periodic": "repeat", "mirror": "mirror",
            # UsdUVTexture's wrap modes, when one sits in a MaterialX network
            "black": "black", "repeat": "repeat", "useMetadata": "useMetadata"}
# UsdShade shader ids of USD's own nodes -> the MaterialX library's definitions of them, for
# networks that mix the two (their unauthored inputs keep USD's Sdr defaults).
_USD_IDS = {"UsdUVTexture": "ND_UsdUVTexture", "UsdTransform2d": "ND_UsdTransform2d",
            "UsdPrimvarReader_float": "ND_UsdPrimvarReader_float",
            "UsdPrimvarReader_float2": "ND_UsdPrimvarReader_vector2",
            "UsdPrimvarReader_float3": "ND_UsdPrimvarReader_vector3",
            "UsdPrimvarReader_float4": "ND_UsdPrimvarReader_vector4"}
# Colour spaces of image files: MaterialX names (and USD's colorSpace metadata) -> TextureDesc's.
_SRGB = {"srgb_texture", "srgb", "srgb_rec709", "g22_rec709"}
_RAW = {"", "lin_rec709", "lin_srgb", "raw", "srgb_linear", "rec709_linear", "scene_linear"}
_SURFACES = {"UsdPreviewSurface", "standard_surface", "open_pbr_surface", "gltf_pbr"}
_MAX_DEPTH = 100  # nodes on one path through a network: deeper is taken for a cycle


def is_mtlx_id(shader_id) -> bool:
    """Whether a UsdShade shader's info:id names a MaterialX node definition."""
    return str(shader_id or "").startswith("ND_")


@lru_cache(maxsize=1)
def _library():
    """MaterialX's standard data libraries (stdlib, pbrlib, bxdf: standard_surface,
    open_pbr_surface, UsdPreviewSurface, ...), loaded once per process."""
    import MaterialX as mx

    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    return lib


def _sdr_defaults(identifier: str) -> dict:
    """Sdr's defaults of one of USD's own shader nodes (renderer/usd/materials.py's)."""
    from .materials import _sdr_defaults as sdr

    return sdr(identifier)


def _nodedef(name: str):
    return _library().getNodeDef(str(name)) if name else None


# --------------------------------------------------------------------------------------
# Folded values: out = A x + b
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Image:
    """An image node's texture before any math: the file, how it is read, where it is looked up
    (st primvar and the affine st transform (m00, m01, m10, m11, t0, t1), () for none) and its
    MaterialX ``default`` as RGBA (used where the file cannot be read)."""

    file: str
    data: bytes | None
    space: str
    wrap_s: str
    wrap_t: str
    st_primvar: str
    st_transform: tuple
    default: tuple
    node: str = field(default="", compare=False)  # the image node's label, for warnings
    udim_tiles: tuple = ()  # a <UDIM> file's ((tile, file), ...), as TextureDesc.udim_tiles
    udim_data: tuple = ()


@dataclass(frozen=True)
class _Primvar:
    """A primvar read per hit (geompropvalue, UsdPrimvarReader): its components and default."""

    name: str
    width: int
    fallback: tuple
    node: str  # the reading node's label, for warnings


@dataclass(frozen=True)
class _St:
    """Texture coordinates: the primvar read (MaterialX texcoord index 0 is USD's 'st')."""

    primvar: str


class _Lin:
    """n components ``A @ x + b``: x the (m,) components of ``source`` (an _Image's RGBA texels,
    an _St's (s, t), or nothing for a constant: m = 0). ``kind`` 'normal' marks a tangent-space
    normal from a normalmap node (only a surface's normal input takes it)."""

    __slots__ = ("A", "b", "source", "kind")

    def __init__(self, A, b, source=None, kind: str = ""):
        self.b = np.asarray(b, dtype=np.float64).reshape(-1)
        self.A = np.asarray(A, dtype=np.float64).reshape(self.b.size, -1)
        self.source = source
        self.kind = kind

    @staticmethod
    def const(v) -> "_Lin":
        b = np.atleast_1d(np.asarray(v, dtype=np.float64)).reshape(-1)
        return _Lin(np.zeros((b.size, 0)), b)

    @property
    def n(self) -> int:
        return self.b.size

    @property
    def is_const(self) -> bool:
        return self.source is None or not np.any(self.A)

    def rows(self, idx) -> "_Lin":
        return _Lin(self.A[list(idx)], self.b[list(idx)], self.source)

    def width(self, n: int) -> "_Lin":
        """As n components: a single one broadcasts, extra ones are dropped, a missing alpha
        (3 -> 4) is 1 (MaterialX's convert)."""
        if self.n == n:
            return self
        if self.n == 1:
            return self.rows([0] * n)
        if self.n > n:
            return self.rows(range(n))
        pad = n - self.n
        return _Lin(np.vstack([self.A, np.zeros((pad, self.A.shape[1]))]), np.r_[self.b, np.ones(pad)], self.source)


class _Unsupported(Exception):
    """A node illum cannot fold: ``node`` its label, ``why`` the reason (or '')."""

    def __init__(self, node, why: str = ""):
        super().__init__(why)
        self.node = node
        self.why = why


def _sum(node, terms, const=None) -> _Lin:
    """sum of c_i * t_i (c_i (n,) constants, t_i _Lin of n components) + const: at most one
    source may vary."""
    source = None
    for _c, t in terms:
        if not t.is_const:
            if source is not None and t.source != source:
                raise _Unsupported(node, "it combines two different textures (or a texture and texture "
                                         "coordinates), which illum's single-texture inputs cannot evaluate")
            source = t.source
    n = terms[0][1].n
    m = 0 if source is None else next(t.A.shape[1] for _c, t in terms if t.source == source and not t.is_const)
    A = np.zeros((n, m))
    b = np.zeros(n) if const is None else np.asarray(const, dtype=np.float64).copy()
    for c, t in terms:
        c = np.broadcast_to(np.asarray(c, dtype=np.float64), (n,))
        if not t.is_const:
            A = A + c[:, None] * t.A
        b = b + c * t.b
    return _Lin(A, b, source)


def _scaled(node, a: _Lin, c: _Lin) -> _Lin:
    """a * c where one of them is constant."""
    if not c.is_const:
        a, c = c, a
    if not c.is_const:
        raise _Unsupported(node, "it multiplies two varying values (textures or coordinates), which illum "
                                 "cannot fold into one texture lookup")
    return _sum(node, [(c.b, a)])


# Nodes folded only when every input is constant: category -> (input names, function of arrays).
_CONST_ONLY = {
    "clamp": (("in", "low", "high"), lambda x, lo, hi: np.minimum(np.maximum(x, lo), hi)),
    "min": (("in1", "in2"), np.minimum),
    "max": (("in1", "in2"), np.maximum),
    "power": (("in1", "in2"), np.power),
    "absval": (("in",), np.abs),
    "sqrt": (("in",), np.sqrt),
    "floor": (("in",), np.floor),
    "ceil": (("in",), np.ceil),
    "sign": (("in",), np.sign),
    "modulo": (("in1", "in2"), lambda a, b: a - b * np.floor(a / b)),
    "sin": (("in",), np.sin),
    "cos": (("in",), np.cos),
    "exp": (("in",), np.exp),
    "ln": (("in",), np.log),
    "smoothstep": (("in", "low", "high"),
                   lambda x, lo, hi: (lambda t: t * t * (3 - 2 * t))(np.clip((x - lo) / (hi - lo), 0, 1))),
    "normalize": (("in",), lambda v: v / np.linalg.norm(v)),
    "magnitude": (("in",), lambda v: np.atleast_1d(np.linalg.norm(v))),
    "dotproduct": (("in1", "in2"), lambda a, b: np.atleast_1d(np.dot(a, b))),
    "luminance": (("in", "lumacoeffs"), lambda c, w: np.r_[np.full(3, np.dot(c[:3], w[:3])), c[3:]]),
}


# --------------------------------------------------------------------------------------
# Node adapters: a UsdShade shader, a node of a .mtlx document, a node of a library graph
# --------------------------------------------------------------------------------------
class _UsdNode:
    """A UsdShade shader whose info:id is a MaterialX node definition."""

    def __init__(self, shader: UsdShade.Shader, time):
        self.shader = shader
        self.time = time
        self.label = str(shader.GetPath())
        self.node_id = str(shader.GetIdAttr().Get() or "") if shader else ""
        self.nodedef = _nodedef(_USD_IDS.get(self.node_id, self.node_id))
        # USD's defaults, except where MaterialX's is a geometric property (UsdUVTexture.st is
        # the 'st' primvar when unconnected, as illum's UsdPreviewSurface path reads it).
        # So is an unconnected UsdTransform2d.in there (renderer/usd/materials.py _st_primvar).
        defs = {d.getName(): d for d in self.nodedef.getActiveInputs()} if self.nodedef is not None else {}
        self.texcoord_inputs = {k for k, d in defs.items() if d.getDefaultGeomProp() is not None} | (
            {"in"} if self.node_id == "UsdTransform2d" else set())
        self.usd_defaults = {k: v for k, v in _sdr_defaults(self.node_id).items()
                             if k in defs and k not in self.texcoord_inputs} if self.node_id in _USD_IDS else {}

    def _attr(self, name: str):
        inp = self.shader.GetInput(name)
        if not inp:
            return None
        attrs = inp.GetValueProducingAttributes()
        return attrs[0] if attrs else None

    def source(self, name: str):
        """None (unauthored), ('value', v) or ('node', adapter, output name)."""
        attr = self._attr(name)
        if attr is None:
            default = self.usd_defaults.get(name)
            return None if default is None else ("value", default)
        if UsdShade.Output.IsOutput(attr):
            return "node", _UsdNode(UsdShade.Shader(attr.GetPrim()), self.time), UsdShade.Output(attr).GetBaseName()
        value = attr.Get(self.time)
        return None if value is None else ("value", value)

    def asset(self, name: str):
        """(prim, attribute name, Sdf.AssetPath, colour space) of a filename input."""
        attr = self._attr(name)
        if attr is None or UsdShade.Output.IsOutput(attr):
            return None
        space = attr.GetColorSpace() if attr.HasColorSpace() else ""
        if not space and self.node_id == "UsdUVTexture":  # its own input, 'auto' by default
            source = self.source("sourceColorSpace")
            space = str(source[1]) if source is not None and source[0] == "value" else "auto"
        return attr.GetPrim(), attr.GetName(), attr.Get(self.time), str(space)


class _DocNode:
    """A node of a .mtlx document (top level or inside a nodegraph). ``where`` is the USD prim
    the document is referenced from (for messages and the missing-asset policy), ``doc`` the
    document's resolved path (file paths are relative to its directory)."""

    def __init__(self, element, where: Usd.Prim, doc: str):
        self.element = element
        self.where = where
        self.doc = doc
        self.label = f"{element.getNamePath()}"
        nd = element.getNodeDef()
        self.nodedef = nd if nd is not None else _nodedef("")
        self.node_id = nd.getName() if nd is not None else element.getCategory()

    def _wrap(self, element):
        return _DocNode(element, self.where, self.doc)

    def source(self, name: str):
        inp = self.element.getInput(name)
        if inp is None:
            return None
        if inp.getNodeGraphString():
            graph = self.element.getDocument().getNodeGraph(inp.getNodeGraphString())
            out = graph.getOutput(inp.getOutputString() or "out") if graph is not None else None
            if out is None or not out.getNodeName():
                raise _Unsupported(self.label, f"input '{name}' names a missing nodegraph output")
            return "node", self._wrap(graph.getNode(out.getNodeName())), out.getOutputString() or "out"
        if inp.getNodeName():
            node = self.element.getParent().getNode(inp.getNodeName())
            if node is None:
                raise _Unsupported(self.label, f"input '{name}' names a missing node '{inp.getNodeName()}'")
            return "node", self._wrap(node), inp.getOutputString() or "out"
        if inp.getInterfaceName():
            graph_input = self.element.getParent().getInput(inp.getInterfaceName())
            if graph_input is None:
                return None
            if graph_input.getNodeName():  # a graph input fed by a top-level node
                node = self.element.getDocument().getNode(graph_input.getNodeName())
                return "node", self._wrap(node), graph_input.getOutputString() or "out"
            inp = graph_input
        return None if inp.getValue() is None else ("value", inp.getValue())

    def asset(self, name: str):
        inp = self.element.getInput(name)
        if inp is not None and inp.getInterfaceName():
            inp = self.element.getParent().getInput(inp.getInterfaceName())
        if inp is None or not inp.getResolvedValueString():
            return None
        authored = inp.getResolvedValueString()  # with the document's fileprefix applied
        path = _join(self.doc, authored)
        resolved = str(Ar.GetResolver().Resolve(path))
        doc = os.path.basename(self.doc.rstrip("]")) or "MaterialX document"
        return (self.where, f"references ({doc}: {self.label}.{name})", Sdf.AssetPath(path, resolved),
                inp.getActiveColorSpace())


class _GraphNode:
    """A node inside a library node graph that implements ``outer`` (e.g. NG_tiledimage_color3):
    its interface inputs are ``outer``'s inputs."""

    def __init__(self, element, outer):
        self.element = element
        self.outer = outer
        self.label = outer.label  # warnings name the user's node
        nd = element.getNodeDef()
        self.nodedef = nd
        self.node_id = nd.getName() if nd is not None else element.getCategory()

    def source(self, name: str):
        inp = self.element.getInput(name)
        if inp is None:
            return None
        if inp.getInterfaceName():
            return "input", self.outer, inp.getInterfaceName()
        if inp.getNodeName():
            return "node", _GraphNode(self.element.getParent().getNode(inp.getNodeName()), self.outer), \
                inp.getOutputString() or "out"
        return None if inp.getValue() is None else ("value", inp.getValue())

    def asset(self, name: str):
        return None


def _as_array(value) -> np.ndarray:
    if hasattr(value, "asTuple"):
        value = value.asTuple()
    if isinstance(value, (bool, int, float, np.floating, np.integer)):
        return np.array([float(value)])
    return np.asarray(tuple(value), dtype=np.float64).reshape(-1)


# --------------------------------------------------------------------------------------
# The evaluator
# --------------------------------------------------------------------------------------
class _Network:
    """Folds one material's network; ``material`` names it in warnings."""

    def __init__(self, ctx: ReadContext, material: str):
        self.ctx = ctx
        self.material = material
        self.st_names: list[str] = []
        self._warned: set[str] = set()
        self._depth = 0

    # ---- inputs ------------------------------------------------------------------------
    def _input_def(self, node, name: str):
        nd = node.nodedef
        return nd.getActiveInput(name) if nd is not None else None

    def text(self, node, name: str) -> str:
        """A string / filename / token input's value (its default when unauthored)."""
        src = node.source(name)
        if src is not None and src[0] == "input":
            return self.text(src[1], src[2])
        if src is not None and src[0] == "value":
            return str(getattr(src[1], "path", src[1]))
        if src is not None:
            raise _Unsupported(src[1].label, f"it feeds the string input '{name}' of {node.label}")
        d = self._input_def(node, name)
        return d.getValueString() if d is not None else ""

    def value(self, node, name: str, n: int | None = None) -> _Lin:
        """Input ``name`` of ``node`` folded, as n components (the input's type width if None)."""
        d = self._input_def(node, name)
        if n is None:
            n = _WIDTH.get(d.getType(), 1) if d is not None else 1
        src = node.source(name)
        if src is None:
            if d is None:
                raise _Unsupported(node.label, f"it has no input '{name}'")
            geom = d.getDefaultGeomProp()
            if geom is not None or name in getattr(node, "texcoord_inputs", ()):
                if d.getType() == "vector2":  # UV0: the default texture coordinates
                    return _Lin(np.eye(2)[:n] if n <= 2 else np.eye(2)[[0] * n], np.zeros(n), _St("st"))
                raise _Unsupported(node.label, f"its input '{name}' defaults to the geometric property "
                                               f"'{d.getDefaultGeomPropString()}'")
            return _Lin.const(_as_array(d.getValue()) if d.getValue() is not None else np.zeros(n)).width(n)
        if src[0] == "value":
            try:
                return _Lin.const(_as_array(src[1])).width(n)
            except (TypeError, ValueError):
                raise _Unsupported(node.label, f"its input '{name}' holds {src[1]!r}, not a number") from None
        if src[0] == "input":
            return self.value(src[1], src[2], n)
        return self.output(src[1], src[2]).width(n)

    # ---- outputs -----------------------------------------------------------------------
    def output(self, node, out: str) -> _Lin:
        self._depth += 1
        try:
            if self._depth > _MAX_DEPTH:
                raise _Unsupported(node.label, f"the network is deeper than {_MAX_DEPTH} nodes (a cycle?)")
            return self._output(node, out)
        finally:
            self._depth -= 1

    def _output(self, node, out: str) -> _Lin:
        nd = node.nodedef
        if nd is None:
            raise _Unsupported(node.label, f"'{node.node_id}' is not a MaterialX node definition illum knows")
        cat = nd.getNodeString()
        outputs = {o.getName(): o.getType() for o in nd.getActiveOutputs()}
        n = _WIDTH.get(outputs.get(out, nd.getType()), 1)
        handler = getattr(self, f"_node_{cat}", None)
        if handler is not None:
            return handler(node, out, n)
        if cat in _CONST_ONLY:
            names, fn = _CONST_ONLY[cat]
            args = [self.value(node, a) for a in names]
            if not all(a.is_const for a in args):
                raise _Unsupported(node.label, f"'{cat}' of a texture is not linear, and illum folds only "
                                               "linear nodes into texture lookups")
            with np.errstate(all="ignore"):
                return _Lin.const(np.asarray(fn(*[a.b for a in args]), dtype=np.float64).reshape(-1)).width(n)
        impl = nd.getImplementation()
        if impl is not None and impl.getCategory() == "nodegraph" and cat not in _SURFACES:
            graph_out = impl.getOutput(out) or impl.getOutputs()[0]
            inner = impl.getNode(graph_out.getNodeName())
            try:
                return self.output(_GraphNode(inner, node), graph_out.getOutputString() or "out")
            except _Unsupported as e:
                raise _Unsupported(node.label, e.why) from None
        raise _Unsupported(node.label, f"illum does not evaluate '{cat}' nodes")

    def _node_constant(self, node, out, n):
        return self.value(node, "value", n)

    def _node_dot(self, node, out, n):
        return self.value(node, "in", n)

    def _node_convert(self, node, out, n):
        return self.value(node, "in").width(n)

    def _node_multiply(self, node, out, n):
        return _scaled(node.label, self.value(node, "in1", n), self.value(node, "in2", n))

    def _node_divide(self, node, out, n):
        b = self.value(node, "in2", n)
        if not b.is_const:
            raise _Unsupported(node.label, "it divides by a texture, which is not linear")
        with np.errstate(divide="ignore"):
            return _sum(node.label, [(1.0 / b.b, self.value(node, "in1", n))])

    def _node_add(self, node, out, n):
        return _sum(node.label, [(1.0, self.value(node, "in1", n)), (1.0, self.value(node, "in2", n))])

    def _node_subtract(self, node, out, n):
        return _sum(node.label, [(1.0, self.value(node, "in1", n)), (-1.0, self.value(node, "in2", n))])

    def _node_mix(self, node, out, n):
        # MaterialX: out = bg * (1 - mix) + fg * mix.
        fg, bg, w = self.value(node, "fg", n), self.value(node, "bg", n), self.value(node, "mix", n)
        if w.is_const:
            return _sum(node.label, [(w.b, fg), (1.0 - w.b, bg)])
        if fg.is_const and bg.is_const:  # bg + (fg - bg) * mix
            return _sum(node.label, [(fg.b - bg.b, w)], bg.b)
        raise _Unsupported(node.label, "it mixes textures by a texture, which is not linear")

    def _node_invert(self, node, out, n):
        return _sum(node.label, [(-1.0, self.value(node, "in", n))], self.value(node, "amount", n).b)

    def _node_remap(self, node, out, n):
        x = self.value(node, "in", n)
        lo, hi, olo, ohi = (self.value(node, k, n) for k in ("inlow", "inhigh", "outlow", "outhigh"))
        if not all(v.is_const for v in (lo, hi, olo, ohi)):
            raise _Unsupported(node.label, "its range inputs are textured")
        with np.errstate(divide="ignore", invalid="ignore"):
            k = (ohi.b - olo.b) / (hi.b - lo.b)
        return _sum(node.label, [(k, x)], olo.b - k * lo.b)

    def _node_extract(self, node, out, n):
        x = self.value(node, "in")
        index = self.value(node, "index", 1)
        if not index.is_const:
            raise _Unsupported(node.label, "its index is not constant")
        return x.rows([int(index.b[0])])

    def _separate(self, node, out, n):
        x = self.value(node, "in")
        k = {"outx": 0, "outy": 1, "outz": 2, "outw": 3, "outr": 0, "outg": 1, "outb": 2, "outa": 3}.get(out)
        if k is None or k >= x.n:
            raise _Unsupported(node.label, f"unknown output '{out}'")
        return x.rows([k])

    _node_separate2 = _node_separate3 = _node_separate4 = _separate

    def _combine(self, node, out, n):
        parts = [self.value(node, d.getName()) for d in node.nodedef.getActiveInputs()]
        sources = {p.source for p in parts if not p.is_const}
        if len(sources) > 1:
            raise _Unsupported(node.label, "it combines channels of different textures")
        m = max((p.A.shape[1] for p in parts if not p.is_const), default=0)
        A = np.vstack([p.A if not p.is_const else np.zeros((p.n, m)) for p in parts])
        return _Lin(A, np.concatenate([p.b for p in parts]), sources.pop() if sources else None)

    _node_combine2 = _node_combine3 = _node_combine4 = _combine

    def _node_rotate2d(self, node, out, n):
        x, amount = self.value(node, "in", 2), self.value(node, "amount", 1)
        if not amount.is_const:
            raise _Unsupported(node.label, "its amount is textured")
        a = math.radians(float(amount.b[0]))
        R = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])  # mx_rotate_vector2
        return _Lin(R @ x.A, R @ x.b, x.source)

    def _condition(self, node, name: str) -> float:
        v = self.value(node, name, 1)
        if not v.is_const:
            raise _Unsupported(node.label, f"its condition input '{name}' is textured")
        return float(v.b[0])

    def _node_switch(self, node, out, n):
        # in<floor(which) + 1>, the index clamped to the inputs there are (mx_switch).
        count = sum(1 for d in node.nodedef.getActiveInputs() if d.getName().startswith("in"))
        k = min(max(int(math.floor(self._condition(node, "which"))), 0), count - 1)
        return self.value(node, f"in{k + 1}", n)

    def _node_ifgreater(self, node, out, n):
        return self.value(node, "in1" if self._condition(node, "value1") > self._condition(node, "value2")
                          else "in2", n)

    def _node_ifgreatereq(self, node, out, n):
        return self.value(node, "in1" if self._condition(node, "value1") >= self._condition(node, "value2")
                          else "in2", n)

    def _node_ifequal(self, node, out, n):
        return self.value(node, "in1" if self._condition(node, "value1") == self._condition(node, "value2")
                          else "in2", n)

    def _node_texcoord(self, node, out, n):
        index = int(self.value(node, "index", 1).b[0])
        return _Lin(np.eye(2)[:n], np.zeros(n), _St("st" if index == 0 else f"st{index}"))

    def _node_geompropvalue(self, node, out, n):
        name = self.text(node, "geomprop")
        name = name[len("primvars:"):] if name.startswith("primvars:") else name
        if n == 2:  # texture coordinates
            return _Lin(np.eye(2), np.zeros(2), _St(name or "st"))
        default = self.value(node, "default", n)
        if not default.is_const:
            raise _Unsupported(node.label, "its default is not constant")
        if not name:  # reads no primvar: always its default
            return _Lin.const(default.b)
        return _Lin(np.eye(n), np.zeros(n), _Primvar(name, n, tuple(float(x) for x in default.b), node.label))

    def _node_normalmap(self, node, out, n):
        for frame in ("normal", "tangent", "bitangent"):
            if node.source(frame) is not None:
                raise _Unsupported(node.label, f"its '{frame}' input is connected (illum uses the surface's "
                                               "own shading frame)")
        x = self.value(node, "in", 3)
        if x.is_const and not np.any(x.b):  # mx_normalmap: a zero vector is the unbent normal
            x = _Lin.const((0.5, 0.5, 1.0))
        s = self.value(node, "scale")
        if not s.is_const:
            raise _Unsupported(node.label, "its scale is textured")
        sx, sy = (float(s.b[0]), float(s.b[0])) if s.n == 1 else (float(s.b[0]), float(s.b[1]))
        # Tangent-space normal = (2 in - 1) * (scale_x, scale_y, 1) (mx_normalmap_vector2).
        d = np.array([sx, sy, 1.0])
        folded = _sum(node.label, [(2.0 * d, x)], -d)
        folded.kind = "normal"
        return folded

    def _node_image(self, node, out, n):
        default = self.value(node, "default", n)
        if not default.is_const:
            raise _Unsupported(node.label, "its default is not constant")
        uv = self.value(node, "texcoord", 2)
        if not uv.is_const and not isinstance(uv.source, _St):
            raise _Unsupported(node.label, "its texcoord is not texture coordinates")
        asset = self._asset(node, "file")
        if asset is None:
            return _Lin.const(default.b)
        (path, data), space, tiles, tile_data = asset
        A = uv.A if not uv.is_const else np.zeros((2, 2))
        st_transform = () if (np.array_equal(A, np.eye(2)) and not np.any(uv.b)) else (
            float(A[0, 0]), float(A[0, 1]), float(A[1, 0]), float(A[1, 1]), float(uv.b[0]), float(uv.b[1]))
        wraps = []
        for axis in ("uaddressmode", "vaddressmode"):
            mode = self.text(node, axis) if node.nodedef.getActiveInput(axis) is not None else "periodic"
            if mode not in _ADDRESS:
                raise self.ctx.error(f"unknown address mode '{mode}' (allowed: {', '.join(_ADDRESS)})",
                                     node.label, f"inputs:{axis}")
            wraps.append(_ADDRESS[mode])
        default4 = np.r_[default.b, np.zeros(4 - n)] if n < 4 else default.b[:4]
        if n == 3:
            default4[3] = 1.0
        image = _Image(path, data, space, wraps[0], wraps[1], uv.source.primvar if not uv.is_const else "st",
                       st_transform, tuple(float(x) for x in default4), node.label, tiles, tile_data)
        return _Lin(np.eye(4)[:n], np.zeros(n), image)

    def _asset(self, node, name: str):
        """((path, bytes or None), colour space, UDIM tiles, their bytes) of a filename input
        (tiles () unless the path holds ``<UDIM>``), or None where it is unauthored or the
        missing-asset policy gives the image's default."""
        src = node.source(name)
        if src is not None and src[0] == "input":
            return self._asset(src[1], src[2])
        if src is not None and src[0] == "node":
            raise _Unsupported(src[1].label, f"it feeds the file input of {node.label}")
        found = node.asset(name)
        if found is None:
            return None
        prim, attr_name, value, space = found
        if not getattr(value, "path", value):
            return None
        consequence = f"{node.label} uses its default"
        tiles, tile_data = (), ()
        if "<UDIM>" in getattr(value, "path", value):
            udim = self.ctx.udim_tiles(prim, attr_name, getattr(value, "path", value), consequence)
            if udim is None:
                return None
            pattern, tiles, tile_data = udim
            asset = (pattern, None)
        else:
            asset = self.ctx.read_image_asset(prim, attr_name, value, consequence)
            if asset is None:
                return None
        key = str(space or "").lower()
        if key == "auto":
            mode = "auto"
        elif key in _SRGB:
            mode = "sRGB"
        elif key in _RAW:
            mode = "raw"
        else:
            self.ctx.warn(f"mtlx-colorspace-{space}", f"{node.label}: colour space '{space}' is not supported "
                                                      "(illum reads srgb_texture and linear Rec.709); read as linear")
            mode = "raw"
        return asset, mode, tiles, tile_data

    # ---- to the description ------------------------------------------------------------
    def material_input(self, lin: _Lin, k: int, node, name: str) -> MaterialInput:
        """A folded value as a k-component MaterialInput (a colour takes 3 components, a float
        input the first)."""
        lin = lin.width(k)
        value = self._finite(lin.b if lin.is_const else lin.A @ np.asarray(
            lin.source.default if isinstance(lin.source, _Image) else np.zeros(lin.A.shape[1])) + lin.b, node, name)
        value = tuple(float(x) for x in value)
        if lin.is_const:
            return MaterialInput(value[0] if k == 1 else value)
        if isinstance(lin.source, _Primvar):
            return self._primvar_input(lin, k, node, name)
        if not isinstance(lin.source, _Image):
            raise _Unsupported(node.label, f"texture coordinates feed its input '{name}'")
        cols = [np.flatnonzero(row) for row in lin.A]
        if any(c.size > 1 for c in cols):
            raise _Unsupported(lin.source.node, f"channels of its texture are mixed on the way to "
                                                f"{node.label}.inputs:{name}")
        chans = [int(c[0]) if c.size else -1 for c in cols]
        scale4, bias4, fb4 = np.array([1.0, 1.0, 1.0, 1.0]), np.zeros(4), np.array(lin.source.default, dtype=float)
        used = {c for c in chans if c >= 0}
        if len(used) == 1 and all(c >= 0 for c in chans) and all(
                lin.A[i, chans[i]] == lin.A[0, chans[0]] and lin.b[i] == lin.b[0] for i in range(k)):
            c = chans[0]
            output = "rgba"[c]
            scale4[c], bias4[c], fb4[c] = lin.A[0, c], lin.b[0], value[0]
        elif k == 3 and all(c in (i, -1) for i, c in enumerate(chans)):
            output = "rgb"
            for i in range(3):
                scale4[i], bias4[i], fb4[i] = lin.A[i, i], lin.b[i], value[i]
        else:
            raise _Unsupported(lin.source.node, f"its channels are rearranged on the way to {node.label}.inputs:{name}")
        img = lin.source
        self.st_names.append(img.st_primvar)
        tex = TextureDesc(file=img.file, source_color_space=img.space, wrap_s=img.wrap_s, wrap_t=img.wrap_t,
                          scale=tuple(float(x) for x in scale4), bias=tuple(float(x) for x in bias4),
                          fallback=tuple(float(x) for x in fb4), output=output, st_primvar=img.st_primvar,
                          st_transform=img.st_transform, data=img.data, udim_tiles=img.udim_tiles,
                          udim_data=img.udim_data)
        return MaterialInput(value[0] if k == 1 else value, tex)

    def _primvar_input(self, lin: _Lin, k: int, node, name: str) -> MaterialInput:
        """A primvar read per hit (PrimvarReaderDesc): no arithmetic may follow it, and its
        components reach the input as renderer/materials.py maps them (the first k, or one
        broadcast)."""
        pv = lin.source
        wanted = np.eye(pv.width)[[0] * k] if pv.width == 1 else np.eye(pv.width)[:k]
        if np.any(lin.b) or lin.A.shape != wanted.shape or not np.array_equal(lin.A, wanted) or (
                pv.width == 2 and k == 3):
            raise _Unsupported(pv.node, f"arithmetic follows its primvar '{pv.name}' on the way to "
                                        f"{node.label}.inputs:{name}, and illum reads primvars per hit as they are")
        value = tuple(pv.fallback[:1] * 3 if pv.width == 1 else pv.fallback[:k]) if k == 3 else pv.fallback[0]
        return MaterialInput(value, primvar=PrimvarReaderDesc(pv.name, pv.width, pv.fallback))

    def _finite(self, v, node, name) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64)
        if not np.all(np.isfinite(v)):
            raise self.ctx.error(f"the network gives the non-finite value {tuple(v.tolist())}", node.label,
                                 f"inputs:{name}")
        return v

    def unsupported(self, e: _Unsupported, surface, name: str) -> None:
        """One warning per (node, material), naming the first surface input it feeds."""
        key = f"mtlx-node-{self.material}-{e.node}"
        if key not in self._warned:
            self._warned.add(key)
            self.ctx.warn(key, f"{self.material}: MaterialX node {e.node} is not supported"
                               f"{' (' + e.why + ')' if e.why else ''}; {surface.label}.inputs:{name} (and any "
                               "other input it feeds) uses its default")


# --------------------------------------------------------------------------------------
# Surface shaders -> MaterialDesc fields
# --------------------------------------------------------------------------------------
class _Surface:
    """Maps one surface shader node onto MaterialDesc fields (docs/materials.md)."""

    def __init__(self, net: _Network, node):
        self.net = net
        self.node = node
        self.lost: list[str] = []

    def lin(self, name: str, n: int | None = None, default=None) -> _Lin:
        try:
            v = self.net.value(self.node, name, n)
            if v.kind == "normal" and name not in ("normal", "geometry_normal"):
                raise _Unsupported(self.node.label, f"a normalmap feeds '{name}'")
            return v
        except _Unsupported as e:
            self.net.unsupported(e, self.node, name)
            d = self.node.nodedef.getActiveInput(name)
            if default is not None:
                fallback = default
            elif d is not None and d.getValue() is not None:
                fallback = _as_array(d.getValue())
            else:
                fallback = np.zeros(n or 1)
            return _Lin.const(fallback).width(n or len(np.atleast_1d(fallback)))

    def const(self, name: str, n: int = 1) -> np.ndarray:
        v = self.lin(name, n)
        if not v.is_const:
            self.net.unsupported(_Unsupported(self.node.label, f"illum reads '{name}' as a constant"), self.node, name)
            return self.lin_default(name, n)
        return v.b

    def lin_default(self, name, n) -> np.ndarray:
        """Input ``name``'s default from the node definition, as n components."""
        d = self.node.nodedef.getActiveInput(name)
        return _Lin.const(_as_array(d.getValue())).width(n).b

    def product(self, *names: str, n: int = 3) -> _Lin:
        """The product of inputs (e.g. base * base_color); one of them may be textured."""
        out = self.lin(names[0], n)
        for name in names[1:]:
            try:
                out = _scaled(self.node.label, out, self.lin(name, n))
            except _Unsupported as e:
                self.net.unsupported(e, self.node, name)
        return out

    def input(self, lin: _Lin, k: int, name: str, default=None) -> MaterialInput:
        """``lin`` as surface input ``name``'s MaterialInput; where it cannot be one, a warning
        and ``default`` (the definition's default if None)."""
        try:
            return self.net.material_input(lin, k, self.node, name)
        except _Unsupported as e:
            self.net.unsupported(e, self.node, name)
            if default is None:
                v = self.lin_default(name, k)
                default = float(v[0]) if k == 1 else tuple(float(x) for x in v)
            return MaterialInput(default)

    def direct(self, name: str, k: int) -> MaterialInput:
        """Surface input ``name`` mapped one to one (k components)."""
        return self.input(self.lin(name, k), k, name)

    def normal(self, name: str) -> MaterialInput:
        """A surface's normal input: unconnected -> the interpolated normal; a normalmap node ->
        its tangent-space vector."""
        flat = (0.0, 0.0, 1.0)
        if self.node.source(name) is None:
            return MaterialInput(flat)
        v = self.lin(name, 3, default=flat)
        if v.kind != "normal" and not (v.is_const and np.allclose(v.b, flat)):
            self.net.unsupported(_Unsupported(self.node.label, f"'{name}' is not fed by a normalmap node"),
                                 self.node, name)
            return MaterialInput(flat)
        return self.input(v, 3, name, flat)

    def authored(self, name: str) -> bool:
        """Whether input ``name`` is connected or differs from its definition's default."""
        src = self.node.source(name)
        if src is None:
            return False
        if src[0] != "value":
            return True
        d = self.node.nodedef.getActiveInput(name)
        return d is None or d.getValue() is None or not np.allclose(_as_array(src[1]), _as_array(d.getValue()))

    def warn_lost(self, names) -> None:
        lost = [name for name in names if self.authored(name)]
        if lost:
            self.net.ctx.warn(f"mtlx-lost-{self.net.material}",
                              f"{self.net.material}: {self.node.node_id} inputs {', '.join(lost)} have no "
                              "counterpart in illum's UsdPreviewSurface BSDF and are ignored (docs/materials.md)")

    # ---- the three surfaces --------------------------------------------------------------
    def preview(self) -> dict:
        """ND_UsdPreviewSurface_surfaceshader: the same inputs as UsdPreviewSurface, exactly."""
        f = {
            "diffuse_color": self.direct("diffuseColor", 3),
            "emissive_color": self.direct("emissiveColor", 3),
            "specular_color": self.direct("specularColor", 3),
            "metallic": self.direct("metallic", 1),
            "roughness": self.direct("roughness", 1),
            "opacity": self.direct("opacity", 1),
            "normal": self.direct("normal", 3),
            "use_specular_workflow": bool(int(self.const("useSpecularWorkflow")[0])),
            "ior": float(self.const("ior")[0]),
            "opacity_threshold": float(self.const("opacityThreshold")[0]),
            "opacity_mode": "presence" if int(self.const("opacityMode")[0]) == 1 else "transparent",
        }
        self.warn_lost(("clearcoat", "clearcoatRoughness", "displacement", "occlusion"))
        return f

    def _layered(self, base, color, metal, spec_w, spec_c, rough, ior, coat_w, coat_c, emission, emission_c,
                 opacity, normal, lost) -> dict:
        """standard_surface, open_pbr_surface and gltf_pbr (the same core under different input
        names; ``base`` and ``coat_c`` '' where a model has no such input)."""
        ior_v = float(self.const(ior)[0])
        diffuse = self.product(base, color) if base else self.lin(color, 3)
        # The coat tints everything under it: base * lerp(1, coat_color, coat).
        coat = self.lin(coat_w, 1)
        if coat_c and not (coat.is_const and coat.b[0] == 0.0):
            tint = self.lin(coat_c, 3)
            if coat.is_const and tint.is_const:
                diffuse = _sum(self.node.label, [(1.0 + coat.b[0] * (tint.b - 1.0), diffuse)])
            else:
                self.net.unsupported(_Unsupported(self.node.label, "a textured coat tint"), self.node, coat_w)
        f = {"diffuse_color": self.input(diffuse, 3, color),
             "metallic": self.direct(metal, 1),
             "roughness": self.direct(rough, 1),
             "ior": ior_v,
             "emissive_color": self.input(self.product(emission, emission_c), 3, emission, (0.0,) * 3),
             "normal": self.normal(normal)}
        op = self.lin(opacity, None)
        f["opacity"] = self.input(_sum(self.node.label, [(1.0 / op.n, op.rows([i]))
                                                         for i in range(op.n)]) if op.n > 1 and op.is_const
                                  else op.rows([0]), 1, opacity)
        # Specular weight and colour: a dielectric's F0 = weight * colour * F0(ior), through the
        # specular workflow (F90 = 1); on metals (or when textured) they are lost.
        w, c = self.lin(spec_w, 1), self.lin(spec_c, 3)
        if w.is_const and c.is_const and (w.b[0] != 1.0 or np.any(c.b != 1.0)):
            m = self.lin(metal, 1)
            if m.is_const and m.b[0] == 0.0:
                f["use_specular_workflow"] = True
                from renderer.bsdfs.preview_surface import dielectric_f0  # numba-free, but heavy to import

                f0 = w.b[0] * c.b * float(dielectric_f0(ior_v))
                f["specular_color"] = MaterialInput(tuple(float(x) for x in f0))
            else:
                lost = (*lost, spec_w, spec_c)
        elif not (w.is_const and c.is_const):
            lost = (*lost, spec_w, spec_c)
        self.warn_lost((*lost, coat_w) if not (coat.is_const and coat.b[0] == 0.0) else lost)
        return f

    def standard_surface(self) -> dict:
        return self._layered("base", "base_color", "metalness", "specular", "specular_color", "specular_roughness",
                             "specular_IOR", "coat", "coat_color", "emission", "emission_color", "opacity", "normal",
                             ("diffuse_roughness", "specular_anisotropy", "transmission", "subsurface", "sheen",
                              "thin_film_thickness", "coat_affect_color", "coat_affect_roughness", "coat_normal"))

    def gltf_pbr(self) -> dict:
        """glTF 2.0 PBR (ND_gltf_pbr_surfaceshader): metallic-roughness is UsdPreviewSurface's
        metallic workflow; alpha_mode 0 (opaque) / 1 (mask at alpha_cutoff) / 2 (blend)."""
        f = self._layered("", "base_color", "metallic", "specular", "specular_color", "roughness", "ior",
                          "clearcoat", "", "emissive_strength", "emissive", "alpha", "normal",
                          ("occlusion", "transmission", "iridescence", "sheen_color", "thickness",
                           "anisotropy_strength", "dispersion", "clearcoat_normal"))
        mode = int(self.const("alpha_mode")[0])
        if mode == 0:
            f["opacity"] = MaterialInput(1.0)
        elif mode == 1:
            f["opacity_threshold"] = float(self.const("alpha_cutoff")[0])
        return f

    def open_pbr_surface(self) -> dict:
        return self._layered("base_weight", "base_color", "base_metalness", "specular_weight", "specular_color",
                             "specular_roughness", "specular_ior", "coat_weight", "coat_color", "emission_luminance",
                             "emission_color", "geometry_opacity", "geometry_normal",
                             ("base_diffuse_roughness", "specular_roughness_anisotropy", "transmission_weight",
                              "subsurface_weight", "fuzz_weight", "thin_film_weight", "geometry_thin_walled",
                              "geometry_coat_normal"))


def _describe(ctx: ReadContext, material_path: str, node, source_note: str) -> tuple[MaterialDesc | None, str | None]:
    """The MaterialDesc of surface shader ``node`` (any adapter), or None (after a warning) for
    a surface illum does not map."""
    nd = node.nodedef
    cat = nd.getNodeString() if nd is not None else ""
    if cat not in _SURFACES:
        ctx.warn(f"mtlx-surface-{node.node_id}",
                 f"{node.label}: MaterialX surface '{node.node_id}' of {material_path} is not supported "
                 "(illum maps ND_UsdPreviewSurface_surfaceshader, ND_standard_surface_surfaceshader, "
                 "ND_open_pbr_surface_surfaceshader and ND_gltf_pbr_surfaceshader); using the material's "
                 "UsdPreviewSurface if it has one, else displayColor/grey")
        return None, None
    net = _Network(ctx, material_path)
    surface = _Surface(net, node)
    fields = getattr(surface, "preview" if cat == "UsdPreviewSurface" else cat)()
    desc = MaterialDesc(path=material_path, source=f"mtlx:{nd.getName()}{source_note}", **fields)
    return desc, (net.st_names[0] if net.st_names else None)


def read_usd_network(ctx: ReadContext, material: UsdShade.Material, shader: UsdShade.Shader):
    """(MaterialDesc or None, st primvar or None) of an inline MaterialX network whose surface
    is ``shader``."""
    return _describe(ctx, str(material.GetPath()), _UsdNode(shader, ctx.time), "")


# --------------------------------------------------------------------------------------
# .mtlx documents referenced from USD
# --------------------------------------------------------------------------------------
def mtlx_reference(prim: Usd.Prim) -> tuple[str, str, str] | None:
    """(authored asset, resolved .mtlx path or '', target prim path) of a reference to a .mtlx
    document authored on ``prim`` (the arc usd-core cannot compose), or None."""
    for spec in prim.GetPrimStack():
        proxy = spec.referenceList
        for kind in ("explicitItems", "prependedItems", "appendedItems", "addedItems", "orderedItems"):
            for ref in getattr(proxy, kind):
                asset = ref.assetPath
                if asset.lower().endswith(".mtlx"):
                    # Through Ar, so a document inside a .usdz package resolves too.
                    resolved = str(Ar.GetResolver().Resolve(spec.layer.ComputeAbsolutePath(asset)))
                    return asset, resolved, str(ref.primPath or "")
    return None


def _join(doc: str, value: str) -> str:
    """File ``value`` named in document ``doc`` (a path, or package-relative
    ``pkg.usdz[dir/look.mtlx]``): relative to the document's directory."""
    if os.path.isabs(value):
        return value
    if Ar.IsPackageRelativePath(doc):
        outer, inner = Ar.SplitPackageRelativePathOuter(doc)
        return Ar.JoinPackageRelativePath(outer, os.path.normpath(os.path.join(os.path.dirname(inner), value)))
    return os.path.normpath(os.path.join(os.path.dirname(doc), value))


def _modified(path: str) -> float:
    """mtime of the file behind ``path`` (a package's, for a path inside one)."""
    return os.path.getmtime(Ar.SplitPackageRelativePathOuter(path)[0] if Ar.IsPackageRelativePath(path) else path)


def document_files(path: str) -> list[tuple[str, str, str]]:
    """(element path, authored value, absolute path) of every document the .mtlx document at
    ``path`` XIncludes and every filename input in it, resolved as the reader resolves them (the
    document's fileprefix, then its directory): what reading it can open
    (renderer/usd/confine.py)."""
    doc = _read_document(path, _modified(path))
    # XIncluded documents (read with it), then the files its filename inputs name.
    out = [("xi:include", uri, _join(path, uri)) for uri in sorted(doc.getReferencedSourceUris())
           if uri and uri != doc.getSourceUri()]
    for element in doc.traverseTree():
        if element.getCategory() == "input" and element.getType() == "filename" and element.getValueString():
            value = element.getResolvedValueString()
            out.append((element.getNamePath(), value, _join(path, value)))
    return out


@lru_cache(maxsize=32)
def _read_document(path: str, mtime: float):
    import MaterialX as mx

    doc = mx.createDocument()
    doc.setDataLibrary(_library())
    if Ar.IsPackageRelativePath(path):  # inside a .usdz: its bytes through Ar
        asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path))
        if asset is None:
            raise OSError(f"cannot open '{path}'")
        mx.readFromXmlString(doc, bytes(asset.GetBuffer()).decode("utf-8"))
    else:
        mx.readFromXmlFile(doc, path)
    return doc


def read_mtlx_material(ctx: ReadContext, prim: Usd.Prim, material_path: str, inner: str):
    """(MaterialDesc or None, st name or None) of the material at usdMtlx path ``inner``
    (``/MaterialX/Materials/<name>``, or just a material name) of the .mtlx document that
    ``prim`` references; None (after a warning) when it has no such material. A missing
    document is reported by renderer/usd/composition.py (an error under --strict)."""
    ref = mtlx_reference(prim)
    if ref is None:
        return None, None
    authored, resolved, _target = ref
    attr = "references"
    if not resolved:  # a missing document is a composition error (renderer/usd/composition.py)
        return None, None
    try:
        doc = _read_document(resolved, _modified(resolved))
    except Exception as e:  # noqa: BLE001 -- MaterialX's parse and file errors have no common base
        raise ctx.error(f"cannot read MaterialX document '{resolved}': {e}", prim, attr) from None
    name = inner.rstrip("/").split("/")[-1]
    node = doc.getNode(name)
    if node is None or node.getType() != "material":
        found = [m.getName() for m in doc.getMaterialNodes()]
        ctx.warn(f"mtlx-no-material-{resolved}-{name}",
                 f"{prim.GetPath()}: MaterialX document '{resolved}' has no material '{name}' "
                 f"(it has: {', '.join(found) or 'none'}); using displayColor/grey")
        return None, None
    surface_input = node.getInput("surfaceshader")
    shader = surface_input.getConnectedNode() if surface_input is not None else None
    if shader is None:
        ctx.warn(f"mtlx-no-surface-{resolved}-{name}",
                 f"{material_path}: MaterialX material '{name}' in '{resolved}' has no surface shader; "
                 "using displayColor/grey")
        return None, None
    return _describe(ctx, material_path, _DocNode(shader, prim, resolved),
                     f" ({os.path.basename(resolved.rstrip(']'))})")
