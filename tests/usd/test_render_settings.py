"""UsdRender settings, RenderProduct overrides, and IllumRenderSettingsAPI."""

import pytest
from pxr import Gf, UsdGeom, UsdRender

from renderer.description import RenderSettingsDesc
from renderer.errors import SettingsError, StageError

from .helpers import read


def _settings(stage, path="/Render/Settings", metadata=True):
    s = UsdRender.Settings.Define(stage, path)
    if metadata:
        stage.SetMetadata("renderSettingsPrimPath", path)
    return s


def test_no_settings_gives_defaults(stage):
    d = read(stage)
    assert d.settings == RenderSettingsDesc()


def test_settings_values(stage):
    UsdGeom.Camera.Define(stage, "/Shot")
    s = _settings(stage)
    s.CreateResolutionAttr(Gf.Vec2i(1920, 800))
    s.CreatePixelAspectRatioAttr(2.0)
    s.CreateAspectRatioConformPolicyAttr("cropAperture")
    s.CreateDataWindowNDCAttr(Gf.Vec4f(0.1, 0.2, 0.9, 1.0))
    s.CreateCameraRel().AddTarget("/Shot")
    s.CreateMaterialBindingPurposesAttr(["preview", ""])
    d = read(stage).settings
    assert d.path == "/Render/Settings"
    assert d.resolution == (1920, 800) and d.pixel_aspect_ratio == 2.0
    assert d.aspect_ratio_conform_policy == "cropAperture"
    assert d.data_window_ndc == pytest.approx((0.1, 0.2, 0.9, 1.0))
    assert d.camera == "/Shot" and d.material_binding_purposes == ("preview", "")
    assert d.included_purposes == ("default", "render")
    assert d.product_name == "" and d.light_sampler == ""


def test_first_product_overrides_where_authored(stage):
    UsdGeom.Camera.Define(stage, "/CamA")
    UsdGeom.Camera.Define(stage, "/CamB")
    s = _settings(stage)
    s.CreateResolutionAttr(Gf.Vec2i(1000, 500))
    s.CreatePixelAspectRatioAttr(1.5)
    s.CreateCameraRel().AddTarget("/CamA")
    p1 = UsdRender.Product.Define(stage, "/Render/Beauty")
    p1.CreateResolutionAttr(Gf.Vec2i(200, 100))
    p1.CreateCameraRel().AddTarget("/CamB")
    p1.CreateProductNameAttr("beauty.####.exr")
    p2 = UsdRender.Product.Define(stage, "/Render/Other")
    p2.CreateProductNameAttr("other.exr")
    s.CreateProductsRel().SetTargets(["/Render/Beauty", "/Render/Other"])
    d = read(stage)
    assert d.settings.resolution == (200, 100)  # product
    assert d.settings.pixel_aspect_ratio == 1.5  # settings (product's is unauthored)
    assert d.settings.camera == "/CamB" and d.camera.path == "/CamB"
    assert d.settings.product_name == "beauty.####.exr"
    assert any("only the first" in w for w in d.warnings)


def test_settings_argument_beats_metadata(stage):
    _settings(stage, "/Render/A").CreateResolutionAttr(Gf.Vec2i(10, 10))
    _settings(stage, "/Render/B", metadata=False).CreateResolutionAttr(Gf.Vec2i(20, 20))
    assert read(stage).settings.resolution == (10, 10)
    assert read(stage, settings="/Render/B").settings.resolution == (20, 20)


def test_missing_settings_prim(stage):
    with pytest.raises(StageError) as err:
        read(stage, settings="/Render/Nope")
    assert err.value.prim == "/Render/Nope"
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Gone")
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.prim == "/Render/Gone" and "renderSettingsPrimPath" in str(err.value)


@pytest.mark.parametrize("res", [(0, 100), (100, -1), (16385, 10), (9000, 9000)])
def test_resolution_limits(stage, res):
    _settings(stage).CreateResolutionAttr(Gf.Vec2i(*res))
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Render/Settings", "resolution")


def test_resolution_limit_on_product_names_product(stage):
    s = _settings(stage)
    p = UsdRender.Product.Define(stage, "/Render/P")
    p.CreateResolutionAttr(Gf.Vec2i(0, 0))
    s.CreateProductsRel().AddTarget("/Render/P")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Render/P", "resolution")


def test_max_resolution_accepted(stage):
    _settings(stage).CreateResolutionAttr(Gf.Vec2i(16384, 4096))  # exactly 64 Mpixel
    assert read(stage).settings.resolution == (16384, 4096)


def test_bad_data_window_and_pixel_aspect(stage):
    s = _settings(stage)
    s.CreateDataWindowNDCAttr(Gf.Vec4f(0.5, 0, 0.5, 1))
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.attribute == "dataWindowNDC"
    s.GetDataWindowNDCAttr().Clear()
    s.CreatePixelAspectRatioAttr(0.0)
    with pytest.raises(StageError) as err:
        read(stage)
    assert err.value.attribute == "pixelAspectRatio"


def test_bad_cli_purpose_is_a_settings_error(stage):
    with pytest.raises(SettingsError):
        read(stage, purposes=("beauty",))


def test_light_sampler(stage):
    s = _settings(stage)
    s.GetPrim().ApplyAPI("IllumRenderSettingsAPI")
    assert read(stage).settings.light_sampler == ""  # unauthored: the renderer chooses
    s.GetPrim().GetAttribute("illum:lightSampler").Set("bvh")
    assert read(stage).settings.light_sampler == "bvh"
    s.GetPrim().GetAttribute("illum:lightSampler").Set("fastest")
    with pytest.raises(StageError) as err:
        read(stage)
    assert (err.value.prim, err.value.attribute) == ("/Render/Settings", "illum:lightSampler")
