"""Request validation without a server: settings schema and limits, path confinement, uploads."""

from __future__ import annotations

import argparse
import os

import pytest

from service.config import Limits
from service.models import render_options, request_hash, settings_from_options, validate_settings
from service.paths import (STAGE_EXTENSIONS, InputError, check_magic, list_stages, resolve_in_root,
                           resolve_upload, upload_name)

LIMITS = Limits(max_spp=1000, max_time_budget=60.0, max_side=512, max_pixels=512 * 256)


def _err(kind, settings):
    with pytest.raises(InputError) as e:
        validate_settings(kind, settings, LIMITS)
    return e.value


@pytest.mark.parametrize("settings, field, words", [
    ({"spp": 1001}, "settings.spp", "limit of 1000"),
    ({"spp": 0}, "settings.spp", "must be an integer in [1, 1000000], got 0"),
    ({"spp": "many"}, "settings.spp", "integer"),
    ({"time_budget": 61}, "settings.time_budget", "limit of 60"),
    ({"time_budget": -1}, "settings.time_budget", "must be a number in (0, 1000000000], got -1"),
    ({"resolution": [513, 10]}, "settings.resolution", "512 pixels per side"),
    ({"resolution": [512, 512]}, "settings.resolution", "131072 pixels"),
    ({"resolution": [0, 10]}, "settings.resolution", "must be an integer >= 1, got 0"),
    ({"resolution": [10]}, "settings.resolution", ""),
    ({"estimator": "best"}, "settings.estimator", "must be one of mis, "),
    ({"estimator": {"Light": "mis"}}, "settings.estimator", "starting with '/'"),
    ({"cv_alpha": "zero"}, "settings.cv_alpha", "must be one of one, "),
    ({"light_samples": 0}, "settings.light_samples", "in [1, 4096], got 0"),
    ({"light_sampler": "best"}, "settings.light_sampler", "must be one of auto, "),
    ({"camera": "Cam era"}, "settings.camera", "prim path starting with '/' or a prim name"),
    ({"sppp": 4}, "settings.sppp", "Extra inputs"),
    ({"frame": float("nan")}, "settings.frame", "finite"),
])
def test_render_settings_errors_name_the_field(settings, field, words):
    e = _err("render", settings)
    assert e.status == 422
    assert e.field == field or e.field.startswith(field + ".")  # tuple items add their index
    assert words in e.message


def test_render_settings_are_normalised():
    s = validate_settings("render", {"resolution": [32, 16], "estimator": "mis", "light_samples": {"/L": 4}}, LIMITS)
    assert s["spp"] == 64  # the default when neither spp nor a time budget is given
    assert s["estimator"] == {"": "mis"} and s["light_samples"] == {"/L": 4}
    assert validate_settings("render", {"time_budget": 5}, LIMITS)["spp"] is None
    # the same request spelled differently hashes the same (idempotency compares normalised bodies)
    t = validate_settings("render", {"estimator": {"": "mis"}, "resolution": [32, 16], "light_samples": {"/L": 4}},
                          LIMITS)
    assert request_hash("render", "a", s, 50, 3) == request_hash("render", "a", t, 50, 3)


def test_render_options_mapping_and_time_cap():
    s = validate_settings("render", {"spp": 8, "resolution": [32, 16], "camera": "/World/Camera",
                                     "settings_prim": "/Render/Settings", "light_sampler": "power",
                                     "estimator": {"/L": "ratio"}, "max_depth": 3, "seed": 7}, LIMITS)
    o = render_options(s, threads=2, max_time=10.0)
    assert (o.spp, o.resolution, o.camera, o.settings, o.light_sampler) == \
        (8, (32, 16), "/World/Camera", "/Render/Settings", "power")
    assert o.estimator == {"/L": "ratio"} and o.max_depth == 3 and o.seed == 7 and o.threads == 2
    assert o.time_budget == 10.0  # an spp-only job is still bounded by the server's time cap
    o.validate()


