"""A small synchronous client for the render service (httpx), used by ``illum submit/jobs``.

Server errors become ``ServiceError`` carrying the status code and the server's one-line
``message``, so callers can print them as they are.
"""

from __future__ import annotations

import os
import time
from typing import Callable, Iterable, Optional

import httpx

__all__ = ["ServiceClient", "ServiceError", "DEFAULT_SERVER", "TERMINAL"]

DEFAULT_SERVER = "http://127.0.0.1:8765"
TERMINAL = ("succeeded", "failed", "canceled")


class ServiceError(Exception):
    """A non-2xx answer (status, message) or an unreachable server (status 0)."""

    def __init__(self, status: int, message: str):
        self.status = status
        self.message = message
        super().__init__(message)


class ServiceClient:
    """Talks to one server. ``token`` defaults to $ILLUM_TOKEN; use as a context manager."""

    def __init__(self, server: str | None = None, token: str | None = None, timeout: float = 30.0):
        self.server = (server or os.environ.get("ILLUM_SERVER") or DEFAULT_SERVER).rstrip("/")
        token = token if token is not None else os.environ.get("ILLUM_TOKEN")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.server, headers=headers, timeout=timeout)

    def __enter__(self) -> "ServiceClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.http.close()

    # ------------------------------------------------------------------ plumbing
    def _request(self, method: str, url: str, **kw) -> httpx.Response:
        try:
            r = self.http.request(method, url, **kw)
        except httpx.TransportError as e:
            raise ServiceError(0, f"cannot reach the render service at {self.server}: {e}") from None
        if r.status_code >= 400:
            try:
                body = r.json()
                msg = body.get("message") or str(body.get("detail"))
            except ValueError:
                msg = r.text.strip()[:300] or r.reason_phrase
            raise ServiceError(r.status_code, f"{msg} (HTTP {r.status_code})")
        return r

    # ------------------------------------------------------------------ API
    def health(self) -> dict:
        return self._request("GET", "/health").json()

    def upload(self, path: str) -> str:
        """Upload a stage file; returns the upload id for ``create_job(upload=...)``."""
        with open(path, "rb") as fh:
            r = self._request("POST", "/uploads", params={"filename": os.path.basename(path)}, content=fh.read(),
                              headers={"Content-Type": "application/octet-stream"})
        return r.json()["upload"]

    def create_job(self, *, stage: str | None = None, upload: str | None = None, kind: str = "render",
                   settings: dict | None = None, priority: int = 50, idempotency_key: str | None = None,
                   max_attempts: int | None = None) -> dict:
        body: dict = {"kind": kind, "settings": settings or {}, "priority": priority}
        if stage is not None:
            body["stage"] = stage
        if upload is not None:
            body["upload"] = upload
        if idempotency_key:
            body["idempotency_key"] = idempotency_key
        if max_attempts:
            body["max_attempts"] = max_attempts
        return self._request("POST", "/jobs", json=body).json()

    def get_job(self, job_id: str) -> dict:
        return self._request("GET", f"/jobs/{job_id}").json()

    def list_jobs(self, states: Iterable[str] | None = None, limit: int = 200, stage: str | None = None) -> dict:
        params: list = [("limit", limit)] + [("state", s) for s in (states or [])]
        if stage:
            params.append(("stage", stage))
        return self._request("GET", "/jobs", params=params).json()

    def set_priority(self, job_id: str, priority: int) -> dict:
        return self._request("PATCH", f"/jobs/{job_id}", json={"priority": priority}).json()

    def requeue(self, job_id: str, priority: int | None = None) -> dict:
        body = {} if priority is None else {"priority": priority}
        return self._request("POST", f"/jobs/{job_id}/requeue", json=body).json()

    def cancel(self, job_id: str) -> dict:
        return self._request("POST", f"/jobs/{job_id}/cancel").json()

    def delete(self, job_id: str) -> None:
        self._request("DELETE", f"/jobs/{job_id}")

    def log(self, job_id: str, tail: int = 0) -> str:
        return self._request("GET", f"/jobs/{job_id}/log", params={"tail": tail}).text

    def image(self, job_id: str, fmt: str = "exr") -> bytes:
        return self._request("GET", f"/jobs/{job_id}/image", params={"format": fmt}).content

    def wait(self, job_id: str, on_update: Optional[Callable[[dict], None]] = None, poll: float = 0.5,
             timeout: float | None = None) -> dict:
        """Poll until the job is succeeded, failed or canceled; returns the final job."""
        t0 = time.monotonic()
        while True:
            job = self.get_job(job_id)
            if on_update is not None:
                on_update(job)
            if job["state"] in TERMINAL:
                return job
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise ServiceError(0, f"job {job_id} still {job['state']} after {timeout:g} s")
            time.sleep(poll)
