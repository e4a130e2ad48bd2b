"""Frame ranges in the service (#20 item 5): a range is one job whose frames are its tasks, each
with its own state, attempts and image. Real server, real workers, the animated turntable stage;
the frames' EXRs are read back with OpenImageIO and compared with ``illum render`` of the same
frame, and a worker killed on frame k has only frame k rendered again."""

from __future__ import annotations

import os
import shutil
import signal

import numpy as np
import pytest

from .conftest import STAGES, make_stage_root, read_exr_bytes, start_server, wait_for, wait_job
from .test_faults import _alive

ANIM = os.path.join(STAGES, "anim", "turntable.usda")
SMALL = {"resolution": [24, 14], "spp": 2, "seed": 4}


@pytest.fixture(scope="module")
def frames_server(tmp_path_factory):
    """One worker rendering on one thread: its frames are then bit-identical to ``illum render
    -j 1`` of the same frame and seed."""
    tmp = tmp_path_factory.mktemp("frames")
    root = make_stage_root(tmp / "root")
    os.makedirs(os.path.join(root, "anim"))
    shutil.copy(ANIM, os.path.join(root, "anim", "turntable.usda"))
    s = start_server(tmp, root, workers=1, extra=["--threads", "1"])
    yield s
    s.stop()


def _cli_frame(tmp_path, frame: float) -> np.ndarray:
    from renderer import cli
    from renderer.film import read_exr

    out = tmp_path / f"cli.{frame:g}.exr"
    assert cli.main(["render", ANIM, "--frame", str(frame), "--res", *map(str, SMALL["resolution"]), "--spp",
                     str(SMALL["spp"]), "--seed", str(SMALL["seed"]), "-j", "1", "-o", str(out), "--quiet"]) == 0
    return read_exr(str(out))[0]


def test_a_range_is_one_job_with_a_task_per_frame(frames_server, tmp_path):
    s = frames_server
    with s.client() as c:
        r = c.post("/jobs", json={"stage": "anim/turntable.usda", "settings": {**SMALL, "frames": "2-6x2"}})
        assert r.status_code == 201, r.text
        job = r.json()
        assert [f["frame"] for f in job["frames"]] == [2.0, 4.0, 6.0]
        assert job["frame_counts"]["queued"] == 3
        done = wait_job(c, job["id"], timeout=180)
        assert done["state"] == "succeeded", done
        assert done["progress"] == 100.0 and done["result"]["frames"] == 3
        assert [(f["index"], f["state"], f["attempts"], f["spp_done"]) for f in done["frames"]] == \
            [(0, "succeeded", 1, 2), (1, "succeeded", 1, 2), (2, "succeeded", 1, 2)]
        listed = next(j for j in c.get("/jobs").json()["jobs"] if j["id"] == job["id"])
        assert listed["frame_counts"]["succeeded"] == 3 and "frames" not in listed
        images = {}
        for f in done["frames"]:
            r = c.get(f["links"]["image_exr"])
            assert r.status_code == 200 and r.headers["X-Illum-Frame"] == f"{f['frame']:g}"
            img, attrs = read_exr_bytes(r.content, tmp_path, f"f{f['index']}.exr")
            assert attrs["illum:frame"] == f["frame"] and attrs["illum:jobId"] == job["id"]
            images[f["frame"]] = img
            assert c.get(f["links"]["image_png"]).content[:8] == b"\x89PNG\r\n\x1a\n"
        # each task rendered its own time code: exactly what `illum render --frame F` gives
        for frame in (2.0, 6.0):
            assert np.array_equal(images[frame], _cli_frame(tmp_path, frame)), frame
        assert not np.array_equal(images[2.0], images[6.0])  # the ball rolled, the camera moved
        assert c.get(f"/jobs/{job['id']}/frames/3/image").status_code == 404
        log = c.get(f"/jobs/{job['id']}/log").text
        assert "frame 4: [2/3] attempt 1 of 3" in log and log.count("succeeded: 2 spp") == 3


@pytest.mark.parametrize("settings, field, words", [
    ({"frames": "5-1"}, "settings.frames", "ends before it starts"),
    ({"frames": "1-3", "frame": 2}, "settings.frames", "cannot be combined"),
    ({"frame_count": 3}, "settings.frame", "needs its first frame"),
    ({"frame": 1, "frame_count": 0}, "settings.frame_count", "in [1, 100000], got 0"),
    ({"frame": 1, "frame_count": 2, "frame_inc": 0}, "settings.frame_inc", "in (0, 1000000000], got 0"),
    ({"frames": "1-20000"}, "settings.frames", "server limit of 10000"),
])
def test_bad_ranges_are_refused_naming_the_setting(frames_server, settings, field, words):
    with frames_server.client() as c:
        r = c.post("/jobs", json={"stage": "anim/turntable.usda", "settings": {**SMALL, **settings}})
        assert r.status_code == 422, r.text
        assert r.json()["detail"][0]["loc"] == ["body", *field.split(".")], r.json()
        assert r.json()["message"].startswith(field + ": ") and words in r.json()["message"], r.json()


def _worker_pid(server, job_id):
    return next((pid for pid, job in server.worker_pids().values() if job == job_id), None)


