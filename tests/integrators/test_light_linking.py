"""UsdLux light linking: collection:lightLink and collection:shadowLink with includeRoot semantics."""

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material


def _stage(path, link_exclude_b=False, shadow_exclude_a=False, hide_a=False):
    stage = new_stage(path)
    cam = add_camera(stage, pos=(0, 8, 0), focal=20.0)
    UsdGeom.Xformable(cam).AddRotateXOp().Set(-90.0)
    add_settings(stage, res=(40, 40))
    grey = preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5))
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-6, 0, -6), (6, 0, -6), (6, 0, 6), (-6, 0, 6)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    floor.CreateSubdivisionSchemeAttr("none")
    bind(floor.GetPrim(), grey)
    for name, x in (("A", -2.0), ("B", 2.0)):
        s = UsdGeom.Sphere.Define(stage, f"/World/{name}")
        s.CreateRadiusAttr(1.0)
        s.AddTranslateOp().Set(Gf.Vec3d(x, 1.5, 0))
        bind(s.GetPrim(), grey)
        if name == "A" and hide_a:
            s.CreateVisibilityAttr("invisible")
    light = UsdLux.SphereLight.Define(stage, "/World/Key")
    light.CreateRadiusAttr(0.3)
    light.CreateIntensityAttr(200.0)
    light.AddTranslateOp().Set(Gf.Vec3d(0, 6, 0))
    api = UsdLux.LightAPI(light)
    if link_exclude_b:
        api.GetLightLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/B")
    if shadow_exclude_a:
        api.GetShadowLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/A")
    stage.GetRootLayer().Save()


def _render(path):
    # Light sampling for every light: a light with a shadowLink is never on continuation MIS (its
    # own estimator traces its rays), so with mis the stages with and without one would sample the
    # light differently and their images differ by noise where they should be equal.
    return render(str(path), RenderOptions(spp=16, max_depth=1, seed=2, threads=1,
                                           estimator={"": "lightSampling"})).film.mean()[..., 1]


def _pixel_of(world_x, world_z):
    # The camera at y = 8 looks straight down (-Y) with +X right and -Z up in the image.
    # focal 20, aperture 20.955: the window half-width at unit distance is 0.5239, so a
    # point at height h, horizontal offset x maps to raster (0.5 + x/(8-h)/1.0478) * 40.
    col = int((0.5 + world_x / 8.0 / 1.0478) * 40)
    row = int((0.5 + world_z / 8.0 / 1.0478) * 40)
    return row, col


def test_light_link_exclusion_leaves_the_excluded_gprim_unlit(tmp_path):
    _stage(tmp_path / "a.usda")
    _stage(tmp_path / "b.usda", link_exclude_b=True)
    base, linked = _render(tmp_path / "a.usda"), _render(tmp_path / "b.usda")
    r, c = _pixel_of(2.0 * 6.5 / 8.0, 0.0)   # top of sphere B (y = 2.5) projects a little inward
    r_a, c_a = _pixel_of(-2.0 * 6.5 / 8.0, 0.0)
    assert base[r, c] > 0.05
    assert linked[r, c] == 0.0, "sphere B is excluded from the light's lightLink"
    assert linked[r_a, c_a] > 0.05 and abs(linked[r_a, c_a] - base[r_a, c_a]) < 0.2 * base[r_a, c_a]


def test_shadow_link_exclusion_removes_the_shadow(tmp_path):
    _stage(tmp_path / "a.usda")
    _stage(tmp_path / "s.usda", shadow_exclude_a=True)
    _stage(tmp_path / "h.usda", hide_a=True)
    base, no_shadow, no_a = _render(tmp_path / "a.usda"), _render(tmp_path / "s.usda"), _render(tmp_path / "h.usda")
    # base and no_shadow show the same geometry; they differ only where A's shadow falls.
    diff = no_shadow - base
    r, c = np.unravel_index(np.argmax(diff), diff.shape)
    assert diff[r, c] > 0.5 * no_shadow[r, c], "A must cast a visible shadow in the plain stage"
    assert c < 20, "the shadow lies on A's side of the image"
    # There the shadow-excluded render equals the floor with A removed altogether.
    assert abs(no_shadow[r, c] - no_a[r, c]) < 0.15 * no_a[r, c]
    # B, still a shadow caster, keeps its own shadow: the right half is unchanged.
    np.testing.assert_allclose(no_shadow[:, 24:], base[:, 24:], atol=1e-6)
