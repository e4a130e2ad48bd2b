"""Mesh lights, cylinder lights and dome portals end to end (render()): emission counted once,
no self-shadowing of mesh lights, unbiased direct lighting against independent references."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from renderer.render import RenderOptions, render
from tests.stage_builders import add_camera, add_settings, bind, new_stage, preview_material


def _glow(stage, path, emissive, diffuse=(0.5, 0.5, 0.5)):
    mat = preview_material(stage, path, diffuse=diffuse)
    UsdShade.Shader(stage.GetPrimAtPath(path + "/PBR")).CreateInput(
        "emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    return mat


def _quad(stage, path, y, size, facing_up=True):
    s = size / 2
    m = UsdGeom.Mesh.Define(stage, path)
    pts = [(-s, y, s), (s, y, s), (s, y, -s), (-s, y, -s)]  # counter-clockwise seen from +Y
    m.CreatePointsAttr(pts if facing_up else pts[::-1])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    return m


def _zdiff(img, ref):
    """Pixelwise z-scores of img's mean against ref's (both Films), pooled: |mean z| sqrt(n)."""
    var = img.variance_of_mean()[..., 1] + ref.variance_of_mean()[..., 1]
    lit = var > 0
    z = (img.mean()[..., 1] - ref.mean()[..., 1])[lit] / np.sqrt(var[lit])
    return abs(z.mean()) * np.sqrt(z.size), int(lit.sum())


# ----------------------------------------------------------------------------------------
# Mesh lights
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode,expected", [
    ("materialGlowTintsLight", (6.0 * 1.0, 6.0 * 0.5, 6.0 * 0.25)),   # intensity x glow, glow not added again
    ("independent", (6.0 + 1.0, 6.0 + 0.5, 6.0 + 0.25)),             # light + the material's own glow
    ("noMaterialResponse", (6.0, 6.0, 6.0)),
])
def test_camera_sees_mesh_light_emission_once(tmp_path, mode, expected):
    """A mesh-light quad facing the camera: its pixels are exactly its emission, at any depth
    (counted at the surface hit only, never again as a crossed light)."""
    path = tmp_path / "m.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 5, 0))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Camera")).AddRotateXOp().Set(-90.0)
    add_settings(stage, res=(8, 8))
    q = _quad(stage, "/World/Glow", 0.0, 20.0)
    bind(q.GetPrim(), _glow(stage, "/World/Looks/Glow", (1.0, 0.5, 0.25)))
    UsdLux.MeshLightAPI.Apply(q.GetPrim())
    UsdLux.LightAPI(q.GetPrim()).CreateIntensityAttr(6.0)
    q.GetPrim().GetAttribute("light:materialSyncMode").Set(mode)
    stage.GetRootLayer().Save()
    for depth in (0, 3):
        img = render(str(path), RenderOptions(spp=2, max_depth=depth, threads=1)).film.mean()
        np.testing.assert_allclose(img.reshape(-1, 3), np.tile(expected, (64, 1)), rtol=1e-6)


def test_emissive_mesh_without_light_api_is_plain_emission(tmp_path):
    path = tmp_path / "e.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 5, 0))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Camera")).AddRotateXOp().Set(-90.0)
    add_settings(stage, res=(4, 4))
    q = _quad(stage, "/World/Sign", 0.0, 20.0)
    bind(q.GetPrim(), _glow(stage, "/World/Looks/Glow", (1.0, 0.5, 0.25)))
    stage.GetRootLayer().Save()
    r = render(str(path), RenderOptions(spp=1, max_depth=2, threads=1))
    assert r.stats["lights"] == []
    np.testing.assert_allclose(r.film.mean().reshape(-1, 3), np.tile([1.0, 0.5, 0.25], (16, 1)), rtol=1e-6)


def _floor_under(tmp_path, name, light_kind, mode=None):
    """A grey floor (y = 0) lit by a 1.5 m square emitter facing down at y = 2 (a mesh light or
    an equivalent RectLight); the camera at the light's height looks down at the floor, so the
    emitter is out of frame."""
    path = tmp_path / f"{name}.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 2.0, 3.0), focal=24.0, tilt_x=-60.0)
    add_settings(stage, res=(10, 10))
    floor = _quad(stage, "/World/Floor", 0.0, 30.0)
    bind(floor.GetPrim(), preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5), roughness=1.0))
    if light_kind == "mesh":
        q = _quad(stage, "/World/Glow", 2.0, 1.5, facing_up=False)
        bind(q.GetPrim(), preview_material(stage, "/World/Looks/Dark", diffuse=(0.2, 0.2, 0.2)))
        UsdLux.MeshLightAPI.Apply(q.GetPrim())
        UsdLux.LightAPI(q.GetPrim()).CreateIntensityAttr(4.0)
        if mode:
            q.GetPrim().GetAttribute("light:materialSyncMode").Set(mode)
    else:
        rect = UsdLux.RectLight.Define(stage, "/World/Rect")
        rect.CreateWidthAttr(1.5)
        rect.CreateHeightAttr(1.5)
        rect.CreateIntensityAttr(4.0)
        lx = UsdGeom.Xformable(rect)
        lx.AddTranslateOp().Set(Gf.Vec3d(0, 2.0, 0))
        lx.AddRotateXOp().Set(-90.0)
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("estimator,depth", [("mis", 1), ("controlVariate", 1), ("mis", 3)])
def test_mesh_light_direct_lighting_matches_the_equivalent_rect(tmp_path, estimator, depth):
    """Light from a mesh-light quad equals that of a RectLight of the same shape and radiance:
    sampled points on the mesh are not shadowed by the mesh itself, its exact F (2 triangles)
    keeps the control variate unbiased, and at depth 3 (noMaterialResponse, so the quad
    reflects nothing, like the transparent rect) the continuation rays' MIS-weighted hits on
    the mesh count its emission once."""
    ref = render(str(_floor_under(tmp_path, "rect", "rect")),
                 RenderOptions(spp=256, max_depth=depth, threads=1, seed=1)).film
    r = render(str(_floor_under(tmp_path, "mesh", "mesh", mode="noMaterialResponse" if depth > 1 else None)),
               RenderOptions(spp=64, max_depth=depth, threads=1, seed=2, estimator={"": estimator},
                             light_samples={"": 2}))
    assert r.stats["lights"][0]["estimator"] == estimator
    z, lit = _zdiff(r.film, ref)
    assert lit > 50 and z < 4.0, z
    assert r.film.mean().mean() > 0.3 * ref.mean().mean()  # not a dark (self-shadowed) floor


# ----------------------------------------------------------------------------------------
# Cylinder lights
# ----------------------------------------------------------------------------------------
def test_cylinder_light_sampling_agrees_with_bsdf_sampling(tmp_path):
    """Two independent techniques on a floor under a fat tube: light sampling (the facing-band
    sampler and its pdf) and BSDF sampling (only intersect and le) agree."""
    path = tmp_path / "c.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 1.4, 3.0), focal=24.0, tilt_x=-55.0)
    add_settings(stage, res=(8, 8))
    floor = _quad(stage, "/World/Floor", 0.0, 30.0)
    bind(floor.GetPrim(), preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5), roughness=1.0))
    tube = UsdLux.CylinderLight.Define(stage, "/World/Tube")
    tube.CreateRadiusAttr(0.4)
    tube.CreateLengthAttr(2.0)
    tube.CreateIntensityAttr(2.0)
    UsdGeom.Xformable(tube).AddTranslateOp().Set(Gf.Vec3d(0, 1.0, 0))
    stage.GetRootLayer().Save()
    light = render(str(path), RenderOptions(spp=128, max_depth=1, threads=1, seed=3,
                                            estimator={"": "lightSampling"})).film
    bsdf = render(str(path), RenderOptions(spp=256, max_depth=1, threads=1, seed=4,
                                           estimator={"": "bsdfSampling"})).film
    z, lit = _zdiff(light, bsdf)
    assert lit > 30 and z < 4.0, z


# ----------------------------------------------------------------------------------------
# Portals and filters on a real stage
# ----------------------------------------------------------------------------------------
def _window_room(tmp_path, with_portal: bool):
    """A closed 2 m box with a 0.8 x 0.6 m window in its roof; a constant dome outside."""
    path = tmp_path / f"room_{with_portal}.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 1.6, 0.9), focal=18.0, tilt_x=-70.0, clip=(0.01, 100.0))
    add_settings(stage, res=(10, 10))
    grey = preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5), roughness=1.0)
    faces = {
        "Floor": [(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)],
        "Back": [(-1, 0, -1), (1, 0, -1), (1, 2, -1), (-1, 2, -1)],
        "Front": [(1, 0, 1), (-1, 0, 1), (-1, 2, 1), (1, 2, 1)],
        "Left": [(-1, 0, 1), (-1, 0, -1), (-1, 2, -1), (-1, 2, 1)],
        "Right": [(1, 0, -1), (1, 0, 1), (1, 2, 1), (1, 2, -1)],
        # the roof (y = 2) around the window x in [-0.4, 0.4], z in [-0.3, 0.3]
        "RoofA": [(-1, 2, -1), (1, 2, -1), (1, 2, -0.3), (-1, 2, -0.3)],
        "RoofB": [(-1, 2, 0.3), (1, 2, 0.3), (1, 2, 1), (-1, 2, 1)],
        "RoofC": [(-1, 2, -0.3), (-0.4, 2, -0.3), (-0.4, 2, 0.3), (-1, 2, 0.3)],
        "RoofD": [(0.4, 2, -0.3), (1, 2, -0.3), (1, 2, 0.3), (0.4, 2, 0.3)],
    }
    for name, pts in faces.items():
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreatePointsAttr(pts)
        m.CreateFaceVertexCountsAttr([4])
        m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        m.CreateSubdivisionSchemeAttr("none")
        bind(m.GetPrim(), grey)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.CreateIntensityAttr(3.0)
    if with_portal:
        p = UsdLux.PortalLight.Define(stage, "/World/Window")
        p.CreateWidthAttr(0.8)
        p.CreateHeightAttr(0.6)
        UsdGeom.Xformable(p).AddTranslateOp().Set(Gf.Vec3d(0, 2.0, 0))
        UsdGeom.Xformable(p).AddRotateXOp().Set(-90.0)  # local -Z -> world -Y: into the room
        dome.CreatePortalsRel().SetTargets([p.GetPath()])
    stage.GetRootLayer().Save()
    return path


def test_portal_render_matches_plain_dome(tmp_path):
    """Portals only guide sampling: the image (direct light, max depth 1) equals the plain
    dome's, and its noise is lower."""
    ref = render(str(_window_room(tmp_path, False)), RenderOptions(spp=256, max_depth=1, threads=1, seed=5)).film
    r = render(str(_window_room(tmp_path, True)), RenderOptions(spp=64, max_depth=1, threads=1, seed=6)).film
    z, lit = _zdiff(r, ref)
    assert lit > 50 and z < 4.0, z
    plain = render(str(_window_room(tmp_path, False)), RenderOptions(spp=64, max_depth=1, threads=1, seed=7)).film
    assert np.median(r.variance_of_mean()[..., 1]) < 0.5 * np.median(plain.variance_of_mean()[..., 1])


