#!/usr/bin/env bash
# Configures build/ (Release, everything enabled) and builds the given targets
# (default: all). Usage: scripts/build.sh [target ...]
set -euo pipefail
cd "$(dirname "$0")/.."
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release \
  -DSPOKEMESH_BUILD_CLIENTS=ON -DSPOKEMESH_BUILD_TESTS=ON -DSPOKEMESH_BUILD_BENCH=ON >/dev/null
if [ $# -eq 0 ]; then
  cmake --build build -j"$(nproc)"
else
  for target in "$@"; do cmake --build build -j"$(nproc)" --target "$target"; done
fi
