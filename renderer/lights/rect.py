"""UsdLuxRectLight: a one-sided emitting rectangle (parallelogram under shear).

Geometry: centred in the local XY plane, ``width`` along local X, ``height`` along local Y,
emitting along local -Z only. The world shape is c + a * ex + b * ey with a, b in [-1/2, 1/2],
where ex, ey are the transformed edge vectors (any affine transform; a shear makes a
parallelogram). The emitting side is the world image of local -Z as a *normal* (cofactor
transform), so mirrored transforms keep emitting toward the image of the -Z half-space.
Seen from behind (or from within its plane) the light gives L = 0 and sample_li fails (pdf 0).

Sampling (decided from the (light, point) pair only, so pdf_li always matches):
* textured rect: texel luminance importance sampling (``Distribution``-style, area measure,
  converted to solid angle: pdf_w = pmf * H * W / A * d^2 / |cos theta_l|);
* untextured rectangle with solid angle >= 1e-4 sr and not grazing: uniform spherical-rectangle
  sampling, pdf_w = 1 / Omega (see ``spherical_rect``);
* otherwise (tiny, grazing, or sheared): uniform area sampling, pdf_w = d^2 / (A |cos theta_l|).

Implementation: sample_li, pdf_li, intersect and the textured radiance run as fused numba
kernels (``renderer.kernels.lights``): one pass per row gathers the light, chooses the strategy
and samples from a single spherical-rectangle setup; textured rows pick their texel and take its
colour by the same kernels' rect_texel_* rows, which the compiled path's vertex kernel calls too.

Texture orientation: the UsdLux doc puts the "texture min coordinates at (+X, +Y), max at
(-X, -Y)". illum reads "min coordinates" as uv = (0, 0), with uv in the OpenGL convention
(v up: v = 0 is the *bottom* row of the image, OIIO row H-1). So

    local x = width * (1/2 - u),   local y = height * (1/2 - v),
    image column = floor(u * W),    image row (0 = top) = floor((1 - v) * H)

i.e. the image's bottom-left texel sits at the (+X, +Y) corner and its top-right texel at
(-X, -Y). (hdEmbree instead puts the top-left texel at (-X, +Y): the same picture rotated by
180 degrees in the light's plane.) Lookup is nearest-texel, which makes the texel sampling pdf
exactly proportional to the texel luminance.
"""

from __future__ import annotations

import numpy as np

from renderer.color import luminance
from renderer.description import LightDesc
from renderer.kernels import lights as kern
from renderer.lights._common import (
    SHAPE_RTOL,
    as_points,
    dot,
    emission_normal,
    invalid_sample,
    linear_part,
    translation,
)
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.spherical_rect import GRAZING_NZ2, MIN_SOLID_ANGLE
from renderer.lights.radiometry import emitted_radiance
from renderer.lights.texture import ImageSet, load_texture_rgb


def rect_edges(desc: LightDesc) -> tuple[np.ndarray, np.ndarray]:
    """World edge vectors (ex, ey) (3,) each: the images of (width, 0, 0) and (0, height, 0)."""
    m3 = linear_part(desc.light_to_world)
    return m3 @ np.array([float(desc.width), 0.0, 0.0]), m3 @ np.array([0.0, float(desc.height), 0.0])


