"""UsdLuxDomeLight / DomeLight_1: radiance at infinity from every direction.

Orientation (OpenEXR lat-long, USD-NOTES section 1): for texel column x and row y (row 0 = top)
of a W x H image, u = (x + 0.5) / W, v = (y + 0.5) / H,

    lon = pi - 2 pi u,  lat = pi/2 - pi v,
    dir_local = (sin lon cos lat, sin lat, cos lon cos lat),

so +Y (local) is the top row, +Z the image centre, +X the column at u = 1/4, -X at u = 3/4 and
-Z the left/right edge. dir_world = R dir_local with R the rotation of ``light_to_world``
(its orthogonal polar factor; the reader has already folded the poleAxis / up-axis fix in).

Lookup is **nearest texel** (no filtering), and importance sampling is exact for it: texels are
picked with probability proportional to lum(texel) * Omega_texel, where
Omega_texel = (2 pi / W) (cos theta_top - cos theta_bottom) is the texel's exact solid angle
(theta = pi v from the +Y pole), and the direction is then drawn *uniformly in solid angle*
inside the texel (phi linear in the column, cos theta linear in the row). Hence

    pdf_w = pmf / Omega_texel = lum(texel) / sum_j lum_j Omega_j  (proportional to lum(Le)),

which is pbrt's lum * sin(theta) weighting made exact (no sin theta mismatch inside a row).
A dome without texture is sampled uniformly over the sphere (pdf 1 / 4 pi).

``texture:format``: 'latlong' is accepted at any size; 'automatic' is accepted when the image
is 2:1 (treated as lat-long), otherwise StageError; other formats (mirroredBall, angular,
cubeMapVerticalCross) raise StageError. Texels that are NaN, infinite or negative raise
StageError with their count. ``normalize`` is ignored for domes (UsdLux).

irradiance_lookup() gives the control variate's F for textured domes: the unshadowed irradiance
E(n) = Σ_t L_t ∫_t max(0, n·ω) dω of exactly these nearest-texel radiances and texel solid
angles, precomputed on a lat-long table and interpolated (renderer/preconvolve.py). The table is
the authored ``illum:dome:irradiance`` map when its recorded source hash matches the texture
(a stale or approximate map is replaced with a warning), else computed at load (64 x 32, exact)
and cached on disk by the texture's content hash.

**Portals** (DomeLight ``portals`` -> PortalLight prims: "a rectangular portal in the local XY
plane ... transmits light in the -Z direction", so the interior is on the portal's local -Z
side). UsdLux says only that portals "guide light sampling"; renderers differ on what they do to
the picture (RenderMan's and Karma's portal lights restrict the dome's *light* to what comes
through them; pbrt-v4's PortalImageInfiniteLight emits only through its portal). illum treats
them purely as a sampling guide, so a stage renders the same image with or without portals:

* a point p for which at least one portal is usable -- p on its interior side (and, for a
  constant dome, the portal's spherical rectangle well conditioned: >= 1e-4 sr, not grazing,
  as for rect lights) -- samples the mixture  f * (portal part) + (1 - f) * (the dome's own
  sampling). The portal part picks a usable portal k with probability w_k / sum(w), then a
  direction through it:
  - constant dome (f = 1): uniformly in the portal's solid angle (Urena et al.'s spherical
    rectangle, lights/spherical_rect.py), w_k = Omega_k; the density is (number of usable
    portals crossed by wi) / sum(Omega), uniform over the openings;
  - textured dome (f = TEXTURED_PORTAL_FRACTION): in proportion to the dome's luminance as seen
    through the window (lights/portal.py: a table in portal-angle space where each point's
    window is a rectangle, sampled with a summed-area table, pbrt-v4's approach), w_k = the
    window's luminance integral. Uniform-in-window sampling would all but miss a sun seen
    through the window; the remaining 1 - f of texel sampling keeps every direction with
    radiance covered;
* every other point samples the dome as without portals (the choice depends only on the
  (light, point) pair, so pdf_li makes the same one);
* rays that escape the scene still see the dome in every direction; their MIS weight uses this
  density, so directions outside the portals (where the portal part has density 0) are covered
  by BSDF sampling alone and the estimate stays unbiased (with f = 1 the light pdf is 0 there
  and the BSDF sample takes weight 1).

A dome with portals has no exact unshadowed integral for the control variate (its light
samples do not cover the whole sphere when f = 1), so irradiance.py reports it inexact and the
estimators use MIS. Portal lights emit nothing and are not lights in the LightSet. The reader
rejects a ``portals`` target that is not a PortalLight; a zero-size or sheared portal is
dropped with a warning naming it.

phi() (for power-based light selection) follows pbrt's infinite lights: the power through a
disk of the scene's radius R, pi R^2 * integral over the sphere of lum(Le) d omega
(= 4 pi^2 R^2 lum(L) for a constant dome).
"""

