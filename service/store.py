"""SQLite job store: the single source of truth for jobs, shared by the server and its workers.

Every process (the server, each worker) opens its own short-lived connections to one database
file in WAL mode, so readers never block the writer and a crash of any process (``kill -9``)
leaves a consistent database: each state change is one transaction.

State machine::

    queued ──claim──► running ──► succeeded | failed | canceled
      ▲                  │
      └──── reaper ──────┘   (stale heartbeat and attempts < max_attempts)

    queued (asset_check 'pending') ──check refused──► failed   (never claimed, never retried)

    failed | canceled ──requeue──► queued   (attempts kept; a fresh allowance of max_attempts)

* A render job is created with its asset check ``pending``: the server's checker threads run the
  check off the request path (service/assets.py) and either fail the job with the checker's
  message (``check_done``) or mark it ``done``; ``claim`` takes only checked jobs. Pending
  checks live in the table, so a restarted server picks them up again.

* ``claim`` is one ``UPDATE … WHERE id = (SELECT … ORDER BY priority DESC, seq) RETURNING``, so
  two workers can never take the same job.
* Workers heartbeat with ``UPDATE … WHERE id=? AND worker=? AND state='running'``. A rowcount of
  0 means the job was canceled, deleted or handed to another worker: the worker must stop.
* Every write a worker makes is guarded the same way, so a worker that lost its job can never
  overwrite what the reaper or a user decided.
* ``requeue`` puts a failed or canceled job back in the queue in one conditional UPDATE, so it
  is idempotent (a second requeue finds the job queued and changes nothing) and never races a
  worker: ``claim`` skips a job that a worker row still holds (a canceled job whose worker has
  not let go yet), so the old worker's guarded writes fail and a new worker starts only once the
  old one released it, resuming from the checkpoint. ``attempts`` keeps counting over requeues;
  ``attempt_base`` (the attempts spent before the last requeue) gives each run its own
  ``max_attempts``.
* Finished jobs add to persistent histograms (render seconds, peak memory) in the same
  transaction that ends them, so ``/metrics`` counts survive restarts and deletions.
* A frame-range job has one row per frame in ``tasks`` (v4). The job is claimed, heartbeated,
  canceled and requeued as a whole; its worker takes the job's tasks one at a time
  (``start_task``, lowest index first) and ends each (``finish_task``). A worker lost on frame k
  puts only frame k back in the queue (the reaper; the job is requeued), or fails frame k once its
  own attempts reach ``max_attempts``: the frames already rendered are never rendered again.
* Deleting a job hides it at once (``deleted_at``); the row and its directory are removed by
  ``collect_deleted`` once no worker holds it, so a worker never writes into a removed dir.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sqlite3
import time
import uuid
from dataclasses import dataclass
from typing import Any, Iterator, Optional

__all__ = ["JobStore", "Job", "STATES", "TERMINAL_STATES", "KINDS"]

STATES = ("queued", "running", "succeeded", "failed", "canceled")
TERMINAL_STATES = ("succeeded", "failed", "canceled")
KINDS = ("render", "preconvolve")
SCHEMA_VERSION = 4

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS jobs (
    seq                 INTEGER PRIMARY KEY AUTOINCREMENT,
    id                  TEXT NOT NULL UNIQUE,
    kind                TEXT NOT NULL CHECK (kind IN ('render', 'preconvolve')),
    state               TEXT NOT NULL CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'canceled')),
    priority            INTEGER NOT NULL CHECK (priority BETWEEN 0 AND 100),
    stage               TEXT NOT NULL,      -- resolved absolute path the worker opens
    stage_name          TEXT NOT NULL,      -- what users see: path relative to the stage root, or upload:NAME
    settings            TEXT NOT NULL,      -- JSON, validated at submission
    idempotency_key     TEXT UNIQUE,
    request_hash        TEXT,               -- detects an idempotency key reused with another body
    created_at          REAL NOT NULL,
    updated_at          REAL NOT NULL,
    started_at          REAL,
    finished_at         REAL,
    worker              TEXT,
    heartbeat_at        REAL,
    attempts            INTEGER NOT NULL DEFAULT 0,
    max_attempts        INTEGER NOT NULL CHECK (max_attempts >= 1),
    progress            REAL NOT NULL DEFAULT 0,   -- percent, 0..100
    spp_done            INTEGER NOT NULL DEFAULT 0,
    spp_target          INTEGER,
    samples_per_second  REAL,
    eta_seconds         REAL,
    render_seconds      REAL NOT NULL DEFAULT 0,
    error               TEXT,
    result              TEXT,               -- JSON summary written on success
    cancel_requested_at REAL,
    deleted_at          REAL,
    asset_check         TEXT NOT NULL DEFAULT 'done' CHECK (asset_check IN ('pending', 'done')),
    peak_memory         INTEGER,            -- bytes: the largest worker RSS seen over the job's attempts
    requeues            INTEGER NOT NULL DEFAULT 0,   -- times a user put the job back in the queue
    attempt_base        INTEGER NOT NULL DEFAULT 0    -- attempts spent before the last requeue
);
CREATE INDEX IF NOT EXISTS jobs_queue ON jobs (state, priority DESC, seq);
-- v4: the frames of a frame-range job, one task each: its own state, attempts and image. The job
-- is claimed as a whole; its worker runs the tasks still queued, in order (service/worker.py).
CREATE TABLE IF NOT EXISTS tasks (
    job_id          TEXT NOT NULL REFERENCES jobs (id) ON DELETE CASCADE,
    idx             INTEGER NOT NULL,          -- position in the range, from 0
    frame           REAL NOT NULL,             -- the time code rendered
    state           TEXT NOT NULL DEFAULT 'queued'
                    CHECK (state IN ('queued', 'running', 'succeeded', 'failed', 'canceled')),
    attempts        INTEGER NOT NULL DEFAULT 0,
    attempt_base    INTEGER NOT NULL DEFAULT 0,   -- attempts spent before the job's last requeue
    progress        REAL NOT NULL DEFAULT 0,      -- percent of this frame
    spp_done        INTEGER NOT NULL DEFAULT 0,
    render_seconds  REAL NOT NULL DEFAULT 0,
    started_at      REAL,
    finished_at     REAL,
    error           TEXT,
    PRIMARY KEY (job_id, idx)
);
CREATE TABLE IF NOT EXISTS workers (
    id            TEXT PRIMARY KEY,
    host          TEXT NOT NULL,
    pid           INTEGER NOT NULL,
    backend       TEXT NOT NULL,
    job_id        TEXT,
    started_at    REAL NOT NULL,
    heartbeat_at  REAL NOT NULL,
    stop_deadline REAL              -- set on cancel: the supervisor kills the process after it
);
-- Histograms of finished jobs for /metrics: one row per (metric, job kind, bucket upper bound),
-- counting the observations that fell in that bucket alone (not cumulative), with their sum.
CREATE TABLE IF NOT EXISTS histograms (
    name  TEXT NOT NULL,
    kind  TEXT NOT NULL,
    le    REAL NOT NULL,
    count INTEGER NOT NULL DEFAULT 0,
    sum   REAL NOT NULL DEFAULT 0,
    PRIMARY KEY (name, kind, le)
);
"""

