"""Small real .usda stages written with pxr for integration tests."""

from __future__ import annotations

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade


def new_stage(path: str, up: str = "Y") -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, up)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    return stage


def add_camera(stage, path="/World/Camera", pos=(0, 0, 5), focal=35.0, aperture=36.0, tilt_x=None, clip=None):
    """A square-aperture camera at pos, looking down -Z, then pitched by tilt_x degrees about X
    (negative looks down) when given; clip: (near, far) clipping range."""
    cam = UsdGeom.Camera.Define(stage, path)
    cam.CreateFocalLengthAttr(focal)
    cam.CreateHorizontalApertureAttr(aperture)
    cam.CreateVerticalApertureAttr(aperture)
    if clip is not None:
        cam.CreateClippingRangeAttr(Gf.Vec2f(*clip))
    cam.AddTranslateOp().Set(Gf.Vec3d(*pos))
    if tilt_x is not None:
        cam.AddRotateXOp().Set(float(tilt_x))
    return cam


def add_settings(stage, res=(32, 32), camera="/World/Camera"):
    s = UsdRender.Settings.Define(stage, "/Render/Settings")
    s.CreateResolutionAttr(Gf.Vec2i(*res))
    s.CreateCameraRel().SetTargets([camera])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    return s


def preview_material(stage, path, diffuse=(0.5, 0.5, 0.5), roughness=0.5, specular_workflow=False,
                     specular=(0, 0, 0), metallic=0.0):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/PBR")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    sh.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(metallic)
    if specular_workflow:
        sh.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
        sh.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*specular))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def textured_quad(stage, path: str) -> UsdGeom.Mesh:
    """A 2 x 2 quad centred on the origin in the XY plane, facing +Z, with st over [0, 1]^2."""
    quad = UsdGeom.Mesh.Define(stage, path)
    quad.CreatePointsAttr([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr("none")
    st = UsdGeom.PrimvarsAPI(quad).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    return quad


def uv_texture(stage, material_path: str, name: str, file: str, fallback=None, wrap=None) -> UsdShade.Shader:
    """A UsdUVTexture ``material_path/name`` reading ``file`` at the st primvar (through the
    UsdPrimvarReader_float2 ``material_path/UV``, made once per material); ``fallback`` (4,) and
    ``wrap`` (wrapS = wrapT) when given. Connect its outputs yourself."""
    tex = UsdShade.Shader.Define(stage, f"{material_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    if fallback is not None:
        tex.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*fallback))
    if wrap is not None:
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    reader = UsdShade.Shader.Get(stage, f"{material_path}/UV")
    if not reader:
        reader = UsdShade.Shader.Define(stage, f"{material_path}/UV")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    return tex


def bind(prim, mat):
    api = UsdShade.MaterialBindingAPI.Apply(prim)
    api.Bind(mat)


def furnace_stage(path, L=2.0, rho=1.0, res=(24, 24)):
    """A white (rho) sphere inside a constant dome of radiance L: every pixel converges to L for rho = 1."""
    stage = new_stage(path)
    add_camera(stage, pos=(0, 0, 4))
    add_settings(stage, res)
    sphere = UsdGeom.Sphere.Define(stage, "/World/Ball")
    sphere.CreateRadiusAttr(1.0)
    bind(sphere.GetPrim(), preview_material(stage, "/World/Looks/White", diffuse=(rho, rho, rho)))
    dome = UsdLux.DomeLight.Define(stage, "/World/Dome")
    dome.CreateIntensityAttr(L)
    stage.GetRootLayer().Save()
    return stage


def add_floor(stage, half=5.0, diffuse=(0.5, 0.5, 0.5), roughness=0.5):
    """A flat grey square floor at y = 0, 2 * half wide, facing +Y, at /World/Floor."""
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-half, 0, -half), (half, 0, -half), (half, 0, half), (-half, 0, half)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 3, 2, 1])
    floor.CreateSubdivisionSchemeAttr("none")
    bind(floor.GetPrim(), preview_material(stage, "/World/Looks/Grey", diffuse=diffuse, roughness=roughness))
    return floor


