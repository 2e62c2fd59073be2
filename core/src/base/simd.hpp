// Internal: two- and four-lane double vectors for branch-free filters (GCC/Clang vector
// extensions; plain loops with comparisons are not vectorized by GCC 12). Two lanes
// are SSE2, which every x86-64 has; four lanes are compiled into functions marked
// target("avx2") and chosen at run time with has_avx2(). Neither has FMA, and the core
// builds with -ffp-contract=off, so a filter computes the same bits with either width.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <string_view>

namespace spokemesh::detail {

using Double2 = double __attribute__((vector_size(16)));
using Mask2 = std::int64_t __attribute__((vector_size(16)));
using Double4 = double __attribute__((vector_size(32)));
using Mask4 = std::int64_t __attribute__((vector_size(32)));

// Marks the four-lane variants. Off x86 it is empty: has_avx2() is false there and
// the two-lane variants run (vector extensions lower to the target's own SIMD).
#if defined(__x86_64__) || defined(__i386__)
#define SPOKEMESH_TARGET_AVX2 __attribute__((target("avx2")))
#else
#define SPOKEMESH_TARGET_AVX2
#endif

// SPOKEMESH_SIMD=sse2 in the environment forces two lanes (the tests run the SSE2
// path that way on machines with AVX2; results are the same, only speed differs).
inline bool has_avx2() {
  static const bool avx2 = [] {
    const char* force = std::getenv("SPOKEMESH_SIMD");
    if (force != nullptr && std::string_view(force) == "sse2") return false;
#if defined(__x86_64__) || defined(__i386__)
    return __builtin_cpu_supports("avx2") != 0;
#else
    return false;
#endif
  }();
  return avx2;
}

}  // namespace spokemesh::detail
