"""LightSet: every light of the scene, grouped by kind, behind one global index.

``LightSet.build(descs, scene_center, scene_radius)`` drops lights that cannot emit (radiance
exactly zero, e.g. intensity 0; zero world area; a degenerate transform) and unknown kinds,
listing their paths in ``dropped`` (with a warning for unknown kinds), then builds one
structure-of-arrays object per kind. The remaining lights
keep the order of ``descs`` and get global indices 0..count-1:

* ``kind_of`` (count,) int8 -- index into ``kinds`` (the tuple of kind objects, KIND_NAMES order);
* ``local_of`` (count,) int64 -- index inside that kind;
* ``delta`` (count,) bool -- point-like lights (sphere treatAsPoint, distant angle 0): their
  sample_li has pdf 1 with L the irradiance-style term, pdf_li is 0, never hit by rays;
* ``infinite`` (k,) int64 -- global indices of the infinite lights (dome, distant);
* ``is_geometry`` (count,) bool -- mesh lights: real geometry in the scene BVH, so rays meet
  them as surfaces (``surface_emission``), not through proxies or ``intersect`` on camera rays;
* ``paths`` (count,) prim paths; ``estimators`` the per-light EstimatorSettings;
* ``warnings`` human-readable, aggregated from the kinds and the build;
* ``shaping`` -- UsdLux ShapingAPI (lights/shaping.py): a ShapingTable or None; ``sample_li``
  and ``le`` multiply each shaped row's radiance by its directional factor, ``phi`` returns
  the shaped power (``shaping_aware = False`` turns that off for comparisons);
* ``plain_shadows`` (count,) bool, ``shadow_tint`` (count, 3) or None -- UsdLux ShadowAPI;
  ``inexact`` (count,) bool with ``inexact_reason`` -- lights whose shaping or shadow colour
  rules out an exact unshadowed integral (the control variate falls back to MIS).

The dispatching methods take GLOBAL light indices (one per row) and group rows by kind with
boolean masks (a Python loop over the <= 5 kinds, never over rows or lights).
"""

from __future__ import annotations

import numpy as np

from renderer.description import EstimatorSettings, LightDesc
from renderer.lights.base import LightLiSample, ShadingContext
from renderer.lights.cylinder import CylinderLight
from renderer.lights.disk import DiskLight
from renderer.lights.distant import DistantLight
from renderer.lights.dome import DomeLight
from renderer.lights.mesh import MeshLight
from renderer.lights.radiometry import emitted_radiance
from renderer.lights.rect import RectLight
from renderer.lights.sphere import SphereLight

KIND_CLASSES = {
    "rect": RectLight,
    "disk": DiskLight,
    "sphere": SphereLight,
    "distant": DistantLight,
    "dome": DomeLight,
    "cylinder": CylinderLight,
    "mesh": MeshLight,
}
KIND_NAMES = tuple(KIND_CLASSES)
UNSUPPORTED_KINDS: tuple = ()


