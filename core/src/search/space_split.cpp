#include "spokemesh/space_split.hpp"

#include <algorithm>
#include <array>
#include <numeric>
#include <span>
#include <thread>

#include "base/dimension.hpp"

namespace spokemesh {

namespace {

// One split of the recursion's output: the blocks met in a range of positions, in
// order (their ends and boxes).
struct Blocks {
  std::vector<std::uint32_t> ends;
  std::vector<double> boxes;
};

// The split on records that carry their coordinates (D known at compile time, or the
// runtime d for D = 0): nth_element then moves 32 to 72 contiguous bytes per point
// instead of chasing an index into the PointSet, which made a 1M-point split 2.5x
// slower than the k-d tree's build.
template <int D>
class Splitter {
 public:
  struct Record {
    std::array<double, D == 0 ? 1 : D> x;  // D = 0: unused (coordinates in `wide`)
    std::uint32_t id;
  };

  Splitter(const PointSet& points, std::uint32_t block, std::uint32_t leaf)
      : ps_(points), d_(D > 0 ? D : points.dimension()), block_(block), leaf_(leaf) {}

  bool before(const Record& a, const Record& b, int axis) const {
    if constexpr (D > 0) {  // before_along with the dimension known (grids tie often)
      const double *p = a.x.data(), *q = b.x.data();
      if (p[axis] != q[axis]) return p[axis] < q[axis];
      for (int c = 0; c < D; ++c) {
        if (p[c] != q[c]) return p[c] < q[c];
      }
      return a.id < b.id;
    } else {
      return before_along(axis, d_, coords(a), a.id, coords(b), b.id);
    }
  }
  const double* coords(const Record& r) const {
    if constexpr (D > 0) {
      return r.x.data();
    } else {
      return ps_.point(r.id);
    }
  }

  void fill(std::vector<Record>& recs) const {
    recs.resize(ps_.size());
    for (std::uint32_t i = 0; i < recs.size(); ++i) {
      recs[i].id = i;
      if constexpr (D > 0) std::copy(ps_.point(i), ps_.point(i) + D, recs[i].x.begin());
    }
  }
  // Records of the listed points, in the list's order.
  void fill(std::vector<Record>& recs, std::span<const std::uint32_t> ids) const {
    recs.resize(ids.size());
    for (std::size_t k = 0; k < ids.size(); ++k) {
      recs[k].id = ids[k];
      if constexpr (D > 0) std::copy(ps_.point(ids[k]), ps_.point(ids[k]) + D, recs[k].x.begin());
    }
  }

  // Splits recs[begin, end) (a node below a block if in_block), appending the blocks it
  // meets to `out` in order. Depth first, left before right.
  void split(std::vector<Record>& recs, std::uint32_t begin, std::uint32_t end, bool in_block, Blocks& out) const {
    struct Node {
      std::uint32_t begin, end;
      bool in_block;
    };
    std::vector<Node> stack{{begin, end, in_block}};
    std::vector<double> lo(static_cast<std::size_t>(d_)), hi(static_cast<std::size_t>(d_));
    while (!stack.empty()) {
      const Node node = stack.back();
      stack.pop_back();
      const std::uint32_t m = node.end - node.begin;
      const bool block_here = !node.in_block && m <= block_;
      if (block_here || m > leaf_) bound(recs, node.begin, node.end, lo, hi);
      if (block_here) {
        out.boxes.insert(out.boxes.end(), lo.begin(), lo.end());
        out.boxes.insert(out.boxes.end(), hi.begin(), hi.end());
        out.ends.push_back(node.end);
      }
      auto first = recs.begin() + node.begin, last = recs.begin() + node.end;
      if (m <= leaf_) {
        std::sort(first, last, [&](const Record& a, const Record& b) { return before(a, b, 0); });
        continue;
      }
      const int axis = widest(lo, hi);
      const std::uint32_t mid = node.begin + m / 2;
      std::nth_element(first, recs.begin() + mid, last,
                       [&](const Record& a, const Record& b) { return before(a, b, axis); });
      stack.push_back({mid, node.end, node.in_block || block_here});  // right, after the left
      stack.push_back({node.begin, mid, node.in_block || block_here});
    }
  }

