// KdTree: nanoflann 1.4.3 index over a PointSet, plus the one query nanoflann lacks.
//
// knn() returns the k nearest points by nanoflann's floating-point squared
// distances, ascending. Those distances are only used for ordering and for
// conservative bounds: see kDistanceMargin.
//
// any_beyond() answers "is there a point strictly on side sigma of the hyperplane
// through x with normal n?", pruning the tree's tight boxes by a conservative
// floating-point bound and deciding each surviving point with an exact predicate.
// RSD uses it to certify hull facets (unbounded Voronoi edges) globally instead of
// by growing the neighbourhood.
//
// Layout: the set is split at the top (its bounding box's widest side, at the median)
// into two nanoflann trees under one root of our own, built concurrently for large
// sets. nanoflann builds over a copy of the coordinates in Z-order (its partitioning
// then reads nearby memory), and that copy is then gathered into the trees' leaf
// order: every leaf's points are contiguous in memory, and leaves name ranges of it.
// Queries speak original point indices; the searches are our own copies of
// nanoflann's (see search_level). find_first and any_beyond walk a flattened copy of
// the tree with each node's tight bounding box.
//
// Extension (KdTree::extended): the tree of a set with points appended, made from the
// tree of its first points without building that again: the base's nanoflann nodes
// are shared (reference-counted), the new points get a tree of their own, and a
// search visits each such part in turn. Answers are the same as a tree built whole
// (knn's ties aside: which of two equally distant points comes first may differ), so
// exact star walks give the same stars; budgeted (approximate) walks may differ.
//
// Ownership: the PointSet must outlive the tree; the tree owns its reordered copy
// (n * d doubles; twice that briefly while it is built), the permutation both ways
// (2 n indices) and the box tree (about 0.36 n nodes of 2 d floats and 3 indices), and
// shares nanoflann's nodes with the trees extended from it.
// Thread safety: immutable after construction; concurrent queries are safe. The
// constructor itself uses one extra thread for sets of 65,536 points or more.
#pragma once