from __future__ import annotations

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.errors import StageError
from renderer.kernels import portal as portal_kernels
from renderer.lights import portal as portal_tables
from renderer.lights._common import (
    SHAPE_RTOL,
    emission_normal,
    far_distance,
    invalid_sample,
    linear_part,
    polar_decomposition_rotation,
)
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.radiometry import emitted_radiance
from renderer.lights.spherical_rect import GRAZING_NZ2, MIN_SOLID_ANGLE
from renderer.lights.texture import ImageSet, load_texture_rgb
from renderer.sampling import INV_4PI, sample_uniform_sphere


# Share of a textured dome's samples drawn through its portals (the rest: texel importance).
# On stages/lux_extra/window_portal.usda (16 spp, depth 4) the relMSE was 0.035 / 0.027 / 0.024
# for 0.5 / 0.75 / 0.9 (0.103 without portals); 0.75 keeps a quarter of texel samples for
# openings the portals do not cover.
TEXTURED_PORTAL_FRACTION = 0.75


def latlong_texel_solid_angles(h: int, w: int) -> np.ndarray:
    """(h,) exact solid angle of one texel in each row of an h x w lat-long image."""
    z = np.cos(np.pi * np.arange(h + 1) / h)
    return (2.0 * np.pi / w) * (z[:-1] - z[1:])