# Columns added after version 1, with their definitions: a database from an older version gets
# them by ALTER TABLE at open (its rows take the defaults, which describe them correctly).
_ADDED_COLUMNS = (
    # v2: jobs of a v1 database were all checked at submission
    ("asset_check", "TEXT NOT NULL DEFAULT 'done' CHECK (asset_check IN ('pending', 'done'))"),
    # v3: nothing measured, never requeued
    ("peak_memory", "INTEGER"),
    ("requeues", "INTEGER NOT NULL DEFAULT 0"),
    ("attempt_base", "INTEGER NOT NULL DEFAULT 0"),
)

# Bucket upper bounds of the histograms (the last bucket, +Inf, is implied).
RENDER_SECONDS_BUCKETS = (1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0, 7200.0,
                          14400.0, 28800.0, 86400.0)
MEMORY_BUCKETS = tuple(float(2 ** k) for k in range(26, 39))   # 64 MiB .. 256 GiB
HISTOGRAMS = {"render_seconds": RENDER_SECONDS_BUCKETS, "peak_memory_bytes": MEMORY_BUCKETS}

# Columns the API exposes (internal bookkeeping such as request_hash stays private).
_PUBLIC = ("id", "kind", "state", "priority", "stage_name", "settings", "idempotency_key", "created_at",
           "updated_at", "started_at", "finished_at", "worker", "heartbeat_at", "attempts", "max_attempts",
           "progress", "spp_done", "spp_target", "samples_per_second", "eta_seconds", "render_seconds",
           "error", "result", "cancel_requested_at", "asset_check", "peak_memory", "requeues")

# Columns a worker may set while it owns a job (names are interpolated into SQL: keep this closed).
_PROGRESS_FIELDS = frozenset({"progress", "spp_done", "spp_target", "samples_per_second", "eta_seconds",
                              "render_seconds", "peak_memory"})


@dataclass(frozen=True)
class Job:
    """One row of ``jobs`` as plain values (settings/result decoded from JSON)."""

    id: str
    kind: str
    state: str
    priority: int
    stage: str
    stage_name: str
    settings: dict
    attempts: int
    max_attempts: int
    worker: Optional[str]
    row: dict

    @property
    def run_attempt(self) -> int:
        """The attempt number within this run (since the job was created or last requeued),
        which ``max_attempts`` bounds; ``attempts`` counts them all."""
        return self.attempts - int(self.row.get("attempt_base") or 0)

    @staticmethod
    def from_row(row: sqlite3.Row) -> "Job":
        d = dict(row)
        d["settings"] = json.loads(d["settings"]) if d.get("settings") else {}
        d["result"] = json.loads(d["result"]) if d.get("result") else None
        return Job(id=d["id"], kind=d["kind"], state=d["state"], priority=d["priority"], stage=d["stage"],
                   stage_name=d["stage_name"], settings=d["settings"], attempts=d["attempts"],
                   max_attempts=d["max_attempts"], worker=d["worker"], row=d)

    def public(self) -> dict:
        """The API representation (see service/README.md)."""
        out = {k: self.row.get(k) for k in _PUBLIC}
        out["stage"] = out.pop("stage_name")
        return out


class IdempotencyConflict(Exception):
    """The idempotency key already names a job created from a different request body."""

    def __init__(self, job: Job):
        self.job = job
        super().__init__(f"idempotency key {job.row.get('idempotency_key')!r} was used for job {job.id} "
                         "with a different request")


