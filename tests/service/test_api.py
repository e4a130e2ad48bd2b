"""The REST API against a real server with real worker processes and real stages."""

from __future__ import annotations

import math
import os
import re
import time

import numpy as np
import pytest

from .conftest import STAGES, TINY, read_exr_bytes, wait_for, wait_job


def _submit(client, **body):
    body.setdefault("stage", "cornell_box.usda")
    body.setdefault("settings", dict(TINY))
    r = client.post("/jobs", json=body)
    assert r.status_code == 201, r.text
    return r.json()


def test_health_docs_and_openapi(client):
    h = client.get("/health").json()
    assert h["status"] == "ok" and h["backend"] == "local" and h["workers"]["alive"] == 2
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    for p in ("/jobs", "/jobs/{job_id}", "/jobs/{job_id}/image", "/jobs/{job_id}/log", "/jobs/{job_id}/cancel",
              "/health", "/metrics", "/stages", "/uploads"):
        assert p in paths, p


def test_stages_listing(client):
    stages = client.get("/stages").json()["stages"]
    assert "cornell_box.usda" in stages and "shots/a.usda" in stages
    assert "textures/sky_latlong.exr" in client.get("/stages", params={"kind": "preconvolve"}).json()["stages"]


def test_render_job_end_to_end(client, tmp_path):
    job = _submit(client, settings={"spp": 8, "resolution": [32, 24]}, priority=70)
    assert job["state"] == "queued" and job["stage"] == "cornell_box.usda" and job["priority"] == 70
    assert job["spp_target"] == 8
    done = wait_job(client, job["id"])
    assert done["state"] == "succeeded", done
    assert done["progress"] == 100.0 and done["spp_done"] == 8 and done["attempts"] == 1
    assert done["error"] is None and done["result"]["resolution"] == [32, 24]

    r = client.get(f"/jobs/{job['id']}/image", params={"format": "exr"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/x-exr"
    assert r.headers["x-illum-image"] == "final"
    img, attrs = read_exr_bytes(r.content, tmp_path)
    assert img.shape == (24, 32, 3) and np.all(np.isfinite(img))
    assert 0.01 < float(img.mean()) < 5.0  # the lit box, not black and not blown out
    assert attrs["illum:spp"] == 8 and attrs["illum:jobId"] == job["id"]
    assert attrs["illum:stage"] == "cornell_box.usda"  # no server paths in deliverables

    png = client.get(f"/jobs/{job['id']}/image", params={"format": "png"})
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    log = client.get(f"/jobs/{job['id']}/log").text
    assert "attempt 1 of 3" in log and "succeeded" in log
    stats = client.get(f"/jobs/{job['id']}/stats").json()
    assert stats["spp"] == 8 and stats["stage"] == "cornell_box.usda"


def test_progressive_snapshots_while_running(client, tmp_path):
    job = _submit(client, settings={"resolution": [48, 48], "spp": 60000, "time_budget": 5})

    def preview():
        r = client.get(f"/jobs/{job['id']}/image", params={"format": "exr"})
        if r.status_code == 200 and r.headers["x-illum-image"] == "preview":
            return r
        return None

    r = wait_for(preview, 30, what="a progressive preview")
    img, attrs = read_exr_bytes(r.content, tmp_path)
    assert img.shape == (48, 48, 3) and attrs["illum:spp"] >= 1
    running = client.get(f"/jobs/{job['id']}").json()
    assert running["state"] == "running"
    assert running["samples_per_second"] > 0 and running["eta_seconds"] is not None
    assert 0 < running["progress"] < 100
    done = wait_job(client, job["id"])
    assert done["state"] == "succeeded" and done["spp_done"] > attrs["illum:spp"]
    assert done["result"]["render_seconds"] == pytest.approx(5, abs=2.5)
    final = client.get(f"/jobs/{job['id']}/image", params={"format": "png"})
    assert final.headers["x-illum-image"] == "final"


def test_list_and_filter(client):
    a = _submit(client)
    wait_job(client, a["id"])
    listing = client.get("/jobs").json()
    assert listing["total"] >= 1 and any(j["id"] == a["id"] for j in listing["jobs"])
    ok = client.get("/jobs", params=[("state", "succeeded"), ("state", "failed")]).json()["jobs"]
    assert all(j["state"] in ("succeeded", "failed") for j in ok) and any(j["id"] == a["id"] for j in ok)
    assert client.get("/jobs", params={"state": "bogus"}).status_code == 422


def test_idempotency_key(client):
    key = f"shot010-{time.monotonic_ns()}"
    body = {"stage": "cornell_box.usda", "settings": dict(TINY), "idempotency_key": key}
    first = client.post("/jobs", json=body)
    again = client.post("/jobs", json=body)
    assert first.status_code == 201 and again.status_code == 200
    assert again.headers["idempotent-replayed"] == "true" and again.json()["id"] == first.json()["id"]
    other = client.post("/jobs", json={**body, "settings": {"spp": 5, "resolution": [16, 16]}})
    assert other.status_code == 409 and key in other.json()["message"]
    hdr = {"Idempotency-Key": key + "-h"}
    h1 = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)}, headers=hdr)
    h2 = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)}, headers=hdr)
    assert h1.json()["id"] == h2.json()["id"]
    both = client.post("/jobs", json={**body, "idempotency_key": key + "-b"}, headers={"Idempotency-Key": key + "-c"})
    assert both.status_code == 400 and both.json()["message"].startswith("idempotency_key:")
    same = client.post("/jobs", json={**body, "idempotency_key": key + "-s"}, headers={"Idempotency-Key": key + "-s"})
    assert same.status_code == 201


