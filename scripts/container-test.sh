#!/usr/bin/env bash
# Container system test: the images of docker/ built with podman, the compose set
# (three replicas sharing a volume, behind nginx) started with podman-compose, replicas
# stopped, killed and restarted under load; tests/container/restart_under_load.py
# checks that every request is answered correctly and promptly and that each restarted
# replica (on a new address) serves again. Then the sharded set (docker/compose-sharded.yaml:
# 2 shards x 2 replicas, the set cut into pieces) with one replica of each shard killed
# and restarted under load.
#
# No registry is reachable, so debian:bookworm-slim is made here with debootstrap (from
# Debian's archive) and imported, once; the images then build from Debian's packages.
# Needs root (debootstrap, rootful podman) and podman, podman-compose, runc, buildah,
# debootstrap (scripts/install-deps.sh --containers installs them).
#
# Usage: scripts/container-test.sh [--keep]     (--keep: leave the compose set running)
# Exit status: 0 passed, 1 failed, 77 skipped (this machine cannot run containers;
# ./test.sh fails the run on 77 when CI=true).
set -euo pipefail
cd "$(dirname "$0")/.."
repo="$PWD"
keep=0
[[ "${1:-}" == "--keep" ]] && keep=1
export CONTAINERS_CONF="$repo/docker/podman/containers.conf"
project=spokemesh-ct
base=docker.io/library/debian:bookworm-slim
mirror="${SPOKEMESH_DEBIAN_MIRROR:-http://deb.debian.org/debian}"
work="$repo/build-container"
log() { echo "== container-test: $*" >&2; }
skip() { log "SKIPPED: $*"; exit 77; }

for tool in podman podman-compose debootstrap runc; do
  command -v "$tool" >/dev/null || skip "$tool is not installed (scripts/install-deps.sh --containers)"
done
if [[ "$(id -u)" != 0 ]]; then
  # Rootful podman and debootstrap: as root, through sudo when it asks no password.
  sudo -n true 2>/dev/null && exec sudo -n --preserve-env=CI,SPOKEMESH_DEBIAN_MIRROR,SPOKEMESH_GRPC_PORT,SPOKEMESH_HTTP_PORT "$0" "$@"
  skip "needs root (debootstrap and rootful podman), and sudo asks for a password"
fi
podman info >/dev/null 2>&1 || skip "podman cannot start here: $(podman info 2>&1 | tail -n 1)"

mkdir -p "$work"
if ! podman image exists "$base"; then
  log "making $base with debootstrap from $mirror"
  rm -rf "$work/rootfs"
  debootstrap --variant=minbase bookworm "$work/rootfs" "$mirror" >"$work/debootstrap.log" 2>&1 \
    || { tail -n 20 "$work/debootstrap.log" >&2; exit 1; }
  cat >"$work/rootfs/etc/apt/sources.list" <<SOURCES
deb $mirror bookworm main
deb $mirror bookworm-updates main
deb http://deb.debian.org/debian-security bookworm-security main
SOURCES
  rm -rf "$work"/rootfs/var/cache/apt/archives/*.deb "$work"/rootfs/var/lib/apt/lists/*
  tar -C "$work/rootfs" -c . | podman import --change 'CMD ["bash"]' - "$base" >/dev/null
  rm -rf "$work/rootfs"
fi
podman run --rm --network none "$base" true 2>"$work/run.err" \
  || skip "podman cannot run a container here: $(tail -n 1 "$work/run.err")"

free_port() { /usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
export SPOKEMESH_GRPC_PORT="${SPOKEMESH_GRPC_PORT:-$(free_port)}"
export SPOKEMESH_HTTP_PORT="${SPOKEMESH_HTTP_PORT:-$(free_port)}"
compose=(podman-compose -p "$project" -f docker/compose.yaml)
sharded_project=${project}-sharded
sharded=(podman-compose -p "$sharded_project" -f docker/compose-sharded.yaml)

down_plain() {
  podman logs "${project}_nginx_1" >"$work/nginx.log" 2>&1 || true
  "${compose[@]}" down -v >"$work/down.log" 2>&1 || true
  podman volume rm -f "${project}_spokemesh-data" >/dev/null 2>&1 || true
}
down_sharded() {
  podman logs "${sharded_project}_nginx_1" >"$work/nginx-sharded.log" 2>&1 || true
  "${sharded[@]}" down -v >"$work/down-sharded.log" 2>&1 || true
  podman volume rm -f "${sharded_project}_spokemesh-data" >/dev/null 2>&1 || true
}
down() {
  if [[ $keep == 0 ]]; then
    down_plain
    down_sharded
  fi
}
trap down EXIT
down_plain
down_sharded

log "building the images (server: a Release build inside the container)"
start=$(date +%s)
"${compose[@]}" build >"$work/build.log" 2>&1 || { tail -n 40 "$work/build.log" >&2; exit 1; }
# podman-compose's exit status does not always carry a failed image build's: check.
for image in spokemesh spokemesh-nginx; do
  podman image exists "localhost/$image:latest" \
    || { grep -B 5 -m 1 -E '^Error|\*\*\*' "$work/build.log" >&2; log "FAILED: image $image was not built"; exit 1; }
done
log "images built in $(( $(date +%s) - start )) s"
"${compose[@]}" up -d >"$work/up.log" 2>&1 || { tail -n 40 "$work/up.log" >&2; exit 1; }
log "compose set up: gRPC on 127.0.0.1:$SPOKEMESH_GRPC_PORT, REST on 127.0.0.1:$SPOKEMESH_HTTP_PORT"

/usr/bin/python3 tests/container/restart_under_load.py --project "$project" \
  --grpc "127.0.0.1:$SPOKEMESH_GRPC_PORT" --http "http://127.0.0.1:$SPOKEMESH_HTTP_PORT" \
  || { podman logs "${project}_nginx_1" 2>&1 | grep -v ' 200 upstream=' | tail -n 20 >&2; exit 1; }
# The page through nginx, from a replica: served, with three.js from the image's
# libjs-three.
/usr/bin/python3 - "$SPOKEMESH_HTTP_PORT" <<'PY' || { log "FAILED: the page is not served from the image"; exit 1; }
import sys
import urllib.request
base = f"http://127.0.0.1:{sys.argv[1]}"
for path, needle in (("/", b"/ui/app.js"), ("/ui/three.min.js", b"REVISION"), ("/ui/OrbitControls.js", b"OrbitControls")):
    with urllib.request.urlopen(base + path, timeout=30) as r:
        assert r.status == 200 and needle in r.read(), path
PY
log "the page is served from the image"

# The sharded set: the same images, 2 shards x 2 replicas; small pieces so that the
# test's set of 20,000 points is cut into 16.
down_plain
export SPOKEMESH_PIECES_ABOVE=10000 SPOKEMESH_PIECE_POINTS=2000
"${sharded[@]}" up -d >"$work/up-sharded.log" 2>&1 || { tail -n 40 "$work/up-sharded.log" >&2; exit 1; }
log "sharded set up: 2 shards x 2 replicas behind nginx"
/usr/bin/python3 tests/container/restart_under_load.py --project "$sharded_project" --sharded \
  --grpc "127.0.0.1:$SPOKEMESH_GRPC_PORT" --http "http://127.0.0.1:$SPOKEMESH_HTTP_PORT" \
  || { podman logs "${sharded_project}_nginx_1" 2>&1 | grep -v ' 200 upstream=' | tail -n 20 >&2; exit 1; }
log "sharded set: passed"
