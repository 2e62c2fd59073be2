#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (ASan + UBSan) in build-fuzz/, replays the
# checked-in corpus (every input once: regressions), then fuzzes each target for
# SECONDS (default 30). New inputs that reach new code stay in build-fuzz/corpus/;
# a crash leaves its input in build-fuzz/ and fails the run: add it to
# tests/fuzz/corpus/<target>/ once fixed, so it is replayed from then on.
# Usage: scripts/fuzz.sh [SECONDS]
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-30}"
targets=(fuzz_points_text fuzz_points_npy fuzz_upload_json fuzz_domains fuzz_grpc_requests)
sanitize="-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER=clang++ \
  -DCMAKE_CXX_FLAGS="$sanitize" -DSPOKEMESH_BUILD_SERVICE=ON -DSPOKEMESH_BUILD_CLIENTS=OFF \
  -DSPOKEMESH_BUILD_TESTS=OFF -DSPOKEMESH_BUILD_BENCH=OFF -DSPOKEMESH_BUILD_FUZZERS=ON >/dev/null
cmake --build build-fuzz -j"$(nproc)" --target "${targets[@]}"
for t in "${targets[@]}"; do
  quiet=()
  # The in-process server logs every request to stderr; libFuzzer keeps its own.
  [[ $t == fuzz_grpc_requests ]] && quiet=(-close_fd_mask=2)
  seeds="tests/fuzz/corpus/$t"
  work="build-fuzz/corpus/$t"
  mkdir -p "$work"
  echo "== $t: replaying $(ls "$seeds" | wc -l) corpus inputs" >&2
  build-fuzz/bin/"$t" "${quiet[@]}" -runs=0 "$seeds"
  echo "== $t: fuzzing for ${seconds}s" >&2
  (cd build-fuzz && bin/"$t" "${quiet[@]}" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=65536 \
     -print_final_stats=1 "corpus/$t" "../$seeds" 2>&1 | tail -n 12)
done