def test_key_replayed_after_delete_gives_a_live_job(client):
    key = f"shot020-{time.monotonic_ns()}"
    body = {"stage": "cornell_box.usda", "settings": dict(TINY), "idempotency_key": key}
    first = client.post("/jobs", json=body).json()
    assert client.delete(f"/jobs/{first['id']}").status_code == 204
    again = client.post("/jobs", json=body)
    assert again.status_code == 201 and again.json()["id"] != first["id"]
    assert client.get(f"/jobs/{again.json()['id']}").status_code == 200
    replay = client.post("/jobs", json=body)
    assert replay.status_code == 200 and replay.json()["id"] == again.json()["id"]


def test_cancel_running_job_stops_within_two_seconds(server, client):
    job = _submit(client, settings={"resolution": [16, 16], "time_budget": 120, "spp": 60000})
    wait_for(lambda: client.get(f"/jobs/{job['id']}").json()["spp_done"] >= 2, 30, what="the render to start")
    worker = client.get(f"/jobs/{job['id']}").json()["worker"]
    t0 = time.monotonic()
    r = client.post(f"/jobs/{job['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "canceled"

    def released():
        return all(w["job"] != job["id"] for w in client.get("/health").json()["workers"]["registered"])

    wait_for(released, 5, what="the worker to drop the canceled job")
    assert time.monotonic() - t0 < 2.0
    spp = client.get(f"/jobs/{job['id']}").json()["spp_done"]
    time.sleep(0.6)
    after = client.get(f"/jobs/{job['id']}").json()
    assert after["state"] == "canceled" and after["spp_done"] == spp  # nothing renders any more
    assert "stopped" in client.get(f"/jobs/{job['id']}/log").text
    assert worker in {w["id"] for w in client.get("/health").json()["workers"]["registered"]}  # not killed
    # canceling again is harmless; a finished job cannot be canceled
    assert client.post(f"/jobs/{job['id']}/cancel").status_code == 200


def test_cancel_queued_and_finished(client):
    done = _submit(client)
    wait_job(client, done["id"])
    assert client.post(f"/jobs/{done['id']}/cancel").status_code == 409
    # priority 0 behind a long priority-100 job per worker keeps these queued long enough to cancel
    blockers = [_submit(client, settings={"resolution": [16, 16], "time_budget": 3, "spp": 60000}, priority=100)
                for _ in range(2)]
    queued = _submit(client, priority=0)
    r = client.post(f"/jobs/{queued['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "canceled"
    for b in blockers:
        client.post(f"/jobs/{b['id']}/cancel")
    assert client.get(f"/jobs/{queued['id']}").json()["attempts"] == 0


def test_delete(server, client):
    job = _submit(client)
    wait_job(client, job["id"])
    jobdir = os.path.join(server.data, "jobs", job["id"])
    assert os.path.isdir(jobdir)
    assert client.delete(f"/jobs/{job['id']}").status_code == 204
    assert client.get(f"/jobs/{job['id']}").status_code == 404
    assert client.delete(f"/jobs/{job['id']}").status_code == 404
    wait_for(lambda: not os.path.exists(jobdir), 10, what="the job directory to be removed")
    assert client.get("/jobs/not-a-job-id").status_code == 422
    assert client.get("/jobs/0123456789abcdef").status_code == 404


def test_malformed_stage_fails_with_loader_message(client):
    up = client.post("/uploads", params={"filename": "broken.usda"}, content=b"#usda 1.0\n( this is not usda\n")
    assert up.status_code == 201, up.text
    job = client.post("/jobs", json={"upload": up.json()["upload"], "settings": dict(TINY)}).json()
    done = wait_job(client, job["id"])
    assert done["state"] == "failed" and done["attempts"] == 1  # a user error is not retried
    assert done["stage"] == "upload:broken.usda"
    assert "cannot open stage" in done["error"] and "\n" not in done["error"]
    assert "/uploads/" not in done["error"]  # the user's name, not the server's path
    assert client.get("/health").json()["status"] == "ok"
    # and the workers keep working
    ok = _submit(client)
    assert wait_job(client, ok["id"])["state"] == "succeeded"


def test_render_error_names_the_setting(client):
    job = _submit(client, settings={**TINY, "estimator": {"/No/Such/Light": "mis"}})
    done = wait_job(client, job["id"])
    assert done["state"] == "failed"
    assert "no light at '/No/Such/Light'" in done["error"]


def test_uploaded_stage_renders(client, tmp_path):
    with open(os.path.join(STAGES, "cornell_box.usda"), "rb") as fh:
        data = fh.read()
    up = client.post("/uploads", params={"filename": "my shot.usda"}, content=data).json()
    assert re.match(r"^[0-9a-f]{16}-my_shot\.usda$", up["upload"]) and up["size"] == len(data)
    again = client.post("/uploads", params={"filename": "my shot.usda"}, content=data).json()
    assert again["upload"] == up["upload"]  # content-addressed
    job = client.post("/jobs", json={"upload": up["upload"], "settings": dict(TINY)}).json()
    done = wait_job(client, job["id"])
    assert done["state"] == "succeeded", done
    img, _ = read_exr_bytes(client.get(f"/jobs/{job['id']}/image", params={"format": "exr"}).content, tmp_path)
    assert img.shape == (16, 16, 3)


def test_request_shape_errors(client):
    r = client.post("/jobs", json={"settings": dict(TINY)})
    assert r.status_code == 422 and "exactly one" in r.json()["message"]
    r = client.post("/jobs", json={"stage": "cornell_box.usda", "priority": 101})
    assert r.status_code == 422 and "priority" in r.json()["message"]
    r = client.post("/jobs", json={"stage": "cornell_box.usda", "kind": "denoise"})
    assert r.status_code == 422 and "kind" in r.json()["message"]
    r = client.post("/jobs", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    assert client.get(f"/jobs/{'0' * 16}/image").status_code == 404
    r = client.get("/no/such/endpoint")
    assert r.status_code == 404 and r.json()["message"] == "Not Found"


def test_image_before_any_snapshot_is_404(client):
    blockers = [_submit(client, settings={"resolution": [16, 16], "time_budget": 2, "spp": 60000}, priority=100)
                for _ in range(2)]
    job = _submit(client, priority=0)
    r = client.get(f"/jobs/{job['id']}/image")
    assert r.status_code == 404 and "no image yet" in r.json()["message"]
    for b in blockers:
        client.post(f"/jobs/{b['id']}/cancel")
    client.post(f"/jobs/{job['id']}/cancel")


def test_metrics_prometheus_format(client):
    text = client.get("/metrics").text
    assert client.get("/metrics").headers["content-type"].startswith("text/plain; version=0.0.4")
    samples = {}
    for line in text.splitlines():
        if line.startswith("#"):
            assert re.match(r"^# (HELP|TYPE) illum_[a-z_]+ .+", line), line
            continue
        m = re.match(r'^(illum_[a-z_]+)(\{[a-z_]+="[^"]*"(,[a-z_]+="[^"]*")*\})? (\S+)$', line)
        assert m, line
        samples[m.group(1) + (m.group(2) or "")] = float(m.group(4))
        assert math.isfinite(samples[m.group(1) + (m.group(2) or "")])
    assert samples['illum_jobs{state="succeeded"}'] >= 1
    assert samples['illum_workers{backend="local"}'] == 2
    assert samples["illum_jobs_created_total"] >= 1
    assert any(k.startswith("illum_http_requests_total") for k in samples)


def test_preconvolve_job(client, tmp_path):
    pytest.importorskip("renderer.preconvolve", reason="renderer/preconvolve.py is not in this tree yet")
    for method in ("sh", "exact"):
        job = client.post("/jobs", json={"kind": "preconvolve", "stage": "textures/sky_latlong.exr",
                                         "settings": {"size": 16, "method": method}}).json()
        done = wait_job(client, job["id"], timeout=120)
        assert done["state"] == "succeeded", done
        assert done["result"]["resolution"] == [16, 8]
        r = client.get(f"/jobs/{job['id']}/image", params={"format": "exr"})
        img, attrs = read_exr_bytes(r.content, tmp_path)
        assert img.shape[:2] == (8, 16) and np.all(np.isfinite(img)) and img.mean() > 0
        assert attrs["illum:method"] == method
    bad = client.post("/jobs", json={"kind": "preconvolve", "stage": "cornell_box.usda"})
    assert bad.status_code == 400


def test_the_job_list_follows_each_change(client):
    """GET /jobs reuses a listed job's JSON while its row is unchanged (service/app.py
    _ListCache): each state, progress and new image is still in the next listing, and a listed
    job is what GET /jobs/{id} says (less the frames and the elapsed time, which runs on)."""
    job = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": {"resolution": [8, 8], "spp": 2}}).json()

    def listed():
        return next(j for j in client.get("/jobs", params={"limit": 1000}).json()["jobs"] if j["id"] == job["id"])

    assert listed()["state"] in ("queued", "running")   # listed (and kept) before it ends
    done = wait_job(client, job["id"])
    last = listed()
    assert last["state"] == "succeeded" and last["progress"] == 100.0 and last["spp_done"] == 2
    assert last["links"]["image_png"] and last["links"]["thumbnail"] and last["result"]["spp"] == 2
    one = client.get(f"/jobs/{job['id']}").json()
    for j in (last, one, done):
        j.pop("elapsed_seconds"), j.pop("frames", None)
    assert last == one == done
    assert client.post(f"/jobs/{job['id']}/requeue").status_code == 409   # succeeded: unchanged
    assert listed()["state"] == "succeeded"
