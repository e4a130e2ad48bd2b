"""UsdLux lights inside PointInstancer prototypes: one LightDesc per instance.

The expected frames are built here from the authored values with numpy (T R S per instance,
the prototype root's xform, the light's xform in the prototype, the instancer's own xform),
independently of UsdGeom.PointInstancer.ComputeInstanceTransformsAtTime, which the reader uses.
Rotations are chosen exactly representable as half-precision quaternions, so the frames must
agree to rounding.
"""

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux

from renderer.lights.radiometry import emitted_radiance
from renderer.lights.rect import RectLight
from renderer.lights.sphere import SphereLight
from renderer.render import RenderOptions, render
from renderer.usd import load_stage
from tests.stage_builders import add_camera, add_floor, add_point_instancer, add_settings, new_stage
from tests.stats import SIGNIFICANCE, z_test

LAMPS = "/World/Lamps"
BULB = f"{LAMPS}/Protos/Bulb/Light"
PANEL = f"{LAMPS}/Protos/Panel/Light"

# Instance table: three bulbs, one panel (non-uniform scale). Quaternions (w, x, y, z):
# identity, 180 deg about Y, 120 deg about (1, 1, 1) -- all exact in half precision.
PROTO_INDICES = [0, 0, 0, 1]
POSITIONS = [(-1.5, 0.0, 0.0), (0.0, 0.0, 1.0), (1.5, 0.0, -0.5), (0.0, 0.5, -1.5)]
ORIENTATIONS = [(1, 0, 0, 0), (0, 0, 1, 0), (0.5, 0.5, 0.5, 0.5), (0, 0, 1, 0)]
SCALES = [(1, 1, 1), (1.5, 1.5, 1.5), (0.5, 0.5, 0.5), (2.0, 1.0, 1.5)]
BULB_RADIUS, BULB_INTENSITY = 0.15, 30.0
PANEL_W, PANEL_H, PANEL_INTENSITY = 0.6, 0.4, 8.0


