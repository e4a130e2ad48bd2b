"""UsdPreviewSurface ``normal``: tangent-space normal maps (renderer/geometry.py perturb_normals).

The map's texels go through the UsdUVTexture's own scale/bias only (the spec: the texture reader
delivers a "properly scaled" [-1, 1] vector); the tangent follows +u (dp/du), the bitangent +v
with the UV handedness. A floor under a delta DistantLight at max depth 1 has a deterministic
radiance per camera ray, E f(wo, wi) cos(wi, n'), so a normal-mapped flat floor must render like
a floor whose geometry is tilted to n' (same camera rays, same wo and wi), and like the closed
form evaluated with the BSDF in n's frame.
"""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.geometry import coordinate_frame, perturb_normals, uv_tangents
from renderer.render import RenderOptions, render
from renderer.usd import load_stage
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material

ALBEDO = 0.6
E_SUN = 3.0  # irradiance at normal incidence of the delta DistantLight
H = 0.5      # floor half-size
# The sun stages sit away from the origin: a tilted floor through the origin shows shadow acne
# (accel.ray_epsilon scales with |p|, small there, not with the triangle's vertex magnitudes).
CENTER = np.array([3.0, 0.0, 2.0])


def _write_exr(path, rgb) -> str:
    """A 2x2 float EXR of one constant RGB texel value."""
    px = np.ascontiguousarray(np.broadcast_to(np.asarray(rgb, dtype=np.float32), (2, 2, 3)))
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), oiio.ImageSpec(2, 2, 3, oiio.FLOAT)), oiio.geterror()
    assert out.write_image(px), out.geterror()
    out.close()
    return str(path)


def _add_normal_map(stage, material_path, file, encoded=True):
    """Connect a UsdUVTexture (reading primvar st) to the material's PBR ``inputs:normal``.
    encoded: the file holds (n + 1) / 2 and the texture's scale (2, 2, 2, 1), bias (-1, -1, -1, 0)
    decode it, as studio assets author it; otherwise the file holds n itself."""
    pbr = UsdShade.Shader.Get(stage, material_path + "/PBR")
    reader = UsdShade.Shader.Define(stage, material_path + "/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    tex = UsdShade.Shader.Define(stage, material_path + "/NormalTex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2))
    if encoded:
        tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
        tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
    rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    pbr.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(rgb)


# World direction of +u and +v on the floor (facing +Y) for each st layout.
LAYOUTS = {
    "plain": ((1, 0, 0), (0, 0, -1)),     # u along +x, v along -z
    "mirrored": ((-1, 0, 0), (0, 0, -1)),  # u reversed: left-handed UVs
    "rotated": ((0, 0, -1), (-1, 0, 0)),   # the plain layout turned 90 degrees
}


def _floor(stage, layout="plain", normal=(0.0, 1.0, 0.0), with_st=True, path="/World/Floor", center=(0, 0, 0)):
    """A square floor through ``center`` facing ``normal`` (its points tilted to that plane),
    with st laid out per LAYOUTS (affine in the floor's x and z)."""
    n = np.asarray(normal, dtype=np.float64)
    n /= np.linalg.norm(n)
    # A basis of the plane that reduces to (+x, -z) for the flat floor.
    a = np.cross(n, (0.0, 0.0, 1.0)) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)  # a x b = n: counter-clockwise seen from the front
    corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    c = np.asarray(center, dtype=np.float64)
    pts = [tuple(c + H * (i * a + j * b)) for i, j in corners]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateSubdivisionSchemeAttr("none")
    if with_st:
        u_dir, v_dir = (np.asarray(x, dtype=np.float64) for x in LAYOUTS[layout])
        st = [(0.5 + np.dot(p - c, u_dir) / (2 * H), 0.5 + np.dot(p - c, v_dir) / (2 * H)) for p in np.asarray(pts)]
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.vertex)
        pv.Set([Gf.Vec2f(*map(float, x)) for x in st])
    return mesh


