"""The material table: UsdPreviewSurface inputs packed as structure-of-arrays, evaluated per hit.

``MaterialTable.build(materials, textures)`` packs the constant inputs of every material into
arrays indexed by material id and records which inputs are textured.
``evaluate(mat, st)`` returns ``SurfaceParams`` for a batch of hits: constants are gathered by
material id, then each *texture* (not each row) overrides the rows of the materials it feeds,
with one vectorised lookup per texture.

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
in the per-hit coordinates, and each texture reads its own (``_texture_st``).

Primvar inputs (a UsdPrimvarReader_* connected to an input, ``MaterialInput.primvar``): the
primvars materials read are laid out after st in the per-hit coordinates (``primvar_layout``:
``evaluate``'s ``st`` is (n, 2 + K), columns 2.. the interpolated primvars, as the geometry's
per-corner table, renderer/scene.py). A hit whose gprim lacks the primvar carries NaN there and
gets the reader's fallback. Components map to the input as for textures.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

import numpy as np
from numba import njit

from renderer.bsdfs.microfacet import albedo_tables
from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.description import MaterialDesc, MaterialInput, TextureDesc, primvar_layout
from renderer.errors import StageError
from renderer.textures import TextureCache, lookup_row, output_channels

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


@njit(cache=True, nogil=True)
def presence_hit(tab, m, s, t):
    """presence_at for one hit of material m at st = (s, t), from MaterialTable.presence_table."""
    op_c, thr, slot, chan, px, off, h, w, nc, ws, wt, xf, has_xf, scale, bias, fallback, loaded = tab
    op = op_c[m]
    j = slot[m]
    if j >= 0:
        c = chan[m]
        if not loaded[j]:
            op = fallback[j, c]
        else:
            op = lookup_row(px, off[j], h[j], w[j], nc[j], s, t, ws[j], wt[j], xf[j] if has_xf[j] else xf[j, :0], c,
                            scale[j, c], bias[j, c], fallback[j, c])
    return presence_row(op, thr[m])


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
        """SurfaceParams at n hits. mat: (n,) int material ids; st: (n, 2) texture coordinates
        (or None: textures are looked up at (0, 0))."""
        mat = np.asarray(mat, dtype=np.int64)
        # The normal is gathered only where some material bends normals (SurfaceParams.normal).
        out = {name: arr[mat] for name, arr in self.const.items() if name != "normal" or self.has_normal_map}
        if self.textures:
            self._apply_textures(out, mat, st, None)
        if self._primvar:
            self._apply_primvars(out, mat, st, None)
        return SurfaceParams(**out)

    def _apply_primvars(self, out: dict, mat: np.ndarray, st: Optional[np.ndarray], only: Optional[str]) -> None:
        """Override primvar-fed inputs in ``out`` from the per-hit coordinates' primvar columns;
        NaN there (the gprim lacks the primvar) or no coordinates at all give the fallback."""
        for (fname, cols), (mats_f, fallbacks) in self._primvar.items():
            if (only is not None and fname != only) or fname not in out:
                continue
            rows = np.nonzero(self._has(mats_f)[mat])[0]
            if rows.size == 0:
                continue
            fb = fallbacks[np.searchsorted(mats_f, mat[rows])] if mats_f.size > 1 else \
                np.broadcast_to(fallbacks[0], (rows.size, fallbacks.shape[1]))
            if st is None or np.shape(st)[1] <= max(cols):
                vals = fb
            else:
                vals = np.asarray(st, dtype=np.float64)[rows][:, list(cols)]
                vals = np.where(np.isnan(vals), fb, vals)
            arr = out[fname]
            arr[rows] = vals[:, 0] if arr.ndim == 1 else vals

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

    def _apply_textures(
        self, out: dict, mat: np.ndarray, st: Optional[np.ndarray], only: Optional[str]
    ) -> None:
        """Override textured inputs in ``out`` (arrays gathered by ``mat``) texture by texture."""
        for s, tex in enumerate(self.textures):
            mats_t, binds = self._by_texture[s]
            if only is not None:
                binds = [b for b in binds if b.field == only]
                if not binds:
                    continue
                mats_t = np.unique(np.array([b.material for b in binds], dtype=np.int64))
            rows = np.nonzero(self._has(mats_t)[mat])[0]
            if rows.size == 0:
                continue
            st_rows = self._texture_st(tex, st, rows)
            rgba = self.texture_cache.lookup(tex, st_rows)
            mat_rows = mat[rows]
            # Group the bindings by (field, channels): usually one group covering every row.
            groups: dict[tuple, list[int]] = {}
            for b in binds:
                groups.setdefault((b.field, b.channels), []).append(b.material)
            for (fname, chans), mats in groups.items():
                arr = out[fname]  # a fresh array from fancy indexing: safe to write
                if len(mats) == mats_t.size:
                    r, vals = rows, rgba[:, list(chans)]
                else:
                    sel = self._has(mats)[mat_rows]
                    r, vals = rows[sel], rgba[sel][:, list(chans)]
                if arr.ndim == 1:
                    arr[r] = vals[:, 0]
                else:
                    arr[r] = vals

    def _texture_st(self, tex: TextureDesc, st: Optional[np.ndarray], rows: np.ndarray) -> np.ndarray:
        """(k, 2) texture coordinates of ``tex`` at hits ``rows``: columns 0-1 of the per-hit
        coordinates, or, where the scene's textures read several st primvars
        (``primvar_layout``), the texture's own st primvar's columns where the hit's gprim has
        it (a gprim whose materials read one st set holds it in columns 0-1 only)."""
        if st is None:
            return np.zeros((rows.size, 2))
        st = np.asarray(st, dtype=np.float64)
        out = st[rows, :2]
        named = self.primvar_layout.get(tex.st_primvar)
        if named is not None and st.shape[1] >= named[0] + 2:
            own = st[rows, named[0]:named[0] + 2]
            out = np.where(np.isfinite(own).all(axis=1, keepdims=True), own, out)
        return out

    def _has(self, mats) -> np.ndarray:
        """(materials,) bool, True at the ids in mats: a gather per hit instead of np.isin's sort."""
        mask = np.zeros(len(self), dtype=bool)
        mask[np.asarray(mats, dtype=np.int64)] = True
        return mask

    def presence_at(self, mat: np.ndarray, st: Optional[np.ndarray] = None) -> np.ndarray:
        """(n,) presence probability at hits without evaluating the other inputs (for shadow
        rays and any-hit style tests)."""
        mat = np.asarray(mat, dtype=np.int64)
        out = {"opacity": self.const["opacity"][mat]}
        if self.textures and np.any(self._slot["opacity"] >= 0):
            self._apply_textures(out, mat, st, "opacity")
        if self._primvar:
            self._apply_primvars(out, mat, st, "opacity")
        return _presence(out["opacity"], self.const["opacity_threshold"][mat])

    @property
    def presence_compiled(self) -> bool:
        """Whether presence_table describes presence exactly: no primvar reader feeds an
        opacity, and every opacity texture is one image (not UDIM tiles) read at the hits'
        first st set (columns 0-1)."""
        if any(fname == "opacity" for fname, _ in self._primvar):
            return False
        if any(any(b.field == "opacity" for b in binds) and self.textures[s].udim_tiles
               for s, (_, binds) in enumerate(self._by_texture)):
            return False  # presence_hit reads one image per texture, not UDIM tiles
        return not any(any(b.field == "opacity" for b in binds) and self.textures[s].st_primvar in self.primvar_layout
                       for s, (_, binds) in enumerate(self._by_texture))

    def presence_table(self) -> tuple:
        """presence_at's inputs as arrays, for compiled callers (presence_hit): (opacity (m,),
        threshold (m,), slot (m,) int64 the texture feeding the material's opacity or -1, channel
        (m,) int64 its channel, then per such texture (k,): pixels (all k images flat, float32),
        offset, height, width, channels (int64), wrap_s, wrap_t (textures.WRAP_MODES codes), xf
        (k, 6) st transform and has_xf (k,) bool, scale, bias, fallback (k, 4), loaded (k,) bool
        (False: the file could not be read, fallback)."""
        from renderer.textures import WRAP_MODES

        m = len(self)
        slot = np.full(m, -1, dtype=np.int64)
        chan = np.zeros(m, dtype=np.int64)
        texs: list[int] = []
        for s, (_, binds) in enumerate(self._by_texture):
            for b in binds:
                if b.field == "opacity":
                    if s not in texs:
                        texs.append(s)
                    slot[b.material], chan[b.material] = texs.index(s), b.channels[0]
        k = len(texs)
        images = [self.texture_cache.image(self.textures[s]) for s in texs]
        shapes = np.array([im.shape if im is not None else (0, 0, 4) for im in images], dtype=np.int64).reshape(k, 3)
        sizes = shapes.prod(axis=1)
        offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if k else np.zeros(0, np.int64)
        pixels = (np.concatenate([im.reshape(-1) for im in images if im is not None]).astype(np.float32)
                  if any(im is not None for im in images) else np.zeros(0, np.float32))
        modes = [self.texture_cache.wrap_modes(self.textures[s]) for s in texs]
        xf = np.zeros((k, 6))
        for j, s in enumerate(texs):
            if self.textures[s].st_transform:
                xf[j] = self.textures[s].st_transform
        per_tex = lambda attr: np.array([np.ravel(getattr(self.textures[s], attr)) for s in texs],  # noqa: E731
                                        dtype=np.float64).reshape(k, 4)
        return (np.ascontiguousarray(self.const["opacity"], dtype=np.float64),
                np.ascontiguousarray(self.const["opacity_threshold"], dtype=np.float64), slot, chan, pixels, offset,
                np.ascontiguousarray(shapes[:, 0]), np.ascontiguousarray(shapes[:, 1]),
                np.ascontiguousarray(shapes[:, 2]),
                np.array([WRAP_MODES.index(a) for a, _ in modes], dtype=np.int64),
                np.array([WRAP_MODES.index(b) for _, b in modes], dtype=np.int64), xf,
                np.array([bool(self.textures[s].st_transform) for s in texs], dtype=np.bool_),
                per_tex("scale"), per_tex("bias"), per_tex("fallback"),
                np.array([im is not None for im in images], dtype=np.bool_))

    @staticmethod
    def presence(params: SurfaceParams) -> np.ndarray:
        """Same as the module-level ``presence``."""
        return presence(params)


# presence_hit inlines textures.lookup_row: its cache follows that file (renderer/kernels).
from renderer.kernels import guard_cache, module_dispatchers  # noqa: E402

guard_cache(__name__, module_dispatchers(globals()), ["renderer/textures.py"])
