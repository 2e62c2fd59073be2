// ConvexHull: the exact convex hull of n points in R^d (2 <= d <= 8), as scipy's
// ConvexHull gives it (triangulated facets, their neighbours and hyperplanes), built
// by Quickhull (Barber, Dobkin & Huhdanpaa 1996) with every visibility decided by the
// exact sign of an orientation determinant (a filter in double with its error bound,
// then GMP rationals).
//
// What a facet is. Facets are (d - 1)-simplices of hull vertices. A point is made a
// vertex only when it lies strictly beyond a facet (orientation > 0); a point on a
// facet's hyperplane (orientation exactly 0) is not beyond it, so points on the hull's
// flat faces and exact duplicates are not vertices, as Qhull's `Qt` leaves them out.
// Flat faces are triangulated by the facets that cover them. A point that lay strictly
// outside when it was added stays a vertex even if later points put it on a flat face
// (Qhull would merge that face within its precision; exact facets are kept).
//
// Determinism: every choice is a function of the point set, not of the input order:
// the initial simplex is the lexicographically smallest and largest points and then the
// furthest points from their span; the point added next is the furthest above the
// oldest facet with an outside set (ties: the lexicographically larger point, then the
// smaller index); points are assigned to the first new facet they lie beyond, in
// creation order. Facet rows are listed in creation order, so extend() appends the new
// facets after the old ones that survive (as scipy's add_points does).
//
// Thread safety: a ConvexHull is a value; concurrent const calls are safe, extend()
// needs exclusive access.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct HullOptions {
  // A point index left out of the hull (scipy's `QGn` viewpoint), or -1 for none.
  std::int64_t exclude = -1;
  // Worker threads for the large steps (assigning many points to facets); 0: all
  // cores. The hull is the same for any count.
  unsigned threads = 0;
  // Set by another thread to stop a long build: CANCELLED. Not owned; may be null.
  const std::atomic<bool>* cancel = nullptr;
};

class ConvexHull {
 public:
  // The hull of the n x d row-major `coordinates` (not kept past the call).
  // Errors (INVALID_ARGUMENT, naming what and where): d outside 2..8, fewer than d + 1
  // points, a non-finite coordinate (its index), more than 2^32 - 16 points, a flat set
  // (every point in one hyperplane: "the hull is flat", with the span's dimension).
  static Result<ConvexHull> build(std::span<const double> coordinates, int d, const HullOptions& options = {});

  // Adds the points after the first size() of `coordinates` (which holds the same
  // first points, then the new ones) and updates the hull: the facets that survive keep
  // their order, new ones follow. Errors as build(); on error the hull is unchanged.
  Status extend(std::span<const double> coordinates, const HullOptions& options = {});

  int dimension() const { return d_; }
  std::size_t points() const { return n_; }
  std::size_t facet_count() const { return facets_.size(); }
  // Facet f's d vertex ids, ordered so that for any point x,
  // det[v1 - v0, ..., v(d-1) - v0, x - v0] > 0 exactly when x lies strictly outside
  // f's hyperplane (for d = 2: each edge v0 -> v1 runs clockwise around the hull).
  std::vector<std::uint32_t> facet_vertices() const;
  // Facet f's neighbour across the ridge opposite its vertex k, row f, column k.
  std::vector<std::int32_t> facet_neighbors() const;
  // Facet f's hyperplane (unit outward normal, then offset: normal . x + offset <= 0
  // inside), computed in double from the vertices (scipy's `equations`).
  std::vector<double> facet_equations(std::span<const double> coordinates) const;
  // The exact sign of facet f's orientation with point x of `coordinates`: +1 x
  // strictly beyond (visible), 0 on the hyperplane, -1 beneath.
  int side(std::span<const double> coordinates, std::size_t f, std::size_t x) const;
  // The polytope's facets as groups of these simplicial facets: facets f and g across a
  // ridge are in one group when g's other vertex lies exactly on f's hyperplane (and so
  // on, transitively). Group ids count from 0 in order of each group's first facet.
  std::vector<std::uint32_t> facet_groups(std::span<const double> coordinates) const;
  // The vertices, ascending point ids.
  std::vector<std::uint32_t> vertices() const;
  // The points of `coordinates` (the hull's) that are not vertices but lie on the
  // boundary, exactly on a facet's hyperplane (equal points and points on flat faces:
  // what Qhull's `Qc` calls coplanar): rows (point, that facet, the facet's vertex
  // nearest to it in double), by point id. Tests every such point against every
  // facet: O(n facets), for callers that ask.
  std::vector<std::array<std::uint32_t, 3>> coplanar(std::span<const double> coordinates,
                                                     std::int64_t exclude = -1) const;

 private:
  // A facet: its vertices (point ids) and neighbours (facet ids), d of each used.
  struct Facet {
    std::array<std::uint32_t, kMaxDimension> v{};
    std::array<std::uint32_t, kMaxDimension> nb{};
    bool live = true;
  };
  class Builder;
  int d_ = 0;
  std::size_t n_ = 0;
  std::vector<Facet> facets_;  // the live facets, in creation order (dead ones dropped after each call)
};

}  // namespace spokemesh