class JobStore:
    """All job-state transitions, as single SQLite transactions.

    path: the database file. Connections are opened per operation (cheap for SQLite) so the
    store is safe to share between threads and across fork/spawn.
    """

    def __init__(self, path: str, busy_timeout_ms: int = 10_000):
        self.path = os.path.abspath(path)
        self.busy_timeout_ms = int(busy_timeout_ms)
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        with self.connect() as db:
            # WAL persists in the file; setting it once per open is harmless and makes a fresh
            # database WAL before the schema is written.
            mode = db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise RuntimeError(f"{self.path}: SQLite refused WAL mode (got {mode!r}); "
                                   "is the data directory on a network filesystem?")
            db.executescript(_SCHEMA)
            columns = {r[1] for r in db.execute("PRAGMA table_info(jobs)")}
            added = [(name, decl) for name, decl in _ADDED_COLUMNS if name not in columns]
            if added:
                db.execute("BEGIN IMMEDIATE")
                try:
                    # another process may have migrated meanwhile: look again under the write lock
                    columns = {r[1] for r in db.execute("PRAGMA table_info(jobs)")}
                    for name, decl in added:
                        if name not in columns:
                            db.execute(f"ALTER TABLE jobs ADD COLUMN {name} {decl}")
                    db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION),))
                except BaseException:
                    db.execute("ROLLBACK")
                    raise
                db.execute("COMMIT")
            db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            # v4 only added a table (made by the schema script above): no column to add.
            db.execute("UPDATE meta SET value=? WHERE key='schema_version' AND CAST(value AS INTEGER) < ?",
                       (str(SCHEMA_VERSION), SCHEMA_VERSION))

    # ------------------------------------------------------------------ connections
    @contextlib.contextmanager
    def connect(self) -> Iterator[sqlite3.Connection]:
        """A connection in autocommit mode (each statement is its own transaction unless
        ``transaction()`` is used); always closed."""
        db = sqlite3.connect(self.path, timeout=self.busy_timeout_ms / 1000.0, isolation_level=None)
        try:
            db.row_factory = sqlite3.Row
            db.execute(f"PRAGMA busy_timeout={self.busy_timeout_ms}")
            # NORMAL is durable across process crashes in WAL mode (only an OS crash can lose the
            # last transactions), which is the failure model here.
            db.execute("PRAGMA synchronous=NORMAL")
            db.execute("PRAGMA foreign_keys=ON")
            yield db
        finally:
            db.close()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE … COMMIT: takes the write lock up front so read-then-write sequences
        cannot interleave with another writer."""
        with self.connect() as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")

    # ------------------------------------------------------------------ submission
    def create(self, *, kind: str, stage: str, stage_name: str, settings: dict, priority: int,
               max_attempts: int, idempotency_key: str | None = None,
               request_hash: str | None = None, check_pending: bool = False,
               frames: list[float] | None = None) -> tuple[Job, bool]:
        """Insert a queued job. Returns (job, created): with an idempotency key already used for
        the same request, the existing job and False; for a different request it raises
        IdempotencyConflict. check_pending: no worker may claim the job until ``check_done``.
        frames: a frame-range job's frames, one task each (in the same transaction)."""
        now = time.time()
        job_id = uuid.uuid4().hex[:16]
        with self.transaction() as db:
            if idempotency_key is not None:
                row = db.execute("SELECT * FROM jobs WHERE idempotency_key=?", (idempotency_key,)).fetchone()
                if row is not None:
                    job = Job.from_row(row)
                    if row["request_hash"] != request_hash:
                        raise IdempotencyConflict(job)
                    return job, False
            db.execute(
                """INSERT INTO jobs (id, kind, state, priority, stage, stage_name, settings, idempotency_key,
                                     request_hash, created_at, updated_at, max_attempts, spp_target, asset_check)
                   VALUES (?, ?, 'queued', ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)""",
                (job_id, kind, int(priority), stage, stage_name, json.dumps(settings, sort_keys=True),
                 idempotency_key, request_hash, now, now, int(max_attempts), settings.get("spp"),
                 "pending" if check_pending else "done"))
            if frames:
                db.executemany("INSERT INTO tasks (job_id, idx, frame) VALUES (?, ?, ?)",
                               [(job_id, k, float(f)) for k, f in enumerate(frames)])
            row = db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        return Job.from_row(row), True

    # ------------------------------------------------------------------ frame tasks
    def tasks(self, job_id: str) -> list[dict]:
        """A frame-range job's tasks in range order ([] for a one-frame job)."""
        with self.connect() as db:
            return [dict(r) for r in db.execute("SELECT * FROM tasks WHERE job_id=? ORDER BY idx", (job_id,))]

    def task_counts(self, job_ids: list[str]) -> dict:
        """{job id: {state: tasks}} for the frame-range jobs among ``job_ids`` (one query)."""
        if not job_ids:
            return {}
        out: dict = {}
        with self.connect() as db:
            for i in range(0, len(job_ids), 500):   # SQLite's bound-parameter limit
                part = job_ids[i:i + 500]
                rows = db.execute(f"""SELECT job_id, state, COUNT(*) FROM tasks WHERE job_id IN
                                      ({','.join('?' * len(part))}) GROUP BY job_id, state""", part).fetchall()
                for job_id, state, n in rows:
                    out.setdefault(job_id, {s: 0 for s in STATES})[state] = int(n)
        return out

    def running_tasks(self) -> dict:
        """{job id: index of its running frame task} over all jobs."""
        with self.connect() as db:
            return {r[0]: int(r[1]) for r in db.execute("SELECT job_id, idx FROM tasks WHERE state='running'")}

    def start_task(self, job_id: str, worker_id: str) -> dict | None | bool:
        """The worker owning the running job takes its next task (the lowest index still
        queued) and counts an attempt on it. Returns the task row, None when no task is left,
        or False when the job is no longer this worker's (stop)."""
        now = time.time()
        with self.transaction() as db:
            if db.execute(f"SELECT 1 FROM jobs WHERE {_OWNED}", (job_id, worker_id)).fetchone() is None:
                return False
            row = db.execute(
                """UPDATE tasks SET state='running', attempts=attempts+1, started_at=?, finished_at=NULL,
                       progress=0, spp_done=0
                   WHERE job_id=? AND idx=(SELECT idx FROM tasks WHERE job_id=? AND state IN ('queued', 'running')
                                           ORDER BY idx LIMIT 1)
                   RETURNING *""", (now, job_id, job_id)).fetchone()
        return dict(row) if row is not None else None

    def finish_task(self, job_id: str, worker_id: str, idx: int, state: str, *, error: str | None = None,
                    **fields) -> bool:
        """End a task's attempt (succeeded, failed, or queued to retry), only by the worker
        owning its job. fields: spp_done, render_seconds, progress."""
        if state not in ("succeeded", "failed", "queued"):
            raise ValueError(f"a worker cannot move a task to {state!r}")
        bad = set(fields) - {"spp_done", "render_seconds", "progress"}
        if bad:
            raise ValueError(f"not task fields: {sorted(bad)}")
        now = time.time()
        sets = ["state=?", "finished_at=?", "error=?", *(f"{k}=?" for k in fields)]
        args = [state, None if state == "queued" else now, error, *fields.values()]
        with self.transaction() as db:
            if db.execute(f"SELECT 1 FROM jobs WHERE {_OWNED}", (job_id, worker_id)).fetchone() is None:
                return False
            cur = db.execute(f"UPDATE tasks SET {', '.join(sets)} WHERE job_id=? AND idx=? AND state='running'",
                             (*args, job_id, int(idx)))
            return cur.rowcount == 1

    # ------------------------------------------------------------------ queries
    def get(self, job_id: str, include_deleted: bool = False) -> Job | None:
        with self.connect() as db:
            row = db.execute("SELECT * FROM jobs WHERE id=?" + ("" if include_deleted else " AND deleted_at IS NULL"),
                             (job_id,)).fetchone()
        return Job.from_row(row) if row is not None else None

    def list_jobs(self, states: list[str] | None = None, limit: int = 200, offset: int = 0,
                  stage: str | None = None) -> tuple[list[Job], int]:
        """Newest first. ``stage``: only jobs whose stage name contains this text (case-blind
        for ASCII letters; matched as plain text, never as a pattern). Returns (jobs, total
        matching)."""
        rows, total = self.list_rows(states, limit, offset, stage)
        return [Job.from_row(r) for r in rows], total

    def list_rows(self, states: list[str] | None = None, limit: int = 200, offset: int = 0,
                  stage: str | None = None) -> tuple[list[sqlite3.Row], int]:
        """``list_jobs`` as undecoded rows (``Job.from_row`` makes jobs of them): GET /jobs
        decodes only the rows that changed since it last listed them."""
        where = "deleted_at IS NULL"
        args: list[Any] = []
        if states:
            where += f" AND state IN ({','.join('?' * len(states))})"
            args += list(states)
        if stage:
            where += " AND instr(lower(stage_name), lower(?)) > 0"
            args.append(stage)
        with self.connect() as db:
            total = db.execute(f"SELECT COUNT(*) FROM jobs WHERE {where}", args).fetchone()[0]
            rows = db.execute(f"SELECT * FROM jobs WHERE {where} ORDER BY seq DESC LIMIT ? OFFSET ?",
                              args + [int(limit), int(offset)]).fetchall()
        return rows, int(total)

    def queue_order(self) -> list[str]:
        """Ids of the claimable jobs in the order workers will take them."""
        with self.connect() as db:
            rows = db.execute(f"SELECT id FROM jobs WHERE {_CLAIMABLE} ORDER BY priority DESC, seq").fetchall()
        return [r[0] for r in rows]

    def counts(self) -> dict:
        """Jobs per state (visible ones), plus totals for metrics."""
        with self.connect() as db:
            rows = db.execute("SELECT state, COUNT(*) FROM jobs WHERE deleted_at IS NULL GROUP BY state").fetchall()
            attempts = db.execute("SELECT COALESCE(SUM(attempts), 0) FROM jobs").fetchone()[0]
            sps = db.execute("SELECT COALESCE(SUM(samples_per_second), 0) FROM jobs WHERE state='running'").fetchone()[0]
            seq = db.execute("SELECT seq FROM sqlite_sequence WHERE name='jobs'").fetchone()
            spp = db.execute("SELECT COALESCE(SUM(spp_done), 0) FROM jobs WHERE state='succeeded'").fetchone()[0]
        out = {s: 0 for s in STATES}
        out.update({r[0]: int(r[1]) for r in rows})
        return {"states": out, "attempts_total": int(attempts), "samples_per_second": float(sps),
                "created_total": int(seq[0]) if seq else 0, "spp_succeeded_total": int(spp)}

    # ------------------------------------------------------------------ user actions
    def cancel(self, job_id: str, grace: float) -> Job | None:
        """Cancel a queued or running job (idempotent for canceled ones). A running job's worker
        sees rowcount 0 at its next heartbeat and stops; ``grace`` seconds later the supervisor
        kills it if it has not let go. Returns the job after the change, None if unknown."""
        now = time.time()
        with self.transaction() as db:
            row = db.execute("SELECT * FROM jobs WHERE id=? AND deleted_at IS NULL", (job_id,)).fetchone()
            if row is None:
                return None
            if row["state"] in ("queued", "running"):
                db.execute("""UPDATE jobs SET state='canceled', cancel_requested_at=?, finished_at=?, updated_at=?,
                              eta_seconds=NULL, samples_per_second=NULL WHERE id=?""", (now, now, now, job_id))
                db.execute("UPDATE workers SET stop_deadline=? WHERE job_id=?", (now + grace, job_id))
                db.execute("""UPDATE tasks SET state='canceled', finished_at=? WHERE job_id=?
                              AND state IN ('queued', 'running')""", (now, job_id))
                if row["state"] == "running":  # a run ended
                    _observe_end(db, job_id)
            row = db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        return Job.from_row(row)

    def set_priority(self, job_id: str, priority: int) -> tuple[Job | None, bool]:
        """Change the priority of a queued or running job (a running one keeps it if it is
        requeued). Returns (job after the call or None if unknown, changed); a finished job is
        returned unchanged with changed False."""
        if not 0 <= int(priority) <= 100:
            raise ValueError(f"priority must be in [0, 100], got {priority}")
        now = time.time()
        with self.transaction() as db:
            cur = db.execute("""UPDATE jobs SET priority=?, updated_at=? WHERE id=? AND deleted_at IS NULL
                                AND state IN ('queued', 'running')""", (int(priority), now, job_id))
            row = db.execute("SELECT * FROM jobs WHERE id=? AND deleted_at IS NULL", (job_id,)).fetchone()
        return (Job.from_row(row) if row is not None else None), cur.rowcount == 1

    def requeue(self, job_id: str, priority: int | None = None) -> tuple[Job | None, bool]:
        """Put a failed or canceled job back in the queue: a new run with max_attempts fresh
        attempts, resuming from its checkpoint if one is left. ``attempts``, the log and the
        checkpoint are kept; the error, progress rate and times of the last run are cleared.
        Render jobs have their stage's assets checked again. Returns (job or None if unknown,
        requeued); a job already queued or running (a repeated request) or succeeded is
        returned unchanged with requeued False.

        Safe against the job's old worker: if it still holds the job (a cancel it has not
        noticed yet) its guarded writes fail from now on, and ``claim`` leaves the job alone
        until that worker has let go."""
        if priority is not None and not 0 <= int(priority) <= 100:
            raise ValueError(f"priority must be in [0, 100], got {priority}")
        now = time.time()
        with self.transaction() as db:
            cur = db.execute(
                """UPDATE jobs SET state='queued', worker=NULL, heartbeat_at=NULL, started_at=NULL,
                       finished_at=NULL, cancel_requested_at=NULL, error=NULL, eta_seconds=NULL,
                       samples_per_second=NULL, requeues=requeues+1, attempt_base=attempts,
                       priority=COALESCE(?, priority), updated_at=?,
                       asset_check=CASE WHEN kind='render' THEN 'pending' ELSE 'done' END
                   WHERE id=? AND deleted_at IS NULL AND state IN ('failed', 'canceled')""",
                (None if priority is None else int(priority), now, job_id))
            if cur.rowcount == 1:  # frames not rendered yet get their fresh attempts too
                db.execute("""UPDATE tasks SET state='queued', attempt_base=attempts, error=NULL, finished_at=NULL
                              WHERE job_id=? AND state IN ('failed', 'canceled', 'running')""", (job_id,))
            row = db.execute("SELECT * FROM jobs WHERE id=? AND deleted_at IS NULL", (job_id,)).fetchone()
        return (Job.from_row(row) if row is not None else None), cur.rowcount == 1

    def delete(self, job_id: str, grace: float) -> bool:
        """Hide a job at once (canceling it if active); ``collect_deleted`` removes it later.

        The job's idempotency key is released in the same transaction: a key replayed after a
        DELETE creates a new job, at once and ever after, rather than answering with a job id
        that then 404s (the hidden row stays until collected)."""
        now = time.time()
        with self.transaction() as db:
            row = db.execute("SELECT state FROM jobs WHERE id=? AND deleted_at IS NULL", (job_id,)).fetchone()
            if row is None:
                return False
            db.execute("""UPDATE jobs SET deleted_at=?, updated_at=?, idempotency_key=NULL,
                          state=CASE WHEN state IN ('queued','running') THEN 'canceled' ELSE state END,
                          finished_at=COALESCE(finished_at, ?) WHERE id=?""", (now, now, now, job_id))
            db.execute("UPDATE workers SET stop_deadline=? WHERE job_id=?", (now + grace, job_id))
        return True

    def collect_deleted(self) -> list[str]:
        """Remove deleted rows no worker holds any more; returns their ids (caller removes dirs)."""
        with self.transaction() as db:
            rows = db.execute("""SELECT id FROM jobs WHERE deleted_at IS NOT NULL
                                 AND id NOT IN (SELECT job_id FROM workers WHERE job_id IS NOT NULL)""").fetchall()
            ids = [r[0] for r in rows]
            db.executemany("DELETE FROM jobs WHERE id=?", [(i,) for i in ids])
        return ids

    # ------------------------------------------------------------------ workers
    def register_worker(self, worker_id: str, pid: int, backend: str) -> None:
        now = time.time()
        with self.connect() as db:
            db.execute("""INSERT INTO workers (id, host, pid, backend, started_at, heartbeat_at) VALUES (?, ?, ?, ?, ?, ?)
                          ON CONFLICT(id) DO UPDATE SET pid=excluded.pid, heartbeat_at=excluded.heartbeat_at,
                          job_id=NULL, stop_deadline=NULL""",
                       (worker_id, socket.gethostname(), int(pid), backend, now, now))

    def unregister_worker(self, worker_id: str) -> None:
        with self.connect() as db:
            db.execute("DELETE FROM workers WHERE id=?", (worker_id,))

    def workers(self) -> list[dict]:
        with self.connect() as db:
            return [dict(r) for r in db.execute("SELECT * FROM workers ORDER BY id").fetchall()]

    def worker_heartbeat(self, worker_id: str) -> bool:
        """Idle heartbeat; False if the worker row is gone (the reaper declared it dead)."""
        with self.connect() as db:
            cur = db.execute("UPDATE workers SET heartbeat_at=? WHERE id=?", (time.time(), worker_id))
            return cur.rowcount == 1

    def claim(self, worker_id: str) -> Job | None:
        """Atomically take the highest-priority, oldest queued job (or None)."""
        now = time.time()
        with self.connect() as db:
            # A read first: idle workers poll often, and a read takes no write lock.
            if db.execute(f"SELECT 1 FROM jobs WHERE {_CLAIMABLE} LIMIT 1").fetchone() is None:
                return None
        with self.transaction() as db:
            row = db.execute(
                """UPDATE jobs SET state='running', worker=?, heartbeat_at=?, updated_at=?,
                       started_at=COALESCE(started_at, ?), attempts=attempts+1, eta_seconds=NULL,
                       samples_per_second=NULL
                   WHERE id=(SELECT id FROM jobs WHERE """ + _CLAIMABLE + """ ORDER BY priority DESC, seq LIMIT 1)
                   RETURNING *""", (worker_id, now, now, now)).fetchone()
            if row is None:
                return None
            db.execute("UPDATE workers SET job_id=?, heartbeat_at=?, stop_deadline=NULL WHERE id=?",
                       (row["id"], now, worker_id))
        return Job.from_row(row)

    def pending_checks(self) -> list[Job]:
        """Queued, visible jobs whose asset check has not run, oldest first."""
        with self.connect() as db:
            rows = db.execute("""SELECT * FROM jobs WHERE asset_check='pending' AND state='queued'
                                 AND deleted_at IS NULL ORDER BY seq""").fetchall()
        return [Job.from_row(r) for r in rows]

    def check_done(self, job_id: str, error: str | None) -> bool:
        """Record a job's asset check: error None lets workers claim it; an error fails it at
        once (a permanent failure: no attempt is spent, nothing retries it). False when the job
        was canceled or deleted meanwhile."""
        now = time.time()
        with self.transaction() as db:
            if error is None:
                cur = db.execute("UPDATE jobs SET asset_check='done', updated_at=? WHERE id=? AND asset_check='pending'",
                                 (now, job_id))
            else:
                cur = db.execute("""UPDATE jobs SET asset_check='done', state='failed', error=?, finished_at=?,
                                     updated_at=? WHERE id=? AND asset_check='pending' AND state='queued'""",
                                 (error, now, now, job_id))
            return cur.rowcount == 1

    def heartbeat(self, job_id: str, worker_id: str, peak_memory: int | None = None) -> bool:
        """True while the worker still owns the running job; False means stop now.
        peak_memory: the worker's peak RSS (bytes) during this attempt, if known."""
        now = time.time()
        with self.connect() as db:
            cur = db.execute("""UPDATE jobs SET heartbeat_at=?, peak_memory=MAX(COALESCE(peak_memory, 0), COALESCE(?, 0))
                                WHERE id=? AND worker=? AND state='running' AND deleted_at IS NULL""",
                             (now, peak_memory, job_id, worker_id))
            db.execute("UPDATE workers SET heartbeat_at=? WHERE id=?", (now, worker_id))
            return cur.rowcount == 1

    def progress(self, job_id: str, worker_id: str, task: tuple[int, dict] | None = None, **fields) -> bool:
        """Update progress columns of a job this worker owns (progress, spp_done, spp_target,
        samples_per_second, eta_seconds, render_seconds); ``task``: (index, {progress,
        spp_done, render_seconds}) of the running frame task, in the same transaction."""
        bad = set(fields) - _PROGRESS_FIELDS
        if bad:
            raise ValueError(f"not progress fields: {sorted(bad)}")
        now = time.time()
        sets = ", ".join(_assign(k) for k in fields)
        with self.transaction() as db:
            cur = db.execute(f"""UPDATE jobs SET {sets}, heartbeat_at=?, updated_at=? WHERE id=? AND worker=?
                                 AND state='running'""", (*fields.values(), now, now, job_id, worker_id))
            if task is not None and cur.rowcount == 1:
                idx, values = task
                bad = set(values) - {"spp_done", "render_seconds", "progress"}
                if bad:
                    raise ValueError(f"not task fields: {sorted(bad)}")
                db.execute(f"UPDATE tasks SET {', '.join(f'{k}=?' for k in values)} WHERE job_id=? AND idx=? "
                           "AND state='running'", (*values.values(), job_id, int(idx)))
            return cur.rowcount == 1

    def finish(self, job_id: str, worker_id: str, state: str, *, error: str | None = None,
               result: dict | None = None, **fields) -> bool:
        """End an attempt: succeeded/failed, or back to queued (a retryable error, or a graceful
        worker shutdown with ``refund_attempt``). Only the owning worker can do it."""
        refund = bool(fields.pop("refund_attempt", False))
        bad = set(fields) - _PROGRESS_FIELDS
        if bad:
            raise ValueError(f"not progress fields: {sorted(bad)}")
        if state not in ("succeeded", "failed", "queued"):
            raise ValueError(f"a worker cannot move a job to {state!r}")
        now = time.time()
        requeue = state == "queued"
        sets = {
            "state": state,
            "updated_at": now,
            "finished_at": None if requeue else now,
            "eta_seconds": None,
            **fields,
        }
        assign = [_assign(k) for k in sets]
        args = list(sets.values())
        # A success clears the error text of earlier attempts; otherwise keep the last reason.
        assign.append("error=?" if state == "succeeded" else "error=COALESCE(?, error)")
        args.append(None if state == "succeeded" else error)
        if result is not None:
            assign.append("result=?")
            args.append(json.dumps(result))
        if requeue:
            assign += ["worker=NULL", "samples_per_second=NULL"]
        if refund:
            assign.append("attempts=MAX(attempts-1, 0)")
        with self.transaction() as db:
            cur = db.execute(f"UPDATE jobs SET {', '.join(assign)} WHERE id=? AND worker=? AND state='running'",
                             (*args, job_id, worker_id))
            db.execute("UPDATE workers SET job_id=NULL, stop_deadline=NULL WHERE id=?", (worker_id,))
            if cur.rowcount == 1:
                # A frame task still running ends with its job: back in the queue (the attempt
                # refunded too on a graceful shutdown), or failed with the job's reason.
                db.execute(f"""UPDATE tasks SET state=?, error=COALESCE(?, error), finished_at=?
                               {', attempts=MAX(attempts-1, 0)' if refund else ''}
                               WHERE job_id=? AND state='running'""",
                           ("queued" if requeue else "failed", None if state == "succeeded" else error,
                            None if requeue else now, job_id))
            if cur.rowcount == 1 and not requeue:
                _observe_end(db, job_id)
            return cur.rowcount == 1

    def release(self, worker_id: str) -> None:
        """The worker holds no job any more (after a cancel or a lost job)."""
        with self.connect() as db:
            db.execute("UPDATE workers SET job_id=NULL, stop_deadline=NULL WHERE id=?", (worker_id,))

    def workers_past_deadline(self) -> list[dict]:
        """Workers that were told to drop a canceled job and have not done so in time."""
        with self.connect() as db:
            rows = db.execute("""SELECT * FROM workers WHERE stop_deadline IS NOT NULL AND stop_deadline < ?
                                 AND job_id IS NOT NULL""", (time.time(),)).fetchall()
        return [dict(r) for r in rows]

    def worker_lost(self, worker_id: str, reason: str) -> list[str]:
        """A worker process is known dead: make its running job stale at once (the reaper then
        requeues or fails it), remember why, and drop the worker row. Returns the job ids."""
        now = time.time()
        with self.transaction() as db:
            rows = db.execute("SELECT id FROM jobs WHERE worker=? AND state='running'", (worker_id,)).fetchall()
            ids = [r[0] for r in rows]
            for job_id in ids:
                db.execute("UPDATE jobs SET heartbeat_at=0, error=?, updated_at=? WHERE id=?", (reason, now, job_id))
            db.execute("DELETE FROM workers WHERE id=?", (worker_id,))
        return ids

    # ------------------------------------------------------------------ reaper
    def reap(self, stale_after: float) -> list[tuple[str, str]]:
        """Requeue running jobs whose heartbeat is older than ``stale_after`` seconds, or fail
        them once attempts >= max_attempts. Also drops worker rows that stopped heartbeating.
        Returns [(job id, new state)]."""
        now = time.time()
        cutoff = now - stale_after
        changed = []
        with self.transaction() as db:
            rows = db.execute("""SELECT id, attempts - attempt_base AS run_attempt, max_attempts, error, heartbeat_at
                                 FROM jobs WHERE state='running' AND heartbeat_at < ?""", (cutoff,)).fetchall()
            for r in rows:
                task = db.execute("""SELECT idx, frame, attempts - attempt_base AS run_attempt FROM tasks
                                     WHERE job_id=? AND state='running'""", (r["id"],)).fetchone()
                if task is not None:
                    # A frame-range job lost on frame k: only frame k is retried (or fails, once
                    # its own attempts are spent); the job goes back to the queue for its other
                    # frames, and the next worker skips the frames already rendered.
                    why = r["error"] or f"worker lost: no heartbeat for {stale_after:g} s"
                    spent = task["run_attempt"] >= r["max_attempts"]
                    db.execute("UPDATE tasks SET state=?, error=?, finished_at=? WHERE job_id=? AND idx=?",
                               ("failed" if spent else "queued",
                                f"{why} (attempt {task['run_attempt']} of {r['max_attempts']}"
                                + ("; giving up)" if spent else ")"), now if spent else None, r["id"], task["idx"]))
                    db.execute("""UPDATE jobs SET state='queued', worker=NULL, updated_at=?, eta_seconds=NULL,
                                  samples_per_second=NULL WHERE id=?""", (now, r["id"]))
                    changed.append((r["id"], "queued"))
                elif r["run_attempt"] >= r["max_attempts"]:
                    why = r["error"] or f"worker lost: no heartbeat for {stale_after:g} s"
                    err = f"{why} (attempt {r['run_attempt']} of {r['max_attempts']}; giving up)"
                    db.execute("""UPDATE jobs SET state='failed', error=?, finished_at=?, updated_at=?,
                                  eta_seconds=NULL, samples_per_second=NULL WHERE id=?""", (err, now, now, r["id"]))
                    _observe_end(db, r["id"])
                    changed.append((r["id"], "failed"))
                else:
                    db.execute("""UPDATE jobs SET state='queued', worker=NULL, updated_at=?, eta_seconds=NULL,
                                  samples_per_second=NULL WHERE id=?""", (now, r["id"]))
                    changed.append((r["id"], "queued"))
                db.execute("UPDATE workers SET job_id=NULL, stop_deadline=NULL WHERE job_id=?", (r["id"],))
            db.execute("DELETE FROM workers WHERE heartbeat_at < ?", (cutoff,))
        return changed

    def set_meta(self, key: str, value: str) -> None:
        """Server settings workers need to know (e.g. the stage root their jobs are confined to)."""
        with self.connect() as db:
            db.execute("INSERT INTO meta (key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE SET value=excluded.value",
                       (key, str(value)))

    def get_meta(self, key: str) -> Optional[str]:
        with self.connect() as db:
            row = db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return row[0] if row is not None else None

    def integrity(self) -> str:
        """``PRAGMA integrity_check`` result ('ok' when the file is sound)."""
        with self.connect() as db:
            return db.execute("PRAGMA integrity_check").fetchone()[0]

    def histograms(self) -> dict:
        """{(name, kind): (cumulative [(upper bound, count)], sum)} over the current bucket
        bounds (HISTOGRAMS), the last bound being +Inf."""
        with self.connect() as db:
            rows = db.execute("SELECT name, kind, le, count, sum FROM histograms").fetchall()
        out: dict = {}
        for r in rows:
            bounds = HISTOGRAMS.get(r["name"])
            if bounds is None:
                continue
            counts, total = out.setdefault((r["name"], r["kind"]), ([0] * (len(bounds) + 1), [0.0]))
            # a row whose bound is not a current one (the bounds changed) joins the next larger bucket
            counts[_bucket(bounds, r["le"])] += int(r["count"])
            total[0] += float(r["sum"])
        result = {}
        for key, (counts, total) in out.items():
            bounds = HISTOGRAMS[key[0]]
            cum, run = [], 0
            for le, n in zip((*bounds, float("inf")), counts):
                run += n
                cum.append((le, run))
            result[key] = (cum, total[0])
        return result


