"""Every render option declared in renderer/options.py reaches render() through each of its
routes: ``illum render`` flags, ``illum submit`` flags against a real server, and the HTTP API.

The tests enumerate the declaration: a new option is covered by adding it, and one a route drops
fails here. What render() received is read back from the render's statistics (``options``: the
RenderOptions it ran with), for the service through ``GET /jobs/{id}/stats``. Bad values are
refused on every route, before any work, with the declaration's message naming the option.
"""

from __future__ import annotations

import argparse
import json
import math

import pytest

from renderer import options
from renderer.options import OPTIONS, ROUTES
from renderer.render import RenderOptions

from .conftest import STAGES, wait_job

STAGE = "cornell_box.usda"
LIGHT = "/World/Lights/CeilingLight"
# Values that depend on the stage; every other option brings its own example.
STAGE_VALUES = {"camera": "/World/Camera", "settings": "/Render/Settings"}


def _value(o):
    """A valid non-default value of ``o`` for cornell_box.usda; per-light options also name the
    light itself, so both the all-lights and the one-light spelling travel."""
    v = STAGE_VALUES.get(o.name, o.example)
    assert v is not None, f"option {o.name!r} declares no example (renderer/options.py): the route tests need one"
    if o.kind == "per_light":
        (x,) = v.values()
        v = {"": x, LIGHT: x}
    assert v != o.default_value(), f"{o.name}: the example equals the default, so it proves nothing"
    options.check(o, v)
    return v


VALUES = {o.name: _value(o) for o in OPTIONS}


def _on(route):
    return [o for o in OPTIONS if route in o.routes]


def _expected(route) -> dict:
    """The options render() must have seen, as JSON: the examples on ``route``'s options."""
    want = RenderOptions(**{o.name: VALUES[o.name] for o in _on(route)}).as_json()
    return {o.name: want[o.name] for o in _on(route)}


def _flags(o, v) -> list[str]:
    """Command-line words that set option ``o`` to ``v`` (the inverse of the parser)."""
    flag = o.flags[0]
    if o.kind == "bool":
        return [flag if v else "--no-" + flag[2:]]
    if o.kind == "int_pair":
        return [flag, *map(str, v)]
    if o.kind == "str_list":
        return [flag, ",".join(v)]
    if o.kind == "per_light":
        return [w for k, x in v.items() for w in (flag, f"{k or '*'}={x}")]
    return [flag, repr(v) if isinstance(v, float) else str(v)]


def _args(route, values) -> list[str]:
    return [w for o in _on(route) if o.name in values for w in _flags(o, values[o.name])]


def _body(values) -> dict:
    return {o.api_name: options.to_json(o, values[o.name]) for o in _on("api") if o.name in values}


@pytest.fixture
def illum(capsys, monkeypatch):
    """``illum ...`` in this process: (exit code, stdout, stderr)."""
    from renderer.cli import main

    monkeypatch.delenv("ILLUM_TOKEN", raising=False)

    def run(*args):
        capsys.readouterr()
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out, err
    return run


# ---------------------------------------------------------------------------- the declaration
def test_every_option_is_on_every_route_or_says_why():
    for o in OPTIONS:
        assert set(o.routes) <= set(ROUTES), o.name
        assert set(o.routes) == set(ROUTES) or o.off_route, f"{o.name} is not on {set(ROUTES) - set(o.routes)}"
        assert ("api" in o.routes) == bool(o.api_name), o.name
        assert o.flags or not ({"render", "submit"} & set(o.routes)), f"{o.name} is on the CLI without a flag"


def test_the_routes_offer_exactly_the_declared_options():
    """No flag or request field exists outside the declaration, and none declared is missing."""
    from renderer.cli import build_parser
    from service.models import RenderSettings

    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    declared = {o.name for o in OPTIONS}
    # `illum render`'s own flags: where its files go and how they are written, and what it prints.
    # Both take a frame range: RANGE_OPTIONS, declared beside OPTIONS (not render() options).
    ranges = {o.name for o in options.RANGE_OPTIONS}
    own_render = {"stage", "output", "preview", "stats", "quiet", "debug", "help", "make_output_path",
                  "exr_compression", "half", "verbosity", "version"}
    for route, own in (("render", own_render),
                       ("submit", {"stage", "server", "upload", "kind", "priority", "idempotency_key",
                                   "max_attempts", "size", "method", "wait", "output", "quiet", "help"})):
        dests = {a.dest for a in sub.choices[route]._actions}
        assert dests - own - ranges == {o.name for o in _on(route)}, route
        assert ranges <= dests and not (own & declared), route
    assert set(RenderSettings.model_fields) == {o.api_name for o in (*_on("api"), *options.RANGE_OPTIONS)}
    assert set(RenderOptions.__dataclass_fields__) == declared