  // The root cut, then its two halves on two threads (each half's blocks in order).
  void split_in_halves(std::vector<Record>& recs, Blocks& out) const {
    const auto n = static_cast<std::uint32_t>(recs.size());
    if (n <= block_ || n < kTwoThreadsAtLeast) {
      split(recs, 0, n, false, out);
      return;
    }
    std::vector<double> lo(static_cast<std::size_t>(d_)), hi(static_cast<std::size_t>(d_));
    bound(recs, 0, n, lo, hi);
    const int axis = widest(lo, hi);
    const std::uint32_t mid = n / 2;
    std::nth_element(recs.begin(), recs.begin() + mid, recs.end(),
                     [&](const Record& a, const Record& b) { return before(a, b, axis); });
    Blocks right;
    std::thread other([&] { split(recs, mid, n, false, right); });
    split(recs, 0, mid, false, out);
    other.join();
    out.ends.insert(out.ends.end(), right.ends.begin(), right.ends.end());
    out.boxes.insert(out.boxes.end(), right.boxes.begin(), right.boxes.end());
  }

 private:
  static constexpr std::uint32_t kTwoThreadsAtLeast = 65536;

  void bound(const std::vector<Record>& recs, std::uint32_t begin, std::uint32_t end, std::vector<double>& lo,
             std::vector<double>& hi) const {
    const double* first = coords(recs[begin]);
    std::copy(first, first + d_, lo.begin());
    std::copy(first, first + d_, hi.begin());
    for (std::uint32_t i = begin + 1; i < end; ++i) {
      const double* p = coords(recs[i]);
      for (int c = 0; c < d_; ++c) {
        lo[static_cast<std::size_t>(c)] = std::min(lo[static_cast<std::size_t>(c)], p[c]);
        hi[static_cast<std::size_t>(c)] = std::max(hi[static_cast<std::size_t>(c)], p[c]);
      }
    }
  }
  // The widest side; the lowest axis among equals.
  int widest(const std::vector<double>& lo, const std::vector<double>& hi) const {
    int axis = 0;
    for (int c = 1; c < d_; ++c) {
      const auto a = static_cast<std::size_t>(axis), k = static_cast<std::size_t>(c);
      if (hi[k] - lo[k] > hi[a] - lo[a]) axis = c;
    }
    return axis;
  }

  const PointSet& ps_;
  int d_;
  std::uint32_t block_, leaf_;
};

}  // namespace

SpaceSplit::SpaceSplit(const PointSet& points, std::uint32_t block, std::uint32_t leaf) : d_(points.dimension()) {
  build(points, {}, {}, block, leaf);
}

SpaceSplit::SpaceSplit(const PointSet& points, std::span<const std::uint32_t> members,
                       std::span<const std::uint32_t> piece_ends, std::uint32_t block, std::uint32_t leaf)
    : d_(points.dimension()) {
  build(points, members, piece_ends, block, leaf);
}

void SpaceSplit::build(const PointSet& points, std::span<const std::uint32_t> members,
                       std::span<const std::uint32_t> piece_ends, std::uint32_t block, std::uint32_t leaf) {
  const auto n = static_cast<std::uint32_t>(points.size());
  const bool whole = piece_ends.empty();
  leaf = std::max<std::uint32_t>(leaf, 1);
  block = std::max(block, leaf);
  first_.push_back(0);
  if (n == 0) return;
  Blocks blocks;
  order_.reserve(n);
  detail::dispatch_dimension(d_, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    const Splitter<D> splitter(points, block, leaf);
    std::vector<typename Splitter<D>::Record> recs;
    if (whole) {
      splitter.fill(recs);
      splitter.split_in_halves(recs, blocks);
    } else {
      splitter.fill(recs, members);
      std::uint32_t begin = 0;
      for (const std::uint32_t end : piece_ends) {
        splitter.split(recs, begin, end, false, blocks);
        begin = end;
      }
    }
    for (const auto& r : recs) order_.push_back(r.id);
  });
  swept_ = static_cast<std::uint32_t>(order_.size());
  leaf_ = leaf;
  if (whole) {
    piece_ends_.assign(1, swept_);
  } else {
    piece_ends_.assign(piece_ends.begin(), piece_ends.end());
  }
  first_.insert(first_.end(), blocks.ends.begin(), blocks.ends.end());
  boxes_ = std::move(blocks.boxes);
  position_.assign(n, 0xFFFFFFFFu);
  for (std::uint32_t i = 0; i < swept_; ++i) position_[order_[i]] = i;
  append_trailing(points);
}