# --------------------------------------------------------------------------------------
# Expected matrices (column vectors), from first principles
# --------------------------------------------------------------------------------------
def _T(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _S(sx, sy, sz):
    return np.diag([sx, sy, sz, 1.0])


def _rot(axis, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _Q(w, x, y, z):
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    return m


INSTANCER_XF = _T(0.5, 2.5, -0.25) @ _rot("Y", 90.0)
BULB_ROOT_XF = _T(0.0, 0.1, 0.0)          # the prototype root's own xform (IncludeProtoXform)
BULB_LIGHT_XF = _T(0.0, 0.2, 0.0)
PANEL_LIGHT_XF = _T(0.0, -0.1, 0.0) @ _rot("X", -90.0)   # emits -Y, down onto the floor


def _instance(i):
    return _T(*POSITIONS[i]) @ _Q(*ORIENTATIONS[i]) @ _S(*SCALES[i])


def _expected_frame(i):
    if PROTO_INDICES[i] == 0:
        return INSTANCER_XF @ _instance(i) @ BULB_ROOT_XF @ BULB_LIGHT_XF
    return INSTANCER_XF @ _instance(i) @ PANEL_LIGHT_XF


# --------------------------------------------------------------------------------------
# Stages
# --------------------------------------------------------------------------------------
def _base(path):
    stage = new_stage(path)
    # below the lamps, looking down at the floor: the lamps are never seen directly, so the
    # pixels carry only their (lower-variance) illumination
    add_camera(stage, pos=(0, 1.5, 0), focal=12.0, tilt_x=-90.0)
    add_settings(stage, res=(32, 32))
    add_floor(stage, half=6.0)
    return stage


def _bulb(stage, path, xf=None):
    light = UsdLux.SphereLight.Define(stage, path)
    light.CreateRadiusAttr(BULB_RADIUS)
    light.CreateIntensityAttr(BULB_INTENSITY)
    if xf is None:
        light.AddTranslateOp().Set(Gf.Vec3d(*BULB_LIGHT_XF[:3, 3]))
    else:
        light.AddTransformOp().Set(Gf.Matrix4d(xf.T.tolist()))
    return light


def _panel(stage, path, xf=None, intensity=PANEL_INTENSITY):
    light = UsdLux.RectLight.Define(stage, path)
    light.CreateWidthAttr(PANEL_W)
    light.CreateHeightAttr(PANEL_H)
    light.CreateIntensityAttr(intensity)
    light.CreateNormalizeAttr(True)
    if xf is None:
        light.AddTranslateOp().Set(Gf.Vec3d(0.0, -0.1, 0.0))
        light.AddRotateXOp().Set(-90.0)
    else:
        light.AddTransformOp().Set(Gf.Matrix4d(xf.T.tolist()))
    return light


def _instanced_stage(path, *, orient="orientations", ids=None, invisible_ids=None):
    """The floor lit by LAMPS: 3 bulbs and 1 panel through one PointInstancer."""
    stage = _base(path)
    root = UsdGeom.Xform.Define(stage, f"{LAMPS}/Protos/Bulb")
    root.AddTranslateOp().Set(Gf.Vec3d(*BULB_ROOT_XF[:3, 3]))
    _bulb(stage, BULB)
    UsdGeom.Xform.Define(stage, f"{LAMPS}/Protos/Panel")
    _panel(stage, PANEL)
    pi = add_point_instancer(stage, LAMPS, [f"{LAMPS}/Protos/Bulb", f"{LAMPS}/Protos/Panel"], PROTO_INDICES,
                             POSITIONS, scales=SCALES, ids=ids, invisible_ids=invisible_ids,
                             **{orient: ORIENTATIONS})
    pi.AddTranslateOp().Set(Gf.Vec3d(*INSTANCER_XF[:3, 3]))
    pi.AddRotateYOp().Set(90.0)
    stage.GetRootLayer().Save()
    return stage


def _individual_stage(path, panel_intensity=PANEL_INTENSITY):
    """The same four lights, each authored on its own with its expected world matrix."""
    stage = _base(path)
    for i, k in enumerate(PROTO_INDICES):
        if k == 0:
            _bulb(stage, f"/World/Bulb{i}", _expected_frame(i))
        else:
            _panel(stage, f"/World/Panel{i}", _expected_frame(i), intensity=panel_intensity)
    stage.GetRootLayer().Save()
    return stage


def _by_path(desc):
    return {light.path: light for light in desc.lights}


# --------------------------------------------------------------------------------------
# LightDescs
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("orient", ["orientations", "orientationsf"])
def test_every_instance_yields_its_light_with_the_instance_frame(tmp_path, orient):
    _instanced_stage(tmp_path / "lamps.usda", orient=orient)
    d = load_stage(str(tmp_path / "lamps.usda"))
    lights = _by_path(d)
    expected = {f"{BULB}[0]": 0, f"{BULB}[1]": 1, f"{BULB}[2]": 2, f"{PANEL}[3]": 3}
    assert sorted(lights) == sorted(expected)
    for path, i in expected.items():
        np.testing.assert_allclose(lights[path].light_to_world, _expected_frame(i), rtol=0, atol=1e-12,
                                   err_msg=path)
    bulb = lights[f"{BULB}[1]"]
    assert (bulb.kind, bulb.radius, bulb.intensity) == ("sphere", pytest.approx(BULB_RADIUS), BULB_INTENSITY)
    # uniform instance scale 1.5: the bulb's world area is that of a sphere of radius 1.5 r
    assert SphereLight.world_area(bulb) == pytest.approx(4 * math.pi * (1.5 * bulb.radius) ** 2, rel=1e-12)
    assert d.stats["instanced_lights"] == 4 and d.stats["lights"] == 4
    assert not any("PointInstancer" in w for w in d.warnings), d.warnings


def test_normalize_divides_by_the_instance_world_area(tmp_path):
    _instanced_stage(tmp_path / "lamps.usda")
    panel = _by_path(load_stage(str(tmp_path / "lamps.usda")))[f"{PANEL}[3]"]
    assert panel.kind == "rect" and panel.normalize
    # scale (2, 1, 1.5): local X -> x2, local Y (turned onto the prototype's -Z) -> x1.5
    area = panel.width * panel.height * 2.0 * 1.5   # width, height as stored (float32)
    assert RectLight.world_area(panel) == pytest.approx(area, rel=1e-12)
    np.testing.assert_allclose(emitted_radiance(panel, RectLight.world_area(panel)), PANEL_INTENSITY / area,
                               rtol=1e-12)
    # what the render core builds from it: the same radiance
    np.testing.assert_allclose(RectLight.build([panel]).L[0], PANEL_INTENSITY / area, rtol=1e-12)


def test_invisible_ids_hide_an_instance_and_ids_name_them(tmp_path):
    _instanced_stage(tmp_path / "lamps.usda", ids=[40, 41, 42, 43], invisible_ids=[41])
    lights = _by_path(load_stage(str(tmp_path / "lamps.usda")))
    assert sorted(lights) == sorted([f"{BULB}[40]", f"{BULB}[42]", f"{PANEL}[43]"])
    np.testing.assert_allclose(lights[f"{BULB}[42]"].light_to_world, _expected_frame(2), atol=1e-12)
    np.testing.assert_allclose(lights[f"{PANEL}[43]"].light_to_world, _expected_frame(3), atol=1e-12)


def test_inactive_ids_and_zero_scale_hide_lights_too(tmp_path):
    stage = _instanced_stage(tmp_path / "lamps.usda")
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(LAMPS))
    pi.DeactivateId(0)
    # a zero scale hides an instance even when its light is a normalized point (which would
    # otherwise shine at its full point intensity whatever its size)
    UsdLux.SphereLight(stage.GetPrimAtPath(BULB)).CreateTreatAsPointAttr(True)
    UsdLux.SphereLight(stage.GetPrimAtPath(BULB)).CreateNormalizeAttr(True)
    pi.GetScalesAttr().Set([Gf.Vec3f(*s) for s in [(1, 1, 1), (0, 0, 0), (0.5, 0.5, 0.5), (2, 1, 1.5)]])
    stage.GetRootLayer().Save()
    d = load_stage(str(tmp_path / "lamps.usda"))
    assert sorted(_by_path(d)) == [f"{BULB}[2]", f"{PANEL}[3]"]
    assert d.stats["instanced_lights"] == 2


def test_nested_instancers_compose_and_name_both_levels(tmp_path):
    stage = _base(tmp_path / "nested.usda")
    inner_path = "/World/Street/Protos/Post"
    _bulb(stage, f"{inner_path}/Protos/Lamp/Light")
    inner = add_point_instancer(stage, inner_path, [f"{inner_path}/Protos/Lamp"], [0, 0],
                                [(0, 1, 0), (0, 2, 0)], ids=[7, 9])
    inner.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 0.25))
    add_point_instancer(stage, "/World/Street", [inner_path], [0, 0, 0],
                        [(-2, 0, 0), (0, 0, 0), (2, 0, 0)], scales=[(1, 1, 1), (1, 2, 1), (1, 1, 1)])
    stage.GetRootLayer().Save()
    lights = _by_path(load_stage(str(tmp_path / "nested.usda")))
    light = f"{inner_path}/Protos/Lamp/Light"
    assert len(lights) == 6
    for i, x, sy in ((0, -2.0, 1.0), (1, 0.0, 2.0), (2, 2.0, 1.0)):
        for j, y in ((7, 1.0), (9, 2.0)):
            want = _T(x, 0, 0) @ _S(1, sy, 1) @ _T(0, 0, 0.25) @ _T(0, y, 0) @ BULB_LIGHT_XF
            np.testing.assert_allclose(lights[f"{light}[{i}][{j}]"].light_to_world, want, atol=1e-12)