def test_cli_flags_round_trip_to_settings():
    from renderer.cli import add_render_flags, options_from_args

    p = argparse.ArgumentParser()
    add_render_flags(p)
    a = p.parse_args(["--spp", "16", "--res", "64", "32", "--estimator", "/World/Lights/Key=controlVariate",
                      "--light-sampler", "power", "--camera", "/World/Camera", "--seed", "3"])
    settings = settings_from_options(options_from_args(a))
    assert settings == {"spp": 16, "resolution": [64, 32], "camera": "/World/Camera", "seed": 3,
                        "light_sampler": "power", "estimator": {"/World/Lights/Key": "controlVariate"}}
    validate_settings("render", settings, Limits())


def test_preconvolve_settings():
    assert validate_settings("preconvolve", {"size": 32, "method": "sh"}, LIMITS) == \
        {"size": 32, "method": "sh", "sanitize": False}
    assert _err("preconvolve", {"size": 33}).field == "settings.size"
    assert _err("preconvolve", {"size": 2}).field == "settings.size"
    assert _err("preconvolve", {"size": 99999}).field == "settings.size"
    assert _err("preconvolve", {"method": "fast"}).field == "settings.method"


# ---------------------------------------------------------------------------- paths
@pytest.fixture
def root(tmp_path):
    r = tmp_path / "root"
    (r / "shots").mkdir(parents=True)
    (r / "shots" / "a.usda").write_text("#usda 1.0\n")
    (r / "b.usdc").write_bytes(b"PXR-USDC")
    outside = tmp_path / "outside.usda"
    outside.write_text("#usda 1.0\n")
    (tmp_path / "secret").mkdir()
    (tmp_path / "secret" / "c.usda").write_text("#usda 1.0\n")
    os.symlink(outside, r / "escape.usda")
    os.symlink(tmp_path / "secret", r / "linkdir")
    os.symlink(r / "shots" / "a.usda", r / "inside_link.usda")
    (r / "notes.txt").write_text("x")
    return r


@pytest.mark.parametrize("path", ["../outside.usda", "shots/../../outside.usda", "escape.usda", "linkdir/c.usda",
                                  "/etc/passwd", "notes.txt", "missing.usda", "", "shots", "a\x00.usda"])
def test_paths_outside_or_invalid_are_rejected(root, path):
    with pytest.raises(InputError) as e:
        resolve_in_root(str(root), path, STAGE_EXTENSIONS)
    assert e.value.status == 400 and e.value.field == "stage"


def test_paths_inside_are_accepted(root):
    assert resolve_in_root(str(root), "shots/a.usda", STAGE_EXTENSIONS)[1] == "shots/a.usda"
    assert resolve_in_root(str(root), "shots/../b.usdc", STAGE_EXTENSIONS)[1] == "b.usdc"
    assert resolve_in_root(str(root), str(root / "shots" / "a.usda"), STAGE_EXTENSIONS)[1] == "shots/a.usda"
    # a symlink that stays inside the root resolves to its target
    assert resolve_in_root(str(root), "inside_link.usda", STAGE_EXTENSIONS)[1] == "shots/a.usda"


def test_list_stages_skips_escaping_links(root):
    assert list_stages(str(root)) == ["b.usdc", "inside_link.usda", "shots/a.usda"]


def test_upload_names_are_sanitised(tmp_path):
    sha = "ab" * 32
    assert upload_name(sha, "../../etc/shot 1.USDA") == "abababababababab-shot_1.usda"
    assert upload_name(sha, "$(rm -rf ~).usdz") == "abababababababab-rm_-rf___.usdz"
    with pytest.raises(InputError):
        upload_name(sha, "x.sh")
    with pytest.raises(InputError):
        resolve_upload(str(tmp_path), "../jobs.db")
    with pytest.raises(InputError):
        resolve_upload(str(tmp_path), "abababababababab-missing.usda")


def test_upload_magic():
    check_magic(b"PXR-USDC\x00", "a.usdc")
    check_magic(b"PK\x03\x04", "a.usdz")
    check_magic(b"anything", "a.usda")  # text layers are the loader's to judge
    for head, name in ((b"#usda 1.0", "a.usdc"), (b"#usda", "a.usdz"), (b"garbage", "a.usd")):
        with pytest.raises(InputError):
            check_magic(head, name)
