// CellPolytope: a Voronoi cell as a simple polytope, clipped by domain walls, and its
// measures (docs/cells.md). Internal to the core: voronoi.cpp is its one user.
//
// Combinatorics. Every vertex lies on exactly d planes, its labels: a Delaunay
// neighbour j (the bisector of seed and j), a domain wall, or "infinity". The
// unclipped cell's vertices are the star's simplices (labels: the simplex without
// the seed); under symbolic perturbation the star is a triangulation, so the cell is
// simple. An unbounded cell gets one ideal vertex per hull facet of the star: the
// direction of its unbounded edge, labelled with the facet's neighbours and
// "infinity" (the cell truncated by a plane at infinity, which is simple too: its
// section is dual to the link of the seed on the hull). Edges are stored, not
// searched: next[v][k] is the vertex reached from v by leaving plane label[v][k].
//
// Clipping by a wall a.x <= b (Voro++'s plane cut, in any d): keep the vertices in
// the closed halfspace, put a new vertex on every edge from a kept to a dropped one
// (the dropped label replaced by the wall's), and join two new vertices when they
// are the two ends of the kept part of one 2-face, found by walking that 2-face's
// boundary. Which vertices are kept is decided exactly: a filter on the double
// coordinates with a tracked error bound, else the vertex solved in rationals from
// its d planes (plane_side's exactness, for constructed points). A vertex on the wall
// is kept, so clipping by a closed halfspace leaves faces of measure zero where a
// wall passes through a vertex; they are reported like any other (area 0). An ideal
// vertex is kept when its direction points into the halfspace, or along the wall
// with its ray's base kept: the limit of truncating the cell far away.
//
// The direct route (ClippedCellBuilder, cells.hpp) starts instead from a box domain
// itself and clips it by bisectors the same way; its new vertices are then solved from
// their d planes (in closed form in 3-d) with a forward error bound, rather than
// interpolated along edges whose bounds would compound over many cuts, and a vertex
// exactly on a cutting plane is reported (clip() returns false) so that the caller can
// take the star route, whose symbolic perturbation handles it.
//
// Measures: a face's k-measure is the sum over its facets of height x measure / k
// (cones from the mean of its vertices), recursively down to edges; centroids
// likewise (a cone's centroid lies k/(k+1) of the way from apex to base centroid).
//
// Thread safety: a value type; one per cell and thread.
#pragma once

#include <gmpxx.h>

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <vector>

#include "spokemesh/domain.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::detail {

// Labels: Delaunay neighbours are point indices; walls and infinity sit above them.
inline constexpr std::uint32_t kWallLabel0 = 0xF0000000u;
inline constexpr std::uint32_t kInfinityLabel = 0xFFFFFFFFu;
inline bool is_wall_label(std::uint32_t l) { return l >= kWallLabel0 && l != kInfinityLabel; }

struct FacetMeasure {
  std::uint32_t label = 0;
  double area = 0;  // +inf when the facet is unbounded
  // Its real vertices: in 3-d a loop counter-clockwise seen from outside (a path when
  // unbounded), otherwise ascending.
  std::vector<std::uint32_t> vertices;
};

struct PolytopeMeasures {
  double volume = 0;                 // +inf when unbounded
  std::vector<double> centroid;      // empty when unbounded
  std::vector<FacetMeasure> facets;  // ascending label
};

class CellPolytope {
 public:
  // The unclipped cell of star.seed; vertex i < star.size() is star simplex i, and an
  // unbounded cell's ideal vertices (exact rational directions) follow. `domain`
  // (nullptr: none) is what clip_all() cuts by; it must outlive the polytope.
  // `weights` (one per point, or null; not owned): the star is a regular
  // triangulation's, the cell a power cell (orthocentres, power bisectors).
  CellPolytope(const PointSet& points, const Star& star, const Domain* domain, const double* weights = nullptr);

