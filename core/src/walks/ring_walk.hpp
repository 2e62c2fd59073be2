// StarWalker::RingWalk: the star walk for d = 2, apart from the general walk.
//
// In 2-d x's star is a ring of triangles about x, each two consecutive neighbours and
// x (a path, ended by two hull edges, when x is on the convex hull), so the walk keeps
// each neighbour with its two neighbours in the ring (the link of x) instead of the
// general walk's facet hashing. It shares the walker's candidates and wraps, and reads
// the run's EdgeCache instead of the FacetCache.
//
// Ownership: owned by its StarWalker, which it borrows. Thread safety: as StarWalker
// (one per thread).
#pragma once

#include <cstdint>
#include <vector>

#include "spokemesh/star.hpp"

namespace spokemesh {

class StarWalker::RingWalk {
 public:
  explicit RingWalk(StarWalker& walker) : w_(walker) {}
  // StarWalker::compute for the walker's current seed (w_.x_), d = 2.
  Status compute(Star& out, StarPart part);

 private:
  // A neighbour of x with its neighbours on either side in the ring (ids, or kHull /
  // kUnknown); sender: it posted its edge with x, so its star came earlier.
  struct RingNode {
    std::uint32_t id;
    std::uint32_t side[2];
    bool sender;
  };
  StarWalker& w_;
  std::vector<RingNode> ring_;
  std::vector<std::uint32_t> ring_open_;       // nodes with a side unknown when the walk began
  std::vector<std::uint64_t> ring_triangles_;  // found, as (low id << 32) | high id
};

}  // namespace spokemesh
