"""Scale-out over Ray: blocks of passes on resident actors, merged with Film.merge; lost actors'
blocks re-run; checkpoint state resumes only the missing blocks; the server's ray backend."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from .conftest import STAGES, make_stage_root, read_exr_bytes, start_server, wait_for, wait_job

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'illum[ray]')")

# One test process runs every test of the module (make test's --dist loadgroup): a second local
# cluster started beside this one by the other process competes for the same two CPUs.
pytestmark = pytest.mark.xdist_group("ray")

CORNELL = os.path.join(STAGES, "cornell_box.usda")


@pytest.fixture(scope="module")
def cluster():
    """A local two-CPU Ray cluster for the module; yields its address."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, namespace="illum-tests")
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def pool(cluster):
    """Two resident actors shared by the module's tests (their scenes stay loaded)."""
    from service.ray_backend import RayPool

    p = RayPool(actors=2)
    yield p
    p.close()


def _opts(**kw):
    from renderer.render import RenderOptions

    return RenderOptions(**{"resolution": (16, 16), "spp": 8, **kw})


def test_blocks_merge_to_the_requested_samples(pool):
    from renderer.render import render

    snaps = []
    r = pool.render(CORNELL, _opts(spp=12), snapshot=lambda f, d, s: snaps.append((d, s)), block_spp=2)
    assert r.stats["spp"] == 12 and np.all(r.film.count == 12)
    assert r.stats["ray"]["blocks_run"] == 6 and r.stats["ray"]["actors"] == 2
    assert [d for d, _ in snaps] == [2, 4, 6, 8, 10, 12]  # progressive: one merge per block
    assert snaps[-1][1]["blocks_done"] == [0, 1, 2, 3, 4, 5]
    # the merged film estimates the same image as a local render (different seeds, same mean)
    local = render(CORNELL, _opts(spp=12))
    a, b = r.film.image().mean(), local.film.image().mean()
    assert abs(a - b) < 0.1 * b, (a, b)
    assert not np.array_equal(r.film.sum, local.film.sum)  # the blocks used their own seeds
    assert r.metadata["illum:spp"] == 12


def test_lost_actor_blocks_are_rerun(pool):
    logs: list[str] = []
    killed = threading.Event()

    def snapshot(film, done, state):
        if not killed.is_set():
            killed.set()
            ray.kill(pool.actors[0])  # a node or actor lost mid-job

    r = pool.render(CORNELL, _opts(spp=16), snapshot=snapshot, log=logs.append, block_spp=1)
    assert killed.is_set()
    assert r.stats["spp"] == 16 and np.all(r.film.count == 16)
    assert any("re-running block" in line for line in logs), logs
    assert pool.lost_actors >= 1
    # the replacement actor is usable for the next job
    assert pool.render(CORNELL, _opts(spp=4), block_spp=1).stats["spp"] == 4


def test_resume_runs_only_missing_blocks(pool):
    state = {}
    stop = threading.Event()

    def snapshot(film, done, st):
        state.update(st, film=film)
        if len(st["blocks_done"]) >= 3:
            stop.set()

    first = pool.render(CORNELL, _opts(spp=10), snapshot=snapshot, cancel=stop.is_set, block_spp=1)
    done_before = int(first.film.count.max())
    assert 3 <= done_before < 10
    film = state.pop("film")
    resumed = pool.render(CORNELL, _opts(spp=10), resume=film, resume_state=state, block_spp=1)
    assert resumed.stats["spp"] == 10 and np.all(resumed.film.count == 10)
    assert resumed.stats["ray"]["blocks_run"] == 10 - done_before