def test_a_light_that_is_itself_the_prototype(tmp_path):
    stage = _base(tmp_path / "root.usda")
    _bulb(stage, "/World/Fireflies/Protos/Fly")     # its own xform is the prototype xform
    add_point_instancer(stage, "/World/Fireflies", ["/World/Fireflies/Protos/Fly"], [0, 0],
                        [(1, 1, 1), (-1, 2, 0)], orientations=[(0.5, 0.5, 0.5, 0.5)] * 2, scales=[(2, 2, 2)] * 2)
    stage.GetRootLayer().Save()
    lights = _by_path(load_stage(str(tmp_path / "root.usda")))
    want = _T(-1, 2, 0) @ _Q(0.5, 0.5, 0.5, 0.5) @ _S(2, 2, 2) @ BULB_LIGHT_XF
    np.testing.assert_allclose(lights["/World/Fireflies/Protos/Fly[1]"].light_to_world, want, atol=1e-12)
    assert len(lights) == 2


def test_a_prototype_shared_by_two_instancers_gets_distinct_paths(tmp_path):
    stage = _base(tmp_path / "shared.usda")
    scope = stage.DefinePrim("/Protos")
    scope.SetSpecifier(Sdf.SpecifierClass)   # not rendered itself
    _bulb(stage, "/Protos/Lamp/Light")
    for name, x in (("A", -2.0), ("B", 2.0)):
        add_point_instancer(stage, f"/World/{name}", ["/Protos/Lamp"], [0], [(x, 0, 0)])
    stage.GetRootLayer().Save()
    lights = _by_path(load_stage(str(tmp_path / "shared.usda")))
    assert sorted(lights) == ["/Protos/Lamp/Light[/World/A:0]", "/Protos/Lamp/Light[/World/B:0]"]
    assert lights["/Protos/Lamp/Light[/World/B:0]"].light_to_world[0, 3] == pytest.approx(2.0)


