"""Security and bad input against a real server: path confinement, size caps, limits, the
bearer token, no shell anywhere, and malformed stages that must not hurt the server."""

from __future__ import annotations

import ast
import glob
import os

import pytest

from .conftest import REPO, TINY, make_stage_root, start_server, wait_job

TOKEN = "s3cret-token-for-tests"


@pytest.fixture(scope="module")
def secure(tmp_path_factory):
    """A server with ILLUM_TOKEN set, a 32 KiB upload cap and tight render limits, and a stage
    root holding traps: links out of the root and shell metacharacters in file names."""
    tmp = tmp_path_factory.mktemp("secure")
    root = make_stage_root(tmp / "root")
    outside = tmp / "outside"
    outside.mkdir()
    with open(os.path.join(root, "cornell_box.usda"), "rb") as fh:
        data = fh.read()
    (outside / "private.usda").write_bytes(data)
    os.symlink(outside / "private.usda", os.path.join(root, "escape.usda"))
    os.symlink(outside, os.path.join(root, "escape_dir"))
    for name in ("$(touch PWNED).usda", "; touch PWNED2 ;.usda", "`touch PWNED3`.usda"):
        with open(os.path.join(root, name), "wb") as fh:
            fh.write(data)
    s = start_server(tmp, root, workers=1, env={"ILLUM_TOKEN": TOKEN},
                     extra=["--max-upload-mb", str(32 / 1024), "--max-spp", "256", "--max-time", "60",
                            "--max-resolution", "256"])
    s.outside = str(outside)
    s.tmp = str(tmp)
    yield s
    s.stop()


@pytest.fixture
def authed(secure):
    with secure.client(token=TOKEN) as c:
        yield c


@pytest.fixture
def anon(secure):
    with secure.client() as c:
        yield c


@pytest.mark.parametrize("stage", ["../outside/private.usda", "shots/../../outside/private.usda", "escape.usda",
                                   "escape_dir/private.usda", "/etc/passwd", "/etc/hosts.usda", "textures",
                                   "missing.usda", "cornell_box.usda/.."])
def test_stage_paths_are_confined(authed, stage):
    r = authed.post("/jobs", json={"stage": stage, "settings": dict(TINY)})
    assert r.status_code == 400, r.text
    assert r.json()["message"].startswith("stage: ")


def test_absolute_path_inside_root_is_accepted(secure, authed):
    r = authed.post("/jobs", json={"stage": os.path.join(secure.stage_root, "shots", "a.usda"),
                                   "settings": dict(TINY)})
    assert r.status_code == 201 and r.json()["stage"] == "shots/a.usda"
    assert wait_job(authed, r.json()["id"])["state"] == "succeeded"


def test_stage_listing_hides_escaping_links(authed):
    stages = authed.get("/stages").json()["stages"]
    assert "cornell_box.usda" in stages
    assert not any(s.startswith("escape") for s in stages)


def test_token_required_on_mutating_endpoints(secure, anon, authed):
    job = authed.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)})
    assert job.status_code == 201
    jid = job.json()["id"]
    for method, url, kw in (("POST", "/jobs", {"json": {"stage": "cornell_box.usda"}}),
                            ("POST", f"/jobs/{jid}/cancel", {}),
                            ("DELETE", f"/jobs/{jid}", {}),
                            ("POST", "/uploads?filename=a.usda", {"content": b"#usda 1.0\n"})):
        r = anon.request(method, url, **kw)
        assert r.status_code == 401, (method, url, r.text)
        assert r.headers["www-authenticate"] == "Bearer"
        with secure.client(token="wrong") as bad:
            assert bad.request(method, url, **kw).status_code == 401
    # the job was not touched by the refused calls
    assert wait_job(authed, jid)["state"] == "succeeded"