def quad_light_stage(path, res=(16, 16), intensity=5.0, light_kind="rect", **light_attrs):
    """A grey floor lit from above by one light; the camera looks down at it."""
    stage = new_stage(path)
    add_camera(stage, pos=(0, 6, 0), tilt_x=-90.0)
    add_settings(stage, res)
    add_floor(stage)
    if light_kind == "rect":
        light = UsdLux.RectLight.Define(stage, "/World/Light")
        light.CreateWidthAttr(light_attrs.get("width", 1.0))
        light.CreateHeightAttr(light_attrs.get("height", 1.0))
    elif light_kind == "sphere":
        light = UsdLux.SphereLight.Define(stage, "/World/Light")
        light.CreateRadiusAttr(light_attrs.get("radius", 0.5))
    else:
        raise ValueError(light_kind)
    light.CreateIntensityAttr(intensity)
    lx = UsdGeom.Xformable(light)
    lx.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    lx.AddRotateXOp().Set(-90.0)
    stage.GetRootLayer().Save()
    return stage


def add_point_instancer(stage, path, prototypes, proto_indices, positions, *, orientations=None,
                        orientationsf=None, scales=None, ids=None, invisible_ids=None):
    """A UsdGeom.PointInstancer at ``path`` over existing prototype prims.

    orientations: (w, x, y, z) tuples stored as quath; orientationsf: the same stored as quatf
    (UsdGeom >= 24.03); scales: (sx, sy, sz) tuples; ids / invisible_ids: int lists.
    """
    pi = UsdGeom.PointInstancer.Define(stage, path)
    rel = pi.CreatePrototypesRel()
    for proto in prototypes:
        rel.AddTarget(proto)
    pi.CreateProtoIndicesAttr(list(proto_indices))
    pi.CreatePositionsAttr([Gf.Vec3f(*p) for p in positions])
    if orientations is not None:
        pi.CreateOrientationsAttr([Gf.Quath(q[0], Gf.Vec3h(*q[1:])) for q in orientations])
    if orientationsf is not None:
        pi.CreateOrientationsfAttr([Gf.Quatf(q[0], Gf.Vec3f(*q[1:])) for q in orientationsf])
    if scales is not None:
        pi.CreateScalesAttr([Gf.Vec3f(*s) for s in scales])
    if ids is not None:
        pi.CreateIdsAttr(list(ids))
    if invisible_ids is not None:
        pi.CreateInvisibleIdsAttr(list(invisible_ids))
    return pi


def add_quad(stage, path, corners, mat=None, double_sided=False):
    """A one-quad polygonal mesh at ``path`` with corners (4, 3) in order; bound to mat when given,
    doubleSided authored true when asked."""
    quad = UsdGeom.Mesh.Define(stage, path)
    quad.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    quad.CreateSubdivisionSchemeAttr("none")
    if double_sided:
        quad.CreateDoubleSidedAttr(True)
    if mat is not None:
        bind(quad.GetPrim(), mat)
    return quad


def sky_room_stage(path, res=(32, 32), sky=1.0, rho=0.5):
    """Easy and hard pixels in one frame: a grey (rho) room lit only by a constant sky dome of
    radiance ``sky``, open at the front, on the right and above its right third, seen from
    outside. The sky fills the upper right of the frame (zero variance); the room's far left
    corner, under the ceiling, sees the sky only through bounces (dark and noisy)."""
    stage = new_stage(path)
    add_camera(stage, pos=(1.0, 1.2, 4.5))
    add_settings(stage, res)
    grey = preview_material(stage, "/World/Looks/Grey", diffuse=(rho, rho, rho), roughness=1.0)
    h = 2.5
    add_quad(stage, "/World/Room/Floor", [(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)], grey)
    add_quad(stage, "/World/Room/Back", [(-2, 0, -2), (2, 0, -2), (2, h, -2), (-2, h, -2)], grey)
    add_quad(stage, "/World/Room/Left", [(-2, 0, -2), (-2, h, -2), (-2, h, 2), (-2, 0, 2)], grey)
    add_quad(stage, "/World/Room/Ceiling", [(-2, h, -2), (0.6, h, -2), (0.6, h, 2), (-2, h, 2)], grey)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateIntensityAttr(sky)
    stage.GetRootLayer().Save()
    return stage
