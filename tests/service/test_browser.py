"""The web page in a real headless Chromium: load it, submit a stage from the stage root, watch
the progressive preview change without a reload, cancel the job."""

from __future__ import annotations

import json
import os

import pytest

from .browser import Browser
from .conftest import start_server, wait_job

# A canvas checksum of the preview <img>: changes when the progressive image changes.
PIXEL_SUM = """(() => { const img = document.getElementById('preview');
  if (img.hidden || !img.complete || !img.naturalWidth) return null;
  const c = document.createElement('canvas'); c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d'); g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data; let s = 0;
  for (let i = 0; i < d.length; i += 1) s = (s * 31 + d[i]) % 1000000007;
  return [c.width, c.height, s]; })()"""


@pytest.fixture
def browser():
    b = Browser()
    yield b
    b.close()


def _submit_from_page(b: Browser, stage: str, *, spp="", time_budget="", w="", h="") -> str:
    b.eval(f"""(() => {{ const set = (id, v) => {{ document.getElementById(id).value = v; }};
        document.getElementById('message').textContent = '';
        set('stage', {json.dumps(stage)}); set('spp', {json.dumps(spp)}); set('time-budget', {json.dumps(time_budget)});
        set('res-w', {json.dumps(w)}); set('res-h', {json.dumps(h)});
        document.getElementById('submit-btn').click(); return true; }})()""")
    msg = b.wait("(() => { const t = document.getElementById('message').textContent;"
                 " return t.startsWith('Submitted job') || t.includes('HTTP') ? t : null; })()",
                 what="the submit answer")
    assert msg.startswith("Submitted job"), msg
    return msg.split()[2]


def test_page_submit_preview_cancel(server, client, browser, tmp_path):
    b = browser
    b.goto(server.url + "/")
    b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
    stages = b.eval("[...document.querySelectorAll('#stage option')].map(o => o.value)")
    assert "cornell_box.usda" in stages and "shots/a.usda" in stages
    assert b.wait("document.getElementById('health').textContent.includes('workers')", what="the health line")

    # A long progressive render: 48x48 until canceled, snapshots every 0.5 s on this server.
    job_id = _submit_from_page(b, "cornell_box.usda", spp="60000", time_budget="60", w="48", h="48")
    assert client.get(f"/jobs/{job_id}").json()["settings"]["resolution"] == [48, 48]
    b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"].selected') !== null",
           what="the new job's row, selected")
    first = b.wait(PIXEL_SUM, timeout=60, what="the first preview")
    assert first[:2] == [48, 48]
    first_spp = int(b.eval("document.getElementById('preview').dataset.spp || '0'"))
    changed = b.wait(f"(() => {{ const v = {PIXEL_SUM}; return v && v[2] !== {first[2]} ? v : null; }})()",
                     timeout=60, what="the preview to change")
    assert changed[:2] == [48, 48]
    assert int(b.eval("document.getElementById('preview').dataset.spp || '0'")) > first_spp
    assert b.eval("performance.getEntriesByType('navigation').length") == 1  # never reloaded
    b.screenshot(str(tmp_path / "running.png"))

    assert b.eval("!document.getElementById('cancel-btn').disabled")
    b.eval("document.getElementById('cancel-btn').click(), true")
    b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"]').dataset.state === 'canceled'",
           what="the row to show canceled")
    assert client.get(f"/jobs/{job_id}").json()["state"] == "canceled"
    assert b.wait("document.getElementById('cancel-btn').disabled")
    assert b.js_errors() == []


@pytest.mark.slow
def test_page_token_flow_and_errors(tmp_path, stage_root):
    """With ILLUM_TOKEN set the page asks for the token, shows a refused request's message, and
    submits once the token is entered; server-side validation messages reach the user."""
    s = start_server(tmp_path, stage_root, workers=1, env={"ILLUM_TOKEN": "page-token"})
    b = Browser()
    try:
        b.goto(s.url + "/")
        b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
        b.wait("!document.getElementById('token-row').hidden", what="the token field")
        b.eval("document.getElementById('submit-btn').click(), true")
        msg = b.wait("(() => { const t = document.getElementById('message').textContent; return t || null; })()")
        assert "HTTP 401" in msg
        b.eval("(() => { const t = document.getElementById('token'); t.value = 'page-token';"
               " t.dispatchEvent(new Event('change')); return true; })()")
        b.eval("(() => { document.getElementById('spp').value = '999999'; document.getElementById('submit-btn').click();"
               " return true; })()")
        msg = b.wait("(() => { const t = document.getElementById('message').textContent;"
                     " return t.includes('settings.spp') ? t : null; })()", what="the limit message")
        assert "exceeds the server limit" in msg
        job_id = _submit_from_page(b, "shots/a.usda", spp="4", w="32", h="32")
        with s.client() as c:
            assert wait_job(c, job_id)["state"] == "succeeded"
        b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"]').dataset.state === 'succeeded'")
        b.wait("document.getElementById('preview').dataset.kind === 'final'", what="the final image")
        b.screenshot(str(tmp_path / "done.png"))
        assert os.path.getsize(tmp_path / "done.png") > 1000
        # the refused requests above are logged as failed loads (401, 422); nothing else may be
        unexpected = [e for e in b.js_errors() if e.get("method") != "Log.entryAdded"
                      or e["params"]["entry"].get("source") != "network"
                      or not any(f"status of {c}" in e["params"]["entry"]["text"] for c in (401, 422))]
        assert unexpected == []
    finally:
        b.close()
        s.stop()