def test_a_worker_killed_on_frame_k_retries_only_frame_k(frames_server):
    """kill -9 of the worker while it renders the second frame: the job goes back to the queue,
    and the next worker renders frame 2 again (its second attempt, resuming from its checkpoint)
    and then frame 3; frame 1's image is never rewritten."""
    s = frames_server
    slow = {"resolution": [24, 14], "time_budget": 4.0, "seed": 1}   # seconds per frame
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "anim/turntable.usda", "settings": {**slow, "frames": "1-3"}}).json()

        def second_frame_checkpointed():
            j = c.get(f"/jobs/{job['id']}").json()
            ckpt = os.path.join(s.data, "jobs", job["id"], "frames", "0001", "checkpoint.json")
            return j if j["frames"][1]["state"] == "running" and os.path.exists(ckpt) else None

        mid = wait_for(second_frame_checkpointed, 120, what="the second frame's first checkpoint")
        assert mid["frames"][0]["state"] == "succeeded" and mid["frame_counts"]["running"] == 1
        first_exr = os.path.join(s.data, "jobs", job["id"], "frames", "0000", "final.exr")
        first_mtime = os.stat(first_exr).st_mtime_ns
        os.kill(_worker_pid(s, job["id"]), signal.SIGKILL)
        done = wait_job(c, job["id"], timeout=180)
        assert done["state"] == "succeeded", done
        assert [f["attempts"] for f in done["frames"]] == [1, 2, 1]
        assert done["attempts"] == 2 and all(f["state"] == "succeeded" for f in done["frames"])
        assert os.stat(first_exr).st_mtime_ns == first_mtime
        log = c.get(f"/jobs/{job['id']}/log").text
        assert "frame 2: [2/3] attempt 2 of 3" in log and "frame 2: resuming from checkpoint" in log, log
        assert log.count("frame 1: [1/3]") == 1 and log.count("frame 3: [3/3]") == 1, log


def test_a_frame_out_of_attempts_fails_alone(frames_server):
    """With max_attempts 1, the frame whose worker is killed fails; the other frames still
    render, and the job fails naming that frame."""
    s = frames_server
    slow = {"resolution": [24, 14], "time_budget": 3.0, "seed": 2}
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "anim/turntable.usda", "max_attempts": 1,
                                    "settings": {**slow, "frame": 5, "frame_count": 3}}).json()
        wait_for(lambda: c.get(f"/jobs/{job['id']}").json()["frames"][1]["state"] == "running", 120,
                 what="the second frame to start")
        os.kill(_worker_pid(s, job["id"]), signal.SIGKILL)
        done = wait_job(c, job["id"], timeout=180)
        assert done["state"] == "failed", done
        assert [f["state"] for f in done["frames"]] == ["succeeded", "failed", "succeeded"]
        assert "killed by SIGKILL" in done["frames"][1]["error"] and "giving up" in done["frames"][1]["error"]
        assert done["error"].startswith("1 of 3 frames failed (6); frame 6: "), done["error"]
        # requeue: only the failed frame runs again
        r = c.post(f"/jobs/{job['id']}/requeue")
        assert r.status_code == 200 and [f["state"] for f in r.json()["frames"]] == ["succeeded", "queued", "succeeded"]
        again = wait_job(c, job["id"], timeout=120)
        assert again["state"] == "succeeded" and [f["attempts"] for f in again["frames"]] == [1, 2, 1], again


def test_a_range_survives_kill9_of_the_server(tmp_path):
    """kill -9 of the server while frame 2 of 3 renders: the workers die with it; the restarted
    server puts frame 2 back in the queue and resumes it from its checkpoint, frame 1 stays
    rendered, and the job ends with every frame."""
    root = make_stage_root(tmp_path / "root")
    os.makedirs(os.path.join(root, "anim"))
    shutil.copy(ANIM, os.path.join(root, "anim", "turntable.usda"))
    slow = {"resolution": [24, 14], "time_budget": 4.0, "seed": 3, "frames": "1-3"}
    s = start_server(tmp_path, root, workers=1, name="first")
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "anim/turntable.usda", "settings": slow}).json()
            ckpt = os.path.join(s.data, "jobs", job["id"], "frames", "0001", "checkpoint.json")
            wait_for(lambda: os.path.exists(ckpt), 120, what="the second frame's first checkpoint")
            first_exr = os.path.join(s.data, "jobs", job["id"], "frames", "0000", "final.exr")
            first_mtime = os.stat(first_exr).st_mtime_ns
            wpid = _worker_pid(s, job["id"])
        s.proc.kill()   # kill -9 the server, not its worker
        s.proc.wait()
        wait_for(lambda: not _alive(wpid), 10, what="the worker to die with its server")
    finally:
        s.stop(signal.SIGKILL)
    s2 = start_server(tmp_path, root, workers=1, data=s.data, name="second")
    try:
        with s2.client() as c:
            done = wait_job(c, job["id"], timeout=180)
            assert done["state"] == "succeeded", done
            assert [f["attempts"] for f in done["frames"]] == [1, 2, 1], done["frames"]
            assert os.stat(first_exr).st_mtime_ns == first_mtime
            assert "frame 2: resuming from checkpoint" in c.get(f"/jobs/{job['id']}/log").text
    finally:
        s2.stop()