def _degenerate(desc: LightDesc, cls) -> bool:
    """True when the light has no extent to emit from (zero area, singular frame)."""
    m = np.asarray(desc.light_to_world, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        return True
    if desc.kind == "distant":
        return not np.any(DistantLight.world_axis(desc))
    if desc.kind == "dome":
        return False
    hook = getattr(cls, "is_degenerate", None)  # kinds with their own rule (cylinder: line lights)
    if hook is not None:
        return bool(hook(desc))
    return not cls.world_area(desc) > 0.0


def _radiance(desc: LightDesc, cls) -> np.ndarray:
    """(3,) the light's emitted quantity, to drop lights that emit nothing."""
    hook = getattr(cls, "radiance", None)  # kinds whose quantity is not L / area (line lights)
    if hook is not None:
        return hook(desc)
    return emitted_radiance(desc, cls.world_area(desc))


class LightSet:
    """All lights of a scene. See the module docstring for the attributes."""

    def __init__(self):
        self.kinds: tuple = ()
        self.count = 0
        self.paths: list[str] = []
        self.kind_of = np.zeros(0, dtype=np.int8)
        self.local_of = np.zeros(0, dtype=np.int64)
        self.delta = np.zeros(0, dtype=bool)
        self.infinite = np.zeros(0, dtype=np.int64)
        self.is_infinite = np.zeros(0, dtype=bool)
        self.is_geometry = np.zeros(0, dtype=bool)
        self.diffuse_scale = np.zeros(0)
        self.specular_scale = np.zeros(0)
        self.has_exact_integral = np.zeros(0, dtype=bool)
        # ShapingAPI (lights/shaping.py) and ShadowAPI: see _build_shaping_and_shadows.
        self.shaping = None
        self.shaped = np.zeros(0, dtype=bool)
        self.shaping_aware = True
        self.plain_shadows = np.zeros(0, dtype=bool)
        self.shadow_tint = None
        self.inexact_reason: dict[int, str] = {}
        self.inexact = np.zeros(0, dtype=bool)
        self.estimators: list[EstimatorSettings] = []
        self.descs: list[LightDesc] = []
        self.dropped: list[str] = []
        self.warnings: list[str] = []
        self._global_of: list[np.ndarray] = []

    # ----------------------------------------------------------------------------------
    # Build
    # ----------------------------------------------------------------------------------
    @classmethod
    def build(cls, descs: list[LightDesc], scene_center=(0.0, 0.0, 0.0), scene_radius: float = 1.0) -> "LightSet":
        ls = cls()
        center = np.asarray(scene_center, dtype=np.float64).reshape(3)
        radius = float(scene_radius)
        kept: list[LightDesc] = []
        for d in descs:
            if d.kind in UNSUPPORTED_KINDS:
                ls.dropped.append(d.path)
                ls.warnings.append(f"{d.path}: {d.kind} lights are not supported yet; the light is ignored")
                continue
            kind_cls = KIND_CLASSES.get(d.kind)
            if kind_cls is None:
                ls.dropped.append(d.path)
                ls.warnings.append(f"{d.path}: unknown light kind '{d.kind}'; the light is ignored")
                continue
            if _degenerate(d, kind_cls):
                ls.dropped.append(d.path)
                ls.warnings.append(f"{d.path}: degenerate light (zero area or singular transform) ignored")
                continue
            if not np.any(_radiance(d, kind_cls) != 0.0):
                ls.dropped.append(d.path)  # emits nothing (intensity 0, black colour): silently skipped
                continue
            if d.enable_color_temperature and not (1000.0 <= float(d.color_temperature) <= 10000.0):
                ls.warnings.append(
                    f"{d.path}: colorTemperature {d.color_temperature} K is outside [1000, 10000] K and is clamped"
                )
            kept.append(d)

        names = [d.kind for d in kept]
        kind_index = {n: i for i, n in enumerate(KIND_NAMES)}
        ls.count = len(kept)
        ls.descs = kept
        ls.paths = [d.path for d in kept]
        ls.estimators = [d.estimator for d in kept]
        ls.kind_of = np.array([kind_index[n] for n in names], dtype=np.int8)
        ls.local_of = np.zeros(ls.count, dtype=np.int64)
        kinds = []
        for k, name in enumerate(KIND_NAMES):
            members = np.nonzero(ls.kind_of == k)[0]
            ls.local_of[members] = np.arange(members.size)
            ls._global_of.append(members.astype(np.int64))
            obj = KIND_CLASSES[name].build([kept[i] for i in members], center, radius)
            kinds.append(obj)
            ls.warnings.extend(obj.warnings)
        ls.kinds = tuple(kinds)
        ls.delta = np.zeros(ls.count, dtype=bool)
        for k, obj in enumerate(ls.kinds):
            ls.delta[ls._global_of[k]] = obj.delta
        ls.infinite = np.nonzero(
            np.isin(ls.kind_of, [kind_index["distant"], kind_index["dome"]])
        )[0].astype(np.int64)
        ls.is_infinite = np.zeros(ls.count, dtype=bool)
        ls.is_infinite[ls.infinite] = True
        # Mesh lights are scene geometry: rays find them in the BVH, not by a light-crossing test.
        ls.is_geometry = np.zeros(ls.count, dtype=bool)
        for k, obj in enumerate(ls.kinds):
            ls.is_geometry[ls._global_of[k]] = bool(getattr(obj, "geometry", False))
        # UsdLux's non-physical per-light multipliers of the diffuse and specular response.
        ls.diffuse_scale = np.array([float(d.diffuse) for d in kept], dtype=np.float64)
        ls.specular_scale = np.array([float(d.specular) for d in kept], dtype=np.float64)
        ls._build_shaping_and_shadows(names)
        from .irradiance import has_exact_integral

        ls.has_exact_integral = has_exact_integral(ls)
        return ls

    def irradiance(self, light: np.ndarray, ctx: ShadingContext) -> tuple[np.ndarray, np.ndarray]:
        """Unshadowed irradiance (n, 3) about ctx.ns and whether it is exact (n,); see irradiance.py."""
        from .irradiance import irradiance

        return irradiance(self, np.asarray(light, dtype=np.int64), ctx)

    # ----------------------------------------------------------------------------------
    # Dispatch helpers
    # ----------------------------------------------------------------------------------
    def _groups(self, light: np.ndarray):
        """Yield (kind object, rows (m,), local indices (m,)) for every kind present in light."""
        light = np.asarray(light, dtype=np.int64)
        kinds = self.kind_of[light]
        for k, obj in enumerate(self.kinds):
            if obj.count == 0:
                continue
            rows = np.nonzero(kinds == k)[0]
            if rows.size:
                yield obj, rows, self.local_of[light[rows]]

    def _single_kind(self, light: np.ndarray):
        """The kind object when the scene has lights of one kind only (so every row of light is
        of that kind), else None."""
        present = [obj for obj in self.kinds if obj.count]
        return present[0] if len(present) == 1 else None

    def sample_li(self, light: np.ndarray, ctx: ShadingContext, u: np.ndarray) -> LightLiSample:
        """Sample each row's light (global index (n,)) from ctx with u (n, 2)."""
        n = np.asarray(light).size
        single = self._single_kind(light)
        if single is not None:
            # Every row is one kind (the common case of a one-kind scene): no row copies.
            s = single.sample_li(self.local_of[light], ctx, u)
            if self.shaping is not None:
                self.shaping.apply(light, -s.wi, s.L)  # emission direction: light -> receiver
            return s
        L = np.zeros((n, 3))
        wi = np.zeros((n, 3))
        wi[:, 2] = 1.0
        pdf = np.zeros(n)
        dist = np.zeros(n)
        p_light = np.zeros((n, 3))
        for obj, rows, loc in self._groups(light):
            s = obj.sample_li(loc, ctx.take(rows), u[rows])
            L[rows], wi[rows], pdf[rows], dist[rows], p_light[rows] = s.L, s.wi, s.pdf, s.dist, s.p_light
        if self.shaping is not None:
            self.shaping.apply(light, -wi, L)  # emission direction: light -> receiver
        return LightLiSample(L=L, wi=wi, pdf=pdf, dist=dist, p_light=p_light)

    def pdf_li(self, light: np.ndarray, ctx: ShadingContext, wi: np.ndarray) -> np.ndarray:
        """(n,) solid-angle pdf of sampling wi toward each row's light (0 for delta lights)."""
        single = self._single_kind(light)
        if single is not None:
            return single.pdf_li(self.local_of[light], ctx, wi)  # no row copies
        out = np.zeros(np.asarray(light).size)
        for obj, rows, loc in self._groups(light):
            out[rows] = obj.pdf_li(loc, ctx.take(rows), wi[rows])
        return out

    def le(self, light: np.ndarray, p_light: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) radiance leaving p_light on each row's (finite) light toward -wi; 0 for infinite."""
        single = self._single_kind(light)
        if single is not None:
            out = (np.zeros((np.asarray(light).size, 3)) if single.infinite
                   else single.le(self.local_of[light], p_light, wi))
        else:
            out = np.zeros((np.asarray(light).size, 3))
            for obj, rows, loc in self._groups(light):
                if not obj.infinite:
                    out[rows] = obj.le(loc, p_light[rows], wi[rows])
        if self.shaping is not None:
            self.shaping.apply(np.asarray(light, dtype=np.int64), -wi, out)
        return out

    def intersect(self, light: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(n,) exact hit distance of rays with each row's (finite) light; inf for infinite/delta."""
        single = self._single_kind(light)
        if single is not None and not single.infinite:
            return single.intersect(self.local_of[light], o, d)  # no row copies
        out = np.full(np.asarray(light).size, np.inf)
        for obj, rows, loc in self._groups(light):
            if not obj.infinite:
                out[rows] = obj.intersect(loc, o[rows], d[rows])
        return out

    def le_escaped(self, light: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(n, 3) radiance of each row's infinite light for escaped rays of direction d; 0 for finite."""
        out = np.zeros((np.asarray(light).size, 3))
        for obj, rows, loc in self._groups(light):
            if obj.infinite:
                out[rows] = obj.le_escaped(loc, d[rows])
        return out

    def surface_emission(self, light: np.ndarray, cos_front: np.ndarray,
                         d: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Emission of geometry lights (mesh lights) at surface hits: (Le (n, 3), absorbing (n,)).

        light: (n,) global index of the light whose triangle was hit; cos_front: (n,) = -d . n
        with n the hit triangle's front normal; d: (n, 3) the ray directions (for ShapingAPI).
        absorbing: the light's materialSyncMode is noMaterialResponse (its surface reflects nothing).
        """
        light = np.asarray(light, dtype=np.int64)
        Le = np.zeros((light.size, 3))
        absorbing = np.zeros(light.size, dtype=bool)
        for obj, rows, loc in self._groups(light):
            fn = getattr(obj, "surface_emission", None)
            if fn is not None:
                Le[rows], absorbing[rows] = fn(loc, cos_front[rows])
        if self.shaping is not None and d is not None:
            self.shaping.apply(light, -np.asarray(d, dtype=np.float64), Le)  # emission direction: light -> viewer
        return Le, absorbing

    def le_escaped_all(self, d: np.ndarray) -> np.ndarray:
        """(n, 3) sum over every infinite light of le_escaped (what an escaped ray sees)."""
        n = d.shape[0]
        k = self.infinite.size
        if k == 0:
            return np.zeros((n, 3))
        light = np.tile(self.infinite, n)  # row-major (n, k)
        return self.le_escaped(light, np.repeat(d, k, axis=0)).reshape(n, k, 3).sum(axis=1)

    def phi(self) -> np.ndarray:
        """(count,) luminance power of every light (for power-proportional light selection)."""
        out = np.zeros(self.count)
        for k, obj in enumerate(self.kinds):
            if obj.count:
                out[self._global_of[k]] = obj.phi()
        if self.shaping is not None and self.shaping_aware:
            # The shaped power (ShapingTable.ratio): what power sampling and the light BVH use.
            sh = self.shaping
            out[sh.light] *= sh.power_luminance_scale(self._base_rgb[sh.light])
        return out

    def proxy_triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """Conservative proxy triangles of all finite lights: (tris (T, 3, 3), owner (T,) GLOBAL index)."""
        tris, owners = [np.zeros((0, 3, 3))], [np.zeros(0, dtype=np.int64)]
        for k, obj in enumerate(self.kinds):
            if obj.count and not obj.infinite:
                t, o = obj.proxy_triangles()
                tris.append(t)
                owners.append(self._global_of[k][o])
        return np.concatenate(tris), np.concatenate(owners)

    def _build_shaping_and_shadows(self, names: list[str]) -> None:
        """ShapingAPI tables and ShadowAPI flags of the kept lights.

        shaping: ShapingTable or None; shaped (count,) bool: the shaping changes the emission.
        plain_shadows (count,) bool: shadows as without ShadowAPI. shadow_tint (count, 3) or
        None: shadow:color of lights with shadows enabled and a non-black colour (estimators
        fold it into the integrand, see estimators/base.py). inexact_reason: {light: why the
        light has no exact unshadowed integral F} for the shaped and tinted lights.
        """
        from .shaping import ShapingTable

        kept = self.descs
        for d in kept:
            if getattr(d, "shaping", None) is not None and d.kind in ("distant", "dome"):
                self.warnings.append(f"{d.path}: ShapingAPI on a {d.kind} light is ignored")
        self.shaping = ShapingTable.build(kept, names)
        self.shaped = self.shaping.shaped(self.count) if self.shaping is not None else np.zeros(self.count, bool)
        self._base_rgb = np.zeros((self.count, 3))
        if self.shaping is not None:
            for i in self.shaping.light:
                d = kept[i]
                self._base_rgb[i] = emitted_radiance(d, KIND_CLASSES[d.kind].world_area(d))
            for j, i in enumerate(self.shaping.light):
                self.inexact_reason[int(i)] = f"ShapingAPI ({self.shaping.descriptions[j]})"
        shadows = [getattr(d, "shadow", None) for d in kept]
        self.plain_shadows = np.array([s is None or s.is_default for s in shadows], dtype=bool)
        tint = np.zeros((self.count, 3))
        for i, s in enumerate(shadows):
            if s is not None and s.enable and any(c != 0.0 for c in s.color):
                tint[i] = s.color
                self.inexact_reason[i] = (self.inexact_reason.get(i, "") + "; " if i in self.inexact_reason
                                          else "") + "ShadowAPI shadow:color"
        self.shadow_tint = tint if np.any(tint != 0.0) else None
        self.inexact = np.zeros(self.count, dtype=bool)
        self.inexact[list(self.inexact_reason)] = True

    @property
    def estimator(self) -> list[EstimatorSettings]:
        """Alias of ``estimators``: the per-light EstimatorSettings, in global index order."""
        return self.estimators

    def kind_name(self, light: int) -> str:
        return KIND_NAMES[int(self.kind_of[light])]
