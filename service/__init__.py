"""illum render service: a job queue over HTTP that runs renders in worker processes.

* ``service.store``       SQLite (WAL) job store: the single source of truth for jobs.
* ``service.app``         the FastAPI application (REST API, metrics, the web page).
* ``service.supervisor``  spawns and watches worker processes, runs the reaper.
* ``service.worker``      the worker entry point (``python -m service.worker``): claims jobs,
                          heartbeats, renders with progressive snapshots and checkpoints.
* ``service.ray_backend`` distributes one job's sample passes over a Ray cluster.
* ``service.assets``      keeps a job's files (layers, textures, IES files) inside the stage root:
                          checked at submission in a child process, and again by the worker.
* ``service.cli``         ``illum serve``, ``illum submit`` and ``illum jobs``.

See service/README.md for the API and the operational model.
"""

from __future__ import annotations

__all__ = ["API_VERSION"]

API_VERSION = "1"
