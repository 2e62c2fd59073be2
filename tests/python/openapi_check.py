"""Validates REST answers against docs/openapi.yaml. conftest's http()
calls check() on every response, so every REST test is also a test of the description:
the operation is found by method and path template, the response by status (or
`default`), and a JSON body (each line of an NDJSON one) must match its schema."""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import urlparse

import yaml
from jsonschema import Draft202012Validator, RefResolver

SPEC = yaml.safe_load((Path(__file__).resolve().parents[2] / "docs" / "openapi.yaml").read_text())
_RESOLVER = RefResolver.from_schema(SPEC)
_ROUTES = [(re.compile("^" + re.sub(r"\{[^}]+\}", "[^/:]+", re.escape(t).replace(r"\{", "{").replace(r"\}", "}")) + "$"),
            t) for t in SPEC["paths"]]
checked = {"responses": 0}


def _resolve(node: dict) -> dict:
    while "$ref" in node:
        node = _RESOLVER.resolve(node["$ref"])[1]
    return node


def _template(path: str):
    for pattern, template in _ROUTES:
        if pattern.match(path):
            return template
    return None


def check(method: str, url: str, status: int, headers: dict, body: bytes) -> None:
    path = urlparse(url).path
    template = _template(path)
    ctype = (headers.get("Content-Type") or "").split(";")[0].strip().lower()
    if template is None or method.lower() not in SPEC["paths"][template]:
        # Not a route: the answer must be an error.
        if ctype == "application/json":
            _validate({"$ref": "#/components/schemas/Error"}, json.loads(body), method, url, status)
        return
    op = SPEC["paths"][template][method.lower()]
    responses = op["responses"]
    response = responses.get(str(status)) or responses.get("default")
    assert response is not None, f"{method} {url}: status {status} is not described in docs/openapi.yaml"
    response = _resolve(response)
    content = response.get("content", {})
    if ctype not in content:
        assert not body or ctype not in ("application/json", "application/x-ndjson"), \
            f"{method} {url}: {ctype} for status {status} is not described"
        return
    schema = content[ctype]["schema"]
    if ctype == "application/x-ndjson":
        for line in body.decode().splitlines():
            _validate(schema, json.loads(line), method, url, status)
    elif ctype == "application/json":
        _validate(schema, json.loads(body), method, url, status)


_VALIDATORS: dict = {}


def _validate(schema: dict, value, method: str, url: str, status: int) -> None:
    # One validator per schema (the hardening tests send thousands of requests).
    key = json.dumps(schema, sort_keys=True)
    validator = _VALIDATORS.get(key)
    if validator is None:
        validator = _VALIDATORS[key] = Draft202012Validator(schema, resolver=_RESOLVER)
    errors = sorted(validator.iter_errors(value), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        raise AssertionError(f"{method} {url} -> {status}: answer does not match docs/openapi.yaml at "
                             f"{'/'.join(map(str, e.path))}: {e.message[:300]}")
    checked["responses"] += 1
