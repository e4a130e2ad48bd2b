"""UsdGeom.Camera -> CameraDesc, and the choice of which camera renders."""

from __future__ import annotations

import math

import numpy as np

from pxr import Sdf, Usd, UsdGeom

from renderer.description import CameraDesc

from .common import ReadContext, gf_matrix_to_np

__all__ = ["read_camera", "find_camera"]

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
                settings_prim: str, first_seen: str | None) -> Usd.Prim:
    """Pick the render camera.

    Order: the ``camera`` argument (a path, or a bare prim name searched for among cameras),
    then the RenderSettings ``camera`` relationship, then the first camera met during the
    render traversal, then the first camera anywhere on the stage (e.g. under an invisible
    scope). No camera at all is a StageError naming the file.
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
    raise ctx.error("the stage has no camera (pass --camera or add a UsdGeom.Camera)")


def _all_cameras(stage: Usd.Stage):
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdGeom.Camera):
            yield prim
