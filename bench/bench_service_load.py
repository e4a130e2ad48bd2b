"""API latency while many large stages are uploaded and submitted at once (#21 item 3).

Starts ``illum serve`` on 127.0.0.1 (no workers: only the API and its asset checks run), then
``--clients`` threads each upload a distinct stage of ``--prims`` prims and submit it, while one
more thread polls ``/health`` and ``GET /jobs`` back to back. Reports the latency percentiles of
those polls during the flood, the time of the slowest upload+submit, and how long until every
job's asset check finished.

    python bench/bench_service_load.py --clients 44 --prims 300000
    python bench/bench_service_load.py --clients 16 --prims 60000 --repo /path/to/other/checkout

``--repo`` runs another checkout's server (a before/after comparison: the stage files and the
load are the same). The machine's other load matters: quote both runs from one sitting.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import httpx

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def big_stage(prims: int, tag: int) -> bytes:
    """A valid stage of ``prims`` Xform prims under one root, made unique by ``tag`` (so the
    server's content-addressed uploads and verdict cache cannot share work between clients)."""
    lines = ["#usda 1.0", f'(\n    doc = "load test {tag}"\n)', 'def Xform "World" {']
    lines += [f'    def Xform "X{i}" {{ double3 xformOp:translate = ({i}, {tag}, 0) '
              f'uniform token[] xformOpOrder = ["xformOp:translate"] }}' for i in range(prims)]
    lines.append("}")
    return ("\n".join(lines) + "\n").encode()


def start(repo: str, data: str, stage_root: str, check_timeout: float) -> tuple[subprocess.Popen, str]:
    log = open(os.path.join(data, "server.log"), "wb")
    env = dict(os.environ, PYTHONPATH=repo)
    env.pop("ILLUM_TOKEN", None)
    proc = subprocess.Popen([sys.executable, "-m", "renderer.cli", "serve", "--host", "127.0.0.1", "--port", "0",
                             "--data", data, "--stage-root", stage_root, "--workers", "0",
                             "--asset-check-timeout", str(check_timeout), "--log-level", "warning",
                             "--max-upload-mb", "64"],
                            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env, cwd=repo)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with open(os.path.join(data, "server.log"), encoding="utf-8", errors="replace") as fh:
            m = re.search(r"serving on (http://127\.0\.0\.1:\d+)", fh.read())
        if m:
            return proc, m.group(1)
        if proc.poll() is not None:
            break
        time.sleep(0.05)
    proc.kill()
    raise SystemExit("the server did not start; see " + os.path.join(data, "server.log"))


def pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q * (len(xs) - 1))))] if xs else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clients", type=int, default=44)
    ap.add_argument("--prims", type=int, default=300_000)
    ap.add_argument("--repo", default=ROOT, help="the checkout whose server runs (default: this one)")
    ap.add_argument("--check-timeout", type=float, default=600.0)
    ap.add_argument("--idle-seconds", type=float, default=5.0,
                    help="poll the server this long after the flood (the machine's own latency; 0: skip)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = os.path.join(tmp, "root")
        data = os.path.join(tmp, "data")
        os.makedirs(root)
        os.makedirs(data)
        bodies = [big_stage(a.prims, i) for i in range(a.clients)]
        proc, url = start(os.path.abspath(a.repo), data, root, a.check_timeout)
        lat: dict[str, list[float]] = {"/health": [], "/jobs": []}
        idle: dict[str, list[float]] = {"/health": [], "/jobs": []}
        submit_s: list[float] = []
        ids: list[str] = []
        errors: list[str] = []
        flooding = threading.Event()
        flooding.set()

        def poll():
            with httpx.Client(base_url=url, timeout=600) as c:
                while flooding.is_set():
                    for path in lat:
                        t0 = time.perf_counter()
                        r = c.get(path)
                        lat[path].append(time.perf_counter() - t0)
                        if r.status_code != 200:
                            errors.append(f"{path}: {r.status_code}")
                    time.sleep(0.01)

        def client(i: int):
            with httpx.Client(base_url=url, timeout=900) as c:
                t0 = time.perf_counter()
                up = c.post("/uploads", params={"filename": f"big{i}.usda"}, content=bodies[i])
                if up.status_code not in (200, 201):
                    errors.append(f"upload {i}: {up.status_code} {up.text[:200]}")
                    return
                r = c.post("/jobs", json={"upload": up.json()["upload"], "settings": {"spp": 1,
                                                                                       "resolution": [8, 8]}})
                submit_s.append(time.perf_counter() - t0)
                if r.status_code in (200, 201):
                    ids.append(r.json()["id"])
                else:
                    errors.append(f"submit {i}: {r.status_code} {r.text[:200]}")

        poller = threading.Thread(target=poll)
        poller.start()
        t_start = time.perf_counter()
        threads = [threading.Thread(target=client, args=(i,)) for i in range(a.clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        t_submitted = time.perf_counter() - t_start
        # Until every check has run (a server without the asset_check field checked in the POST).
        with httpx.Client(base_url=url, timeout=600) as c:
            while True:
                jobs = [c.get(f"/jobs/{j}").json() for j in ids]
                if all(j.get("asset_check", "done") == "done" for j in jobs):
                    break
                time.sleep(0.5)
        t_checked = time.perf_counter() - t_start
        flooding.clear()
        poller.join()
        # The same polls once the flood is over (the same jobs listed): on a shared machine this
        # says how much of the latency under the flood is the machine's own load.
        with httpx.Client(base_url=url, timeout=600) as c:
            t_idle = time.perf_counter() + a.idle_seconds
            while time.perf_counter() < t_idle:
                for path in idle:
                    t0 = time.perf_counter()
                    c.get(path)
                    idle[path].append(time.perf_counter() - t0)
                time.sleep(0.01)
        proc.terminate()
        proc.wait(30)
    mb = len(bodies[0]) / 1e6
    print(f"{a.clients} clients x {a.prims} prims ({mb:.1f} MB each), server from {a.repo}")
    for label, table in (("idle", idle), ("flood", lat)):
        for path, xs in table.items():
            if xs:
                print(f"  {label:5s} GET {path:8s} n={len(xs):5d}  p50 {1e3 * statistics.median(xs):8.1f} ms  "
                      f"p99 {1e3 * pct(xs, 0.99):8.1f} ms  max {1e3 * max(xs):8.1f} ms")
    print(f"  slowest upload+submit {max(submit_s, default=float('nan')):.1f} s; all submitted after {t_submitted:.1f} s; "
          f"all checked after {t_checked:.1f} s; errors: {len(errors)}")
    for e in errors[:5]:
        print("   ", e)
    return 0


if __name__ == "__main__":
    sys.exit(main())
