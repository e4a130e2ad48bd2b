"""Camera rays from a CameraDesc: perspective/orthographic, aperture offsets, conform policy,
thin-lens depth of field, and the sample offset within a pixel (drawn from the pixel filter for
filter importance sampling, uniform for a splatting film: renderer/pixel_filter.py).

Screen space: the film window in camera space at unit distance (perspective) or in scene units
(orthographic) is ``[wx0, wx1] x [wy0, wy1]``, matching ``Gf.Camera.frustum.window`` (tests check
this against pxr). Pixel (x, y) has its top-left corner at raster (x, y), raster y grows down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .description import CameraDesc
from .errors import SettingsError
from .geometry import normalize
from .kernels import NoAliasCompiler
from .pixel_filter import PixelFilter
from .sampling import sample_uniform_disk_concentric

MAX_SIDE = 16384
MAX_PIXELS = 64 * 1024 * 1024


def check_resolution(width: int, height: int, source: str = "resolution") -> None:
    """Reject absurd resolutions before any memory is allocated."""
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))):
        raise SettingsError(f"resolution must be integers, got {width!r} x {height!r}", attribute=source)
    if width <= 0 or height <= 0:
        raise SettingsError(f"resolution {width}x{height} must be positive", attribute=source)
    if width > MAX_SIDE or height > MAX_SIDE:
        raise SettingsError(f"resolution {width}x{height} exceeds {MAX_SIDE} pixels per side", attribute=source)
    if width * height > MAX_PIXELS:
        raise SettingsError(
            f"resolution {width}x{height} = {width * height / 1e6:.1f} Mpixel exceeds 64 Mpixel", attribute=source
        )


def _raster_index(p) -> np.ndarray:
    """Pixel coordinates (n,) as the kernel takes them: int64, or float64 if given as floats."""
    p = np.asarray(p)
    if p.dtype.kind in "iub":
        return np.ascontiguousarray(p, dtype=np.int64)
    return np.ascontiguousarray(p, dtype=np.float64)


@dataclass(frozen=True)
class CameraRays:
    o: np.ndarray  # (n, 3)
    d: np.ndarray  # (n, 3) unit
    tmax: np.ndarray  # (n,) far clip distance along d
    tmin: np.ndarray  # (n,) near clip distance along d

    def at_near_plane(self) -> tuple[np.ndarray, np.ndarray]:
        """(o + tmin d (n, 3), tmax - tmin (n,)): the rays started at the near clip plane, as
        the integrators trace them. One compiled pass (numpy's took three temporaries, ~2% of a
        fast-path render); the same operations, so the same values."""
        o = np.empty_like(self.o)
        t = np.empty_like(self.tmax)
        _near_plane_kernel(self.o, self.d, self.tmin, self.tmax, o, t)
        return o, t


@njit(cache=True, nogil=True)
def _near_plane_kernel(o, d, tmin, tmax, o_out, t_out):
    """CameraRays.at_near_plane for n rows."""
    for i in range(o.shape[0]):
        for c in range(3):
            o_out[i, c] = o[i, c] + d[i, c] * tmin[i]
        t_out[i] = tmax[i] - tmin[i]


# --------------------------------------------------------------------------------------
# Kernel (conventions: renderer/kernels/__init__.py). Camera._generate_numpy is the same
# computation in numpy, kept as the reference the kernel is tested against; every formula
# below is written in the same operation order so the two agree to rounding.
# --------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _filter_offset(inv, u):
    """PixelFilter.sample for one coordinate: lerp in the tabulated inverse CDF inv."""
    k = inv.shape[0] - 1
    # Clamped to [0, 1] like np.clip; NaN goes to 0 rather than to an out-of-bounds index.
    if not u >= 0.0:
        u = 0.0
    elif u > 1.0:
        u = 1.0
    f = u * k
    i = int(f)
    if i > k - 1:
        i = k - 1
    lo = inv[i]
    return lo + (f - i) * (inv[i + 1] - lo)


@njit(cache=True, nogil=True, inline="always")
def _pinhole_dir(sx, sy):
    """The pinhole direction through window point (sx, sy): (sx, sy, -1) normalised."""
    length = math.sqrt(sx * sx + sy * sy + 1.0)
    s = length if length > 0.0 else 1.0
    return sx / s, sy / s, -1.0 / s


@njit(cache=True, nogil=True, inline="always")
def _clip_per_t(dz):
    """1 / cos of the view axis angle (-dz, at least 1e-12): the clip planes are perpendicular to
    the view axis, so a clip distance z is z times this along d."""
    c = -dz
    if c < 1e-12:
        c = 1e-12
    return 1.0 / c


@njit(cache=True, nogil=True, inline="always")
def _unit_and_scale(dwx, dwy, dwz):
    """A camera_to_world-transformed direction as a unit vector and its length (world scale in
    the matrix rescales the clip distances by it)."""
    scale = math.sqrt(dwx * dwx + dwy * dwy + dwz * dwz)
    return dwx / scale, dwy / scale, dwz / scale, scale


@njit(cache=True, nogil=True)
def _generate_kernel(px, py, u_filter, u_lens, inv, window, width, height, orthographic, lens_radius,
                     focus_distance, near, far, planes, M, o, d, tmin, tmax):
    """Camera.generate for rows of (px, py) (n,), u_filter, u_lens (n, 2): writes o, d (n, 3),
    tmin, tmax (n,). window (4,) = (wx0, wx1, wy0, wy1); planes (K, 4) camera-space clipping
    planes (K may be 0); M (4, 4) camera_to_world."""
    wx0 = window[0]
    wx1 = window[1]
    wy0 = window[2]
    wy1 = window[3]
    for i in range(px.shape[0]):
        rx = px[i] + 0.5 + _filter_offset(inv, u_filter[i, 0])
        ry = py[i] + 0.5 + _filter_offset(inv, u_filter[i, 1])
        sx = wx0 + (rx / width) * (wx1 - wx0)
        sy = wy1 - (ry / height) * (wy1 - wy0)
        if orthographic:
            ox = sx
            oy = sy
            oz = 0.0
            dx = 0.0
            dy = 0.0
            dz = -1.0
            t0 = near
            t1 = far
        else:
            dx, dy, dz = _pinhole_dir(sx, sy)
            ox = 0.0
            oy = 0.0
            oz = 0.0
            if lens_radius > 0.0:
                # Thin lens: a concentric-disk point on the lens (sampling.sample_uniform_disk_concentric),
                # aimed at where the pinhole ray meets the focus plane.
                a = 2.0 * u_lens[i, 0] - 1.0
                b = 2.0 * u_lens[i, 1] - 1.0
                if abs(a) > abs(b):
                    r = a
                    theta = (math.pi / 4.0) * (b / a if a != 0.0 else 0.0)
                else:
                    r = b
                    theta = (math.pi / 2.0) - (math.pi / 4.0) * (a / b if b != 0.0 else 0.0)
                ox = lens_radius * (r * math.cos(theta))
                oy = lens_radius * (r * math.sin(theta))
                ft = focus_distance / -dz
                qx = dx * ft - ox
                qy = dy * ft - oy
                qz = dz * ft
                length = math.sqrt(qx * qx + qy * qy + qz * qz)
                s = length if length > 0.0 else 1.0
                dx = qx / s
                dy = qy / s
                dz = qz / s
            inv_cos = _clip_per_t(dz)
            t0 = near * inv_cos
            t1 = far * inv_cos
        # clippingPlanes (Camera._clip): each plane keeps a half-line of t.
        lo = -np.inf
        hi = np.inf
        for j in range(planes.shape[0]):
            n_dot_d = dx * planes[j, 0] + dy * planes[j, 1] + dz * planes[j, 2]
            f0 = ox * planes[j, 0] + oy * planes[j, 1] + oz * planes[j, 2] + planes[j, 3]
            if n_dot_d > 0.0:
                t_cross = -f0 / n_dot_d
                if t_cross > lo:
                    lo = t_cross
            elif n_dot_d < 0.0:
                t_cross = -f0 / n_dot_d
                if t_cross < hi:
                    hi = t_cross
            elif n_dot_d == 0.0 and f0 < 0.0:
                hi = -np.inf  # parallel and outside
        if planes.shape[0] > 0:
            if lo > t0:
                t0 = lo
            if hi < t1:
                t1 = hi
            if t0 > t1:
                t1 = t0
        # camera_to_world; world scale in the matrix rescales the clip distances.
        dwx = dx * M[0, 0] + dy * M[0, 1] + dz * M[0, 2]
        dwy = dx * M[1, 0] + dy * M[1, 1] + dz * M[1, 2]
        dwz = dx * M[2, 0] + dy * M[2, 1] + dz * M[2, 2]
        o[i, 0] = ox * M[0, 0] + oy * M[0, 1] + oz * M[0, 2] + M[0, 3]
        o[i, 1] = ox * M[1, 0] + oy * M[1, 1] + oz * M[1, 2] + M[1, 3]
        o[i, 2] = ox * M[2, 0] + oy * M[2, 1] + oz * M[2, 2] + M[2, 3]
        d[i, 0], d[i, 1], d[i, 2], scale = _unit_and_scale(dwx, dwy, dwz)
        tmin[i] = t0 * scale
        tmax[i] = t1 * scale


@njit(cache=True, nogil=True, error_model="numpy", pipeline_class=NoAliasCompiler)
def _generate_pinhole_kernel(px, py, u_filter, inv, window, width, height, near, far, M, o, d, tmin, tmax):
    """_generate_kernel for the common camera, perspective without a thin lens or clipping
    planes: the same operations (so bit-identical results) in a loop LLVM vectorises, with no
    inner loop or branches around work (the general kernel ran ~20 ns a ray, a few per cent of a
    fast-path render). u_filter (2 n,), o, d (3 n,) flat, row i at 2 i or 3 i: with a runtime
    row stride (a 2-D array's) LLVM either cannot rule out that one row's stores overlap the
    next's or vectorises on the guess that the stride is 1 and runs the scalar loop when it is
    not; the arrays noalias (NoAliasCompiler)."""
    wx0 = window[0]
    wx1 = window[1]
    wy0 = window[2]
    wy1 = window[3]
    for i in range(px.shape[0]):
        rx = px[i] + 0.5 + _filter_offset(inv, u_filter[2 * i])
        ry = py[i] + 0.5 + _filter_offset(inv, u_filter[2 * i + 1])
        sx = wx0 + (rx / width) * (wx1 - wx0)
        sy = wy1 - (ry / height) * (wy1 - wy0)
        dx, dy, dz = _pinhole_dir(sx, sy)
        inv_cos = _clip_per_t(dz)
        dwx = dx * M[0, 0] + dy * M[0, 1] + dz * M[0, 2]
        dwy = dx * M[1, 0] + dy * M[1, 1] + dz * M[1, 2]
        dwz = dx * M[2, 0] + dy * M[2, 1] + dz * M[2, 2]
        o[3 * i] = M[0, 3]
        o[3 * i + 1] = M[1, 3]
        o[3 * i + 2] = M[2, 3]
        d[3 * i], d[3 * i + 1], d[3 * i + 2], scale = _unit_and_scale(dwx, dwy, dwz)
        tmin[i] = (near * inv_cos) * scale
        tmax[i] = (far * inv_cos) * scale


class Camera:
    """Generates world-space rays for raster positions.

    width, height: the full image in pixels; pixel_aspect: pixel width / height.
    conform: UsdRender aspectRatioConformPolicy.
    sample_filter: the distribution of each ray's offset from its pixel centre: the pixel filter
    itself for filter importance sampling (default: the Gaussian, sigma 0.5 px), or
    pixel_filter.jitter() (uniform over the pixel) for a splatting film.
    """

    def __init__(self, desc: CameraDesc, width: int, height: int, pixel_aspect: float = 1.0,
                 conform: str = "expandAperture", sample_filter: PixelFilter | None = None):
        check_resolution(width, height)
        self.desc = desc
        self.width = width
        self.height = height
        self.camera_to_world = np.asarray(desc.camera_to_world, dtype=np.float64)
        ha, va = float(desc.horizontal_aperture), float(desc.vertical_aperture)
        image_aspect = width * pixel_aspect / height
        # Conform the aperture to the image aspect (CameraUtil's ConformWindow semantics).
        if conform in ("expandAperture", "cropAperture"):
            aperture_aspect = ha / va
            grow_width = (image_aspect > aperture_aspect) == (conform == "expandAperture")
            if grow_width:
                ha = va * image_aspect
            else:
                va = ha / image_aspect
        elif conform == "adjustApertureWidth":
            ha = va * image_aspect
        elif conform == "adjustApertureHeight":
            va = ha / image_aspect
        # adjustPixelAspectRatio keeps the aperture; pixels stretch instead.
        self.horizontal_aperture = ha
        self.vertical_aperture = va
        ho, vo = float(desc.horizontal_aperture_offset), float(desc.vertical_aperture_offset)
        if desc.projection == "orthographic":
            scale = 1.0
        else:
            scale = 1.0 / float(desc.focal_length)
        self.window = (
            (-0.5 * ha + ho) * scale,
            (0.5 * ha + ho) * scale,
            (-0.5 * va + vo) * scale,
            (0.5 * va + vo) * scale,
        )
        self.orthographic = desc.projection == "orthographic"
        self.near, self.far = float(desc.clipping_range[0]), float(desc.clipping_range[1])
        self.lens_radius = 0.0
        if desc.f_stop > 0.0 and desc.focus_distance > 0.0 and not self.orthographic:
            self.lens_radius = float(desc.focal_length) / (2.0 * float(desc.f_stop))
        self.focus_distance = float(desc.focus_distance)
        # (K, 4) UsdGeomCamera clippingPlanes (camera space), applied to camera rays
        self.clip_planes = np.asarray(getattr(desc, "clipping_planes", ()), dtype=np.float64).reshape(-1, 4)
        self.filter = sample_filter if sample_filter is not None else PixelFilter()

    def raster_to_camera(self, rx: np.ndarray, ry: np.ndarray) -> np.ndarray:
        """Raster coords (n,) -> points on the window plane in camera space (n, 3), z = -1 (perspective)."""
        wx0, wx1, wy0, wy1 = self.window
        sx = wx0 + (rx / self.width) * (wx1 - wx0)
        sy = wy1 - (ry / self.height) * (wy1 - wy0)
        return np.stack([sx, sy, -np.ones_like(sx)], axis=1)

    def generate(self, px: np.ndarray, py: np.ndarray, u_filter: np.ndarray, u_lens: np.ndarray) -> CameraRays:
        """Rays for pixels (px, py) (n,) int with filter and lens random numbers (n, 2) each.

        One compiled pass (_generate_kernel), clipping planes included; _generate_numpy is the
        same computation in numpy, the reference the kernel is tested against."""
        px, py = _raster_index(px), _raster_index(py)
        n = px.shape[0]
        o = np.empty((n, 3))
        d = np.empty((n, 3))
        tmin = np.empty(n)
        tmax = np.empty(n)
        u_filter = np.ascontiguousarray(u_filter, dtype=np.float64)
        M = np.ascontiguousarray(self.camera_to_world, dtype=np.float64)
        if not self.orthographic and not self.lens_radius > 0.0 and len(self.clip_planes) == 0:
            _generate_pinhole_kernel(px, py, u_filter.reshape(-1), self.filter._inv, np.array(self.window, dtype=np.float64),
                                     float(self.width), float(self.height), float(self.near), float(self.far), M,
                                     o.reshape(-1), d.reshape(-1), tmin, tmax)
            return CameraRays(o=o, d=d, tmax=tmax, tmin=tmin)
        _generate_kernel(px, py, np.ascontiguousarray(u_filter, dtype=np.float64),
                         np.ascontiguousarray(u_lens, dtype=np.float64), self.filter._inv,
                         np.array(self.window, dtype=np.float64), float(self.width), float(self.height),
                         bool(self.orthographic), float(self.lens_radius), float(self.focus_distance),
                         float(self.near), float(self.far), np.ascontiguousarray(self.clip_planes, dtype=np.float64),
                         np.ascontiguousarray(self.camera_to_world, dtype=np.float64), o, d, tmin, tmax)
        return CameraRays(o=o, d=d, tmax=tmax, tmin=tmin)

    def _generate_numpy(self, px: np.ndarray, py: np.ndarray, u_filter: np.ndarray, u_lens: np.ndarray) -> CameraRays:
        """generate in numpy: the reference for _generate_kernel (tests only)."""
        off = self.filter.sample(u_filter)
        rx = px + 0.5 + off[:, 0]
        ry = py + 0.5 + off[:, 1]
        q = self.raster_to_camera(rx, ry)
        n = q.shape[0]
        if self.orthographic:
            o_cam = np.stack([q[:, 0], q[:, 1], np.zeros(n)], axis=1)
            d_cam = np.tile(np.array([0.0, 0.0, -1.0]), (n, 1))
            tmin = np.full(n, self.near)
            tmax = np.full(n, self.far)
        else:
            d_cam = normalize(q)
            o_cam = np.zeros((n, 3))
            if self.lens_radius > 0.0:
                # Thin lens: every ray through the pinhole direction converges at the focus plane.
                lens = self.lens_radius * sample_uniform_disk_concentric(u_lens)
                ft = self.focus_distance / -d_cam[:, 2]
                p_focus = d_cam * ft[:, None]
                o_cam = np.stack([lens[:, 0], lens[:, 1], np.zeros(n)], axis=1)
                d_cam = normalize(p_focus - o_cam)
            # Clipping planes are perpendicular to the view axis: convert to distances along d.
            inv_cos = 1.0 / np.maximum(-d_cam[:, 2], 1e-12)
            tmin = self.near * inv_cos
            tmax = self.far * inv_cos
        if self.clip_planes.size:
            tmin, tmax = self._clip(o_cam, d_cam, tmin, tmax)
        M = self.camera_to_world
        # Column multiply-adds: much faster than (n,3) @ (3,3) on a transposed view for large n.
        d_w = d_cam[:, 0:1] * M[:3, 0] + d_cam[:, 1:2] * M[:3, 1] + d_cam[:, 2:3] * M[:3, 2]
        o = o_cam[:, 0:1] * M[:3, 0] + o_cam[:, 1:2] * M[:3, 1] + o_cam[:, 2:3] * M[:3, 2] + M[:3, 3]
        # World scale in the camera matrix changes distances: rescale the clip distances.
        scale = np.sqrt(np.einsum("ij,ij->i", d_w, d_w))
        d = d_w / scale[:, None]
        return CameraRays(o=o, d=d, tmax=tmax * scale, tmin=tmin * scale)

    def _clip(self, o_cam: np.ndarray, d_cam: np.ndarray, tmin: np.ndarray, tmax: np.ndarray):
        """Narrow each ray's camera-space interval [tmin, tmax] (n,) to the part every clipping
        plane keeps (a x + b y + c z + d >= 0 along o_cam + t d_cam, both (n, 3)). One plane
        keeps a half-line of t, so the kept set stays one interval; an empty one becomes
        tmax = tmin, a ray that sees no geometry (the background, as beyond the far plane)."""
        n_dot_d = d_cam @ self.clip_planes[:, :3].T  # (n, K)
        f0 = o_cam @ self.clip_planes[:, :3].T + self.clip_planes[:, 3]  # plane value at t = 0
        with np.errstate(divide="ignore", invalid="ignore"):
            t_cross = -f0 / n_dot_d
        lo = np.where(n_dot_d > 0.0, t_cross, -np.inf)
        hi = np.where(n_dot_d < 0.0, t_cross, np.inf)
        hi = np.where((n_dot_d == 0.0) & (f0 < 0.0), -np.inf, hi)  # parallel and outside
        tmin = np.maximum(tmin, lo.max(axis=1))
        tmax = np.minimum(tmax, hi.min(axis=1))
        return tmin, np.maximum(tmax, tmin)

    def world_to_camera(self) -> np.ndarray:
        return np.linalg.inv(self.camera_to_world)

    def projection_matrix(self) -> np.ndarray:
        """Camera space -> NDC-like screen space [-1,1]^2 (for EXR metadata 'worldToScreen')."""
        wx0, wx1, wy0, wy1 = self.window
        sx = 2.0 / (wx1 - wx0)
        sy = 2.0 / (wy1 - wy0)
        cx = -(wx1 + wx0) / (wx1 - wx0)
        cy = -(wy1 + wy0) / (wy1 - wy0)
        if self.orthographic:
            return np.array([[sx, 0, 0, cx], [0, sy, 0, cy], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)
        # Perspective: x_s = sx * x / -z + cx
        return np.array([[sx, 0, -cx, 0], [0, sy, -cy, 0], [0, 0, 0, 1], [0, 0, -1, 0]], dtype=np.float64)
