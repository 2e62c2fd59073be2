// BlockDecomposition: a point set cut into compact blocks of space along the k-d
// tree's leaf order, the unit of work of a sweep.
//
// Block b is a subtree of the KdTree: the points at leaf-order positions [begin(b),
// end(b)), inside the subtree's tight box. Blocks are the maximal subtrees holding at
// most `max_points` points (a leaf when even a leaf holds more), listed in leaf order,
// so they tile [0, n) and a prefix of them is a union of at most one subtree per tree
// level. That is what bounds a sweep's front: the boundary between the blocks done and
// the blocks to come is the surface of those few subtrees, O(n^((d-1)/d)) points,
// never a part of the volume (docs/algorithm.md, "The sweep").
//
// The decomposition is a function of the tree and max_points (the tree is a function
// of the point set), never of a thread count: a whole mesh writes its rows in the
// blocks' order, and a distributed run cuts the same blocks into ranks.
//
// Ownership: borrows the KdTree, which must outlive the decomposition.
// Thread safety: immutable after construction; concurrent reads are safe.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/kd_tree.hpp"

namespace spokemesh {

class BlockDecomposition {
 public:
  // Blocks of at most max_points points (>= 1) over the tree's whole point set.
  BlockDecomposition(const KdTree& tree, std::uint32_t max_points);

  // The block size a whole mesh of n points in dimension d uses: large enough that
  // most facets of a block's stars stay inside it (a block's surface is a small part
  // of its volume), small enough to balance two workers and to bound what is buffered
  // (measured: bench/README.md, "Tuning history"). A function of d and n only.
  static std::uint32_t default_max_points(int d, std::uint64_t n);

  const KdTree& tree() const { return tree_; }
  std::uint32_t size() const { return static_cast<std::uint32_t>(first_.size() - 1); }
  // Leaf-order positions [begin(b), end(b)) of block b < size().
  std::uint32_t begin(std::uint32_t b) const { return first_[b]; }
  std::uint32_t end(std::uint32_t b) const { return first_[b + 1]; }
  // Block b's tight box: d lows, then d highs (floats rounded outwards).
  std::span<const float> box(std::uint32_t b) const {
    return {boxes_[b], 2 * static_cast<std::size_t>(tree_.points().dimension())};
  }
  // The block holding leaf-order position `rank` (< n); O(log size()).
  std::uint32_t block_of_rank(std::uint32_t rank) const;
  // The block holding point `id` (< n).
  std::uint32_t block_of(std::uint32_t id) const { return block_of_rank(tree_.leaf_rank(id)); }

 private:
  const KdTree& tree_;
  std::vector<std::uint32_t> first_;  // size() + 1 entries: block b is [first_[b], first_[b + 1])
  std::vector<const float*> boxes_;
};

}  // namespace spokemesh
