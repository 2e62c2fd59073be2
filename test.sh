#!/usr/bin/env bash
# Install what is missing, build everything, and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")"
scripts/install-deps.sh
scripts/build.sh -DSPOKEMESH_BUILD_TESTS=ON -DSPOKEMESH_BUILD_BENCH=ON
cd build
ctest --output-on-failure -j"$(nproc)"