# ---------------------------------------------------------------------------- good values
def test_every_option_reaches_render_through_illum_render(illum, tmp_path):
    stats = tmp_path / "stats.json"
    code, _, err = illum("render", f"{STAGES}/{STAGE}", "-o", tmp_path / "o.exr", "--stats", stats, "--quiet",
                         *_args("render", VALUES))
    assert code == 0, err
    seen = json.loads(stats.read_text())["options"]
    assert {k: seen[k] for k in _expected("render")} == _expected("render")


def _job_options(client, job_id) -> dict:
    job = wait_job(client, job_id, timeout=180)
    assert job["state"] == "succeeded", job
    r = client.get(f"/jobs/{job_id}/stats")
    assert r.status_code == 200, r.text
    return r.json()["options"]


def test_every_option_reaches_render_through_illum_submit(server, client, illum):
    code, out, err = illum("submit", STAGE, "--server", server.url, "--wait", "--quiet", *_args("submit", VALUES))
    assert code == 0, err
    seen = _job_options(client, out.split()[0])
    assert {k: seen[k] for k in _expected("submit")} == _expected("submit")


def test_every_option_reaches_render_through_the_http_api(client):
    r = client.post("/jobs", json={"stage": STAGE, "settings": _body(VALUES)})
    assert r.status_code == 201, r.text
    seen = _job_options(client, r.json()["id"])
    assert {k: seen[k] for k in _expected("api")} == _expected("api")


# ---------------------------------------------------------------------------- bad values
def _bad(o):
    """A value of ``o``'s own type that its declaration refuses, or None when there is none
    (a flag that takes no value)."""
    kind = o.value_kind
    if o.choices is not None:
        v = "nonsense"
    elif kind == "str":
        v = "bad value" if o.pattern else None
    elif kind == "int":
        v = o.lo - 1 if o.lo is not None else o.hi + 1
    elif kind == "float":
        v = float(o.lo if o.lo is not None and o.lo_open else (o.lo - 1 if o.lo is not None else math.inf))
    else:
        return None
    if o.kind == "int_pair":
        return (v, 5)
    if o.kind == "str_list":
        return ("bad-token",)
    if o.kind == "per_light":
        return {"": v}
    return v


BAD = [o for o in OPTIONS if _bad(o) is not None]


def _message(o, v) -> str:
    """The declaration's message for the bad value: the same on every route."""
    with pytest.raises(ValueError) as e:
        options.check(o, v)
    return str(e.value)


def test_every_option_with_values_has_a_bad_one():
    assert {o.name for o in OPTIONS} - {o.name for o in BAD} == {o.name for o in OPTIONS if o.kind == "bool"}


@pytest.mark.parametrize("o", BAD, ids=[o.name for o in BAD])
def test_bad_values_are_refused_by_illum_render(o, illum, tmp_path):
    v = _bad(o)
    code, _, err = illum("render", tmp_path / "never_read.usda", "-o", tmp_path / "o.exr", *_flags(o, v))
    assert code == 2
    assert err == f"illum: error: {o.name}: {_message(o, v)}\n"  # one line, before the stage is opened
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("o", [o for o in BAD if "submit" in o.routes], ids=lambda o: o.name)
def test_bad_values_are_refused_by_illum_submit(o, server, client, illum):
    before = client.get("/jobs", params={"limit": 1000}).json()["total"]
    v = _bad(o)
    code, _, err = illum("submit", STAGE, "--server", server.url, *_flags(o, v))
    assert code == 2
    assert err == f"illum: error: {o.name}: {_message(o, v)}\n"
    assert client.get("/jobs", params={"limit": 1000}).json()["total"] == before  # nothing was sent


@pytest.mark.parametrize("o", [o for o in BAD if "api" in o.routes], ids=lambda o: o.name)
def test_bad_values_are_refused_by_the_http_api(o, client):
    v = _bad(o)
    body = json.dumps({"stage": STAGE, "settings": {o.api_name: options.to_json(o, v)}}, allow_nan=True)
    r = client.post("/jobs", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    d = r.json()["detail"][0]
    assert d["loc"] == ["body", "settings", o.api_name]
    assert d["msg"] == _message(o, options.normalise(o, v))


def test_a_value_of_the_wrong_type_is_refused_by_the_http_api(client):
    for o in OPTIONS:
        if "api" not in o.routes:
            continue
        wrong = "four" if o.value_kind in ("int", "float", "bool") else 4
        r = client.post("/jobs", json={"stage": STAGE, "settings": {o.api_name: wrong}})
        assert r.status_code == 422, (o.name, r.text)
        assert r.json()["detail"][0]["loc"][:3] == ["body", "settings", o.api_name], o.name
