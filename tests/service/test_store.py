"""The SQLite job store: atomic claims, priority order, heartbeats, reaper, idempotency."""

from __future__ import annotations

import threading
import time

import pytest

from service.store import HISTOGRAMS, SCHEMA_VERSION, IdempotencyConflict, JobStore


def _new(store: JobStore, priority: int = 50, key: str | None = None, h: str = "h", max_attempts: int = 3):
    job, created = store.create(kind="render", stage="/x/a.usda", stage_name="a.usda", settings={"spp": 4},
                                priority=priority, max_attempts=max_attempts, idempotency_key=key, request_hash=h)
    return job, created


@pytest.fixture
def store(tmp_path) -> JobStore:
    return JobStore(str(tmp_path / "jobs.db"))


def test_wal_mode_and_schema(store):
    with store.connect() as db:
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store.integrity() == "ok"


def test_claim_order_is_priority_then_fifo(store):
    low, _ = _new(store, 10)
    first, _ = _new(store, 90)
    second, _ = _new(store, 90)
    store.register_worker("w", 1, "local")
    order = [store.claim("w").id for _ in range(3)]
    assert order == [first.id, second.id, low.id]
    assert store.claim("w") is None


def test_concurrent_claims_never_share_a_job(store):
    ids = {_new(store)[0].id for _ in range(60)}
    got: list[str] = []
    lock = threading.Lock()

    def worker(n):
        store.register_worker(f"w{n}", n, "local")
        while True:
            job = store.claim(f"w{n}")
            if job is None:
                return
            with lock:
                got.append(job.id)

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(got) == sorted(ids)  # every job exactly once


def test_heartbeat_stops_after_cancel_and_guards_writes(store):
    job, _ = _new(store)
    store.register_worker("w", 1, "local")
    assert store.claim("w").id == job.id
    assert store.heartbeat(job.id, "w")
    assert store.progress(job.id, "w", progress=50.0, spp_done=2)
    assert store.cancel(job.id, grace=1.0).state == "canceled"
    assert not store.heartbeat(job.id, "w")  # rowcount 0: the worker must stop
    assert not store.progress(job.id, "w", progress=60.0)
    assert not store.finish(job.id, "w", "succeeded", result={})
    assert store.get(job.id).state == "canceled"
    assert store.get(job.id).row["progress"] == 50.0


def test_reaper_requeues_then_fails_after_max_attempts(store):
    job, _ = _new(store, max_attempts=2)
    store.register_worker("w", 1, "local")
    store.claim("w")
    with store.connect() as db:
        db.execute("UPDATE jobs SET heartbeat_at=? WHERE id=?", (time.time() - 100, job.id))
    assert store.reap(stale_after=10) == [(job.id, "queued")]
    again = store.claim("w")
    assert again.id == job.id and again.attempts == 2
    store.worker_lost("w", "worker w was killed by SIGKILL")
    assert store.reap(stale_after=10) == [(job.id, "failed")]
    failed = store.get(job.id)
    assert failed.state == "failed"
    assert "killed by SIGKILL" in failed.row["error"] and "attempt 2 of 2" in failed.row["error"]


def test_fresh_heartbeat_is_not_reaped(store):
    job, _ = _new(store)
    store.register_worker("w", 1, "local")
    store.claim("w")
    assert store.reap(stale_after=10) == []
    assert store.get(job.id).state == "running"


def test_graceful_requeue_refunds_the_attempt(store):
    job, _ = _new(store)
    store.register_worker("w", 1, "local")
    store.claim("w")
    assert store.finish(job.id, "w", "queued", refund_attempt=True)
    j = store.get(job.id)
    assert (j.state, j.attempts, j.worker) == ("queued", 0, None)


def test_idempotency(store):
    a, created_a = _new(store, key="k1", h="same")
    b, created_b = _new(store, key="k1", h="same")
    assert created_a and not created_b and a.id == b.id
    with pytest.raises(IdempotencyConflict):
        _new(store, key="k1", h="different")
    assert store.list_jobs()[1] == 1