def _sun_stage(path, toward_light, *, nmap=None, layout="plain", tilt=None, with_st=True, tmp_path=None):
    """A grey roughness-1 floor seen straight down through a narrow camera, under a delta
    DistantLight shining from ``toward_light``. nmap: tangent-space normal of a constant map
    (None: no map); tilt: the floor's geometric normal (None: +Y)."""
    stage = new_stage(path)
    add_camera(stage, pos=tuple(CENTER + (0, 6, 0)), focal=100.0, aperture=2.0, tilt_x=-90.0)
    add_settings(stage, (8, 8))
    floor = _floor(stage, layout, normal=tilt or (0.0, 1.0, 0.0), with_st=with_st, center=CENTER)
    look = preview_material(stage, "/World/Looks/Grey", diffuse=(ALBEDO,) * 3, roughness=1.0)
    if nmap is not None:
        enc = (np.asarray(nmap, dtype=np.float64) + 1.0) / 2.0
        _add_normal_map(stage, "/World/Looks/Grey", _write_exr(tmp_path / "n.exr", enc))
    bind(floor.GetPrim(), look)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateAngleAttr(0.0)
    sun.CreateIntensityAttr(E_SUN)
    # The light shines along its local -Z: map local +Z onto the direction toward the light.
    z = np.asarray(toward_light, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.cross((0.0, 0.0, 1.0), z) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    UsdGeom.Xformable(sun).AddTransformOp().Set(Gf.Matrix4d(*x, 0, *y, 0, *z, 0, 0, 0, 0, 1))
    stage.GetRootLayer().Save()
    return str(path)


def _render_sun(stage, **kw):
    return render(stage, RenderOptions(spp=4, max_depth=1, threads=1, seed=3, **kw))


def _closed_form(n_world, toward_light, wo=(0.0, 1.0, 0.0)) -> float:
    """E f(wo, wi) cos(wi, n') of the floor's BSDF in the frame of n' (one channel)."""
    n = np.asarray([n_world], dtype=np.float64)
    n /= np.linalg.norm(n)
    s, t = coordinate_frame(n)
    wi = np.asarray([toward_light], dtype=np.float64)
    wi /= np.linalg.norm(wi)
    wo = np.asarray([wo], dtype=np.float64)
    loc = lambda v: np.stack([(v * s).sum(1), (v * t).sum(1), (v * n).sum(1)], axis=1)  # noqa: E731
    bsdf = PreviewSurfaceBSDF.from_inputs(np.full((1, 3), ALBEDO), np.zeros((1, 3)), np.zeros(1, bool),
                                          np.zeros(1), np.ones(1), np.full(1, 1.5))
    wi_l = loc(wi)
    return float(E_SUN * bsdf.f(loc(wo), wi_l)[0, 0] * max(wi_l[0, 2], 0.0))


def _tilt(deg, axis):
    """Tangent-space unit normal tilted by ``deg`` from +z toward +x ('u') or +y ('v')."""
    a = np.radians(deg)
    return (np.sin(a), 0.0, np.cos(a)) if axis == "u" else (0.0, np.sin(a), np.cos(a))


def _expected_world(layout, nmap):
    u_dir, v_dir = (np.asarray(x, dtype=np.float64) for x in LAYOUTS[layout])
    return nmap[0] * u_dir + nmap[1] * v_dir + nmap[2] * np.array([0.0, 1.0, 0.0])


# ---- 1. a flat map is no map -------------------------------------------------------------------
def test_flat_normal_map_renders_identically(tmp_path):
    """A map of (0, 0, 1) everywhere leaves every shading normal bit for bit as it was: the
    image equals the unmapped one (same seed, same estimator path)."""
    def stage(path, mapped):
        st = new_stage(path)
        add_camera(st, pos=(0, 1.5, 5.0))
        add_settings(st, (16, 12))
        floor = _floor(st, "plain")
        look = preview_material(st, "/World/Looks/Grey", diffuse=(0.6, 0.5, 0.4), roughness=0.4)
        if mapped:
            _add_normal_map(st, "/World/Looks/Grey", _write_exr(tmp_path / "flat.exr", (0, 0, 1)), encoded=False)
        bind(floor.GetPrim(), look)
        light = UsdLux.RectLight.Define(st, "/World/Light")
        light.CreateIntensityAttr(8.0)
        xf = UsdGeom.Xformable(light)
        xf.AddTranslateOp().Set(Gf.Vec3d(0.5, 2.0, 0.0))
        xf.AddRotateXOp().Set(-70.0)
        st.GetRootLayer().Save()
        return str(path)

    opt = RenderOptions(spp=4, max_depth=3, threads=1, seed=11, fast_path=False)
    plain = render(stage(tmp_path / "plain.usda", False), opt)
    mapped = render(stage(tmp_path / "mapped.usda", True), opt)
    assert not any("normal" in w for w in mapped.warnings)
    a, b = plain.film.mean(), mapped.film.mean()
    assert a.sum() > 0.0
    assert np.array_equal(a, b)


# ---- 2. the cosine law about the tangent -------------------------------------------------------
def test_tilted_normal_follows_the_cosine_law(tmp_path):
    """Normal tilted 25 degrees about the tangent (toward +v = -z); sun 40 degrees from the
    zenith toward -z: the floor's radiance is E f cos(15 degrees) in the tilted frame, and the
    unmapped floor's E f cos(40 degrees)."""
    toward = (0.0, np.cos(np.radians(40)), -np.sin(np.radians(40)))
    nmap = _tilt(25, "v")
    flat = _render_sun(_sun_stage(tmp_path / "flat.usda", toward, tmp_path=tmp_path)).film.mean()[..., 0]
    bent = _render_sun(_sun_stage(tmp_path / "bent.usda", toward, nmap=nmap, tmp_path=tmp_path)).film.mean()[..., 0]
    want_flat = _closed_form((0.0, 1.0, 0.0), toward)
    want_bent = _closed_form(_expected_world("plain", nmap), toward)
    # The cosines themselves: the tilted normal sees the sun at 15 degrees.
    assert np.isclose(np.dot(_expected_world("plain", nmap), toward), np.cos(np.radians(15)))
    np.testing.assert_allclose(flat, want_flat, rtol=2e-3)
    np.testing.assert_allclose(bent, want_bent, rtol=2e-3)
    assert want_bent / want_flat > 1.2  # the check can tell the two apart


SUN_3 = (0.55, 0.8, -0.25)  # toward the sun in test 3 (normalised where used)


# ---- 3. the tangent follows +u -----------------------------------------------------------------
@pytest.mark.parametrize("layout,axis", [("plain", "u"), ("mirrored", "u"), ("rotated", "u"),
                                         ("plain", "v"), ("mirrored", "v"), ("rotated", "v")])
def test_tilt_follows_texture_space(tmp_path, layout, axis):
    """A map tilted 30 degrees toward +u (or +v), sun from +x, a little toward -z: the
    normal-mapped flat floor renders like a floor whose geometry is tilted to the world
    direction of +u (+v) in that UV layout (mirrored UVs flip u, not v; rotated UVs turn both),
    pixel for pixel, and like the closed form. The sun sees each of the four tilt directions
    (+-x, +-z) at a different angle, so a tangent or bitangent of the wrong sign shows."""
    toward = SUN_3
    nmap = _tilt(30, axis)
    n_world = _expected_world(layout, nmap)
    bent = _render_sun(_sun_stage(tmp_path / "bent.usda", toward, nmap=nmap, layout=layout,
                                  tmp_path=tmp_path)).film.mean()[..., 0]
    tilted = _render_sun(_sun_stage(tmp_path / "tilted.usda", toward, tilt=tuple(n_world),
                                    tmp_path=tmp_path)).film.mean()[..., 0]
    np.testing.assert_allclose(bent, tilted, rtol=1e-5)
    want = _closed_form(n_world, toward)
    np.testing.assert_allclose(bent, want, rtol=2e-3)
    # The other three tilt directions would each be at least 5 % off.
    for other in (-n_world * [1, 0, 1] + [0, n_world[1], 0], n_world[[2, 1, 0]], -n_world[[2, 1, 0]] * [1, -1, 1]):
        assert abs(_closed_form(other, toward) / want - 1.0) > 0.05


# ---- 4. no st: a warning and no perturbation ----------------------------------------------------
def test_normal_map_without_st_warns_and_renders_unperturbed(tmp_path):
    toward = (np.sin(np.radians(35)), np.cos(np.radians(35)), 0.0)
    plain = _render_sun(_sun_stage(tmp_path / "plain.usda", toward, with_st=False, tmp_path=tmp_path))
    mapped = _render_sun(_sun_stage(tmp_path / "mapped.usda", toward, nmap=_tilt(30, "u"), with_st=False,
                                    tmp_path=tmp_path))
    msgs = [w for w in mapped.warnings if "normal" in w]
    assert len(msgs) == 1 and "/World/Floor" in msgs[0] and "st" in msgs[0]
    assert msgs[0] in mapped.stats["warnings"]
    assert np.array_equal(plain.film.mean(), mapped.film.mean())


# ---- 5. the fast path serves normal maps (tests/integrators/test_fast_path_materials.py) ---------
def test_fast_path_serves_normal_mapped_materials(tmp_path):
    path = _sun_stage(tmp_path / "bent.usda", SUN_3, nmap=_tilt(30, "u"), tmp_path=tmp_path)
    fast = render(path, RenderOptions(spp=4, max_depth=2, threads=1, seed=3, estimator={"": "mis"}))
    assert fast.stats["fast_path"] == "on"
    # One bounce off a lone floor under a delta sun: the closed form of the bent normal.
    np.testing.assert_allclose(fast.film.mean()[..., 0], _closed_form(_expected_world("plain", _tilt(30, "u")), SUN_3),
                               rtol=2e-3)


# ---- 6. oblique views: the bent normal is corrected continuously (issue 19, item 9) -------------
def test_corrected_normal_is_continuous_and_mirrors_above_the_surface():
    """A normal tilted 30, 60 or 80 degrees seen from every elevation on both sides: the shading
    normal perturb_normals gives faces the viewer, mirrors wo at least min(0.01, 0.9 wo.ng)
    above the surface, moves by at most ~ the step of wo between neighbouring views (replacing it
    by ng where it faced away jumped by the whole tilt), and is the map's normal itself wherever
    that already mirrors wo high enough."""
    fn = np.array([[0.0, 0.0, 1.0]])
    tangent, handed = uv_tangents(np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]]),
                                  np.array([[[0.0, 0], [1, 0], [0, 1]]]))
    # From grazing on the +u side over the top to grazing on the -u side.
    phi = np.radians(np.linspace(0.5, 179.5, 3000))
    wo = np.stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=1)
    m = wo.shape[0]
    step = np.max(np.linalg.norm(np.diff(wo, axis=0), axis=1))
    for tilt in (30, 60, 80):
        t = np.radians(tilt)
        nmap = np.tile([np.sin(t), 0.0, np.cos(t)], (m, 1))
        n = perturb_normals(np.tile(fn, (m, 1)), np.tile(fn, (m, 1)), wo, nmap, np.ones(m, bool),
                            np.zeros(m, np.int64), tangent, handed, fn)
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
        cos_o = (n * wo).sum(1)
        assert np.all(cos_o > 0.0)
        r_z = 2.0 * cos_o * n[:, 2] - wo[:, 2]
        assert np.all(r_z >= np.minimum(0.01, 0.9 * wo[:, 2]) - 1e-12)
        assert np.max(np.linalg.norm(np.diff(n, axis=0), axis=1)) < 2.0 * step
        r_m = 2.0 * (nmap * wo).sum(1) * nmap[:, 2] - wo[:, 2]
        keep = r_m >= 0.01
        assert keep.any() and not keep.all()
        np.testing.assert_allclose(n[keep], nmap[keep], atol=1e-12)


