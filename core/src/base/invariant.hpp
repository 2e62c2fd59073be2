// Debug-build assertions of the walks' invariants.
//
// SPOKEMESH_INVARIANT(condition, what) checks a property the algorithm guarantees
// (not a property of the input: bad input gets a Status, never an assertion). It is
// compiled in debug builds and wherever SPOKEMESH_CHECK_INVARIANTS is defined (the
// test suite builds one checked copy of the core: tests/CMakeLists.txt), and costs
// nothing in release builds. A failure prints the condition and where, then aborts.
#pragma once

#include <cstdio>
#include <cstdlib>

#if !defined(NDEBUG) && !defined(SPOKEMESH_CHECK_INVARIANTS)
#define SPOKEMESH_CHECK_INVARIANTS 1
#endif

namespace spokemesh::detail {

[[noreturn]] inline void invariant_failed(const char* condition, const char* what, const char* file, int line) {
  std::fprintf(stderr, "%s:%d: spokemesh invariant violated: %s (%s)\n", file, line, what, condition);
  std::abort();
}

}  // namespace spokemesh::detail

#ifdef SPOKEMESH_CHECK_INVARIANTS
#define SPOKEMESH_INVARIANT(condition, what) \
  ((condition) ? void(0) : ::spokemesh::detail::invariant_failed(#condition, what, __FILE__, __LINE__))
#else
#define SPOKEMESH_INVARIANT(condition, what) ((void)0)
#endif
