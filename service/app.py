"""The FastAPI application: REST API, Prometheus metrics and the web page.

The server process only validates requests, reads and writes the job store, and serves files.
It never renders: workers (service.worker) do, in their own processes, supervised by
service.supervisor. See service/README.md for the API reference.

Errors share one shape: ``{"detail": ..., "message": "one line naming the field"}``.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import os
import tempfile
import time
from typing import Literal, Optional

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import API_VERSION
from .assets import AssetChecker, CheckQueue
from .config import ServiceConfig
from .metrics import Metrics
from .models import (JobCreate, JobPatch, JobRequeue, check_stage_search, job_frames, request_hash,
                     validate_settings)
from .paths import (IMAGE_EXTENSIONS, STAGE_EXTENSIONS, InputError, check_magic, list_stages, resolve_in_root,
                    resolve_upload, upload_name)
from .store import STATES, IdempotencyConflict, Job, JobStore
from .supervisor import Supervisor, append_job_log
from .worker import (FINAL_DENOISED_PNG, FINAL_EXR, FINAL_PNG, JOB_LOG, PREVIEW_DENOISED_PNG, PREVIEW_EXR, PREVIEW_PNG,
                     STATS_JSON, THUMB_PNG, THUMB_SIZE, frame_dir)

__all__ = ["create_app"]

STATIC_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")
# The Swagger UI files /docs needs, served from the swagger-ui-py package: no CDN, so the docs
# work on an air-gapped farm. Without the package /docs answers 404 and /openapi.json remains.
SWAGGER_FILES = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
                 "favicon-32x32.png": "image/png"}
JOB_ID = r"^[0-9a-f]{16}$"
MEDIA = {"png": "image/png", "exr": "image/x-exr"}


class BodyTooLarge(HTTPException):
    """Raised from inside the body stream: FastAPI passes HTTPExceptions through untouched."""

    def __init__(self, limit: int):
        super().__init__(413, f"request body exceeds the server limit of {limit} bytes")


# Methods counted under their own name in /metrics; anything else a client invents is "other",
# so made-up methods cannot grow the counter table (and the metrics page) without bound.
_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


class _Limits:
    """Pure ASGI middleware: caps request bodies (by Content-Length up front, and by counting
    streamed bytes for chunked bodies) and counts responses for /metrics."""

    def __init__(self, app, config: ServiceConfig, metrics: Metrics):
        self.app = app
        self.config = config
        self.metrics = metrics

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        lim = self.config.limits
        limit = lim.max_upload_bytes if scope["path"] == "/uploads" else lim.max_json_bytes
        status_box = [500]

        async def counting_send(message):
            if message["type"] == "http.response.start":
                status_box[0] = message["status"]
            await send(message)

        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        try:
            if declared is not None and int(declared) > limit:
                resp = JSONResponse({"detail": f"request body exceeds the server limit of {limit} bytes",
                                     "message": f"body: {int(declared)} bytes exceed the limit of {limit}"},
                                    status_code=413)
                await resp(scope, receive, counting_send)
                return
        except ValueError:
            resp = JSONResponse({"detail": "bad Content-Length", "message": "bad Content-Length"}, status_code=400)
            await resp(scope, receive, counting_send)
            return
        seen = [0]

        async def limited_receive():
            message = await receive()
            if message["type"] == "http.request":
                seen[0] += len(message.get("body", b""))
                if seen[0] > limit:
                    raise BodyTooLarge(limit)
            return message

        try:
            await self.app(scope, limited_receive, counting_send)
        finally:
            method = scope.get("method", "")
            self.metrics.count_request(method if method in _METHODS else "other", status_box[0])


def create_app(config: ServiceConfig, *, start_workers: bool = True) -> FastAPI:
    """Build the application. ``start_workers=False`` runs the API alone (workers started
    elsewhere, or none)."""
    os.makedirs(config.jobs_dir, exist_ok=True)
    os.makedirs(config.uploads_dir, exist_ok=True)
    if not os.path.isdir(config.stage_root):
        raise ValueError(f"stage root {config.stage_root!r} is not a directory")
    store = JobStore(config.db_path)
    store.set_meta("stage_root", os.path.realpath(config.stage_root))  # for workers started by hand
    supervisor = Supervisor(config, store)
    assets = AssetChecker(config.stage_root, config.uploads_dir, timeout=config.asset_check_timeout)

    def refused(job: Job, message: str) -> None:
        d = os.path.join(config.jobs_dir, job.id)
        os.makedirs(d, exist_ok=True)
        append_job_log(d, f"[api] refused by the asset check: {message}")

    checks = CheckQueue(store, assets, on_refused=refused)
    started = time.time()
    metrics = Metrics(store, config.backend, started)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        checks.start()
        if start_workers:
            supervisor.start()
        try:
            yield
        finally:
            # Workers first: a running job checkpoints at once. A check still running is not
            # waited for: its job stays pending in the store, and its child dies with the server.
            if start_workers:
                await run_in_threadpool(supervisor.stop)
            await run_in_threadpool(checks.stop, 0.5)

    app = FastAPI(
        title="illum render service",
        version=API_VERSION,
        description=("Submit USD renders and dome preconvolutions, follow their progress, fetch progressive "
                     "and final images. Jobs live in SQLite (WAL); workers render in separate processes. "
                     "When the server runs with ILLUM_TOKEN set, every endpoint that reads or changes jobs, "
                     "stages or metrics needs `Authorization: Bearer <token>` (the Authorize button); "
                     "`/health` then answers only its status without the token."),
        lifespan=lifespan,
        docs_url=None,    # served below from local files
        redoc_url=None,
    )
    app.state.config = config
    app.state.store = store
    app.state.supervisor = supervisor
    app.add_middleware(_Limits, config=config, metrics=metrics)

    # ---------------------------------------------------------------- errors
    @app.exception_handler(InputError)
    async def _input_error(request: Request, exc: InputError):
        parts = exc.field.split(".") if exc.field else []
        loc = parts if parts[:1] in (["query"], ["path"]) else ["body", *parts]
        return JSONResponse({"detail": [{"loc": loc, "msg": exc.message, "type": "value_error"}],
                             "message": str(exc)}, status_code=exc.status)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        parts = []
        for e in errors:
            loc = [str(p) for p in e.get("loc", ()) if p not in ("body",)]
            parts.append(f"{'.'.join(loc)}: {e.get('msg')}" if loc else str(e.get("msg")))
        clean = [{"loc": list(e.get("loc", ())), "msg": e.get("msg"), "type": e.get("type")} for e in errors]
        return JSONResponse({"detail": clean, "message": "; ".join(parts)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)  # also the router's own 404/405
    async def _http_error(request: Request, exc: StarletteHTTPException):
        message = str(exc.detail)
        if exc.status_code == 400 and message == "There was an error parsing the body":
            # FastAPI's answer when the JSON parser itself gives up (e.g. nesting too deep)
            message = "body: not valid JSON (malformed or nested too deeply)"
        return JSONResponse({"detail": exc.detail, "message": message}, status_code=exc.status_code,
                            headers=getattr(exc, "headers", None))

    # ---------------------------------------------------------------- helpers
    bearer = HTTPBearer(auto_error=False, description="ILLUM_TOKEN, when the server was started with one")

    def token_ok(creds: Optional[HTTPAuthorizationCredentials]) -> bool:
        if not config.token:
            return True
        return creds is not None and hmac.compare_digest(creds.credentials.strip().encode("utf-8", "replace"),
                                                         config.token.encode())

    def require_token(creds: Optional[HTTPAuthorizationCredentials] = Depends(bearer)):
        # One policy for reads and writes: job data, images, logs, stage names and metrics are
        # the show's business too. Only the page shell, its static files, the API docs and the
        # bare health status stay open (the page is where a user types the token).
        if not token_ok(creds):
            raise HTTPException(401, "this server requires a bearer token (Authorization: Bearer <ILLUM_TOKEN>)",
                                headers={"WWW-Authenticate": "Bearer"})

    auth = [Depends(require_token)]

    def job_or_404(job_id: str) -> Job:
        job = store.get(job_id)
        if job is None:
            raise HTTPException(404, f"no job {job_id}")
        return job

    def api_log(job: Job, message: str) -> None:
        # The log tells the whole story, also for a job no worker has taken yet.
        d = config.job_dir(job.id)
        with contextlib.suppress(OSError):
            os.makedirs(d, exist_ok=True)
        append_job_log(d, f"[api] {message}")

    def job_json(job: Job, task_counts: Optional[dict] = None, tasks: Optional[list] = None) -> dict:
        """The API form of a job. A frame-range job also has ``frame_counts`` ({state: frames});
        ``tasks`` (its task rows) adds ``frames``, each frame's state, attempts and images."""
        out = job.public()
        out["frame_counts"] = task_counts
        if tasks is not None:
            out["frame_counts"] = {st: sum(t["state"] == st for t in tasks) for st in STATES} if tasks else None
            out["frames"] = [frame_json(job, t) for t in tasks] if tasks else None
        files = _listing(config.job_dir(job.id))
        has = {fmt: not files.isdisjoint(names)
               for fmt, names in (("png", (FINAL_PNG, PREVIEW_PNG)), ("exr", (FINAL_EXR, PREVIEW_EXR)))}
        started_at = job.row.get("started_at")
        out["elapsed_seconds"] = (None if started_at is None
                                  else max(0.0, (job.row.get("finished_at") or time.time()) - started_at))
        thumb = THUMB_PNG in files
        out["links"] = {"self": f"/jobs/{job.id}", "log": f"/jobs/{job.id}/log",
                        "image_png": f"/jobs/{job.id}/image?format=png" if has["png"] else None,
                        "image_denoised_png": (f"/jobs/{job.id}/image?format=png&denoised=true"
                                               if not files.isdisjoint((FINAL_DENOISED_PNG, PREVIEW_DENOISED_PNG))
                                               else None),
                        "image_exr": f"/jobs/{job.id}/image?format=exr" if has["exr"] else None,
                        "thumbnail": f"/jobs/{job.id}/thumbnail" if thumb else None}
        return out

    listed = _ListCache(job_json)

    def frame_json(job: Job, t: dict) -> dict:
        files = _listing(os.path.join(config.job_dir(job.id), frame_dir(t["idx"])))
        base = f"/jobs/{job.id}/frames/{t['idx']}/image"
        return {"index": t["idx"], "frame": t["frame"], "state": t["state"], "attempts": t["attempts"],
                "progress": t["progress"], "spp_done": t["spp_done"], "render_seconds": t["render_seconds"],
                "started_at": t["started_at"], "finished_at": t["finished_at"], "error": t["error"],
                "links": {"image_png": f"{base}?format=png" if FINAL_PNG in files else None,
                          "image_exr": f"{base}?format=exr" if FINAL_EXR in files else None}}

    def full_json(job: Job) -> dict:
        """One job as GET /jobs/{id} gives it: with its frames."""
        return job_json(job, tasks=store.tasks(job.id))

    # ---------------------------------------------------------------- pages
    @app.get("/", include_in_schema=False)
    def index():
        # The page loads only its own script and style, and previews as blob: URLs.
        return FileResponse(os.path.join(STATIC_DIR, "index.html"), headers={
            "Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; object-src 'none'; "
                                       "base-uri 'none'; frame-ancestors 'none'"})

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon():
        return Response(status_code=204)

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    swagger_dir = _swagger_dir()

    @app.get("/docs", include_in_schema=False)
    def docs():
        if swagger_dir is None:
            raise HTTPException(404, "the API docs page needs the swagger-ui-py package, which this server lacks; "
                                     "the OpenAPI schema is at /openapi.json")
        page = get_swagger_ui_html(openapi_url=app.openapi_url, title=f"{app.title} API",
                                   swagger_js_url="/docs/assets/swagger-ui-bundle.js",
                                   swagger_css_url="/docs/assets/swagger-ui.css",
                                   swagger_favicon_url="/docs/assets/favicon-32x32.png",
                                   # no call to the public validator service
                                   swagger_ui_parameters={"validatorUrl": None})
        page.headers["Cache-Control"] = "no-cache"
        page.headers["X-Content-Type-Options"] = "nosniff"
        return page

    @app.get("/docs/assets/{name}", include_in_schema=False)
    def docs_asset(name: str):
        if swagger_dir is None or name not in SWAGGER_FILES:
            raise HTTPException(404, f"no docs asset {name!r}")
        return FileResponse(os.path.join(swagger_dir, name), media_type=SWAGGER_FILES[name],
                            headers={"Cache-Control": "public, max-age=86400", "X-Content-Type-Options": "nosniff"})

    # ---------------------------------------------------------------- service
    @app.get("/health", summary="Liveness, workers and queue depth",
             description="Without the token (on a server that has one) only status, version and auth are given.")
    def health(creds: Optional[HTTPAuthorizationCredentials] = Depends(bearer)):
        alive = supervisor.alive() if start_workers else None
        status = "ok" if (not start_workers or not supervisor.slots or alive) else "degraded"
        if not token_ok(creds):  # liveness for probes; nothing about workers or jobs
            return {"status": status, "version": API_VERSION, "auth": True, "authorized": False}
        counts = store.counts()["states"]
        workers = store.workers()
        return {"status": status, "version": API_VERSION, "backend": config.backend,
                "uptime_seconds": time.time() - started,
                "workers": {"configured": len(supervisor.slots) if start_workers else 0, "alive": alive,
                            "registered": [{"id": w["id"], "pid": w["pid"], "host": w["host"], "job": w["job_id"]}
                                           for w in workers]},
                "jobs": counts, "auth": bool(config.token), "authorized": True}

    @app.get("/metrics", summary="Prometheus metrics (text exposition format 0.0.4)",
             response_class=PlainTextResponse, dependencies=auth)
    def metrics_page():
        body, content_type = metrics.exposition()
        return Response(body, media_type=content_type)

    @app.get("/stages", dependencies=auth,
             summary="Stages (or, for kind=preconvolve, environment maps) under the stage root")
    def stages(kind: Literal["render", "preconvolve"] = "render"):
        exts = STAGE_EXTENSIONS if kind == "render" else IMAGE_EXTENSIONS
        return {"kind": kind, "stages": list_stages(config.stage_root, exts)}

    # ---------------------------------------------------------------- uploads
    @app.post("/uploads", status_code=201, dependencies=auth,
              summary="Upload a .usda/.usdc/.usdz stage as the raw request body",
              description=("Send the file as the body (`Content-Type: application/octet-stream`) with "
                           "`?filename=shot.usdz`. Answers an `upload` id to pass in `POST /jobs`. The size is "
                           "capped (413). Only self-contained files make sense: references to other files "
                           "resolve next to the stored upload, i.e. not at all; prefer .usdz."))
    async def upload(request: Request, filename: str = Query(..., min_length=1, max_length=255)):
        probe = upload_name("0" * 64, filename)  # validates the name before reading the body
        del probe
        hasher = hashlib.sha256()
        head = b""
        size = 0
        fd, tmp = tempfile.mkstemp(prefix=".upload-", dir=config.uploads_dir)
        try:
            with os.fdopen(fd, "wb") as fh:
                async for chunk in request.stream():
                    if not chunk:
                        continue
                    size += len(chunk)
                    if size > config.limits.max_upload_bytes:
                        raise BodyTooLarge(config.limits.max_upload_bytes)
                    if len(head) < 16:
                        head = (head + chunk)[:16]
                    hasher.update(chunk)
                    await run_in_threadpool(fh.write, chunk)  # keep the event loop free
            if size == 0:
                raise InputError(400, "body", "the upload is empty")
            check_magic(head, filename)
            upload_id = upload_name(hasher.hexdigest(), filename)
            os.replace(tmp, os.path.join(config.uploads_dir, upload_id))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return {"upload": upload_id, "size": size, "sha256": hasher.hexdigest()}

    # ---------------------------------------------------------------- jobs
    @app.post("/jobs", status_code=201, dependencies=auth, summary="Create a job",
              responses={200: {"description": "idempotent replay: the job created earlier with this key"},
                         400: {"description": "bad stage path or upload id, or an idempotency key in the body "
                                               "that differs from the Idempotency-Key header"},
                         409: {"description": "idempotency key reused with a different request"},
                         413: {"description": "body too large"},
                         422: {"description": "invalid or over-limit settings (the field is named)"}})
    def create_job(body: JobCreate, response: Response,
                   idempotency_key: Optional[str] = Header(None, alias="Idempotency-Key", max_length=255)):
        if body.idempotency_key is not None and idempotency_key is not None and body.idempotency_key != idempotency_key:
            raise InputError(400, "idempotency_key", "the body's idempotency_key differs from the Idempotency-Key "
                             "header; send one, or the same key in both")
        key = body.idempotency_key or idempotency_key
        if (body.stage is None) == (body.upload is None):
            raise InputError(422, "stage", "give exactly one of 'stage' (a path under the stage root) and 'upload'")
        if body.upload is not None:
            if body.kind != "render":
                raise InputError(422, "upload", "only render jobs take uploaded stages")
            path, name = resolve_upload(config.uploads_dir, body.upload)
        else:
            exts = STAGE_EXTENSIONS if body.kind == "render" else IMAGE_EXTENSIONS
            path, name = resolve_in_root(config.stage_root, body.stage, exts)
        settings = validate_settings(body.kind, body.settings, config.limits)
        frames = job_frames(settings) if body.kind == "render" else None
        max_attempts = body.max_attempts or config.max_attempts
        digest = request_hash(body.kind, name, settings, body.priority, max_attempts)
        try:
            job, created = store.create(kind=body.kind, stage=path, stage_name=name, settings=settings,
                                        priority=body.priority, max_attempts=max_attempts,
                                        idempotency_key=key, request_hash=digest,
                                        check_pending=body.kind == "render", frames=frames)
        except IdempotencyConflict as e:
            raise HTTPException(409, str(e)) from None
        if created and body.kind == "render":
            # Files the stage would read outside the stage root (layers, references, textures, IES
            # files...) are looked for by the checker threads, off this request thread; a refused
            # job fails naming layer, prim, attribute and path. The worker checks again.
            checks.notify()
        response.headers["Location"] = f"/jobs/{job.id}"
        if not created:
            response.status_code = 200
            response.headers["Idempotent-Replayed"] = "true"
        return full_json(job)

    @app.get("/jobs", dependencies=auth, summary="List jobs, newest first",
             description="Filter by one or more `state`s and by `stage`: text the stage name contains (plain "
                         "text, case-blind for ASCII letters).")
    def list_jobs(state: Optional[list[Literal["queued", "running", "succeeded", "failed", "canceled"]]] = Query(None),
                  stage: Optional[str] = Query(None, description="text the stage name contains"),
                  limit: int = Query(200, ge=1, le=1000), offset: int = Query(0, ge=0, le=2**62)):
        rows, total = store.list_rows(states=state, limit=limit, offset=offset, stage=check_stage_search(stage))
        counts = store.task_counts([r["id"] for r in rows])
        texts = [listed.text(r, counts.get(r["id"])) for r in rows]
        listed.trim()
        # The body is assembled from each job's JSON text (FastAPI's generic encoder, which walked
        # every value of every job, was half of this endpoint's time; #21 item 3).
        body = '{"jobs":[' + ",".join(texts) + f'],"count":{len(rows)},"total":{total}}}'
        return Response(body.encode(), media_type="application/json")

    @app.get("/jobs/{job_id}", dependencies=auth,
             summary="One job: state, progress %, spp, samples/s, ETA, error, attempts")
    def get_job(job_id: str = Path(..., pattern=JOB_ID)):
        return full_json(job_or_404(job_id))

    @app.get("/jobs/{job_id}/frames/{index}/image", dependencies=auth,
             summary="One frame of a frame-range job: its final image",
             responses={200: {"content": {"image/png": {}, "image/x-exr": {}}},
                        404: {"description": "no such frame, or not rendered yet"}})
    def frame_image(job_id: str = Path(..., pattern=JOB_ID), index: int = Path(..., ge=0, le=10**9),
                    format: Literal["png", "exr"] = "png",
                    t: Optional[str] = Query(None, description="ignored; lets pages defeat caches")):
        job = job_or_404(job_id)
        tasks = store.tasks(job.id)
        if index >= len(tasks):
            raise HTTPException(404, f"job {job.id} has no frame index {index} ({len(tasks)} frames)")
        path = os.path.join(config.job_dir(job.id), frame_dir(index), FINAL_EXR if format == "exr" else FINAL_PNG)
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except FileNotFoundError:
            raise HTTPException(404, f"frame {tasks[index]['frame']:g} of job {job.id} has no image yet "
                                     f"(state {tasks[index]['state']})") from None
        return Response(data, media_type=MEDIA[format], headers={
            "Cache-Control": "no-store", "X-Illum-Image": "frame", "X-Illum-Frame": f"{tasks[index]['frame']:g}",
            "X-Illum-Spp": str(tasks[index]["spp_done"]), "X-Illum-State": tasks[index]["state"],
            "Content-Disposition": f'inline; filename="{job.id}.{index:04d}.{format}"'})

    @app.get("/jobs/{job_id}/image", dependencies=auth, summary="The final image, else the latest progressive snapshot",
             responses={200: {"content": {"image/png": {}, "image/x-exr": {}}},
                        404: {"description": "no image yet"}})
    def job_image(job_id: str = Path(..., pattern=JOB_ID), format: Literal["png", "exr"] = "png",
                  denoised: bool = Query(False, description="the OIDN-denoised beauty (a job with settings.denoise; "
                                                            "PNG only: the final EXR holds it as its 'denoised' layer)"),
                  t: Optional[str] = Query(None, description="ignored; lets pages defeat caches")):
        job = job_or_404(job_id)
        d = config.job_dir(job.id)
        if denoised and format != "png":
            raise InputError(422, "query.denoised", "the denoised image is served as PNG; the final EXR holds it as "
                                                    "its 'denoised' layer")
        if denoised and not job.settings.get("denoise"):
            raise HTTPException(404, f"job {job.id} does not denoise (settings.denoise is false)")
        final, preview = ((FINAL_DENOISED_PNG, PREVIEW_DENOISED_PNG) if denoised
                          else (FINAL_PNG, PREVIEW_PNG) if format == "png" else (FINAL_EXR, PREVIEW_EXR))
        for name, kind in ((final, "final"), (preview, "preview")):
            try:
                fh = open(os.path.join(d, name), "rb")
            except FileNotFoundError:
                continue
            # Open once and read from that descriptor: the preview is replaced (renamed over)
            # every few seconds, and a stat-then-open would race with that.
            headers = {"Cache-Control": "no-store", "X-Illum-Image": kind,
                       "X-Illum-Spp": str(job.row.get("spp_done") or 0), "X-Illum-State": job.state,
                       "Content-Disposition": f'inline; filename="{job.id}.{format}"'}
            size = os.fstat(fh.fileno()).st_size
            if size <= 64 * 1024 * 1024:
                with fh:
                    return Response(fh.read(), media_type=MEDIA[format], headers=headers)
            headers["Content-Length"] = str(size)
            return StreamingResponse(_iter_file(fh), media_type=MEDIA[format], headers=headers)
        raise HTTPException(404, f"job {job.id} has no image yet (state {job.state})")

    @app.get("/jobs/{job_id}/thumbnail", dependencies=auth,
             summary=f"A small sRGB PNG of the job's latest image (at most {THUMB_SIZE} px on its longer side)",
             responses={200: {"content": {"image/png": {}}}, 404: {"description": "no image yet"}})
    def job_thumbnail(job_id: str = Path(..., pattern=JOB_ID),
                      t: Optional[str] = Query(None, description="ignored; lets pages defeat caches")):
        job = job_or_404(job_id)
        try:
            with open(os.path.join(config.job_dir(job.id), THUMB_PNG), "rb") as fh:  # replaced by rename
                data = fh.read()
        except FileNotFoundError:
            raise HTTPException(404, f"job {job.id} has no image yet (state {job.state})") from None
        return Response(data, media_type="image/png", headers={
            "Cache-Control": "no-store", "X-Illum-Spp": str(job.row.get("spp_done") or 0), "X-Illum-State": job.state})

    @app.get("/jobs/{job_id}/log", dependencies=auth, summary="The job's log (attempts, progress, errors)",
             response_class=PlainTextResponse)
    def job_log(job_id: str = Path(..., pattern=JOB_ID), tail: int = Query(0, ge=0, le=100_000,
                                                                          description="last N lines; 0 = all")):
        job = job_or_404(job_id)
        path = os.path.join(config.job_dir(job.id), JOB_LOG)
        try:
            with open(path, "rb") as fh:
                fh.seek(0, os.SEEK_END)
                n = fh.tell()
                fh.seek(max(0, n - 4 * 1024 * 1024))  # the last 4 MiB at most
                text = fh.read().decode("utf-8", errors="replace")
        except FileNotFoundError:
            text = ""
        if tail:
            text = "".join(text.splitlines(keepends=True)[-tail:])
        return PlainTextResponse(text, headers={"Cache-Control": "no-store"})

    @app.get("/jobs/{job_id}/stats", dependencies=auth, summary="Render statistics of a succeeded render job (JSON)")
    def job_stats(job_id: str = Path(..., pattern=JOB_ID)):
        job = job_or_404(job_id)
        path = os.path.join(config.job_dir(job.id), STATS_JSON)
        if not os.path.exists(path):
            raise HTTPException(404, f"job {job.id} has no statistics (state {job.state})")
        return FileResponse(path, media_type="application/json")

    @app.post("/jobs/{job_id}/cancel", dependencies=auth, summary="Cancel a queued or running job",
              responses={409: {"description": "the job already finished"}})
    def cancel_job(job_id: str = Path(..., pattern=JOB_ID)):
        job = store.cancel(job_id, grace=config.cancel_grace)
        if job is None:
            raise HTTPException(404, f"no job {job_id}")
        if job.state in ("succeeded", "failed"):
            raise HTTPException(409, f"job {job_id} already {job.state}")
        api_log(job, f"canceled by request (attempts so far: {job.attempts})")
        return full_json(job)

    @app.patch("/jobs/{job_id}", dependencies=auth, summary="Change a queued or running job's priority",
               description="The queue takes the new priority into account at once: workers claim the highest "
                           "priority first, the oldest first among equals.",
               responses={409: {"description": "the job already finished (requeue it instead)"}})
    def patch_job(body: JobPatch, job_id: str = Path(..., pattern=JOB_ID)):
        job, changed = store.set_priority(job_id, body.priority)
        if job is None:
            raise HTTPException(404, f"no job {job_id}")
        if not changed:
            raise HTTPException(409, f"job {job_id} already {job.state}: only queued or running jobs take a new "
                                     "priority (requeue it with one)")
        api_log(job, f"priority set to {body.priority}")
        return full_json(job)

    @app.post("/jobs/{job_id}/requeue", dependencies=auth, summary="Run a failed or canceled job again",
              description=("The job goes back to `queued` with a fresh allowance of `max_attempts` attempts, "
                           "resuming from its last checkpoint if one is left. `attempts` keeps counting, the log "
                           "keeps the history, `requeues` counts the requeues. Repeating the request while the "
                           "job is queued or running changes nothing (200)."),
              responses={409: {"description": "the job succeeded"}})
    def requeue_job(job_id: str = Path(..., pattern=JOB_ID), body: Optional[JobRequeue] = None):
        priority = body.priority if body is not None else None
        job, requeued = store.requeue(job_id, priority)
        if job is None:
            raise HTTPException(404, f"no job {job_id}")
        if job.state == "succeeded":
            raise HTTPException(409, f"job {job_id} already succeeded; submit it again to render it again")
        if requeued:
            if job.kind == "render":
                checks.notify()
            api_log(job, f"requeued by request (requeue {job.row['requeues']}, {job.attempts} attempts "
                              f"so far; a fresh {job.max_attempts} attempts"
                              + (f", priority {job.priority}" if priority is not None else "") + ")")
        return full_json(job)

    @app.delete("/jobs/{job_id}", status_code=204, dependencies=auth,
                summary="Delete a job and its files (a running job is canceled first)")
    def delete_job(job_id: str = Path(..., pattern=JOB_ID)):
        if not store.delete(job_id, grace=config.cancel_grace):
            raise HTTPException(404, f"no job {job_id}")
        return Response(status_code=204)

    return app


