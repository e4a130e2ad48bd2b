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


# Records every blob the page turns into a URL ([url, blob]): the page's CSP keeps fetch() away
# from blob: URLs, so a test reads the blob itself.
CAPTURE_BLOBS = ("window.__blobs = []; const __make = URL.createObjectURL;"
                 " URL.createObjectURL = (blob) => { const u = __make(blob); window.__blobs.push([u, blob]); return u; }")


def _enter_token(b: Browser, value: str) -> None:
    b.eval("(() => { const t = document.getElementById('token'); t.value = " + json.dumps(value) + ";"
           " t.dispatchEvent(new Event('change')); return true; })()")


def _only_refusals(b: Browser, codes=(401,)) -> list:
    """Browser errors other than the refused loads a test caused on purpose."""
    return [e for e in b.js_errors() if e.get("method") != "Log.entryAdded"
            or e["params"]["entry"].get("source") != "network"
            or not any(f"status of {c}" in e["params"]["entry"]["text"] for c in codes)]


@pytest.fixture(scope="module")
def token_server(tmp_path_factory, stage_root):
    s = start_server(tmp_path_factory.mktemp("page-token"), stage_root, workers=1, env={"ILLUM_TOKEN": "page-token"})
    yield s
    s.stop()


def test_page_sends_the_token(token_server, browser):
    """On a server with ILLUM_TOKEN, reads need the token too: the page shows nothing but the
    token field until it is entered, then lists stages and jobs, shows the preview, and fetches
    the log with the token (a plain link could not send it)."""
    s, b = token_server, browser
    b.goto(s.url + "/")
    b.wait("!document.getElementById('token-row').hidden", what="the token field")
    msg = b.wait("(() => { const t = document.getElementById('message').textContent;"
                 " return t.includes('HTTP 401') ? t : null; })()", what="the refused stage list")
    assert msg.startswith("cannot list stages")
    assert b.wait("document.getElementById('health').textContent.includes('access token')")
    assert b.eval("document.querySelectorAll('#stage option').length") == 0
    _enter_token(b, "page-token")
    b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
    b.wait("document.getElementById('message').textContent === ''", what="the 401 message to go")
    b.wait("document.getElementById('health').textContent.includes('workers')", what="the full health line")
    job_id = _submit_from_page(b, "shots/a.usda", spp="4", w="16", h="16")
    with s.client(token="page-token") as c:
        assert wait_job(c, job_id)["state"] == "succeeded"
    b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"]').dataset.state === 'succeeded'")
    b.wait("document.getElementById('preview').dataset.kind === 'final'", what="the final image")
    assert b.wait(PIXEL_SUM, what="the preview pixels")[:2] == [16, 16]
    b.wait("document.getElementById('log').textContent.includes('succeeded')", what="the log tail")
    # the log link opens a blob: URL of the text fetched with the token
    b.eval(CAPTURE_BLOBS + "; window.__opened = null; window.open = (u) => { window.__opened = u; return null; };"
           " document.getElementById('log-link').click(); true")
    url = b.wait("window.__opened", what="the log link to open")
    assert url.startswith("blob:")
    assert "attempt 1 of" in b.eval("window.__blobs.find(x => x[0] === " + json.dumps(url) + ")[1].text()")
    assert _only_refusals(b) == []


def test_docs_render_offline(server, browser):
    """Swagger UI comes from the server itself: the machine has no route to a CDN, so the
    operations list appears only if the local files work."""
    b = browser
    b.goto(server.url + "/docs")
    b.wait("document.querySelectorAll('.opblock').length >= 10", timeout=60, what="the Swagger operations")
    assert "illum render service" in b.eval("document.querySelector('.info .title').textContent")
    assert b.eval("[...document.scripts].every(s => !s.src || s.src.startsWith(location.origin))")
    assert b.js_errors() == []


