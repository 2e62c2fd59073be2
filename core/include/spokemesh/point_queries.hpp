// Answers at points that are not in the set, for callers that answer many of them over
// one set (the service's :locate and :interpolate): the simplex holding a query point,
// its barycentric coordinates, its natural neighbours with Sibson's coordinates, and
// values interpolated from those or from the nearest point.
//
// Every answer is a function of the point set and the query point alone, never of the
// walk that found the simplex or of the other queries in a batch: a point on a face
// shared by several simplices gets the least of them (canonical_simplex), and every
// sum runs in ascending point order. So replicas, shards and batches of any size give
// the same bytes, and so does the Python module (which answers from the same rows).
//
// Thread safety: a DelaunayIndex is immutable once built; its member functions and
// answer_point may run concurrently.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/locate.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/natural_neighbors.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// Among the simplices holding q (one, or several when q lies exactly on a face they
// share: every orientation sign of q against a facet is exact), the one whose
// ascending vertex list is least; `located` is any of them (SimplexLocator's), -1
// outside the hull (returned as it is). The simplices holding q are those reached
// from `located` across facets q lies on.
std::int32_t canonical_simplex(const DelaunayArrays& tri, std::int32_t located, const double* q);

// A simplex's w point ids sorted ascending, in place (an insertion sort: w <= 9).
void sort_vertices(std::uint32_t* v, int w);

// The Delaunay triangulation of a set as arrays (mesh_seeds' rows, canonical and
// positively oriented), their adjacency and a SimplexLocator over them. About
// 8 (d + 1) bytes a simplex and 4 a point (2-d: 2 simplices a point; 3-d uniform: 6.8).
// Ownership: borrows the tree (and through it the points), which must outlive it.
class DelaunayIndex {
 public:
  // mesh_seeds(tree, options) with its rows kept (options.split, .whole, .threads,
  // .star.cancel are the caller's: a kept triangulation of every point makes it a
  // copy). reserve_bytes, when set, is asked for the rows and the adjacency before
  // they are made (false: RESOURCE_EXHAUSTED). Errors: mesh_seeds'.
  static Result<std::unique_ptr<DelaunayIndex>> build(const KdTree& tree, MeshOptions options,
                                                      const std::function<bool(std::size_t)>& reserve_bytes = {});
  // What it holds, bytes.
  std::size_t bytes() const;
  const PointSet& points() const { return tree_.points(); }
  const KdTree& tree() const { return tree_; }
  DelaunayArrays arrays() const { return {&tree_.points(), simplices_, adjacency_}; }
  const SimplexLocator& locator() const { return *locator_; }

 private:
  explicit DelaunayIndex(const KdTree& tree) : tree_(tree) {}
  const KdTree& tree_;
  std::vector<std::uint32_t> simplices_;
  std::vector<std::int32_t> adjacency_;
  std::unique_ptr<SimplexLocator> locator_;
};

// One query point's answer.
struct PointAnswer {
  // The canonical simplex holding it, ascending point ids (vertex_count = d + 1), and
  // its barycentric coordinates in that order; vertex_count 0 outside the hull.
  int vertex_count = 0;
  std::array<std::uint32_t, kMaxDimension + 1> simplex{};
  std::array<double, kMaxDimension + 1> barycentric{};
  // With natural neighbours asked (2-d and 3-d): Sibson's coordinates, from the
  // canonical simplex (natural_neighbors.hpp; where kOutside outside the hull).
  NaturalCoordinates natural;
};

// The answer at q from `located` (SimplexLocator's simplex for q, or -1 outside).
// natural: also its natural neighbours (INVALID_ARGUMENT outside 2-d and 3-d).
Status answer_point(const DelaunayArrays& tri, std::int32_t located, const double* q, bool natural, PointAnswer& out);

// What an answer at q rests on, for a caller holding part of a set (a piece: pieces.hpp)
// that must know whether the answer it computed is the whole set's: the simplices
// holding q (canonical_simplex's search) and, with natural, the cavity and the
// simplices across its boundary; and the hull facets (simplex, opposite vertex) q lies
// on or the cavity ends at. The answer from a subset's triangulation is the whole
// set's when each of these simplices is one of the whole set's (an empty circumsphere
// in the whole set) and each hull facet lies on the whole set's hull. outside: q lies
// outside the triangulation's hull (located < 0): nothing else is said.
struct AnswerSupport {
  bool outside = false;
  std::vector<std::int32_t> simplices;
  std::vector<std::pair<std::int32_t, int>> hull_facets;
};
void answer_support(const DelaunayArrays& tri, std::int32_t located, const double* q, bool natural, AnswerSupport& out);

// Values at a query point from its answer: `values` holds `width` values per point of
// the set (row-major); out[0..width). Linear: the barycentric coordinates applied;
// natural: Sibson's. False outside the hull (out untouched).
bool interpolate_linear(const PointAnswer& answer, std::span<const double> values, std::size_t width, double* out);
bool interpolate_natural(const PointAnswer& answer, std::span<const double> values, std::size_t width, double* out);

// The nearest point of the tree's set to q: of those at the least squared distance (as
// computed in double), the smallest index, so equally near points cannot make two
// answers differ.
std::uint32_t nearest_point(const KdTree& tree, const double* q);

}  // namespace spokemesh