def test_prototype_light_linking_applies_to_every_instance(tmp_path):
    stage = _instanced_stage(tmp_path / "lamps.usda")
    UsdGeom.Sphere.Define(stage, "/World/Ball")
    api = UsdLux.LightAPI(stage.GetPrimAtPath(BULB))
    api.GetLightLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/Ball")
    api.GetShadowLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/Floor")
    stage.GetRootLayer().Save()
    lights = _by_path(load_stage(str(tmp_path / "lamps.usda")))
    for i in range(3):
        assert lights[f"{BULB}[{i}]"].light_link_excludes == frozenset({"/World/Ball"})
        assert lights[f"{BULB}[{i}]"].shadow_link_excludes == frozenset({"/World/Floor"})
    assert lights[f"{PANEL}[3]"].light_link_excludes is None


def test_mesh_lights_in_prototypes_are_still_skipped_with_a_warning(tmp_path):
    stage = _instanced_stage(tmp_path / "lamps.usda")
    glow = UsdGeom.Sphere.Define(stage, f"{LAMPS}/Protos/Bulb/Glow")
    UsdLux.MeshLightAPI.Apply(glow.GetPrim())
    stage.GetRootLayer().Save()
    d = load_stage(str(tmp_path / "lamps.usda"))
    assert len(d.lights) == 4 and all(light.kind != "mesh" for light in d.lights)
    assert any("Glow" in w and "mesh lights inside PointInstancer" in w for w in d.warnings)


