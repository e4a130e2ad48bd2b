"""``illum serve``, ``illum submit`` and ``illum jobs`` (registered by renderer.cli).

Exit codes follow ``illum render``: 0 success, 2 a user-facing error (a refused request, a failed
job; one line), 1 an internal error; ``submit --wait`` returns 3 when the job was canceled.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import os
import socket
import sys
import time

__all__ = ["register_cli"]


def register_cli(subparsers) -> None:
    """Add the service subcommands to the ``illum`` parser."""
    from renderer.cli import add_render_flags

    s = subparsers.add_parser("serve", help="run the render service (HTTP API, web page, workers)",
                              description="Run the render service: REST API (docs at /docs), the web page at /, "
                                          "and worker processes. Set ILLUM_TOKEN to require a bearer token on "
                                          "every endpoint that reads or changes jobs.")
    s.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    s.add_argument("--port", type=int, default=8765, help="port (default 8765; 0 picks a free one)")
    s.add_argument("--data", default=os.environ.get("ILLUM_DATA", "illum-data"),
                   help="data directory: jobs.db, job outputs, uploads (default $ILLUM_DATA or ./illum-data)")
    s.add_argument("--stage-root", default=".", help="the only directory stages may be read from (default .)")
    s.add_argument("--workers", type=int, default=1, help="worker processes, each rendering one job (default 1)")
    s.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="local: render in the worker process; ray: spread each job's passes over a Ray cluster")
    s.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray)")
    s.add_argument("--ray-actors", type=int, default=None, help="Ray actors per job (default: the cluster's CPUs)")
    s.add_argument("--threads", type=int, default=None, help="render threads per worker (default: cores / workers)")
    s.add_argument("--max-attempts", type=int, default=3, help="attempts before a job fails (default 3)")
    s.add_argument("--heartbeat-timeout", type=float, default=15.0,
                   help="seconds without a heartbeat before the reaper requeues a job (default 15)")
    s.add_argument("--snapshot-interval", type=float, default=2.0,
                   help="seconds between progressive snapshots and checkpoints (default 2)")
    s.add_argument("--max-spp", type=int, default=65536)
    s.add_argument("--max-time", type=float, default=24 * 3600.0, help="max render seconds per job (default 86400)")
    s.add_argument("--max-time-grace", type=float, default=600.0, metavar="SECONDS",
                   help="seconds a job may run beyond --max-time (loading, compiling, writing) before its worker "
                        "is killed and the job failed, heartbeats or not (default 600)")
    s.add_argument("--max-job-memory", type=_size, default=None, metavar="SIZE",
                   help="memory one job may use (8G, 512M): its render's --max-memory cap, and with headroom its "
                        "worker's hard address-space limit (default 80%% of the machine's memory / --workers)")
    s.add_argument("--max-resolution", type=int, default=8192, help="max pixels per image side (default 8192)")
    s.add_argument("--max-upload-mb", type=float, default=256.0, help="max upload size in MiB (default 256)")
    s.add_argument("--asset-check-timeout", type=float, default=60.0,
                   help="seconds the submission-time check of a stage's files may take; beyond it the "
                        "worker's own check decides (default 60)")
    s.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    s.set_defaults(func=cmd_serve)

    sub = subparsers.add_parser("submit", help="submit a render job to a render service",
                                description="Submit STAGE (a path under the server's stage root, or a local file "
                                            "with --upload) to the render service.")
    sub.add_argument("stage", help="stage path relative to the server's --stage-root (or a local file with --upload)")
    sub.add_argument("--server", default=None, help="service URL (default $ILLUM_SERVER or http://127.0.0.1:8765)")
    sub.add_argument("--upload", action="store_true", help="upload the local file (self-contained .usda/.usdc/.usdz)")
    sub.add_argument("--kind", choices=("render", "preconvolve"), default="render")
    sub.add_argument("--priority", type=int, default=50, help="0-100, higher runs first (default 50)")
    sub.add_argument("--idempotency-key", default=None, help="resubmitting with the same key never duplicates the job")
    sub.add_argument("--max-attempts", type=int, default=None)
    sub.add_argument("--size", type=int, default=None, help="preconvolve: output size")
    sub.add_argument("--method", choices=("exact", "sh"), default=None, help="preconvolve: method")
    sub.add_argument("--wait", action="store_true", help="follow the job with a progress bar until it ends")
    sub.add_argument("-o", "--output", default=None, help="download the final image here (.exr or .png; implies --wait)")
    sub.add_argument("--quiet", action="store_true")
    add_render_flags(sub, "submit")
    add_render_flags(sub, "submit", ranges=True)   # a range is one job, a task per frame
    sub.set_defaults(func=cmd_submit)

    j = subparsers.add_parser("jobs", help="list a render service's jobs (or show, cancel, delete one)")
    j.add_argument("job", nargs="?", help="a job id: show it")
    j.add_argument("--server", default=None, help="service URL (default $ILLUM_SERVER or http://127.0.0.1:8765)")
    j.add_argument("--state", action="append", choices=("queued", "running", "succeeded", "failed", "canceled"),
                   help="only jobs in this state (repeatable)")
    j.add_argument("--stage", default=None, metavar="TEXT", help="only jobs whose stage name contains TEXT")
    j.add_argument("--limit", type=int, default=50)
    j.add_argument("--json", action="store_true", help="print JSON")
    j.add_argument("--cancel", action="store_true", help="cancel JOB")
    j.add_argument("--delete", action="store_true", help="delete JOB and its files")
    j.add_argument("--log", action="store_true", help="print JOB's log")
    j.add_argument("--requeue", action="store_true", help="run a failed or canceled JOB again (with --priority: at it)")
    j.add_argument("--priority", type=int, default=None, metavar="P",
                   help="set a queued or running JOB's priority (0-100, higher runs first)")
    j.set_defaults(func=cmd_jobs)


# ------------------------------------------------------------------------------ serve
def _size(text: str) -> int:
    from renderer.memory import parse_size

    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cmd_serve(a) -> int:
    import logging

    import uvicorn

    from renderer.errors import SettingsError

    from .app import create_app
    from .config import Limits, ServiceConfig

    if not os.path.isdir(a.stage_root):
        raise SettingsError(f"{a.stage_root!r} is not a directory", attribute="stage-root")
    if a.backend == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:  # fail now, not in every worker
            raise SettingsError("the ray backend needs Ray: pip install 'illum[ray]'", attribute="backend")
    limits = Limits(max_spp=a.max_spp, max_time_budget=a.max_time, max_side=a.max_resolution,
                    max_pixels=min(a.max_resolution * a.max_resolution, 8192 * 8192),
                    max_upload_bytes=int(a.max_upload_mb * 1024 * 1024))
    try:
        config = ServiceConfig(data_dir=os.path.abspath(a.data), stage_root=os.path.abspath(a.stage_root),
                               workers=a.workers, backend=a.backend, ray_address=a.ray_address,
                               ray_actors=a.ray_actors, threads=a.threads, max_attempts=a.max_attempts,
                               heartbeat_timeout=a.heartbeat_timeout, snapshot_interval=a.snapshot_interval,
                               token=os.environ.get("ILLUM_TOKEN") or None, limits=limits,
                               asset_check_timeout=a.asset_check_timeout, job_memory=a.max_job_memory,
                               max_time_grace=a.max_time_grace)
    except ValueError as e:
        raise SettingsError(str(e), attribute="serve") from None
    logging.basicConfig(level=a.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if not _is_loopback(a.host) and not config.token:
        print(f"illum: warning: serving on {a.host} without ILLUM_TOKEN: anyone who reaches this port can "
              "submit, read, cancel and delete jobs", file=sys.stderr)
    try:
        sock = _bind(a.host, a.port)
    except OSError as e:
        raise SettingsError(f"cannot listen on {a.host}:{a.port}: {e.strerror}", attribute="port") from None
    port = sock.getsockname()[1]
    host = f"[{a.host}]" if ":" in a.host else a.host
    url = f"http://{host}:{port}"
    app = create_app(config)
    os.makedirs(config.data_dir, exist_ok=True)
    with open(os.path.join(config.data_dir, "server.json"), "w", encoding="utf-8") as fh:
        json.dump({"url": url, "pid": os.getpid(), "started_at": time.time()}, fh)
    print(f"illum: serving on {url} (data {config.data_dir}, stage root {config.stage_root}, "
          f"{len(app.state.supervisor.slots)} {config.backend} worker(s); API docs at {url}/docs)", flush=True)
    server = uvicorn.Server(uvicorn.Config(app, log_level=a.log_level, access_log=a.log_level == "debug",
                                           timeout_graceful_shutdown=5))
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
    return 0


# ------------------------------------------------------------------------------ client side
class _Bar:
    """tqdm on a TTY, ``ALF_PROGRESS nn%`` lines otherwise (the farm convention)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.bar = None
        self.last = -1

    def __call__(self, job: dict) -> None:
        if self.quiet:
            return
        pct = int(job.get("progress") or 0)
        if self.tty:
            if self.bar is None:
                from tqdm import tqdm

                self.bar = tqdm(total=100, unit="%", desc=f"job {job['id']}", file=sys.stderr,
                                bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix}")
            self.bar.n = pct
            eta = job.get("eta_seconds")
            sps = job.get("samples_per_second")
            self.bar.set_postfix_str(f"{job['state']}, {job.get('spp_done', 0)} spp"
                                     + (f", {sps / 1e3:.0f} ks/s" if sps else "")
                                     + (f", ETA {eta:.0f} s" if eta is not None else ""), refresh=False)
            self.bar.refresh()
        elif pct != self.last:
            print(f"ALF_PROGRESS {pct}%", flush=True)
            self.last = pct

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _client(a):
    from .client import ServiceClient

    return ServiceClient(a.server)


