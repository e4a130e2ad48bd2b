"""A bounded load test over loopback: concurrent clients submit a mix of valid, duplicate
(idempotent) and invalid jobs. Every submission must be accepted or cleanly rejected, no
accepted job may be lost or duplicated, every job must finish, and the database must stay
consistent."""

from __future__ import annotations

import os
import random
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from .conftest import make_stage_root, start_server, wait_for

MICRO = {"resolution": [8, 8], "spp": 1}


def _plan(n: int, seed: int) -> list[dict]:
    """n request bodies: ~75 % new jobs, ~15 % repeats of an earlier idempotency key, ~10 %
    invalid (over a limit, outside the stage root, unknown field)."""
    rng = random.Random(seed)
    tag = f"load-{seed}-{time.monotonic_ns()}"
    bodies, originals = [], []
    for i in range(n):
        r = rng.random()
        if r < 0.10:
            bodies.append(rng.choice([
                {"stage": "cornell_box.usda", "settings": {"spp": 10**9}},
                {"stage": "../../etc/passwd", "settings": MICRO},
                {"stage": "cornell_box.usda", "settings": {**MICRO, "turbo": True}},
            ]))
        elif r < 0.25 and originals:
            bodies.append(dict(rng.choice(originals)))  # a client retrying: the same body and key
        else:
            body = {"stage": "cornell_box.usda", "settings": MICRO, "idempotency_key": f"{tag}-{i}",
                    "priority": rng.randint(0, 100)}
            originals.append(body)
            bodies.append(body)
    return bodies


def run_load(server, n: int, clients: int, seed: int = 1, time_limit: float = 120.0) -> None:
    bodies = _plan(n, seed)
    t_end = time.monotonic() + time_limit

    def submit(chunk: list[dict]) -> list[tuple[dict, int, dict]]:
        out = []
        with httpx.Client(base_url=server.url, timeout=30) as c:
            for body in chunk:
                assert time.monotonic() < t_end, "the load test ran out of time"
                r = c.post("/jobs", json=body)
                out.append((body, r.status_code, r.json()))
        return out

    chunks = [bodies[i::clients] for i in range(clients)]
    with ThreadPoolExecutor(clients) as ex:
        results = [x for part in ex.map(submit, chunks) for x in part]
    assert len(results) == n

    by_key: dict[str, set] = {}
    accepted: set[str] = set()
    for body, status, data in results:
        assert status in (200, 201, 400, 422), (status, data)       # accepted or cleanly rejected
        if status in (200, 201):
            accepted.add(data["id"])
            by_key.setdefault(body["idempotency_key"], set()).add(data["id"])
        else:
            assert data["message"], data                            # a rejection says why
            assert "idempotency_key" not in body or body["settings"] != MICRO
    assert all(len(ids) == 1 for ids in by_key.values())            # a key never made two jobs
    assert len(accepted) == len(by_key)

    with server.client() as c:
        def all_done():
            states = [c.get(f"/jobs/{jid}").json()["state"] for jid in accepted]
            return states if all(s in ("succeeded", "failed", "canceled") for s in states) else None

        states = wait_for(all_done, max(5.0, t_end - time.monotonic()), interval=0.5, what="every job to finish")
        assert set(states) == {"succeeded"}
        listed = {j["id"] for j in c.get("/jobs", params={"limit": 1000}).json()["jobs"]}
        assert accepted <= listed                                   # none lost
        metrics = c.get("/metrics").text
        assert "illum_jobs_created_total" in metrics

    from service.store import JobStore

    store = JobStore(os.path.join(server.data, "jobs.db"))
    assert store.integrity() == "ok"
    with store.connect() as db:
        keys = list(by_key)
        rows = db.execute(f"SELECT idempotency_key, COUNT(*) FROM jobs WHERE idempotency_key IN "
                          f"({','.join('?' * len(keys))}) GROUP BY idempotency_key", keys).fetchall()
        assert len(rows) == len(keys) and all(r[1] == 1 for r in rows)
        bad = db.execute("SELECT COUNT(*) FROM jobs WHERE state='succeeded' AND (spp_done != 1 OR progress != 100)"
                         " AND id IN (%s)" % ",".join("?" * len(accepted)), list(accepted)).fetchone()[0]
        assert bad == 0
        assert db.execute("SELECT COUNT(*) FROM workers WHERE job_id IS NOT NULL AND job_id NOT IN "
                          "(SELECT id FROM jobs WHERE state='running')").fetchone()[0] == 0


def test_load_reduced(server):
    """40 submissions from 8 concurrent clients on the shared two-worker server."""
    run_load(server, n=40, clients=8, seed=7, time_limit=90)


@pytest.mark.slow
def test_load_200(tmp_path):
    """~200 submissions from 16 concurrent clients on a dedicated server."""
    s = start_server(tmp_path, make_stage_root(tmp_path / "root"), workers=2)
    try:
        run_load(s, n=200, clients=16, seed=11, time_limit=300)
    finally:
        s.stop()
