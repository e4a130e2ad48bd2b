"""Frame ranges on the command line (husk's --frame/--frame-count/--frame-inc and --frames),
output names per frame, per-frame progress and statistics, the stage opened once, and each
frame read at its own time code (stages/anim/turntable.usda animates a transform, points and a
light). Real renders read back with OpenImageIO."""

import json
import os

import numpy as np
import pytest

from renderer.errors import SettingsError
from renderer.film import read_exr
from renderer.frames import frame_name, parse_frames

from .test_cli import ROOT, _error, illum

ANIM = os.path.join(ROOT, "stages", "anim", "turntable.usda")
SMALL = ("--res", 32, 18, "--spp", 2, "--seed", 4, "-j", 1)


def test_frame_specs_and_names():
    assert parse_frames("1-10x3") == [1, 4, 7, 10]
    assert parse_frames("1-100x2")[:3] == [1, 3, 5] and len(parse_frames("1-100x2")) == 50
    assert parse_frames("5, 1-2, 7-8x0.5") == [5, 1, 2, 7, 7.5, 8]
    assert parse_frames("-2--1") == [-2, -1]
    for bad in ("", "1-", "a-b", "5-1", "1-5x0", "1-5x-1"):
        with pytest.raises(SettingsError, match="--frames"):
            parse_frames(bad)
    assert frame_name("a.$F4.exr", 12) == "a.0012.exr"
    assert frame_name("a.${F3}_$F.exr", 7) == "a.007_7.exr"
    assert frame_name("a.####.exr", 3) == "a.0003.exr" and frame_name("a.#.exr", 12) == "a.12.exr"
    assert frame_name("a.$FF.exr", 12.5) == "a.12.5.exr" and frame_name("a.$F4.exr", -3) == "a.-003.exr"
    assert frame_name("plain.exr", 3) == "plain.exr"
    assert [frame_name("$F", f) for f in (1.5, 2.5, -1.5)] == ["2", "3", "-1"]  # half up


def test_range_matches_separate_frames_and_names_them(tmp_path):
    """--frames 1-10x3 writes t.0001 ... t.0010, each identical (same seed, one thread) to that
    frame rendered on its own: every frame is read at its time code from the stage opened once."""
    r = illum("render", ANIM, "--frames", "1-10x3", "-o", tmp_path / "t.$F4.exr", "--preview",
              tmp_path / "p.####.png", "--stats", tmp_path / "s.json", *SMALL)
    assert r.returncode == 0, r.stderr
    names = sorted(os.listdir(tmp_path))
    assert names == ["p.0001.png", "p.0004.png", "p.0007.png", "p.0010.png", "s.json",
                     "t.0001.exr", "t.0004.exr", "t.0007.exr", "t.0010.exr"], names
    # progress: ALF_PROGRESS over the whole range, one line per frame written
    pct = [int(l.split()[1].rstrip("%")) for l in r.stdout.splitlines() if l.startswith("ALF_PROGRESS")]
    assert pct == sorted(pct) and pct[-1] == 100
    assert any(p <= 25 for p in pct) and any(50 <= p < 75 for p in pct)  # the range's, not one frame's
    for k, f in enumerate((1, 4, 7, 10)):
        assert f"frame {f} [{k + 1}/4]: wrote" in r.stderr, r.stderr
    assert "4 frames in" in r.stderr and "frames/min" in r.stderr
    stats = json.loads((tmp_path / "s.json").read_text())
    assert [s["frame"] for s in stats["frames"]] == [1, 4, 7, 10] and stats["range"]["frames"] == 4
    assert all(s["spp"] == 2 for s in stats["frames"])
    single = tmp_path / "single"
    single.mkdir()
    r = illum("render", ANIM, "--frame", 7, "-o", single / "t7.exr", *SMALL)
    assert r.returncode == 0, r.stderr
    img7, attrs7 = read_exr(str(tmp_path / "t.0007.exr"))
    alone, _ = read_exr(str(single / "t7.exr"))
    np.testing.assert_array_equal(img7, alone)
    img1, attrs1 = read_exr(str(tmp_path / "t.0001.exr"))
    img10, attrs10 = read_exr(str(tmp_path / "t.0010.exr"))
    assert attrs1["illum:frame"] == 1.0 and attrs7["illum:frame"] == 7.0 and attrs10["illum:frame"] == 10.0
    # the camera dollies from z = 4 to z = 3 (y = 1.2): worldToCamera's translation is the
    # origin's position in camera space, at the camera's distance from it
    t1 = np.array(attrs1["worldToCamera"]).reshape(4, 4)[3, :3]
    t10 = np.array(attrs10["worldToCamera"]).reshape(4, 4)[3, :3]
    assert np.linalg.norm(t1) == pytest.approx(np.hypot(1.2, 4.0), rel=1e-5)
    assert np.linalg.norm(t10) == pytest.approx(np.hypot(1.2, 3.0), rel=1e-5)
    assert not np.array_equal(img1, img10)
    # the key light doubles its intensity and warms to colour (1, 0.8, 0.6): the floor in front
    # (the bottom rows; the dome's constant 0.15 fills the sky) brightens and turns orange
    floor1, floor10 = img1[-3:].reshape(-1, 3).mean(axis=0), img10[-3:].reshape(-1, 3).mean(axis=0)
    assert floor1[0] / floor1[2] == pytest.approx(1.0, abs=0.05)
    assert floor10[0] / floor10[2] > 1.3 and floor10[0] > 1.3 * floor1[0]


