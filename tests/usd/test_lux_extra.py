"""Reading mesh lights (MeshLightAPI, materialSyncMode), dome portals, cylinder lights and light
filters into LightDescs."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.errors import StageError
from tests.usd.helpers import add_quad, mesh, read


def glow_material(stage, path="/Looks/Glow", emissive=(1.0, 0.25, 0.5), diffuse=(0.4, 0.4, 0.4)):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/PBR")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if emissive is not None:
        sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def mesh_light(stage, path="/Glow", mode=None, material=None, **light):
    m = add_quad(stage, path, z=1.0, size=2.0)
    UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(0.5, 0.0, 0.0))
    UsdLux.MeshLightAPI.Apply(m.GetPrim())
    api = UsdLux.LightAPI(m.GetPrim())
    for name, value in light.items():
        m.GetPrim().GetAttribute(f"inputs:{name}").Set(value)
    if mode is not None:
        api.GetMaterialSyncModeAttr().Set(mode)
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def light_of(d, path):
    found = [x for x in d.lights if x.path == path]
    assert len(found) == 1, [x.path for x in d.lights]
    return found[0]


def test_mesh_light_has_the_meshs_world_triangles(stage):
    mesh_light(stage, intensity=5.0)
    d = read(stage)
    light = light_of(d, "/Glow")
    geo = mesh(d, "/Glow")
    assert light.kind == "mesh" and light.mesh_path == "/Glow"
    np.testing.assert_array_equal(light.mesh_triangles, geo.points[geo.triangles])
    assert light.mesh_triangles[:, :, 0].min() == 0.5  # the xform is applied
    assert light.intensity == 5.0 and light.material_sync_mode == "materialGlowTintsLight"
    assert not light.mesh_two_sided


def test_glow_tints_light_and_moves_the_glow_into_the_light(stage):
    mat = glow_material(stage)
    mesh_light(stage, material=mat, color=Gf.Vec3f(0.5, 1.0, 1.0))
    d = read(stage)
    light = light_of(d, "/Glow")
    np.testing.assert_allclose(light.color, (0.5, 0.25, 0.5))
    # The surface keeps its diffuse response but not its glow (counted once, as the light).
    m = d.materials[mesh(d, "/Glow").material]
    assert m.emissive_color.value == (0.0, 0.0, 0.0) and m.diffuse_color.value == pytest.approx((0.4, 0.4, 0.4))


def test_independent_keeps_the_material_glow(stage):
    mat = glow_material(stage)
    mesh_light(stage, mode="independent", material=mat, color=Gf.Vec3f(0.5, 1.0, 1.0))
    d = read(stage)
    assert light_of(d, "/Glow").color == pytest.approx((0.5, 1.0, 1.0))
    assert d.materials[mesh(d, "/Glow").material].emissive_color.value == pytest.approx((1.0, 0.25, 0.5))


def test_no_material_response_is_black(stage):
    mat = glow_material(stage)
    mesh_light(stage, mode="noMaterialResponse", material=mat)
    d = read(stage)
    light = light_of(d, "/Glow")
    m = d.materials[mesh(d, "/Glow").material]
    assert light.material_sync_mode == "noMaterialResponse" and light.color == (1.0, 1.0, 1.0)
    assert m.diffuse_color.value == (0.0, 0.0, 0.0) and m.emissive_color.value == (0.0, 0.0, 0.0)


def test_material_without_glow_leaves_the_light_untinted(stage):
    mat = glow_material(stage, emissive=None)
    mesh_light(stage, material=mat, color=Gf.Vec3f(0.2, 0.4, 0.6))
    assert light_of(read(stage), "/Glow").color == pytest.approx((0.2, 0.4, 0.6))


def test_light_api_on_a_mesh_defaults_to_no_material_response(stage):
    m = add_quad(stage, "/Panel")
    UsdLux.LightAPI.Apply(m.GetPrim())
    m.CreateDoubleSidedAttr(True)
    light = light_of(read(stage), "/Panel")
    assert light.material_sync_mode == "noMaterialResponse" and light.mesh_two_sided


def test_bad_sync_mode_names_prim_and_attribute(stage):
    m = mesh_light(stage)
    m.GetPrim().GetAttribute("light:materialSyncMode").Set("glowy")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Glow", "light:materialSyncMode")


def test_emissive_mesh_without_light_api_is_not_a_light(stage):
    m = add_quad(stage, "/Sign")
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(glow_material(stage))
    d = read(stage)
    assert d.lights == []
    assert d.materials[mesh(d, "/Sign").material].emissive_color.value == pytest.approx((1.0, 0.25, 0.5))


# ----------------------------------------------------------------------------------------
# Portals
# ----------------------------------------------------------------------------------------
def dome_with_portals(stage, *targets):
    dome = UsdLux.DomeLight.Define(stage, "/Sky")
    dome.CreatePortalsRel().SetTargets([Sdf.Path(t) for t in targets])
    return dome


def test_portals_are_read_into_the_dome(stage):
    p = UsdLux.PortalLight.Define(stage, "/Win")
    p.CreateWidthAttr(2.0)
    p.CreateHeightAttr(0.5)
    UsdGeom.Xformable(p).AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    UsdGeom.Xformable(p).AddRotateYOp().Set(90.0)
    dome_with_portals(stage, "/Win")
    d = read(stage)
    assert [x.path for x in d.lights] == ["/Sky"]  # the portal is no light
    dome = d.lights[0]
    assert dome.portal_paths == ("/Win",)
    m = dome.portals[0]
    np.testing.assert_allclose(m[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(m[:3, 0], [0, 0, -2.0], atol=1e-12)  # width along local X
    np.testing.assert_allclose(m[:3, 1], [0, 0.5, 0], atol=1e-12)
    np.testing.assert_allclose(m[:3, 2], [1.0, 0, 0], atol=1e-12)   # light passes toward -Z = world -X
    assert not [w for w in d.warnings if "Win" in w]


def test_portal_target_must_be_a_portal_light(stage):
    UsdLux.RectLight.Define(stage, "/NotAPortal")
    dome_with_portals(stage, "/NotAPortal")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Sky", "portals")
    assert "/NotAPortal" in str(err.value) and "RectLight" in str(err.value)


def test_missing_portal_target_is_an_error(stage):
    dome_with_portals(stage, "/Nowhere")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Sky", "portals")


def test_bad_portal_sizes(stage):
    UsdLux.PortalLight.Define(stage, "/Zero").CreateWidthAttr(0.0)
    dome_with_portals(stage, "/Zero")
    d = read(stage)
    assert d.lights[0].portals is None
    assert any("/Zero" in w and "zero width" in w for w in d.warnings)
    UsdLux.PortalLight.Define(stage, "/Neg").CreateHeightAttr(-1.0)
    dome_with_portals(stage, "/Zero", "/Neg")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Neg", "inputs:height")


# ----------------------------------------------------------------------------------------
# Cylinder lights and light filters
# ----------------------------------------------------------------------------------------
def test_cylinder_light_fields(stage):
    c = UsdLux.CylinderLight.Define(stage, "/Tube")
    c.CreateRadiusAttr(0.125)
    c.CreateLengthAttr(3.0)
    c.CreateTreatAsLineAttr(True)
    light = light_of(read(stage), "/Tube")
    assert (light.kind, light.radius, light.length, light.treat_as_line) == ("cylinder", 0.125, 3.0, True)


def test_negative_cylinder_radius_names_prim_and_attribute(stage):
    UsdLux.CylinderLight.Define(stage, "/Tube").CreateRadiusAttr(-0.2)
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Tube", "inputs:radius")


def test_light_filters_one_warning_per_light_with_types(stage):
    UsdLux.LightFilter.Define(stage, "/Filters/Gel")
    UsdLux.PluginLightFilter.Define(stage, "/Filters/Barn")
    c = UsdLux.CylinderLight.Define(stage, "/Tube")
    c.GetFiltersRel().SetTargets([Sdf.Path("/Filters/Gel"), Sdf.Path("/Filters/Barn")])
    m = mesh_light(stage)
    m.GetPrim().CreateRelationship("light:filters").AddTarget("/Filters/Gel")
    d = read(stage)
    msgs = [w for w in d.warnings if "filters" in w]
    assert len(msgs) == 2
    tube = [w for w in msgs if w.startswith("/Tube")][0]
    assert "/Filters/Gel (LightFilter)" in tube and "/Filters/Barn (PluginLightFilter)" in tube and "ignored" in tube
    assert any(w.startswith("/Glow") for w in msgs)


def test_empty_mesh_light_warns(stage):
    m = UsdGeom.Mesh.Define(stage, "/Empty")
    UsdLux.MeshLightAPI.Apply(m.GetPrim())
    d = read(stage)
    assert d.lights == [] and any("/Empty" in w and "no surface" in w for w in d.warnings)