def test_a_pending_asset_check_holds_the_job(store):
    """Jobs created with their asset check pending are never claimed; a passed check releases
    them, a refused one fails them at once without spending an attempt."""
    ok = store.create(kind="render", stage="/s.usda", stage_name="s.usda", settings={"spp": 1}, priority=90,
                      max_attempts=3, check_pending=True)[0]
    bad = store.create(kind="render", stage="/b.usda", stage_name="b.usda", settings={"spp": 1}, priority=90,
                       max_attempts=3, check_pending=True)[0]
    plain, _ = _new(store)
    store.register_worker("w", 1, "local")
    assert [j.id for j in store.pending_checks()] == [ok.id, bad.id]
    assert store.claim("w").id == plain.id  # lower priority, but the only checked one
    store.finish(plain.id, "w", "succeeded")
    assert store.claim("w") is None
    assert store.check_done(bad.id, "b.usda: /M.inputs:file: leads outside") and not store.check_done(bad.id, None)
    j = store.get(bad.id)
    assert (j.state, j.attempts, j.row["error"]) == ("failed", 0, "b.usda: /M.inputs:file: leads outside")
    assert store.check_done(ok.id, None) and store.pending_checks() == []
    assert store.claim("w").id == ok.id


def test_a_version_1_database_is_migrated(tmp_path):
    import sqlite3

    path = tmp_path / "old.db"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
    db.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    db.execute("""CREATE TABLE jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, kind TEXT NOT NULL,
                  state TEXT NOT NULL, priority INTEGER NOT NULL, stage TEXT NOT NULL, stage_name TEXT NOT NULL,
                  settings TEXT NOT NULL, idempotency_key TEXT UNIQUE, request_hash TEXT, created_at REAL NOT NULL,
                  updated_at REAL NOT NULL, started_at REAL, finished_at REAL, worker TEXT, heartbeat_at REAL,
                  attempts INTEGER NOT NULL DEFAULT 0, max_attempts INTEGER NOT NULL, progress REAL NOT NULL DEFAULT 0,
                  spp_done INTEGER NOT NULL DEFAULT 0, spp_target INTEGER, samples_per_second REAL, eta_seconds REAL,
                  render_seconds REAL NOT NULL DEFAULT 0, error TEXT, result TEXT, cancel_requested_at REAL,
                  deleted_at REAL)""")
    db.execute("""INSERT INTO jobs (id, kind, state, priority, stage, stage_name, settings, created_at, updated_at,
                  max_attempts) VALUES ('old', 'render', 'queued', 50, '/s.usda', 's.usda', '{}', 0, 0, 3)""")
    db.commit()
    db.close()
    store = JobStore(str(path))
    assert store.get_meta("schema_version") == str(SCHEMA_VERSION)
    store.register_worker("w", 1, "local")
    assert store.claim("w").id == "old"  # checked at submission under version 1


def test_key_replayed_after_delete_creates_a_new_job(store):
    """A DELETE releases the job's idempotency key: a replay creates a new job, both while the
    hidden row waits for collection and after it is gone, never the id of the deleted job."""
    a, _ = _new(store, key="k-del", h="same")
    assert store.delete(a.id, grace=1.0)
    b, created = _new(store, key="k-del", h="same")
    assert created and b.id != a.id and store.get(b.id) is not None
    c, created_c = _new(store, key="k-del", h="same")
    assert not created_c and c.id == b.id
    assert store.collect_deleted() == [a.id]
    assert store.delete(b.id, grace=1.0) and store.collect_deleted() == [b.id]
    d, created_d = _new(store, key="k-del", h="different")
    assert created_d and d.id not in (a.id, b.id)


