#!/usr/bin/python3
"""Build step: docs/openapi.yaml -> a C++ header holding it as compact JSON, which
spokemesh-server serves at /openapi.json. Usage: openapi_header.py IN.yaml OUT.hpp"""

import json
import sys

import yaml

with open(sys.argv[1]) as f:
    document = yaml.safe_load(f)
text = json.dumps(document, separators=(",", ":"), sort_keys=False)
assert ")openapi_json\"" not in text
with open(sys.argv[2], "w") as out:
    out.write("// Generated from docs/openapi.yaml by scripts/openapi_header.py; do not edit.\n#pragma once\n")
    out.write("namespace spokemesh::service {\ninline constexpr char kOpenApiJson[] = R\"openapi_json(")
    out.write(text)
    out.write(")openapi_json\";\n}  // namespace spokemesh::service\n")
