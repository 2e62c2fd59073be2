// KdTree: nanoflann 1.4.3 index over a PointSet, plus the one query nanoflann lacks.
//
// knn() returns the k nearest points by nanoflann's floating-point squared
// distances, ascending. Those distances are only used for ordering and for
// conservative bounds: see kDistanceMargin.
//
// any_beyond() answers "is there a point strictly on side sigma of the hyperplane
// through x with normal n?", pruning boxes of nanoflann's tree by a conservative
// floating-point bound and deciding each surviving point with an exact predicate.
// RSD uses it to certify hull facets (unbounded Voronoi edges) globally instead of
// by growing the neighbourhood.
//
// Layout: after nanoflann builds its tree, the coordinates are copied in the tree's
// leaf order and nanoflann's index permutation is reset to the identity, so every
// leaf's points are contiguous in memory (the tree itself is unchanged). Queries
// speak original point indices.
//
// Ownership: the PointSet must outlive the tree; the tree owns its reordered copy
// (n * d doubles) and the permutation both ways (2 n indices). Thread safety: immutable after construction; concurrent queries
// are safe.
#pragma once

#include <nanoflann.hpp>

#include <cmath>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {

// Relative margin by which a nanoflann squared distance may exceed the exact one.
// Its error is a few ulps times d (a sum of d rounded squares, and bounding-box
// distances updated incrementally during the search); 1e-9 exceeds it by far for
// every d up to 1000, so "exact >= nanoflann * (1 - kDistanceMargin)" is certain.
inline constexpr double kDistanceMargin = 1e-9;

class KdTree {
 public:
  explicit KdTree(const PointSet& points);
  KdTree(const KdTree&) = delete;
  KdTree& operator=(const KdTree&) = delete;

  const PointSet& points() const { return points_; }

  // Up to k nearest points to `query` (which may itself be a point of the set, and
  // is then returned first at distance 0). Returns the count written. With `coords`,
  // also each point's coordinates (pointers into the tree's leaf-ordered copy, equal
  // to the PointSet's values, valid for the tree's lifetime).
  std::size_t knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2,
                  const double** coords = nullptr) const;

  // Position of point `id` in the tree's leaf order: points close in this order are
  // close in space (for visiting seeds in a cache-friendly order).
  std::uint32_t leaf_rank(std::uint32_t id) const { return rank_of_[id]; }

  // Every point p with nanoflann's squared distance to `query` <= r2 (unsorted).
  void within(const double* query, double r2, std::vector<std::pair<std::uint32_t, double>>& out) const;

  // First point p found (in tree order) with `exact_side(p) == sigma` (or
  // `exact_side(p, coordinates of p)`), or -1 if none. `normal` approximates the
  // hyperplane's normal with certified error bounds; it prunes boxes only where no
  // point can be strictly on side sigma.
  template <class ExactSide>
  std::int64_t any_beyond(const double* x, const Approx* normal, int sigma, ExactSide&& exact_side) const;

  // First point p (in tree order) with accept(p), visiting only boxes for which
  // may_contain(lo, hi) holds. may_contain must be conservative: false only when
  // no point of the box can be accepted. `accept` may also take (p, coordinates of
  // p), read from the leaf-ordered copy.
  template <class MayContain, class Accept>
  std::int64_t find_first(MayContain&& may_contain, Accept&& accept) const;

 private:
  // Reads the PointSet while nanoflann builds, the leaf-ordered copy afterwards.
  struct Adaptor {
    const double* coords;
    std::size_t n;
    std::size_t d;
    std::size_t kdtree_get_point_count() const { return n; }
    double kdtree_get_pt(std::size_t i, std::size_t c) const { return coords[i * d + c]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const { return false; }
  };
  using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Adaptor>,
                                                    Adaptor, -1, std::uint32_t>;
  using Node = typename Index::Node;

  template <class ResultSet>
  void search(const double* query, ResultSet& result) const;
  template <int D, class ResultSet>
  bool search_level(const Node* node, ResultSet& result, const double* query, double mindistsq, double* offsets) const;

  const PointSet& points_;
  Adaptor adaptor_;
  std::unique_ptr<Index> index_;
  std::vector<double> leaf_coords_;    // coordinates in leaf order, n * d
  std::vector<std::uint32_t> id_of_;  // leaf position -> original index
  std::vector<std::uint32_t> rank_of_;  // original index -> leaf position
};