@pytest.mark.slow
def test_page_token_flow_and_errors(tmp_path, stage_root):
    """With ILLUM_TOKEN set the page asks for the token, shows a refused request's message (a
    wrong token too), and submits once the right token is entered; server-side validation
    messages reach the user; the EXR download carries the token."""
    s = start_server(tmp_path, stage_root, workers=1, env={"ILLUM_TOKEN": "page-token"})
    b = Browser()
    try:
        b.goto(s.url + "/")
        b.wait("!document.getElementById('token-row').hidden", what="the token field")
        b.wait("document.getElementById('message').textContent.includes('HTTP 401')", what="the refusal")
        _enter_token(b, "wrong-token")
        b.wait("document.getElementById('message').textContent.includes('HTTP 401')", what="the refusal again")
        assert b.eval("document.querySelectorAll('#stage option').length") == 0
        _enter_token(b, "page-token")
        b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
        b.eval("(() => { document.getElementById('spp').value = '999999'; document.getElementById('submit-btn').click();"
               " return true; })()")
        msg = b.wait("(() => { const t = document.getElementById('message').textContent;"
                     " return t.includes('settings.spp') ? t : null; })()", what="the limit message")
        assert "exceeds the server limit" in msg
        job_id = _submit_from_page(b, "shots/a.usda", spp="4", w="32", h="32")
        with s.client(token="page-token") as c:
            assert wait_job(c, job_id)["state"] == "succeeded"
        b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"]').dataset.state === 'succeeded'")
        b.wait("document.getElementById('preview').dataset.kind === 'final'", what="the final image")
        b.wait("!document.getElementById('exr-link').hidden", what="the EXR link")
        # the download is a blob: URL of bytes fetched with the token
        b.eval(CAPTURE_BLOBS + "; window.__dl = null; const orig = HTMLAnchorElement.prototype.click;"
               " HTMLAnchorElement.prototype.click = function () { if (this.download) window.__dl = [this.href, this.download];"
               " else orig.call(this); }; document.getElementById('exr-link').click(); true")
        href, name = b.wait("window.__dl", what="the EXR download")
        assert href.startswith("blob:") and name == f"{job_id}.exr"
        head = b.eval("window.__blobs.find(x => x[0] === " + json.dumps(href) + ")[1].arrayBuffer()"
                      ".then(a => [...new Uint8Array(a.slice(0, 4))])")
        assert head == [0x76, 0x2F, 0x31, 0x01]  # the OpenEXR magic number
        b.screenshot(str(tmp_path / "done.png"))
        assert os.path.getsize(tmp_path / "done.png") > 1000
        # the refused requests above are logged as failed loads (401, 422); nothing else may be
        assert _only_refusals(b, (401, 422)) == []
    finally:
        b.close()
        s.stop()


def test_page_shows_per_frame_progress(server, client, browser):
    """A frame range submitted from the page: the job's row counts its frames, the selected job
    shows one cell per frame with its state as the range renders (one done while the next runs),
    and clicking a rendered frame shows that frame's image."""
    b = browser
    b.goto(server.url + "/")
    b.wait("document.querySelectorAll('#stage option').length > 0", what="the stage list")
    b.eval("document.getElementById('frames').value = '1-3', true")
    job_id = _submit_from_page(b, "cornell_box.usda", spp="60000", time_budget="2", w="16", h="16")
    job = client.get(f"/jobs/{job_id}").json()
    assert job["settings"]["frames"] == "1-3" and [f["frame"] for f in job["frames"]] == [1.0, 2.0, 3.0]
    cells = "[...document.querySelectorAll('#frame-strip .frame')].map(c => c.dataset.state)"
    mixed = b.wait(f"(() => {{ const s = {cells}; return s.length === 3 && s[0] === 'succeeded' && "
                   "s[1] === 'running' ? s : null; })()", timeout=120, what="frame 1 done while frame 2 renders")
    assert mixed[2] == "queued"
    b.wait(f"(() => {{ const s = {cells}; return s.every(x => x === 'succeeded') ? s : null; }})()", timeout=120,
           what="every frame done")
    b.wait("document.getElementById('sel-frames-text').textContent === '3 of 3 done'", what="the frame summary")
    b.wait(f"document.querySelector('#jobs-body tr[data-id=\"{job_id}\"] .frames-done').textContent === '3/3 frames'",
           what="the row's frame count")
    b.eval("document.querySelectorAll('#frame-strip .frame')[1].click(), true")
    b.wait("document.getElementById('preview').dataset.kind === 'frame'", what="frame 2's image")
    assert b.wait(PIXEL_SUM, what="the frame's pixels")[:2] == [16, 16]
    assert b.eval("document.querySelectorAll('#frame-strip .frame.shown').length") == 1
    assert b.js_errors() == []