class RectLight:
    """All rect lights of a scene as structure-of-arrays.

    center, ex, ey, n: (count, 3) world centre, edge vectors and emitting normal (unit);
    ex_dual, ey_dual: (count, 3) with (p - center) . ex_dual = a (the ex coordinate);
    x_hat, y_hat: (count, 3) ex, ey as unit vectors, edge_len: (count, 2) their lengths;
    area: (count,) world area |ex x ey|; L: (count, 3) emitted radiance (nits, Rec.709);
    is_rectangle: (count,) bool (False when sheared); tex: (count,) int64 image index or -1.
    """

    name = "rect"
    infinite = False

    def __init__(self, paths, center, ex, ey, n, L, tex, images: ImageSet):
        self.paths = list(paths)
        self.count = len(self.paths)
        # C-contiguous float64 / int64 / bool: the kernels index these tables directly.
        self.center = as_points(center)
        self.ex = as_points(ex)
        self.ey = as_points(ey)
        self.n = as_points(n)
        self.L = as_points(L)
        self.tex = np.ascontiguousarray(tex, dtype=np.int64)
        self.images = images
        ex, ey = self.ex, self.ey
        self.area = np.linalg.norm(np.cross(ex, ey), axis=1) if self.count else np.zeros(0)
        gxx = np.einsum("ij,ij->i", ex, ex)
        gyy = np.einsum("ij,ij->i", ey, ey)
        gxy = np.einsum("ij,ij->i", ex, ey)
        det = gxx * gyy - gxy * gxy
        det = np.where(det > 0.0, det, 1.0)
        self.ex_dual = (gyy[:, None] * ex - gxy[:, None] * ey) / det[:, None]
        self.ey_dual = (gxx[:, None] * ey - gxy[:, None] * ex) / det[:, None]
        self.is_rectangle = np.ascontiguousarray(np.abs(gxy) <= SHAPE_RTOL * np.sqrt(gxx * gyy))
        # The spherical-rectangle frame, once per light instead of once per kernel row.
        self.edge_len = as_points(np.stack([np.sqrt(gxx), np.sqrt(gyy)], axis=1), 2)
        safe = np.where(self.edge_len > 0.0, self.edge_len, 1.0)
        self.x_hat = as_points(ex / safe[:, :1])
        self.y_hat = as_points(ey / safe[:, 1:])
        self.delta = np.zeros(self.count, dtype=bool)
        self.warnings: list[str] = []

    # ----------------------------------------------------------------------------------
    # Build
    # ----------------------------------------------------------------------------------
    @staticmethod
    def world_area(desc: LightDesc) -> float:
        """World-space area |ex x ey| (scene units^2), including the transform's scale/shear."""
        ex, ey = rect_edges(desc)
        return float(np.linalg.norm(np.cross(ex, ey)))

    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=None, scene_radius: float = 1.0) -> "RectLight":
        k = len(descs)
        center = np.zeros((k, 3))
        ex = np.zeros((k, 3))
        ey = np.zeros((k, 3))
        n = np.zeros((k, 3))
        L = np.zeros((k, 3))
        tex = np.full(k, -1, dtype=np.int64)
        images, weights = [], []
        for i, d in enumerate(descs):
            center[i] = translation(d.light_to_world)
            ex[i], ey[i] = rect_edges(d)
            n[i] = emission_normal(ex[i], ey[i], linear_part(d.light_to_world))
            L[i] = emitted_radiance(d, cls.world_area(d))
            if d.texture_file:
                img = load_texture_rgb(d.texture_file, d.path, data=d.texture_data)
                tex[i] = len(images)
                images.append(img)
                weights.append(luminance(img))
        return cls([d.path for d in descs], center, ex, ey, n, L, tex, ImageSet.build(images, weights))

    # ----------------------------------------------------------------------------------
    # Geometry helpers
    # ----------------------------------------------------------------------------------
    def _ab(self, idx: np.ndarray, q: np.ndarray) -> np.ndarray:
        rel = q - self.center[idx]
        return np.stack([dot(rel, self.ex_dual[idx]), dot(rel, self.ey_dual[idx])], axis=1)

    def _radiance_at(self, idx: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Front-side radiance (n, 3) at world points q on the light (texture applied:
        kernels/lights.py rect_radiance_row)."""
        L = np.empty((idx.size, 3))
        kern.rect_radiance_kernel(np.ascontiguousarray(idx, dtype=np.int64), as_points(q), self.center,
                                  self.ex_dual, self.ey_dual, self.L, self.tex, self.images.kernel_record(), L)
        return L

    # ----------------------------------------------------------------------------------
    # LightKind protocol
    # ----------------------------------------------------------------------------------
    def sample_li(self, idx: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Sample a point on light idx (n,) seen from ctx.p; u (n, 2). Fails (pdf 0) from behind."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n_rows = idx.size
        if n_rows == 0:
            return invalid_sample(0)
        p = as_points(ctx.p)
        u = as_points(u, 2)
        L = np.empty((n_rows, 3))
        wi = np.empty((n_rows, 3))
        pdf = np.empty(n_rows)
        dist = np.empty(n_rows)
        p_l = np.empty((n_rows, 3))
        kern.rect_sample_kernel(
            idx, p, u, self.center, self.ex, self.ey, self.x_hat, self.y_hat, self.edge_len, self.n, self.area,
            self.L, self.tex, self.is_rectangle, self.ex_dual, self.ey_dual, self.images.kernel_record(),
            MIN_SOLID_ANGLE, GRAZING_NZ2, L, wi, pdf, dist, p_l,
        )
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_l)

    def pdf_li(self, idx: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """Solid-angle pdf (n,) of sample_li(idx, ctx) producing wi; 0 if wi misses the front."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        n_rows = idx.size
        if n_rows == 0:
            return np.zeros(0)
        p = as_points(ctx.p)
        wi = as_points(wi)
        pdf = np.empty(n_rows)
        kern.rect_pdf_kernel(
            idx, p, wi, self.center, self.ex, self.ey, self.x_hat, self.y_hat, self.edge_len, self.n, self.area,
            self.ex_dual, self.ey_dual, self.tex, self.is_rectangle, self.images.kernel_record(), MIN_SOLID_ANGLE,
            GRAZING_NZ2, pdf,
        )
        return pdf

    def _hit(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray, with_ab: bool = False):
        """(t (n,) hit distance or inf, (a, b) (n, 2) plane-hit edge coordinates if with_ab)."""
        t = np.empty(idx.size)
        ab = np.empty((idx.size if with_ab else 0, 2))
        kern.rect_hit_kernel(
            idx, as_points(o), as_points(d), self.center, self.n, self.ex_dual, self.ey_dual, t, ab
        )
        return t, (ab if with_ab else None)

    def intersect(self, idx: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Hit distance (n,) of rays o + t d with the (two-sided) shape, inf where none."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0)
        return self._hit(idx, o, d)[0]

    def le(self, idx: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """Radiance (n, 3) leaving p_light toward -wi: L (times texture) on the front, 0 behind."""
        idx = np.asarray(idx, dtype=np.int64)
        if idx.size == 0:
            return np.zeros((0, 3))
        front = -dot(wi, self.n[idx]) > 0.0
        return np.where(front[:, None], self._radiance_at(idx, p_light), 0.0)

    def phi(self) -> np.ndarray:
        """(count,) luminance power pi * A * lum(L * mean texture) (one-sided Lambertian)."""
        rgb = self.L.copy()
        t = self.tex >= 0
        if t.any():
            rgb[t] *= self.images.mean_rgb[self.tex[t]]
        return np.pi * self.area * luminance(rgb)

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """The exact two triangles of each parallelogram: ((2 count, 3, 3), owner (2 count,))."""
        c, hx, hy = self.center, 0.5 * self.ex, 0.5 * self.ey
        p00, p10, p11, p01 = c - hx - hy, c + hx - hy, c + hx + hy, c - hx + hy
        tris = np.stack([np.stack([p00, p10, p11], axis=1), np.stack([p00, p11, p01], axis=1)], axis=1)
        owner = np.repeat(np.arange(self.count, dtype=np.int64), 2)
        return tris.reshape(-1, 3, 3), owner
