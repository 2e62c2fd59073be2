// VoronoiCell: the Voronoi cell of a seed, assembled from its Delaunay star.
//
// Vertices are the circumcentres of the star's simplices (floating point: these
// are outputs, the topology behind them is exact), each within 1e-12 of its
// circumradius plus one ulp of the exact one (see circumcentre()). Facets are one per Delaunay
// neighbour, listing the vertices on them. A cell is bounded iff no facet of the
// star lies on the convex hull. The volume of a bounded cell is summed over flags
// x = F_0 < F_1 < ... < F_d of Delaunay faces through x: the simplex
// [c(F_0), ..., c(F_d)] of their circumcentres has mutually orthogonal edges, and its
// volume counts negatively where c(F_k) lies beyond the Voronoi face of F_{k+1}
// (the pyramid decomposition of a convex polytope from the foot of each perpendicular).
//
// Thread safety: value type; building one only reads the PointSet.
#pragma once

#include <cstdint>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh {

struct VoronoiFacet {
  std::uint32_t neighbor = 0;           // the Delaunay neighbour across this facet
  std::vector<std::uint32_t> vertices;  // indices into VoronoiCell::vertices
};

struct VoronoiCell {
  std::uint32_t seed = 0;
  int dimension = 0;
  std::vector<double> vertices;            // d coordinates per vertex
  std::vector<std::uint32_t> vertex_simplices;  // the Delaunay simplex of each vertex (d + 1 ids)
  std::vector<VoronoiFacet> facets;        // sorted by neighbour
  bool bounded = false;
  double volume = 0;                       // +infinity when unbounded (docs/service.md)

  std::size_t vertex_count() const { return dimension == 0 ? 0 : vertices.size() / dimension; }
};

VoronoiCell voronoi_cell(const PointSet& points, const Star& star);

// Circumcentre of the points `ids` (2..d+1 of them): the centre of the smallest
// sphere through them, which lies in their affine hull. Solved on the coordinate
// differences by column-pivoting QR, and in exact rationals where the condition
// estimate says double could miss the bound: within 1e-12 of the circumradius plus
// one ulp of each coordinate. No heap allocation but the result (d <= 8).
std::vector<double> circumcentre(const PointSet& points, const std::uint32_t* ids, int count);

// Delaunay neighbours of the seed, ascending.
std::vector<std::uint32_t> star_neighbors(const Star& star);

}  // namespace spokemesh
