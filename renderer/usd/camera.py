"""UsdGeom.Camera -> CameraDesc, and the choice of which camera renders."""

from __future__ import annotations

import math

import numpy as np

from pxr import Gf, Sdf, Usd, UsdGeom

from renderer.description import CameraDesc

from .common import ReadContext, gf_matrix_to_np

__all__ = ["read_camera", "find_camera", "framing_camera"]

# UsdGeomCamera's focal length and apertures are in tenths of a scene unit (Gf.Camera's
# APERTURE_UNIT == FOCAL_LENGTH_UNIT == 0.1).
TENTHS = 0.1


def read_camera(prim: Usd.Prim, ctx: ReadContext) -> CameraDesc:
    """Camera values at the read time, lengths converted to scene units and validated."""
    cam = UsdGeom.Camera(prim)

    def num(name: str, **kw) -> float:
        return ctx.finite_float(prim, name, ctx.get(prim, name), **kw)

    projection = str(ctx.get(prim, "projection", "perspective"))
    if projection not in ("perspective", "orthographic"):
        raise ctx.error(f"unknown projection '{projection}'", prim, "projection")
    near, far = (float(x) for x in ctx.get(prim, "clippingRange"))
    if not (math.isfinite(near) and math.isfinite(far)) or near < 0.0 or far <= near:
        raise ctx.error(f"clipping range ({near:g}, {far:g}) must satisfy 0 <= near < far", prim, "clippingRange")

    # -inf or a huge exposure would give a silently black or infinite image.
    exposure = num("exposure")
    if abs(exposure) > 128.0:
        raise ctx.error(f"exposure {exposure:g} is outside [-128, 128] stops", prim, "exposure")
    if hasattr(cam, "ComputeLinearExposureScale"):
        exposure_scale = float(cam.ComputeLinearExposureScale(ctx.time))
    else:  # older usd-core: only the plain exposure attribute exists
        exposure_scale = 2.0 ** num("exposure")
    if not math.isfinite(exposure_scale) or exposure_scale <= 0.0:
        raise ctx.error(f"linear exposure scale is {exposure_scale:g}", prim, "exposure")

    planes = []
    for k, plane in enumerate(ctx.get(prim, "clippingPlanes", None) or ()):
        a, b, c, d = ctx.finite_tuple(prim, "clippingPlanes", plane)
        if a == 0.0 and b == 0.0 and c == 0.0:
            raise ctx.error(f"plane {k} {(a, b, c, d)} has a zero normal", prim, "clippingPlanes")
        planes.append((a, b, c, d))

    return CameraDesc(
        path=str(prim.GetPath()),
        camera_to_world=_invertible_world(prim, ctx),
        projection=projection,
        # "Perspective focal length": an orthographic camera never uses it, so any finite value
        # (0 included) is valid there.
        focal_length=num("focalLength", positive=projection == "perspective") * TENTHS,
        horizontal_aperture=num("horizontalAperture", positive=True) * TENTHS,
        vertical_aperture=num("verticalAperture", positive=True) * TENTHS,
        horizontal_aperture_offset=num("horizontalApertureOffset") * TENTHS,
        vertical_aperture_offset=num("verticalApertureOffset") * TENTHS,
        clipping_range=(near, far),
        f_stop=num("fStop", min_value=0.0),
        focus_distance=num("focusDistance", min_value=0.0),
        exposure_scale=exposure_scale,
        clipping_planes=tuple(planes),
    )


def _invertible_world(prim: Usd.Prim, ctx: ReadContext) -> np.ndarray:
    """The camera's finite world matrix, which must be invertible: rays start from it and the
    EXR's worldToCamera is its inverse. A singular one (a scale of 0 on the camera or an
    ancestor) is a StageError naming the xformOp that makes it so."""
    m = ctx.finite_world(prim)
    if _invertible(m):
        return m
    p = prim
    while p and not p.IsPseudoRoot():
        xf = UsdGeom.Xformable(p)
        if xf:
            for op in xf.GetOrderedXformOps():
                if not _invertible(gf_matrix_to_np(op.GetOpTransform(ctx.time))):
                    raise ctx.error("the camera's transform is singular (a scale of 0?): it cannot be inverted",
                                    p, op.GetAttr().GetName())
        p = p.GetParent()
    raise ctx.error("the camera's world transform is singular: it cannot be inverted", prim, "xformOpOrder")


def _invertible(m: np.ndarray) -> bool:
    """The (4, 4) matrix's linear part keeps full rank to float64 precision."""
    s = np.linalg.svd(np.asarray(m, dtype=np.float64)[:3, :3], compute_uv=False)
    return bool(s[0] > 0.0 and s[-1] > 1e-12 * s[0])


