// Point location in a Delaunay triangulation given as arrays: the simplex holding each
// query point, by a visibility walk (Edelsbrunner: it terminates in a Delaunay
// triangulation) whose every side test is an exact orientation sign. Queries are taken
// in Morton order and each walks from the one before (from the simplex of its nearest
// input point when that walk is long), so a raster or a scattered batch costs a few
// steps a point.
//
// Thread safety: a SimplexLocator is immutable once built; locate() and locate_many()
// may run concurrently.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <type_traits>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/point_set.hpp"

namespace spokemesh {

// The exact sign of det[p_1 - p_0, ..., p_d - p_0] for d + 1 points of R^d given by
// pointers (any coordinates, not only a set's): in 2-d and 3-d the determinant written
// out with BoundedDouble's error bound; otherwise, or where that cannot tell, a filter
// in double (Gaussian elimination with partial pivoting; its error is below
// d^3 2^(d-1) u times the product of the rows' norms by Hadamard, under 1e-10 of it for
// d <= 8), then rationals.
int orientation_of(const std::array<const double*, kMaxDimension + 1>& p, int d);

// The barycentric coordinates of q (d coordinates) in the simplex s (d + 1 point ids of
// `points`), in double: out[0..d], summing to 1 (Gaussian elimination with partial
// pivoting on the differences from s[0]; a zero pivot gives a zero coordinate).
void barycentric_coordinates(const PointSet& points, const std::uint32_t* s, const double* q, double* out);

// The order of `count` points (d coordinates each, row-major) along a Morton curve over
// their box: points close in it are close in space.
std::vector<std::uint32_t> morton_order(const double* x, std::size_t count, int d);

class SimplexLocator {
 public:
  // points: the triangulated set; simplices: m x (d + 1) point ids, each positively
  // oriented; adjacency: the simplex across the facet opposite vertex k, -1 on the hull;
  // tree: a k-d tree of the points. None is owned; all must outlive the locator.
  SimplexLocator(const PointSet& points, std::span<const std::uint32_t> simplices,
                 std::span<const std::int32_t> adjacency, const KdTree& tree);

  // The simplex holding q (a point on a shared face gets one of its simplices), -1
  // outside the hull: the walk from the simplex of q's nearest input point.
  std::int32_t locate(const double* q) const;
  // The walk from simplex `start`, at most max_steps simplices: kWalkTooLong when longer.
  static constexpr std::int32_t kWalkTooLong = -2;
  std::int32_t locate_from(const double* q, std::int32_t start, std::size_t max_steps) const;
  // locate() of `count` queries (row-major) into out[0..count), on `threads` threads:
  // in Morton order, in runs of 256 each walked from the one before. visit(i, simplex),
  // when given, is called for each query as it is located (from the worker threads).
  template <class Visit>
  void locate_many(const double* queries, std::size_t count, unsigned threads, Visit&& visit) const;

 private:
  const PointSet& points_;
  std::span<const std::uint32_t> simplices_;
  std::span<const std::int32_t> adjacency_;
  const KdTree& tree_;
  int d_;
  std::vector<std::int32_t> first_simplex_;  // point -> a simplex holding it
};

// The runs of locate_many: each run's queries in Morton order, walked from the one
// before; after two long walks in a row the hint is tried every 16th query only (a
// scattered run's next point is rarely next door).
void locate_runs(const SimplexLocator& locator, const double* queries, std::size_t count, int d, unsigned threads,
                 const std::vector<std::uint32_t>& order,
                 void (*visit)(void* context, std::size_t run, std::size_t i, std::int32_t simplex), void* context);

template <class Visit>
void SimplexLocator::locate_many(const double* queries, std::size_t count, unsigned threads, Visit&& visit) const {
  const std::vector<std::uint32_t> order = morton_order(queries, count, d_);
  auto trampoline = [](void* context, std::size_t run, std::size_t i, std::int32_t simplex) {
    (*static_cast<std::remove_reference_t<Visit>*>(context))(run, i, simplex);
  };
  locate_runs(*this, queries, count, d_, threads, order, trampoline, &visit);
}

}  // namespace spokemesh
