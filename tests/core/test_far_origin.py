"""A scene far from the world origin renders as it does at the origin (#21 item 7).

build_scene re-centres the description on the camera (renderer/scene.py recentre), so the
Cornell box moved 1e7 units out traces in the same float32 coordinates as at home; before, it
rendered 8 % dark (self-intersections), and 1e30 units out it rendered black with exit 0.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from renderer.description import LightDesc, translated
from renderer.render import RenderOptions, render
from renderer.usd import load_stage

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORNELL = os.path.join(ROOT, "stages", "cornell_box.usda")


def far_stage(path, offset, *, res: int = 48, sphere_lights: int = 0, camera: str = "") -> str:
    """The Cornell box, camera included, referenced under an Xform translated by offset (a
    float: along every axis, or a 3-tuple); sphere_lights small sphere lights along the box's
    ceiling (17+ builds the light BVH); camera: opinions on the box's Camera prim (usda)."""
    x, y, z = (offset,) * 3 if np.isscalar(offset) else offset
    lights = "\n".join(
        f'''        def SphereLight "S{i}"
        {{
            float inputs:intensity = 40
            float inputs:radius = 0.6
            double3 xformOp:translate = ({-24 + 3 * i}, 50, {-10 + (i % 5) * 4})
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}''' for i in range(sphere_lights))
    with open(path, "w") as f:
        f.write(f'''#usda 1.0
(
    defaultPrim = "Far"
    metersPerUnit = 0.01
    upAxis = "Y"
    renderSettingsPrimPath = "/Render/Settings"
)
def Xform "Far"
{{
    double3 xformOp:translate = ({x!r}, {y!r}, {z!r})
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Xform "World" (references = @{CORNELL}@</World>)
    {{
{lights}
        over "Camera"
        {{
            {camera}
        }}
    }}
}}
def Scope "Render"
{{
    def RenderSettings "Settings"
    {{
        rel camera = </Far/World/Camera>
        uniform int2 resolution = ({res}, {res})
    }}
}}
''')
    return str(path)


def _render(path, **kw):
    return render(path, RenderOptions(spp=8, max_depth=4, threads=1, seed=5, **kw))


def _far_warnings(result) -> list[str]:
    return [w for w in result.warnings if "coordinates are rounded" in w]


@pytest.mark.parametrize("lights", [0, 17])
def test_translated_cornell_box_renders_the_same_image(tmp_path, lights):
    """1e7 units out (float32 spacing 1 unit there, the box 55 units wide) the image agrees
    pixel by pixel with the box at the origin at the same seed: the re-centred coordinates
    differ only by float64 rounding (~2e-9 units), which moves a handful of float32 vertices by
    one ulp. With 17 sphere lights the light BVH (scene.light_accel) is built too."""
    home = _render(far_stage(tmp_path / "home.usda", 0.0, sphere_lights=lights))
    far = _render(far_stage(tmp_path / "far.usda", 1e7, sphere_lights=lights))
    a, b = home.film.image(), far.film.image()
    assert a.mean() > 0.05
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * float(a.max()))
    assert not _far_warnings(home) and not _far_warnings(far)


def test_camera_metadata_stays_in_world_space(tmp_path):
    """worldToCamera / worldToNDC map world points: a box corner moved by the offset lands where
    the unmoved corner does in the unmoved render (float64 rounding at 1e7: ~1e-9)."""
    home = _render(far_stage(tmp_path / "home.usda", 0.0))
    far = _render(far_stage(tmp_path / "far.usda", 1e7))
    p = np.array([-27.5, 0.0, -28.0, 1.0])
    moved = p + np.array([1e7, 1e7, 1e7, 0.0])
    for key in ("worldToCamera", "worldToNDC", "worldToScreen"):
        want = np.asarray(home.metadata[key]) @ p
        got = np.asarray(far.metadata[key]) @ moved
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    # And the translation is really there (a matrix left in re-centred space would fail above).
    assert abs(np.asarray(far.metadata["worldToCamera"])[0, 3] + 1e7) < 1.0


def test_collapsed_scene_exits_2_naming_the_extent(tmp_path):
    """1e30 units out, float64 coordinates are 1.4e14 apart: the box is a single point. The CLI
    refuses with exit 2 and a message naming the extent, and writes nothing."""
    out = tmp_path / "far.exr"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", far_stage(tmp_path / "far.usda", 1e30),
                        "-o", str(out), "--spp", "1", "--threads", "1"], capture_output=True, text=True, cwd=ROOT,
                       timeout=600)
    assert r.returncode == 2, r.stderr
    assert "extent of 0 units" in r.stderr and "collapsed" in r.stderr
    assert not out.exists()


def test_insufficient_precision_warns_once(tmp_path):
    """1e16 units out, float64 already rounds the box's coordinates to 2 units, more than a
    48-pixel render's footprint (~1.6 units at the box): one warning names the extent."""
    result = _render(far_stage(tmp_path / "far.usda", 1e16))
    found = _far_warnings(result)
    assert len(found) == 1
    assert "extent of" in found[0] and "rounded to 2 units" in found[0]


def test_telephoto_across_float32_distance_warns(tmp_path):
    """The box moves 1e7 units down -z while the camera stays at home, with a lens long enough
    to fill the frame with it: re-centred on the camera, float32 steps at the box are 1 unit
    against a pixel footprint of ~1.2 units, so one warning names the extent."""
    camera = ("double3 xformOp:translate = (0, 27.3, 10000107.96)\n"
              "float focalLength = 4545000\n"
              "float2 clippingRange = (1, 100000000)")
    result = _render(far_stage(tmp_path / "tele.usda", (0.0, 0.0, -1e7), camera=camera))
    found = _far_warnings(result)
    assert len(found) == 1 and "rounded to 1 units" in found[0], result.warnings
    assert result.film.image().mean() > 0.05  # the box fills the frame: not black


def test_translation_moves_positions_not_infinite_lights():
    """translated() moves meshes, the camera and finite lights (and dome portals), not the
    frames of dome and distant lights, whose translation means nothing."""
    desc = load_stage(CORNELL)
    frame = np.eye(4)
    frame[:3, 3] = (5.0, 6.0, 7.0)
    portals = np.stack([frame, frame])
    dome = LightDesc(path="/Dome", kind="dome", light_to_world=frame, portals=portals)
    distant = LightDesc(path="/Sun", kind="distant", light_to_world=frame)
    desc.lights = list(desc.lights) + [dome, distant]
    offset = np.array([-1.0, 2.0, -3.0])
    moved = translated(desc, offset)
    np.testing.assert_array_equal(moved.meshes[0].points, np.asarray(desc.meshes[0].points) + offset)
    np.testing.assert_array_equal(moved.camera.camera_to_world[:3, 3], desc.camera.camera_to_world[:3, 3] + offset)
    np.testing.assert_array_equal(moved.lights[0].light_to_world[:3, 3], desc.lights[0].light_to_world[:3, 3] + offset)
    np.testing.assert_array_equal(moved.lights[0].light_to_world[:3, :3], desc.lights[0].light_to_world[:3, :3])
    np.testing.assert_array_equal(moved.lights[-2].light_to_world, frame)
    np.testing.assert_array_equal(moved.lights[-1].light_to_world, frame)
    np.testing.assert_array_equal(moved.lights[-2].portals[:, :3, 3], portals[:, :3, 3] + offset)
    # The input is left as it was (render.py keeps it for on_loaded and the metadata's paths).
    np.testing.assert_array_equal(desc.lights[-2].portals, portals)
