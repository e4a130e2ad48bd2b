"""Fixtures for the render-service tests: a real ``illum serve`` in a subprocess on 127.0.0.1
(random free port), real worker processes, real stages rendered at tiny resolutions.

Snapshots come every 0.5 s (a server flag) so previews and checkpoints appear quickly. A dead
worker is noticed by its supervisor at once, so the generous heartbeat timeout (10 s, which keeps
a heavily loaded machine from looking like a hung worker) does not slow the fault tests down.
Every process started here is stopped here.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field

import httpx
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STAGES = os.path.join(REPO, "stages")
TINY = {"resolution": [16, 16], "spp": 4}


@dataclass
class Server:
    """A running ``illum serve`` subprocess."""

    url: str
    data: str
    stage_root: str
    proc: subprocess.Popen
    log_path: str
    args: list = field(default_factory=list)
    env: dict = field(default_factory=dict)

    @property
    def token(self) -> str | None:
        """The server's ILLUM_TOKEN (None when it has none)."""
        return self.env.get("ILLUM_TOKEN") or None

    def client(self, token: str | None = None, timeout: float = 30.0) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, timeout=timeout, headers=headers)

    def log(self) -> str:
        with open(self.log_path, encoding="utf-8", errors="replace") as fh:
            return fh.read()

    def worker_pids(self) -> dict:
        with self.client(self.token) as c:
            return {w["id"]: (w["pid"], w["job"]) for w in c.get("/health").json()["workers"]["registered"]}

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 20.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


def _read(path: str) -> str:
    with open(path, encoding="utf-8", errors="replace") as fh:
        return fh.read()


def start_server(tmp_path, stage_root: str, *, workers: int = 1, extra: list | None = None,
                 env: dict | None = None, data: str | None = None, wait_workers: bool = True,
                 name: str = "server") -> Server:
    """Start ``python -m renderer.cli serve`` and wait until /health answers (and the workers
    registered)."""
    data = data or str(tmp_path / "data")
    log_path = str(tmp_path / f"{name}-{time.monotonic_ns()}.log")
    args = [sys.executable, "-m", "renderer.cli", "serve", "--host", "127.0.0.1", "--port", "0",
            "--data", data, "--stage-root", stage_root, "--workers", str(workers),
            "--heartbeat-timeout", "10", "--snapshot-interval", "0.5", "--log-level", "warning", *(extra or [])]
    full_env = dict(os.environ)
    full_env.pop("ILLUM_TOKEN", None)
    full_env.update(env or {})
    with open(log_path, "wb") as out:
        proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=full_env, cwd=str(tmp_path))
    deadline = time.monotonic() + 60
    url = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with {proc.returncode}:\n{_read(log_path)}")
        m = re.search(r"serving on (http://127\.0\.0\.1:\d+)", _read(log_path))
        if m:
            url = m.group(1)
            break
        time.sleep(0.05)
    if url is None:
        proc.kill()
        proc.wait()
        raise RuntimeError(f"server did not start:\n{_read(log_path)}")
    server = Server(url=url, data=data, stage_root=stage_root, proc=proc, log_path=log_path, args=args,
                    env=full_env)
    token = full_env.get("ILLUM_TOKEN")
    try:
        with httpx.Client(base_url=url, timeout=5, headers={"Authorization": f"Bearer {token}"} if token else {}) as c:
            while time.monotonic() < deadline:
                try:
                    h = c.get("/health").json()
                    if not wait_workers or len(h["workers"]["registered"]) >= min(workers, 1):
                        return server
                except httpx.TransportError:
                    pass
                time.sleep(0.05)
    except BaseException:  # never leave a server behind when the wait itself fails
        server.stop(signal.SIGKILL)
        raise
    server.stop(signal.SIGKILL)
    raise RuntimeError("server never became healthy")


def make_stage_root(path) -> str:
    """A stage root with real stages (copies, so tests may add files next to them)."""
    os.makedirs(path, exist_ok=True)
    for name in ("cornell_box.usda", "zup_dome.usda"):
        shutil.copy(os.path.join(STAGES, name), os.path.join(path, name))
    shutil.copytree(os.path.join(STAGES, "textures"), os.path.join(path, "textures"), dirs_exist_ok=True)
    os.makedirs(os.path.join(path, "shots"), exist_ok=True)
    shutil.copy(os.path.join(STAGES, "cornell_box.usda"), os.path.join(path, "shots", "a.usda"))
    return str(path)


def write_fifo_clip_stage(path: str, sublayer: str | None = None) -> str:
    """A stage at ``path`` whose /Clipped prim takes values from a value-clip layer that is a
    FIFO (``pipe.usda`` next to it): opening the stage blocks until a writer appears, which
    never happens. FIFO sublayers and references are refused before anything opens them
    (renderer/usd/composition.py); clip layers are opened while composing, so this is the
    hang the load deadline and the checks' timeouts are for."""
    pipe = os.path.join(os.path.dirname(path), "pipe.usda")
    os.mkfifo(pipe)
    layers = f"    subLayers = [@{sublayer}@]\n" if sublayer else ""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"""#usda 1.0
(
{layers})
def Xform "Clipped" (
    clips = {{
        dictionary default = {{
            asset[] assetPaths = [@./pipe.usda@]
            string primPath = "/Clipped"
            double2[] active = [(0, 0)]
        }}
    }}
)
{{
}}
""")
    return pipe


def wait_for(predicate, timeout: float = 30.0, interval: float = 0.05, what: str = "condition"):
    """Poll ``predicate`` until it returns a truthy value; fail the test after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def wait_job(client: httpx.Client, job_id: str, states=("succeeded", "failed", "canceled"),
             timeout: float = 60.0) -> dict:
    def check():
        j = client.get(f"/jobs/{job_id}").json()
        return j if j["state"] in states else None
    return wait_for(check, timeout, what=f"job {job_id} in {states}")


def read_exr_bytes(data: bytes, tmp_path, name: str = "img.exr"):
    """Write bytes to a file and read them back with OpenImageIO: (pixels, attributes)."""
    from renderer.film import read_exr

    p = tmp_path / name
    p.write_bytes(data)
    return read_exr(str(p))


@pytest.fixture(scope="session")
def stage_root(tmp_path_factory) -> str:
    return make_stage_root(tmp_path_factory.mktemp("stage-root"))


@pytest.fixture(scope="session")
def server(tmp_path_factory, stage_root):
    """One shared server with two workers for the API tests."""
    tmp = tmp_path_factory.mktemp("server")
    s = start_server(tmp, stage_root, workers=2)
    yield s
    s.stop()


@pytest.fixture
def client(server):
    with server.client() as c:
        yield c


def pytest_collection_modifyitems(config, items):
    """The heavy variants (``@pytest.mark.slow``: the 200-job load test, the full browser flow)
    run when asked for (``pytest -m slow``, ``make stress``) or with ILLUM_SERVICE_SLOW=1; the
    default suite runs their reduced forms only, to stay within its time budget."""
    markexpr = config.getoption("-m") or ""
    if "slow" in markexpr or os.environ.get("ILLUM_SERVICE_SLOW"):
        return
    here = os.path.dirname(os.path.abspath(__file__))
    skip = pytest.mark.skip(reason="heavy service test: run with `pytest -m slow` or ILLUM_SERVICE_SLOW=1")
    for item in items:
        if "slow" in item.keywords and str(item.path).startswith(here):
            item.add_marker(skip)
