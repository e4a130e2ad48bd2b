"""`illum render` refuses what it cannot finish, before the work: files that would block or never
end (a FIFO or a device as the stage, a sublayer, a reference or a texture), scenes over the
memory cap (meshes, instances, images from their headers, the film), and loads that do not
finish within --load-timeout. Each is exit 2 and one line naming the file, prim and attribute
(or the argument). Real stages, real images, real subprocesses."""

import os
import shutil
import struct
import zlib

import numpy as np
import pytest
from pxr import UsdGeom, UsdLux

from renderer import memory

from tests.stage_builders import add_camera, add_point_instancer, add_settings, new_stage, quad_light_stage

from .test_cli import ROOT
from .test_validation import _refused, illum

TEXTURED = os.path.join(ROOT, "stages", "textured.usda")


def _textured_copy(tmp_path):
    """stages/textured.usda with its textures directory, in tmp_path (checker.png to be replaced)."""
    shutil.copy(TEXTURED, tmp_path / "textured.usda")
    shutil.copytree(os.path.join(ROOT, "stages", "textures"), tmp_path / "textures")
    os.unlink(tmp_path / "textures" / "checker.png")
    return tmp_path / "textured.usda"


# ---------------------------------------------------------------------------------- special files
@pytest.mark.parametrize("case", ["fifo_stage", "device_stage", "directory_stage", "fifo_sublayer",
                                  "fifo_reference", "fifo_payload"])
def test_a_fifo_or_device_layer_is_refused_before_it_is_opened(tmp_path, case):
    pipe = tmp_path / "pipe.usda"
    os.mkfifo(pipe)
    stage = tmp_path / "s.usda"
    cornell = os.path.join(ROOT, "stages", "cornell_box.usda")
    texts = {"fifo_sublayer": f"#usda 1.0\n(\n    subLayers = [@./pipe.usda@, @{cornell}@]\n)\n",
             "fifo_reference": f'#usda 1.0\n(\n    subLayers = [@{cornell}@]\n)\ndef "A" (\n    references = @./pipe.usda@\n) {{}}\n',
             "fifo_payload": '#usda 1.0\ndef "A" {\n    def "B" (\n        payload = @./pipe.usda@\n    ) {}\n}\n'}
    if case in texts:
        stage.write_text(texts[case])
    else:
        stage = {"fifo_stage": pipe, "device_stage": "/dev/zero", "directory_stage": tmp_path}[case]
    want = {"fifo_stage": ("the stage is a FIFO, not a regular file",),
            "device_stage": ("/dev/zero", "the stage is a character device"),
            "directory_stage": ("the stage is a directory",),
            "fifo_sublayer": ("s.usda: subLayers: './pipe.usda' is a FIFO, not a regular file",),
            "fifo_reference": ("s.usda: /A.references: './pipe.usda' is a FIFO",),
            "fifo_payload": ("s.usda: /A/B.payload: './pipe.usda' is a FIFO",)}[case]
    _refused(illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8), *want)
    assert not (tmp_path / "o.exr").exists()


def test_a_fifo_texture_is_refused_even_without_strict(tmp_path):
    stage = _textured_copy(tmp_path)
    os.mkfifo(tmp_path / "textures" / "checker.png")
    _refused(illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8),
             "textured.usda: /World/Looks/Checker/checker.inputs:file:", "checker.png' is a FIFO, not a regular file")


def test_a_load_that_never_finishes_stops_at_the_load_timeout(tmp_path):
    """A value-clip layer that is a FIFO (clips are opened while composing, not refused up
    front) blocks Usd.Stage.Open in C++: the deadline ends the process with exit 2."""
    from tests.service.conftest import write_fifo_clip_stage

    stage = tmp_path / "hang.usda"
    write_fifo_clip_stage(str(stage), sublayer=os.path.join(ROOT, "stages", "cornell_box.usda"))
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8, "--load-timeout", 1)
    _refused(r, "hang.usda: opening and reading the stage did not finish within 1 s (--load-timeout)")
    r = illum("render", stage, "-o", tmp_path / "o_$F.exr", "--spp", 1, "--res", 8, 8, "--load-timeout", 1,
              "--frames", "0-1")
    _refused(r, "hang.usda: opening the stage did not finish within 1 s (--load-timeout)")


# ---------------------------------------------------------------------------------- memory caps
def _zero_png(path, n: int) -> None:
    """A valid n x n 8-bit grey PNG of zeros, written with OpenImageIO (8192^2: a 64 KB file)."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(n, n, 1, oiio.UINT8))
    assert out.write_image(np.zeros((n, n, 1), np.uint8))
    out.close()


@pytest.mark.parametrize("size,small,large", [
    (2048, "256M", "1G"),  # 2048^2 x 96 B = 384 MiB of estimate
    pytest.param(8192, "1G", "7G", marks=pytest.mark.heavy),  # 6 GiB: the decode alone takes a minute
])
def test_an_image_over_the_cap_is_refused_from_its_header(tmp_path, size, small, large):
    """A PNG of a few KB that decodes to size x size texels (GiBs once decoded at 8192) is
    refused from its header, before any texel is decoded: the message names the prim, attribute
    and image. Under a cap it fits, it renders."""
    stage = _textured_copy(tmp_path)
    _zero_png(tmp_path / "textures" / "checker.png", size)
    assert os.path.getsize(tmp_path / "textures" / "checker.png") < 100_000
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8, "--max-memory", small)
    _refused(r, "textured.usda: /World/Looks/Checker/checker.inputs:file:", f"the {size}x{size} image",
             "checker.png'", f"more than --max-memory {memory.format_size(memory.parse_size(small))}")
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8, "--max-memory", large, "--quiet")
    assert r.returncode == 0, r.stderr


def test_a_tiny_png_claiming_a_huge_image_is_never_decoded(tmp_path):
    """A 100-byte PNG whose header says 60000 x 60000: OpenImageIO's header check already calls
    it corrupt, so it is never decoded: the missing-asset policy's warning, or exit 2 under
    --strict, naming the file."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    stage = _textured_copy(tmp_path)
    (tmp_path / "textures" / "checker.png").write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8, "--strict")
    _refused(r, "/World/Looks/Checker/checker.inputs:file", "cannot read image", "checker.png")
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 8, 8)
    assert r.returncode == 0 and "checker.png" in r.stderr and "uses its inputs:fallback" in r.stderr, r.stderr