def _raise_user(e) -> None:
    from renderer.errors import IllumError

    raise IllumError(e.message) from None


def cmd_submit(a) -> int:
    from renderer.cli import options_from_args

    from .client import ServiceError
    from .models import range_settings, settings_from_options

    if a.kind == "render":
        settings = {**settings_from_options(options_from_args(a, "submit")), **range_settings(a)}
    else:
        settings = {k: v for k, v in (("size", a.size), ("method", a.method)) if v is not None}
    with _client(a) as client:
        try:
            upload = client.upload(a.stage) if a.upload else None
            job = client.create_job(stage=None if a.upload else a.stage, upload=upload, kind=a.kind,
                                    settings=settings, priority=a.priority, idempotency_key=a.idempotency_key,
                                    max_attempts=a.max_attempts)
        except (ServiceError, OSError) as e:
            _raise_user(e if isinstance(e, ServiceError) else ServiceError(0, f"{a.stage}: {e.strerror}"))
        if not a.quiet:
            print(f"illum: job {job['id']} {job['state']} ({client.server}/jobs/{job['id']})", file=sys.stderr)
        else:
            print(job["id"])
        if not (a.wait or a.output):
            if not a.quiet:
                print(job["id"])
            return 0
        bar = _Bar(a.quiet)
        try:
            job = client.wait(job["id"], on_update=bar)
        except KeyboardInterrupt:
            bar.close()
            print(f"illum: detached; job {job['id']} continues on the server", file=sys.stderr)
            return 130
        except ServiceError as e:
            bar.close()
            _raise_user(e)
        bar.close()
        if job["state"] == "failed":
            _raise_user(ServiceError(0, f"job {job['id']} failed: {job.get('error')}"))
        if job["state"] == "canceled":
            print(f"illum: job {job['id']} was canceled", file=sys.stderr)
            return 3
        if a.output:
            fmt = "png" if a.output.lower().endswith(".png") else "exr"
            data = client.image(job["id"], fmt)
            d = os.path.dirname(os.path.abspath(a.output))
            os.makedirs(d, exist_ok=True)
            tmp = a.output + ".part"
            with open(tmp, "wb") as fh:
                fh.write(data)
            os.replace(tmp, a.output)
        if not a.quiet:
            r = job.get("result") or {}
            print(f"illum: job {job['id']} succeeded ({job.get('spp_done')} spp, "
                  f"{r.get('render_seconds', 0):.1f} s)" + (f"; wrote {a.output}" if a.output else ""),
                  file=sys.stderr)
    return 0


