// All Voronoi cells of a point set (or of a range of seeds), clipped to a domain,
// computed by worker threads and handed over in seed order (docs/cells.md).
//
// compute_cells() works in rounds: each worker computes one block of consecutive
// seeds, then the calling thread hands the finished blocks to `sink` in order. Memory
// is the tree plus threads x block cells, never all cells. Each cell is the same
// whatever the threads or block size (a function of the point set and the domain).
//
// Thread safety: safe to call concurrently on the same tree.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <span>

#include "spokemesh/domain.hpp"
#include "spokemesh/facet_cache.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

struct CellsOptions {
  unsigned threads = 1;                   // worker threads (>= 1)
  std::uint32_t seed_begin = 0;           // cells of seeds [seed_begin, seed_end)
  std::uint32_t seed_end = 0xFFFFFFFFu;   // clamped to n
  std::uint32_t block_size = 2048;        // seeds per worker and round
  // Drop each cell's vertex coordinates and facet vertex lists before the sink sees
  // them (measures only: what `spokemesh cells ... -o x.npz` writes).
  bool measures_only = false;
  // Cap (bytes) on the cache through which the run's stars share their wraps, as in
  // MeshOptions; 0 for none. The cells are the same either way.
  std::size_t facet_cache_bytes = std::size_t{1} << 28;
  StarOptions star;                       // star.cancel also stops the run
};

// Receives the cells of consecutive seeds and the number of seeds done so far; a
// non-OK status stops the run and is returned.
using CellSink = std::function<Status(std::span<const VoronoiCell> cells, std::uint64_t seeds_done)>;

// `domain`: nullptr for unclipped cells. Errors: the first seed outside the domain
// (INVALID_ARGUMENT, naming it), CANCELLED, or the sink's status.
Status compute_cells(const KdTree& tree, const Domain* domain, const CellsOptions& options, const CellSink& sink);

}  // namespace spokemesh