def test_token_required_on_reads(secure, anon, authed):
    """Reads follow the same policy: job data, images, logs, stage names and metrics need the
    token; the page shell, its files, the API docs and the bare health status stay open."""
    jid = authed.post("/jobs", json={"stage": "cornell_box.usda", "settings": dict(TINY)}).json()["id"]
    assert wait_job(authed, jid)["state"] == "succeeded"
    reads = ["/jobs", f"/jobs/{jid}", f"/jobs/{jid}/image?format=png", f"/jobs/{jid}/image?format=exr",
             f"/jobs/{jid}/log", f"/jobs/{jid}/stats", "/stages", "/stages?kind=preconvolve", "/metrics"]
    for url in reads:
        r = anon.get(url)
        assert r.status_code == 401, (url, r.text)
        assert r.headers["www-authenticate"] == "Bearer" and "bearer token" in r.json()["message"]
        with secure.client(token="wrong") as bad:
            assert bad.get(url).status_code == 401, url
        assert authed.get(url).status_code == 200, url
    # a job id that does not exist answers 401 too: no probing for ids without the token
    assert anon.get("/jobs/0123456789abcdef").status_code == 401
    h = anon.get("/health").json()
    assert h == {"status": "ok", "version": h["version"], "auth": True, "authorized": False}
    full = authed.get("/health").json()
    assert full["authorized"] is True and "workers" in full and "jobs" in full
    for url in ("/", "/static/app.js", "/static/style.css", "/openapi.json", "/docs"):
        assert anon.get(url).status_code == 200, url
    schemes = anon.get("/openapi.json").json()["components"]["securitySchemes"]
    assert schemes["HTTPBearer"]["scheme"] == "bearer"  # Swagger UI's Authorize button


def test_upload_size_cap(authed):
    big = b"#usda 1.0\n" + b"#" * (40 * 1024)
    r = authed.post("/uploads", params={"filename": "big.usda"}, content=big)
    assert r.status_code == 413 and "limit" in r.json()["message"]

    def chunks():  # no Content-Length: the server must count streamed bytes
        yield b"#usda 1.0\n"
        for _ in range(10):
            yield b"#" * 8192

    r = authed.post("/uploads", params={"filename": "big.usda"}, content=chunks())
    assert r.status_code == 413
    ok = authed.post("/uploads", params={"filename": "small.usda"}, content=b"#usda 1.0\n")
    assert ok.status_code == 201
    assert authed.post("/uploads", params={"filename": "x.exe"}, content=b"MZ").status_code == 400
    assert authed.post("/uploads", params={"filename": "x.usdc"}, content=b"#usda 1.0").status_code == 400
    assert authed.post("/uploads", params={"filename": "x.usda"}, content=b"").status_code == 400


def test_no_partial_uploads_left_behind(secure, authed):
    authed.post("/uploads", params={"filename": "big.usda"}, content=b"#" * (64 * 1024))
    names = os.listdir(os.path.join(secure.data, "uploads"))
    assert not [n for n in names if n.startswith(".upload-")]


