#!/usr/bin/env bash
# Install what is missing, build everything, and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")"
scripts/install-deps.sh
scripts/build.sh
(cd build && ctest --output-on-failure -j"$(nproc)")
# The fuzzers: the checked-in corpus replayed, then 30 s of fuzzing per target.
scripts/fuzz.sh 30