def test_rim_has_no_jump_where_the_bent_normal_turns_away(tmp_path):
    """A floor whose map tilts every normal 60 degrees toward +u, seen from the -u side at
    elevations 48-68 degrees (the bent normal turns away from the viewer at 60), under a delta sun
    from that side at 40 degrees, one bounce: each pixel is E f cos of its corrected normal, and
    the image's rows change smoothly. Snapping the normal to the geometric one where it turned
    away lit the rows below 60 degrees at E f sin(40) and left the others black: a bright rim."""
    stage = new_stage(tmp_path / "rim.usda")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(100.0)
    cam.CreateHorizontalApertureAttr(6.0)  # the 8 x 48 image's aspect: 20 degrees tall
    cam.CreateVerticalApertureAttr(36.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 100.0))
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(*(CENTER + (-0.375, 0.6, 0.0))))
    xf.AddRotateYOp().Set(-90.0)
    xf.AddRotateXOp().Set(-58.0)
    add_settings(stage, (8, 48))
    floor = _floor(stage, "plain", center=CENTER)
    look = preview_material(stage, "/World/Looks/Grey", diffuse=(ALBEDO,) * 3, roughness=1.0)
    _add_normal_map(stage, "/World/Looks/Grey", _write_exr(tmp_path / "n.exr", (np.array(_tilt(60, "u")) + 1) / 2))
    bind(floor.GetPrim(), look)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateAngleAttr(0.0)
    sun.CreateIntensityAttr(E_SUN)
    # Local -Z shines along (cos 40, -sin 40, 0): from the -x side, 40 degrees up.
    UsdGeom.Xformable(sun).AddRotateYOp().Set(-90.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-40.0)
    stage.GetRootLayer().Save()
    img = _render_sun(str(tmp_path / "rim.usda")).film.mean()[..., 0]
    rows = img[:, 3:5].mean(axis=1)
    scale = E_SUN * ALBEDO / np.pi
    assert rows.max() > 0.2 * scale  # lit: the corrected normals lean toward the sun
    assert np.all(rows <= scale * (1 + 1e-6))
    # 48 rows over 20 degrees: a smooth profile moves a few percent of E f a row.
    assert np.max(np.abs(np.diff(rows))) < 0.1 * scale, np.round(rows / scale, 3)