# A job a worker may take: queued, checked, visible, and not still held by a worker that has not
# let go of it (a canceled job requeued before its old worker stopped).
_CLAIMABLE = ("state='queued' AND asset_check='done' AND deleted_at IS NULL "
              "AND id NOT IN (SELECT job_id FROM workers WHERE job_id IS NOT NULL)")


# The job is running under this worker (bound: job id, worker id).
_OWNED = "id=? AND worker=? AND state='running' AND deleted_at IS NULL"


def _assign(column: str) -> str:
    """SET clause of one progress column: a peak only grows (the largest over attempts)."""
    if column == "peak_memory":
        return "peak_memory=MAX(COALESCE(peak_memory, 0), COALESCE(?, 0))"
    return f"{column}=?"


def _bucket(bounds: tuple, value: float) -> int:
    """Index of the bucket holding ``value``: the first bound >= value, else the +Inf one."""
    import bisect

    return bisect.bisect_left(bounds, value)


def _observe(db: sqlite3.Connection, name: str, kind: str, value: float) -> None:
    bounds = HISTOGRAMS[name]
    i = _bucket(bounds, value)
    le = bounds[i] if i < len(bounds) else float("inf")
    db.execute("""INSERT INTO histograms (name, kind, le, count, sum) VALUES (?, ?, ?, 1, ?)
                  ON CONFLICT(name, kind, le) DO UPDATE SET count=count+1, sum=sum+excluded.sum""",
               (name, kind, le, float(value)))


def _observe_end(db: sqlite3.Connection, job_id: str) -> None:
    """A run of the job ended (in the caller's transaction): add its render time (successes)
    and its peak memory (when measured) to the histograms."""
    row = db.execute("SELECT kind, state, render_seconds, peak_memory FROM jobs WHERE id=?", (job_id,)).fetchone()
    if row is None:
        return
    if row["state"] == "succeeded":
        _observe(db, "render_seconds", row["kind"], float(row["render_seconds"] or 0.0))
    if row["peak_memory"]:
        _observe(db, "peak_memory_bytes", row["kind"], float(row["peak_memory"]))
