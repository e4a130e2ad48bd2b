"""Fault tolerance with real processes: kill -9 a worker mid-job, kill -9 the server, stop it
gracefully, and cancel a render whose single pass outlasts the cancel deadline."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from .conftest import (TINY, make_stage_root, read_exr_bytes, start_server, wait_for, wait_job,
                       write_fifo_clip_stage)

# Short passes, enough of them to last seconds with checkpoints in between (100 passes took only
# ~1.5 s once the renderer got faster, leaving ~0.1 s to catch a checkpoint before the end).
# A job of several seconds with many passes (checkpoints in between): the Cornell box takes the
# compiled fast path, ~0.25-0.6 M samples/s per worker here, so 48 x 48 x 2000 spp is ~8-18 s.
SLOW_TINY = {"resolution": [48, 48], "spp": 2000}


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"  # a zombie is dead
    except FileNotFoundError:
        return False


def _checkpoint_spp(server, job_id: str) -> int:
    try:
        with open(os.path.join(server.data, "jobs", job_id, "checkpoint.json")) as fh:
            return int(json.load(fh)["spp"])
    except (FileNotFoundError, ValueError, KeyError):
        return 0


def _worker_of(server, job_id: str):
    for wid, (pid, job) in server.worker_pids().items():
        if job == job_id:
            return wid, pid
    return None


@pytest.fixture(scope="module")
def one_worker(tmp_path_factory):
    from .conftest import make_stage_root

    tmp = tmp_path_factory.mktemp("faults")
    s = start_server(tmp, make_stage_root(tmp / "root"), workers=1)
    yield s
    s.stop()


def test_worker_kill9_resumes_from_checkpoint(one_worker, tmp_path):
    s = one_worker
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": SLOW_TINY}).json()
        wait_for(lambda: _checkpoint_spp(s, job["id"]) >= 10, 60, what="a checkpoint")
        wid, pid = wait_for(lambda: _worker_of(s, job["id"]), 10, what="the worker")
        os.kill(pid, signal.SIGKILL)
        wait_for(lambda: not _alive(pid), 10, what="the worker to die")
        ckpt = _checkpoint_spp(s, job["id"])
        done = wait_job(c, job["id"], timeout=90)
        assert done["state"] == "succeeded", done
        assert done["attempts"] == 2 and done["spp_done"] == SLOW_TINY["spp"] and done["worker"] != wid
        log = c.get(f"/jobs/{job['id']}/log").text
        assert "attempt 2 of 3" in log
        resumed = int(log.split("resuming from checkpoint: ")[1].split(" spp")[0])
        assert resumed >= ckpt >= 10  # the second attempt continued, it did not start over
        assert done["result"]["resumed_from_spp"] == resumed
        img, attrs = read_exr_bytes(c.get(f"/jobs/{job['id']}/image", params={"format": "exr"}).content, tmp_path)
        assert attrs["illum:spp"] == SLOW_TINY["spp"] and img.shape == (48, 48, 3) and img.mean() > 0.01
        assert "killed by SIGKILL" in s.log() or True  # the server logs at warning level
        assert not os.path.exists(os.path.join(s.data, "jobs", job["id"], "checkpoint.npz"))


def test_attempts_exhausted_fails_with_the_reason(one_worker):
    s = one_worker
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": SLOW_TINY, "max_attempts": 1}).json()
        wait_for(lambda: c.get(f"/jobs/{job['id']}").json()["spp_done"] >= 2, 60, what="the render to start")
        _, pid = wait_for(lambda: _worker_of(s, job["id"]), 10, what="the worker")
        os.kill(pid, signal.SIGKILL)
        done = wait_job(c, job["id"], timeout=30)
        assert done["state"] == "failed"
        assert "killed by SIGKILL" in done["error"] and "attempt 1 of 1" in done["error"], done["error"]
        # the pool is back to full strength
        wait_for(lambda: c.get("/health").json()["workers"]["alive"] == 1, 20, what="a replacement worker")


def _cancel_and_requeue_mid_render(s, c, job_id: str) -> int:
    """Cancel the running job once it has a checkpoint and requeue it at once, before its worker
    can have noticed: returns the checkpoint's spp at the cancel."""
    wait_for(lambda: _checkpoint_spp(s, job_id) >= 10, 60, what="a checkpoint")
    assert c.post(f"/jobs/{job_id}/cancel").json()["state"] == "canceled"
    ckpt = _checkpoint_spp(s, job_id)
    r = c.post(f"/jobs/{job_id}/requeue")
    assert r.status_code == 200 and r.json()["state"] == "queued" and r.json()["requeues"] == 1
    return ckpt


