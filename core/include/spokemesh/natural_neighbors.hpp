// Natural neighbours and Sibson coordinates of a query point that is not in the set:
// the points whose Voronoi cells the query's own cell would take volume from if it were
// inserted, and those volumes' shares (Sibson 1980). Nothing is inserted: the
// Delaunay simplices whose circumspheres hold the query strictly (the Bowyer-Watson
// cavity, decided by an exact in-sphere test: a filter with its error bound, then
// rationals) name the natural neighbours, and the query's Voronoi cell is split into
// the stolen parts in double, relative to the query: in 2-d by Watson's construction
// (each neighbour's part from the Voronoi vertices before and after, in O(cavity)), in
// 3-d from each part's faces, which the cavity names (their areas as fans of the new
// and old Voronoi vertices, their planes the bisectors: the divergence theorem's sum),
// with exact hulls of each part's vertices where that fails to reproduce the query.
//
// Sibson's coordinates are non-negative, sum to 1, and reproduce linear functions:
// sum w_i p_i = q (to rounding). A point on the circumsphere of a simplex (exactly) is
// not in its conflict: the neighbour it would add has a zero share, so the coordinates
// are the same either way.
//
// Thread safety: natural_neighbors is a pure function; concurrent calls are safe.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// A Delaunay triangulation as arrays: m simplices of d + 1 point ids each, positively
// oriented (det[p1 - p0, ..., pd - p0] > 0), and their adjacency (simplex across the
// facet opposite vertex k, -1 on the hull). Not owned.
struct DelaunayArrays {
  const PointSet* points = nullptr;
  std::span<const std::uint32_t> simplices;
  std::span<const std::int32_t> adjacency;
};

struct NaturalCoordinates {
  // kInside: Sibson's coordinates; kOnHull: the query lies on the hull's boundary,
  // where Sibson's coordinates are their limit, the containing simplex's barycentric
  // ones here (exact for d = 2, where the boundary is edges; for d = 3 the limit on a
  // hull facet would be 2-d Sibson coordinates within it); kOutside: none.
  enum class Where { kInside, kOnHull, kOutside };
  Where where = Where::kOutside;
  std::vector<std::uint32_t> neighbors;  // ascending point ids
  std::vector<double> weights;           // one per neighbour
};

// The natural neighbours of q (d coordinates) and their Sibson coordinates, given the
// simplex containing q (`simplex`, -1 when q is outside the hull; SimplexLocator finds
// it). d is 2 or 3 (INVALID_ARGUMENT otherwise: the split of the query's cell is
// written for those).
Result<NaturalCoordinates> natural_neighbors(const DelaunayArrays& tri, std::int32_t simplex, const double* q);
// The same into `out`, reusing its buffers (a loop over many queries allocates little).
Status natural_neighbors(const DelaunayArrays& tri, std::int32_t simplex, const double* q, NaturalCoordinates& out);

// The exact sign of q against the circumsphere of the positively oriented simplex
// `s` (d + 1 point ids): +1 strictly inside, 0 on it, -1 outside.
int in_circumsphere(const PointSet& points, const std::uint32_t* s, const double* q);

}  // namespace spokemesh
