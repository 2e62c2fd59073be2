// Internal: two- and four-lane double vectors for branch-free filters (GCC/Clang vector
// extensions; plain loops with comparisons are not vectorized by GCC 12). Two lanes
// are SSE2, which every x86-64 has; four lanes are compiled into functions marked
// target("avx2") and chosen at run time with has_avx2(). Neither has FMA, and the core
// builds with -ffp-contract=off, so a filter computes the same bits with either width.
#pragma once

#include <cstdint>

namespace spokemesh::detail {

using Double2 = double __attribute__((vector_size(16)));
using Mask2 = std::int64_t __attribute__((vector_size(16)));
using Double4 = double __attribute__((vector_size(32)));
using Mask4 = std::int64_t __attribute__((vector_size(32)));

inline bool has_avx2() {
  static const bool avx2 = __builtin_cpu_supports("avx2");
  return avx2;
}

}  // namespace spokemesh::detail
