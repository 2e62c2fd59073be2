// Whole-mesh assembly with no communication between seeds.
//
// Every Delaunay simplex is emitted by exactly one seed, its owner: its smallest
// vertex index. Meshing seeds [begin, end) emits exactly the simplices owned there;
// the union over any partition of [0, n) is the whole mesh, each simplex once.
// Because a simplex's first (smallest) index is its owner, concatenating the owned
// simplices seed by seed is already lexicographic order: the output is canonical.
//
// mesh_seeds() runs worker threads over blocks of seeds and hands finished blocks to
// `sink` in seed order, on the calling thread. At most a fixed window of blocks is in
// flight, so memory is the point set, the tree, a bounded buffer and the FacetCache
// (in 2-d the EdgeCache; capped by facet_cache_bytes), never the mesh. The workers' stars share their wraps
// through that cache; each star, and so the output, is the same without it.
//
// Thread safety: mesh_seeds() is safe to call concurrently on the same tree.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <span>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct MeshOptions {
  unsigned threads = 1;             // worker threads (>= 1)
  std::uint32_t seed_begin = 0;     // seeds [seed_begin, seed_end) are meshed
  std::uint32_t seed_end = 0xFFFFFFFFu;  // clamped to n
  std::uint32_t block_size = 0;     // seeds per block; 0 = automatic
  // Cap on the FacetCache (in 2-d the EdgeCache) that lets the stars of this run share
  // their wraps (see facet_cache.hpp): bytes, 0 to mesh without it. The output is the
  // same either way.
  std::size_t facet_cache_bytes = std::size_t{1} << 30;
  StarOptions star;                 // star.cancel also stops the whole run
};

struct MeshStats {
  std::uint64_t seeds = 0;
  std::uint64_t simplices = 0;
  std::size_t facet_cache_bytes = 0;  // reserved by the run's FacetCache or EdgeCache
  StarStats star;
};

// Receives a block of owned simplices ((d + 1) indices each, positively oriented as in
// Star, the owner first; lexicographic by sorted vertex lists)
// and the number of seeds finished so far. A non-OK status stops the run.
using SimplexSink = std::function<Status(std::span<const std::uint32_t> simplices, std::uint64_t seeds_done)>;

Result<MeshStats> mesh_seeds(const KdTree& tree, const MeshOptions& options, const SimplexSink& sink);

// The simplices owned by `seed` within its star (a suffix of star.simplices).
std::span<const std::uint32_t> owned_simplices(const Star& star);

}  // namespace spokemesh
