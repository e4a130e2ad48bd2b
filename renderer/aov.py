"""Render passes (AOVs) seen by the camera rays' first hits, and the beauty's alpha.

Which passes a render writes comes from its RenderProduct's ``orderedVars`` (RenderVar
``sourceName`` / ``sourceType`` / ``dataType``, read by renderer/usd/render_settings.py into
``RenderVarDesc``) or from ``--aov NAME[,NAME...]``. ``SOURCES`` lists what illum computes:

=============  ========  =====================================================================
source         channels  value
=============  ========  =====================================================================
color (Ci)     R G B     the beauty itself (never written twice)
alpha (a, A)   A         coverage (below)
albedo         .R .G .B  first-hit diffuse reflectance: UsdPreviewSurface diffuseColor, textures
                         applied, clamped to [0, 1] (in the metallic workflow also the metal's
                         F0, so metals are not black to a denoiser); 0 where nothing is hit
normal (N)     .X .Y .Z  first-hit world-space shading normal (normal maps applied), facing the
                         camera ray; 0 where nothing is hit
normalCamera   .X .Y .Z  the same in USD camera space (x right, y up, the camera looks down -z)
depth (Z, Pz)  one       camera-space distance along the view axis (-z of USD camera space);
                         +inf where no sample of the pixel hits
P              .X .Y .Z  world position of the first hit; 0 where no sample hits
primId         one       index of the gprim (EXR metadata illum:primPaths lists their paths),
materialId               the material's index (illum:materialPaths); -1 where nothing is hit
sampleCount    one       camera samples traced in each pixel (the film's count; with adaptive
                         sampling also the decision samples, renderer/adaptive.py)
=============  ========  =====================================================================

Filtering: every pass but the ids and the sample count goes through the same film as the
beauty (renderer/film.py, same pixel filter, splat or importance mode, the same camera samples:
``FirstHitPass`` regenerates each pass's camera rays exactly as PathIntegrator.trace_paths does,
from the pixel's sequence point), so the passes line up with the beauty to the sample. alpha,
albedo and the normals are premultiplied (a pixel half covered holds half the value, as Cycles'
passes are); depth and P are divided by the hit coverage (an edge pixel holds the mean depth of
its covering samples, not a depth halfway to nothing). The ids are point samples: each pixel
keeps the id of its sample nearest to the pixel centre (a filtered id means nothing).

Alpha: the filtered fraction of camera rays that hit geometry inside the clipping range.
Cut-outs count as transparent (one presence draw per surface, as the integrator draws them).
Lights the camera sees directly (area lights, which our rays cross, and the dome) add their
emission to RGB but no coverage: in premultiplied terms a visible light is an additive emitter
over what is behind it, which is what a light transparent to every ray (renderer/integrators/
path.py's convention, Cycles') makes it; emissive *geometry* is geometry, coverage 1. (Not
checked against Karma's or Cycles' own alpha for a visible area light: no documentation of it
was found.) The dome (and any infinite light) seen directly stays in RGB unless
``--alpha-dome-transparent`` (or IllumRenderSettingsAPI ``illum:alpha:domeTransparent``) asks
for a transparent background: then the radiance the escaped camera rays saw is accumulated
here through the same film samples and subtracted from the beauty, which is exact where no
cut-out lies in front of the dome (the integrator's camera rays and these are the same rays)
and unbiased behind cut-outs (whose presence draws differ) and for a thin lens's further
emitter-sample rays (--emitter-samples K > 1: their lens samples come from the integrator's
stream after its path, which this pass does not replay). A resumed render's passes hold the
samples of this run only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .errors import SettingsError
from .film import splat_scratch, splat_weights

__all__ = ["SOURCES", "ALIASES", "AovRequest", "AovResult", "resolve_source", "requests_from_names", "requests_from_vars",
           "FirstHitPass", "aov_channels", "DATA_TYPE_WIDTH"]

# canonical source -> channel suffixes ("" for a scalar named after its layer)
SOURCES = {
    "color": ("R", "G", "B"),
    "alpha": ("A",),
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "normalCamera": ("X", "Y", "Z"),
    "depth": ("",),
    "P": ("X", "Y", "Z"),
    "primId": ("",),
    "materialId": ("",),
    "sampleCount": ("",),
}
ALIASES = {"Ci": "color", "C": "color", "rgb": "color", "beauty": "color", "a": "alpha", "A": "alpha",
           "N": "normal", "Nn": "normal", "Nc": "normalCamera", "Z": "depth", "Pz": "depth", "z": "depth",
           "id": "primId", "primid": "primId", "materialid": "materialId", "samples": "sampleCount"}
# The per-sample columns each filtered source adds to the films (alpha's hit coverage is always there).
_COLUMNS = {"albedo": 3, "normal": 3, "normalCamera": 3, "depth": 1, "P": 3}
_IDS = ("primId", "materialId")
# UsdRender RenderVar dataType -> components (None: any)
DATA_TYPE_WIDTH = {"color3f": 3, "color3h": 3, "float3": 3, "half3": 3, "normal3f": 3, "normal3h": 3,
                   "point3f": 3, "vector3f": 3, "color4f": 4, "float4": 4, "half4": 4, "float": 1, "half": 1,
                   "int": 1, "uint": 1, "int64": 1, "float2": 2}


@dataclass(frozen=True)
class AovRequest:
    """One pass to write: ``name`` the layer (the RenderVar's prim name, or the --aov token),
    ``source`` a SOURCES key, ``path`` the RenderVar prim ('' for --aov)."""

    name: str
    source: str
    path: str = ""


def resolve_source(source_name: str, source_type: str = "raw") -> str | None:
    """The SOURCES key a RenderVar's (sourceName, sourceType) asks for, or None when illum does
    not compute it (light path expressions, arbitrary primvars, unknown names)."""
    if source_type == "lpe":
        return None
    name = str(source_name)
    if name in SOURCES:
        return name
    return ALIASES.get(name)


def requests_from_names(names) -> tuple[AovRequest, ...]:
    """--aov NAME[,NAME...] -> requests; an unknown name is a SettingsError naming it."""
    out = []
    for name in names:
        src = resolve_source(name)
        if src is None:
            known = ", ".join([*SOURCES, *ALIASES])
            raise SettingsError(f"unknown AOV {name!r}; known: {known}", attribute="aov")
        out.append(AovRequest(name, src))
    return tuple(out)


def requests_from_vars(render_vars) -> tuple[AovRequest, ...]:
    """RenderVarDesc entries (renderer/description.py) -> requests for the supported ones (the
    reader warned once about each of the others)."""
    return tuple(AovRequest(v.name, v.source, v.path) for v in render_vars if v.source)


def aov_channels(req: AovRequest) -> tuple[str, ...]:
    """The EXR channel names of one pass (OpenImageIO's layer.channel naming)."""
    if req.source == "color":
        return ("R", "G", "B")
    if req.source == "alpha":
        return ("A",)
    return tuple(f"{req.name}.{c}" if c else req.name for c in SOURCES[req.source])


@njit(cache=True, nogil=True)
def _splat_columns(rows, off, V, values, radius, width, flat_sum, flat_w):
    """Splat samples with C columns: sample i, in data-window pixel rows[i] (flat, row-major over
    width columns) at offset off[i] (2,) from its centre, adds w V[i] (C,) to flat_sum (m, C) and
    w to flat_w (m,) of every pixel under the filter, with the footprint and weights w of
    renderer/film.py's _splat_kernel (film.splat_weights; so the two films' sums of w are the
    same numbers)."""
    m = flat_w.shape[0]
    height = m // width
    C = V.shape[1]
    scale, wx, wy, ps, ws = splat_scratch(values, radius)
    for i in range(rows.shape[0]):
        for j in range(splat_weights(rows[i], off[i, 0], off[i, 1], width, height, radius, values, scale, wx, wy,
                                     ps, ws)):
            flat_w[ps[j]] += ws[j]
            for c in range(C):
                flat_sum[ps[j], c] += ws[j] * V[i, c]


class FirstHitPass:
    """First-hit passes, alpha and the directly seen dome over the camera rays of each render
    pass (module docstring).

    scene, camera: the render's; film: the beauty film (its size, window and splat filter are
    taken); sources: the SOURCES keys to compute; seed, emitter_samples: the integrator's (its
    camera rays are regenerated from them); exposure: the camera's exposure scale (the dome's
    radiance is subtracted at the beauty's scale); dome_transparent: accumulate the dome seen
    directly; bend: a function (prim, mat, ns, ng, wo, params) -> normal-mapped ns, or None.
    """

    def __init__(self, scene, camera, film, sources, *, seed: int, emitter_samples: int, exposure: float = 1.0,
                 dome_transparent: bool = False, bend=None):
        self.scene, self.camera = scene, camera
        self.sources = tuple(dict.fromkeys(sources))
        self.seed, self.K, self.exposure, self.bend = int(seed), max(1, int(emitter_samples)), float(exposure), bend
        lights = scene.lights
        self.infinite = (np.nonzero(lights.is_infinite)[0] if dome_transparent and lights.count
                         else np.zeros(0, np.int64))
        self.dome_transparent = bool(dome_transparent)
        # Column layout of one sample's values: hit coverage first, then each filtered source.
        self.slots: dict[str, slice] = {"alpha": slice(0, 1)}
        c = 1
        for s in self.sources:
            if s in _COLUMNS:
                self.slots[s] = slice(c, c + _COLUMNS[s])
                c += _COLUMNS[s]
        if self.infinite.size:
            self.slots["dome"] = slice(c, c + 3)
            c += 3
        self.columns = c
        h, w = film.shape
        self.splat = film.splat
        self.sum = np.zeros((h, w, c))      # sum(w v) per column
        self.weight = np.zeros((h, w))      # sum(w): the beauty film's W1 for the same samples
        self.ids = {s: np.full(film.shape, -1, dtype=np.int64) for s in self.sources if s in _IDS}
        self.id_dist = np.full(film.shape, np.inf) if self.ids else None
        self.world_to_camera = camera.world_to_camera()
        # primId is the gprim's: a mesh split by material subsets is one prim.
        paths = list(scene.geometry.mesh_paths)
        self.prim_paths = list(dict.fromkeys(paths))
        where = {p: i for i, p in enumerate(self.prim_paths)}
        self.prim_of_mesh = np.array([where[p] for p in paths], dtype=np.int64)

    # ------------------------------------------------------------------ tracing
    def render_pass(self, film, pass_index: int, pool=None, rows=None) -> None:
        """Add this pass's camera samples (the ones PathIntegrator.render_pass takes for the
        beauty film ``film``, over the same rows: flat data-window pixels, None for all) to the
        passes. pool: an executor the chunks are traced on (the integrator's), each in its own
        thread; they are accumulated in order afterwards."""
        from .accel import serial_tracing
        from .integrators.path import chunk_size

        px, py = film.pixel_coords()
        if rows is not None:
            px, py = px[rows], py[rows]
        n = px.size
        size = chunk_size(n)
        chunks = [(c, a, min(n, a + size)) for c, a in enumerate(range(0, n, size))]

        def work(job):
            with serial_tracing():
                return self._chunk(job, px, py, film.width, pass_index)

        results = pool.map(work, chunks) if pool is not None and len(chunks) > 1 else map(
            lambda job: self._chunk(job, px, py, film.width, pass_index), chunks)
        splat = film.splat is not None
        for at, samples in results:
            pixels = at if rows is None else rows[at]
            for k, (values, offset, hit_ids) in enumerate(samples):
                self._keep_ids(pixels, offset, hit_ids)
                if splat:
                    self._add(pixels, values, offset, k == 0)
            if not splat:
                self._add(pixels, sum(v for v, _, _ in samples) / len(samples), None, True)

    def _chunk(self, job, px, py, width: int, pass_index: int):
        """(positions a..b-1 in px / py, [(values, offsets, ids) per camera ray k]) of one chunk
        (c, a, b) of the pass, its rays made as PathIntegrator.trace_paths makes them."""
        from .sampling import pixel_sequence

        c, a, b = job
        m = b - a
        cx, cy = px[a:b], py[a:b]
        thin_lens = self.camera.lens_radius > 0.0
        K = self.K
        # The integrator's chunk stream: its first draw is the first camera ray's lens sample.
        rng = np.random.default_rng([self.seed, pass_index, c])
        own = np.random.default_rng([self.seed, pass_index, c, 0x41])  # cut-outs, further lenses
        pixel = cy.astype(np.int64) * max(width, 1) + cx
        samples = []
        for k in range(K):
            u = pixel_sequence(self.seed, pixel, pass_index * K + k)
            u_lens = ((rng if k == 0 else own).random((m, 2)) if thin_lens else np.zeros((m, 2)))
            rays = self.camera.generate(cx, cy, u, u_lens)
            o, tmax = rays.at_near_plane()
            values, hit_ids = self._first_hits(o, rays.d, tmax, own)
            offset = u - 0.5 if self.splat is not None else self.camera.filter.sample(u)
            samples.append((values, offset, hit_ids))
        return np.arange(a, b), samples

    def _add(self, rows, values, offsets, count: bool) -> None:
        """Accumulate one sample per row as the beauty film does (renderer/film.py): splatted with
        the film's filter at offsets (pixels from the centre), or with weight 1 in its own pixel."""
        flat_sum = self.sum.reshape(-1, self.columns)
        flat_w = self.weight.reshape(-1)
        if self.splat is None:
            flat_sum[rows] += values   # one sample per pixel and call: rows are unique
            flat_w[rows] += 1.0
            return
        f = self.splat
        _splat_columns(np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(offsets, dtype=np.float64),
                       np.ascontiguousarray(values, dtype=np.float64), f._values, float(f.radius),
                       int(self.sum.shape[1]), flat_sum, flat_w)

    def _keep_ids(self, rows, offset, hit_ids) -> None:
        """Each pixel keeps the ids of its sample nearest to the centre (module docstring)."""
        if not self.ids:
            return
        dist = offset[:, 0] ** 2 + offset[:, 1] ** 2
        flat_d = self.id_dist.reshape(-1)
        closer = dist < flat_d[rows]
        r = rows[closer]
        flat_d[r] = dist[closer]
        for s, arr in self.ids.items():
            arr.reshape(-1)[r] = hit_ids[s][closer]

    def _first_hits(self, o, d, tmax, rng):
        """(values (m, columns), {id source: (m,) int}) of camera rays o, d (m, 3) with far
        distances tmax (m,), through cut-outs (presence drawn from rng)."""
        from .geometry import offset_origin, surface_interaction

        scene = self.scene
        g, mats, accel = scene.geometry, scene.materials, scene.accel
        m = o.shape[0]
        values = np.zeros((m, self.columns))
        ids = {s: np.full(m, -1, dtype=np.int64) for s in self.ids}
        rows = np.arange(m)
        o, d, tmax = o.copy(), d.copy(), tmax.copy()
        for _ in range(64):  # the integrator's bound on cut-out pass-throughs
            hits = accel.intersect(o[rows], d[rows], tmax[rows])
            hit = hits.hit
            escaped = rows[~hit]
            if escaped.size and self.infinite.size:
                D = np.zeros((escaped.size, 3))
                for li in self.infinite:
                    D += scene.lights.le_escaped(np.full(escaped.size, li, dtype=np.int64), d[escaped])
                values[escaped, self.slots["dome"]] = D * self.exposure
            k = np.nonzero(hit)[0]
            if not k.size:
                break
            r = rows[k]
            prim = hits.prim[k].astype(np.int64)
            p, ng, ns, st = surface_interaction(g.vertices, g.face_normal, g.normals, g.st, prim, hits.b1[k],
                                                hits.b2[k], d[r])
            mat = g.material[prim]
            params = mats.evaluate(mat, st) if (mats.params_needed or "albedo" in self.slots) else None
            if mats.has_cutout:
                through = rng.random(r.size) >= mats.presence(params)
                t_ = np.nonzero(through)[0]
                r_next = r[t_]
                if t_.size:  # on from just past the surface, with what is left of the far clip
                    o_next = offset_origin(p[t_], ng[t_], d[r_next], accel.ray_epsilon(p[t_], prim[t_]))
                    tmax[r_next] = np.maximum(tmax[r_next] - hits.t[k][t_], 0.0)
                    o[r_next] = o_next
                solid = np.nonzero(~through)[0]
                r, prim, p, ng, ns, st, mat = r[solid], prim[solid], p[solid], ng[solid], ns[solid], st[solid], mat[solid]
                params = params.take(solid) if params is not None else None
            else:
                r_next = np.zeros(0, np.int64)
            self._shade(values, ids, r, prim, mat, p, ng, ns, -d[r], params)
            rows = r_next
            if not rows.size:
                break
        return values, ids

    def _shade(self, values, ids, r, prim, mat, p, ng, ns, wo, params) -> None:
        """Write the first-hit values of the solid hits r."""
        if not r.size:
            return
        sl = self.slots
        values[r, 0] = 1.0
        if self.bend is not None and self.scene.materials.has_normal_map and ("normal" in sl or "normalCamera" in sl):
            ns = self.bend(prim, mat, ns, ng, wo, params)
        R = self.world_to_camera[:3, :3]
        if "albedo" in sl:
            values[r, sl["albedo"]] = np.clip(params.diffuse, 0.0, 1.0)
        if "normal" in sl:
            values[r, sl["normal"]] = ns
        if "normalCamera" in sl:
            nc = ns @ R.T
            values[r, sl["normalCamera"]] = nc / np.linalg.norm(nc, axis=1, keepdims=True)
        if "depth" in sl:
            z = p @ R[2] + self.world_to_camera[2, 3]
            values[r, sl["depth"]] = -z[:, None]
        if "P" in sl:
            # The scene is traced re-centred on the camera (renderer/scene.py recentre); P is world.
            values[r, sl["P"]] = p + self.scene.origin
        if "primId" in ids:
            ids["primId"][r] = self.prim_of_mesh[self.scene.geometry.mesh[prim]]
        if "materialId" in ids:
            ids["materialId"][r] = mat

    # ------------------------------------------------------------------ results
    def means(self) -> np.ndarray:
        """(h, w, columns) float64 filtered means of the data window (0 where no sample weighs in)."""
        W = self.weight[:, :, None]
        return self.sum / np.where(W > 0.0, W, 1.0)

    def alpha(self) -> np.ndarray:
        """(h, w) filtered coverage."""
        return self.means()[:, :, 0]

    def dome(self) -> np.ndarray | None:
        """(h, w, 3) the filtered radiance of the infinite lights seen directly, or None."""
        return self.means()[:, :, self.slots["dome"]] if "dome" in self.slots else None

    def image(self, source: str, beauty_count: np.ndarray) -> np.ndarray:
        """(h, w, C) float32 pass of the data window (module docstring's conventions)."""
        if source == "sampleCount":
            return beauty_count[:, :, None].astype(np.float32)
        if source in self.ids:
            return self.ids[source][:, :, None].astype(np.float32)
        means = self.means()
        if source == "alpha":
            return means[:, :, 0:1].astype(np.float32)
        v = means[:, :, self.slots[source]]
        if source in ("depth", "P"):
            cover = means[:, :, 0:1]
            ok = cover > 1e-12
            v = np.where(ok, v / np.where(ok, cover, 1.0), np.inf if source == "depth" else 0.0)
        return v.astype(np.float32)


@dataclass
class AovResult:
    """What a render adds to its beauty film: the passes asked for, whether the beauty has
    alpha, the first-hit passes (None when nothing needed them) and the denoised beauty."""

    requests: tuple
    alpha: bool
    passes: FirstHitPass | None
    material_paths: tuple = ()
    denoised: np.ndarray | None = None   # (h, w, 3) float32 data window
    denoise_seconds: float = 0.0
    # (h, w) camera samples traced in each pixel when they are more than the beauty film's count
    # (adaptive sampling's decision samples, renderer/adaptive.py); None: the film's count.
    sample_count: np.ndarray | None = None

    @property
    def layered(self) -> bool:
        """Whether the EXR holds more than the film's RGB: passes, alpha or a denoised layer."""
        return (self.passes is not None or self.denoised is not None
                or any(r.source not in ("color",) for r in self.requests))

    def pass_image(self, source: str, film) -> np.ndarray:
        """(h, w, C) float32 pass ``source`` of the data window (FirstHitPass.image; the sample
        count needs no first-hit pass)."""
        count = film.count if self.sample_count is None else self.sample_count
        if self.passes is None:   # only the sample count is asked for
            return count[:, :, None].astype(np.float32)
        return self.passes.image(source, count)

    def beauty(self, film) -> np.ndarray:
        """(h, w, 3 or 4) float32 data window: the film's mean, without the dome seen directly
        where it is transparent, and the alpha when asked for (premultiplied)."""
        rgb = film.mean()
        if self.passes is None:
            return rgb
        dome = self.passes.dome()
        if dome is not None:
            rgb = (rgb - dome).astype(np.float32)
        if not self.alpha:
            return rgb
        return np.concatenate([rgb, self.passes.image("alpha", film.count)], axis=2)

    def layers(self, film) -> tuple[np.ndarray, tuple[str, ...]]:
        """(pixels (h, w, C) float32, channel names) of the whole EXR: the beauty's R G B (A),
        each requested pass (aov_channels), and denoised.R/G/B."""
        parts = [self.beauty(film)]
        names = ["R", "G", "B", "A"][:parts[0].shape[2]]
        seen = set(names)
        for req in self.requests:
            chans = aov_channels(req)
            if req.source in ("color", "alpha") or seen.intersection(chans):
                continue  # the beauty's own channels, or a pass already written under this name
            parts.append(self.pass_image(req.source, film))
            names += chans
            seen.update(chans)
        if self.denoised is not None:
            parts.append(self.denoised)
            names += ["denoised.R", "denoised.G", "denoised.B"]
        return np.concatenate(parts, axis=2).astype(np.float32), tuple(names)

    def metadata(self) -> dict:
        """EXR attributes that say what the id passes' numbers are."""
        out = {}
        srcs = {r.source for r in self.requests}
        if "primId" in srcs and self.passes is not None:
            out["illum:primPaths"] = self.passes.prim_paths
        if "materialId" in srcs:
            out["illum:materialPaths"] = list(self.material_paths)
        if self.denoised is not None:
            out["illum:denoiseSeconds"] = float(self.denoise_seconds)
        return out


# _splat_columns inlines film.splat_weights: its cache follows that file (renderer/kernels).
from renderer.kernels import guard_cache, module_dispatchers  # noqa: E402

guard_cache(__name__, module_dispatchers(globals()), ["renderer/film.py"])