def test_delete_hides_then_collects(store):
    job, _ = _new(store)
    store.register_worker("w", 1, "local")
    store.claim("w")
    assert store.delete(job.id, grace=1.0)
    assert store.get(job.id) is None
    assert store.collect_deleted() == []  # the worker still holds it
    store.release("w")
    assert store.collect_deleted() == [job.id]
    assert store.get(job.id, include_deleted=True) is None


def test_success_clears_errors_of_earlier_attempts(store):
    job, _ = _new(store)
    store.register_worker("w", 1, "local")
    store.claim("w")
    store.finish(job.id, "w", "queued", error="internal error: OSError: disk full")
    assert store.get(job.id).row["error"].startswith("internal error")
    store.claim("w")
    store.finish(job.id, "w", "succeeded", result={"spp": 4})
    done = store.get(job.id)
    assert done.state == "succeeded" and done.row["error"] is None and done.row["result"] == {"spp": 4}


def test_progress_rejects_unknown_columns(store):
    with pytest.raises(ValueError):
        store.progress("x", "w", state="succeeded")


# A version 2 jobs table (asset checks off the request path; no peak memory, no requeues).
_V2_JOBS = """CREATE TABLE jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, kind TEXT NOT NULL,
    state TEXT NOT NULL, priority INTEGER NOT NULL, stage TEXT NOT NULL, stage_name TEXT NOT NULL,
    settings TEXT NOT NULL, idempotency_key TEXT UNIQUE, request_hash TEXT, created_at REAL NOT NULL,
    updated_at REAL NOT NULL, started_at REAL, finished_at REAL, worker TEXT, heartbeat_at REAL,
    attempts INTEGER NOT NULL DEFAULT 0, max_attempts INTEGER NOT NULL, progress REAL NOT NULL DEFAULT 0,
    spp_done INTEGER NOT NULL DEFAULT 0, spp_target INTEGER, samples_per_second REAL, eta_seconds REAL,
    render_seconds REAL NOT NULL DEFAULT 0, error TEXT, result TEXT, cancel_requested_at REAL, deleted_at REAL,
    asset_check TEXT NOT NULL DEFAULT 'done' CHECK (asset_check IN ('pending', 'done')))"""


def test_a_version_2_database_is_migrated(tmp_path):
    """Version 3 adds peak_memory, requeues, attempt_base and the histograms table, version 4 the
    frame tasks: a version 2 database opens with its jobs intact, and a job that used up its
    attempts there can be requeued for a fresh set."""
    import sqlite3

    path = tmp_path / "v2.db"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
    db.execute("INSERT INTO meta VALUES ('schema_version', '2')")
    db.execute(_V2_JOBS)
    db.execute("""INSERT INTO jobs (id, kind, state, priority, stage, stage_name, settings, created_at, updated_at,
                  attempts, max_attempts, error) VALUES ('v2failed', 'render', 'failed', 50, '/s.usda', 's.usda', '{}',
                  0, 0, 3, 3, 'internal error: disk full (attempt 3 of 3; giving up)')""")
    db.commit()
    db.close()
    store = JobStore(str(path))
    assert store.get_meta("schema_version") == "4" == str(SCHEMA_VERSION)
    with store.connect() as c:
        columns = {r[1] for r in c.execute("PRAGMA table_info(jobs)")}
        assert {"peak_memory", "requeues", "attempt_base"} <= columns
        assert c.execute("SELECT COUNT(*) FROM histograms").fetchone()[0] == 0
    old = store.get("v2failed")
    assert (old.state, old.attempts, old.row["requeues"], old.row["peak_memory"], old.run_attempt) == \
        ("failed", 3, 0, None, 3)
    JobStore(str(path))  # opening a migrated database again changes nothing
    job, requeued = store.requeue("v2failed")
    assert requeued and job.state == "queued" and job.run_attempt == 0 and job.attempts == 3
    assert store.check_done("v2failed", None)  # render jobs are checked again after a requeue
    store.register_worker("w", 1, "local")
    claimed = store.claim("w")
    assert (claimed.id, claimed.attempts, claimed.run_attempt) == ("v2failed", 4, 1)


