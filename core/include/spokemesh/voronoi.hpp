// VoronoiCell: the Voronoi cell of a seed, assembled from its Delaunay star, and
// optionally clipped to a Domain (docs/cells.md).
//
// With power weights the cell is the power (Laguerre) cell: vertices are
// the orthocentres of the regular triangulation's star, facets lie on the power
// bisectors; a hidden seed's cell is empty (hidden, volume 0, no facets).
//
// Vertices are the circumcentres of the star's simplices (floating point: these
// are outputs, the topology behind them is exact), each within 1e-12 of its
// circumradius plus one ulp of the exact one (see circumcentre()); a clipped cell
// adds the points where its edges cross the walls. Facets are one per Delaunay
// neighbour (and per wall that cuts the cell), decided exactly. A cell without a
// domain is bounded iff no facet of the star lies on the convex hull; its volume is
// then finite, otherwise +infinity (docs/service.md, "Unbounded cells").
//
// Measures are double-precision values of the exact polytope: volume, centroid, and
// per facet its (d-1)-measure and unit outward normal (cones from each face's vertex
// mean, recursively: cell_polytope.hpp).
//
// Thread safety: value type; building one only reads the PointSet.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/circumcentre.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct VoronoiFacet {
  // The Delaunay neighbour across this facet (>= 0), or -1 - k for domain wall k.
  std::int64_t neighbor = 0;
  // Indices into VoronoiCell::vertices: in 3-d a loop counter-clockwise seen from
  // outside (a path when the facet is unbounded); otherwise ascending.
  std::vector<std::uint32_t> vertices;
  double area = 0;             // (d-1)-measure; +infinity when the facet is unbounded
  std::vector<double> normal;  // unit outward normal (d)

  bool is_wall() const { return neighbor < 0; }
  std::size_t wall() const { return static_cast<std::size_t>(-1 - neighbor); }
};

struct VoronoiCell {
  std::uint32_t seed = 0;
  int dimension = 0;
  std::vector<double> vertices;  // d coordinates per vertex
  // The Delaunay simplex of each vertex (d + 1 ids); unclipped cells only.
  std::vector<std::uint32_t> vertex_simplices;
  std::vector<VoronoiFacet> facets;  // neighbours ascending, then walls ascending
  bool bounded = false;
  bool clipped = false;          // clipped to a domain
  double volume = 0;             // +infinity when unbounded (docs/service.md)
  std::vector<double> centroid;  // d; empty when unbounded or hidden
  bool hidden = false;           // with weights: the power cell is empty (volume 0)
  // On a torus (periodic.hpp): per facet, the offset (d integers, in box lengths) of the
  // neighbour's image across it; facets[k].neighbor is then the neighbour's point. Empty
  // otherwise.
  std::vector<std::int32_t> facet_offsets;

  std::size_t vertex_count() const { return dimension == 0 ? 0 : vertices.size() / dimension; }
};

// The unclipped cell. In 2-d its vertices are counter-clockwise around the seed (a
// path from the hull edge when unbounded); otherwise in the star's order.
// `weights`: the star's power weights (one per point; empty: unweighted).
VoronoiCell voronoi_cell(const PointSet& points, const Star& star, std::span<const double> weights = {});
// The cell clipped to `domain` (its walls cut in order). In 2-d the vertices are a
// counter-clockwise cycle. Errors: INVALID_ARGUMENT when the domain's dimension is not
// the points', or when the seed lies outside the domain (naming seed and wall).
Result<VoronoiCell> voronoi_cell(const PointSet& points, const Star& star, const Domain& domain,
                                 std::span<const double> weights = {});

// INVALID_ARGUMENT naming the seed and the wall when point `seed` lies outside the
// domain (whose dimension must be the points'); OK otherwise.
Status check_seed_in_domain(const PointSet& points, std::uint32_t seed, const Domain& domain);
// The same for a point given by its coordinates and the index to name it by.
Status check_seed_in_domain(const double* point, std::uint64_t seed, const Domain& domain);

// Drops a cell's vertex coordinates, vertex simplices and facet vertex lists, keeping
// its measures and neighbours (what `measures_only` streams and `.npz` files carry).
void keep_measures_only(VoronoiCell& cell);

}  // namespace spokemesh
