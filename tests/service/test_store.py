"""The SQLite job store: atomic claims, priority order, heartbeats, reaper, idempotency."""

from __future__ import annotations

import threading
import time

import pytest

from service.store import IdempotencyConflict, JobStore


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
    assert store.get_meta("schema_version") == "2"
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
