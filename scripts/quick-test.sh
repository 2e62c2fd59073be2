#!/usr/bin/env bash
# The quick loop for a change to the library: builds only what the unit and oracle
# tiers need (in build/, shared with ./test.sh), checks the format of the C++ files you
# changed, and runs those two tiers. About 3 minutes from a warm build on 2 cores;
# ./test.sh is the whole suite. Extra arguments go to ctest (e.g. -R test_star).
# Usage: scripts/quick-test.sh [ctest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
start=$SECONDS
scripts/build.sh quick_tier
scripts/check-format.sh
ctest --test-dir build -L '^(unit|oracle)$' -j"$(nproc)" --output-on-failure "$@"
echo "quick tier: $((SECONDS - start)) s (build, format check, unit and oracle tests)"
