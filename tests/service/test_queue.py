"""The queue a farm wrangler expects, through a real ``illum serve`` on 127.0.0.1: priority
edits that reorder the queue, requeue of failed or canceled jobs (idempotent, safe against the
job's old worker), filters by state and stage, thumbnails, elapsed time, peak memory and
attempts per job, and the render-time and memory histograms of ``/metrics``.

Most tests use a server without workers (nothing renders, so the queue stays as the test left
it); the test process takes the part of a worker through the same job store, as a worker
process would. One tiny render on the shared two-worker server covers what only a real worker
produces (thumbnail, peak memory, elapsed time).
"""

from __future__ import annotations

import json
import os
import threading

import numpy as np
import pytest

from service.store import HISTOGRAMS, JobStore

from .conftest import start_server, wait_for, wait_job
from .test_browser import _enter_token, _only_refusals, browser  # noqa: F401 (browser is a fixture)

TOKEN = "queue-token"


@pytest.fixture(scope="module")
def idle_server(tmp_path_factory, stage_root):
    """A server with a token and no workers: jobs stay queued until the test claims them."""
    s = start_server(tmp_path_factory.mktemp("queue"), stage_root, workers=0, wait_workers=False,
                     env={"ILLUM_TOKEN": TOKEN})
    yield s
    s.stop()


@pytest.fixture
def api(idle_server):
    with idle_server.client(TOKEN) as c:
        yield c


@pytest.fixture
def store(idle_server) -> JobStore:
    return JobStore(os.path.join(idle_server.data, "jobs.db"))


def _submit(c, stage="cornell_box.usda", priority=50, **settings) -> dict:
    r = c.post("/jobs", json={"stage": stage, "settings": {"resolution": [16, 16], "spp": 1, **settings},
                              "priority": priority})
    assert r.status_code == 201, r.text
    return r.json()


def _checked(c, job_id: str) -> dict:
    """The job once the server's asset check has passed it (workers may claim it from then on)."""
    return wait_for(lambda: (lambda j: j if j["asset_check"] == "done" else None)(c.get(f"/jobs/{job_id}").json()),
                    60, what=f"the asset check of {job_id}")


def _as_worker(store: JobStore, worker: str, job_id: str):
    """Claim ``job_id`` as worker ``worker`` (the test's jobs are the only claimable ones)."""
    store.register_worker(worker, os.getpid(), "local")
    order = store.queue_order()
    assert order and order[0] == job_id, (order, job_id)
    job = store.claim(worker)
    assert job.id == job_id
    return job


def test_priority_edit_reorders_the_queue(api, store):
    a, b, c = (_submit(api, priority=p) for p in (40, 40, 60))
    for j in (a, b, c):
        _checked(api, j["id"])
    mine = lambda: [i for i in store.queue_order() if i in (a["id"], b["id"], c["id"])]  # noqa: E731
    assert mine() == [c["id"], a["id"], b["id"]]
    r = api.patch(f"/jobs/{b['id']}", json={"priority": 95})
    assert r.status_code == 200 and r.json()["priority"] == 95
    assert mine() == [b["id"], c["id"], a["id"]]
    assert api.get(f"/jobs/{b['id']}").json()["priority"] == 95
    assert "priority set to 95" in api.get(f"/jobs/{b['id']}/log").text
    # the order workers take them in
    for expected in (b["id"], c["id"], a["id"]):
        job = _as_worker(store, "w-prio", expected)
        assert store.finish(job.id, "w-prio", "succeeded", result={})
    # a finished job takes no priority: requeue is the way back
    r = api.patch(f"/jobs/{a['id']}", json={"priority": 10})
    assert r.status_code == 409 and "already succeeded" in r.json()["message"]
    assert api.get(f"/jobs/{a['id']}").json()["priority"] == 40


@pytest.mark.parametrize("body", [
    {"priority": "50"}, {"priority": 50.0}, {"priority": True}, {"priority": None}, {"priority": -1},
    {"priority": 101}, {"priority": 10 ** 30}, {"priority": [50]}, {}, {"priority": 50, "state": "running"},
    {"priority": 50, "worker": "x"}])
def test_hostile_priority_edits_are_refused(api, store, body):
    job = _submit(api, priority=50)
    before = api.get(f"/jobs/{job['id']}").json()
    r = api.patch(f"/jobs/{job['id']}", json=body)
    assert r.status_code == 422, (body, r.text)
    assert r.json()["message"]
    after = api.get(f"/jobs/{job['id']}").json()
    assert (after["priority"], after["state"]) == (before["priority"], before["state"])
    assert "priority set" not in api.get(f"/jobs/{job['id']}/log").text
    api.post(f"/jobs/{job['id']}/cancel")


