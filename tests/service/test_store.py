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
