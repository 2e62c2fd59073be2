"""The OpenAPI 3.1 description (docs/openapi.yaml): served at /openapi.json as the same
document, well-formed, and covering every route; conftest's http() checks every REST
answer of the suite against it (openapi_check.py)."""

from __future__ import annotations

import json

from jsonschema import Draft202012Validator

import openapi_check
from conftest import http, http_json, uniform


def test_served_document_is_the_yaml_one_and_well_formed(server):
    status, headers, body = http("GET", f"{server.http}/openapi.json")
    assert status == 200 and headers["Content-Type"].startswith("application/json")
    served = json.loads(body)
    assert served == openapi_check.SPEC
    assert served["openapi"] == "3.1.0"
    for schema in served["components"]["schemas"].values():
        Draft202012Validator.check_schema(schema)
    routes = set(served["paths"])
    for route in ["/v1/pointsets", "/v1/pointsets/{id}", "/v1/pointsets/{id}/seeds/{seed}/star",
                  "/v1/pointsets/{id}/seeds/{seed}/neighbors", "/v1/pointsets/{id}/seeds/{seed}/cell",
                  "/v1/pointsets/{id}/simplices", "/v1/pointsets/{id}/cells", "/v1/pointsets/{id}/stars:batch",
                  "/v1/pointsets/{id}/neighbors:batch", "/v1/pointsets/{id}/cells:batch", "/healthz", "/readyz",
                  "/metrics", "/openapi.json"]:
        assert route in routes, route


def test_every_route_answers_as_described(server):
    before = openapi_check.checked["responses"]
    base = f"{server.http}/v1/pointsets"
    status, ps = http_json("POST", base, {"points": uniform(200, 2, 1).tolist(), "display_name": "d"})
    assert status == 201
    pid = ps["id"]
    assert http_json("POST", base, {"dimension": 2, "coordinates": uniform(200, 2, 1).ravel().tolist()})[0] == 200
    for path in ["", f"/{pid}", f"/{pid}/seeds/3/star", f"/{pid}/seeds/3/neighbors",
                 f"/{pid}/seeds/3/neighbors?mode=approximate", f"/{pid}/seeds/3/cell",
                 f"/{pid}/seeds/3/cell?bounding_box=true", f"/{pid}/simplices?shard=0&shards=2",
                 f"/{pid}/cells?measures_only=true", f"/{pid}/seeds/999/star", "/nope"]:
        http("GET", base + path)
    for kind in ("stars", "neighbors", "cells"):
        http("POST", f"{base}/{pid}/{kind}:batch", {"seeds": [0, 1, 2], "box": [0, 0, 1, 1]} if kind == "cells"
             else {"seeds": [0, 1, 2]})
    http("GET", f"{server.http}/healthz")
    http("GET", f"{server.http}/readyz")
    http("GET", f"{server.http}/nothing/here")
    http("DELETE", f"{base}/{pid}")
    assert openapi_check.checked["responses"] - before >= 18


def test_weighted_and_periodic_answers_as_described(server):
    """Weights and periodic boxes add fields (weighted, periodic_box, hidden, offsets):
    each answer still matches the description."""
    before = openapi_check.checked["responses"]
    base = f"{server.http}/v1/pointsets"
    pts = uniform(150, 2, 7)
    weights = (uniform(150, 1, 8).ravel() * 1e-3).tolist()
    status, ps = http_json("POST", base, {"points": pts.tolist(), "weights": weights, "periodic_box": [0, 0, 1, 1]})
    assert status == 201 and ps["weighted"] and ps["periodic_box"] == [0, 0, 1, 1]
    pid = ps["id"]
    for path in [f"/{pid}", f"/{pid}/seeds/3/star", f"/{pid}/seeds/3/neighbors", f"/{pid}/seeds/3/cell",
                 f"/{pid}/simplices", f"/{pid}/cells", f"/{pid}/seeds/3/cell?box=0,0,1,1"]:
        http("GET", base + path)
    for kind in ("stars", "neighbors", "cells"):
        http("POST", f"{base}/{pid}/{kind}:batch", {"seeds": [0, 5]})
    status, weighted = http_json("POST", base, {"points": pts.tolist(), "weights": weights})
    assert status == 201 and weighted["weighted"] and "periodic_box" not in weighted
    http("GET", f"{base}/{weighted['id']}/seeds/3/star")
    assert openapi_check.checked["responses"] - before >= 13