void SpaceSplit::append_trailing(const PointSet& points) {
  const auto n = static_cast<std::uint32_t>(points.size());
  if (swept_ >= n) return;
  // The points of no piece: one trailing block, split as a node of its own so that
  // consecutive positions are near in space (the order a triangulation of the held
  // points inserts them in; with index order each insertion's walk crossed the set).
  std::vector<std::uint32_t> rest;
  rest.reserve(n - swept_);
  for (std::uint32_t i = 0; i < n; ++i) {
    if (position_[i] == 0xFFFFFFFFu) rest.push_back(i);
  }
  detail::dispatch_dimension(d_, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    const Splitter<D> splitter(points, leaf_, leaf_);
    std::vector<typename Splitter<D>::Record> recs;
    splitter.fill(recs, rest);
    Blocks unused;
    splitter.split(recs, 0, static_cast<std::uint32_t>(recs.size()), true, unused);
    for (std::size_t k = 0; k < recs.size(); ++k) rest[k] = recs[k].id;
  });
  std::vector<double> lo(points.point(rest[0]), points.point(rest[0]) + d_), hi = lo;
  for (const std::uint32_t i : rest) {
    position_[i] = static_cast<std::uint32_t>(order_.size());
    order_.push_back(i);
    for (int c = 0; c < d_; ++c) {
      const auto k = static_cast<std::size_t>(c);
      lo[k] = std::min(lo[k], points.point(i)[c]);
      hi[k] = std::max(hi[k], points.point(i)[c]);
    }
  }
  first_.push_back(n);
  boxes_.insert(boxes_.end(), lo.begin(), lo.end());
  boxes_.insert(boxes_.end(), hi.begin(), hi.end());
}

SpaceSplit SpaceSplit::remapped(const PointSet& points, std::span<const std::uint32_t> id_of) const {
  SpaceSplit out(Empty{}, points.dimension());
  out.swept_ = swept_;
  out.leaf_ = leaf_;
  out.piece_ends_ = piece_ends_;
  out.order_.reserve(points.size());
  out.position_.assign(points.size(), 0xFFFFFFFFu);
  for (std::uint32_t i = 0; i < swept_; ++i) {
    const std::uint32_t id = id_of[order_[i]];
    out.order_.push_back(id);
    out.position_[id] = i;
  }
  // The pieces' blocks (those before the trailing one).
  const std::uint32_t blocks = swept_ < size() ? block_count() - 1 : block_count();
  out.first_.assign(first_.begin(), first_.begin() + blocks + 1);
  out.boxes_.assign(boxes_.begin(), boxes_.begin() + static_cast<std::ptrdiff_t>(blocks) * 2 * d_);
  out.append_trailing(points);
  return out;
}

std::uint32_t SpaceSplit::default_block_points(int d, std::uint64_t n) {
  // At least 16 blocks where the set allows, so two workers balance; at most a size
  // per dimension beyond which larger blocks gained nothing (bench/README.md, "Tuning
  // history"): a block's table then outgrows the CPU's caches.
  const std::uint64_t cap = detail::policy(d).sweep_block_points;
  return static_cast<std::uint32_t>(std::clamp<std::uint64_t>(n / 16, 64, cap));
}

std::vector<std::pair<std::uint32_t, std::uint32_t>> SpaceSplit::nodes_of_at_most(std::uint32_t max_points) const {
  // The recursion of Splitter::split on counts alone: [b, e) has children
  // [b, b + (e - b) / 2) and [b + (e - b) / 2, e) until a node holds at most `leaf_`.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> out, stack;
  std::uint32_t begin = 0;
  for (const std::uint32_t end : piece_ends_) {
    stack.emplace_back(begin, end);
    while (!stack.empty()) {
      const auto [b, e] = stack.back();
      stack.pop_back();
      if (e - b <= max_points || e - b <= leaf_) {
        if (e > b) out.emplace_back(b, e);
        continue;
      }
      const std::uint32_t mid = b + (e - b) / 2;
      stack.emplace_back(mid, e);  // right, after the left
      stack.emplace_back(b, mid);
    }
    begin = end;
  }
  return out;
}

std::uint32_t SpaceSplit::block_of(std::uint32_t position) const {
  // The last block that begins at or before `position`.
  const auto it = std::upper_bound(first_.begin(), first_.end() - 1, position);
  return static_cast<std::uint32_t>(it - first_.begin()) - 1;
}

}  // namespace spokemesh