def test_requeue_and_edit_refusals(api, idle_server):
    job = _submit(api)
    for bad in ("not json", "[1, 2]", '{"priority": 500}', '{"priority": "high"}', '{"attempts": 0}'):
        r = api.post(f"/jobs/{job['id']}/requeue", content=bad, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, (bad, r.text)
    assert api.post(f"/jobs/{'0' * 16}/requeue").status_code == 404
    assert api.patch(f"/jobs/{'0' * 16}", json={"priority": 5}).status_code == 404
    for bad_id in ("..%2f..%2fjobs.db", "ABCDEF0123456789", "0" * 17, "'%20OR%201=1"):
        assert api.post(f"/jobs/{bad_id}/requeue").status_code in (404, 422)
        assert api.patch(f"/jobs/{bad_id}", json={"priority": 5}).status_code in (404, 422)
    # a queued job is not requeued (nothing to do), and keeps its state
    r = api.post(f"/jobs/{job['id']}/requeue")
    assert r.status_code == 200 and r.json()["state"] == "queued" and r.json()["requeues"] == 0
    # without the token: 401, nothing changes
    with idle_server.client() as anon:
        assert anon.patch(f"/jobs/{job['id']}", json={"priority": 99}).status_code == 401
        assert anon.post(f"/jobs/{job['id']}/requeue").status_code == 401
        assert anon.get(f"/jobs/{job['id']}/thumbnail").status_code == 401
    assert api.get(f"/jobs/{job['id']}").json()["priority"] == 50
    r = api.get(f"/jobs/{job['id']}/thumbnail")
    assert r.status_code == 404 and "no image yet" in r.json()["message"]
    api.post(f"/jobs/{job['id']}/cancel")


def test_requeue_a_failed_job_keeps_its_history(api, store):
    job = _submit(api, priority=30)
    _checked(api, job["id"])
    claimed = _as_worker(store, "w-fail", job["id"])
    assert store.heartbeat(job["id"], "w-fail", peak_memory=123 * 2**20)
    assert store.finish(claimed.id, "w-fail", "failed", error="internal error: disk full (attempt 1 of 3; giving up)")
    failed = api.get(f"/jobs/{job['id']}").json()
    assert failed["state"] == "failed" and failed["elapsed_seconds"] >= 0 and failed["peak_memory"] == 123 * 2**20

    # eight clients press "requeue" at once: one requeue happens, every answer is the queued job
    answers = []
    barrier = threading.Barrier(8)

    def press():
        barrier.wait()
        answers.append(api.post(f"/jobs/{job['id']}/requeue", json={"priority": 70}))

    threads = [threading.Thread(target=press) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [r.status_code for r in answers] == [200] * 8
    assert {r.json()["state"] for r in answers} == {"queued"}
    j = api.get(f"/jobs/{job['id']}").json()
    assert (j["state"], j["attempts"], j["requeues"], j["priority"], j["error"], j["elapsed_seconds"]) == \
        ("queued", 1, 1, 70, None, None)
    assert j["peak_memory"] == 123 * 2**20    # the largest over the job's runs
    log = api.get(f"/jobs/{job['id']}/log").text
    assert log.count("requeued by request") == 1 and "1 attempts so far" in log
    # the new run: attempt 2 in all, the first of its own max_attempts
    _checked(api, job["id"])
    again = _as_worker(store, "w-fail", job["id"])
    assert (again.attempts, again.run_attempt) == (2, 1)
    assert store.finish(again.id, "w-fail", "succeeded", result={"spp": 1}, render_seconds=0.5)
    done = api.get(f"/jobs/{job['id']}").json()
    assert done["state"] == "succeeded" and done["attempts"] == 2 and done["requeues"] == 1
    r = api.post(f"/jobs/{job['id']}/requeue")
    assert r.status_code == 409 and "already succeeded" in r.json()["message"]


def test_requeue_while_the_old_worker_still_holds_the_job(api, store):
    """Cancel a running job and requeue it before its worker noticed: the new run waits until
    the old worker let go, and the old worker can no longer write anything."""
    job = _submit(api)
    _checked(api, job["id"])
    _as_worker(store, "w-old", job["id"])
    assert api.post(f"/jobs/{job['id']}/cancel").json()["state"] == "canceled"
    r = api.post(f"/jobs/{job['id']}/requeue")
    assert r.status_code == 200 and r.json()["state"] == "queued"
    _checked(api, job["id"])
    store.register_worker("w-new", os.getpid(), "local")
    assert job["id"] not in store.queue_order()
    assert store.claim("w-new") is None or pytest.fail("claimed a job its old worker still holds")
    assert not store.heartbeat(job["id"], "w-old")
    assert not store.finish(job["id"], "w-old", "succeeded", result={})   # also releases it
    assert api.get(f"/jobs/{job['id']}").json()["state"] == "queued"
    taken = store.claim("w-new")
    assert taken.id == job["id"] and taken.attempts == 2
    store.finish(taken.id, "w-new", "failed", error="x")


def test_filters_by_state_and_stage(api):
    a = _submit(api, stage="shots/a.usda")
    b = _submit(api, stage="cornell_box.usda")
    api.post(f"/jobs/{b['id']}/cancel")
    ids = lambda r: {j["id"] for j in r.json()["jobs"]}  # noqa: E731
    r = api.get("/jobs", params={"stage": "SHOTS/"})
    assert r.status_code == 200 and a["id"] in ids(r) and b["id"] not in ids(r)
    assert all("shots/" in j["stage"] for j in r.json()["jobs"])
    r = api.get("/jobs", params=[("state", "canceled"), ("stage", "cornell")])
    assert b["id"] in ids(r) and a["id"] not in ids(r)
    assert all(j["state"] == "canceled" and "cornell" in j["stage"] for j in r.json()["jobs"])
    assert r.json()["total"] == len(r.json()["jobs"])
    assert {j["stage"] for j in api.get("/jobs", params={"stage": "_"}).json()["jobs"]} == {"cornell_box.usda"}
    for text in ("%", "' OR 1=1 --", "a.usda'); DROP TABLE jobs; --", "*", "\\", "ショット"):
        r = api.get("/jobs", params={"stage": text})
        assert r.status_code == 200 and r.json()["jobs"] == [], text
    total = api.get("/jobs", params={"limit": 1000}).json()["total"]
    assert api.get("/jobs", params={"stage": "   "}).json()["total"] == total   # blank: no filter
    api.post(f"/jobs/{a['id']}/cancel")


@pytest.mark.parametrize("params", [
    {"state": "deleted"}, {"state": "QUEUED"}, {"state": "queued' OR '1'='1"}, {"state": ""},
    {"stage": "x" * 257}, {"stage": "a\x00b"}, {"stage": "a\x1b[2Jb"}, {"stage": "a\nb"}, {"stage": "\x7f"},
    {"limit": "all"}, {"limit": 0}, {"limit": 10 ** 30}, {"offset": -1}])
def test_hostile_list_queries_get_4xx(api, params):
    r = api.get("/jobs", params=params)
    assert r.status_code == 422, (params, r.status_code, r.text[:200])
    assert r.json()["message"]


def test_metrics_histograms_through_prometheus_client(api, store):
    """The exposition parses with prometheus-client's own parser; finishing a run adds exactly
    one observation to each histogram, in the bucket its value falls in."""
    from prometheus_client.parser import text_string_to_metric_families

    def scrape() -> dict:
        r = api.get("/metrics")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain; version=0.0.4")
        return {f.name: f for f in text_string_to_metric_families(r.text)}

    def buckets(fams, name) -> dict:
        return {float(s.labels["le"]): s.value for s in fams[name].samples
                if s.name == name + "_bucket" and s.labels["kind"] == "render"}

    def total(fams, name) -> float:
        return next(s.value for s in fams[name].samples if s.name == name + "_sum" and s.labels["kind"] == "render")

    before = scrape()
    assert before["illum_job_render_seconds"].type == "histogram"
    assert before["illum_job_peak_memory_bytes"].type == "histogram"
    for name in ("illum_jobs", "illum_jobs_created", "illum_job_attempts", "illum_samples_per_second",
                 "illum_samples_succeeded", "illum_workers", "illum_workers_busy", "illum_http_requests",
                 "illum_uptime_seconds"):
        assert name in before, name
    job = _submit(api)
    _checked(api, job["id"])
    _as_worker(store, "w-metrics", job["id"])
    assert store.heartbeat(job["id"], "w-metrics", peak_memory=300 * 2**20)
    assert store.finish(job["id"], "w-metrics", "succeeded", result={}, render_seconds=7.0, spp_done=1)
    after = scrape()
    for name, value, bucket in (("illum_job_render_seconds", 7.0, 10.0),
                                ("illum_job_peak_memory_bytes", 300 * 2**20, 512 * 2**20)):
        b0, b1 = buckets(before, name), buckets(after, name)
        assert sorted(b1) == sorted((*HISTOGRAMS[name.removeprefix("illum_job_")], float("inf")))
        for le in b1:
            assert b1[le] - b0[le] == (1 if le >= bucket else 0), (name, le)
        assert total(after, name) - total(before, name) == pytest.approx(value, rel=1e-12)


# ------------------------------------------------------------------ a real worker
def test_a_rendered_job_has_thumbnail_memory_and_elapsed(server, client, tmp_path):
    from renderer.film import read_exr
    from renderer.output import display_encode
    from service.worker import thumbnail

    job = client.post("/jobs", json={"stage": "shots/a.usda", "settings": {"resolution": [96, 48], "spp": 2}}).json()
    done = wait_job(client, job["id"], timeout=240)
    assert done["state"] == "succeeded", done
    assert done["attempts"] == 1 and done["requeues"] == 0
    assert done["elapsed_seconds"] >= done["render_seconds"] > 0
    # the worker's RSS: the imported renderer alone is ~190 MB; the job cap bounds it
    assert 50 * 2**20 < done["peak_memory"] < 64 * 2**30
    assert done["links"]["thumbnail"] == f"/jobs/{job['id']}/thumbnail"
    r = client.get(done["links"]["thumbnail"])
    assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content[:4] == b"\x89PNG"
    (tmp_path / "thumb.png").write_bytes(r.content)
    (tmp_path / "final.exr").write_bytes(client.get(f"/jobs/{job['id']}/image", params={"format": "exr"}).content)
    import OpenImageIO as oiio

    thumb = oiio.ImageBuf(str(tmp_path / "thumb.png"))
    spec = thumb.spec()
    assert (spec.width, spec.height, spec.format) == (64, 32, oiio.UINT8)
    got = thumb.get_pixels(oiio.UINT8)[:, :, :3].astype(np.int32)
    final, _ = read_exr(str(tmp_path / "final.exr"))
    expected = np.round(np.clip(display_encode(thumbnail(final[:, :, :3])), 0, 1) * 255).astype(np.int32)
    assert np.array_equal(got, expected)         # box filter in linear light, then sRGB: as computed here
    assert got.max() > 0


def test_thumbnail_is_a_box_filter():
    from service.worker import thumbnail

    rng = np.random.default_rng(7)
    img = rng.random((30, 20, 3)).astype(np.float32)
    small = thumbnail(img, size=10)
    assert small.shape == (10, 7, 3)                       # 30x20 -> longer side 10, aspect kept
    rows = (np.arange(10) * 30) // 10
    cols = (np.arange(7) * 20) // 7
    for i in range(10):
        for k in range(7):
            r1 = rows[i + 1] if i + 1 < 10 else 30
            c1 = cols[k + 1] if k + 1 < 7 else 20
            np.testing.assert_allclose(small[i, k], img[rows[i]:r1, cols[k]:c1].mean(axis=(0, 1)), rtol=1e-6)
    # equal blocks: every input pixel counted once, so the mean is kept
    assert thumbnail(img[:20, :20], size=10).mean() == pytest.approx(img[:20, :20].mean(), rel=1e-6)
    assert small.dtype == np.float32
    np.testing.assert_array_equal(thumbnail(img, size=64), img)                  # never enlarged


# ------------------------------------------------------------------ the page, in headless Chromium
def _row(job_id: str, what: str) -> str:
    """JS: a property of the job's row in the table (null while the row is absent)."""
    return f"(() => {{ const tr = document.querySelector('#jobs-body tr[data-id=\"{job_id}\"]'); return tr ? {what} : null; }})()"


def _click(b, element_id: str) -> None:
    b.eval(f"document.getElementById('{element_id}').click(), true")


def test_page_queue_controls(idle_server, api, store, browser):
    """Priority edit, requeue, filters and delete with its confirmation, from the page."""
    b = browser
    b.goto(idle_server.url + "/")
    _enter_token(b, TOKEN)
    b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
    shot = _submit(api, stage="shots/a.usda", priority=40)
    box = _submit(api, stage="cornell_box.usda", priority=40)
    broken = _submit(api, stage="cornell_box.usda", priority=20)
    for j in (shot, box, broken):
        _checked(api, j["id"])
    order = [i for i in store.queue_order() if i in (shot["id"], box["id"], broken["id"])]
    assert order == [shot["id"], box["id"], broken["id"]]
    api.patch(f"/jobs/{broken['id']}", json={"priority": 100})   # next in line, then it fails
    _as_worker(store, "w-page", broken["id"])
    store.finish(broken["id"], "w-page", "failed", error="internal error: disk full")

    # priority: the selected queued job takes a new one; the queue order follows
    b.wait(_row(box["id"], "tr.querySelector('td.priority').textContent === '40'"), what="the job rows")
    b.eval(_row(box["id"], "(tr.click(), true)"))
    b.wait("!document.getElementById('priority-btn').disabled", what="the priority control")
    b.eval("document.getElementById('sel-priority').value = '150', true")
    _click(b, "priority-btn")
    b.wait("document.getElementById('message').textContent.includes('0 to 100')", what="the range message")
    assert api.get(f"/jobs/{box['id']}").json()["priority"] == 40
    b.eval("document.getElementById('sel-priority').value = '90', true")
    _click(b, "priority-btn")
    b.wait(_row(box["id"], "tr.querySelector('td.priority').textContent === '90'"), what="the new priority")
    assert api.get(f"/jobs/{box['id']}").json()["priority"] == 90
    order = [i for i in store.queue_order() if i in (shot["id"], box["id"])]
    assert order == [box["id"], shot["id"]]

    # requeue: only failed and canceled jobs; the row shows the new run and its history
    assert b.eval("document.getElementById('requeue-btn').disabled")
    b.eval(_row(broken["id"], "(tr.click(), true)"))
    b.wait("!document.getElementById('requeue-btn').disabled", what="the requeue button")
    assert b.eval("document.getElementById('priority-btn').disabled")
    _click(b, "requeue-btn")
    b.wait(_row(broken["id"], "tr.dataset.state === 'queued'"), what="the requeued row")
    assert b.wait(_row(broken["id"], "tr.querySelector('td.attempts').textContent")) == "1 (requeued 1×)"
    j = api.get(f"/jobs/{broken['id']}").json()
    assert (j["state"], j["requeues"], j["attempts"], j["error"]) == ("queued", 1, 1, None)

    # filters: by state, by stage text; the rows follow without a reload
    b.eval("(() => { const s = document.getElementById('filter-state'); s.value = 'queued';"
           " s.dispatchEvent(new Event('change')); return true; })()")
    b.wait("[...document.querySelectorAll('#jobs-body tr')].every(tr => tr.dataset.state === 'queued')"
           " && document.querySelectorAll('#jobs-body tr').length >= 3", what="only queued rows")
    b.eval("(() => { const s = document.getElementById('filter-stage'); s.value = 'SHOTS/';"
           " s.dispatchEvent(new Event('input')); return true; })()")
    b.wait(f"(() => {{ const rows = [...document.querySelectorAll('#jobs-body tr')];"
           f" return rows.length > 0 && rows.every(tr => tr.querySelector('td.stage').textContent.startsWith('shots/'))"
           f" && rows.some(tr => tr.dataset.id === '{shot['id']}'); }})()", what="only shots/ rows")
    b.eval("(() => { const s = document.getElementById('filter-stage'); s.value = \"' OR 1=1 --\";"
           " s.dispatchEvent(new Event('input')); return true; })()")
    b.wait("document.querySelectorAll('#jobs-body tr').length === 0 && "
           "document.getElementById('jobs-empty').textContent === 'No job matches the filters.'", what="no rows")
    b.eval("(() => { for (const [id, ev] of [['filter-state', 'change'], ['filter-stage', 'input']]) {"
           " const s = document.getElementById(id); s.value = ''; s.dispatchEvent(new Event(ev)); } return true; })()")
    b.wait(_row(box["id"], "true"), what="all rows again")

    # delete: asks first; "Keep" keeps the job, "Delete" removes it
    b.eval(_row(box["id"], "(tr.click(), true)"))
    b.wait("!document.getElementById('delete-btn').disabled", what="the delete button")
    _click(b, "delete-btn")
    assert b.wait("document.getElementById('delete-dialog').open && "
                  "document.getElementById('delete-what').textContent").startswith(box["id"])
    _click(b, "delete-keep")
    b.wait("!document.getElementById('delete-dialog').open", what="the dialog to close")
    assert api.get(f"/jobs/{box['id']}").status_code == 200
    _click(b, "delete-btn")
    b.wait("document.getElementById('delete-dialog').open", what="the dialog")
    _click(b, "delete-confirm")
    b.wait(f"document.getElementById('message').textContent === 'Deleted job {box['id']}'", what="the deletion")
    b.wait(_row(box["id"], "false") + " === null", what="the row to go")
    assert api.get(f"/jobs/{box['id']}").status_code == 404
    assert b.eval("document.getElementById('sel-id').textContent") == ""
    assert _only_refusals(b) == []   # the 401s before the token was entered, nothing else
    for j in (shot, broken):
        api.post(f"/jobs/{j['id']}/cancel")


def test_page_rows_show_thumbnail_elapsed_memory(server, client, browser):
    """A rendered job's row shows its thumbnail (fetched as a blob), elapsed time, peak memory
    and attempts."""
    job = client.post("/jobs", json={"stage": "shots/a.usda", "settings": {"resolution": [24, 12], "spp": 2}}).json()
    done = wait_job(client, job["id"], timeout=240)
    assert done["state"] == "succeeded", done
    b = browser
    b.goto(server.url + "/")
    size = b.wait(_row(job["id"], "(() => { const img = tr.querySelector('td.thumb img');"
                               " return img && !img.hidden && img.complete && img.naturalWidth"
                               " ? [img.naturalWidth, img.naturalHeight, img.src.slice(0, 5)] : null; })()"),
                  what="the row's thumbnail")
    assert size == [24, 12, "blob:"]
    cells = b.eval(_row(job["id"], "[...tr.querySelectorAll('td')].map(td => td.textContent)"))
    elapsed = b.eval(_row(job["id"], "tr.querySelector('td.elapsed').textContent"))
    memory = b.eval(_row(job["id"], "tr.querySelector('td.memory').textContent"))
    parts = elapsed.split()
    if len(parts) == 2:                                    # "12.3 s"
        assert parts[1] == "s" and abs(float(parts[0]) - done["elapsed_seconds"]) <= 0.05 + 1e-9, cells
    else:                                                  # "1 min 05 s" (a loaded machine)
        assert parts[1::2] == ["min", "s"], cells
        assert int(parts[0]) * 60 + int(parts[2]) == int(done["elapsed_seconds"]), cells
    value, unit = memory.split()
    scale = {"MiB": 2**20, "GiB": 2**30}[unit]
    assert abs(float(value) - done["peak_memory"] / scale) <= (0.05 if "." in value else 0.5) + 1e-9, cells
    assert b.eval(_row(job["id"], "tr.querySelector('td.attempts').textContent")) == f"1/{done['max_attempts']}"
    assert b.js_errors() == []


def test_cli_priority_requeue_and_search(idle_server, api, capsys, monkeypatch):
    """``illum jobs ID --priority P``, ``--requeue`` and ``illum jobs --stage TEXT``."""
    from renderer.cli import main

    monkeypatch.setenv("ILLUM_TOKEN", TOKEN)

    def illum(*args):
        capsys.readouterr()
        code = main(["jobs", "--server", idle_server.url, *args])
        return code, *capsys.readouterr()

    job = _submit(api, stage="shots/a.usda", priority=10)
    code, out, _ = illum(job["id"], "--priority", "77")
    assert code == 0 and json.loads(out)["priority"] == 77
    code, out, err = illum(job["id"], "--priority", "777")
    assert code == 2 and "priority" in err and api.get(f"/jobs/{job['id']}").json()["priority"] == 77
    api.post(f"/jobs/{job['id']}/cancel")
    code, out, _ = illum(job["id"], "--requeue", "--priority", "60")
    j = json.loads(out)
    assert code == 0 and (j["state"], j["priority"], j["requeues"]) == ("queued", 60, 1)
    code, out, _ = illum("--stage", "shots/", "--state", "queued", "--limit", "1000")
    lines = out.splitlines()
    assert code == 0 and lines[0].split()[:9] == ["ID", "STATE", "PROGRESS", "SPP", "PRIO", "TRIES", "ELAPSED",
                                                 "PEAK", "MEM"]
    row = next(r for r in lines[1:] if r.startswith(job["id"]))
    assert "0/3 +1rq" in row and "shots/a.usda" in row
    assert all("shots/" in r and " queued " in r for r in lines[1:])
    code, _, err = illum("--requeue")
    assert code == 2 and "need a job id" in err
    api.post(f"/jobs/{job['id']}/cancel")