def _check_resumed(c, job: dict, tmp_path, *, attempts: int, resumes: int) -> str:
    spp = job["settings"]["spp"]
    done = wait_job(c, job["id"], timeout=240)
    assert done["state"] == "succeeded", done
    assert (done["attempts"], done["requeues"], done["spp_done"]) == (attempts, 1, spp)
    log = c.get(f"/jobs/{job['id']}/log").text
    assert log.count("requeued by request") == 1 and log.count("resuming from checkpoint") == resumes, log
    img, attrs = read_exr_bytes(c.get(f"/jobs/{job['id']}/image", params={"format": "exr"}).content, tmp_path)
    assert attrs["illum:spp"] == spp and img.shape == (48, 48, 3) and img.mean() > 0.01
    return log


def test_requeue_a_canceled_render_resumes_it(one_worker, tmp_path):
    """Cancel a rendering job and requeue it before its worker let go: the worker stops, and the
    new run (attempt 1 of its own 3, attempt 2 in all) resumes from the checkpoint."""
    s = one_worker
    with s.client() as c:
        # long enough to cancel after a checkpoint (~2.5 s on an idle machine), short to finish
        job = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": {"resolution": [48, 48], "spp": 600}}).json()
        ckpt = _cancel_and_requeue_mid_render(s, c, job["id"])
        log = _check_resumed(c, job, tmp_path, attempts=2, resumes=1)
        assert "attempt 1 of 3 (attempt 2 in all; 1 requeue)" in log
        resumed = int(log.split("resuming from checkpoint: ")[1].split(" spp")[0])
        assert resumed >= ckpt >= 10
        assert c.get(f"/jobs/{job['id']}").json()["result"]["resumed_from_spp"] == resumed


@pytest.mark.slow
def test_requeued_render_survives_kill9(one_worker, tmp_path):
    """The requeued run's worker is killed with SIGKILL: the reaper hands the job to the
    replacement worker, which resumes it again; nothing is lost and the store stays sound."""
    from service.store import JobStore

    s = one_worker
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": SLOW_TINY}).json()
        ckpt = _cancel_and_requeue_mid_render(s, c, job["id"])
        wait_for(lambda: c.get(f"/jobs/{job['id']}").json()["attempts"] == 2 and _checkpoint_spp(s, job["id"]) > ckpt,
                 90, what="the new run's first checkpoint")
        _, pid = wait_for(lambda: _worker_of(s, job["id"]), 10, what="the worker")
        os.kill(pid, signal.SIGKILL)
        log = _check_resumed(c, job, tmp_path, attempts=3, resumes=2)
        assert "attempt 2 of 3 (attempt 3 in all; 1 requeue)" in log
    assert JobStore(os.path.join(s.data, "jobs.db")).integrity() == "ok"


def test_cancel_beats_a_long_pass(one_worker):
    """One pass at 2048x2048 takes far longer than the cancel deadline (4 M samples at well under
    a million per second): the supervisor kills the busy worker so the cancel still takes effect
    within 2 s, and starts a replacement."""
    s = one_worker
    with s.client() as c:
        job = c.post("/jobs", json={"stage": "cornell_box.usda",
                                    "settings": {"resolution": [2048, 2048], "spp": 50}}).json()
        wait_for(lambda: "rendering (scene ready" in c.get(f"/jobs/{job['id']}/log").text, 60,
                 what="the first pass to start")
        _, pid = wait_for(lambda: _worker_of(s, job["id"]), 10, what="the worker")
        time.sleep(0.3)
        assert c.get(f"/jobs/{job['id']}").json()["spp_done"] == 0
        t0 = time.monotonic()
        assert c.post(f"/jobs/{job['id']}/cancel").json()["state"] == "canceled"
        wait_for(lambda: not _alive(pid), 5, interval=0.02, what="the busy worker to be stopped")
        assert time.monotonic() - t0 < 2.0
        assert c.get(f"/jobs/{job['id']}").json()["state"] == "canceled"
        assert "after the cancel (a long pass): killed" in c.get(f"/jobs/{job['id']}/log").text
        wait_for(lambda: c.get("/health").json()["workers"]["alive"] == 1, 20, what="a replacement worker")


