"""``service.fastpath``: GLB synthesis answered outside FastAPI's routing gives the route's
answer, byte for byte, and leaves every other case (errors included) to the route.

``Content-Type: application/json; charset=utf-8`` is not taken by the short path, so it gives
the route's own answer to compare with.
"""

from __future__ import annotations

import pytest

SYN = "/v1/models/default/synthesize"
FAST = {"Content-Type": "application/json"}
ROUTE = {"Content-Type": "application/json; charset=utf-8"}
BODIES = [
    {"sex": "female", "height_m": 1.62, "weight_kg": 58},
    {"sex": "male", "height_m": 1.81, "weight_kg": 84, "age": 40},
    {"sex": "male", "seed": 11},
    {"sex": "female", "pca": [0.01, -0.02]},
    {"sex": "male", "height_m": 1.85, "weight_kg": 141},  # extrapolated: a warnings header
    {"sex": "female", "height_m": 1.40, "weight_kg": 107.8, "age": 70},
]


def _post(client, body, headers):
    import json

    return client.post(SYN, content=json.dumps(body), headers=headers)


def _warm(client):
    r = _post(client, BODIES[0], ROUTE)  # loads the model, fills the key cache
    assert r.status_code == 200, r.text


@pytest.mark.parametrize("body", BODIES)
def test_short_path_answers_as_the_route(client, body):
    _warm(client)
    fast, route = _post(client, body, FAST), _post(client, body, ROUTE)
    assert fast.status_code == route.status_code == 200
    assert fast.content == route.content
    for h in ("content-type", "content-length"):
        assert fast.headers[h] == route.headers[h]
    assert set(fast.headers) == set(route.headers)
    warned = fast.headers.get("x-bodyspace-warnings")
    assert warned == route.headers.get("x-bodyspace-warnings")
    assert (warned is not None) == (body.get("weight_kg", 0) > 100)


@pytest.mark.parametrize(
    ("body", "status", "code"),
    [
        ({"sex": "female", "height_m": 3.5}, 422, "out_of_range"),
        ({"sex": "other"}, 422, "validation_error"),
        ({"height_m": 1.7}, 422, "missing_field"),
        ({"sex": "male", "pca": [1e9]}, 422, "out_of_range"),
        ({"sex": "male", "chest": "wide"}, 422, "validation_error"),
    ],
)
def test_errors_after_warm_up_are_the_routes(client, body, status, code):
    """With the model loaded and the key cached, bad bodies still get the route's errors (the
    body read by the short path is replayed to the app)."""
    _warm(client)
    fast, route = _post(client, body, FAST), _post(client, body, ROUTE)
    assert fast.status_code == route.status_code == status, fast.text
    assert fast.json() == route.json()
    assert fast.json()["error"]["code"] == code


def test_unparsable_json_and_keys_take_the_route(client, server):
    _warm(client)
    r = client.post(SYN, content=b'{"sex": "female",', headers=FAST)
    assert r.status_code == 422 and r.json()["error"]["code"] == "validation_error"
    import httpx

    key = client.headers["authorization"].split()[-1]
    with httpx.Client(base_url=server["url"], timeout=60) as anon:
        body = {"sex": "female", "height_m": 1.7}
        assert _post(anon, body, FAST).status_code == 401
        bad = {**FAST, "Authorization": "Bearer not-a-key"}
        assert _post(anon, body, bad).json()["error"]["code"] == "invalid_api_key"
        xkey = {**FAST, "X-API-Key": key}
        assert _post(anon, body, xkey).status_code == 200
        js = {**FAST, "Authorization": f"Bearer {key}", "Accept": "application/json"}
        r = _post(anon, body, js)
        assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    r = client.post("/v1/models/nope/synthesize", content=b'{"sex": "male"}', headers=FAST)
    assert r.status_code == 404
