"""Asset confinement against a real server: a submitted stage may read files only under the
stage root (an upload: under the stage root and the uploads). Sublayers, references, payloads,
textures and IES files that lead elsewhere make the job fail, before any worker takes it, with a
message naming layer, prim, attribute and path; the check runs off the request path (POST answers
with the check pending); a stage changed after the check is stopped by the worker."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from .conftest import STAGES, TINY, make_stage_root, start_server, wait_for, wait_job, write_fifo_clip_stage

CUBE_TEX = """def Material "M" {{
    token outputs:surface.connect = </M/S.outputs:surface>
    def Shader "S" {{
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </M/T.outputs:rgb>
        token outputs:surface
    }}
    def Shader "T" {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{tex}@
        float3 outputs:rgb
    }}
}}"""


@pytest.fixture(scope="module")
def confined(tmp_path_factory):
    """A server (no workers: submission checks only) whose stage root holds stages that reach
    out of it in every way, and a directory next to the root with the files they want."""
    tmp = tmp_path_factory.mktemp("confined")
    root = make_stage_root(tmp / "root")
    outside = tmp / "outside"
    outside.mkdir()
    with open(os.path.join(root, "cornell_box.usda"), encoding="utf-8") as fh:
        box = fh.read()
    (outside / "secret.usda").write_text('#usda 1.0\ndef Xform "Secret" {}\n')
    shutil.copy(os.path.join(STAGES, "textures", "checker.png"), outside / "secret.png")
    (outside / "spot.ies").write_text("IESNA:LM-63-2002\n")
    os.symlink(outside / "secret.png", os.path.join(root, "textures", "innocent.png"))

    def stage(name, body):
        text = box + "\n" + body + "\n"
        with open(os.path.join(root, name), "w", encoding="utf-8") as fh:
            fh.write(text)

    with open(os.path.join(root, "shots", "sub.usda"), "w", encoding="utf-8") as fh:
        fh.write("#usda 1.0\n(\n    subLayers = [@../../outside/secret.usda@, @../cornell_box.usda@]\n)\n")
    stage("shots/ref.usda", body=f'def "R" (\n    references = @{outside}/secret.usda@\n) {{}}')
    stage("shots/missing_ref.usda", body='def "R" (\n    references = @../../outside/nothere.usda@\n) {}')
    stage("shots/payload.usda", body='def "P" (\n    prepend payload = @../../outside/secret.usda@\n) {}')
    stage("shots/tex.usda", body=CUBE_TEX.format(tex="../../outside/secret.png"))
    stage("shots/tex_link.usda", body=CUBE_TEX.format(tex="../textures/innocent.png"))
    stage("shots/tex_etc.usda", body=CUBE_TEX.format(tex="/etc/hostname"))
    stage("shots/ies.usda", body='def SphereLight "Spot" (\n    prepend apiSchemas = ["ShapingAPI"]\n) {\n'
                                 '    asset inputs:shaping:ies:file = @../../outside/spot.ies@\n}')
    stage("shots/tex_ok.usda", body=CUBE_TEX.format(tex="../textures/checker.png"))
    s = start_server(tmp, root, workers=0, wait_workers=False)
    s.outside = str(outside)
    s.tmp = tmp
    yield s
    s.stop()


@pytest.fixture
def cclient(confined):
    with confined.client() as c:
        yield c


def checked(client, job_id: str) -> dict:
    """The job once its asset check has run."""
    return wait_for(lambda: (lambda j: j if j["asset_check"] == "done" else None)(
        client.get(f"/jobs/{job_id}").json()), 60, what=f"the asset check of {job_id}")


@pytest.mark.parametrize("stage, where, asset", [
    ("shots/sub.usda", "shots/sub.usda: subLayers", "../../outside/secret.usda"),
    ("shots/ref.usda", "shots/ref.usda: /R.references", "{outside}/secret.usda"),
    # a missing file outside is refused exactly like an existing one: no probing for files
    ("shots/missing_ref.usda", "shots/missing_ref.usda: /R.references", "../../outside/nothere.usda"),
    ("shots/payload.usda", "shots/payload.usda: /P.payload", "../../outside/secret.usda"),
    ("shots/tex.usda", "shots/tex.usda: /M/T.inputs:file", "../../outside/secret.png"),
    ("shots/tex_link.usda", "shots/tex_link.usda: /M/T.inputs:file", "../textures/innocent.png"),
    ("shots/tex_etc.usda", "shots/tex_etc.usda: /M/T.inputs:file", "/etc/hostname"),
    ("shots/ies.usda", "shots/ies.usda: /Spot.inputs:shaping:ies:file", "../../outside/spot.ies"),
])
def test_escaping_stages_are_refused_naming_the_asset(confined, cclient, stage, where, asset):
    asset = asset.replace("{outside}", confined.outside)
    r = cclient.post("/jobs", json={"stage": stage, "settings": dict(TINY)})
    assert r.status_code == 201 and r.json()["asset_check"] == "pending", r.text
    job = checked(cclient, r.json()["id"])
    assert (job["state"], job["attempts"]) == ("failed", 0), job  # refused before any worker
    assert job["error"] == f"{where}: asset path '{asset}' leads outside the stage root", job["error"]
    log = cclient.get(f"/jobs/{job['id']}/log").text
    assert "refused by the asset check" in log and asset in log


def test_confined_stages_are_accepted(cclient):
    for stage in ("cornell_box.usda", "shots/tex_ok.usda", "zup_dome.usda"):
        r = cclient.post("/jobs", json={"stage": stage, "settings": dict(TINY)})
        assert r.status_code == 201, r.text
        job = checked(cclient, r.json()["id"])
        assert (job["state"], job["error"]) == ("queued", None), job


def test_uploads_may_use_the_stage_root_but_nothing_else(confined, cclient):
    tex_root = os.path.join(confined.stage_root, "textures", "checker.png")
    with open(os.path.join(confined.stage_root, "cornell_box.usda"), encoding="utf-8") as fh:
        box = fh.read()
    ok = box + "\n" + CUBE_TEX.format(tex=tex_root)
    up = cclient.post("/uploads", params={"filename": "ok.usda"}, content=ok.encode())
    r = cclient.post("/jobs", json={"upload": up.json()["upload"], "settings": dict(TINY)})
    assert r.status_code == 201 and checked(cclient, r.json()["id"])["state"] == "queued"
    bad = box + "\n" + CUBE_TEX.format(tex=os.path.join(confined.outside, "secret.png"))
    up = cclient.post("/uploads", params={"filename": "bad.usda"}, content=bad.encode())
    r = cclient.post("/jobs", json={"upload": up.json()["upload"], "settings": dict(TINY)})
    assert r.status_code == 201
    job = checked(cclient, r.json()["id"])
    assert job["state"] == "failed" and job["error"] == (
        f"upload:bad.usda: /M/T.inputs:file: asset path '{confined.outside}/secret.png' leads outside the "
        f"stage root and the uploads")


def test_an_edited_layer_is_checked_again(confined, cclient):
    """The verdict cache follows the layers: editing one to reach out is noticed at once."""
    path = os.path.join(confined.stage_root, "shots", "edited.usda")
    shutil.copy(os.path.join(confined.stage_root, "cornell_box.usda"), path)
    for _ in range(2):  # the second verdict comes from the cache
        r = cclient.post("/jobs", json={"stage": "shots/edited.usda", "settings": dict(TINY)})
        assert checked(cclient, r.json()["id"])["state"] == "queued"
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(CUBE_TEX.format(tex="../../outside/secret.png") + "\n")
    r = cclient.post("/jobs", json={"stage": "shots/edited.usda", "settings": dict(TINY)})
    job = checked(cclient, r.json()["id"])
    assert job["state"] == "failed" and "/M/T.inputs:file" in job["error"]


def test_the_worker_checks_again_before_rendering(tmp_path):
    """A stage that reaches out only after its job was queued is failed by the worker, with the
    same message (a worker started by hand learns the stage root from jobs.db)."""
    root = make_stage_root(tmp_path / "root")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.usda").write_text('#usda 1.0\ndef Xform "Secret" {}\n')
    s = start_server(tmp_path, root, workers=0, wait_workers=False)
    try:
        with s.client() as c:
            jid = c.post("/jobs", json={"stage": "shots/a.usda", "settings": dict(TINY)}).json()["id"]
            assert checked(c, jid)["state"] == "queued"  # the server's check passed it
            path = os.path.join(root, "shots", "a.usda")
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(text + '\ndef "Late" (\n    references = @../../outside/secret.usda@\n) {}\n')
            worker = subprocess.run([sys.executable, "-m", "service.worker", "--data", s.data, "--id", "by-hand",
                                     "--max-jobs", "1"], cwd=str(tmp_path), capture_output=True, text=True,
                                    timeout=120, stdin=subprocess.DEVNULL)
            assert worker.returncode == 0, worker.stderr[-2000:]
            done = wait_job(c, jid)
            assert done["state"] == "failed" and done["attempts"] == 1
            assert done["error"] == ("shots/a.usda: /Late.references: asset path '../../outside/secret.usda' "
                                     "leads outside the stage root"), done["error"]
            assert not os.path.exists(os.path.join(s.data, "jobs", jid, "final.exr"))
    finally:
        s.stop()


def test_a_timed_out_check_is_cached_while_the_stage_is_unchanged(tmp_path):
    """Resubmitting a stage whose check timed out must not hold a checking slot for another full
    timeout each time: the timeout is cached, keyed on the stage file, and forgotten when it
    changes."""
    from service.assets import AssetChecker

    root = make_stage_root(tmp_path / "root")
    stage = os.path.join(root, "shots", "hang.usda")
    write_fifo_clip_stage(stage)  # the check blocks opening the clip layer
    checker = AssetChecker(root, str(tmp_path / "uploads"), timeout=2.0)
    runs = []
    real = checker._run_child
    checker._run_child = lambda *a: runs.append(a) or real(*a)
    first = checker.check(stage, upload=False)
    assert (first.error, first.checked) == (None, False) and "timed out" in first.reason
    again = checker.check(stage, upload=False)
    assert (again.checked, again.reason, len(runs)) == (False, first.reason, 1)
    with open(stage, "w", encoding="utf-8") as fh:
        fh.write("#usda 1.0\n")
    checker.check(stage, upload=False)  # (its verdict depends on how fast a child starts here)
    assert len(runs) == 2  # the changed stage file was checked again