def find_camera(ctx: ReadContext, requested: str | None, settings_camera: str,
                settings_prim: str, first_seen: str | None) -> Usd.Prim | None:
    """Pick the render camera.

    Order: the ``camera`` argument (a path, or a bare prim name searched for among cameras),
    then the RenderSettings ``camera`` relationship, then the first camera met during the
    render traversal, then the first camera anywhere on the stage (e.g. under an invisible
    scope). None when the stage has no camera at all (``framing_camera`` then frames it).
    """
    stage = ctx.stage
    if requested:
        if not requested.startswith("/"):
            matches = [p for p in _all_cameras(stage) if p.GetName() == requested]
            if len(matches) == 1:
                return matches[0]
            if not matches:
                raise ctx.error(f"no camera named '{requested}' on the stage")
            raise ctx.error(f"camera name '{requested}' is ambiguous: "
                            f"{', '.join(str(p.GetPath()) for p in matches)}")
        if not Sdf.Path.IsValidPathString(requested):
            raise ctx.error(f"'{requested}' is not a valid prim path", requested)
        prim = stage.GetPrimAtPath(requested)
        if not prim:
            raise ctx.error("camera prim does not exist", requested)
        if not prim.IsA(UsdGeom.Camera):
            raise ctx.error(f"prim is a '{prim.GetTypeName()}', not a Camera", requested)
        return prim
    if settings_camera:
        prim = stage.GetPrimAtPath(settings_camera)
        if not prim or not prim.IsA(UsdGeom.Camera):
            what = "does not exist" if not prim else f"is a '{prim.GetTypeName()}', not a Camera"
            raise ctx.error(f"camera target {settings_camera} {what}", settings_prim, "camera")
        return prim
    if first_seen:
        return stage.GetPrimAtPath(first_seen)
    for prim in _all_cameras(stage):
        return prim
    return None


# Where a default camera is needed: usdrecord's (UsdAppUtilsFrameRecorder) framing of the stage.
DEFAULT_CAMERA_PATH = "<default camera>"


def framing_camera(ctx: ReadContext, purposes: tuple[str, ...]) -> CameraDesc:
    """The camera usdrecord renders through when a stage has none: GfCamera's defaults (50 mm
    focal length, 20.955 x 15.2908 mm aperture), looking down the axis that is horizontal and
    not the up axis (-Z on a Y-up stage, +Y on a Z-up one) at the centre of the stage's world
    bounding box (``purposes`` included), from where the box's half-diagonal in the image plane
    fills half the horizontal field of view, backed off by half the box's depth. An empty
    stage gives a camera at the origin. The near clipping plane is brought closer than
    GfCamera's 1 unit when the box is that close, so a small stage is not clipped away."""
    cache = UsdGeom.BBoxCache(ctx.time, list(purposes), useExtentsHint=True)
    box = cache.ComputeWorldBound(ctx.stage.GetPseudoRoot())
    box_range = box.ComputeAlignedRange()
    if box_range.IsEmpty():
        center, dim = Gf.Vec3d(0.0), Gf.Vec3d(0.0)
    else:
        center, dim = box.ComputeCentroid(), box_range.GetSize()
    z_up = ctx.up_axis == UsdGeom.Tokens.z
    corner = Gf.Vec2d(dim[0], dim[2] if z_up else dim[1]) / 2.0
    gf = Gf.Camera()
    half_fov = math.radians(gf.GetFieldOfView(Gf.Camera.FOVHorizontal) / 2.0)
    distance = math.sqrt(Gf.Dot(corner, corner)) / math.tan(half_fov) + (dim[1] if z_up else dim[2]) / 2.0
    xf = Gf.Matrix4d(1.0)
    if z_up:
        xf.SetRotate(Gf.Rotation(Gf.Vec3d(1.0, 0.0, 0.0), 90.0))
        xf.SetTranslateOnly(center + Gf.Vec3d(0.0, -distance, 0.0))
    else:
        xf.SetTranslate(center + Gf.Vec3d(0.0, 0.0, distance))
    to_world = gf_matrix_to_np(xf)
    if not np.all(np.isfinite(to_world)):
        raise ctx.error("the stage's bounding box is not finite: cannot frame a default camera")
    near, far = gf.clippingRange.min, gf.clippingRange.max
    extent = math.sqrt(Gf.Dot(dim, dim))
    if distance - extent < near:
        near = max(1e-6, 1e-3 * max(distance, extent))
    far = max(far, 2.0 * (distance + extent))
    return CameraDesc(
        path=DEFAULT_CAMERA_PATH,
        camera_to_world=to_world,
        focal_length=gf.focalLength * TENTHS,
        horizontal_aperture=gf.horizontalAperture * TENTHS,
        vertical_aperture=gf.verticalAperture * TENTHS,
        clipping_range=(near, far),
    )


def _all_cameras(stage: Usd.Stage):
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdGeom.Camera):
            yield prim
