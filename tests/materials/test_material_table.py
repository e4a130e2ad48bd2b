"""MaterialTable: packing constants, textured inputs grouped per texture, flags, presence."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from renderer.bsdfs.preview_surface import PreviewSurfaceBSDF
from renderer.description import MaterialDesc, MaterialInput, TextureDesc
from renderer.errors import StageError
from renderer.materials import B_SLOT, C_METALLIC, C_ROUGHNESS, MaterialTable, SurfaceParams, make_bsdf, presence
from renderer.textures import TextureCache


def write_exr(path, px: np.ndarray) -> str:
    px = np.ascontiguousarray(px, dtype=np.float32)
    h, w, c = px.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(px), out.geterror()
    out.close()
    return str(path)


@pytest.fixture
def rgba_exr(tmp_path):
    """2x1 RGBA: left texel (0.1, 0.2, 0.3, 0.25), right texel (0.7, 0.8, 0.9, 1.0)."""
    px = np.array([[[0.1, 0.2, 0.3, 0.25], [0.7, 0.8, 0.9, 1.0]]])
    return write_exr(tmp_path / "rgba.exr", px)


LEFT, RIGHT = np.array([[0.25, 0.5]]), np.array([[0.75, 0.5]])


def _tex(path, output="rgb"):
    return TextureDesc(file=path, wrap_s="clamp", wrap_t="clamp", output=output)


def test_constants_are_packed_by_material_id():
    mats = [
        MaterialDesc("/A"),  # Sdr defaults
        MaterialDesc(
            "/B",
            diffuse_color=MaterialInput((0.9, 0.1, 0.2)),
            emissive_color=MaterialInput((2.0, 3.0, 4.0)),
            specular_color=MaterialInput((0.5, 0.6, 0.7)),
            use_specular_workflow=True,
            metallic=MaterialInput(0.3),
            roughness=MaterialInput(0.05),
            ior=1.33,
            opacity=MaterialInput(0.4),
            opacity_threshold=0.2,
        ),
    ]
    table = MaterialTable.build(mats, TextureCache())
    assert len(table) == 2
    p = table.evaluate(np.array([1, 0, 1, 1]))
    assert isinstance(p, SurfaceParams) and len(p) == 4
    np.testing.assert_allclose(p.diffuse, [[0.9, 0.1, 0.2], [0.18] * 3, [0.9, 0.1, 0.2], [0.9, 0.1, 0.2]])
    np.testing.assert_allclose(p.emission[0], [2.0, 3.0, 4.0])
    np.testing.assert_allclose(p.emission[1], 0.0)
    np.testing.assert_allclose(p.specular_color[0], [0.5, 0.6, 0.7])
    np.testing.assert_array_equal(p.use_specular_workflow, [True, False, True, True])
    np.testing.assert_allclose(p.metallic, [0.3, 0.0, 0.3, 0.3])
    np.testing.assert_allclose(p.roughness, [0.05, 0.5, 0.05, 0.05])
    np.testing.assert_allclose(p.ior, [1.33, 1.5, 1.33, 1.33])
    np.testing.assert_allclose(p.opacity, [0.4, 1.0, 0.4, 0.4])
    np.testing.assert_allclose(p.opacity_threshold, [0.2, 0.0, 0.2, 0.2])
    for name in ("diffuse", "specular_color", "emission"):
        assert getattr(p, name).shape == (4, 3) and getattr(p, name).dtype == np.float64
    # Flags.
    assert table.has_emission and table.has_cutout
    np.testing.assert_array_equal(table.emissive_materials, [False, True])
    # A subset keeps its rows.
    np.testing.assert_allclose(p.take(np.array([1])).diffuse, [[0.18] * 3])


def test_flags_for_plain_materials():
    table = MaterialTable.build([MaterialDesc("/A"), MaterialDesc("/B")], TextureCache())
    assert not table.has_emission and not table.has_cutout
    assert not table.emissive_materials.any()


def test_textured_inputs(rgba_exr):
    mats = [
        MaterialDesc("/Const", diffuse_color=MaterialInput((0.5, 0.5, 0.5))),
        MaterialDesc(
            "/Tex",
            diffuse_color=MaterialInput((0.0, 0.0, 0.0), _tex(rgba_exr, "rgb")),
            roughness=MaterialInput(0.9, _tex(rgba_exr, "g")),
            opacity=MaterialInput(1.0, _tex(rgba_exr, "a")),
        ),
        MaterialDesc("/Tex2", emissive_color=MaterialInput((0.0, 0.0, 0.0), _tex(rgba_exr, "b"))),
    ]
    cache = TextureCache()
    table = MaterialTable.build(mats, cache)
    assert len(table.textures) == 4  # distinct (file, output) descriptions ...
    assert len(cache._files) == 1  # ... of one file, read once
    assert table.has_cutout and table.has_emission
    np.testing.assert_array_equal(table.emissive_materials, [False, False, True])
    mat = np.array([0, 1, 1, 2, 0, 2])
    st = np.concatenate([LEFT, LEFT, RIGHT, RIGHT, RIGHT, LEFT])
    p = table.evaluate(mat, st)
    np.testing.assert_allclose(
        p.diffuse,
        [[0.5] * 3, [0.1, 0.2, 0.3], [0.7, 0.8, 0.9], [0.18] * 3, [0.5] * 3, [0.18] * 3],
        rtol=1e-6,
    )
    np.testing.assert_allclose(p.roughness, [0.5, 0.2, 0.8, 0.5, 0.5, 0.5], rtol=1e-6)
    np.testing.assert_allclose(p.opacity, [1.0, 0.25, 1.0, 1.0, 1.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(
        p.emission, [[0] * 3, [0] * 3, [0] * 3, [0.9] * 3, [0] * 3, [0.3] * 3], rtol=1e-6
    )
    # presence_at evaluates only opacity, and agrees with presence(evaluate()).
    np.testing.assert_allclose(table.presence_at(mat, st), presence(p))
    np.testing.assert_allclose(presence(p), [1.0, 0.25, 1.0, 1.0, 1.0, 1.0], rtol=1e-6)


def test_textures_without_st_use_origin(rgba_exr):
    mats = [MaterialDesc("/Tex", diffuse_color=MaterialInput((0.0, 0.0, 0.0), _tex(rgba_exr)))]
    table = MaterialTable.build(mats, TextureCache())
    p = table.evaluate(np.array([0, 0]))
    np.testing.assert_allclose(p.diffuse, [[0.1, 0.2, 0.3]] * 2, rtol=1e-6)  # clamp at (0, 0)


def test_one_texture_feeding_two_inputs_is_packed_once(rgba_exr):
    """Two inputs fed by one texture share its slot (and its image) in the compiled record."""
    t = _tex(rgba_exr, "r")
    mats = [MaterialDesc("/M", metallic=MaterialInput(0.0, t), roughness=MaterialInput(0.0, t))]
    table = MaterialTable.build(mats, TextureCache())
    rec = table.surface_record()
    MI, tx = rec[1], rec[3]
    assert len(table.textures) == 1 and tx[1].shape[0] == 1 and tx[2].shape[0] == 1  # one image, one texture
    assert MI[0, C_METALLIC, B_SLOT] == MI[0, C_ROUGHNESS, B_SLOT] == 0
    p = table.evaluate(np.zeros(5, dtype=np.int64), np.tile(RIGHT, (5, 1)))
    np.testing.assert_allclose(p.metallic, 0.7, rtol=1e-6)
    np.testing.assert_allclose(p.roughness, 0.7, rtol=1e-6)


def test_presence_rules():
    n = 6
    opacity = np.array([0.0, 0.3, 0.5, 0.7, 1.0, np.nan])
    base = dict(
        diffuse=np.zeros((n, 3)),
        specular_color=np.zeros((n, 3)),
        use_specular_workflow=np.zeros(n, dtype=bool),
        metallic=np.zeros(n),
        roughness=np.zeros(n),
        ior=np.full(n, 1.5),
        opacity=opacity,
        emission=np.zeros((n, 3)),
    )
    stochastic = SurfaceParams(**base, opacity_threshold=np.zeros(n))
    np.testing.assert_allclose(presence(stochastic), [0.0, 0.3, 0.5, 0.7, 1.0, 1.0])
    cutout = SurfaceParams(**base, opacity_threshold=np.full(n, 0.5))
    np.testing.assert_allclose(presence(cutout), [0.0, 0.0, 1.0, 1.0, 1.0, 1.0])
    assert MaterialTable.presence(cutout).shape == (n,)


def test_opacity_mode_presence_without_threshold_is_fractional():
    mats = [MaterialDesc("/P", opacity=MaterialInput(0.25), opacity_mode="presence")]
    table = MaterialTable.build(mats, TextureCache())
    np.testing.assert_allclose(table.presence_at(np.array([0])), [0.25])


def test_make_bsdf(rgba_exr):
    mats = [
        MaterialDesc("/Metal", diffuse_color=MaterialInput((0.9, 0.6, 0.3)), metallic=MaterialInput(1.0)),
        MaterialDesc("/Plastic", diffuse_color=MaterialInput((0.2, 0.4, 0.6)), roughness=MaterialInput(0.2)),
    ]
    table = MaterialTable.build(mats, TextureCache())
    b = make_bsdf(table.evaluate(np.array([0, 1])))
    assert isinstance(b, PreviewSurfaceBSDF)
    np.testing.assert_allclose(b.diffuse_albedo(), [[0.0, 0.0, 0.0], [0.2, 0.4, 0.6]])
    np.testing.assert_allclose(b.f0[0], [0.9, 0.6, 0.3])
    np.testing.assert_allclose(b.f0[1], [0.04] * 3)
    np.testing.assert_allclose(b.alpha, [0.25, 0.04])


def test_per_material_bsdf_rows_equal_make_bsdf_at_the_hits(rgba_exr):
    """MaterialTable.bsdf gathers a packed row per material; it must be bit-identical to the
    BSDF built from the evaluated inputs, and textured BSDF inputs must take the per-hit path."""
    mats = [
        MaterialDesc("/Metal", diffuse_color=MaterialInput((0.9, 0.6, 0.3)), metallic=MaterialInput(1.0)),
        MaterialDesc("/Plastic", diffuse_color=MaterialInput((0.2, 0.4, 0.6)), roughness=MaterialInput(0.2)),
        MaterialDesc("/Spec", specular_color=MaterialInput((0.5, 0.6, 0.7)), use_specular_workflow=True,
                     ior=1.33, roughness=MaterialInput(0.0)),
        MaterialDesc("/Glow", emissive_color=MaterialInput((1.0, 2.0, 3.0))),
    ]
    table = MaterialTable.build(mats, TextureCache())
    assert table.bsdf_is_constant and table.params_needed  # emission still needs the inputs
    mat = np.random.default_rng(0).integers(0, len(mats), 500)
    np.testing.assert_array_equal(table.bsdf(mat).packed, make_bsdf(table.evaluate(mat)).packed)
    plain = MaterialTable.build(mats[:3], TextureCache())
    assert not plain.params_needed
    textured = MaterialTable.build(
        [mats[0], MaterialDesc("/T", roughness=MaterialInput(0.9, _tex(rgba_exr, "g")))], TextureCache())
    assert not textured.bsdf_is_constant and textured.params_needed
    m = np.array([0, 1, 1])
    st = np.concatenate([LEFT, LEFT, RIGHT])
    p = textured.evaluate(m, st)
    np.testing.assert_array_equal(textured.bsdf(m, p).packed, make_bsdf(p).packed)
    with pytest.raises(ValueError):
        textured.bsdf(m)


def test_errors_name_the_material(tmp_path):
    with pytest.raises(StageError, match=r"/Bad\.inputs:roughness"):
        MaterialTable.build([MaterialDesc("/Bad", roughness=MaterialInput(float("nan")))], TextureCache())
    missing = str(tmp_path / "missing.png")
    with pytest.raises(StageError) as info:
        MaterialTable.build(
            [MaterialDesc("/T", diffuse_color=MaterialInput((0, 0, 0), _tex(missing)))], TextureCache()
        )
    assert "missing.png" in str(info.value) and "/T.inputs:diffuseColor" in str(info.value)


def test_empty_table():
    table = MaterialTable.build([], TextureCache())
    assert len(table) == 0 and not table.has_emission and not table.has_cutout
    p = table.evaluate(np.zeros(0, dtype=np.int64))
    assert p.diffuse.shape == (0, 3) and p.opacity.shape == (0,)


def test_texture_desc_with_list_fields(rgba_exr):
    """Scale / bias given as lists (unhashable) still work and are shared by identical inputs."""
    t1 = TextureDesc(file=rgba_exr, wrap_s="clamp", wrap_t="clamp", scale=[2.0, 2.0, 2.0, 1.0])
    t2 = TextureDesc(file=rgba_exr, wrap_s="clamp", wrap_t="clamp", scale=[2.0, 2.0, 2.0, 1.0])
    mats = [
        MaterialDesc("/A", diffuse_color=MaterialInput((0, 0, 0), t1)),
        MaterialDesc("/B", diffuse_color=MaterialInput((0, 0, 0), t2)),
    ]
    table = MaterialTable.build(mats, TextureCache())
    assert len(table.textures) == 1
    p = table.evaluate(np.array([0, 1]), np.concatenate([LEFT, RIGHT]))
    np.testing.assert_allclose(p.diffuse, [[0.2, 0.4, 0.6], [1.4, 1.6, 1.8]], rtol=1e-6)
