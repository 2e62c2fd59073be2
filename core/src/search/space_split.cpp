#include "spokemesh/space_split.hpp"

#include <algorithm>
#include <numeric>

namespace spokemesh {

namespace {

// The total order along `axis`: that coordinate, then all of them in turn, then the
// index (never reached for a validated set, which has no duplicates).
struct AlongAxis {
  const PointSet& ps;
  int axis;
  bool operator()(std::uint32_t a, std::uint32_t b) const {
    const double* p = ps.point(a);
    const double* q = ps.point(b);
    if (p[axis] != q[axis]) return p[axis] < q[axis];
    for (int c = 0; c < ps.dimension(); ++c) {
      if (p[c] != q[c]) return p[c] < q[c];
    }
    return a < b;
  }
};

}  // namespace

SpaceSplit::SpaceSplit(const PointSet& points, std::uint32_t block, std::uint32_t leaf) : d_(points.dimension()) {
  const auto n = static_cast<std::uint32_t>(points.size());
  const std::size_t d = static_cast<std::size_t>(d_);
  leaf = std::max<std::uint32_t>(leaf, 1);
  block = std::max(block, leaf);
  order_.resize(n);
  std::iota(order_.begin(), order_.end(), 0u);
  first_.push_back(0);
  std::vector<double> lo(d), hi(d);
  auto bound = [&](std::uint32_t begin, std::uint32_t end) {
    for (std::size_t c = 0; c < d; ++c) lo[c] = hi[c] = points.point(order_[begin])[c];
    for (std::uint32_t i = begin + 1; i < end; ++i) {
      const double* p = points.point(order_[i]);
      for (std::size_t c = 0; c < d; ++c) {
        lo[c] = std::min(lo[c], p[c]);
        hi[c] = std::max(hi[c], p[c]);
      }
    }
  };
  // Depth first, left before right: nodes are met in position order, so blocks and
  // leaves are appended in order too.
  struct Node {
    std::uint32_t begin, end;
    bool in_block;  // an ancestor (or the node itself) is a block already
  };
  std::vector<Node> stack;
  if (n != 0) stack.push_back({0, n, false});
  while (!stack.empty()) {
    const Node node = stack.back();
    stack.pop_back();
    const std::uint32_t m = node.end - node.begin;
    bool in_block = node.in_block;
    if (!in_block && m <= block) {
      in_block = true;  // a maximal node of at most `block` points: a block
      bound(node.begin, node.end);
      boxes_.insert(boxes_.end(), lo.begin(), lo.end());
      boxes_.insert(boxes_.end(), hi.begin(), hi.end());
      first_.push_back(node.end);  // blocks are met in order: this one ends here
    }
    auto first = order_.begin() + node.begin, last = order_.begin() + node.end;
    if (m <= leaf) {
      std::sort(first, last, AlongAxis{points, 0});
      continue;
    }
    bound(node.begin, node.end);
    int axis = 0;
    for (std::size_t c = 1; c < d; ++c) {
      if (hi[c] - lo[c] > hi[static_cast<std::size_t>(axis)] - lo[static_cast<std::size_t>(axis)]) axis = static_cast<int>(c);
    }
    const std::uint32_t mid = node.begin + m / 2;
    std::nth_element(first, order_.begin() + mid, last, AlongAxis{points, axis});
    stack.push_back({mid, node.end, in_block});  // right, taken after the left
    stack.push_back({node.begin, mid, in_block});
  }
  position_.resize(n);
  for (std::uint32_t i = 0; i < n; ++i) position_[order_[i]] = i;
}

}  // namespace spokemesh
