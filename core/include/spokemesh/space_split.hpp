// SpaceSplit: a point set cut recursively by counts into compact blocks, an order of
// the points that P processes can compute together (docs/distributed.md).
//
// A node's points are split along the widest side of their bounding box: the lower
// floor(m / 2) of its m points in the total order along that axis go left, the rest
// right, until a node holds at most `leaf` points. A leaf lists its points in
// lexicographic order. The leaves in order give every point a position; the maximal
// nodes of at most `block` points are the blocks, which tile the positions in order.
//
// The total order along axis c: coordinate c, then every coordinate in turn
// (lexicographic), then the index. So a split is decided by counts and comparisons of
// coordinates only: the result is a function of the point set (as a set) and the two
// sizes, whatever the order the points come in, and every step has a distributed
// form (bounding boxes by reductions, medians by rounds of counts).
//
// Unlike KdTree's leaf order (nanoflann's in-place partitions depend on the order
// points arrive in), this order can be reproduced without holding the whole set.
//
// Cost: records of coordinates and index are partitioned in place (nth_element), the
// two halves of the root on two threads from 65,536 points: a little less than the
// KdTree's build (bench/README.md, "Tuning history").
//
// Ownership: keeps the order both ways (2 n indices) and the blocks' boxes; the
// PointSet is only read during construction (which copies it once, as records).
// Thread safety: immutable after construction; the constructor uses one extra thread
// for 65,536 points or more.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/point_set.hpp"

namespace spokemesh {

// The total order along `axis` of d-dimensional points p and q with indices i and j:
// coordinate `axis`, then every coordinate in turn (lexicographic), then the index.
inline bool before_along(int axis, int d, const double* p, std::uint64_t i, const double* q, std::uint64_t j) {
  if (p[axis] != q[axis]) return p[axis] < q[axis];
  for (int c = 0; c < d; ++c) {
    if (p[c] != q[c]) return p[c] < q[c];
  }
  return i < j;
}

class SpaceSplit {
 public:
  // Preconditions: block >= leaf >= 1; `points` validated (no duplicates).
  SpaceSplit(const PointSet& points, std::uint32_t block, std::uint32_t leaf = kLeafPoints);

  // The leaf size every sweep uses: positions depend on it (and not on `block`), so
  // one value is the contract between a whole mesh on one process and on many.
  static constexpr std::uint32_t kLeafPoints = 8;

  // The block size a whole mesh of n points in dimension d uses: large enough that
  // most facets of a block's stars stay inside it (a block's surface is a small part
  // of its volume), small enough to balance two workers and to bound what is buffered
  // (measured: bench/README.md, "Tuning history"). A function of d and n only; the
  // rows' order does not depend on it.
  static std::uint32_t default_block_points(int d, std::uint64_t n);

  // The same order for a part of a larger set, as one process of a distributed run
  // holds it: `pieces` are nodes of the whole set's split, in its order, each given as
  // the indices (into `points`) of its points: piece p is members[piece_ends[p - 1],
  // piece_ends[p]) (from 0 for p = 0). Each piece is split on exactly as the whole
  // set's recursion splits that node, so positions follow the whole set's order
  // restricted to the pieces. Points in no piece (another process's, held to complete
  // stars) come after them, split as one node of their own (in space order: the order a
  // triangulation of the held points inserts them in), as one trailing block no sweep takes.
  // Preconditions: the pieces are disjoint; each is a node of the whole set's split
  // with the same leaf size.
  SpaceSplit(const PointSet& points, std::span<const std::uint32_t> members, std::span<const std::uint32_t> piece_ends,
             std::uint32_t block, std::uint32_t leaf = kLeafPoints);

  // This split over another PointSet that holds the same pieces' points (a process's
  // held points, grown): id_of maps each point id of this split to its id in `points`.
  // The pieces' positions and blocks are kept; the points of `points` in no piece trail
  // as the constructor places them. O(n), plus the split of the trailing points.
  SpaceSplit remapped(const PointSet& points, std::span<const std::uint32_t> id_of) const;

  int dimension() const { return d_; }
  // Positions [0, swept()) are the pieces' points (all of them for a whole set).
  std::uint32_t swept() const { return swept_; }

  std::uint32_t size() const { return static_cast<std::uint32_t>(order_.size()); }
  // The point at a position, and the position of a point (inverse permutations).
  std::uint32_t point_at(std::uint32_t position) const { return order_[position]; }
  std::uint32_t position_of(std::uint32_t id) const { return position_[id]; }
  // Every point in order (point_at of each position): a layout for KdTree.
  std::span<const std::uint32_t> order() const { return order_; }

  // Blocks: positions [begin(b), end(b)), in order; they tile [0, size()).
  std::uint32_t block_count() const { return static_cast<std::uint32_t>(first_.size() - 1); }
  std::uint32_t begin(std::uint32_t b) const { return first_[b]; }
  std::uint32_t end(std::uint32_t b) const { return first_[b + 1]; }
  // The block holding `position` (< size()); O(log block_count()).
  std::uint32_t block_of(std::uint32_t position) const;
  // The maximal nodes of the split holding at most max_points points each (a leaf when
  // even a leaf holds more), as position ranges [first, second) in order: they tile
  // [0, swept()). A node's children are fixed by its count alone (the lower half, by
  // count, goes left), so these follow from the pieces' ranges: the blocks are the
  // nodes of at most `block` points, and coarser or finer nodes are as compact.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> nodes_of_at_most(std::uint32_t max_points) const;
  // The pieces' ends in positions (a whole set: one piece, ending at swept()).
  std::span<const std::uint32_t> piece_ends() const { return piece_ends_; }
  // Block b's bounding box: d lows, then d highs (exact coordinates of its points).
  std::span<const double> box(std::uint32_t b) const {
    return {boxes_.data() + std::size_t{b} * 2 * static_cast<std::size_t>(d_), 2 * static_cast<std::size_t>(d_)};
  }

 private:
  void build(const PointSet& points, std::span<const std::uint32_t> members, std::span<const std::uint32_t> piece_ends,
             std::uint32_t block, std::uint32_t leaf);
  // The points in no piece (position_ unset), split as one node, as one trailing block.
  void append_trailing(const PointSet& points);
  struct Empty {};
  SpaceSplit(Empty, int d) : d_(d) {}  // an empty split, for remapped()

  int d_;
  std::uint32_t swept_ = 0;
  std::uint32_t leaf_ = kLeafPoints;
  std::vector<std::uint32_t> piece_ends_;  // the pieces' ends in positions (a whole set: one piece)
  std::vector<std::uint32_t> order_, position_;
  std::vector<std::uint32_t> first_;  // block b starts at first_[b]; first_.back() == size()
  std::vector<double> boxes_;
};

}  // namespace spokemesh
