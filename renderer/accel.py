"""The one module that touches Embree: batched closest-hit and occlusion queries.

embree works in float32 with tnear fixed at 0, so this module (1) converts to float32 here and
nowhere else, (2) offers ``ray_epsilon`` so callers can push ray origins off surfaces by an
amount proportional to the coordinates' magnitude (a stage placed 1e4 units from the origin
needs a larger offset than one at the origin), and (3) splits large batches into chunks that run
on a thread pool: the tracing releases the GIL, so threads scale.

Two routes trace the same BVH build:
* native (the default): ctypes bindings to the Embree 4 library the embreex wheel ships
  (``embreex.libs/libembree4*.so.4``), called from numba ``nogil`` kernels through the functions'
  addresses. The batch calls trace packets of BATCH_WIDTH rays (rtcIntersect8 / rtcOccluded8);
  kernels elsewhere can trace single rays themselves with ``Accel.native_handles()``,
  ``set_ray`` and ``rtc_intersect1`` / ``rtc_occluded1``, or packets with
  ``Accel.packet_handles(width)`` and ``_intersect_rows`` / ``_occluded_rows`` (and report what
  they traced with ``Accel.count_traced``). Same BVH flags as embreex (robust), so
  the hits are identical; bench/bench_embree_native.py measures the routes on every stage
  (bench/results/embree_native/results.md).
* embreex's batch calls: the fallback when the native library cannot be loaded (one warning).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import threading
import warnings
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

# embreex reports a miss as tfar = 1e37 and primID = -1.
_EMBREE_INF = np.float32(1e37)
# Rays per embree call: large enough to amortise the Python call, small enough to keep
# both cores busy on a 256x256 batch.
CHUNK = 32768
# Relative float32 error budget for origin offsets: about 8 float32 ulps (2^-23 ~ 1.2e-7) of
# the coordinate magnitude, enough for embree's own intersection error. Larger offsets let
# shadow rays start past nearby occluders (the stress suite caught 2e-5 erasing shadows 1e5
# units from the origin).
_REL_EPS = 5.0e-7

# Set inside serial_tracing(): the calling thread is one of several that already trace in
# parallel, so a batch is traced in that thread instead of being split over the Accel's pool.
_SERIAL = threading.local()


@contextlib.contextmanager
def serial_tracing():
    """Trace every batch in the calling thread (no split over the Accel's own pool) while the
    block runs. For callers that parallelise over batches themselves (the integrator's chunks of
    pixels): splitting each batch again over the same cores made 2 threads no faster than 1 at
    128x128 (measured: 1.00x; 1.42x with this and 4096-pixel chunks)."""
    old = getattr(_SERIAL, "on", False)
    _SERIAL.on = True
    try:
        yield
    finally:
        _SERIAL.on = old


# ---- native Embree 4: the C API of the library the embreex wheel ships ---------------------
# RTCRayHit (rtcore_ray.h), in 4-byte words from the record's start. Single rays use one record
# (16-byte aligned); packets of W rays (rtcIntersect4/8/16) use the same fields as arrays of W
# lanes: field f of lane j is word f * W + j, and the record is aligned to 4 W bytes.
RAY_ORG = 0  # org_x, org_y, org_z
RAY_TNEAR = 3
RAY_DIR = 4  # dir_x, dir_y, dir_z
RAY_TIME = 7
RAY_TFAR = 8
RAY_MASK = 9
RAY_ID = 10
RAY_FLAGS = 11
RAY_WORDS = 12  # RTCRay: 48 bytes (what rtcOccluded* reads and writes)
HIT_NG = 12  # Ng_x, Ng_y, Ng_z: unnormalised geometric normal
HIT_U = 15
HIT_V = 16
HIT_PRIM = 17
HIT_GEOM = 18
HIT_INST = 19  # instID[RTC_MAX_INSTANCE_LEVEL_COUNT = 1]
# instPrimID[1] exists when Embree is built with instance arrays, as the 4.4 release is (the
# tests check that Embree writes it); reserving it keeps a record valid for either build.
HIT_INST_PRIM = 20
RAYHIT_FIELDS = 21
RAYHIT_WORDS = 24  # 96 bytes: the 84 of the fields rounded up to RTCRayHit's 16-byte alignment
INVALID_ID = -1  # RTC_INVALID_GEOMETRY_ID (0xFFFFFFFF) read as an int32 word
# Embree reads each float3 vertex with one 16-byte load, so the vertex buffer must stay readable
# for 4 bytes past its last 12-byte element (rtcSetSharedGeometryBuffer).
VERTEX_PAD_FLOATS = 1
PACKET_WIDTHS = (1, 4, 8, 16)
# Rays per native call in the batch routes: packets of 8 traced 1.3x the single-ray rate (and
# the embreex batches' rate) over the stages' camera, bounce and shadow rays, with identical
# answers (bench/results/embree_native/results.md). Kernels that trace one path at a time use
# rtc_intersect1 / rtc_occluded1.
BATCH_WIDTH = 8
# rtcore enums used here (rtcore_common.h, rtcore_geometry.h, rtcore_buffer.h, rtcore_device.h).
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003
_DEVICE_PROPERTY_VERSION = 0
# Watertight triangle tests (no rays slipping between triangles sharing an edge); embreex sets it
# too, so both routes build and intersect alike.
_SCENE_FLAG_ROBUST = 1 << 2


class _EmbreeLib:
    """ctypes bindings to libembree4 plus the addresses of its trace functions for kernels."""

    def __init__(self, path: str):
        lib = ctypes.CDLL(path)
        vp, u32, i32, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_size_t

        def bind(name, res, *args):
            f = getattr(lib, name)
            f.restype, f.argtypes = res, list(args)
            return f

        self.path = path
        self.new_device = bind("rtcNewDevice", vp, ctypes.c_char_p)
        self.retain_device = bind("rtcRetainDevice", None, vp)
        self.release_device = bind("rtcReleaseDevice", None, vp)
        self.device_error = bind("rtcGetDeviceError", i32, vp)
        self.device_property = bind("rtcGetDeviceProperty", ctypes.c_ssize_t, vp, i32)
        self.new_scene = bind("rtcNewScene", vp, vp)
        self.commit_scene = bind("rtcCommitScene", None, vp)
        self.release_scene = bind("rtcReleaseScene", None, vp)
        self.set_scene_flags = bind("rtcSetSceneFlags", None, vp, i32)
        self.scene_flags = bind("rtcGetSceneFlags", i32, vp)
        self.get_geometry = bind("rtcGetGeometry", vp, vp, u32)
        self.geometry_buffer_data = bind("rtcGetGeometryBufferData", vp, vp, i32, u32)
        self.new_geometry = bind("rtcNewGeometry", vp, vp, i32)
        # (geometry, buffer type, slot, format, ptr, byte offset, byte stride, item count)
        self.set_shared_buffer = bind("rtcSetSharedGeometryBuffer", None, vp, i32, u32, i32, vp, sz, sz, sz)
        self.commit_geometry = bind("rtcCommitGeometry", None, vp)
        self.attach_geometry = bind("rtcAttachGeometry", u32, vp, vp)
        self.release_geometry = bind("rtcReleaseGeometry", None, vp)
        # rtcIntersect1(scene, RTCRayHit*, RTCIntersectArguments*), rtcOccluded1(scene, RTCRay*,
        # RTCOccludedArguments*); the W-wide ones take (const int* valid, scene, record*, args*).
        # Kernels call them by address with NULL arguments (the defaults).
        self.intersect = {w: ctypes.cast(getattr(lib, f"rtcIntersect{w}"), vp).value for w in PACKET_WIDTHS}
        self.occluded = {w: ctypes.cast(getattr(lib, f"rtcOccluded{w}"), vp).value for w in PACKET_WIDTHS}
        self.device = self.new_device(None)
        if not self.device:
            raise RuntimeError(f"rtcNewDevice failed in {path}")
        self.version = int(self.device_property(self.device, _DEVICE_PROPERTY_VERSION))

    def check(self, what: str) -> None:
        code = self.device_error(self.device)
        if code:
            raise RuntimeError(f"Embree error {code} in {what}")


_NATIVE: list = []  # [ _EmbreeLib or None ], filled on first use


def embree_library_path() -> str | None:
    """The libembree4 shared library that the embreex wheel ships, or None."""
    import embreex

    site = os.path.dirname(os.path.dirname(os.path.abspath(embreex.__file__)))
    found = sorted(glob.glob(os.path.join(site, "embreex.libs", "libembree4*.so*")))
    return found[0] if found else None


def native_embree() -> _EmbreeLib | None:
    """The process's native Embree (one device, kept for the process), or None with one warning
    when it cannot be loaded (every Accel then traces through embreex)."""
    if not _NATIVE:
        try:
            path = embree_library_path()
            if path is None:
                raise OSError("no embreex.libs/libembree4*.so* next to the embreex package")
            _NATIVE.append(_EmbreeLib(path))
        except (OSError, AttributeError, RuntimeError) as e:
            warnings.warn(f"native Embree unavailable ({e}); tracing through embreex batches", RuntimeWarning,
                          stacklevel=2)
            _NATIVE.append(None)
    return _NATIVE[0]


def _release_native(lib: _EmbreeLib, scene: int, _buffers) -> None:
    # _buffers: the shared vertex and index arrays, kept alive until the scene that reads them
    # is gone.
    lib.release_scene(scene)
    lib.release_device(lib.device)


class _NativeScene:
    """A committed Embree scene of one triangle geometry (geomID 0, primID = triangle index).

    Holds the shared vertex/index buffers and a reference on the device; ``release`` (or garbage
    collection) releases the scene and the device reference exactly once."""

    def __init__(self, lib: _EmbreeLib, tri32: np.ndarray):
        n = tri32.shape[0]
        self.vertices = np.zeros(9 * n + VERTEX_PAD_FLOATS, dtype=np.float32)
        self.vertices[: 9 * n] = tri32.reshape(-1)
        self.indices = np.arange(3 * n, dtype=np.uint32).reshape(n, 3)
        lib.retain_device(lib.device)
        scene = lib.new_scene(lib.device)
        lib.set_scene_flags(scene, _SCENE_FLAG_ROBUST)
        if n:  # an empty scene stays a valid handle that every ray misses
            geom = lib.new_geometry(lib.device, _GEOMETRY_TYPE_TRIANGLE)
            lib.set_shared_buffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, self.vertices.ctypes.data, 0, 12,
                                  3 * n)
            lib.set_shared_buffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, self.indices.ctypes.data, 0, 12, n)
            lib.commit_geometry(geom)
            lib.attach_geometry(scene, geom)
            lib.release_geometry(geom)  # the scene holds it now
        lib.commit_scene(scene)
        self.lib, self.scene = lib, int(scene)
        self._finalizer = weakref.finalize(self, _release_native, lib, self.scene, (self.vertices, self.indices))
        lib.check("building the scene")

    @property
    def alive(self) -> bool:
        return self._finalizer.alive

    def buffer_address(self, index: bool) -> int:
        """The address Embree reads the vertex (index False) or index buffer from."""
        geom = self.lib.get_geometry(self.scene, 0)
        return int(self.lib.geometry_buffer_data(geom, _BUFFER_TYPE_INDEX if index else _BUFFER_TYPE_VERTEX, 0))

    def release(self) -> None:
        self._finalizer()  # a no-op after the first call


@dataclass(frozen=True)
class NativeHandles:
    """What a kernel needs to trace a scene: its RTCScene and the functions' addresses (ints).

    Valid while the Accel that gave them is open: hold the Accel, not only these."""

    scene: int
    intersect1: int
    occluded1: int


# ---- calling Embree from numba -----------------------------------------------------------
@intrinsic
def _call3(typingctx, fn, a, b, c):
    """void fn(void*, void*, void*) at address fn (int64), arguments as int64 addresses."""
    sig = types.void(types.int64, types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        p = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [p, p, p]).as_pointer())
        builder.call(f, [builder.inttoptr(x, p) for x in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call4(typingctx, fn, a, b, c, d):
    """void fn(void*, void*, void*, void*) at address fn (int64)."""
    sig = types.void(types.int64, types.int64, types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        p = ir.IntType(8).as_pointer()
        f = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [p, p, p, p]).as_pointer())
        builder.call(f, [builder.inttoptr(x, p) for x in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True)
def aligned_record(words, align):
    """(words,) float32 zeros starting at a multiple of align bytes (Embree's ray records: 16 for
    RTCRayHit, 4 W for a W-ray packet; 64, a cache line, satisfies every width)."""
    buf = np.zeros(words + align // 4, dtype=np.float32)
    skip = (align - buf.ctypes.data % align) % align
    return buf[skip // 4: skip // 4 + words]


@njit(cache=True, nogil=True, inline="always")
def set_ray(rec, rec_i, lane, width, ox, oy, oz, dx, dy, dz, tnear, tfar, mask):
    """Write ray `lane` of a record of `width` lanes (1: an RTCRayHit) and reset its hit IDs.

    rec: float32 record (aligned_record); rec_i: the same memory as int32 (rec.view)."""
    rec[RAY_ORG * width + lane] = ox
    rec[(RAY_ORG + 1) * width + lane] = oy
    rec[(RAY_ORG + 2) * width + lane] = oz
    rec[RAY_TNEAR * width + lane] = tnear
    rec[RAY_DIR * width + lane] = dx
    rec[(RAY_DIR + 1) * width + lane] = dy
    rec[(RAY_DIR + 2) * width + lane] = dz
    rec[RAY_TIME * width + lane] = 0.0
    rec[RAY_TFAR * width + lane] = tfar
    rec_i[RAY_MASK * width + lane] = mask
    rec_i[RAY_ID * width + lane] = 0
    rec_i[RAY_FLAGS * width + lane] = 0
    if rec.shape[0] > HIT_INST_PRIM * width:  # an RTCRayHit, not a bare RTCRay
        rec_i[HIT_PRIM * width + lane] = INVALID_ID
        rec_i[HIT_GEOM * width + lane] = INVALID_ID
        rec_i[HIT_INST * width + lane] = INVALID_ID
        rec_i[HIT_INST_PRIM * width + lane] = INVALID_ID


@njit(cache=True, nogil=True, inline="always")
def ray_epsilon_row(px, py, pz, tri_mag_k, eps_rel, eps_floor, eps_add):
    """Accel.ray_epsilon of one point (px, py, pz) on a triangle of vertex magnitude tri_mag_k,
    from Accel.epsilon_terms (eps_rel, eps_floor, eps_add), for kernels offsetting origins."""
    mag = max(max(max(abs(px), abs(py)), abs(pz)), tri_mag_k)
    return eps_rel * max(mag, eps_floor) + eps_add


@njit(cache=True, nogil=True, inline="always")
def rtc_intersect1(fn, scene, rec):
    """rtcIntersect1(scene, rec, NULL): fn = NativeHandles.intersect1, rec an RTCRayHit record."""
    _call3(fn, scene, rec.ctypes.data, 0)


@njit(cache=True, nogil=True, inline="always")
def rtc_occluded1(fn, scene, rec):
    """rtcOccluded1(scene, rec, NULL): tfar becomes -inf when blocked."""
    _call3(fn, scene, rec.ctypes.data, 0)


@njit(cache=True, nogil=True, inline="always")
def _far(tmax, use_tmax, i):
    # The float32 far limit of ray i, as the embreex route sends it (<= 1e37).
    if not use_tmax:
        return np.float32(1e37)
    t = tmax[i]
    return np.float32(1e37) if t > 1e37 else np.float32(t)


@njit(cache=True, nogil=True, inline="always")
def _packet_record(words, width):
    # A record of `words` (float32 and int32 views of one cache-line-aligned buffer) and the
    # valid mask of a `width`-ray packet (aligned to 4 W bytes, as rtcIntersect<W> requires).
    rec = aligned_record(words, 64)
    return rec, rec.view(np.int32), aligned_record(width, 4 * max(width, 4)).view(np.int32)


@njit(cache=True, nogil=True, inline="always")
def _fill_packet(rec, rec_i, valid, width, o, d, tmax, use_tmax, s, m):
    # Rays s..s+m-1 into the record's lanes; lanes past m repeat the last ray and are switched
    # off in `valid` (Embree skips them).
    for j in range(width):
        i = s + min(j, m - 1)
        set_ray(rec, rec_i, j, width, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2], 0.0,
                _far(tmax, use_tmax, i), -1)
        valid[j] = -1 if j < m else 0


@njit(cache=True, nogil=True, inline="always")
def _trace(fn, scene, width, rec, valid):
    # rtcIntersect1/rtcOccluded1 (scene, record, NULL) or the W-wide (valid, scene, record, NULL).
    if width == 1:
        _call3(fn, scene, rec.ctypes.data, 0)
    else:
        _call4(fn, valid.ctypes.data, scene, rec.ctypes.data, 0)


@njit(cache=True, nogil=True)
def _intersect_rows(fn, scene, width, o, d, tmax, use_tmax, a, b, t_out, prim, u, v, inf_on_miss):
    """Closest hits of rays a..b-1 in groups of `width` (1: rtcIntersect1, else rtcIntersect<W>
    at address fn). o, d: (n, 3); tmax: (n,) (ignored unless use_tmax). Writes t_out (inf on a
    miss when inf_on_miss, else tmax's float32), prim (-1 on a miss), u, v (0 on a miss)."""
    rec, rec_i, valid = _packet_record(max(RAYHIT_FIELDS * width, RAYHIT_WORDS), width)
    for s in range(a, b, width):
        m = min(width, b - s)
        _fill_packet(rec, rec_i, valid, width, o, d, tmax, use_tmax, s, m)
        _trace(fn, scene, width, rec, valid)
        for j in range(m):
            i = s + j
            if rec_i[HIT_GEOM * width + j] != INVALID_ID:
                t_out[i] = rec[RAY_TFAR * width + j]
                prim[i] = rec_i[HIT_PRIM * width + j]
                u[i] = rec[HIT_U * width + j]
                v[i] = rec[HIT_V * width + j]
            else:
                t_out[i] = np.inf if inf_on_miss else rec[RAY_TFAR * width + j]
                prim[i] = -1
                u[i] = 0.0
                v[i] = 0.0


@njit(cache=True, nogil=True)
def _occluded_rows(fn, scene, width, o, d, tmax, a, b, out):
    """out[i] = is ray i (a <= i < b) blocked before tmax[i]; rtcOccluded1 or rtcOccluded<W>
    (which set tfar = -inf where blocked)."""
    rec, rec_i, valid = _packet_record(RAY_WORDS * width, width)
    for s in range(a, b, width):
        m = min(width, b - s)
        _fill_packet(rec, rec_i, valid, width, o, d, tmax, True, s, m)
        _trace(fn, scene, width, rec, valid)
        for j in range(m):
            out[s + j] = rec[RAY_TFAR * width + j] == -np.inf


@dataclass(frozen=True)
class Hits:
    """Closest hits of a ray batch.

    t: (n,) float64 hit distance, inf where the ray missed.
    prim: (n,) int64 triangle index, -1 where missed.
    b1, b2: (n,) float64 barycentrics of vertices 1 and 2 (b0 = 1 - b1 - b2).
    """

    t: np.ndarray
    prim: np.ndarray
    b1: np.ndarray
    b2: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.prim >= 0


def default_threads() -> int:
    return max(1, os.cpu_count() or 1)


class Accel:
    """A static triangle BVH.

    triangles: (T, 3, 3) float64 world-space vertices. An empty scene is allowed (every ray misses).
    threads: worker threads for batched queries.
    tri_index: (T,) int64, for a BVH over a subset of a scene's triangles (a shadowLink BVH):
    the scene index of each of its triangles, so a hit's material can be looked up; None when
    the BVH holds the scene's triangles in order.
    backend: "native" (numba kernels calling libembree4), "embreex" (its batch calls), or None:
    native when the library loads, else embreex (module docstring).
    """

    def __init__(self, triangles: np.ndarray, threads: int | None = None, tri_index: np.ndarray | None = None,
                 backend: str | None = None):
        tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        self.tri_index = tri_index
        self.count = tri.shape[0]
        self.threads = max(1, int(threads or default_threads()))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        if self.count:
            lo = tri.reshape(-1, 3).min(axis=0)
            hi = tri.reshape(-1, 3).max(axis=0)
        else:
            lo = hi = np.zeros(3)
        self.bounds = (lo, hi)
        self.diagonal = float(np.linalg.norm(hi - lo))
        self.magnitude = float(max(np.abs(lo).max(), np.abs(hi).max()))
        # Largest |coordinate| of each triangle's vertices (T,): embree's float32 hit distance
        # errs in proportion to the vertices' magnitude, not only the hit point's (a tilted
        # plane through the origin with vertices 50 units out self-shadowed a third of its
        # shadow rays near the origin when the offset scaled with |p| alone).
        self.tri_mag = np.ascontiguousarray(np.abs(tri).max(axis=(1, 2))) if self.count else np.zeros(0)
        if backend not in (None, "native", "embreex"):
            raise ValueError(f"Accel backend must be 'native' or 'embreex', not {backend!r}")
        lib = native_embree() if backend != "embreex" else None
        if backend == "native" and lib is None:
            raise RuntimeError("the native Embree library could not be loaded")
        self.backend = "native" if lib is not None else "embreex"
        self._scene = None
        self._native = None
        self._closed = False
        if lib is not None:  # even without triangles: kernels get a valid (empty) scene handle
            self._native = _NativeScene(lib, np.ascontiguousarray(tri, dtype=np.float32))
        elif self.count:
            self._scene = rtcs.EmbreeScene()
            # The mesh object must stay alive as long as the scene uses its buffers.
            self._mesh = TriangleMesh(self._scene, np.ascontiguousarray(tri, dtype=np.float32))
        self.rays_traced = {"intersect": 0, "occluded": 0}
        self._count_lock = threading.Lock()

    def close(self) -> None:
        """Stop the pool and release the Embree scene (once; later calls do nothing). Tracing
        after close raises."""
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
        if self._native is not None:
            self._native.release()
        self._closed = True

    def native_handles(self) -> NativeHandles:
        """The scene handle and single-ray function addresses for kernels that trace themselves
        (rtc_intersect1 / rtc_occluded1); valid until close()."""
        self._check_open()
        if self._native is None:
            raise RuntimeError("this Accel traces through embreex: no native Embree scene")
        lib = self._native.lib
        return NativeHandles(self._native.scene, lib.intersect[1], lib.occluded[1])

    def packet_handles(self, width: int) -> tuple[int, int, int]:
        """(scene, rtcIntersect<W>, rtcOccluded<W>) for kernels that trace packets of ``width``
        rays (1: single rays) with _intersect_rows / _occluded_rows; valid until close()."""
        self._check_open()
        if self._native is None:
            raise RuntimeError("this Accel traces through embreex: no native Embree scene")
        if width not in PACKET_WIDTHS:
            raise ValueError(f"Embree packet width must be one of {PACKET_WIDTHS}, not {width}")
        lib = self._native.lib
        return self._native.scene, lib.intersect[width], lib.occluded[width]

    def count_traced(self, intersect: int = 0, occluded: int = 0) -> None:
        """Add rays a kernel traced through the handles above to ``rays_traced`` (the batch
        calls count their own)."""
        with self._count_lock:
            self.rays_traced["intersect"] += int(intersect)
            self.rays_traced["occluded"] += int(occluded)

    def _check_open(self) -> None:
        if self._closed and self._native is not None:
            raise RuntimeError("Accel used after close(): its Embree scene is released")

    # ----------------------------------------------------------------------------------
    def ray_epsilon(self, p: np.ndarray, prim: np.ndarray | None = None) -> np.ndarray:
        """(n,) origin offset for points p (n, 3) on triangles prim (n,): proportional to the
        float32 rounding error of the point and of the triangle's vertices (``tri_mag``)."""
        a = np.abs(p)
        mag = np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])  # cheaper than max(axis=1) on (n, 3)
        if prim is not None and self.count:
            mag = np.maximum(mag, self.tri_mag[np.asarray(prim, dtype=np.int64)])
        return _REL_EPS * np.maximum(mag, 1e-3 * self.diagonal) + 1e-9 * self.diagonal + 1e-30

    def epsilon_terms(self) -> tuple[float, float, float]:
        """(rel, floor, add) with ray_epsilon(p, prim) = rel max(max_k |p_k|, tri_mag[prim], floor)
        + add, for kernels that offset origins themselves."""
        return _REL_EPS, 1e-3 * self.diagonal, 1e-9 * self.diagonal + 1e-30

    def _map(self, fn, n: int):
        # Native chunks split even a small batch over the threads (rays are independent, so the
        # answers do not depend on the split); embreex keeps CHUNK to amortise its Python call.
        size = CHUNK if self._native is None else max(1024, min(CHUNK, -(-n // self.threads)))
        bounds = [(s, min(n, s + size)) for s in range(0, n, size)]
        if self._pool is None or len(bounds) == 1 or getattr(_SERIAL, "on", False):
            return [fn(a, b) for a, b in bounds]
        return list(self._pool.map(lambda ab: fn(*ab), bounds))

    def intersect(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray | None = None) -> Hits:
        """Closest hit along o + t d for t in (0, tmax). o, d: (n, 3); tmax: (n,) or None (inf)."""
        n = o.shape[0]
        self._check_open()
        self.rays_traced["intersect"] += n
        if n == 0 or (self._scene is None and self._native is None):
            return Hits(np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n), np.zeros(n))
        if self._native is not None:
            return self._intersect_native(o, d, tmax)
        o32 = np.ascontiguousarray(o, dtype=np.float32)
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        if tmax is None:
            t32 = np.full(n, _EMBREE_INF, dtype=np.float32)
        else:
            t32 = np.minimum(np.asarray(tmax, dtype=np.float64), 1e37).astype(np.float32)
        t_out = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        b1 = np.zeros(n)
        b2 = np.zeros(n)

        def run(a: int, b: int) -> None:
            # embreex overwrites a dists array it is given, so pass a copy of our slice.
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), output=1)
            pid = r["primID"].astype(np.int64)
            hit = pid >= 0
            prim[a:b] = pid
            t_out[a:b] = np.where(hit, r["tfar"].astype(np.float64), np.inf)
            b1[a:b] = r["u"]
            b2[a:b] = r["v"]

        self._map(run, n)
        return Hits(t_out, prim, b1, b2)

    def occluded(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> np.ndarray:
        """(n,) bool: is anything hit along o + t d for t in (0, tmax)?"""
        n = o.shape[0]
        self._check_open()
        self.rays_traced["occluded"] += n
        if n == 0 or (self._scene is None and self._native is None):
            return np.zeros(n, dtype=bool)
        if self._native is not None:
            return self._occluded_native(o, d, tmax)
        o32 = np.ascontiguousarray(o, dtype=np.float32)
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        t32 = np.minimum(np.asarray(tmax, dtype=np.float64), 1e37).astype(np.float32)
        out = np.zeros(n, dtype=bool)

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), query="OCCLUDED")
            # OCCLUDED answers 0 where blocked and -1 where the segment is free.
            out[a:b] = np.asarray(r) != -1

        self._map(run, n)
        return out


    # ---- the native route ------------------------------------------------------------------
    def _intersect_rows(self, o, d, tmax, use_tmax, t_out, prim, u, v, inf_on_miss, width=BATCH_WIDTH):
        if width not in PACKET_WIDTHS:
            raise ValueError(f"Embree packet width must be one of {PACKET_WIDTHS}, not {width}")
        fn, scene = self._native.lib.intersect[width], self._native.scene
        self._map(lambda a, b: _intersect_rows(fn, scene, width, o, d, tmax, use_tmax, a, b, t_out, prim, u, v,
                                               inf_on_miss), o.shape[0])

    def _occluded_rows(self, o, d, tmax, out, width=BATCH_WIDTH):
        if width not in PACKET_WIDTHS:
            raise ValueError(f"Embree packet width must be one of {PACKET_WIDTHS}, not {width}")
        fn, scene = self._native.lib.occluded[width], self._native.scene
        self._map(lambda a, b: _occluded_rows(fn, scene, width, o, d, tmax, a, b, out), o.shape[0])

    def _intersect_native(self, o, d, tmax) -> Hits:
        n = o.shape[0]
        o = np.ascontiguousarray(o, dtype=np.float64)
        d = np.ascontiguousarray(d, dtype=np.float64)
        use_tmax = tmax is not None
        tmax = np.ascontiguousarray(tmax, dtype=np.float64) if use_tmax else np.zeros(1)
        t_out = np.empty(n)
        prim = np.empty(n, dtype=np.int64)
        b1 = np.empty(n)
        b2 = np.empty(n)
        self._intersect_rows(o, d, tmax, use_tmax, t_out, prim, b1, b2, True)
        return Hits(t_out, prim, b1, b2)

    def _occluded_native(self, o, d, tmax) -> np.ndarray:
        out = np.empty(o.shape[0], dtype=bool)
        self._occluded_rows(np.ascontiguousarray(o, dtype=np.float64), np.ascontiguousarray(d, dtype=np.float64),
                            np.ascontiguousarray(tmax, dtype=np.float64), out)
        return out

    # ---- float32 batches prepared by compiled kernels (the fast path) -------------------
    def intersect_prepared(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray, width: int = BATCH_WIDTH):
        """Closest hits of rays a kernel wrote in embree's own format, without conversions.

        o32, d32: (n, 3) C-contiguous float32; t32: (n,) float32 far limits (<= 1e37), which
        are *overwritten* with the hit distances (unchanged where the ray missed).
        Returns prim (n,) int32 (-1 on a miss) and the barycentrics u, v (n,) float32.
        width: rays per native Embree call (1, or a packet of 4, 8, 16; BATCH_WIDTH).
        """
        n = o32.shape[0]
        self._check_open()
        self.rays_traced["intersect"] += n
        prim = np.full(n, -1, dtype=np.int32)
        u = np.zeros(n, dtype=np.float32)
        v = np.zeros(n, dtype=np.float32)
        if n == 0 or (self._scene is None and self._native is None):
            return prim, u, v
        if self._native is not None:
            self._intersect_rows(o32, d32, t32, True, t32, prim, u, v, False, width)
            return prim, u, v

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b], output=1)
            prim[a:b] = r["primID"]
            u[a:b] = r["u"]
            v[a:b] = r["v"]
            t32[a:b] = r["tfar"]

        self._map(run, n)
        return prim, u, v

    def occluded_prepared(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray,
                          width: int = BATCH_WIDTH) -> np.ndarray:
        """occluded() for float32 rays in embree's format (as intersect_prepared; t32 may be
        overwritten). Returns (n,) bool, True where blocked."""
        n = o32.shape[0]
        self._check_open()
        self.rays_traced["occluded"] += n
        out = np.zeros(n, dtype=bool)
        if n == 0 or (self._scene is None and self._native is None):
            return out
        if self._native is not None:
            self._occluded_rows(o32, d32, t32, out, width)
            return out

        def run(a: int, b: int) -> None:
            r = self._scene.run(o32[a:b], d32[a:b], dists=t32[a:b], query="OCCLUDED")
            out[a:b] = np.asarray(r) != -1

        self._map(run, n)
        return out


def raw_throughput_probe(accel: Accel, o: np.ndarray, d: np.ndarray, query: str = "INTERSECT") -> float:
    """Time embree alone on a prepared float32 batch, in seconds (for the benchmark's ratio).

    Uses the same route, chunking and threads as Accel but no float64 conversion or
    post-processing.
    """
    import time

    o32 = np.ascontiguousarray(o, dtype=np.float32)
    d32 = np.ascontiguousarray(d, dtype=np.float32)
    n = o32.shape[0]
    t32 = np.full(n, _EMBREE_INF, dtype=np.float32)
    if accel.backend == "native":
        t0 = time.perf_counter()
        if query == "INTERSECT":
            accel.intersect_prepared(o32, d32, t32)
        else:
            accel.occluded_prepared(o32, d32, t32)
        return time.perf_counter() - t0

    def run(a: int, b: int):
        if query == "INTERSECT":
            return accel._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), output=1)
        return accel._scene.run(o32[a:b], d32[a:b], dists=t32[a:b].copy(), query="OCCLUDED")

    t0 = time.perf_counter()
    accel._map(run, n)
    return time.perf_counter() - t0
