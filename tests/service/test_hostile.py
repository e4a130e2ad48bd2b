"""Hostile requests against a real server: each gets an error naming the field (never a 500),
and none changes what the server holds or shows."""

from __future__ import annotations

import json
import os
import re
import shutil

import pytest

from .conftest import TINY, wait_job


def _post_raw(client, body: bytes):
    return client.post("/jobs", content=body, headers={"Content-Type": "application/json"})


def test_absurd_numbers_in_queries_are_refused(client):
    for params, field in (({"offset": 10**30}, "offset"), ({"offset": -1}, "offset"), ({"limit": 10**30}, "limit"),
                          ({"limit": 0}, "limit")):
        r = client.get("/jobs", params=params)
        assert r.status_code == 422, (params, r.text)
        assert r.json()["message"].startswith(f"query.{field}: "), r.json()
    r = client.get("/jobs/0123456789abcdef/log", params={"tail": 10**30})
    assert r.status_code == 422 and r.json()["message"].startswith("query.tail: ")


@pytest.mark.parametrize("settings, field", [
    ({"camera": "/World/Cam\x00era"}, "settings.camera"),
    ({"settings_prim": "/Render/\nSettings"}, "settings.settings_prim"),
    ({"purposes": ["render", "x" * 100]}, "settings.purposes"),
    ({"purposes": ["render; rm -rf /"]}, "settings.purposes"),
    ({"estimator": {"/Light\x00": "mis"}}, "settings.estimator"),
    ({"light_samples": {f"/L{i}": 1 for i in range(5000)}}, "settings.light_samples"),
    ({"spp": 10**40}, "settings.spp"),
    ({"resolution": [2**70, 2**70]}, "settings.resolution"),
    ({"frame": "NaN"}, "settings.frame"),
])
def test_hostile_settings_name_the_field(client, settings, field):
    r = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": settings})
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith(field + ": "), r.json()["message"]


def test_bad_unicode_and_deep_json(client):
    # a lone surrogate cannot become a file name or a database string
    for body, field in ((b'{"stage": "\\ud800.usda"}', "stage"),
                        (b'{"stage": "cornell_box.usda", "idempotency_key": "\\udfff"}', "idempotency_key"),
                        (b'{"stage": "cornell_box.usda", "settings": {"camera": "/\\ud800"}}', "settings.camera")):
        r = _post_raw(client, body)
        assert r.status_code == 422 and r.json()["message"].startswith(field + ": "), r.text
    r = _post_raw(client, b'{"settings": ' + b"[" * 100_000 + b"]" * 100_000 + b"}")
    assert r.status_code == 400 and r.json()["message"].startswith("body: "), r.text
    r = _post_raw(client, b"\xff\xfe not json")
    assert r.status_code == 400 and r.json()["message"].startswith("body: "), r.text
    # 1e400 parses as infinity
    r = _post_raw(client, b'{"stage": "cornell_box.usda", "settings": {"time_budget": 1e400}}')
    assert r.status_code == 422 and r.json()["message"].startswith("settings.time_budget: "), r.text


def test_unicode_stage_names_work(server, client):
    name = "shots/ünïcødé ✓ 渲染.usda"
    shutil.copy(os.path.join(server.stage_root, "cornell_box.usda"), os.path.join(server.stage_root, name))
    r = client.post("/jobs", json={"stage": name, "settings": dict(TINY)})
    assert r.status_code == 201, r.text
    assert r.json()["stage"] == name
    done = wait_job(client, r.json()["id"])
    assert done["state"] == "succeeded", done
    assert name in client.get("/stages").json()["stages"]
    up = client.post("/uploads", params={"filename": "ショット.usda"}, content=b"#usda 1.0\n")
    assert up.status_code == 201 and re.fullmatch(r"[0-9a-f]{16}-stage\.usda", up.json()["upload"]), up.text


@pytest.mark.parametrize("url", ["/jobs/..%2F..%2Fjobs.db", "/jobs/..%2F..%2Fjobs.db/log", "/jobs/%2e%2e/log",
                                 "/jobs/0123456789abcdef%2F..%2F..%2Fjobs.db/image",
                                 "/static/..%2Fapp.py", "/static/%2e%2e/config.py",
                                 "/docs/assets/..%2F..%2Fapp.py", "/docs/assets/swagger-editor.js"])
def test_traversal_in_ids_and_file_names(client, url):
    r = client.get(url)
    assert r.status_code in (404, 422), (url, r.status_code)
    assert b"SQLite format" not in r.content and b"import" not in r.content
    assert r.json()["message"]


def test_made_up_methods_do_not_grow_the_metrics(client):
    for i in range(20):
        r = client.request(f"X-METHOD-{i}", "/jobs")
        assert r.status_code == 405 and r.json()["message"]
    text = client.get("/metrics").text
    assert "X-METHOD" not in text
    # prometheus-client writes labels sorted by name
    assert re.search(r'illum_http_requests_total\{code="405",method="other"\} \d+', text)


def test_refused_requests_change_nothing(client):
    before = client.get("/jobs", params={"limit": 1000}).json()["total"]
    for body in ({"stage": "cornell_box.usda", "settings": {"camera": "not a prim"}},
                 {"stage": "../outside.usda"}, {"stage": "cornell_box.usda", "priority": 101},
                 {"stage": "cornell_box.usda", "upload": "0123456789abcdef-x.usda"}):
        assert client.post("/jobs", json=body).status_code in (400, 422)
    assert client.get("/jobs", params={"limit": 1000}).json()["total"] == before
    assert client.get("/health").json()["status"] == "ok"


def test_docs_are_served_offline(client):
    page = client.get("/docs")
    assert page.status_code == 200
    refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert refs and all(u.startswith("/") and not u.startswith("//") for u in refs), refs
    assert "cdn" not in page.text.lower() and '"validatorUrl": null' in page.text
    for name, kind in (("swagger-ui-bundle.js", "javascript"), ("swagger-ui.css", "text/css")):
        r = client.get(f"/docs/assets/{name}")
        assert r.status_code == 200 and kind in r.headers["content-type"] and len(r.content) > 10_000
    assert json.loads(client.get("/openapi.json").text)["info"]["title"] == "illum render service"