  // The box domain itself (2^d vertices, labels its walls), to be clipped by the
  // bisectors of seed's neighbours (voronoi.hpp, ClippedCellBuilder). Preconditions:
  // box.is_box() with lower < upper on every axis; box outlives the polytope.
  CellPolytope(const PointSet& points, std::uint32_t seed, const Domain& box);
  // Starts over from the box, for another seed (keeps the memory).
  void reset_to_box(std::uint32_t seed);

  // Clips by every wall of the domain given to the constructor, in order.
  void clip_all();
  // Clips by the plane `label` (a wall, or the bisector of the seed and point
  // `label`). Returns false when a real vertex lies exactly on that plane (it is kept:
  // the domain is closed); a caller that needs general position starts over elsewhere.
  // `coordinates`, if given, are point label's (equal to the PointSet's, e.g. the k-d
  // tree's copy, which neighbours share cache lines in); they must outlive the polytope.
  bool clip(std::uint32_t label, const double* coordinates = nullptr);
  // An upper bound on the squared distance from the seed to every real vertex (the
  // security radius: a bisector farther than this from the seed cuts nothing).
  double radius2_upper() const;
  // Whether the last clip() removed any vertex.
  bool changed() const { return changed_; }
  // Recomputes vertices on d bisectors as their simplex's circumcentre (circumcentre()'s
  // accuracy, and the same bits as a cell built from the star).
  void refine_voronoi_vertices();
  // Threshold scale for constructing cut vertices exactly (the cell's size).
  void set_scale(double scale) { scale_ = scale; }

  std::size_t size() const { return ideal_.size(); }
  bool is_ideal(std::size_t v) const { return ideal_[v] >= 0; }
  bool bounded() const;
  const double* coordinates(std::size_t v) const { return &x_[v * d_]; }
  const std::uint32_t* labels(std::size_t v) const { return &label_[v * d_]; }
  const std::uint32_t* next(std::size_t v) const { return &next_[v * d_]; }

  PolytopeMeasures measures() const;
  // measures() in 3-d: each facet's loop walked once, then fans and cones from it.
  PolytopeMeasures measures_3d() const;
  // The closed walk around the 2-face on plane `label` from vertex `start` (3-d).
  std::vector<std::uint32_t> facet_cycle(std::uint32_t label, std::uint32_t start) const;
  // Unit outward normal of the facet with this label.
  std::vector<double> facet_normal(std::uint32_t label) const;
  // The vertices on plane `label` (a facet), ordered around it: a cycle in 3-d (as a
  // path of real vertices when it has ideal ones), counter-clockwise seen from
  // outside. Other dimensions: ascending.
  std::vector<std::uint32_t> facet_vertices(std::uint32_t label) const;
  // 2-d: the vertices in counter-clockwise order (a cycle, or the path of real ones).
  std::vector<std::uint32_t> polygon_order() const;

 private:
  void normal_of(std::uint32_t label, double* out) const;
  // The plane of a label, exactly: n . x <= c.
  void exact_plane(std::uint32_t label, std::vector<mpq_class>& n, mpq_class& c) const;
  std::optional<std::vector<mpq_class>> exact_vertex(std::size_t v) const;
  std::vector<mpq_class> exact_ray(const std::uint32_t* labels, std::uint32_t away_from) const;
  // A clipping plane in double: a . (x - origin) <= b, origin the seed for a bisector
  // (then a = p - s, b = |a|^2 / 2, both rounded) or none (a wall: the domain's a, b).
  struct Plane {
    std::uint32_t label = 0;
    std::array<double, kMaxDimension> a{};
    double b = 0;
    double b_magnitude = 0;  // a bound on b's terms: |b|, or for a bisector (|q|^2 + |w_p - w_s|) / 2
    double a_norm = 0;
    const double* origin = nullptr;
  };
  Plane plane_of(std::uint32_t label) const;
  // The plane's value at x and a bound on its rounding error (against the exact plane).
  double plane_value(const Plane& pl, const double* x, double& rounding) const;
  int side(std::size_t v, const Plane& pl, const std::vector<int>& sides) const;
  std::size_t cut(std::size_t in, int position, std::size_t out, const Plane& pl);
  // Recomputes real vertex v from its d planes (LU in double with a forward error
  // bound), keeping whichever of that and its current bound is tighter.
  void solve_vertex(std::size_t v);
  // 3-d, a vertex on three bisectors: its circumcentre in closed form with a forward
  // error bound. False (nothing changed) for wall vertices and near-flat tetrahedra.
  bool solve_bisectors_3d(std::size_t v);
  // An upper bound on the distance from the seed to real vertex v.
  double vertex_radius(std::size_t v) const;
  // Point `label`'s coordinates: as given to clip(), else the PointSet's.
  const double* point_of(std::uint32_t label) const;
  std::size_t walk_to_partner(std::size_t u, int wall_position, int m, std::size_t first_new) const;
  std::size_t add_vertex();
  int position_of(std::size_t v, std::uint32_t label) const;
  double face_measure(const std::vector<std::uint32_t>& verts, std::vector<std::uint32_t>& planes,
                      std::vector<double>& basis, double* centroid, std::vector<FacetMeasure>* top) const;

