// Internal: zeroed memory straight from the OS for the run memos (walk_memo.cpp's
// EdgeCache, mesh/facet_cache.cpp's FacetCache), counted in mapped_cache_bytes().
//
// Thread safety: safe to call concurrently.
#pragma once

#include <cstddef>

#include "spokemesh/walk_memo.hpp"

namespace spokemesh {

// `words` zeroed 32-bit words, committed page by page on first touch; with `huge`,
// huge pages are asked for (advice only). Empty on failure.
MappedWords allocate_zeroed(std::size_t words, bool huge = true);

}  // namespace spokemesh