def _age(t: float | None) -> str:
    if not t:
        return "-"
    s = max(0.0, time.time() - t)
    return f"{s:.0f}s" if s < 120 else f"{s / 60:.0f}m" if s < 7200 else f"{s / 3600:.0f}h"


def cmd_jobs(a) -> int:
    from .client import ServiceError

    with _client(a) as client:
        try:
            if a.job:
                if a.cancel:
                    out = client.cancel(a.job)
                elif a.delete:
                    client.delete(a.job)
                    print(f"illum: deleted job {a.job}", file=sys.stderr)
                    return 0
                elif a.log:
                    sys.stdout.write(client.log(a.job))
                    return 0
                elif a.requeue:
                    out = client.requeue(a.job, a.priority)
                elif a.priority is not None:
                    out = client.set_priority(a.job, a.priority)
                else:
                    out = client.get_job(a.job)
                print(json.dumps(out, indent=2, sort_keys=True))
                return 0
            if a.cancel or a.delete or a.log or a.requeue or a.priority is not None:
                _raise_user(ServiceError(0, "--cancel, --delete, --log, --requeue and --priority need a job id"))
            listing = client.list_jobs(a.state, limit=a.limit, stage=a.stage)
        except ServiceError as e:
            _raise_user(e)
    if a.json:
        print(json.dumps(listing, indent=2, sort_keys=True))
        return 0
    from renderer.memory import format_size

    rows = [("ID", "STATE", "PROGRESS", "SPP", "PRIO", "TRIES", "ELAPSED", "PEAK MEM", "AGE", "STAGE", "ERROR")]
    for j in listing["jobs"]:
        tries = f"{j['attempts']}/{j['max_attempts']}" + (f" +{j['requeues']}rq" if j.get("requeues") else "")
        elapsed = j.get("elapsed_seconds")
        progress = f"{j.get('progress') or 0:.0f}%"
        fc = j.get("frame_counts")
        if fc:   # a frame range: frames ended / frames
            progress += f" ({fc['succeeded'] + fc['failed']}/{sum(fc.values())} frames)"
        rows.append((j["id"], j["state"], progress, str(j.get("spp_done") or 0),
                     str(j["priority"]), tries, "-" if elapsed is None else f"{elapsed:.1f}s",
                     format_size(j["peak_memory"]) if j.get("peak_memory") else "-", _age(j.get("created_at")),
                     j["stage"], (j.get("error") or "")[:60]))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    if listing["total"] > listing["count"]:
        print(f"({listing['count']} of {listing['total']} jobs; --limit to see more)", file=sys.stderr)
    return 0