def _listing(directory: str) -> set:
    """The names in a job's (or frame's) directory: one read instead of a stat per file, since
    the job list builds links for every row. Empty before anything is written (or once removed)."""
    try:
        return set(os.listdir(directory))
    except OSError:
        return set()


def _dumps(obj) -> str:
    """JSON text as Starlette's JSONResponse writes it."""
    return json.dumps(obj, ensure_ascii=False, allow_nan=False, separators=(",", ":"))


class _ListCache:
    """The JSON text of each job GET /jobs listed, reused while its row and frame counts are
    unchanged: the page polls the list every second, and under load (#21 item 3) decoding each
    row's settings, reading its directory and encoding it again was most of the endpoint's time.

    A job's image links follow its files, which a worker writes between two writes of the row
    (progress, heartbeat every ``--heartbeat-interval``): a running job's links are at most one
    heartbeat late. A job with a start and no end (running) has its elapsed time computed anew on
    each listing; only its decoding and its files are reused. Safe across request threads (a
    race only encodes a job twice)."""

    MAX = 10_000

    def __init__(self, encode):
        self.encode = encode            # (Job, frame counts) -> the API dict (job_json)
        self.entries: dict = {}         # id -> (row values, frame counts, API dict, text or None)

    def text(self, row, counts: Optional[dict]) -> str:
        key = (tuple(row), None if counts is None else tuple(sorted(counts.items())))
        hit = self.entries.get(row["id"])
        if hit is None or hit[0] != key:
            out = self.encode(Job.from_row(row), counts)
            live = row["started_at"] is not None and row["finished_at"] is None
            hit = (key, out, None if live else _dumps(out))
            self.entries[row["id"]] = hit
        if hit[2] is not None:
            return hit[2]
        out = dict(hit[1])
        out["elapsed_seconds"] = max(0.0, time.time() - row["started_at"])
        return _dumps(out)

    def trim(self) -> None:
        if len(self.entries) > self.MAX:   # deleted jobs and old pages: start afresh
            self.entries.clear()


def _swagger_dir() -> Optional[str]:
    """The static directory of the installed swagger-ui-py package, or None. Found without
    importing the package (its __init__ pulls in handlers for other web frameworks)."""
    import importlib.util

    try:
        spec = importlib.util.find_spec("swagger_ui")
    except (ImportError, ValueError):
        return None
    for base in (spec.submodule_search_locations or []) if spec else []:
        d = os.path.join(base, "static")
        if all(os.path.isfile(os.path.join(d, n)) for n in SWAGGER_FILES):
            return d
    return None


def _iter_file(fh, chunk: int = 256 * 1024):
    with fh:
        while True:
            data = fh.read(chunk)
            if not data:
                break
            yield data