def _fail(store: JobStore, job_id: str, worker: str = "w") -> None:
    store.register_worker(worker, 1, "local")
    assert store.claim(worker).id == job_id
    assert store.finish(job_id, worker, "failed", error="boom")


def test_requeue_keeps_history_and_gives_a_fresh_run(store):
    job, _ = _new(store, max_attempts=2)
    _fail(store, job.id)
    j, requeued = store.requeue(job.id, priority=80)
    assert requeued
    assert (j.state, j.attempts, j.run_attempt, j.row["requeues"], j.priority, j.row["error"], j.worker) == \
        ("queued", 1, 0, 1, 80, None, None)
    assert j.row["asset_check"] == "pending" and j.row["started_at"] is None and j.row["finished_at"] is None
    # repeated: nothing changes (idempotent), also not the priority
    again, requeued_again = store.requeue(job.id, priority=10)
    assert not requeued_again and again.row["requeues"] == 1 and again.priority == 80
    store.check_done(job.id, None)
    # the new run has its own max_attempts: the reaper requeues a stale first attempt of it
    claimed = store.claim("w")
    assert (claimed.attempts, claimed.run_attempt) == (2, 1)
    with store.connect() as db:
        db.execute("UPDATE jobs SET heartbeat_at=0 WHERE id=?", (job.id,))
    assert store.reap(stale_after=10) == [(job.id, "queued")]
    store.register_worker("w", 1, "local")
    assert store.claim("w").run_attempt == 2
    with store.connect() as db:
        db.execute("UPDATE jobs SET heartbeat_at=0 WHERE id=?", (job.id,))
    assert store.reap(stale_after=10) == [(job.id, "failed")]
    assert "attempt 2 of 2" in store.get(job.id).row["error"] and store.get(job.id).attempts == 3
    # only failed and canceled jobs go back; unknown or deleted ones are None
    ok, _ = _new(store)
    store.register_worker("w", 1, "local")
    store.claim("w")
    assert store.finish(ok.id, "w", "succeeded", result={})
    assert store.requeue(ok.id) == (store.get(ok.id), False)
    assert store.requeue("0" * 16) == (None, False)
    store.delete(job.id, grace=1.0)
    assert store.requeue(job.id) == (None, False)
    with pytest.raises(ValueError):
        store.requeue(ok.id, priority=101)


def test_a_requeued_job_waits_for_its_old_worker_to_let_go(store):
    """Cancel a running job and requeue it before its worker noticed: the old worker's guarded
    writes fail, and no other worker takes the job until the old one released it."""
    job, _ = _new(store, key="k", h="h")
    store.register_worker("old", 1, "local")
    store.register_worker("new", 2, "local")
    assert store.claim("old").id == job.id
    assert store.cancel(job.id, grace=5.0).state == "canceled"
    j, requeued = store.requeue(job.id)
    assert requeued and j.state == "queued"
    store.check_done(job.id, None)
    assert store.claim("new") is None                       # still held by "old"
    assert store.queue_order() == []
    assert not store.heartbeat(job.id, "old")               # the old worker is told to stop
    assert not store.progress(job.id, "old", progress=99.0)
    assert not store.finish(job.id, "old", "succeeded", result={})   # and its result is refused
    assert store.get(job.id).state == "queued"
    store.release("old")                                    # what finish already did; harmless again
    claimed = store.claim("new")
    assert claimed.id == job.id and claimed.worker == "new" and claimed.attempts == 2


