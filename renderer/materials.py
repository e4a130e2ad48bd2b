"""The material table: UsdPreviewSurface inputs packed as structure-of-arrays, evaluated per hit.

``MaterialTable.build(materials, textures)`` packs the constant inputs of every material into
arrays indexed by material id and records which inputs are textured.
``evaluate(mat, st)`` returns ``SurfaceParams`` for a batch of hits, each hit's inputs by the
compiled ``columns_row`` on one record of every material (``surface_record``: constants, each
input's texture or primvar binding, the textures packed by TextureCache.pack, UDIM tiles
included). The fast path's vertex kernel calls the same rows at every hit (``surface_hits``:
the packed BSDF row, the emission and the bent shading normal), and the cut-out walks read
presence through them (``presence_hit``): one evaluation for every route.

Opacity (UsdPreviewSurface spec) -> ``presence(params)``, the probability that the surface is
there at a hit (the integrator continues the ray through the surface with probability
1 - presence, which is unbiased for fractional opacity; shadow rays do the same through
``presence_at``, so a cut-out casts the shadow of what is present):

* opacityThreshold > 0: a cutout mask. presence = 1 where opacity >= threshold, else 0 (the spec:
  "opacity values less than the opacityThreshold will not be rendered, and values greater than
  or equal to it will be fully visible").
* opacityThreshold == 0: presence = clamp(opacity, 0, 1), stochastically. For
  opacityMode = 'presence' this is the spec's meaning ("the entire lighting response, including
  specular, is scaled by opacity"). For the default 'transparent' mode the spec means glass-like
  transparency that keeps a specular response at opacity 0; illum has no refraction or
  transmission lobe, so transparency is rendered as presence too (a fully transparent surface
  is invisible, reflections included). This is a documented deviation.
  (Note: the brief this module was written to suggested treating opacityMode = 'presence' as a
  cutout even with threshold 0; with threshold 0 that cutout would make every surface fully
  present, contradicting the spec, so only the threshold selects cutout behaviour.)

hdStorm additionally multiplies diffuseColor by opacity ("premultiplied" blending); a ray
tracer with stochastic presence must not, so we do not.

Normal maps (UsdPreviewSurface ``normal``, tangent space): ``SurfaceParams.normal`` carries the
tangent-space vector (x along +u, y along +v, z along the shading normal) exactly as the texture
reader delivers it, so a map's own scale (2, 2, 2, 1) / bias (-1, -1, -1, 0) produce the [-1, 1]
vector and illum adds no 2x - 1 of its own (the spec: "your texture reader implementation should
provide data to this node that is properly scaled"). ``normal_mapped`` marks the materials whose
normal is textured or a constant other than (0, 0, 1); the integrator bends their shading normals
(renderer/geometry.py ``perturb_normals``).

Textured inputs: a colour input fed by a single-channel output ('r', 'g', 'b', 'a') broadcasts it
to RGB; a float input fed by 'rgb' takes the red channel. Without texture coordinates (st None)
textures are looked up at st = (0, 0), the UsdPrimvarReader_float2 fallback.

Several st sets: where the scene's textures read more than one st primvar (UsdUVTexture.st from
UsdPrimvarReader_float2 nodes with different varnames), each of those primvars also gets columns
in the per-hit coordinates, and each texture reads its own (columns_row, MI's B_ST).

Primvar inputs (a UsdPrimvarReader_* connected to an input, ``MaterialInput.primvar``): the
primvars materials read are laid out after st in the per-hit coordinates (``primvar_layout``:
``evaluate``'s ``st`` is (n, 2 + K), columns 2.. the interpolated primvars, as the geometry's
per-corner table, renderer/scene.py). A hit whose gprim lacks the primvar carries NaN there and
gets the reader's fallback. Components map to the input as for textures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Optional

import numpy as np
from numba import njit

from renderer.bsdfs._preview_kernels import K as P_COLUMNS
from renderer.bsdfs._preview_kernels import init_row, inputs_row
from renderer.bsdfs.microfacet import albedo_tables
from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.description import MaterialDesc, MaterialInput, TextureDesc, primvar_layout
from renderer.errors import StageError
from renderer.geometry import _interaction_row, perturb_row, st_row
from renderer.textures import TextureCache, output_channels, texture_row

# (attribute on MaterialDesc, SurfaceParams field, components, USD input name)
_TEXTURABLE = (
    ("diffuse_color", "diffuse", 3, "inputs:diffuseColor"),
    ("specular_color", "specular_color", 3, "inputs:specularColor"),
    ("metallic", "metallic", 1, "inputs:metallic"),
    ("roughness", "roughness", 1, "inputs:roughness"),
    ("opacity", "opacity", 1, "inputs:opacity"),
    ("emissive_color", "emission", 3, "inputs:emissiveColor"),
    ("normal", "normal", 3, "inputs:normal"),
)

_FLAT = (0.0, 0.0, 1.0)  # the tangent-space normal that leaves the shading normal as it is

# The columns of one hit's inputs in the compiled surface rows (input_row, params_row): every
# SurfaceParams field, use_specular_workflow as 0.0 / 1.0.
C_DIFFUSE = 0
C_SPECULAR = 3
C_WORKFLOW = 6
C_METALLIC = 7
C_ROUGHNESS = 8
C_IOR = 9
C_OPACITY = 10
C_EMISSION = 11
C_THRESHOLD = 14
C_NORMAL = 15
N_COLUMNS = 18
_COLUMN = {"diffuse": C_DIFFUSE, "specular_color": C_SPECULAR, "use_specular_workflow": C_WORKFLOW,
           "metallic": C_METALLIC, "roughness": C_ROUGHNESS, "ior": C_IOR, "opacity": C_OPACITY,
           "emission": C_EMISSION, "opacity_threshold": C_THRESHOLD, "normal": C_NORMAL}


def texture_inputs(mat: MaterialDesc) -> list[tuple[str, TextureDesc]]:
    """(UsdPreviewSurface input name, TextureDesc) of every textured input of ``mat``."""
    return [(usd_name, getattr(mat, attr).texture) for attr, _f, _k, usd_name in _TEXTURABLE
            if getattr(mat, attr).texture is not None]


def normal_mapped(desc: MaterialDesc) -> bool:
    """Whether a material bends shading normals: a textured ``normal`` or a constant other than
    (0, 0, 1)."""
    inp = desc.normal
    return inp.texture is not None or tuple(np.ravel(np.asarray(inp.value, dtype=np.float64)).tolist()) != _FLAT


@dataclass(frozen=True)
class SurfaceParams:
    """UsdPreviewSurface inputs evaluated at n hits (textures applied, values not clamped).

    diffuse, specular_color, emission: (n, 3) linear RGB (emission is radiance).
    use_specular_workflow: (n,) bool. metallic, roughness, ior, opacity: (n,) float64.
    opacity_threshold: (n,) float64 (> 0 selects cutout presence, see ``presence``).
    normal: (n, 3) tangent-space normal (module docstring), or None when no material of the
    table is normal-mapped.
    """

    diffuse: np.ndarray
    specular_color: np.ndarray
    use_specular_workflow: np.ndarray
    metallic: np.ndarray
    roughness: np.ndarray
    ior: np.ndarray
    opacity: np.ndarray
    emission: np.ndarray
    opacity_threshold: np.ndarray
    normal: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return self.metallic.shape[0]

    def take(self, rows: np.ndarray) -> "SurfaceParams":
        """The parameters of a subset of the hits."""
        vals = {f.name: getattr(self, f.name) for f in fields(self)}
        return SurfaceParams(**{k: (v if v is None else v[rows]) for k, v in vals.items()})


def presence(params: SurfaceParams) -> np.ndarray:
    """(n,) probability in [0, 1] that the surface is present at each hit (module docstring)."""
    return _presence(params.opacity, params.opacity_threshold)


@njit(cache=True, nogil=True)
def presence_row(opacity: float, threshold: float) -> float:
    """Cutout where threshold > 0 (opacity >= threshold -> 1, else 0), else clamp(opacity, 0, 1).
    A NaN opacity (e.g. from a texture's bias) counts as present."""
    if opacity != opacity:
        return 1.0
    if threshold > 0.0:
        return 1.0 if opacity >= threshold else 0.0
    return min(max(opacity, 0.0), 1.0)


@njit(cache=True, nogil=True)
def _presence_kernel(opacity, threshold, out):
    for i in range(out.shape[0]):
        out[i] = presence_row(opacity[i], threshold[i])


def _presence(opacity: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """presence_row over (n,) opacities and thresholds: (n,) float64."""
    op, thr = np.broadcast_arrays(np.asarray(opacity, dtype=np.float64), np.asarray(threshold, dtype=np.float64))
    out = np.empty(op.shape)
    _presence_kernel(np.ascontiguousarray(op).reshape(-1), np.ascontiguousarray(thr).reshape(-1), out.reshape(-1))
    return out


# The per-(material, input column) bindings of MaterialTable.surface_record (MI's last axis).
B_SLOT, B_CHANNEL, B_PRIMVAR, B_ST = 0, 1, 2, 3


@njit(cache=True, nogil=True, _nrt=False)
def columns_row(C, MI, px, IMI, TXI, TXF, tiles, m, stv, c0, c1, vals):
    """Input columns c0..c1 (C_*) of material m at one hit whose per-hit coordinates are stv
    (MaterialTable.evaluate's st row: st, then the primvars materials read; empty: none), on the
    record of MaterialTable.surface_record unpacked (C, MI and TextureCache.pack's arrays): a
    primvar reader's value (its fallback, the constant, where the hit has none or NaN), a
    texture's channel (textures.texture_row at the texture's own st set where the hit has it,
    else st; (0, 0) without coordinates), or the constant. Into vals[c0:c1] where vals is not
    empty; returns column c1 - 1. The one evaluation of UsdPreviewSurface inputs (evaluate,
    presence_at, the cut-out walks and the compiled per-hit rows all come here).

    The per-hit rows (this one, texture_row, params_row, input_row, presence_hit, and the
    geometry and BSDF rows surface_hits calls) are compiled without numba's reference counting
    (_nrt=False: they allocate nothing): counting the arrays of each call cost ~10 ns an array,
    13 us a hit in all, 50x the evaluation itself."""
    n = stv.shape[0]
    v = 0.0
    for col in range(c0, c1):
        v = C[m, col]
        p = MI[m, col, B_PRIMVAR]
        j = MI[m, col, B_SLOT]
        if p >= 0:
            if p < n and stv[p] == stv[p]:
                v = stv[p]
        elif j >= 0:
            s = stv[0] if n >= 2 else 0.0
            t = stv[1] if n >= 2 else 0.0
            q = MI[m, col, B_ST]
            if q >= 0 and n >= q + 2 and math.isfinite(stv[q]) and math.isfinite(stv[q + 1]):
                s = stv[q]
                t = stv[q + 1]
            v = texture_row(px, IMI, TXI, TXF, tiles, j, s, t, MI[m, col, B_CHANNEL])
        if vals.shape[0] > 0:
            vals[col] = v
    return v


@njit(cache=True, nogil=True, _nrt=False)
def input_row(R, m, col, stv):
    """Input column col of material m at one hit (columns_row) from the record R."""
    C, MI, _, TX, _, _ = R
    px, IMI, TXI, TXF, tiles = TX
    return columns_row(C, MI, px, IMI, TXI, TXF, tiles, m, stv, col, col + 1, stv[:0])


@njit(cache=True, nogil=True, _nrt=False)
def params_row(C, MI, px, IMI, TXI, TXF, tiles, m, stv, vals):
    """Every input column of material m at one hit into vals (N_COLUMNS,) (columns_row)."""
    columns_row(C, MI, px, IMI, TXI, TXF, tiles, m, stv, 0, N_COLUMNS, vals)


@njit(cache=True, nogil=True)
def _params_kernel(R, mat, st, out):
    C, MI, _, TX, _, _ = R
    px, IMI, TXI, TXF, tiles = TX
    for i in range(mat.shape[0]):
        params_row(C, MI, px, IMI, TXI, TXF, tiles, mat[i], st[i], out[i])


@njit(cache=True, nogil=True, _nrt=False)
def presence_hit(R, m, stv):
    """presence_at for one hit of material m with per-hit coordinates stv (input_row)."""
    return presence_row(input_row(R, m, C_OPACITY, stv), R[0][m, C_THRESHOLD])


@njit(cache=True, nogil=True)
def _presence_at_kernel(R, mat, st, out):
    for i in range(mat.shape[0]):
        out[i] = presence_hit(R, mat[i], st[i])


@njit(cache=True, nogil=True)
def surface_hits(H, vertices, face_normal, normals, tri_mat, prim, b1, b2, S, D):
    """The per-hit surface record of the fast path's vertex kernel (its ``surf``): (P (h, K)
    packed rows of the h hits among prim (n,) (-1: missed), row (n,) int64 each ray's row in P or
    -1, emission (h, 3) or (0, 3) where no material emits, bent_ns (h, 3) or (0, 3) where no
    material is normal-mapped) at barycentrics b1, b2 (n,) along the unit directions
    S[:, D:D + 3]. H: MaterialTable.hit_record. Each hit: its per-hit coordinates (st_row), its
    inputs (params_row), the packed row (the BSDF's inputs_row and init_row: make_bsdf's), the
    emission, and the shading normal bent where its material is normal-mapped (perturb_row: the
    general path's PathIntegrator.bent_normals)."""
    R, st_tab, tangent, handed, ta_avg, tb_avg = H
    C, MI, mapped, TX, has_emission, has_normal_map = R
    px, IMI, TXI, TXF, tiles = TX
    n = prim.shape[0]
    row = np.empty(n, dtype=np.int64)
    h = 0
    for r in range(n):
        row[r] = h if prim[r] >= 0 else -1
        h += 1 if prim[r] >= 0 else 0
    P = np.empty((h, P_COLUMNS))
    emission = np.empty((h if has_emission else 0, 3))
    bent_ns = np.empty((h if has_normal_map else 0, 3))
    stv = np.empty(st_tab.shape[2])
    vals = np.empty(N_COLUMNS)
    bend = tangent.shape[0] > 0
    for r in range(n):
        q = row[r]
        if q < 0:
            continue
        k = prim[r]
        w1 = float(b1[r])
        w2 = float(b2[r])
        m = tri_mat[k]
        st_row(st_tab, k, w1, w2, stv)
        params_row(C, MI, px, IMI, TXI, TXF, tiles, m, stv, vals)
        inputs_row(P, q, vals[C_DIFFUSE], vals[C_DIFFUSE + 1], vals[C_DIFFUSE + 2], vals[C_SPECULAR],
                   vals[C_SPECULAR + 1], vals[C_SPECULAR + 2], vals[C_WORKFLOW] != 0.0, vals[C_METALLIC],
                   vals[C_ROUGHNESS], vals[C_IOR])
        init_row(P, q, ta_avg, tb_avg)
        if has_emission:
            for c in range(3):
                emission[q, c] = vals[C_EMISSION + c]
        if has_normal_map:
            dx, dy, dz = S[r, D], S[r, D + 1], S[r, D + 2]
            _, gg, ss = _interaction_row(vertices, face_normal, normals, k, w1, w2, dx, dy, dz)
            nx, ny, nz = ss
            if bend and mapped[m]:
                nx, ny, nz = perturb_row(nx, ny, nz, gg[0], gg[1], gg[2], -dx, -dy, -dz, vals[C_NORMAL],
                                         vals[C_NORMAL + 1], vals[C_NORMAL + 2], k, tangent, handed, face_normal)
            bent_ns[q, 0] = nx
            bent_ns[q, 1] = ny
            bent_ns[q, 2] = nz
    return P, row, emission, bent_ns


# The SurfaceParams fields the BSDF reads (the others: emission, opacity, opacity_threshold).
BSDF_FIELDS = ("diffuse", "specular_color", "use_specular_workflow", "metallic", "roughness", "ior")


def make_bsdf(params: SurfaceParams) -> PreviewSurfaceBSDF:
    """The UsdPreviewSurface BSDF for these parameters (see renderer/bsdfs/preview_surface.py)."""
    return PreviewSurfaceBSDF.from_params(params)


def _as_components(value, k: int, where: str, path: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).ravel()
    if v.size == 1 and k == 3:
        v = np.repeat(v, 3)
    elif v.size == 3 and k == 1:
        v = v[:1]
    if v.size != k:
        raise StageError(f"expected {k} component(s), got {v.size}", prim=path, attribute=where)
    if not np.all(np.isfinite(v)):
        raise StageError("value is not finite", prim=path, attribute=where)
    return v


def _components(k: int, n: int) -> list[int]:
    """Which of n source components feed a k-component input: broadcast 1 -> 3, else the first
    k (the reader refuses a float2 feeding a 3-component input)."""
    if k == 1:
        return [0]
    if n == 2:
        raise StageError("a 2-component primvar cannot feed a 3-component input")
    return [0, 0, 0] if n == 1 else [0, 1, 2]


def _texture_key(tex: TextureDesc) -> tuple:
    """A hashable identity for a TextureDesc (its sequences may arrive as lists)."""
    return (
        tex.file,
        tex.udim_tiles,
        tex.source_color_space,
        tex.wrap_s,
        tex.wrap_t,
        tuple(np.ravel(tex.scale).tolist()),
        tuple(np.ravel(tex.bias).tolist()),
        tuple(np.ravel(tex.fallback).tolist()),
        tex.output,
        tuple(tex.st_transform),
        tex.st_primvar,
    )


@dataclass(frozen=True)
class _Binding:
    """One textured input of one material: SurfaceParams field <- channels of texture slot."""

    material: int
    field: str
    channels: tuple


class MaterialTable:
    """Structure-of-arrays over m materials (use ``build``).

    Constant arrays (m, 3) / (m,) named like the SurfaceParams fields; ``textures`` the distinct
    TextureDescs in use; ``has_emission`` / ``has_cutout`` table-level flags;
    ``emissive_materials`` (m,) bool: the material may emit (constant emission > 0 or an emission
    texture); ``cutout_materials`` (m,) bool: the material may be absent at a hit (opacity below 1
    or textured), ``has_cutout`` any of them; ``normal_mapped`` (m,) bool: the material bends shading normals (module docstring),
    ``has_normal_map`` any of them; ``paths`` the material prim paths.
    """

    def __init__(self) -> None:  # use MaterialTable.build
        self.paths: list[str] = []
        self.const: dict[str, np.ndarray] = {}
        self.textures: list[TextureDesc] = []
        self.texture_cache: Optional[TextureCache] = None
        # Per texture slot: (material ids (k,) int64, bindings (list of _Binding)).
        self._by_texture: list[tuple[np.ndarray, list[_Binding]]] = []
        # Per SurfaceParams field: (m,) int64 texture slot or -1.
        self._slot: dict[str, np.ndarray] = {}
        # Primvar inputs: {(field, columns of the per-hit coordinates): (materials (k,), fallback
        # rows (k, components))} (module docstring).
        self._primvar: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.primvar_layout: dict[str, tuple[int, int]] = {}
        self._varies: dict[str, np.ndarray] = {}  # per field: (m,) bool, textured or primvar-fed
        self.has_emission = False
        self.has_cutout = False
        self.cutout_materials = np.zeros(0, dtype=bool)
        self.emissive_materials = np.zeros(0, dtype=bool)
        self.normal_mapped = np.zeros(0, dtype=bool)
        self.has_normal_map = False
        self._bsdf_rows: Optional[np.ndarray] = None  # (m, K) packed BSDF of each material
        self._record: Optional[tuple] = None  # surface_record, built on first use

    def __len__(self) -> int:
        return len(self.paths)

    # ----------------------------------------------------------------------------------
    # Build
    # ----------------------------------------------------------------------------------
    @staticmethod
    def build(materials: list[MaterialDesc], textures: TextureCache) -> "MaterialTable":
        """Pack ``materials`` (index = material id) and load their textures into ``textures``.

        Raises StageError for non-finite constants or a missing texture file.
        """
        table = MaterialTable()
        table.texture_cache = textures
        m = len(materials)
        table.paths = [mat.path for mat in materials]
        const = {
            "diffuse": np.zeros((m, 3)),
            "specular_color": np.zeros((m, 3)),
            "emission": np.zeros((m, 3)),
            "metallic": np.zeros(m),
            "roughness": np.zeros(m),
            "opacity": np.zeros(m),
            "use_specular_workflow": np.zeros(m, dtype=bool),
            "ior": np.zeros(m),
            "opacity_threshold": np.zeros(m),
            "normal": np.zeros((m, 3)),
        }
        slot_of: dict[tuple, int] = {}
        slots = {fname: np.full(m, -1, dtype=np.int64) for _, fname, _, _ in _TEXTURABLE}
        bindings: list[list[_Binding]] = []
        table.primvar_layout = layout = primvar_layout(materials)
        primvar_fed = {fname: np.zeros(m, dtype=bool) for _, fname, _, _ in _TEXTURABLE}
        by_columns: dict[tuple, tuple[list, list]] = {}
        for i, mat in enumerate(materials):
            for attr, fname, k, usd_name in _TEXTURABLE:
                inp: MaterialInput = getattr(mat, attr)
                v = _as_components(inp.value, k, usd_name, mat.path)
                const[fname][i] = v if k == 3 else v[0]
                if inp.primvar is not None:
                    first, _w = layout[inp.primvar.name]
                    cols = tuple(first + c for c in _components(k, int(inp.primvar.width)))
                    mats_f, fallbacks = by_columns.setdefault((fname, cols), ([], []))
                    mats_f.append(i)
                    fallbacks.append(v)
                    primvar_fed[fname][i] = True
                if inp.texture is not None:
                    tex = inp.texture
                    try:
                        textures.add(tex)
                    except StageError as e:
                        raise StageError(
                            e.message, file=e.file, prim=mat.path, attribute=usd_name
                        ) from None
                    key = _texture_key(tex)
                    if key not in slot_of:
                        slot_of[key] = len(table.textures)
                        table.textures.append(tex)
                        bindings.append([])
                    s = slot_of[key]
                    slots[fname][i] = s
                    chans = output_channels(tex.output)
                    if k == 1:
                        chans = chans[:1]
                    elif len(chans) == 1:
                        chans = chans * 3
                    else:
                        chans = chans[:3]
                    bindings[s].append(_Binding(i, fname, tuple(chans)))
            scalars = (("inputs:ior", mat.ior), ("inputs:opacityThreshold", mat.opacity_threshold))
            for name, val in scalars:
                if not np.isfinite(val):
                    raise StageError("value is not finite", prim=mat.path, attribute=name)
            const["use_specular_workflow"][i] = bool(mat.use_specular_workflow)
            const["ior"][i] = float(mat.ior)
            const["opacity_threshold"][i] = float(mat.opacity_threshold)
        for arr in const.values():
            arr.setflags(write=False)
        table.const = const
        table._slot = slots
        table._primvar = {key: (np.array(ms, dtype=np.int64), np.array(fb, dtype=np.float64))
                          for key, (ms, fb) in by_columns.items()}
        # A primvar-fed input varies per hit like a textured one.
        varies = {f: (slots[f] >= 0) | primvar_fed[f] for f in slots}
        table._varies = varies
        table._by_texture = [
            (np.unique(np.array([b.material for b in bs], dtype=np.int64)), bs) for bs in bindings
        ]
        emissive = np.any(const["emission"] > 0.0, axis=1) | varies["emission"]
        table.emissive_materials = emissive
        table.has_emission = bool(emissive.any())
        table.cutout_materials = (const["opacity"] < 1.0) | varies["opacity"]
        table.has_cutout = bool(table.cutout_materials.any())
        table.normal_mapped = np.any(const["normal"] != np.array(_FLAT), axis=1) | varies["normal"]
        table.has_normal_map = bool(table.normal_mapped.any())
        return table

    # ----------------------------------------------------------------------------------
    # Evaluate
    # ----------------------------------------------------------------------------------
    def evaluate(self, mat: np.ndarray, st: Optional[np.ndarray] = None) -> SurfaceParams:
        """SurfaceParams at n hits. mat: (n,) int material ids; st: (n, 2 + K) per-hit
        coordinates (st, then the primvars materials read: primvar_layout), or None: textures
        are looked up at (0, 0) and primvar readers give their fallbacks (input_row per hit)."""
        mat = np.ascontiguousarray(mat, dtype=np.int64)
        out = np.empty((mat.shape[0], N_COLUMNS))
        _params_kernel(self.surface_record(), mat, self._st_rows(st, mat.shape[0]), out)
        cols = {name: (out[:, c:c + 3] if self.const[name].ndim == 2 else out[:, c]) for name, c in _COLUMN.items()
                if name != "normal" or self.has_normal_map}  # the normal only where some material bends normals
        cols = {name: np.ascontiguousarray(v) for name, v in cols.items()}
        cols["use_specular_workflow"] = cols["use_specular_workflow"] != 0.0
        return SurfaceParams(**cols)

    @staticmethod
    def _st_rows(st: Optional[np.ndarray], n: int) -> np.ndarray:
        """The per-hit coordinates as the compiled rows read them: (n, C) float64, (n, 0) for none."""
        if st is None:
            return np.zeros((n, 0))
        return np.ascontiguousarray(np.reshape(st, (n, -1)), dtype=np.float64)

    def surface_record(self) -> tuple:
        """The inputs of every material as one record for the compiled rows (input_row; built
        once): (C (m, N_COLUMNS) the constants; MI (m, N_COLUMNS, 4) int64 per (material,
        column) its binding (B_*): the texture slot feeding it or -1, that texture's channel, the
        per-hit coordinate column of the primvar reader feeding it or -1, and the first column of
        the texture's own st set or -1 (st); normal_mapped (m,) bool; TextureCache.pack of the
        textures; has_emission, has_normal_map)."""
        if self._record is None:
            m = len(self)
            C = np.zeros((m, N_COLUMNS))
            for name, c in _COLUMN.items():
                v = np.asarray(self.const[name], dtype=np.float64)
                w = 3 if v.ndim == 2 else 1
                C[:, c:c + w] = v.reshape(m, w)
            MI = np.full((m, N_COLUMNS, 4), -1, dtype=np.int64)
            MI[:, :, B_CHANNEL] = 0
            own_st = [self.primvar_layout[t.st_primvar][0] if t.st_primvar in self.primvar_layout else -1
                      for t in self.textures]
            for s, (_, binds) in enumerate(self._by_texture):
                for b in binds:
                    for i, ch in enumerate(b.channels):
                        MI[b.material, _COLUMN[b.field] + i, [B_SLOT, B_CHANNEL, B_ST]] = (s, ch, own_st[s])
            for (fname, cols), (mats_f, _fallbacks) in self._primvar.items():
                for i, col in enumerate(cols):
                    MI[mats_f, _COLUMN[fname] + i, B_PRIMVAR] = col
            tx = (self.texture_cache.pack(self.textures) if self.texture_cache is not None
                  else TextureCache().pack([]))
            self._record = (C, MI, np.ascontiguousarray(self.normal_mapped, dtype=np.bool_), tx,
                            bool(self.has_emission), bool(self.has_normal_map))
        return self._record

    def hit_record(self, geometry) -> tuple:
        """surface_hits' record for the hits on ``geometry`` (GeometryTables): (surface_record,
        the per-corner coordinates st (T, 3, C), the normal maps' tangent (T, 3) and handed (T,)
        (empty where no triangle is normal-mapped), the albedo tables' averages a_avg, b_avg)."""
        f64 = np.float64
        tables = albedo_tables()
        tangent = np.zeros((0, 3)) if geometry.tangent is None else geometry.tangent
        handed = np.zeros(0) if geometry.handed is None else geometry.handed
        return (self.surface_record(), np.ascontiguousarray(geometry.st, dtype=f64),
                np.ascontiguousarray(tangent, dtype=f64), np.ascontiguousarray(handed, dtype=f64),
                np.ascontiguousarray(tables.a_avg, dtype=f64), np.ascontiguousarray(tables.b_avg, dtype=f64))

    @property
    def bsdf_is_constant(self) -> bool:
        """No BSDF input of any material is textured: the BSDF depends on the material alone."""
        return not any(np.any(self._varies[f]) for f in BSDF_FIELDS if f in self._varies)

    @property
    def emission_is_constant(self) -> bool:
        """No material's emission is textured or primvar-fed: const["emission"] (m, 3) is each
        material's radiance at every hit."""
        return not np.any(self._varies.get("emission", False))

    @property
    def params_needed(self) -> bool:
        """Whether a renderer needs ``evaluate`` at hits at all: for emission, cutouts, normal
        maps or a textured BSDF input (otherwise ``bsdf(mat)`` alone describes the surface)."""
        return self.has_emission or self.has_cutout or self.has_normal_map or not self.bsdf_is_constant

    def packed_bsdf(self):
        """(rows (materials, K), table_a, table_b): every material's packed PreviewSurfaceBSDF
        row and the albedo tables its kernels read, or None where a BSDF input is textured
        (for the compiled path vertex, renderer/integrators/fast_path.py)."""
        if not (self.bsdf_is_constant and len(self)):
            return None
        if self._bsdf_rows is None:
            self._bsdf_rows = make_bsdf(SurfaceParams(**self.const)).packed
        tables = albedo_tables()
        return np.ascontiguousarray(self._bsdf_rows), tables.a, tables.b

    def bsdf(self, mat: np.ndarray, params: Optional[SurfaceParams] = None) -> PreviewSurfaceBSDF:
        """The BSDF at hits of materials mat (n,). Where no BSDF input is textured, each hit
        gathers its material's packed row, built once (the same numbers ``make_bsdf`` gives,
        without the per-hit input mapping); otherwise it is built from ``params`` (evaluated at
        these hits)."""
        if self.bsdf_is_constant and len(self):
            if self._bsdf_rows is None:
                # Built on first use; two threads racing here build the same table.
                self._bsdf_rows = make_bsdf(SurfaceParams(**self.const)).packed
            return PreviewSurfaceBSDF.from_packed(np.take(self._bsdf_rows, np.asarray(mat, dtype=np.int64), axis=0))
        if params is None:
            raise ValueError("textured BSDF inputs need the SurfaceParams evaluated at the hits")
        return make_bsdf(params)

    def presence_at(self, mat: np.ndarray, st: Optional[np.ndarray] = None) -> np.ndarray:
        """(n,) presence probability at hits without evaluating the other inputs (for shadow
        rays and any-hit style tests; presence_hit per hit)."""
        mat = np.ascontiguousarray(mat, dtype=np.int64)
        out = np.empty(mat.shape[0])
        _presence_at_kernel(self.surface_record(), mat, self._st_rows(st, mat.shape[0]), out)
        return out

    @staticmethod
    def presence(params: SurfaceParams) -> np.ndarray:
        """Same as the module-level ``presence``."""
        return presence(params)


# The compiled rows inline textures.texture_row, geometry's rows and the BSDF's input mapping:
# their cache follows those files (renderer/kernels).
from renderer.kernels import guard_cache, module_dispatchers  # noqa: E402

guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/textures.py", "renderer/geometry.py", "renderer/bsdfs/_preview_kernels.py",
             "renderer/kernels/vmath.py"])