# ---- reader and kernel details ------------------------------------------------------------------
def test_reader_keeps_the_normal_input(tmp_path):
    toward = (0.0, 1.0, 0.0)
    path = _sun_stage(tmp_path / "s.usda", toward, nmap=_tilt(30, "u"), tmp_path=tmp_path)
    desc = load_stage(path)
    (mat,) = [m for m in desc.materials if m.path == "/World/Looks/Grey"]
    assert mat.normal.texture is not None
    assert tuple(mat.normal.texture.scale) == (2.0, 2.0, 2.0, 1.0)
    assert not any("'normal' is ignored" in w for w in desc.warnings)


def test_back_side_mirrors_the_front_and_degenerate_uvs_keep_n():
    """Seen from below, the bent normal is the front one mirrored through the surface plane
    (a bump seen from behind is a dent); a triangle whose st are collinear has no frame."""
    v = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]],      # z = 0, facing +z; u = +x, v = +y
                  [[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    st = np.array([[[0.0, 0], [1, 0], [0, 1]],
                   [[0.0, 0], [1, 1], [2, 2]]])           # collinear: degenerate
    tangent, handed = uv_tangents(v, st)
    np.testing.assert_allclose(tangent[0], [1, 0, 0])
    assert handed.tolist() == [1.0, 0.0]
    fn = np.array([[0.0, 0, 1], [0.0, 0, 1]])
    m = np.array([[0.3, 0.4, np.sqrt(0.75)]] * 2)
    prim = np.array([0, 0])
    up, down = np.array([0.0, 0, 1]), np.array([0.0, 0, -1])
    ns = np.array([up, down])
    wo = np.array([normalize3(0.1, 0.2, 1.0), normalize3(0.1, 0.2, -1.0)])
    out = perturb_normals(ns, ns.copy(), wo, m, np.array([True, True]), prim, tangent, handed, fn)
    np.testing.assert_allclose(out[0], m[0], atol=1e-12)
    np.testing.assert_allclose(out[1], m[0] * [1, 1, -1], atol=1e-12)
    kept = perturb_normals(ns[:1], ns[:1].copy(), wo[:1], m[:1], np.array([True]), np.array([1]), tangent,
                           handed, fn)
    assert np.array_equal(kept, ns[:1])
    unmapped = perturb_normals(ns[:1], ns[:1].copy(), wo[:1], m[:1], np.array([False]), prim[:1], tangent,
                               handed, fn)
    assert np.array_equal(unmapped, ns[:1])


def normalize3(x, y, z):
    v = np.array([x, y, z], dtype=np.float64)
    return v / np.linalg.norm(v)
