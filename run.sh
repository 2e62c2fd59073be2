#!/usr/bin/env bash
# The main job: install what is missing, build, and run spokemesh-server on localhost
# (gRPC 127.0.0.1:50051, REST 127.0.0.1:8080, point sets stored in ./spokemesh-data).
# Stop it with Ctrl-C. Extra arguments go to the server (see --help).
set -euo pipefail
cd "$(dirname "$0")"
scripts/install-deps.sh
scripts/build.sh spokemesh_server spokemesh_cli spokemesh_python
cat >&2 <<'HINT'
spokemesh-server is starting. In another terminal, for example:
  build/bin/spokemesh --server 127.0.0.1:50051 upload examples/ball-3d.txt      # prints the id
  build/bin/spokemesh --server 127.0.0.1:50051 star ID --seed 0
  curl -s 127.0.0.1:8080/v1/pointsets
HINT
exec build/bin/spokemesh-server --data-dir ./spokemesh-data "$@"