template <class MayContain, class Accept>
std::int64_t KdTree::find_first(MayContain&& may_contain, Accept&& accept) const {
  // Depth first with an explicit stack; each frame carries its box (nanoflann keeps
  // only the split values), stored in a fixed pool: no allocation per query.
  const int d = points().dimension();
  constexpr int kMaxDepth = 128;  // nanoflann's tree depth is O(log n)
  const Node* nodes[kMaxDepth];
  thread_local std::vector<double> pool;
  if (pool.size() < static_cast<std::size_t>(kMaxDepth * 2 * d)) pool.resize(kMaxDepth * 2 * d);
  auto boxes = [&](int i) { return pool.data() + static_cast<std::size_t>(i) * 2 * d; };
  int top = 0;
  nodes[0] = index_->root_node;
  for (int c = 0; c < d; ++c) {
    boxes(0)[c] = index_->root_bbox[c].low;
    boxes(0)[d + c] = index_->root_bbox[c].high;
  }
  while (top >= 0) {
    const Node* node = nodes[top];
    double* box = boxes(top);
    if (!may_contain(box, box + d)) {
      --top;
      continue;
    }
    if (node->child1 == nullptr && node->child2 == nullptr) {
      --top;
      for (auto k = node->node_type.lr.left; k < node->node_type.lr.right; ++k) {
        const std::uint32_t p = id_of_[k];
        if constexpr (std::is_invocable_v<Accept&, std::uint32_t, const double*>) {
          if (accept(p, &leaf_coords_[k * static_cast<std::size_t>(d)])) return p;
        } else {
          if (accept(p)) return p;
        }
      }
      continue;
    }
    if (top + 2 >= kMaxDepth) return -1;  // unreachable for trees of fewer than 2^100 points
    const int feature = node->node_type.sub.divfeat;
    // Replace this frame by its right child and push the left one (visited first).
    std::copy(box, box + 2 * d, boxes(top + 1));
    box[feature] = node->node_type.sub.divhigh;  // right child: lo[feature]
    nodes[top] = node->child2;
    boxes(top + 1)[d + feature] = node->node_type.sub.divlow;  // left child: hi[feature]
    nodes[top + 1] = node->child1;
    ++top;
  }
  return -1;
}

template <class ExactSide>
std::int64_t KdTree::any_beyond(const double* x, const Approx* normal, int sigma, ExactSide&& exact_side) const {
  const int d = points().dimension();
  auto on_side = [&](std::uint32_t p, const double* coords) {
    if constexpr (std::is_invocable_v<ExactSide&, std::uint32_t, const double*>) {
      return exact_side(p, coords) == sigma;
    } else {
      (void)coords;
      return exact_side(p) == sigma;
    }
  };
  for (int c = 0; c < d; ++c) {
    if (normal[c].n >= Approx::kUnsafe || !(normal[c].a <= DBL_MAX)) {
      return find_first([](const double*, const double*) { return true; }, on_side);
    }
  }
  // Upper bound of sigma * n.(p - x) over a box. Each normal component is known to
  // within e_c; box offsets are rounded once; the sum is rounded d times. The 1e-12
  // relative slack covers those roundings (<= (d + 3) 2^-53 relative).
  auto may_contain = [&](const double* lo, const double* hi) {
    double bound = 0, magnitude = 0;
    for (int c = 0; c < d; ++c) {
      const double t = sigma * normal[c].v;
      const double lo_off = lo[c] - x[c], hi_off = hi[c] - x[c];
      const double reach = std::max(std::fabs(lo_off), std::fabs(hi_off));
      const double e = normal[c].a * (static_cast<double>(normal[c].n + 2) * 0x1p-53) * 1.01;
      bound += std::max(t * lo_off, t * hi_off) + e * reach;
      magnitude += std::fabs(t) * reach + e * reach;
    }
    return bound + 1e-12 * magnitude >= 0;
  };
  return find_first(may_contain, on_side);
}

}  // namespace spokemesh