def test_concurrent_requeues_requeue_once(store):
    job, _ = _new(store)
    _fail(store, job.id)
    results = []
    barrier = threading.Barrier(8)

    def go():
        barrier.wait()
        results.append(store.requeue(job.id)[1])

    threads = [threading.Thread(target=go) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == [False] * 7 + [True]
    assert store.get(job.id).row["requeues"] == 1


def test_priority_edit_reorders_the_queue(store):
    a, _ = _new(store, 50)
    b, _ = _new(store, 50)
    c, _ = _new(store, 60)
    assert store.queue_order() == [c.id, a.id, b.id]
    j, changed = store.set_priority(b.id, 90)
    assert changed and j.priority == 90
    assert store.queue_order() == [b.id, c.id, a.id]
    store.register_worker("w", 1, "local")
    assert [store.claim("w").id for _ in range(3)] == [b.id, c.id, a.id]
    store.finish(b.id, "w", "succeeded", result={})
    assert store.set_priority(b.id, 10) == (store.get(b.id), False)   # finished: unchanged
    assert store.get(b.id).priority == 90
    assert store.set_priority(a.id, 5)[1]                              # running: allowed
    assert store.set_priority("f" * 16, 5) == (None, False)
    for bad in (-1, 101):
        with pytest.raises(ValueError):
            store.set_priority(a.id, bad)


def test_stage_search_is_plain_text(store):
    names = ["shots/a.usda", "shots/b_100%.usda", "env/sky.usda", "O'Brien/x.usda"]
    for n in names:
        store.create(kind="render", stage="/" + n, stage_name=n, settings={}, priority=50, max_attempts=1)
    found = lambda text: sorted(j.stage_name for j in store.list_jobs(stage=text)[0])  # noqa: E731
    assert found("SHOTS/") == ["shots/a.usda", "shots/b_100%.usda"]
    assert found("%") == ["shots/b_100%.usda"]        # not a LIKE wildcard
    assert found("_") == ["shots/b_100%.usda"]
    assert found("'") == ["O'Brien/x.usda"]
    assert found("' OR 1=1 --") == []
    assert found("x'); DROP TABLE jobs; --") == []
    assert store.list_jobs()[1] == 4 and store.integrity() == "ok"
    assert store.list_jobs(states=["queued"], stage="sky")[1] == 1
    assert store.list_jobs(states=["failed"], stage="sky")[1] == 0


def test_histograms_count_finished_runs(store):
    """Render seconds of successes and peak memory of every run that ended, bucketed with
    inclusive upper bounds; a deleted job's observations stay (counters never go down)."""
    store.register_worker("w", 1, "local")
    secs = HISTOGRAMS["render_seconds"]
    runs = [(secs[0], 100 * 2**20, "succeeded"), (secs[0] + 1e-9, None, "succeeded"), (1e9, 3 * 2**30, "failed")]
    for seconds, peak, state in runs:
        job, _ = _new(store)
        assert store.claim("w").id == job.id
        if peak:
            assert store.heartbeat(job.id, "w", peak_memory=peak // 2)
            assert store.heartbeat(job.id, "w", peak_memory=peak)
            assert store.heartbeat(job.id, "w", peak_memory=peak // 4)     # a peak never goes down
        assert store.finish(job.id, "w", state, render_seconds=seconds)
    assert store.get(job.id).row["peak_memory"] == 3 * 2**30
    # a running job canceled ends a run too; a queued one does not
    running, _ = _new(store)
    store.claim("w")
    store.heartbeat(running.id, "w", peak_memory=2**20)
    store.cancel(running.id, grace=1.0)
    queued, _ = _new(store)
    store.cancel(queued.id, grace=1.0)
    store.delete(running.id, grace=1.0)
    store.collect_deleted()
    h = store.histograms()
    cum, total = h[("render_seconds", "render")]
    assert cum[0] == (secs[0], 1) and cum[1] == (secs[1], 2) and cum[-1] == (float("inf"), 2)
    assert total == pytest.approx(2 * secs[0] + 1e-9)
    mem, mem_total = h[("peak_memory_bytes", "render")]
    bounds = dict(mem)
    assert bounds[64 * 2**20] == 1 and bounds[128 * 2**20] == 2 and bounds[2 * 2**30] == 2
    assert bounds[4 * 2**30] == 3 and mem[-1] == (float("inf"), 3)
    assert mem_total == 100 * 2**20 + 3 * 2**30 + 2**20