def _grid_stage(path, n: int, instances: int = 0):
    """An n x n quad grid (2 n^2 triangles) at /World/Grid, or as the prototype of a
    PointInstancer /World/Trees with ``instances`` instances."""
    stage = new_stage(str(path))
    add_camera(stage)
    add_settings(stage, res=(8, 8))
    UsdLux.DistantLight.Define(stage, "/World/Sun")
    where = "/World/Protos/Grid" if instances else "/World/Grid"
    mesh = UsdGeom.Mesh.Define(stage, where)
    xs = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    mesh.CreatePointsAttr(np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1).astype(np.float32))
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    a = (j * (n + 1) + i).ravel()
    mesh.CreateFaceVertexCountsAttr(np.full(n * n, 4, np.int32))
    mesh.CreateFaceVertexIndicesAttr(np.stack([a, a + 1, a + n + 2, a + n + 1], 1).ravel().astype(np.int32))
    mesh.CreateSubdivisionSchemeAttr("none")
    if instances:
        add_point_instancer(stage, "/World/Trees", ["/World/Protos/Grid"], [0] * instances,
                            [(float(k), 0.0, 0.0) for k in range(instances)])
    stage.GetRootLayer().Save()
    return path


def test_a_mesh_over_the_cap_is_refused_before_it_is_triangulated(tmp_path):
    stage = _grid_stage(tmp_path / "grid.usda", 100)  # 20000 triangles
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--max-memory", "4M")
    _refused(r, "grid.usda: /World/Grid.faceVertexCounts: 20000 triangles needs about", "more than --max-memory 4.0 MiB")
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--max-memory", "64M", "--quiet")
    assert r.returncode == 0, r.stderr


def test_instances_over_the_cap_are_refused_naming_the_prototype(tmp_path):
    stage = _grid_stage(tmp_path / "trees.usda", 20, instances=200)  # 800 triangles x 200
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--max-memory", "64M")
    _refused(r, "trees.usda: /World/Protos/Grid: 800 triangles x 200 instances needs about",
             "more than --max-memory 64.0 MiB")


def test_a_film_over_the_cap_is_refused_before_the_scene_is_built(tmp_path):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage)
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--res", 4096, 4096, "--max-memory", "256M")
    _refused(r, "resolution: a 4096x4096 film needs about", "more than --max-memory 256.0 MiB")


@pytest.mark.parametrize("text,want", [("0.5M", "max_memory: must be an integer >= 1048576, got 524288"),
                                       ("lots", "--max-memory expected a size such as 8G")])
def test_a_bad_max_memory_is_refused(tmp_path, text, want):
    stage = tmp_path / "q.usda"
    quad_light_stage(stage)
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--spp", 1, "--max-memory", text)
    assert r.returncode == 2 and want in r.stderr, r.stderr


def test_without_max_memory_the_cap_is_a_share_of_what_the_process_may_allocate(tmp_path):
    """The default cap is 80 % of available_memory(), which an address-space limit lowers: under
    a 3 GiB RLIMIT_AS the 8192^2 image (~6 GiB of estimate) is refused, saying how to raise it."""
    import resource
    import subprocess
    import sys

    stage = _textured_copy(tmp_path)
    _zero_png(tmp_path / "textures" / "checker.png", 8192)

    def address_space():
        resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))

    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", str(stage), "-o", str(tmp_path / "o.exr"),
                        "--spp", "1", "--res", "8", "8"], capture_output=True, text=True, cwd=ROOT, timeout=600,
                       preexec_fn=address_space)
    _refused(r, "the 8192x8192 image", "more than the default cap of", "(80% of the memory available; raise it "
             "with --max-memory)")


def test_a_subdivision_level_past_the_cap_is_refused_before_refining(tmp_path):
    """--subdiv-level multiplies a cage's faces by 4 per level: the estimate is checked before
    the refinement allocates, naming the mesh and its subdivisionScheme."""
    stage = tmp_path / "sub.usda"
    stage.write_text('#usda 1.0\n(\n    upAxis = "Y"\n)\ndef Mesh "Box" {\n'
                     '    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n'
                     '    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]\n'
                     '    point3f[] points = [(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), '
                     '(-1, -1, -1), (1, -1, -1)]\n}\n')
    _refused(illum("render", stage, "-o", tmp_path / "x.exr", "--res", 16, 16, "--spp", 1, "--subdiv-level", 8,
                   "--max-memory", "256M"), "/Box.subdivisionScheme", "786432 triangles after 8 subdivision levels")