def direction_to_texel(d_local: np.ndarray, h: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest texel (row, col) (n,) int64 of local unit directions (n, 3) in h x w images."""
    theta = np.arctan2(np.hypot(d_local[:, 0], d_local[:, 2]), d_local[:, 1])  # from +Y, [0, pi]
    lon = np.arctan2(d_local[:, 0], d_local[:, 2])  # (-pi, pi]
    u = (np.pi - lon) / (2.0 * np.pi)  # [0, 1)
    row = np.clip(np.floor(theta / np.pi * h).astype(np.int64), 0, h - 1)
    col = np.floor(u * w).astype(np.int64) % w
    return row, col


def texel_to_direction(u: np.ndarray, cos_theta: np.ndarray) -> np.ndarray:
    """Local unit direction (n, 3) from the horizontal texture coordinate u and cos(theta)."""
    lon = np.pi - 2.0 * np.pi * u
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_theta * cos_theta))
    return np.stack([np.sin(lon) * sin_t, cos_theta, np.cos(lon) * sin_t], axis=1)


class DomeLight:
    """All dome lights as structure-of-arrays.

    rot: (count, 3, 3) local-to-world rotation; L: (count, 3) radiance multiplier (nits);
    tex: (count,) int64 image index or -1 (constant dome).
    """

    name = "dome"
    infinite = True

    def __init__(self, paths, rot, L, tex, images: ImageSet, scene_center, scene_radius, irradiance=None):
        self.paths = list(paths)
        self.count = len(self.paths)
        self.rot = rot
        self.L = L
        self.tex = tex
        self.images = images
        self.delta = np.zeros(self.count, dtype=bool)
        self.scene_center = np.asarray(scene_center, dtype=np.float64).reshape(3)
        self.scene_radius = float(scene_radius)
        self.warnings: list[str] = []
        # Per light: renderer.preconvolve.IrradianceTable of its texture (None for constant domes).
        self.irradiance = list(irradiance) if irradiance is not None else [None] * self.count
        # Integral of the texture over the sphere (RGB), per light.
        integ = np.tile(np.full(3, 4.0 * np.pi), (self.count, 1))
        for i in np.nonzero(tex >= 0)[0]:
            j = tex[i]
            h, w = int(images.height[j]), int(images.width[j])
            o = int(images.offset[j])
            texels = images.texels[o : o + h * w].reshape(h, w, 3)
            integ[i] = np.einsum("hwc,h->c", texels, latlong_texel_solid_angles(h, w))
        self.radiance_integral = integ * L  # (count, 3): integral of Le over the sphere

    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """Domes have no area (normalize is ignored); returns 1."""
        return 1.0

    @staticmethod
    def load_latlong(desc: LightDesc) -> np.ndarray:
        """Read and check the dome's lat-long texture -> (H, W, 3)."""
        fmt = desc.texture_format or "automatic"
        if fmt not in ("automatic", "latlong"):
            raise StageError(
                f"DomeLight texture:format '{fmt}' is not supported (use 'latlong' or 'automatic' "
                f"with a 2:1 lat-long image)",
                prim=desc.path,
                attribute="inputs:texture:format",
            )
        img = load_texture_rgb(desc.texture_file, desc.path, data=desc.texture_data)
        h, w = img.shape[:2]
        if fmt == "automatic" and w != 2 * h:
            raise StageError(
                f"cannot infer the layout of '{desc.texture_file}' ({w}x{h}): texture:format "
                f"'automatic' needs a 2:1 lat-long image; author texture:format = 'latlong'",
                prim=desc.path,
                attribute="inputs:texture:file",
            )
        return img

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=(0.0, 0.0, 0.0), scene_radius: float = 1.0) -> "DomeLight":
        k = len(descs)
        rot = np.tile(np.eye(3), (k, 1, 1))
        L = np.zeros((k, 3))
        tex = np.full(k, -1, dtype=np.int64)
        images, weights = [], []
        tables, warnings = [None] * k, []
        for i, d in enumerate(descs):
            rot[i] = polar_decomposition_rotation(linear_part(d.light_to_world))
            L[i] = emitted_radiance(d, 1.0)
            if d.texture_file:
                img = cls.load_latlong(d)
                h, w = img.shape[:2]
                tex[i] = len(images)
                images.append(img)
                weights.append(luminance(img) * latlong_texel_solid_angles(h, w)[:, None])
                tables[i], warns = cls._irradiance_table(d, img)
                warnings.extend(warns)
        obj = cls([d.path for d in descs], rot, L, tex, ImageSet.build(images, weights), scene_center, scene_radius,
                  irradiance=tables)
        obj.warnings.extend(warnings)
        obj._set_portals(descs)
        return obj

    # ----------------------------------------------------------------------------------
    # Portals
    # ----------------------------------------------------------------------------------
    def _set_portals(self, descs: list[LightDesc]) -> None:
        """Portal tables from each dome's ``portals`` frames (see the module docstring).

        portal_start, portal_count: (count,) int64 ranges into the (P, ...) tables:
        portal_center (P, 3), portal_ex, portal_ey (P, 3) full edge vectors (orthogonal),
        portal_frame (P, 3, 3) rows x, y (unit, along ex, ey) and z (unit, out of the room: the
        opposite of the PortalLight's transmit direction -Z), portal_half (P, 2) half width and
        height; portal_table (P,) index into portal_f / portal_sat / portal_col (the windowed
        luminance tables of lights/portal.py, textured domes only) or -1. has_portals (count,).
        """
        centers, exs, eys, frames_out, counts, tables, table_of, warns = [], [], [], [], [], [], [], []
        for i, d in enumerate(descs):
            frames = np.zeros((0, 4, 4)) if d.portals is None else np.asarray(d.portals, dtype=np.float64)
            names = list(d.portal_paths) + [""] * max(0, len(frames) - len(d.portal_paths))
            kept = 0
            for m, name in zip(frames.reshape(-1, 4, 4), names):
                m3 = m[:3, :3]
                ex, ey = m3[:, 0].copy(), m3[:, 1].copy()
                lx, ly = float(np.linalg.norm(ex)), float(np.linalg.norm(ey))
                label = name or "a portal"
                if not (lx > 0.0 and ly > 0.0) or not np.all(np.isfinite(m)):
                    warns.append(f"{d.path}: portal {label} has zero width or height; it is ignored")
                    continue
                if abs(float(ex @ ey)) > SHAPE_RTOL * 1e3 * lx * ly:
                    warns.append(f"{d.path}: portal {label} is sheared (not a rectangle); it is ignored")
                    continue
                n_in = emission_normal(ex, ey, m3)  # world image of local -Z: into the room
                x, y, z = ex / lx, ey / ly, -n_in
                centers.append(m[:3, 3].copy())
                exs.append(ex)
                eys.append(ey)
                frames_out.append(np.stack([x, y, z]))
                if self.tex[i] >= 0:
                    table_of.append(len(tables))
                    tables.append(portal_tables.build_table(
                        frames_out[-1], lambda w, i=i: self.le_escaped(np.full(w.shape[0], i, dtype=np.int64), w)))
                else:
                    table_of.append(-1)
                kept += 1
            counts.append(kept)
        self.portal_count = np.asarray(counts, dtype=np.int64).reshape(self.count)
        self.portal_start = (np.cumsum(self.portal_count) - self.portal_count).astype(np.int64)
        self.portal_center = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        self.portal_ex = np.asarray(exs, dtype=np.float64).reshape(-1, 3)
        self.portal_ey = np.asarray(eys, dtype=np.float64).reshape(-1, 3)
        self.portal_frame = np.asarray(frames_out, dtype=np.float64).reshape(-1, 3, 3)
        self.portal_n = -self.portal_frame[:, 2] if len(frames_out) else np.zeros((0, 3))
        self.portal_half = 0.5 * np.stack([np.linalg.norm(self.portal_ex, axis=1),
                                           np.linalg.norm(self.portal_ey, axis=1)], axis=1)
        self.portal_table = np.asarray(table_of, dtype=np.int64)
        n_tab = portal_tables.N_CELLS
        self.portal_f = np.asarray(tables, dtype=np.float64).reshape(-1, n_tab, n_tab)
        sats, cols = zip(*(portal_tables.prefix_tables(f) for f in self.portal_f)) if tables else ((), ())
        self.portal_sat = np.asarray(sats, dtype=np.float64).reshape(-1, n_tab + 1, n_tab + 1)
        self.portal_col = np.asarray(cols, dtype=np.float64).reshape(-1, n_tab, n_tab + 1)
        self.has_portals = self.portal_count > 0
        # Share of the samples drawn through the portals: all of them for a constant dome (every
        # visible direction has the same radiance), TEXTURED_PORTAL_FRACTION for a textured one
        # (the rest: the dome's texel sampling, which also keeps the support complete).
        self.portal_fraction = np.where(self.tex >= 0, TEXTURED_PORTAL_FRACTION, 1.0)
        self.warnings.extend(warns)

    def portal_record(self) -> tuple:
        """The portals as the compiled rows read them (renderer/kernels/portal.py): (PP (P, NPP)
        a row per portal, columns PP_*; PT (3 T, N + 1, N + 1) the windowed tables, f, sat and
        col of table t at 3 t, 3 t + 1 and 3 t + 2). Dome j's portals are rows portal_start[j]
        .. + portal_count[j]."""
        if getattr(self, "_portal_record", None) is None:
            P = self.portal_center.shape[0]
            PP = np.zeros((P, portal_kernels.NPP))
            PP[:, portal_kernels.PP_C:portal_kernels.PP_C + 3] = self.portal_center
            PP[:, portal_kernels.PP_EX:portal_kernels.PP_EX + 3] = self.portal_ex
            PP[:, portal_kernels.PP_EY:portal_kernels.PP_EY + 3] = self.portal_ey
            PP[:, portal_kernels.PP_FR:portal_kernels.PP_FR + 9] = self.portal_frame.reshape(P, 9)
            PP[:, portal_kernels.PP_HALF:portal_kernels.PP_HALF + 2] = self.portal_half
            PP[:, portal_kernels.PP_TABLE] = self.portal_table
            PP[:, portal_kernels.PP_FRACTION] = np.repeat(self.portal_fraction, self.portal_count)
            n = portal_tables.N_CELLS
            PT = np.zeros((3 * self.portal_f.shape[0], n + 1, n + 1))
            PT[0::3, :n, :n] = self.portal_f
            PT[1::3] = self.portal_sat
            PT[2::3, :n, :] = self.portal_col
            self._portal_record = (np.ascontiguousarray(PP), np.ascontiguousarray(PT))
        return self._portal_record

    def _portal_sample(self, i: np.ndarray, p: np.ndarray, u: np.ndarray):
        """(wi (m, 3), pdf (m,), L (m, 3)) of domes i (m,) with portals from p (m, 3) with u (m, 2):
        the compiled rows (kernels/portal.py portal_dome_sample_row)."""
        m = i.size
        wi, pdf, kt = np.empty((m, 3)), np.empty(m), np.empty(m, dtype=np.int64)
        _tx, off, h, w, wt, tot, rc, rcs, cc, ccs = self.images.kernel_record()
        portal_kernels.portal_dome_sample_kernel(
            np.ascontiguousarray(i, dtype=np.int64), np.ascontiguousarray(p, dtype=np.float64),
            np.ascontiguousarray(u, dtype=np.float64), *self.portal_record(), self.portal_start, self.portal_count,
            self.tex, np.ascontiguousarray(self.rot, dtype=np.float64), h, w, rc, rcs, cc, ccs, wt, tot, off,
            MIN_SOLID_ANGLE,
            GRAZING_NZ2, wi, pdf, kt)
        L = self.L[i].copy()
        tex = kt >= 0
        L[tex] *= self.images.texels[kt[tex]]
        return wi, pdf, np.where((pdf > 0.0)[:, None], L, 0.0)

    def _portal_pdf(self, i: np.ndarray, p: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """pdf_li (m,) of domes i (m,) with portals from p along wi (m, 3) (portal_dome_pdf_row)."""
        pdf = np.empty(i.size)
        _tx, off, h, w, wt, tot = self.images.kernel_record()[:6]
        portal_kernels.portal_dome_pdf_kernel(
            np.ascontiguousarray(i, dtype=np.int64), np.ascontiguousarray(p, dtype=np.float64),
            np.ascontiguousarray(wi, dtype=np.float64), *self.portal_record(), self.portal_start, self.portal_count,
            self.tex, np.ascontiguousarray(self.rot, dtype=np.float64), h, w, wt, tot, off, MIN_SOLID_ANGLE,
            GRAZING_NZ2, pdf)
        return pdf

    @staticmethod
    def _irradiance_table(desc: LightDesc, img: np.ndarray):
        """(IrradianceTable, warnings) for a textured dome: the authored illum:dome:irradiance
        when fresh, else computed from these very texels (cached on disk by content hash)."""
        from renderer.preconvolve import dome_irradiance_table

        return dome_irradiance_table(desc.texture_file, img, desc.estimator.dome_irradiance, prim=desc.path,
                                    texture_data=desc.texture_data)

    # ----------------------------------------------------------------------------------
    def _to_local(self, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.einsum("nji,nj->ni", self.rot[idx], w)  # R^T w

    def _to_world(self, idx: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.einsum("nij,nj->ni", self.rot[idx], v)

    def _texel_of(self, idx: np.ndarray, w_world: np.ndarray):
        img = np.maximum(self.tex[idx], 0)
        h = self.images.height[img]
        wd = self.images.width[img]
        row, col = direction_to_texel(self._to_local(idx, w_world), h, wd)
        return img, row, col, h, wd

    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Texel-luminance importance sampling (textured) or uniform sphere (constant), or through
        the portals where the dome has portals that face p (see the module docstring). u (n, 2)."""
        idx = np.asarray(idx, dtype=np.int64)
        n_rows = idx.size
        if n_rows == 0:
            return invalid_sample(0)
        portal_rows = np.nonzero(self.has_portals[idx])[0] if self.count else np.zeros(0, np.int64)
        if not portal_rows.size:
            return self._sample_dome(idx, ctx, u)
        s = self._sample_dome(idx, ctx, u)
        wi, pdf, L = s.wi.copy(), s.pdf.copy(), s.L.copy()
        wi[portal_rows], pdf[portal_rows], L[portal_rows] = self._portal_sample(
            idx[portal_rows], ctx.p[portal_rows], np.asarray(u, dtype=np.float64)[portal_rows])
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=s.dist, p_light=ctx.p + wi * far_distance(
            ctx.p, self.scene_center, self.scene_radius)[:, None])

    def _sample_dome(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """The dome's own sampling: texel importance (textured) or the uniform sphere."""
        n_rows = idx.size
        wi = sample_uniform_sphere(u)
        pdf = np.full(n_rows, INV_4PI)
        L = self.L[idx].copy()
        textured = self.tex[idx] >= 0
        if textured.any():
            rows = np.nonzero(textured)[0]
            i = idx[rows]
            img = self.tex[i]
            r, c, s, t, pmf = self.images.sample(img, u[rows])
            h = self.images.height[img]
            w = self.images.width[img]
            z_top = np.cos(np.pi * r / h)
            z_bot = np.cos(np.pi * (r + 1) / h)
            cos_t = z_top + t * (z_bot - z_top)
            d_local = texel_to_direction((c + s) / w, cos_t)
            wi[rows] = self._to_world(i, d_local)
            omega = (2.0 * np.pi / w) * (z_top - z_bot)
            pdf[rows] = np.divide(pmf, omega, out=np.zeros(rows.size), where=omega > 0.0)
            L[rows] *= self.images.lookup(img, r, c)
        far = far_distance(ctx.p, self.scene_center, self.scene_radius)
        L = np.where((pdf > 0.0)[:, None], L, 0.0)
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=np.full(n_rows, np.inf), p_light=ctx.p + wi * far[:, None])

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (n,) of sample_li producing wi."""
        idx = np.asarray(idx, dtype=np.int64)
        pdf = self._pdf_dome(idx, wi)
        portal_rows = np.nonzero(self.has_portals[idx])[0] if self.count else np.zeros(0, np.int64)
        if portal_rows.size:
            pdf[portal_rows] = self._portal_pdf(idx[portal_rows], ctx.p[portal_rows], wi[portal_rows])
        return pdf

    def _pdf_dome(self, idx: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (n,) of the dome's own sampling (no portals)."""
        pdf = np.full(idx.size, INV_4PI)
        textured = self.tex[idx] >= 0
        if textured.any():
            rows = np.nonzero(textured)[0]
            i = idx[rows]
            img, r, c, h, w = self._texel_of(i, wi[rows])
            omega = (2.0 * np.pi / w) * (np.cos(np.pi * r / h) - np.cos(np.pi * (r + 1) / h))
            pdf[rows] = np.divide(self.images.pmf(img, r, c), omega, out=np.zeros(rows.size), where=omega > 0.0)
        return pdf

    def le_escaped(self, idx: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Radiance (n, 3) arriving along -d for rays of direction d escaping the scene."""
        idx = np.asarray(idx, dtype=np.int64)
        L = self.L[idx].copy()
        textured = self.tex[idx] >= 0
        if textured.any():
            rows = np.nonzero(textured)[0]
            img, r, c, _, _ = self._texel_of(idx[rows], d[rows])
            L[rows] *= self.images.lookup(img, r, c)
        return L

    def irradiance_lookup(self, idx: np.ndarray, n_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unshadowed irradiance from textured domes: (E (m, 3), ok (m,) bool).

        idx (m,) local light indices, n_world (m, 3) unit shading normals (world). E = L · T(R^T n)
        with T the light's IrradianceTable (exact E = Σ_t texel_t ∫_t max(0, n·ω) dω at the
        table's texel centres, interpolated in between; see renderer/preconvolve.py) and L the
        radiance multiplier (intensity, exposure, colour). ok is False for constant domes
        (irradiance.py handles them: E = π L) and True wherever a table exists.
        """
        idx = np.asarray(idx, dtype=np.int64)
        E = np.zeros((idx.size, 3))
        ok = np.zeros(idx.size, dtype=bool)
        for i in np.unique(idx):
            table = self.irradiance[i]
            if table is None:
                continue
            rows = np.nonzero(idx == i)[0]
            n_local = np.asarray(n_world[rows], dtype=np.float64) @ self.rot[i]  # R^T n, row vectors
            E[rows] = table.lookup(n_local) * self.L[i]
            ok[rows] = True
        return E, ok

    def phi(self) -> np.ndarray:
        """(count,) pi R^2 * lum(integral of Le over the sphere), R the scene radius."""
        return np.pi * self.scene_radius**2 * luminance(self.radiance_integral)