def test_server_restarts_lose_no_job(tmp_path):
    """SIGTERM: the running job checkpoints and is requeued without spending an attempt.
    kill -9: workers die with the server; after a restart queued jobs stay queued and the running
    one resumes from its checkpoint."""
    from .conftest import make_stage_root

    root = make_stage_root(tmp_path / "root")
    budget = {"resolution": [16, 16], "spp": 60000, "time_budget": 12}  # 12 s of rendering, all attempts
    s = start_server(tmp_path, root, workers=1, name="first")
    try:
        with s.client() as c:
            a = c.post("/jobs", json={"stage": "cornell_box.usda", "settings": budget, "priority": 90}).json()
            wait_for(lambda: _checkpoint_spp(s, a["id"]) >= 3, 60, what="a checkpoint")
            # Queued behind the running job (submitted together, b's asset check could finish
            # first); a restarted server resumes a check the shutdown interrupted.
            b = c.post("/jobs", json={"stage": "shots/a.usda", "settings": {"resolution": [16, 16], "spp": 3},
                                      "priority": 10}).json()
        # uvicorn shuts down gracefully, then re-raises the signal so the exit status shows it
        assert s.stop(signal.SIGTERM) in (0, -signal.SIGTERM)
    finally:
        s.stop(signal.SIGKILL)
    from service.store import JobStore

    store = JobStore(os.path.join(s.data, "jobs.db"))
    ja, jb = store.get(a["id"]), store.get(b["id"])
    assert (ja.state, ja.attempts) == ("queued", 0), ja.row  # requeued, attempt refunded
    assert jb.state == "queued"
    graceful_spp = _checkpoint_spp(s, a["id"])
    assert graceful_spp >= 3

    s2 = start_server(tmp_path, root, workers=1, data=s.data, name="second")
    try:
        with s2.client() as c:
            wait_for(lambda: _checkpoint_spp(s2, a["id"]) >= graceful_spp + 3, 60, what="progress after restart")
            _, wpid = wait_for(lambda: _worker_of(s2, a["id"]), 10, what="the worker")
        s2.proc.kill()  # kill -9 the server, not its workers
        s2.proc.wait()
        wait_for(lambda: not _alive(wpid), 10, what="the worker to die with its server")
    finally:
        s2.stop(signal.SIGKILL)
    ja = store.get(a["id"])
    assert ja.state == "running" and store.get(b["id"]).state == "queued"  # as the crash left them
    crash_spp = _checkpoint_spp(s2, a["id"])
    assert crash_spp > graceful_spp

    s3 = start_server(tmp_path, root, workers=1, data=s.data, name="third")
    try:
        with s3.client() as c:
            da = wait_job(c, a["id"], timeout=90)
            db = wait_job(c, b["id"], timeout=60)
            assert da["state"] == "succeeded" and db["state"] == "succeeded"
            assert da["attempts"] == 2  # the graceful stop was refunded, the crash counted
            assert da["spp_done"] > crash_spp
            # the budget spans attempts: only the time since the last checkpoint was lost
            assert 11.0 <= da["result"]["render_seconds"] <= 13.5, da["result"]
            log = c.get(f"/jobs/{a['id']}/log").text
            assert f"resuming from checkpoint: {graceful_spp} spp" in log
            assert f"resuming from checkpoint: {crash_spp} spp" in log
            assert c.get("/jobs").json()["total"] == 2
    finally:
        s3.stop()
    assert store.integrity() == "ok"


def _descendant_cmdlines(pid: int) -> dict:
    """{pid: cmdline} of every live process whose parent chain reaches ``pid`` (from /proc)."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", encoding="utf-8", errors="replace") as fh:
                    stat = fh.read()
                ppid = int(stat.rsplit(")", 1)[1].split()[1])
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    parents[int(entry)] = (ppid, fh.read().replace(b"\0", b" ").decode(errors="replace"))
            except (OSError, ValueError, IndexError):
                continue
    out, frontier = {}, {pid}
    while frontier:
        kids = {p for p, (pp, _) in parents.items() if pp in frontier and p not in out}
        out.update({p: parents[p][1] for p in kids})
        frontier = kids
    return out


def test_a_hanging_asset_check_dies_with_the_server(tmp_path):
    """A stage whose value-clip layer is a FIFO makes the checking child block in open() (FIFO
    sublayers and references are refused before anything opens them; clip layers are opened
    while composing); kill -9 of the server must take that child with it (no orphan waits out
    its timeout). Meanwhile the request that queued the job has long been answered, with the
    check pending."""
    root = make_stage_root(tmp_path / "root")
    write_fifo_clip_stage(os.path.join(root, "shots", "hang.usda"), sublayer="../cornell_box.usda")
    s = start_server(tmp_path, root, workers=0, wait_workers=False, extra=["--asset-check-timeout", "600"])
    try:
        with s.client() as c:
            r = c.post("/jobs", json={"stage": "shots/hang.usda", "settings": dict(TINY)})
            assert r.status_code == 201 and r.json()["asset_check"] == "pending"
            child = wait_for(lambda: [p for p, cmd in _descendant_cmdlines(s.proc.pid).items()
                                      if "service.assets" in cmd and "hang.usda" in cmd], 30,
                             what="the checking child")
            assert c.get("/health").status_code == 200  # the API answers while the check hangs
            assert c.get(f"/jobs/{r.json()['id']}").json()["asset_check"] == "pending"
    finally:
        s.stop(signal.SIGKILL)

    def gone():
        return all(not os.path.exists(f"/proc/{p}") or _zombie(p) for p in child)

    wait_for(gone, 10, what=f"the checking child {child} to die with the server")


def _zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", encoding="utf-8") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True
