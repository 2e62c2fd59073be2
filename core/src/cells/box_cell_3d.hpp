// BoxCell3d: the direct route's cell in 3-d (cells.hpp, ClippedCellBuilder), specialised.
//
// The same construction as CellPolytope built from a box (cell_polytope.hpp): a simple
// polytope, each vertex on exactly three planes with its three edges stored, cut by the
// bisectors of the seed's nearest points. Specialised for the one case that dominates
// `spokemesh cells` (profiled on 1M uniform points, bench/README.md): 64-byte vertex
// records in coordinates relative to the seed, planes in a small table, no heap
// allocation after the first cells, and measures taken from cones at the seed.
//
// With power weights the cuts are power bisectors, |y|^2 - w_s <= |y - q|^2
// - w_p, i.e. q . y <= (|q|^2 - (w_p - w_s)) / 2: the same planes with other offsets,
// decided by the same predicates with weighted heights; the cell need not contain the
// seed (then some offsets are negative), and may become empty (the caller then asks
// the star whether the seed is hidden); an exact tie, which the perturbation would
// decide, sends the seed to the star as well (exact_side).
//
// On a periodic cover (periodic_cover.hpp) the cuts are by the cover's points and images; an
// image's difference from the seed is computed from its exact position, rounded once
// (image_difference), and the exact stages read exact images (Predicates' ImageMap), so
// the decisions are those of the torus's cell.
//
// Every keep/drop decision is certified: by a forward error bound (the plane's
// rounding plus the vertex's error) where it holds, otherwise exactly by the star's
// predicates, ties by its symbolic perturbation (exact_side), so the cell is the
// star's cell, zero-area facets included. Every new vertex is solved from its three
// planes by Cramer's rule with a bound; when that system is nearly singular, clip()
// returns false and the caller builds the cell by the generic CellPolytope. So the
// polytope, whenever this class finishes it, is the exact clipped cell, and its
// measures are double values of it.
//
// Thread safety: a value type with scratch buffers; one per thread.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include <gmpxx.h>

#include "spokemesh/domain.hpp"
#include "spokemesh/periodic_cover.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::detail {

class BoxCell3d {
 public:
  // `box`: a 3-d box domain with lower < upper (is_box()); borrowed, with `points` and
  // `weights` (one power weight per point, or empty: plain bisectors).
  BoxCell3d(const PointSet& points, const Domain& box, std::span<const double> weights = {},
            const PeriodicCover* cover = nullptr);

  // Starts over from the box around `seed` (which must lie in the closed box).
  void reset(std::uint32_t seed);
  // Cuts by the bisector of the seed and point `label`, whose coordinates are `p`
  // (they must stay valid until assemble()). False when a decision or a new vertex
  // could not be certified: the cell must then be built another way.
  bool clip(std::uint32_t label, const double* p);
  // Whether the last clip() removed any vertex.
  bool changed() const { return changed_; }
  // An upper bound on the squared distance from the seed to every vertex: a bisector
  // farther than twice this cuts nothing (the security radius).
  double radius2_upper() const { return rmax_ * rmax_ * (1 + 1e-12); }
  // Unused (CellPolytope's threshold); kept so both polytopes drive the same loop.
  void set_scale(double) {}
  // An upper bound on w_p - w_s over every point p (0 unweighted): a point can cut a
  // vertex at distance r from the seed only if it lies within r + sqrt(r^2 + this).
  double weight_reach() const { return weight_reach_; }

  // The finished cell: facets (neighbours ascending, then walls), measures, and unless
  // `measures_only`, the vertices and each facet's loop, counter-clockwise seen from
  // outside. Vertices on three bisectors within circumcentre()'s bound of the exact
  // circumcentre (recomputed by it where the solve's bound is looser).
  void assemble(VoronoiCell& out, bool measures_only);

  std::size_t size() const { return v_.size(); }

 private:
  // A plane a . y <= c in coordinates relative to the seed (y = x - s). Bisectors: a =
  // q = p - s rounded, c = (|q|^2 - (w_p - w_s)) / 2 rounded. Box walls: a = +-e_axis, c the wall's
  // distance from the seed, rounded (their coordinate is restored exactly on output).
  struct Plane {
    std::array<double, 3> a{};
    double c = 0;
    double a_norm = 0;
    double dw = 0;            // w_p - w_s rounded (0 unweighted, and for walls)
    std::uint32_t label = 0;  // point index, or kWallLabel0 + wall
    int axis = -1;            // walls: the axis; bisectors: -1
  };
  struct alignas(64) Vertex {
    std::array<double, 3> y{};             // relative to the seed
    double error = 0;                      // bound on |y - exact vertex - s| (Euclidean)
    double radius = 0;                     // bound on |exact vertex - s|
    std::array<std::uint32_t, 3> plane{};  // indices into planes_
    std::array<std::uint32_t, 3> next{};   // next[k]: the neighbour reached by leaving plane[k]
  };
  static_assert(sizeof(Vertex) == 64);

  bool solve(Vertex& v) const;
  // The side of `bisector` vertex v lies on, decided exactly with the star's symbolic
  // perturbation (> 0 beyond: cut); 0 only if v's three planes were dependent, which a
  // solved vertex's are not (the caller then leaves the cell to the generic route).
  int exact_side(const Vertex& v, const Plane& bisector) const;
  // The vertex after cur around face (a plane index), coming from prev; from a vertex
  // where the walk starts (prev == cur), either way round.
  std::uint32_t step_around(std::uint32_t face, std::uint32_t prev, std::uint32_t cur) const;

  const PointSet& points_;
  const Domain& box_;
  // The exact coordinate c of point or image `id` minus the seed's, as a rational.
  mpq_class exact_difference(std::uint32_t id, int c) const;

  const PeriodicCover* cover_ = nullptr;  // a periodic cover's images, or null
  const double* weights_ = nullptr;
  double max_weight_ = 0;
  double weight_reach_ = 0;
  Predicates predicates_;
  std::uint32_t seed_ = 0;
  const double* s_ = nullptr;
  double rmax_ = 0;
  bool changed_ = false;
  std::vector<Plane> planes_;
  std::vector<Vertex> v_;
  std::vector<std::int8_t> side_;
  std::vector<std::uint32_t> dropped_end_;  // clip(): per new vertex, its dropped neighbour
  // assemble() scratch.
  std::vector<std::uint32_t> first_on_plane_, loop_;
};

}  // namespace spokemesh::detail
