#!/usr/bin/python3
"""Build step: the browser page's own files (service/ui/*) -> a C++ header holding
them, so spokemesh-server serves its page with nothing installed beside it.
three.js is not embedded: the server reads it from Debian's libjs-three at startup.
Usage: embed_ui.py OUT.hpp FILE..."""

import os
import sys

TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml"}
DELIMITER = "ui_asset"

out_path, files = sys.argv[1], sorted(sys.argv[2:])
with open(out_path + ".tmp", "w") as out:
    out.write("// Generated from service/ui/ by scripts/embed_ui.py; do not edit.\n#pragma once\n")
    out.write("#include <string_view>\nnamespace spokemesh::service {\n")
    out.write("struct EmbeddedAsset { std::string_view name, content_type, body; };\n")
    out.write("inline constexpr EmbeddedAsset kEmbeddedUi[] = {\n")
    for path in files:
        name = os.path.basename(path)
        with open(path, encoding="utf-8") as f:
            text = f.read()
        assert ")" + DELIMITER + '"' not in text, path
        # Adjacent raw literals, each well under compilers' string-literal limits.
        pieces = [text[i:i + 16000] for i in range(0, len(text), 16000)] or [""]
        body = "\n".join(f'R"{DELIMITER}({p}){DELIMITER}"' for p in pieces)
        out.write(f'  {{"{name}", "{TYPES[os.path.splitext(name)[1]]}",\n{body}}},\n')
    out.write("};\n}  // namespace spokemesh::service\n")
os.replace(out_path + ".tmp", out_path)