#include <nanoflann.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
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
  // A tree whose points from id `first_inexact` on stand for positions known only to
  // within `pad` per coordinate (a periodic set's images, stored rounded: periodic.hpp):
  // the boxes holding them are widened by pad and never flat, so that find_first and
  // any_beyond prune only where no true position can be. knn distances stay those of
  // the stored coordinates (callers allow for pad).
  KdTree(const PointSet& points, std::uint32_t first_inexact, double pad);
  // The tree of `points`, whose first base.points().size() points are base's (same
  // coordinates, same order): base's structure extended by a tree of the rest (see
  // Extension above), or a tree built whole when base already has kMaxParts parts or
  // more than 1/kRebuildBeyondShare of the points are new. `base` may be destroyed
  // afterwards (what is shared is reference-counted). Cost of an extension: copies of
  // base's arrays (about 8 d + 8 bytes a point) and the new points' build.
  static std::unique_ptr<KdTree> extended(const KdTree& base, const PointSet& points);
  static constexpr std::size_t kMaxParts = 8;
  static constexpr std::size_t kRebuildBeyondShare = 16;
  // The trees a search visits: 1 for a tree built whole, one more per extension.
  std::size_t parts() const { return parts_.size(); }
  KdTree(const KdTree&) = delete;
  KdTree& operator=(const KdTree&) = delete;

  const PointSet& points() const { return points_; }

  // Up to k nearest points to `query` (which may itself be a point of the set, and
  // is then returned first at distance 0). Returns the count written. With `coords`,
  // also each point's coordinates (pointers into the tree's leaf-ordered copy, equal
  // to the PointSet's values, valid for the tree's lifetime).
  // With `bound2`, only points at squared distance < bound2 are reported (fewer than
  // k when fewer lie that close): a good bound prunes most of the search.
  std::size_t knn(const double* query, std::size_t k, std::uint32_t* ids, double* dist2,
                  const double** coords = nullptr, double bound2 = std::numeric_limits<double>::infinity()) const;

  // Position of point `id` in the tree's leaf order: points close in this order are
  // close in space (for visiting seeds in a cache-friendly order).
  std::uint32_t leaf_rank(std::uint32_t id) const { return rank_of_[id]; }
  // The point at a leaf-order position (the inverse of leaf_rank).
  std::uint32_t point_at_rank(std::uint32_t rank) const { return id_of_[rank]; }
  // A subtree of the tree: the leaf-order positions [begin, end) and their tight box
  // (d lows, then d highs; floats rounded outwards, so every point lies inside).
  struct Subtree {
    std::uint32_t begin = 0, end = 0;
    const float* box = nullptr;  // valid for the tree's lifetime
  };
  // The maximal subtrees holding at most max_points points each (a leaf when even a
  // leaf holds more), in leaf order: their ranges tile [0, n). Empty for an empty set.
  std::vector<Subtree> subtrees_of_at_most(std::uint32_t max_points) const;

  // Every point p with nanoflann's squared distance to `query` < r2 (strictly, as
  // nanoflann's radius search; unsorted).
  void within(const double* query, double r2, std::vector<std::pair<std::uint32_t, double>>& out) const;

  // First point p found (in tree order) with `exact_side(p) == sigma` (or
  // `exact_side(p, coordinates of p)`), or none. `normal` approximates the
  // hyperplane's normal with certified error bounds; it prunes boxes only where no
  // point can be strictly on side sigma.
  template <class ExactSide>
  std::optional<std::uint32_t> any_beyond(const double* x, const BoundedDouble* normal, int sigma,
                                          ExactSide&& exact_side) const;

  // First point p (in tree order) with accept(p), visiting only boxes for which
  // may_contain(lo, hi) holds (d lows, d highs: floats rounded outwards, read in
  // place; widened to double, they are exact). may_contain must be conservative:
  // false only when no point of the box can be accepted. It may also take (lo, hi,
  // flat, first): bit c of `flat` set when every point of the box has coordinate c
  // equal to first[c] (exact doubles). `accept` may also take (p, coordinates of p),
  // read from the leaf-ordered copy. None when no point is accepted.
  template <class MayContain, class Accept>
  std::optional<std::uint32_t> find_first(MayContain&& may_contain, Accept&& accept) const;

 private:
  KdTree(const KdTree& base, const PointSet& points);  // the extension (see extended)
  void build_whole();                                  // the constructors' build of points_ as one tree

  // Reads the PointSet while nanoflann builds, the leaf-ordered copy afterwards.
  struct Adaptor {
    const double* coords;
    std::size_t n;
    std::size_t d;
    std::size_t kdtree_get_point_count() const { return n; }
    double kdtree_get_pt(std::size_t i, std::size_t c) const { return coords[i * d + c]; }
    template <class Box>
    bool kdtree_get_bbox(Box&) const {
      return false;
    }
  };
  using Index =
      nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Adaptor>, Adaptor, -1, std::uint32_t>;
  using Node = typename Index::Node;

  template <class ResultSet>
  void search(const double* query, ResultSet& result) const;
  template <int D, class ResultSet>
  bool search_level(const Node* node, ResultSet& result, const double* query, double mindistsq, double* offsets) const;
  // Appends `node`'s subtree to the box tree; returns the node's position.
  std::size_t add_box_nodes(const Node* node);

  // nanoflann's tree again, flattened in preorder (left child first) with each
  // node's tight bounding box, for find_first: a subtree is the leaf-order range
  // [begin, end), and `skip` is the position just past it (a leaf: its own + 1).
  // Tight boxes prune far better than the split planes nanoflann keeps, most of all
  // for the large spheres of seeds near the hull (5-d: 3x fewer points tested). The
  // bounds are floats rounded outwards (still conservative): about 0.36 nodes per
  // point, so 2.9 d + 4.3 bytes per point where doubles would take 5.8 d + 4.3.
  struct BoxNode {
    std::uint32_t begin, end, skip;
    // Bit c: every point of the box has the same coordinate c (read it exactly from
    // the box's first point). Grids' faces are such boxes: flat along their normal.
    std::uint32_t flat;
  };

  // Sets at least this large are split at the top into two nanoflann trees (see the
  // constructor), built concurrently from this size on.
  static constexpr std::size_t kSplitAtLeast = 64;
  static constexpr std::size_t kBuildInParallelAtLeast = 65536;
  // Adds `by` to the point ranges of the leaves under node.
  static void shift_leaves(Node* node, std::uint32_t by);

  // One build's nanoflann trees and the root of our own above them. Shared with the
  // trees extended from this one, which search the same nodes (never written after
  // the build; the leaves' ranges are leaf positions, the same in the extension).
  struct Built {
    Adaptor adaptors[2];  // each half's coordinates, while nanoflann builds
    std::unique_ptr<Index> halves[2];
    Node top{};  // the root above the two halves
  };
  // A tree searched on its own: its root and its points' bounding box (d lows, then d
  // highs). One for a tree built whole; an extension adds one per extension.
  struct Part {
    const Node* root = nullptr;
    std::vector<double> bbox;
  };

  const PointSet& points_;
  std::size_t d_;
  std::vector<std::shared_ptr<Built>> built_;
  std::vector<Part> parts_;             // over consecutive ranges of leaf positions, in order
  std::vector<double> bbox_;            // all points' box: d lows, then d highs
  std::vector<double> leaf_coords_;     // coordinates in leaf order, n * d
  std::vector<std::uint32_t> id_of_;    // leaf position -> original index
  std::vector<std::uint32_t> rank_of_;  // original index -> leaf position
  std::vector<BoxNode> box_nodes_;
  std::vector<float> box_bounds_;  // per box node: d lows, then d highs, rounded outwards
  std::uint32_t first_inexact_ = 0xFFFFFFFFu;
  double pad_ = 0;
};