def test_frame_count_and_inc_with_product_name(tmp_path):
    """husk's -f/-n/-i forms; no -o: the RenderProduct's productName turntable.$F4.exr."""
    r = illum("render", ANIM, "--frame", 2, "--frame-count", 3, "--frame-inc", 2, *SMALL, "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(tmp_path)) == ["turntable.0002.exr", "turntable.0004.exr", "turntable.0006.exr"]
    assert r.stdout == "" and r.stderr == ""


def test_frame_count_starts_at_the_stage_start(tmp_path):
    r = illum("render", ANIM, "-n", 2, "-o", tmp_path / "f_####.exr", *SMALL, "--stats", tmp_path / "s_$F.json")
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(tmp_path)) == ["f_0001.exr", "f_0002.exr", "s_1.json", "s_2.json"]
    assert json.loads((tmp_path / "s_2.json").read_text())["frame"] == 2.0


def test_stage_is_opened_once_for_a_range(tmp_path, monkeypatch):
    from renderer import cli
    from renderer.usd import stage_reader

    opened = []
    real = stage_reader.open_stage
    monkeypatch.setattr(stage_reader, "open_stage", lambda path: opened.append(path) or real(path))
    assert cli.main(["render", ANIM, "--frames", "3-5", "-o", str(tmp_path / "o.$F.exr"), *map(str, SMALL),
                     "--quiet"]) == 0
    assert opened == [ANIM]
    assert sorted(os.listdir(tmp_path)) == ["o.3.exr", "o.4.exr", "o.5.exr"]


@pytest.mark.parametrize("args, needles", [
    (("--frames", "1-3", "-o", "same.exr"), ("--output", "names no frame")),
    (("--frames", "1-3", "-o", "o.$F.exr", "--preview", "p.png"), ("--preview", "names no frame")),
    (("--frames", "5-1", "-o", "o.$F.exr"), ("--frames", "ends before it starts")),
    (("--frames", "1-3", "--frame", "2", "-o", "o.$F.exr"), ("--frames", "cannot be combined")),
    (("--frames", "1-2x0.5", "-o", "o.$F.exr"), ("also the --output output",)),
    (("--frame-count", "0", "-o", "o.$F.exr"), ("--frame-count",)),
    (("--frames", "1-3", "-o", "nowhere/o.$F.exr"), ("--output", "does not exist")),
])
def test_bad_ranges_are_refused_before_rendering(tmp_path, args, needles):
    r = illum("render", ANIM, *args, "--spp", 1, cwd=tmp_path)
    _error(r, *needles)
    assert "ALF_PROGRESS" not in r.stdout
    assert os.listdir(tmp_path) == []


def test_product_name_without_a_frame_token_is_refused_for_a_range(tmp_path):
    from tests.stage_builders import quad_light_stage

    p = tmp_path / "q.usda"
    quad_light_stage(p)   # no RenderProduct: the default name gets the frame
    r = illum("render", p, "--frames", "1-2", "--spp", 1, "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(tmp_path)) == ["q.usda", "q_0001.exr", "q_0002.exr"]


def test_version_and_verbosity(tmp_path):
    from renderer.render import VERSION

    for args in (("--version",), ("render", "--version")):
        r = illum(*args)
        assert r.returncode == 0 and r.stdout.strip() == f"illum {VERSION}", r
    base = ("render", ANIM, "--frames", "1-2", "-o", tmp_path / "o.$F.exr", *SMALL)
    quiet = illum(*base, "-V", 0)
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""
    one = illum(*base, "-V", 1)
    assert "ALF_PROGRESS" not in one.stdout and "frame 2 [2/2]: wrote" in one.stderr
    assert " s, build " not in one.stderr
    three = illum(*base, "-V", "3a")
    assert "ALF_PROGRESS 100%" in three.stdout
    assert "frame 1 [1/2]: load" in three.stderr and "build" in three.stderr
    four = illum(*base, "-V", 4)
    assert "Mrays/s" in four.stderr and "/World/Lights/Key=" in four.stderr
    bad = illum(*base, "-V", "x")
    assert bad.returncode == 2 and "-V expects a level 0-9" in bad.stderr
