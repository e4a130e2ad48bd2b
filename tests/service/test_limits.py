"""The service's limits, with a real server and real workers: a job over its memory cap fails at
once and is not retried; a FIFO layer is refused by the submission check; a job whose load
blocks in C++ fails at its load timeout; and a job running past --max-time + --max-time-grace
has its worker killed and fails, although the worker still sends heartbeats."""

from __future__ import annotations

import os

import pytest

from .conftest import TINY, make_stage_root, start_server, wait_for, wait_job, write_fifo_clip_stage


def test_a_job_over_the_memory_cap_fails_at_once_without_retries(tmp_path):
    """The server's per-job cap (--max-job-memory) caps a job's film, and a request's own
    settings.max_memory can only lower it: both refusals are permanent (attempts 1 of 3)."""
    root = make_stage_root(tmp_path / "root")
    s = start_server(tmp_path, root, workers=1, extra=["--max-job-memory", "8M"])
    try:
        with s.client() as c:
            big = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": {"resolution": [1024, 1024],
                                                                                 "spp": 1}}).json()
            own = c.post("/jobs", json={"stage": "cornell_box.usda",
                                        "settings": {"resolution": [256, 256], "spp": 1,
                                                     "max_memory": 2**20}}).json()
            fits = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)}).json()
            for job, size in ((big, "8.0 MiB"), (own, "1.0 MiB")):
                done = wait_job(c, job["id"], timeout=120)
                assert done["state"] == "failed" and done["attempts"] == 1, done
                assert done["error"].startswith("resolution: a ") and f"more than --max-memory {size}" in done["error"]
            assert wait_job(c, fits["id"], timeout=120)["state"] == "succeeded"
    finally:
        s.stop()


def test_a_load_stuck_in_cpp_fails_the_job_at_its_load_timeout(tmp_path):
    """A FIFO value clip blocks the worker's own check in C++ (the submission check gave up
    after --asset-check-timeout): at settings.load_timeout the worker fails the job for good
    and exits; the supervisor starts a new worker, which renders the next job."""
    root = make_stage_root(tmp_path / "root")
    write_fifo_clip_stage(os.path.join(root, "shots", "hang.usda"), sublayer="../cornell_box.usda")
    s = start_server(tmp_path, root, workers=1, extra=["--asset-check-timeout", "1"])
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "shots/hang.usda", "settings": {**TINY, "load_timeout": 2}}).json()
            done = wait_job(c, job["id"], timeout=120)
            assert done["state"] == "failed" and done["attempts"] == 1, done
            assert done["error"] == ("shots/hang.usda: checking the stage's files did not finish within 2 s "
                                     "(--load-timeout); a file that never finishes reading (a FIFO, a hung "
                                     "network mount)?"), done["error"]
            after = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)}).json()
            assert wait_job(c, after["id"], timeout=180)["state"] == "succeeded"
    finally:
        s.stop()


def test_max_time_is_enforced_while_the_worker_still_heartbeats(tmp_path):
    """The worker is blocked (a FIFO value clip, under the default 600 s load timeout) but its
    heartbeat thread runs: the supervisor kills it at --max-time + --max-time-grace, fails the
    job, once, saying why, and starts a new worker."""
    root = make_stage_root(tmp_path / "root")
    write_fifo_clip_stage(os.path.join(root, "shots", "hang.usda"), sublayer="../cornell_box.usda")
    s = start_server(tmp_path, root, workers=1, extra=["--asset-check-timeout", "1", "--max-time", "1",
                                                        "--max-time-grace", "3"])
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "shots/hang.usda", "settings": dict(TINY)}).json()
            running = wait_job(c, job["id"], states=("running",), timeout=60)
            assert running["heartbeat_at"] is not None
            done = wait_job(c, job["id"], timeout=60)
            assert done["state"] == "failed" and done["attempts"] == 1, done
            assert "beyond this server's limit of 1 s (--max-time) + 3 s (--max-time-grace): its worker was killed" \
                in done["error"], done["error"]
            # (No render after it here: under --max-time 1 + 3 s of grace, a loaded machine may
            # not load, render and write even a tiny job in time. The load-timeout test renders
            # on the replacement worker.)
            wait_for(lambda: s.worker_pids() and all(job_id is None for _p, job_id in s.worker_pids().values()),
                     60, what="a fresh worker")
    finally:
        s.stop()


def test_a_memory_error_fails_the_job_for_good(tmp_path):
    """A job that runs out of address space in spite of the estimate (here: a worker started by
    hand under a 3 GiB RLIMIT_AS, with a 64 GiB job cap the estimate trusts) fails with
    'out of memory' on its first attempt: a MemoryError is never retried as transient."""
    import resource
    import subprocess
    import sys

    root = make_stage_root(tmp_path / "root")
    s = start_server(tmp_path, root, workers=0, wait_workers=False)
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "cornell_box.usda",
                                        "settings": {"resolution": [8192, 8192], "spp": 1}}).json()

            def address_space():
                resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))

            worker = subprocess.run([sys.executable, "-m", "service.worker", "--data", s.data, "--id", "by-hand",
                                     "--max-jobs", "1", "--no-warmup", "--max-memory", str(64 * 2**30)],
                                    capture_output=True, text=True, timeout=300, preexec_fn=address_space,
                                    stdin=subprocess.DEVNULL, cwd=str(tmp_path))
            assert worker.returncode == 0, worker.stderr[-2000:]
            done = c.get(f"/jobs/{job['id']}").json()
            assert done["state"] == "failed" and done["attempts"] == 1, done
            assert done["error"].startswith("out of memory: ") and "64.0 GiB, --max-job-memory" in done["error"], done
    finally:
        s.stop()



@pytest.mark.parametrize("case", ["sublayer", "texture"])
def test_a_fifo_layer_or_texture_is_refused_by_the_submission_check(tmp_path, case):
    """Failed at once by the server's asset check (no attempt spent), naming layer, prim and field."""
    root = make_stage_root(tmp_path / "root")
    os.mkfifo(os.path.join(root, "textures" if case == "texture" else "shots", "pipe.png" if case == "texture"
                           else "pipe.usda"))
    text = {"sublayer": "#usda 1.0\n(\n    subLayers = [@./pipe.usda@, @../cornell_box.usda@]\n)\n",
            "texture": ('#usda 1.0\n(\n    subLayers = [@../cornell_box.usda@]\n)\n'
                        'def Shader "Tex" {\n    uniform token info:id = "UsdUVTexture"\n'
                        '    asset inputs:file = @../textures/pipe.png@\n}\n')}[case]
    with open(os.path.join(root, "shots", "s.usda"), "w", encoding="utf-8") as fh:
        fh.write(text)
    want = {"sublayer": "shots/s.usda: subLayers: './pipe.usda' is a FIFO, not a regular file",
            "texture": "shots/s.usda: /Tex.inputs:file: '../textures/pipe.png' is a FIFO, not a regular file"}[case]
    s = start_server(tmp_path, root, workers=0, wait_workers=False)
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "shots/s.usda", "settings": dict(TINY)}).json()
            done = wait_job(c, job["id"], timeout=60)
            assert done["state"] == "failed" and done["attempts"] == 0, done
            assert done["error"] == want, done["error"]
    finally:
        s.stop()
