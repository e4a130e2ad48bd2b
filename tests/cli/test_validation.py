"""`illum render` refuses what it cannot finish before it renders anything: unwritable outputs,
out-of-range seeds, a singular camera, a film larger than memory. Each is exit 2 and one line
naming the argument, or the prim and attribute; no progress line is printed (no pass ran) and no
file is left behind. Real stages, real subprocesses."""

import os
import resource
import subprocess
import sys

import pytest

from renderer.film import read_exr
from tests.stage_builders import quad_light_stage

from .test_cli import ROOT, _error, illum

def _refused(r, *needles):
    """Exit 2, one line naming ``needles``, and no render pass (no progress line on stdout)."""
    msg = _error(r, *needles)
    assert "ALF_PROGRESS" not in r.stdout, r.stdout
    return msg


@pytest.fixture
def stage(tmp_path):
    p = tmp_path / "q.usda"
    quad_light_stage(p)
    return p


@pytest.mark.parametrize("case", ["missing_dir", "a_directory", "unsupported_ext", "the_input", "no_ext"])
def test_unwritable_output_is_refused_before_rendering(tmp_path, stage, case):
    out = {"missing_dir": tmp_path / "no" / "such" / "o.exr", "a_directory": tmp_path,
           "unsupported_ext": tmp_path / "o.xyz", "the_input": stage, "no_ext": tmp_path / "o"}[case]
    before = sorted(os.listdir(tmp_path))
    want = {"missing_dir": "does not exist", "a_directory": "is a directory", "unsupported_ext": "'.xyz'",
            "the_input": "is the input stage", "no_ext": "unsupported extension"}[case]
    _refused(illum("render", stage, "-o", out, "--spp", 1), "--output", want)
    assert sorted(os.listdir(tmp_path)) == before
    assert stage.read_text().startswith("#usda")


def test_missing_directory_is_created_with_make_output_path(tmp_path, stage):
    out = tmp_path / "shots" / "sh010" / "o.exr"
    r = illum("render", stage, "-o", out, "--spp", 1, "--quiet", "--make-output-path")
    assert r.returncode == 0, r.stderr
    assert read_exr(str(out))[0].shape == (16, 16, 3)


def test_unwritable_preview_leaves_no_exr_behind(tmp_path, stage):
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--preview", tmp_path / "nowhere" / "p.png", "--spp", 1)
    _refused(r, "--preview", "does not exist")
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--preview", tmp_path / "p.exr", "--spp", 1)
    _refused(r, "--preview", "unsupported extension '.exr'")
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--stats", tmp_path / "gone" / "s.json", "--spp", 1)
    _refused(r, "--stats", "does not exist")
    r = illum("render", stage, "-o", tmp_path / "o.png", "--preview", tmp_path / "o.png", "--spp", 1)
    _refused(r, "--preview", "also the --output output")
    assert sorted(os.listdir(tmp_path)) == ["q.usda"]


@pytest.fixture
def read_only_dir(tmp_path):
    """A directory that refuses new files: mode 0555, and for root (whom permission bits do not
    bind) also the immutable attribute."""
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    immutable = os.geteuid() == 0
    if immutable and subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
        pytest.skip("running as root where chattr +i is refused: no directory refuses root's writes")
    yield d
    if immutable:
        subprocess.run(["chattr", "-i", str(d)], check=True)
    d.chmod(0o755)


def test_read_only_directory_is_refused(stage, read_only_dir):
    _refused(illum("render", stage, "-o", read_only_dir / "o.exr", "--spp", 1), "--output",
             "cannot write in directory", str(read_only_dir))
    assert os.listdir(read_only_dir) == []


@pytest.mark.parametrize("seed", ["2147483648", "4294967296", "-1"])
def test_seed_out_of_range(tmp_path, stage, seed):
    _refused(illum("render", stage, "-o", tmp_path / "o.exr", "--seed", seed), "seed", "2147483647")
    assert not (tmp_path / "o.exr").exists()


def test_largest_seed_renders_and_is_recorded(tmp_path, stage):
    r = illum("render", stage, "-o", tmp_path / "o.exr", "--seed", 2**31 - 1, "--spp", 1, "--quiet")
    assert r.returncode == 0, r.stderr
    assert read_exr(str(tmp_path / "o.exr"))[1]["illum:seed"] == 2**31 - 1


@pytest.mark.parametrize("where", ["/World/Camera", "/World"])
def test_singular_camera_names_prim_and_attribute(tmp_path, where):
    from pxr import UsdGeom

    p = tmp_path / "s.usda"
    st = quad_light_stage(p)
    xf = UsdGeom.Xformable(st.GetPrimAtPath(where)) if where == "/World/Camera" else UsdGeom.Xform.Define(st, where)
    xf.AddScaleOp().Set((1.0, 0.0, 1.0))  # on the camera, or on an ancestor
    st.GetRootLayer().Save()
    _refused(illum("render", p, "-o", tmp_path / "o.exr", "--spp", 1), f"{where}.xformOp:scale", "singular")
    assert not (tmp_path / "o.exr").exists()


def test_film_larger_than_memory_is_refused(tmp_path, stage):
    """Under a 4 GiB address-space limit an 8000 x 8000 film (several GiB of float64 sums) cannot
    fit: refused naming the resolution, not a MemoryError after loading."""
    limit = 4 * 2**30

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    r = subprocess.run([sys.executable, "-m", "renderer.cli", "render", str(stage), "-o", str(tmp_path / "o.exr"),
                        "--res", "8000", "8000", "--spp", "1"], capture_output=True, text=True, cwd=ROOT,
                       timeout=600, preexec_fn=cap)
    _refused(r, "resolution", "8000x8000", "GiB")
    assert not (tmp_path / "o.exr").exists()
