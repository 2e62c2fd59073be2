#!/usr/bin/env bash
# Installs the Debian bookworm packages spokemesh needs, skipping those present.
# Usage: scripts/install-deps.sh            (build + tests + benchmarks)
set -euo pipefail

packages=(
  build-essential cmake pkg-config
  libnanoflann-dev libeigen3-dev libgmp-dev
  libcli11-dev nlohmann-json3-dev
  # the service: gRPC + Protobuf (C++ and the Python plugin), Beast/Asio, OpenSSL, metrics
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  libboost-dev libssl-dev openssl prometheus-cpp-dev
  # the Python client and its tests (Debian's interpreter: /usr/bin/python3)
  python3 python3-grpcio python3-protobuf python3-numpy python3-pytest
  # the replica test puts Debian's nginx in front of three servers; bench/serving.py
  # measures us beside nginx with Apache's ab
  nginx apache2-utils
  # tests and benchmarks: GoogleTest, rapidcheck, and the oracles CGAL and Qhull
  libgtest-dev librapidcheck-dev libcgal-dev libmpfr-dev qhull-bin
  # clipped Voronoi cells: .npz output (zlib for the CRC-32s), and the oracles scipy and Voro++
  zlib1g-dev python3-scipy voro++
  # the in-process Python module (pybind11) and its pip-installable package
  pybind11-dev python3-pybind11 python3-dev python3-venv python3-setuptools
  # the OpenAPI description: compiled in from YAML, and the schema check of REST answers
  python3-yaml python3-jsonschema
  # the exact Delaunay-neighbour oracle of the high-dimensional tests (an LP per pair)
  libglpk-dev
  # spokemesh-mpi: Open MPI 4.1, its compilers' wrappers and mpirun
  libopenmpi-dev openmpi-bin
  # the browser page: three.js served from the system package, and the
  # page's tests in headless Chromium driven by Selenium
  libjs-three chromium chromium-driver python3-selenium
  # the fuzzers (scripts/fuzz.sh): clang with libFuzzer and its sanitizers
  clang libfuzzer-14-dev libclang-rt-14-dev
  # the C++ format check of the quick tier (scripts/check-format.sh)
  clang-format
  # the container system test (scripts/container-test.sh): rootful podman with runc,
  # netavark and aardvark-dns (replicas found by name), podman-compose, and
  # debootstrap for the base image (no registry is reachable)
  podman buildah podman-compose runc netavark aardvark-dns containernetworking-plugins
  slirp4netns fuse-overlayfs uidmap iptables debootstrap
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
echo "Installing: ${missing[*]}" >&2
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
