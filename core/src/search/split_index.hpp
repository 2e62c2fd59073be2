// SplitIndex: box queries over a SpaceSplit's own hierarchy, for the whole mesh's local
// triangulations when no k-d tree was built (spokemesh mesh: the sweep needs the split
// anyway, and a KdTree holds about 60 bytes a point more: its copy of the points in
// leaf order, both permutations and nanoflann's nodes).
//
// The split's recursion by counts (a node [b, e) has children [b, b + (e - b) / 2) and
// [b + (e - b) / 2, e), down to leaves of at most kLeafPoints positions) fixes the node
// ranges; this keeps each node's tight bounding box (floats rounded outwards, so every
// point lies inside) in preorder, with the position past its subtree. Its pieces'
// positions (and a distributed run's trailing block of held points) are indexed the
// same way. Points are read from the PointSet through the split's order.
//
// Ownership: borrows the PointSet and the SpaceSplit, which must outlive it; owns 9
// floats and integers per node (about a node per 4 points).
// Thread safety: immutable after construction; concurrent queries are safe.
#pragma once

#include <cstdint>
#include <optional>
#include <type_traits>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh::detail {

class SplitIndex {
 public:
  SplitIndex(const PointSet& points, const SpaceSplit& split);

  // The first point p (in position order) with accept(p, coordinates of p), visiting
  // only boxes for which may_contain(lo, hi) holds (d lows, d highs; floats rounded
  // outwards: conservative), as KdTree::find_first. None when no point is accepted.
  template <class MayContain, class Accept>
  std::optional<std::uint32_t> find_first(MayContain&& may_contain, Accept&& accept) const;

  std::size_t bytes() const { return nodes_.capacity() * sizeof(Node) + bounds_.capacity() * sizeof(float); }

 private:
  struct Node {
    std::uint32_t begin, end, skip;  // positions [begin, end); the node past its subtree
  };
  // Appends the node over positions [begin, end) and its subtree; returns nothing,
  // writes its box into bounds_.
  void build(std::uint32_t begin, std::uint32_t end);

  static constexpr std::uint32_t kLeafPoints = SpaceSplit::kLeafPoints;
  const PointSet& points_;
  const SpaceSplit& split_;
  int d_;
  std::vector<Node> nodes_;
  std::vector<float> bounds_;  // per node: d lows, then d highs
};

template <class MayContain, class Accept>
std::optional<std::uint32_t> SplitIndex::find_first(MayContain&& may_contain, Accept&& accept) const {
  const auto d = static_cast<std::size_t>(d_);
  const std::size_t count = nodes_.size();
  for (std::size_t i = 0; i < count;) {
    const Node& node = nodes_[i];
    const float* lo = &bounds_[i * 2 * d];
    if (!may_contain(lo, lo + d)) {
      i = node.skip;
      continue;
    }
    if (node.skip == i + 1) {  // a leaf
      // Its points lie at random places in the set: ask for them all before the first
      // is read (they are a few, and each is read).
      for (std::uint32_t r = node.begin; r < node.end; ++r) __builtin_prefetch(points_.point(split_.point_at(r)));
      for (std::uint32_t r = node.begin; r < node.end; ++r) {
        const std::uint32_t p = split_.point_at(r);
        if (accept(p, points_.point(p))) return p;
      }
    }
    ++i;
  }
  return std::nullopt;
}

}  // namespace spokemesh::detail
