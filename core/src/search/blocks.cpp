#include "spokemesh/blocks.hpp"

#include <algorithm>

#include "base/dimension.hpp"

namespace spokemesh {

BlockDecomposition::BlockDecomposition(const KdTree& tree, std::uint32_t max_points) : tree_(tree) {
  const auto subtrees = tree.subtrees_of_at_most(std::max(max_points, 1u));
  first_.reserve(subtrees.size() + 1);
  boxes_.reserve(subtrees.size());
  for (const KdTree::Subtree& s : subtrees) {
    first_.push_back(s.begin);
    boxes_.push_back(s.box);
  }
  first_.push_back(static_cast<std::uint32_t>(tree.points().size()));
}

std::uint32_t BlockDecomposition::default_max_points(int d, std::uint64_t n) {
  // At least 16 blocks where the set allows, so two workers balance; at most a size
  // per dimension beyond which larger blocks gained nothing (bench/README.md, "Tuning
  // history"): a block's table then outgrows the CPU's caches.
  const std::uint64_t cap = detail::policy(d).sweep_block_points;
  return static_cast<std::uint32_t>(std::clamp<std::uint64_t>(n / 16, 64, cap));
}

std::uint32_t BlockDecomposition::block_of_rank(std::uint32_t rank) const {
  // The last block that begins at or before rank.
  const auto it = std::upper_bound(first_.begin(), first_.end() - 1, rank);
  return static_cast<std::uint32_t>(it - first_.begin()) - 1;
}

}  // namespace spokemesh
