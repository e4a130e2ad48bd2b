"""A `.usdz` uploaded to the render service renders as the same stage unpacked under the stage
root, and the missing-asset policy is chosen per job (settings.strict)."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, UsdUtils

from tests.usd.test_usdz import _textured_stage, package_without_albedo

from .conftest import TINY, read_exr_bytes, wait_job

SETTINGS = {**TINY, "seed": 11, "max_depth": 2}


def _upload(client, path, name):
    with open(path, "rb") as fh:
        up = client.post("/uploads", params={"filename": name}, content=fh.read())
    assert up.status_code == 201, up.text
    return up.json()["upload"]


def _image(client, tmp_path, body, name):
    job = client.post("/jobs", json={**body, "settings": dict(SETTINGS)})
    assert job.status_code == 201, job.text
    done = wait_job(client, job.json()["id"], timeout=180)
    assert done["state"] == "succeeded", done
    data = client.get(f"/jobs/{done['id']}/image", params={"format": "exr"}).content
    return read_exr_bytes(data, tmp_path, name)[0]


def test_uploaded_usdz_renders_like_the_unpacked_stage(client, stage_root, tmp_path):
    import pathlib

    src = _textured_stage(pathlib.Path(stage_root) / "usdz_src")
    pkg = str(tmp_path / "packed.usdz")
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(src), pkg)
    packed = _image(client, tmp_path, {"upload": _upload(client, pkg, "packed.usdz")}, "packed.exr")
    plain = _image(client, tmp_path, {"stage": "usdz_src/scene.usda"}, "plain.exr")
    assert np.all(np.isfinite(packed)) and packed.max() > 0.0
    assert np.array_equal(packed, plain)


def test_strict_is_per_job(client, tmp_path):
    upload = _upload(client, package_without_albedo(tmp_path), "broken.usdz")
    ok = client.post("/jobs", json={"upload": upload, "settings": dict(SETTINGS)}).json()
    strict = client.post("/jobs", json={"upload": upload, "settings": {**SETTINGS, "strict": True}}).json()
    assert wait_job(client, ok["id"], timeout=180)["state"] == "succeeded"
    done = wait_job(client, strict["id"], timeout=180)
    assert done["state"] == "failed" and done["attempts"] == 1
    assert "/World/Looks/Tex/Albedo.inputs:file: file not found" in done["error"]
    assert "albedo.png" in done["error"]
