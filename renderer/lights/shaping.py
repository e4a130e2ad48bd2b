"""UsdLux ShapingAPI: the directional factor (focus, cone, IES) of a finite light's emission.

The factor multiplies a light's radiance toward an *emission direction* e, the unit direction
from the point on the light toward the receiver (so e = -wi for a light sample). It is the
product of three terms, each from the UsdLux user doc (schemaUserDoc.usda, ShapingAPI):

    cos_off = e_local . (0, 0, -1)        theta_off = acos(cos_off)      (light axis: local -Z)

    focus:  ff = |cos_off|^focus,  focusColor = lerp(ff, focusTint, 1) = focusTint + ff (1 - focusTint)
            (only for focus > 0: "values < 0 are ignored"; a white tint disables focus)
    cone:   smoothStart = lerp(softness, theta_cut, 0) = (1 - softness) theta_cut,
            factor = 1 - smoothstep(theta_off, smoothStart, theta_cut),  theta_cut = radians(angle)
            (softness 0: a hard cut, factor 1 for theta_off <= theta_cut and 0 beyond)
    IES:    theta_ies = theta_off / s            for angleScale s > 0
                      = theta_off                for s = 0
                      = (theta_off - pi) / -s + pi   for s < 0,   clamped to [0, pi],
            factor = profile(theta_ies, phi) [/ profile.power() if ies:normalize]

Conventions checked against OpenUSD's hdEmbree (pxr/imaging/plugin/hdEmbree, light.cpp
``HdEmbreeEvaluateDirectionalShaping`` and renderer.cpp ``_EvalAreaLight``):

* The light axis is local -Z for every kind, sphere lights included (hdEmbree compares the
  emission direction with the light's -Z row, not with the sphere's surface normal). The doc's
  focus text says "the light's surface normal", which is -Z for rect and disk lights.
* Directions are measured in the light's local space, e_local = normalize(M^-1 e) with M the
  linear part of light_to_world (hdEmbree: ``xformWorldToLight.TransformDir``); a singular M
  (a flat light with zero Z scale) uses the orthogonal factor of its polar decomposition.
* phi (the IES horizontal angle) = atan2(y, x) of -e_local, the direction from the receiver
  back toward the light in the light's frame: hdEmbree's ``_Phi(omegaInLocal)``. The doc does
  not fix phi's origin; this keeps illum's IES orientation identical to hdEmbree's.
* smoothstep with equal edges is a step (0 at or below the edge, 1 above), hdEmbree's
  ``_Smoothstep``; so at the fallback softness 0 the cone angle is a hard binary cut.
* The angleScale mapping is the doc's formula (newer hdEmbree follows it too, see
  ``_IesKnotToEvalTheta``); older hdEmbree used RenderMan's (theta - pi)/(1 + s) + pi.
* ``ies:normalize`` divides by the profile's power: hdEmbree's mean intensity over the sphere
  (or hemisphere) of the profile (renderer/lights/ies.py). The doc's formula line writes a
  multiplication, which would not "preserve the overall energy output" as its text says.
* "The cone does not affect IES profiles" is read as: the cone does not remap the profile's
  angles (angleScale does); both factors still multiply, as in hdEmbree.

Distant and dome lights have no emission point and are not shaped (the light set warns).

``ShapingTable`` holds structure-of-arrays over the lights whose shaping actually changes their
emission, and applies the factor with one fused numba kernel per batch
(renderer/kernels/shaping.py). Lights without shaping (or with shaping that is the identity,
e.g. a rect light with cone 90 and focus 0) have ``row_of == -1`` and cost one gather and a
comparison per row; a scene without shaped lights has no table at all. The same kernel, fed
light-space directions, evaluates the factor for the power quadrature at build time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from renderer.color import luminance

__all__ = ["ShapingTable", "empty_kernel_record", "ies_theta_inverse", "ONE_SIDED_KINDS"]

# Kinds that emit only into the hemisphere about local -Z (others: every direction).
ONE_SIDED_KINDS = ("rect", "disk")
# Relative tolerance deciding that a transform is a similarity (angles preserved), so the
# local-space cone is a world-space cone for the light BVH.
_SIMILARITY_RTOL = 1e-6
# Gauss-Legendre points per smooth sub-interval of the power quadrature.
_GL = np.polynomial.legendre.leggauss(16)
_GL_PHI = np.polynomial.legendre.leggauss(4)


def ies_theta_inverse(theta_ies: float, s: float) -> float:
    """theta_light that maps to theta_ies (before clamping): the inverse of the doc's
    applyAngleScale (theta / s for s > 0, (theta - pi) / -s + pi for s < 0, theta for s = 0)."""
    if s > 0.0:
        return s * theta_ies
    if s < 0.0:
        return math.pi + (-s) * (theta_ies - math.pi)
    return theta_ies


@dataclass
class ShapingTable:
    """Shaping of every light whose emission it changes (structure of arrays over k rows).

    row_of: (count,) int64 row of each global light, -1 when unshaped.
    light: (k,) global index; to_local: (k, 3, 3) world -> light-space direction map;
    focus: (k,); tint: (k, 3); theta_cut, theta_soft: (k,) radians (pi and pi: no cone);
    ies: list of IesProfile; ies_of: (k,) index into ies or -1; angle_scale, ies_scale: (k,);
    ratio: (k, 3) emitted power relative to the unshaped light, per channel;
    support: (k,) largest off-axis angle with non-zero emission (radians, <= pi);
    flat: (k,) off-axis angle up to which the cone term is 1 (for the light BVH's cone split);
    axis: (k, 3) world light axis (image of local -Z), similarity: (k,) bool.
    descriptions: (k,) short text of what shapes each light (stats / warnings).
    """

    row_of: np.ndarray
    light: np.ndarray
    to_local: np.ndarray
    focus: np.ndarray
    tint: np.ndarray
    theta_cut: np.ndarray
    theta_soft: np.ndarray
    ies: list
    ies_of: np.ndarray
    angle_scale: np.ndarray
    ies_scale: np.ndarray
    ratio: np.ndarray
    support: np.ndarray
    flat: np.ndarray
    axis: np.ndarray
    similarity: np.ndarray
    descriptions: list

    # ------------------------------------------------------------------------------
    @classmethod
    def build(cls, descs, kinds: list[str]) -> "ShapingTable | None":
        """From LightDescs (with ``shaping`` set or None) and their kind names, or None when no
        light's shaping changes its emission. Distant and dome lights are never shaped."""
        from renderer.lights.ies import load_ies

        count = len(descs)
        rows = []
        for i, (d, kind) in enumerate(zip(descs, kinds)):
            sh = getattr(d, "shaping", None)
            if sh is None or kind in ("distant", "dome"):
                continue
            one_sided = kind in ONE_SIDED_KINDS
            theta_max = 0.5 * math.pi if one_sided else math.pi
            focus = float(sh.focus)
            tint = np.clip(np.asarray(sh.focus_tint, dtype=np.float64).reshape(3), 0.0, None)
            has_focus = focus > 0.0 and bool(np.any(tint != 1.0))
            cut = math.radians(min(max(float(sh.cone_angle), 0.0), 180.0))
            soft = (1.0 - min(max(float(sh.cone_softness), 0.0), 1.0)) * cut
            has_cone = soft < theta_max
            profile = None
            if sh.ies_file:
                profile = sh.ies_profile if sh.ies_profile is not None else load_ies(sh.ies_file)
            if not (has_focus or has_cone or profile is not None):
                continue
            rows.append((i, kind, focus if has_focus else 0.0, tint, cut if has_cone else math.pi,
                         soft if has_cone else math.pi, profile, float(sh.ies_angle_scale),
                         bool(sh.ies_normalize), np.asarray(d.light_to_world, dtype=np.float64)[:3, :3]))
        if not rows:
            return None
        k = len(rows)
        row_of = np.full(count, -1, dtype=np.int64)
        light = np.array([r[0] for r in rows], dtype=np.int64)
        row_of[light] = np.arange(k)
        profiles: list = []
        ies_of = np.full(k, -1, dtype=np.int64)
        ies_scale = np.ones(k)
        to_local = np.zeros((k, 3, 3))
        axis = np.zeros((k, 3))
        similarity = np.zeros(k, dtype=bool)
        descriptions = []
        for j, r in enumerate(rows):
            _, kind, focus, tint, cut, soft, profile, s, normalize, m3 = r
            to_local[j], axis[j], similarity[j] = _frame(m3)
            if profile is not None:
                ies_of[j] = len(profiles)
                profiles.append(profile)
                if normalize:
                    power = profile.power()
                    ies_scale[j] = 1.0 / power if power > 0.0 else 0.0
            parts = []
            if focus > 0.0:
                parts.append(f"focus {focus:g}")
            if cut < math.pi or soft < math.pi:
                parts.append(f"cone {math.degrees(cut):g} deg softness {1.0 - soft / cut if cut > 0 else 0.0:g}")
            if profile is not None:
                parts.append("IES " + profile.file.rsplit("/", 1)[-1])
            descriptions.append(", ".join(parts))
        table = cls(
            row_of=row_of, light=light, to_local=to_local,
            focus=np.array([r[2] for r in rows]), tint=np.array([r[3] for r in rows]).reshape(k, 3),
            theta_cut=np.array([r[4] for r in rows]), theta_soft=np.array([r[5] for r in rows]),
            ies=profiles, ies_of=ies_of, angle_scale=np.array([r[7] for r in rows]), ies_scale=ies_scale,
            ratio=np.ones((k, 3)), support=np.full(k, math.pi), flat=np.zeros(k), axis=axis,
            similarity=similarity, descriptions=descriptions,
        )
        for j, r in enumerate(rows):
            one_sided = r[1] in ONE_SIDED_KINDS
            table.ratio[j] = table._power_ratio(j, one_sided)
            table.support[j], table.flat[j] = table._support(j, one_sided)
        return table

    # ------------------------------------------------------------------------------
    def factor(self, light: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(rows (m,), factor (m, 3)) for the rows of ``light`` (n,) global indices whose light is
        shaped, toward world emission directions e (n, 3); None when no row is shaped."""
        light = np.ascontiguousarray(light, dtype=np.int64)
        rows = np.nonzero(self.row_of[light] >= 0)[0]
        if rows.size == 0:
            return None
        f = np.ones((rows.size, 3))
        self._kernel(light[rows], np.ascontiguousarray(e[rows], dtype=np.float64), f)
        return rows, f

    def apply(self, light: np.ndarray, e: np.ndarray, L: np.ndarray) -> None:
        """Multiply L (n, 3) in place by the factor toward emission directions e (n, 3); rows of
        unshaped lights are left alone (renderer/kernels/shaping.py, one fused pass)."""
        light = np.ascontiguousarray(light, dtype=np.int64)
        e = np.ascontiguousarray(e, dtype=np.float64)
        if L.flags.c_contiguous and L.dtype == np.float64:
            self._kernel(light, e, L)
        else:
            out = np.ascontiguousarray(L, dtype=np.float64)
            self._kernel(light, e, out)
            L[...] = out

    def _kernel(self, light, e, L) -> None:
        from renderer.kernels.shaping import shaping_apply_kernel

        shaping_apply_kernel(light, e, L, self.row_of, *self.kernel_record())

    def kernel_record(self) -> tuple:
        """The arguments of renderer/kernels/shaping.shaping_factor_row after (j, e): the k rows'
        to_local, focus, tint, theta_cut, theta_soft, ies_of, angle_scale, ies_scale and the flat
        IES tables (v_all, v_off, h_all, h_off, c_all, c_off)."""
        if not hasattr(self, "_packed"):
            self._pack()
        return (self.to_local, self.focus, self.tint, self.theta_cut, self.theta_soft, self.ies_of, self.angle_scale,
                self.ies_scale, *self._packed)

    def _pack(self) -> None:
        """Flat IES tables for the kernel (see renderer/kernels/shaping.py)."""
        v = [np.asarray(p.theta, dtype=np.float64) for p in self.ies] or [np.zeros(2)]
        h = [np.asarray(p.phi, dtype=np.float64) for p in self.ies] or [np.zeros(2)]
        c = [np.ascontiguousarray(p.candela, dtype=np.float64).ravel() for p in self.ies] or [np.zeros(4)]
        off = lambda parts: np.concatenate([[0], np.cumsum([a.size for a in parts])]).astype(np.int64)  # noqa: E731
        self._packed = (np.concatenate(v), off(v), np.concatenate(h), off(h), np.concatenate(c), off(c))
        for name in ("row_of", "ies_of"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.int64))
        for name in ("to_local", "focus", "tint", "theta_cut", "theta_soft", "angle_scale", "ies_scale"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))

    def shaped(self, count: int) -> np.ndarray:
        """(count,) bool: lights whose emission the shaping changes."""
        return self.row_of[:count] >= 0

    # ------------------------------------------------------------------------------
    def _local_factor(self, j: int, loc: np.ndarray) -> np.ndarray:
        """Factor (n, 3) of row j for light-space emission directions loc (n, 3)."""
        world = np.ascontiguousarray(loc @ np.linalg.inv(self.to_local[j]).T)
        f = np.ones((loc.shape[0], 3))
        self._kernel(np.full(loc.shape[0], self.light[j], dtype=np.int64), world, f)
        return f

    def _theta_breaks(self, j: int, theta_max: float) -> np.ndarray:
        """Off-axis angles where the factor may have a kink (sub-interval ends of the quadrature)."""
        b = [0.0, theta_max, 0.5 * math.pi]
        if self.theta_soft[j] < math.pi:
            b += [self.theta_soft[j], self.theta_cut[j]]
        p = self.ies_of[j]
        if p >= 0:
            s = float(self.angle_scale[j])
            knots = list(self.ies[p].theta) + [0.0, math.pi]
            b += [ies_theta_inverse(float(t), s) for t in knots]
        b = np.unique(np.clip(np.array(b), 0.0, theta_max))
        return b

    def _power_ratio(self, j: int, one_sided: bool) -> np.ndarray:
        """(3,) shaped / unshaped emitted power: (1/pi) ∫ f cos dw over the front hemisphere for
        one-sided (cosine) emitters, (1/4pi) ∫ f dw over the sphere otherwise (spheres emit the
        same intensity pi r^2 L in every direction). Gauss-Legendre between the factor's kinks
        in theta and, with an IES profile, between its horizontal knots in phi."""
        theta_max = 0.5 * math.pi if one_sided else math.pi
        tb = self._theta_breaks(j, theta_max)
        x, w = _GL
        th, wt = [], []
        for a, b in zip(tb[:-1], tb[1:]):
            if b - a <= 0.0:
                continue
            th.append(0.5 * (b - a) * x + 0.5 * (a + b))
            wt.append(0.5 * (b - a) * w)
        th = np.concatenate(th)
        wt = np.concatenate(wt)
        p = self.ies_of[j]
        if p >= 0:
            pb = self.ies[p].knots_phi()
            xp, wp = _GL_PHI
            ph = np.concatenate([0.5 * (b - a) * xp + 0.5 * (a + b) for a, b in zip(pb[:-1], pb[1:]) if b > a])
            wph = np.concatenate([0.5 * (b - a) * wp for a, b in zip(pb[:-1], pb[1:]) if b > a])
        else:
            ph, wph = np.array([0.0]), np.array([2.0 * math.pi])
        # The local emission direction at (theta, phi) with phi measured on -e (see factor()).
        T, P = np.meshgrid(th, ph, indexing="ij")
        st = np.sin(T)
        loc = np.stack([-st * np.cos(P), -st * np.sin(P), -np.cos(T)], axis=-1).reshape(-1, 3)
        f = self._local_factor(j, loc).reshape(th.size, ph.size, 3)
        weight = (wt * np.sin(th) * (np.cos(th) if one_sided else 1.0))[:, None] * wph[None, :]
        integral = (f * weight[:, :, None]).sum(axis=(0, 1))
        return integral / (math.pi if one_sided else 4.0 * math.pi)

    def _support(self, j: int, one_sided: bool) -> tuple[float, float]:
        """(support, flat): the largest off-axis angle with non-zero emission and the angle
        up to which the cone term is 1 (0 when an IES profile or focus varies from the axis)."""
        theta_max = 0.5 * math.pi if one_sided else math.pi
        sup = theta_max
        if self.theta_soft[j] < math.pi:
            sup = min(sup, float(self.theta_cut[j]))
        p = self.ies_of[j]
        flat = float(min(self.theta_soft[j], sup))
        if p >= 0:
            t_ies = self.ies[p].theta_support()
            if t_ies < 0.0:
                return 0.0, 0.0
            if t_ies < math.pi:
                # theta_ies grows with theta for every angleScale, so the profile is zero
                # beyond the theta that maps to its last non-zero vertical angle.
                sup = min(sup, max(0.0, ies_theta_inverse(t_ies, float(self.angle_scale[j]))))
            flat = 0.0
        if self.focus[j] > 0.0:
            flat = 0.0
        return float(sup), float(min(flat, sup))

    # ------------------------------------------------------------------------------
    def tighten_bounds(self, glob: np.ndarray, w: np.ndarray, theta_o: np.ndarray, theta_e: np.ndarray,
                       one_sided: bool):
        """Light BVH orientation bounds (w, theta_o, theta_e) for the lights glob (m,) of one kind,
        narrowed to the shaped emission where the transform preserves angles (otherwise the
        unshaped bounds stay: conservative). theta_o + theta_e covers the support angle about
        the light axis, as pbrt-v4's spot light bounds do (theta_o = the flat part)."""
        w, theta_o, theta_e = w.copy(), theta_o.copy(), theta_e.copy()
        r = self.row_of[glob]
        for i in np.nonzero(r >= 0)[0]:
            j = r[i]
            if not self.similarity[j]:
                continue
            sup = float(self.support[j])
            if one_sided:
                # Rect and disk normals are the axis already: emission within sup of it.
                w[i] = self.axis[j]
                theta_o[i] = 0.0
                theta_e[i] = min(theta_e[i], sup, 0.5 * math.pi)
            else:
                if sup >= math.pi:
                    continue
                o = max(float(self.flat[j]), sup - 0.5 * math.pi)
                w[i] = self.axis[j]
                theta_o[i] = o
                theta_e[i] = sup - o
        return w, theta_o, theta_e

    def power_luminance_scale(self, L_rgb: np.ndarray) -> np.ndarray:
        """(k,) lum(L * ratio) / lum(L) for the shaped lights with colours L_rgb (k, 3)."""
        base = luminance(L_rgb)
        shaped = luminance(L_rgb * self.ratio)
        return np.divide(shaped, base, out=np.zeros_like(base), where=base > 0.0)


def empty_kernel_record() -> tuple:
    """ShapingTable.kernel_record for a scene without shaped lights (no rows, the same types)."""
    f, i = np.float64, np.int64
    return (np.zeros((0, 3, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=i),
            np.zeros(0), np.zeros(0), np.zeros(2, dtype=f), np.zeros(2, dtype=i), np.zeros(2, dtype=f),
            np.zeros(2, dtype=i), np.zeros(4, dtype=f), np.zeros(2, dtype=i))


def _frame(m3: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """(world -> local direction map (3, 3), world axis (3,), is-similarity) of a light's
    linear part m3."""
    m3 = np.asarray(m3, dtype=np.float64)
    u, s, vt = np.linalg.svd(m3)
    if s[0] > 0.0 and s[-1] > 1e-12 * s[0]:
        to_local = np.linalg.inv(m3)
    else:
        # Singular (a flat light with zero Z scale): measure angles in the rotation part.
        to_local = (u @ vt).T
    a = m3 @ np.array([0.0, 0.0, -1.0]) if s[-1] > 1e-12 * s[0] else (u @ vt) @ np.array([0.0, 0.0, -1.0])
    n = float(np.linalg.norm(a))
    axis = a / n if n > 0.0 else np.array([0.0, 0.0, -1.0])
    similarity = bool(s[0] > 0.0 and (s[0] - s[-1]) <= _SIMILARITY_RTOL * s[0])
    return to_local, axis, similarity
