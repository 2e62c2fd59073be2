// The Delaunay graph (the edges of the Delaunay mesh) of a whole point set.
//
// Exact (d <= kMaxDimension): each seed's neighbours from its exact star. Approximate
// (any d <= kMaxApproxDimension): each seed's certified neighbours from ApproxWalker.
// Symmetrised by union: an edge found from either endpoint is kept (it is certified
// either way). Edges are (i, j) with i < j, sorted; identical for any thread count.
//
// Thread safety: delaunay_graph() may be called concurrently on the same tree.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "spokemesh/approx.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct GraphOptions {
  bool approximate = false;
  ApproxOptions approx;  // used when approximate
  StarOptions star;      // used when exact
  unsigned threads = 1;
  const std::atomic<bool>* cancel = nullptr;
  // Called now and then from the calling thread with the seeds finished so far.
  std::function<void(std::uint64_t seeds_done)> progress;
};

struct GraphStats {
  std::uint64_t vertices = 0;     // approximate: Voronoi vertices visited (or rays), summed
  std::uint64_t uncertified = 0;  // approximate: proposals whose witness failed
};

using Edges = std::vector<std::pair<std::uint32_t, std::uint32_t>>;

Result<Edges> delaunay_graph(const KdTree& tree, const GraphOptions& options, GraphStats* stats = nullptr);

}  // namespace spokemesh