def test_json_body_cap(authed):
    r = authed.post("/jobs", content=b'{"stage": "' + b"a" * (2 * 1024 * 1024) + b'"}',
                    headers={"Content-Type": "application/json"})
    assert r.status_code == 413

    def chunks():  # no Content-Length: counted as it streams
        yield b'{"stage": "'
        for _ in range(160):
            yield b"a" * 8192
        yield b'"}'

    r = authed.post("/jobs", content=chunks(), headers={"Content-Type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["message"]


@pytest.mark.parametrize("settings, field", [
    ({"spp": 257}, "settings.spp"),
    ({"time_budget": 61}, "settings.time_budget"),
    ({"resolution": [257, 16]}, "settings.resolution"),
    ({"resolution": [16, 100000]}, "settings.resolution"),
    ({"max_depth": 100000}, "settings.max_depth"),
    ({"spp": 4, "shell": "rm -rf /"}, "settings.shell"),
])
def test_limits_answer_422_naming_the_field(authed, settings, field):
    r = authed.post("/jobs", json={"stage": "cornell_box.usda", "settings": settings})
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith(field), r.json()


def test_stage_authored_resolution_is_capped(secure, authed):
    # cornell_box.usda asks for 512x512 in its RenderSettings; this server allows 256 per side
    r = authed.post("/jobs", json={"stage": "cornell_box.usda", "settings": {"spp": 1}})
    done = wait_job(authed, r.json()["id"])
    assert done["state"] == "failed" and "512x512" in done["error"] and "limit" in done["error"]


def test_shell_metacharacters_in_names_are_inert(secure, authed):
    ids = []
    for name in ("$(touch PWNED).usda", "; touch PWNED2 ;.usda", "`touch PWNED3`.usda"):
        r = authed.post("/jobs", json={"stage": name, "settings": dict(TINY)})
        assert r.status_code == 201 and r.json()["stage"] == name
        ids.append(r.json()["id"])
    with open(os.path.join(secure.stage_root, "cornell_box.usda"), "rb") as fh:
        up = authed.post("/uploads", params={"filename": "$(touch PWNED4).usda"}, content=fh.read())
    assert up.status_code == 201 and "$" not in up.json()["upload"]
    ids.append(authed.post("/jobs", json={"upload": up.json()["upload"], "settings": dict(TINY)}).json()["id"])
    for jid in ids:
        assert wait_job(authed, jid)["state"] == "succeeded"
    for where in (secure.tmp, secure.stage_root, secure.data, os.getcwd(), REPO):
        assert not glob.glob(os.path.join(where, "**", "PWNED*"), recursive=True), where


def test_service_code_never_uses_a_shell():
    """Static guard: no shell=True, os.system, os.popen or shell-string helpers in service/."""
    banned_calls = {("os", "system"), ("os", "popen"), ("subprocess", "getoutput"), ("subprocess", "getstatusoutput")}
    for path in glob.glob(os.path.join(REPO, "service", "*.py")):
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                for kw in node.keywords:
                    assert not (kw.arg == "shell" and isinstance(kw.value, ast.Constant) and kw.value.value), \
                        f"{path}:{node.lineno}: shell=True"
                f = node.func
                if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
                    assert (f.value.id, f.attr) not in banned_calls, f"{path}:{node.lineno}: {f.value.id}.{f.attr}"


def test_malformed_stages_fail_cleanly(secure, authed):
    cases = {"empty.usda": b"#usda 1.0\n", "garbage.usda": b"\x00\x01 definitely not a layer {{{",
             "truncated.usda": b'#usda 1.0\ndef Xform "World" {\n  def Mesh "M" {\n    point3f[] points = [(0,0'}
    ids = {}
    for name, data in cases.items():
        up = authed.post("/uploads", params={"filename": name}, content=data)
        assert up.status_code == 201, up.text
        ids[name] = authed.post("/jobs", json={"upload": up.json()["upload"], "settings": dict(TINY)}).json()["id"]
    # A valid but empty stage is not malformed: it renders black through the default framing
    # camera, with the no-camera and no-light warnings (#19), like usdrecord.
    empty = wait_job(authed, ids.pop("empty.usda"))
    assert empty["state"] == "succeeded", empty
    warnings = " ".join(empty["result"]["warnings"])
    assert "camera" in warnings and "light" in warnings, warnings
    for name, jid in ids.items():
        done = wait_job(authed, jid)
        assert done["state"] == "failed", (name, done)
        assert done["error"] and "\n" not in done["error"] and done["attempts"] == 1
        assert "internal error" not in done["error"], done["error"]
    assert authed.get("/health").json()["status"] == "ok"
    assert secure.proc.poll() is None


def test_cli_reads_the_token_from_the_environment(secure):
    import subprocess
    import sys

    def illum(env_token):
        env = {k: v for k, v in os.environ.items() if k != "ILLUM_TOKEN"}
        if env_token:
            env["ILLUM_TOKEN"] = env_token
        return subprocess.run([sys.executable, "-m", "renderer.cli", "submit", "cornell_box.usda", "--server",
                               secure.url, "--spp", "1", "--res", "8", "8"], capture_output=True, text=True,
                              env=env, timeout=120, stdin=subprocess.DEVNULL)

    r = illum(None)
    assert r.returncode == 2 and "bearer token" in r.stderr
    r = illum(TOKEN)
    assert r.returncode == 0, r.stderr
