"""`illum bench` end to end on a tiny stage: files written, references cached and reused.

Budgets are tiny (0.2-0.3 s) and nothing asserts on timing: only on what gets written.
"""

import csv
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from renderer.bench import BenchSettings, parse_configs, run_bench, stage_content_hash
from renderer.errors import SettingsError
from renderer.film import Film, write_exr
from tests.stage_builders import quad_light_stage

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture
def tiny_stage(tmp_path):
    path = tmp_path / "tiny.usda"
    quad_light_stage(str(path), res=(16, 12), intensity=3.0)
    return str(path)


def settings(out, **kw):
    base = dict(configs=parse_configs("mis,controlVariate:one"), budgets=[0.2], out=str(out), resolution=(16, 12),
                max_depth=1, seed=3, reference_spp=4, light_samples=2)
    base.update(kw)
    return BenchSettings(**base)


def test_cli_writes_all_three_files(tmp_path, tiny_stage):
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "renderer.cli", "bench", tiny_stage, "--estimators", "mis,bsdfSampling",
                        "--budgets", "0.3", "--res", "16", "12", "--max-depth", "1", "--reference-spp", "8",
                        "--out", str(out), "--raw-throughput", "--raw-seconds", "0.2", "--raw-max-depth", "2"],
                       capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    for name in ("results.csv", "results.md", "error_vs_time.png"):
        assert (out / name).stat().st_size > 0, name
    with open(out / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [row["config"] for row in rows] == ["mis", "bsdfSampling"]
    for row in rows:
        assert float(row["relmse"]) >= 0.0 and float(row["rmse"]) >= 0.0
        assert float(row["efficiency"]) > 0.0 and int(row["spp"]) >= 1
        assert (row["width"], row["height"], row["max_depth"]) == ("16", "12", "1")
    md = (out / "results.md").read_text()
    for needle in ("## Machine", "CPU:", "embreex", "numpy", "relMSE", "| mis |", "## Raw throughput",
                   "ratio ours / raw", "illum bench"):
        assert needle in md, needle
    assert (out / "error_vs_time.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((out / "references").glob("tiny-*.exr"))) == 1


def test_reference_is_cached_and_reused(tmp_path, tiny_stage):
    out = tmp_path / "out"
    first = run_bench([tiny_stage], settings(out, configs=parse_configs("mis")))
    ref1 = first["references"]["tiny"]
    assert not ref1.cached and ref1.floor is not None and ref1.floor >= 0.0
    mtime = os.path.getmtime(ref1.path)
    second = run_bench([tiny_stage], settings(out, configs=parse_configs("ratio")))
    ref2 = second["references"]["tiny"]
    assert ref2.cached and ref2.path == ref1.path
    assert os.path.getmtime(ref2.path) == mtime
    np.testing.assert_array_equal(ref1.image.astype(np.float32), ref2.image.astype(np.float32))
    assert ref2.floor == pytest.approx(ref1.floor)
    # A different resolution or depth is a different reference.
    third = run_bench([tiny_stage], settings(out, resolution=(12, 9), configs=parse_configs("mis")))
    assert not third["references"]["tiny"].cached
    assert len(list((out / "references").glob("*.exr"))) == 2


def test_content_hash_follows_content_not_location(tmp_path, tiny_stage):
    h = stage_content_hash(tiny_stage)
    moved = tmp_path / "elsewhere" / "tiny.usda"
    moved.parent.mkdir()
    shutil.copy(tiny_stage, moved)
    assert stage_content_hash(str(moved)) == h
    with open(moved, "a") as fh:
        fh.write("\n")
    assert stage_content_hash(str(moved)) != h


def test_user_reference_exr(tmp_path, tiny_stage):
    film = Film(16, 12)
    film.add(np.arange(16 * 12), np.full((16 * 12, 3), 0.25))
    ref = tmp_path / "ref.exr"
    write_exr(str(ref), film)
    res = run_bench([tiny_stage], settings(tmp_path / "out", reference=str(ref), configs=parse_configs("mis")))
    assert res["references"]["tiny"].floor is None
    assert not (tmp_path / "out" / "references").exists()
    (row,) = res["rows"]
    assert row["relmse"] > 0.0
    # A reference of the wrong size is a user error.
    with pytest.raises(SettingsError):
        run_bench([tiny_stage], settings(tmp_path / "out2", reference=str(ref), resolution=(8, 6)))


def test_cli_user_errors(tmp_path, tiny_stage, capsys):
    from renderer.cli import main

    for args in (["--estimators", "nope"], ["--budgets", "0"], ["--reference", str(tmp_path / "missing.exr")],
                 ["--light-samplers", "closest"]):
        code = main(["bench", tiny_stage, "--out", str(tmp_path / "o"), *args])
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        assert err.startswith("illum: error:") and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


def test_repeats_are_interleaved_and_report_what_auto_picked(tmp_path, tiny_stage):
    out = tmp_path / "out"
    res = run_bench([tiny_stage], settings(out, configs=parse_configs("mis,auto"), repeats=2))
    rows = res["rows"]
    # Each repeat runs every configuration back to back, with its own seed.
    assert [(r["repeat"], r["config"], r["seed"]) for r in rows] == [(0, "mis", 3), (0, "auto", 3),
                                                                     (1, "mis", 4), (1, "auto", 4)]
    for r in rows:
        if r["config"] == "auto":
            assert r["auto_choice"] in ("lightSampling", "bsdfSampling", "mis", "controlVariate")
            assert r["pilot_cpu_seconds"] > 0.0  # the warm-up's pilot, reported once per stage
        else:
            assert r["auto_choice"] == "" and r["pilot_cpu_seconds"] == 0.0
    md = (out / "results.md").read_text()
    assert "ran 2 times" in md and "`auto` picked **" in md
    assert "| mis | " in md and " 1 (1-1) |" in md  # MIS against itself: median 1, range 1-1