# --------------------------------------------------------------------------------------
# Native instancing (instanceable references): lights keep working through instance proxies
# --------------------------------------------------------------------------------------
def test_lights_in_instanceable_references(tmp_path):
    stage = _base(tmp_path / "native.usda")
    stage.DefinePrim("/Lib").SetSpecifier(Sdf.SpecifierClass)
    UsdGeom.Xform.Define(stage, "/Lib/Lamp")
    _bulb(stage, "/Lib/Lamp/Light")
    UsdLux.LightAPI(stage.GetPrimAtPath("/Lib/Lamp/Light")).GetLightLinkCollectionAPI() \
        .CreateExcludesRel().AddTarget("/World/Floor")
    # a PointInstancer inside the instanced asset: each native instance has its own lamps
    _bulb(stage, "/Lib/Lamp/Row/Protos/P/Light")
    add_point_instancer(stage, "/Lib/Lamp/Row", ["/Lib/Lamp/Row/Protos/P"], [0, 0], [(1, 0, 0), (2, 0, 0)])
    for name, x in (("A", -3.0), ("B", 3.0)):
        inst = UsdGeom.Xform.Define(stage, f"/World/{name}")
        inst.AddTranslateOp().Set(Gf.Vec3d(x, 1.0, 0.0))
        inst.GetPrim().GetReferences().AddInternalReference("/Lib/Lamp")
        inst.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    lights = _by_path(load_stage(str(tmp_path / "native.usda")))
    assert sorted(lights) == sorted([f"/World/{n}/{p}" for n in "AB" for p in
                                     ("Light", "Row/Protos/P/Light[0]", "Row/Protos/P/Light[1]")])
    np.testing.assert_allclose(lights["/World/B/Light"].light_to_world, _T(3, 1, 0) @ BULB_LIGHT_XF, atol=1e-12)
    np.testing.assert_allclose(lights["/World/A/Row/Protos/P/Light[1]"].light_to_world,
                               _T(-3, 1, 0) @ _T(2, 0, 0) @ BULB_LIGHT_XF, atol=1e-12)
    assert lights["/World/A/Light"].light_link_excludes == frozenset({"/World/Floor"})
    assert lights["/World/A/Row/Protos/P/Light[0]"].light_link_excludes is None


# --------------------------------------------------------------------------------------
# Render: instanced lights light the scene exactly as the same lights authored one by one
# --------------------------------------------------------------------------------------
def _image(path, seed, **estimator):
    opt = RenderOptions(spp=8, max_depth=1, seed=seed, threads=1, estimator={"": "mis", **estimator})
    res = render(str(path), opt)
    return res.film.mean().mean(axis=-1), res.stats


def test_render_matches_individually_authored_lights(tmp_path):
    _instanced_stage(tmp_path / "inst.usda")
    _individual_stage(tmp_path / "single.usda")
    # normalize without the instance scale would make the panel 3x brighter
    _individual_stage(tmp_path / "wrong.usda", panel_intensity=3.0 * PANEL_INTENSITY)
    # an estimator override addressed to one instance by its path
    inst, stats = _image(tmp_path / "inst.usda", 1, **{f"{PANEL}[3]": "lightSampling"})
    single, _ = _image(tmp_path / "single.usda", 2)
    wrong, _ = _image(tmp_path / "wrong.usda", 3)
    by_path = {li["path"]: li for li in stats["lights"]}
    assert sorted(by_path) == sorted([f"{BULB}[0]", f"{BULB}[1]", f"{BULB}[2]", f"{PANEL}[3]"])
    assert by_path[f"{PANEL}[3]"]["estimator"] == "lightSampling" and by_path[f"{BULB}[0]"]["estimator"] == "mis"
    # independent seeds: per-pixel differences are independent with mean 0 when both stages
    # have the same expected image
    assert inst.mean() > 0.05
    p = z_test(inst - single, 0.0)
    assert p > SIGNIFICANCE, (p, inst.mean(), single.mean())
    assert z_test(inst - wrong, 0.0) < SIGNIFICANCE, "the comparison must detect a 3x panel"
    # and with one seed and one estimator the two stages are the same scene, sample for sample
    same, _ = _image(tmp_path / "inst.usda", 2)
    np.testing.assert_allclose(same, single, rtol=0, atol=1e-5)
