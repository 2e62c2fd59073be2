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
// Ownership: the PointSet must outlive the tree. Thread safety: immutable after
// construction; concurrent queries are safe.
#pragma once

#include <nanoflann.hpp>

#include <cmath>
#include <cstdint>
#include <memory>
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

  const PointSet& points() const { return adaptor_.ps; }

  // Up to k nearest points to `query` (which may itself be a point of the set, and
  // is then returned first at distance 0). Returns the count written.
  std::size_t knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2) const;

  // First point p found (in tree order) with `exact_side(p) == sigma`, or -1 if
  // none. `normal` approximates the hyperplane's normal with certified error
  // bounds; it prunes boxes only where no point can be strictly on side sigma.
  template <class ExactSide>
  std::int64_t any_beyond(const double* x, const Approx* normal, int sigma, ExactSide&& exact_side) const;

 private:
  struct Adaptor {
    const PointSet& ps;
    std::size_t kdtree_get_point_count() const { return ps.size(); }
    double kdtree_get_pt(std::size_t i, std::size_t c) const { return ps.point(i)[c]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const { return false; }
  };
  using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Adaptor>,
                                                    Adaptor, -1, std::uint32_t>;
  using Node = typename Index::Node;

  template <class ExactSide>
  std::int64_t search_beyond(const Node* node, std::vector<double>& lo, std::vector<double>& hi,
                             const double* x, const Approx* normal, int sigma,
                             ExactSide& exact_side) const;

  Adaptor adaptor_;
  std::unique_ptr<Index> index_;
};

template <class ExactSide>
std::int64_t KdTree::any_beyond(const double* x, const Approx* normal, int sigma,
                                ExactSide&& exact_side) const {
  const int d = points().dimension();
  std::vector<double> lo(d), hi(d);
  for (int c = 0; c < d; ++c) {
    lo[c] = index_->root_bbox[c].low;
    hi[c] = index_->root_bbox[c].high;
  }
  return search_beyond(index_->root_node, lo, hi, x, normal, sigma, exact_side);
}

template <class ExactSide>
std::int64_t KdTree::search_beyond(const Node* node, std::vector<double>& lo, std::vector<double>& hi,
                                   const double* x, const Approx* normal, int sigma,
                                   ExactSide& exact_side) const {
  const int d = points().dimension();
  // Upper bound of sigma * n.(p - x) over the box. Each normal component is known
  // to within e_c; box offsets are rounded once; the sum is rounded d times. The
  // 1e-12 relative slack covers those roundings (<= (d + 3) 2^-53 relative).
  double bound = 0, magnitude = 0;
  for (int c = 0; c < d; ++c) {
    const double t = sigma * normal[c].v;
    const double lo_off = lo[c] - x[c], hi_off = hi[c] - x[c];
    const double reach = std::max(std::fabs(lo_off), std::fabs(hi_off));
    const double e = normal[c].a * (static_cast<double>(normal[c].n + 2) * 0x1p-53) * 1.01;
    bound += std::max(t * lo_off, t * hi_off) + e * reach;
    magnitude += std::fabs(t) * reach + e * reach;
  }
  const bool unsafe = [&] {
    for (int c = 0; c < d; ++c) {
      if (normal[c].n >= Approx::kUnsafe || !(normal[c].a <= DBL_MAX)) return true;
    }
    return false;
  }();
  if (!unsafe && bound + 1e-12 * magnitude < 0) return -1;

  if (node->child1 == nullptr && node->child2 == nullptr) {
    for (auto k = node->node_type.lr.left; k < node->node_type.lr.right; ++k) {
      const std::uint32_t p = index_->vAcc[k];
      if (exact_side(p) == sigma) return p;
    }
    return -1;
  }
  const int f = node->node_type.sub.divfeat;
  const double saved_hi = hi[f];
  hi[f] = node->node_type.sub.divlow;
  std::int64_t found = search_beyond(node->child1, lo, hi, x, normal, sigma, exact_side);
  hi[f] = saved_hi;
  if (found >= 0) return found;
  const double saved_lo = lo[f];
  lo[f] = node->node_type.sub.divhigh;
  found = search_beyond(node->child2, lo, hi, x, normal, sigma, exact_side);
  lo[f] = saved_lo;
  return found;
}

}  // namespace spokemesh