def test_light_filter_warning_reaches_the_stats(tmp_path):
    path = tmp_path / "f.usda"
    stage = new_stage(path)
    add_camera(stage)
    add_settings(stage, res=(4, 4))
    UsdLux.LightFilter.Define(stage, "/World/Gel")
    tube = UsdLux.CylinderLight.Define(stage, "/World/Tube")
    tube.GetFiltersRel().SetTargets([Sdf.Path("/World/Gel")])
    stage.GetRootLayer().Save()
    stats_path = tmp_path / "stats.json"
    r = render(str(path), RenderOptions(spp=1, threads=1))
    msgs = [w for w in r.stats["warnings"] if "/World/Gel" in w]
    assert len(msgs) == 1 and msgs[0].startswith("/World/Tube") and "LightFilter" in msgs[0]
    json.dumps(r.stats)  # the stats JSON carries it
    assert not stats_path.exists()


def _closed_mesh_light(tmp_path, name, nu, nv):
    """A grey floor beside a closed UV-sphere mesh light of radius 0.6 (nu x nv faces, poles as
    fans; 2 nu (nv - 1) triangles), noMaterialResponse so that it reflects nothing. The camera
    looks straight down at the floor next to it (the ball out of frame), where the ball fills
    enough of the sky for BSDF sampling to be a sound reference."""
    path = tmp_path / f"{name}.usda"
    stage = new_stage(path)
    add_camera(stage, pos=(0, 0.7, 0.0), focal=24.0, tilt_x=-90.0, clip=(0.01, 100.0))
    add_settings(stage, res=(8, 8))
    floor = _quad(stage, "/World/Floor", 0.0, 30.0)
    bind(floor.GetPrim(), preview_material(stage, "/World/Looks/Grey", diffuse=(0.5, 0.5, 0.5), roughness=1.0))
    pts = [(0.0, 0.6, 0.0)]
    for i in range(1, nv):
        th = np.pi * i / nv
        for j in range(nu):
            ph = 2 * np.pi * j / nu
            pts.append((0.6 * np.sin(th) * np.cos(ph), 0.6 * np.cos(th), 0.6 * np.sin(th) * np.sin(ph)))
    pts.append((0.0, -0.6, 0.0))
    counts, idx = [], []

    def ring(i, j):
        return 1 + (i - 1) * nu + j % nu

    for j in range(nu):  # counter-clockwise seen from outside (normal (b - a) x (c - a) outward)
        counts.append(3)
        idx += [0, ring(1, j + 1), ring(1, j)]
        counts.append(3)
        idx += [len(pts) - 1, ring(nv - 1, j), ring(nv - 1, j + 1)]
    for i in range(1, nv - 1):
        for j in range(nu):
            counts.append(4)
            idx += [ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)]
    m = UsdGeom.Mesh.Define(stage, "/World/Ball")
    m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    m.CreateFaceVertexCountsAttr(counts)
    m.CreateFaceVertexIndicesAttr(idx)
    m.CreateSubdivisionSchemeAttr("none")
    UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(1.0, 1.0, 0.0))
    UsdLux.MeshLightAPI.Apply(m.GetPrim())
    UsdLux.LightAPI(m.GetPrim()).CreateIntensityAttr(3.0)
    m.GetPrim().GetAttribute("light:materialSyncMode").Set("noMaterialResponse")
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("shape", [(4, 3), (12, 6)])   # 16 triangles (per-point pick), 120 (triangle BVH)
def test_closed_mesh_light_oriented_pick_is_unbiased(tmp_path, shape):
    """A closed mesh light: light sampling (the oriented triangle pick), MIS with its own BSDF
    half (depth 1) and MIS riding on the continuation ray (depth 2: the pick probability is
    replayed at the previous vertex) all match BSDF sampling, which never uses the pick."""
    from renderer.lights import mesh as mesh_mod

    nu, nv = shape
    assert (2 * nu * (nv - 1) > mesh_mod.EXACT_PICK_TRIANGLES) == (shape == (12, 6))
    path = str(_closed_mesh_light(tmp_path, f"ball{nu}", nu, nv))
    ref = render(path, RenderOptions(spp=256, max_depth=1, threads=1, seed=11, estimator={"": "bsdfSampling"})).film
    for k, (est, depth) in enumerate((("lightSampling", 1), ("mis", 1), ("mis", 2))):
        r = render(path, RenderOptions(spp=16, max_depth=depth, threads=1, seed=12 + k, estimator={"": est}))
        z, lit = _zdiff(r.film, ref)
        assert lit > 40 and z < 4.0, (est, depth, z)
