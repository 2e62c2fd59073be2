// The Voronoi diagram of a whole point set, read off a triangulation of it: the
// Delaunay triangulation (the nearest-site diagram), as scipy.spatial.Voronoi
// describes a diagram: vertices, ridges between pairs of points, a region per point.
//
// Vertices are the simplices' circumcentres, one per group of simplices that share a
// circumsphere: two adjacent simplices whose vertices are cospherical (decided by the
// exact, unperturbed in-sphere sign) meet in one Voronoi vertex, as Qhull's merged
// facets do. So a grid's squares give one vertex each, not two, and a ridge between
// two points whose Delaunay edge lies inside such a group (of measure zero) is left
// out. Everything is a function of the points and the triangulation's simplices as a
// set: vertex k is the group whose smallest simplex (as a sorted tuple of point
// indices) is the k-th smallest, its coordinates that simplex's circumcentre. A ridge
// is listed when it has at least d vertices counting the one at infinity, as Qhull
// lists them (Delaunay neighbours whose ridge is a 3-d wedge from a single vertex are
// then not among the ridges; the triangulation has them).
//
// Thread safety: free functions; they only read their arguments.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct VoronoiDiagram {
  std::vector<double> vertices;                 // k x d circumcentres
  std::vector<std::int64_t> vertex_of_simplex;  // m: the Voronoi vertex of each simplex
  // Ridges in ascending (p, q), p < q: the Voronoi face between points p and q, its
  // vertices ridge_vertices[ridge_ptr[r] .. ridge_ptr[r + 1]), -1 first when it reaches
  // infinity. In 3-d the vertices go around the face (from the -1's end when
  // unbounded); in 2-d they are the edge's two ends; above 3-d ascending.
  std::vector<std::uint32_t> ridge_points;
  std::vector<std::int64_t> ridge_ptr;
  std::vector<std::int32_t> ridge_vertices;
  // Point i's region: regions[region_ptr[i] .. region_ptr[i + 1]), -1 first when
  // unbounded; empty for a point in no simplex. In 2-d counter-clockwise (a bounded
  // region from its smallest vertex, an unbounded one from infinity along its path);
  // otherwise ascending.
  std::vector<std::int64_t> region_ptr;
  std::vector<std::int32_t> regions;
};

// `simplices`: m rows of d + 1 point indices, each positively oriented (det[p_1 - p_0,
// ..., p_d - p_0] > 0), the Delaunay triangulation of the points they use;
// `adjacency`: simplex_adjacency() of them. `threads`
// >= 1 share the work; the result does not depend on it.
VoronoiDiagram voronoi_diagram(const PointSet& points, std::span<const std::uint32_t> simplices,
                               std::span<const std::int32_t> adjacency, unsigned threads);

// Row s, column k: the simplex across the facet opposite vertex k of simplex s, -1
// when no other simplex has that facet. `threads` >= 1 share the work.
std::vector<std::int32_t> simplex_adjacency(std::span<const std::uint32_t> simplices, int d, unsigned threads = 1);

// The furthest-site Delaunay triangulation (scipy's furthest_site=True): the
// simplices whose circumspheres hold every point, the upper hull of the points lifted
// to the paraboloid. Gift-wrapped from a hull facet of the Delaunay triangulation
// `delaunay` (with its `adjacency`) over the hull's vertices: beyond each facet, the
// candidate whose sphere through the facet is outermost (furthest_site.cpp), with the
// perturbed in-sphere test deciding cospherical points. O(h) per simplex for h hull
// vertices. Rows sorted, each positively oriented (ascending but for the last two
// where that is negative). When every hull facet's hyperplane holds more than d
// points (a box grid's faces) the wrap starts, above 2-d, from a simplex of the hull's
// corners whose sphere holds the others (searched among C(corners - 1, d) of them);
// INVALID_ARGUMENT when that search would exceed 2e6 sphere tests.
Result<std::vector<std::uint32_t>> furthest_site_simplices(const PointSet& points,
                                                           std::span<const std::uint32_t> delaunay,
                                                           std::span<const std::int32_t> adjacency);

}  // namespace spokemesh