template <class MayContain, class Accept>
std::optional<std::uint32_t> KdTree::find_first(MayContain&& may_contain, Accept&& accept) const {
  // Stackless preorder walk of the box tree: a rejected box jumps past its subtree.
  const std::size_t d = d_;
  const std::size_t count = box_nodes_.size();
  for (std::size_t i = 0; i < count;) {
    const BoxNode& node = box_nodes_[i];
    const float* lo = &box_bounds_[i * 2 * d];
    bool visit;
    if constexpr (std::is_invocable_v<MayContain&, const float*, const float*, std::uint32_t, const double*>) {
      visit = may_contain(lo, lo + d, node.flat, leaf_coords_.data() + std::size_t{node.begin} * d);
    } else {
      visit = may_contain(lo, lo + d);
    }
    if (!visit) {
      i = node.skip;
      continue;
    }
    if (node.skip == i + 1) {  // a leaf
      for (std::uint32_t k = node.begin; k < node.end; ++k) {
        const std::uint32_t p = id_of_[k];
        if constexpr (std::is_invocable_v<Accept&, std::uint32_t, const double*>) {
          if (accept(p, &leaf_coords_[k * d])) return p;
        } else {
          if (accept(p)) return p;
        }
      }
    }
    ++i;
  }
  return std::nullopt;
}

template <class ExactSide>
std::optional<std::uint32_t> KdTree::any_beyond(const double* x, const BoundedDouble* normal, int sigma,
                                                ExactSide&& exact_side) const {
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
    if (normal[c].depth >= BoundedDouble::kUnsafe || !(normal[c].magnitude <= DBL_MAX)) {
      return find_first([](const float*, const float*) { return true; }, on_side);
    }
  }
  // Upper bound of sigma * n.(p - x) over a box. Each normal component is known to
  // within e_c; box offsets are rounded once; the sum is rounded d times. The 1e-12
  // relative slack covers those roundings (<= (d + 3) 2^-53 relative).
  // A box is also skipped when every term sigma n_c (p_c - x_c) is certainly <= 0 for
  // all its points: the normal component is exactly zero (no monomial: a == 0; safe
  // depths were checked above), or its sign is certain and the box lies on the
  // non-positive side of x_c (fl(p - x) keeps the sign of p - x, so the comparisons
  // are exact), or the box is flat at x_c. The rounded bound cannot see this where
  // the maximum is exactly 0: a grid's face seed's hull facets lie in the face, and
  // each hull query visited every box along the face (quadratic in its size).
  auto may_contain = [&](const float* lo, const float* hi, std::uint32_t flat, const double* first) {
    double bound = 0, magnitude = 0;
    bool nonpositive = true;
    for (int c = 0; c < d; ++c) {
      const double t = sigma * normal[c].value;
      const bool is_flat = (flat >> c) & 1u;
      const double low = is_flat ? first[c] : static_cast<double>(lo[c]);
      const double high = is_flat ? first[c] : static_cast<double>(hi[c]);
      const double lo_off = low - x[c], hi_off = high - x[c];
      const double reach = std::max(std::fabs(lo_off), std::fabs(hi_off));
      const double e = filter::error_bound(normal[c].magnitude, normal[c].depth);
      bound += std::max(t * lo_off, t * hi_off) + e * reach;
      magnitude += std::fabs(t) * reach + e * reach;
      nonpositive &= normal[c].magnitude == 0 || (low == x[c] && high == x[c]) || (t > e && high <= x[c]) ||
                     (t < -e && low >= x[c]);
    }
    return !nonpositive && bound + 1e-12 * magnitude >= 0;
  };
  return find_first(may_contain, on_side);
}

}  // namespace spokemesh
