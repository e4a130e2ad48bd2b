"""Jobs the renderer refuses before rendering (issue 21, item 1) fail at once in the service,
with the CLI's one-line message, and are not retried: a singular camera, a film larger than the
worker's memory; an out-of-range seed is a 422 at submission."""

from __future__ import annotations

from pxr import UsdGeom

from tests.stage_builders import quad_light_stage

from .conftest import TINY, wait_job


def _upload(client, tmp_path, name, edit=None) -> str:
    p = tmp_path / name
    st = quad_light_stage(p)
    if edit is not None:
        edit(st)
    st.GetRootLayer().Save()
    up = client.post("/uploads", params={"filename": name}, content=p.read_bytes())
    assert up.status_code == 201, up.text
    return up.json()["upload"]


def test_singular_camera_fails_at_once_without_retry(client, tmp_path):
    def flatten(st):
        UsdGeom.Xformable(st.GetPrimAtPath("/World/Camera")).AddScaleOp().Set((0.0, 0.0, 0.0))

    upload = _upload(client, tmp_path, "flat_camera.usda", flatten)
    job = client.post("/jobs", json={"upload": upload, "settings": dict(TINY), "max_attempts": 3}).json()
    done = wait_job(client, job["id"])
    assert done["state"] == "failed" and done["attempts"] == 1, done
    assert "/World/Camera.xformOp:scale" in done["error"] and "singular" in done["error"], done["error"]
    assert "\n" not in done["error"]


def test_seed_beyond_int32_is_refused_at_submission(client):
    r = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": {**TINY, "seed": 2**31}})
    assert r.status_code == 422, r.text
    assert "seed" in r.text
    ok = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": {**TINY, "seed": 2**31 - 1}})
    assert ok.status_code == 201, ok.text
    assert wait_job(client, ok.json()["id"])["state"] == "succeeded"