  const PointSet& ps_;
  const Domain* domain_;
  const double* weights_ = nullptr;  // power weights, or null
  std::uint32_t seed_;
  int d_;
  double scale_ = 0;  // the cell's size, for error thresholds
  bool from_box_ = false;
  bool changed_ = false;        // the last clip() cut something
  std::vector<double> radius_;  // from_box_: vertex_radius() of each vertex
  std::vector<std::pair<std::uint32_t, const double*>>
      known_points_;                  // clip()'s coordinates            // built by reset_to_box (the direct route)
  std::vector<double> x_;             // d per vertex: coordinates, or an ideal vertex's direction
  std::vector<std::uint32_t> label_;  // d per vertex
  std::vector<std::uint32_t> next_;   // d per vertex
  std::vector<double> error_;         // bound on |x - exact| (real vertices)
  std::vector<int> ideal_;            // -1, or the index of the exact direction in rays_
  std::vector<std::vector<mpq_class>> rays_;
  std::vector<int> sides_;            // clip() scratch
  std::vector<std::uint32_t> index_;  // clip() scratch
  // measures(): faces of dimension 1 .. d - 3 already measured, by sorted planes.
  mutable std::map<std::vector<std::uint32_t>, std::pair<double, std::array<double, kMaxDimension>>> memo_;
};

// Facets in VoronoiCell's order: neighbours ascending, then walls ascending (voronoi.cpp).
void sort_facets(std::vector<VoronoiFacet>& facets);

// 3-d: the area of the planar polygon `loop` along its unit normal `n`, by a fan from
// its first vertex (negative when the loop turns clockwise seen from the normal's
// side), and in `weighted_centre` the sum of each fan triangle's signed area times its
// centroid (over the area: the polygon's centroid). point(v): v's 3 coordinates.
template <class Point>
double fan_area(const std::vector<std::uint32_t>& loop, Point point, const double* n, double* weighted_centre) {
  const double* p0 = point(loop[0]);
  double area = 0;
  weighted_centre[0] = weighted_centre[1] = weighted_centre[2] = 0;
  for (std::size_t k = 1; k + 1 < loop.size(); ++k) {
    const double* a = point(loop[k]);
    const double* b = point(loop[k + 1]);
    const double u[3] = {a[0] - p0[0], a[1] - p0[1], a[2] - p0[2]};
    const double w[3] = {b[0] - p0[0], b[1] - p0[1], b[2] - p0[2]};
    const double cross[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
    const double t = 0.5 * (cross[0] * n[0] + cross[1] * n[1] + cross[2] * n[2]);
    area += t;
    for (int c = 0; c < 3; ++c) weighted_centre[c] += t * (p0[c] + a[c] + b[c]) / 3;
  }
  return area;
}

// The VoronoiCell of a clipped polytope (voronoi.cpp): 2-d vertices counter-clockwise,
// otherwise in polytope order; facets with their measures.
VoronoiCell assemble_clipped(const CellPolytope& polytope, std::uint32_t seed, int d);

}  // namespace spokemesh::detail
