"""``illum submit`` and ``illum jobs`` as a user runs them: subprocesses against a real server."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from .conftest import STAGES


def _illum(*args, env=None, timeout=120):
    full = dict(os.environ)
    full.pop("ILLUM_TOKEN", None)
    full.update(env or {})
    return subprocess.run([sys.executable, "-m", "renderer.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=full, stdin=subprocess.DEVNULL)


class _Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def illum(capsys, monkeypatch):
    """``illum ...`` in this process (the same entry point, no interpreter start-up per call)."""
    from renderer.cli import main

    monkeypatch.delenv("ILLUM_TOKEN", raising=False)

    def run(*args):
        capsys.readouterr()
        code = main(list(args))
        out, err = capsys.readouterr()
        return _Result(code, out, err)
    return run


def test_submit_wait_and_download(server, tmp_path):
    out = tmp_path / "shots" / "out.exr"
    r = _illum("submit", "cornell_box.usda", "--server", server.url, "--wait", "-o", str(out),
               "--spp", "6", "--res", "24", "16", "--estimator", "mis", "--priority", "60")
    assert r.returncode == 0, r.stderr
    assert "ALF_PROGRESS 100%" in r.stdout  # not a TTY: the farm-style progress lines
    assert "succeeded" in r.stderr and str(out) in r.stderr
    from renderer.film import read_exr

    img, attrs = read_exr(str(out))
    assert img.shape == (16, 24, 3) and attrs["illum:spp"] == 6


def test_submit_list_show_cancel(server, illum):
    """Fire-and-forget submissions (idempotent), then ``illum jobs`` to list, show, cancel, read
    the log."""
    args = ("submit", "cornell_box.usda", "--server", server.url, "--time-budget", "60", "--res", "16", "16",
            "--idempotency-key", "cli-key-1")
    r = illum(*args)
    assert r.returncode == 0, r.stderr
    job_id = r.stdout.strip().splitlines()[-1]
    assert illum(*args).stdout.strip().splitlines()[-1] == job_id  # the same key: the same job
    shown = illum("jobs", job_id, "--server", server.url)
    assert shown.returncode == 0 and json.loads(shown.stdout)["id"] == job_id
    listing = illum("jobs", "--server", server.url, "--state", "queued", "--state", "running")
    assert listing.returncode == 0, listing.stderr
    lines = listing.stdout.splitlines()
    assert lines[0].split()[:3] == ["ID", "STATE", "PROGRESS"]
    assert any(ln.startswith(job_id) for ln in lines[1:])
    assert all((" running " in ln or " queued " in ln) for ln in lines[1:])
    r = illum("jobs", job_id, "--cancel", "--server", server.url)
    assert r.returncode == 0 and json.loads(r.stdout)["state"] == "canceled"
    r = illum("jobs", "--server", server.url, "--json", "--limit", "3")
    assert r.returncode == 0 and 1 <= len(json.loads(r.stdout)["jobs"]) <= 3
    r = illum("jobs", job_id, "--log", "--server", server.url)
    # Whether or not a worker had taken the job (its "attempt" line), the log records the cancel.
    assert r.returncode == 0 and "canceled by request" in r.stdout


def test_submit_upload(server, illum):
    r = illum("submit", os.path.join(STAGES, "cornell_box.usda"), "--upload", "--server", server.url,
              "--wait", "--spp", "2", "--res", "8", "8")
    assert "ALF_PROGRESS 100%" in r.stdout
    assert r.returncode == 0, r.stderr


def test_submit_errors_are_one_line(server, illum, tmp_path):
    r = illum("submit", "../etc/passwd.usda", "--server", server.url)
    assert r.returncode == 2
    assert r.stderr.startswith("illum: error: stage: ") and "outside the stage root" in r.stderr
    # within the option's own bound but beyond this server's --max-spp (65536): the server refuses it
    r = illum("submit", "cornell_box.usda", "--server", server.url, "--spp", "100000")
    assert r.returncode == 2 and "settings.spp" in r.stderr and "server limit" in r.stderr
    # beyond the option's bound: refused before anything is sent
    r = illum("submit", "cornell_box.usda", "--server", server.url, "--spp", "99999999")
    assert r.returncode == 2 and r.stderr == "illum: error: spp: must be an integer in [1, 1000000], got 99999999\n"
    bad = tmp_path / "bad.usda"
    bad.write_text("#usda 1.0\n(((\n")
    r = illum("submit", str(bad), "--upload", "--server", server.url, "--wait")
    assert r.returncode == 2 and "failed" in r.stderr and "cannot open stage" in r.stderr
    r = illum("jobs", "--server", "http://127.0.0.1:9")  # nothing listens on the discard port
    assert r.returncode == 2 and "cannot reach" in r.stderr


def test_progress_bar_on_a_tty(server):
    """On a terminal, ``--wait`` draws a tqdm bar (on stderr) instead of ALF_PROGRESS lines."""
    import fcntl
    import pty
    import struct
    import termios

    master, slave = pty.openpty()
    # a real terminal has a size; tqdm sizes its bar from it
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    try:
        env = dict(os.environ)
        env.pop("ILLUM_TOKEN", None)
        proc = subprocess.Popen([sys.executable, "-m", "renderer.cli", "submit", "cornell_box.usda",
                                 "--server", server.url, "--wait", "--spp", "3", "--res", "8", "8"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave, env=env)
        os.close(slave)
        slave = -1
        chunks = []
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        out, _ = proc.communicate(timeout=120)
        proc.stdout.close()
    finally:
        os.close(master)
        if slave >= 0:
            os.close(slave)
    tty = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 0, tty
    assert "100%|" in tty and "succeeded" in tty
    assert b"ALF_PROGRESS" not in out


def test_submit_a_frame_range(server, illum):
    """``illum submit --frames`` (the range flags of ``illum render``, RANGE_OPTIONS) makes one job
    with a task per frame; a bad range is refused by the server naming the setting."""
    from .conftest import wait_job

    r = illum("submit", "cornell_box.usda", "--server", server.url, "--frames", "3-7x2", "--spp", "1",
              "--res", "8", "8", "--quiet")
    assert r.returncode == 0, r.stderr
    job_id = r.stdout.strip()
    with server.client() as c:
        done = wait_job(c, job_id, timeout=120)
    assert done["settings"]["frames"] == "3-7x2" and done["state"] == "succeeded", done
    assert [(f["frame"], f["state"]) for f in done["frames"]] == [(3.0, "succeeded"), (5.0, "succeeded"),
                                                                   (7.0, "succeeded")]
    r = illum("submit", "cornell_box.usda", "--server", server.url, "--frame", "2", "--frame-count", "0")
    assert r.returncode == 2 and "settings.frame_count" in r.stderr, r.stderr
    r = illum("jobs", "--server", server.url)
    assert r.returncode == 0 and f"{job_id}  succeeded  100% (3/3 frames)" in r.stdout, r.stdout