def test_render_errors_surface_as_illum_errors(pool, tmp_path):
    from renderer.errors import IllumError

    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n(((\n")
    with pytest.raises(IllumError, match="cannot open stage"):
        pool.render(str(bad), _opts(spp=2))


def test_server_ray_backend_end_to_end(tmp_path, cluster, pool):
    """``illum serve --backend ray --ray-address ADDR``: the worker joins an existing cluster (as
    on a farm), the job's passes run on two actors there, and the result is a normal job with a
    normal EXR."""
    pool.close()  # this test runs last: give the cluster's two CPUs to the server's actors
    root = make_stage_root(tmp_path / "root")
    s = start_server(tmp_path, root, workers=1,
                     extra=["--backend", "ray", "--ray-address", cluster, "--ray-actors", "2"])
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "cornell_box.usda",
                                        "settings": {"resolution": [16, 16], "spp": 8}}).json()
            done = wait_job(c, job["id"], timeout=120)
            assert done["state"] == "succeeded", (done, c.get(f"/jobs/{job['id']}/log").text)
            assert done["spp_done"] == 8
            img, attrs = read_exr_bytes(c.get(f"/jobs/{job['id']}/image", params={"format": "exr"}).content,
                                        tmp_path)
            assert img.shape == (16, 16, 3) and attrs["illum:rayActors"] == 2 and attrs["illum:spp"] == 8
            stats = c.get(f"/jobs/{job['id']}/stats").json()
            assert stats["ray"]["actors"] == 2 and stats["ray"]["blocks_run"] >= 2

            # a frame range: each frame's passes go to the actors, each frame is its own task
            rng = c.post("/jobs", json={"stage": "cornell_box.usda",
                                        "settings": {"resolution": [16, 16], "spp": 4, "frames": "1-2"}}).json()
            done = wait_job(c, rng["id"], timeout=120)
            assert done["state"] == "succeeded", (done, c.get(f"/jobs/{rng['id']}/log").text)
            assert [(f["state"], f["spp_done"]) for f in done["frames"]] == [("succeeded", 4)] * 2
            img, attrs = read_exr_bytes(c.get(done["frames"][1]["links"]["image_exr"]).content, tmp_path, "f2.exr")
            assert attrs["illum:frame"] == 2.0 and attrs["illum:rayActors"] == 2 and img.shape == (16, 16, 3)

            # cancel reaches the actors too: the driver lets go of the job within 2 s
            long = c.post("/jobs", json={"stage": "cornell_box.usda",
                                         "settings": {"resolution": [16, 16], "spp": 60000, "time_budget": 60}}).json()
            wait_for(lambda: c.get(f"/jobs/{long['id']}").json()["spp_done"] >= 2, 60, what="blocks to merge")
            t0 = time.monotonic()
            assert c.post(f"/jobs/{long['id']}/cancel").json()["state"] == "canceled"
            wait_for(lambda: all(w["job"] != long["id"] for w in c.get("/health").json()["workers"]["registered"]),
                     5, what="the driver to drop the job")
            assert time.monotonic() - t0 < 2.0
    finally:
        s.stop()


def test_ray_processes_die_with_the_server(tmp_path):
    """Without --ray-address the worker starts its own local Ray and renders a job on it; kill -9
    of the server then takes every process it started with it: the worker, the local Ray
    cluster the worker started (GCS, raylet, their agents such as DashboardAgent and
    RuntimeEnvAgent) and the actors. Listed from /proc before the kill, checked after."""
    from .test_faults import _descendant_cmdlines, _zombie

    root = make_stage_root(tmp_path / "root")
    s = start_server(tmp_path, root, workers=1, extra=["--backend", "ray", "--ray-actors", "2"])
    try:
        with s.client() as c:
            job = c.post("/jobs", json={"stage": "cornell_box.usda",
                                        "settings": {"resolution": [16, 16], "spp": 4}}).json()
            done = wait_job(c, job["id"], timeout=180)
            assert done["state"] == "succeeded", (done, c.get(f"/jobs/{job['id']}/log").text)
        started = _descendant_cmdlines(s.proc.pid)
        assert any("raylet" in cmd for cmd in started.values()), started
    finally:
        s.stop(signal.SIGKILL)

    def survivors():
        return {p: cmd[:120] for p, cmd in started.items() if os.path.exists(f"/proc/{p}") and not _zombie(p)}

    deadline = time.monotonic() + 30
    while survivors() and time.monotonic() < deadline:
        time.sleep(0.2)
    left = survivors()
    for p in left:  # leave no orphans behind for the rest of the suite
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    assert not left, left
