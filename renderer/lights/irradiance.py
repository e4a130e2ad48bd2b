"""Unshadowed irradiance E = ∫ L cos dω (over the upper hemisphere of the shading normal) of
each light kind, for the control variate's analytic integral F = c(wo) · E.

Exact where the light's radiance is uniform over its surface (untextured rect/parallelogram,
circular disk, sphere, constant dome, distant light with angle > 0): the geometric part comes
from lights/analytic.py. Elsewhere (textured rects, elliptical disks, textured domes without a
preconvolved irradiance, delta lights) ``exact`` is False and the estimators fall back to MIS.
Mesh lights are exact up to EXACT_MAX_TRIANGLES triangles (Lambert per facing triangle);
cylinder lights and domes with portals never are. Shaped lights (ShapingAPI focus, cone or IES that change the emission) and lights with a
ShadowAPI shadow colour are never exact (``LightSet.inexact``): the directional factor has no
closed-form integral, and a tinted shadow needs a per-channel visibility the control variate's
scalar alpha cannot carry.
"""

from __future__ import annotations

import numpy as np

from .analytic import (projected_solid_angle_disk, projected_solid_angle_distant,
                       projected_solid_angle_dome_constant, projected_solid_angle_rect,
                       projected_solid_angle_sphere)
from .base import ShadingContext

# Relative difference of a disk's semi-axes below which it is treated as circular.
_CIRCLE_RTOL = 1e-9


def _rect(obj, idx, ctx):
    G = projected_solid_angle_rect(ctx.p, ctx.ns, obj.center[idx], obj.ex[idx], obj.ey[idx], obj.n[idx])
    exact = obj.tex[idx] < 0
    return G[:, None] * obj.L[idx], exact


def _disk(obj, idx, ctx):
    circular = np.abs(obj.s1[idx] - obj.s2[idx]) <= _CIRCLE_RTOL * np.maximum(obj.s1[idx], obj.s2[idx])
    G = projected_solid_angle_disk(ctx.p, ctx.ns, obj.center[idx], obj.n[idx], obj.s1[idx])
    return G[:, None] * obj.L[idx], circular


def _sphere(obj, idx, ctx):
    r = np.where(obj.delta[idx], 1.0, obj.radius[idx])
    G = projected_solid_angle_sphere(ctx.p, ctx.ns, obj.center[idx], r)
    return G[:, None] * obj.L[idx], ~obj.delta[idx]


def _distant(obj, idx, ctx):
    # A cone of half-angle θmax about the light's axis (analytic.distant_F: the sphere's exact
    # formula); exact for 0 < θmax < π/2.
    th = obj.theta_max[idx]
    G = projected_solid_angle_distant(ctx.ns, obj.axis[idx], th)
    return G[:, None] * obj.L[idx], (th > 0.0) & (th < 0.5 * np.pi)


def _dome(obj, idx, ctx):
    E = np.zeros((idx.size, 3))
    const = obj.tex[idx] < 0
    # A constant dome over the whole upper hemisphere: ∫ cos dω = π.
    E[const] = projected_solid_angle_dome_constant() * obj.L[idx[const]]
    exact = const.copy()
    irr = getattr(obj, "irradiance_lookup", None)
    if irr is not None:
        tex_rows = np.nonzero(~const)[0]
        if tex_rows.size:
            e, ok = irr(idx[tex_rows], ctx.ns[tex_rows])
            E[tex_rows] = e
            exact[tex_rows] = ok
    # With portals the light samples need not cover the sphere: no exact F (dome.py).
    exact &= ~getattr(obj, "has_portals", np.zeros(obj.count, dtype=bool))[idx]
    return E, exact


def _mesh(obj, idx, ctx):
    # Lambert's polygon formula per facing triangle (lights/mesh.py; exact up to a size limit).
    return obj.irradiance(idx, ctx)


# CylinderLight has no entry: no exact F, the estimators use MIS.
_BY_KIND = {"rect": _rect, "disk": _disk, "sphere": _sphere, "distant": _distant, "dome": _dome,
            "mesh": _mesh}


def irradiance(lights, light: np.ndarray, ctx: ShadingContext) -> tuple[np.ndarray, np.ndarray]:
    """(E (n, 3) unshadowed irradiance from light at ctx.p about ctx.ns, exact (n,) bool)."""
    n = light.shape[0]
    E = np.zeros((n, 3))
    exact = np.zeros(n, dtype=bool)
    for obj, rows, local in lights._groups(light):
        fn = _BY_KIND.get(obj.name)
        if fn is None:
            continue
        e, ok = fn(obj, local, ctx.take(rows))
        E[rows] = e
        exact[rows] = ok
    if getattr(lights, "inexact_reason", None):
        # ShapingAPI emission or a ShadowAPI shadow colour: no exact F (see light_set.py).
        exact &= ~lights.inexact[light]
    return E, exact


def has_exact_integral(lights) -> np.ndarray:
    """(count,) bool: does the light have an exact F everywhere (used by the `auto` rule)?"""
    out = np.zeros(lights.count, dtype=bool)
    for k, obj in enumerate(lights.kinds):
        g = lights._global_of[k]
        if not g.size:
            continue
        if obj.name == "rect":
            out[g] = obj.tex < 0
        elif obj.name == "disk":
            out[g] = np.abs(obj.s1 - obj.s2) <= _CIRCLE_RTOL * np.maximum(obj.s1, obj.s2)
        elif obj.name == "sphere":
            out[g] = ~obj.delta
        elif obj.name == "distant":
            out[g] = (obj.theta_max > 0.0) & (obj.theta_max < 0.5 * np.pi)
        elif obj.name == "dome":
            out[g] = (obj.tex < 0) | bool(getattr(obj, "irradiance_lookup", None) is not None)
            out[g] &= ~getattr(obj, "has_portals", np.zeros(obj.count, dtype=bool))
        elif obj.name == "mesh":
            from .mesh import EXACT_MAX_TRIANGLES

            out[g] = obj.tri_count <= EXACT_MAX_TRIANGLES
    inexact = getattr(lights, "inexact", None)
    if inexact is not None and inexact.size:
        out &= ~inexact
    return out
