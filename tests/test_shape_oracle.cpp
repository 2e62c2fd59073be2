// Cells in domains of any shape against CGAL: for each seed, the convex clipped cell
// intersected with the domain by CGAL (3-d: Polygon_mesh_processing's
// corefine_and_compute_intersection on Surface_mesh with exact constructions; 2-d:
// Boolean_set_operations_2 on a Polygon_with_holes_2), then its volume (area) and,
// facet for facet, the area of each neighbour facet (result faces on the bisector of
// the seed and that neighbour) and each wall facet (result faces on that domain face),
// each to 1e-9 relative (of the cell's or the facet's scale). CGAL is a test oracle only.
#include <CGAL/Boolean_set_operations_2.h>
#include <CGAL/Exact_predicates_exact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/corefinement.h>
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Polygon_with_holes_2.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/convex_hull_2.h>
#include <CGAL/convex_hull_3.h>
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "shape_fixtures.hpp"
#include "spokemesh/cells.hpp"

namespace spokemesh {
namespace {

using namespace testing;
using K = CGAL::Exact_predicates_exact_constructions_kernel;
using SurfaceMesh = CGAL::Surface_mesh<K::Point_3>;
namespace PMP = CGAL::Polygon_mesh_processing;

struct Measures {
  double volume = 0;
  std::map<std::int64_t, double> facets;  // neighbour (>= 0) or -1 - face
};

Measures ours(const VoronoiCell& c) {
  Measures m;
  m.volume = c.volume;
  for (const VoronoiFacet& f : c.facets) m.facets[f.neighbor] += f.area;
  return m;
}

// What a result face (3 points, double) lies on: a domain face or a neighbour's bisector.
std::int64_t classify_3d(const PointSet& ps, std::uint32_t seed, const VoronoiCell& convex, const ShapeDomain& shape,
                         const double x[3][3], double scale) {
  // A domain face: coplanar with it and holding the result face's centroid.
  double g[3];
  for (int c = 0; c < 3; ++c) g[c] = (x[0][c] + x[1][c] + x[2][c]) / 3;
  std::int64_t best = INT64_MIN;
  double best_distance = INFINITY;
  for (std::size_t t = 0; t < shape.face_count(); ++t) {
    const double* n = shape.face_normal(t);
    const double* a = &shape.vertices()[3 * shape.faces()[3 * t]];
    double worst = 0;
    for (int k = 0; k < 3; ++k) {
      double h = 0;
      for (int c = 0; c < 3; ++c) h += n[c] * (x[k][c] - a[c]);
      worst = std::max(worst, std::abs(h));
    }
    if (worst > 1e-9 * scale) continue;
    // Distance from g to the triangle (in its plane): how far outside its edges.
    double outside = 0;
    for (int e = 0; e < 3; ++e) {
      const double* u = &shape.vertices()[3 * shape.faces()[3 * t + e]];
      const double* v = &shape.vertices()[3 * shape.faces()[3 * t + (e + 1) % 3]];
      const double edge[3] = {v[0] - u[0], v[1] - u[1], v[2] - u[2]};
      const double out[3] = {edge[1] * n[2] - edge[2] * n[1], edge[2] * n[0] - edge[0] * n[2],
                             edge[0] * n[1] - edge[1] * n[0]};
      const double len = std::sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2]);
      const double h = ((g[0] - u[0]) * out[0] + (g[1] - u[1]) * out[1] + (g[2] - u[2]) * out[2]) / len;
      outside = std::max(outside, h);
    }
    if (outside < best_distance) {
      best_distance = outside;
      best = -1 - static_cast<std::int64_t>(t);
    }
  }
  // On a domain face (a piece of a bisector lying on a wall is the wall's: the domain
  // is on one side of it only), else on a neighbour's bisector.
  if (best_distance <= 1e-9 * scale) return best;
  const double* p = ps.point(seed);
  for (const VoronoiFacet& f : convex.facets) {
    if (f.neighbor < 0) continue;
    const double* q = ps.point(static_cast<std::size_t>(f.neighbor));
    bool on = true;
    for (int k = 0; k < 3 && on; ++k) {
      double dp = 0, dq = 0;
      for (int c = 0; c < 3; ++c) {
        dp += (x[k][c] - p[c]) * (x[k][c] - p[c]);
        dq += (x[k][c] - q[c]) * (x[k][c] - q[c]);
      }
      on = std::abs(dp - dq) <= 1e-9 * scale * scale;
    }
    if (on) return f.neighbor;
  }
  return best;
}

Measures cgal_3d(const PointSet& ps, std::uint32_t seed, const VoronoiCell& convex, const ShapeDomain& shape) {
  // The convex cell as the hull of its vertices (at ties several coincide).
  SurfaceMesh cell, domain, out;
  std::vector<K::Point_3> corners;
  for (std::size_t v = 0; v < convex.vertex_count(); ++v) {
    corners.emplace_back(convex.vertices[3 * v], convex.vertices[3 * v + 1], convex.vertices[3 * v + 2]);
  }
  CGAL::convex_hull_3(corners.begin(), corners.end(), cell);
  std::vector<SurfaceMesh::Vertex_index> dv;
  for (std::size_t v = 0; v < shape.vertex_count(); ++v) {
    dv.push_back(domain.add_vertex(
        K::Point_3(shape.vertices()[3 * v], shape.vertices()[3 * v + 1], shape.vertices()[3 * v + 2])));
  }
  for (std::size_t t = 0; t < shape.face_count(); ++t) {
    domain.add_face(dv[shape.faces()[3 * t]], dv[shape.faces()[3 * t + 1]], dv[shape.faces()[3 * t + 2]]);
  }
  EXPECT_TRUE(PMP::corefine_and_compute_intersection(cell, domain, out)) << "seed " << seed;
  Measures m;
  m.volume = CGAL::to_double(PMP::volume(out));
  const double scale = std::cbrt(std::max(convex.volume, 1e-300));
  for (auto f : out.faces()) {
    double x[3][3];
    int k = 0;
    for (auto v : out.vertices_around_face(out.halfedge(f))) {
      for (int c = 0; c < 3; ++c) x[k][c] = CGAL::to_double(out.point(v)[c]);
      ++k;
    }
    const std::int64_t on = classify_3d(ps, seed, convex, shape, x, scale);
    m.facets[on] += CGAL::to_double(PMP::face_area(f, out));
  }
  return m;
}

using Polygon = CGAL::Polygon_2<K>;
using PolygonWithHoles = CGAL::Polygon_with_holes_2<K>;

Measures cgal_2d(const PointSet& ps, std::uint32_t seed, const VoronoiCell& convex, const ShapeDomain& shape,
                 const PolygonWithHoles& domain) {
  std::vector<K::Point_2> corners;
  for (std::size_t v = 0; v < convex.vertex_count(); ++v)
    corners.emplace_back(convex.vertices[2 * v], convex.vertices[2 * v + 1]);
  Polygon cell;
  CGAL::convex_hull_2(corners.begin(), corners.end(), std::back_inserter(cell));
  std::vector<PolygonWithHoles> pieces;
  CGAL::intersection(cell, domain, std::back_inserter(pieces));
  Measures m;
  const double* p = ps.point(seed);
  const double scale = std::sqrt(std::max(convex.volume, 1e-300));
  auto edge = [&](const K::Segment_2& s) {
    const double a[2] = {CGAL::to_double(s.source().x()), CGAL::to_double(s.source().y())};
    const double b[2] = {CGAL::to_double(s.target().x()), CGAL::to_double(s.target().y())};
    const double len = std::hypot(b[0] - a[0], b[1] - a[1]);
    if (len == 0) return;
    std::int64_t on = INT64_MIN;
    const double g[2] = {(a[0] + b[0]) / 2, (a[1] + b[1]) / 2};
    double best = INFINITY;
    std::int64_t nearest = INT64_MIN;
    for (std::size_t t = 0; t < shape.face_count(); ++t) {
      const double* u = &shape.vertices()[2 * shape.faces()[2 * t]];
      const double* v = &shape.vertices()[2 * shape.faces()[2 * t + 1]];
      const double dx = v[0] - u[0], dy = v[1] - u[1], l2 = dx * dx + dy * dy;
      const double s = std::clamp(((g[0] - u[0]) * dx + (g[1] - u[1]) * dy) / l2, 0.0, 1.0);
      const double dist = std::hypot(g[0] - u[0] - s * dx, g[1] - u[1] - s * dy);
      if (dist < best) {
        best = dist;
        nearest = -1 - static_cast<std::int64_t>(t);
      }
    }
    if (best <= 1e-9 * scale) on = nearest;  // on a wall (the domain is on one side only)
    for (const VoronoiFacet& f : convex.facets) {
      if (on != INT64_MIN || f.neighbor < 0) continue;
      const double* q = ps.point(static_cast<std::size_t>(f.neighbor));
      bool both = true;
      for (const double* x : {a, b}) {
        const double dp = (x[0] - p[0]) * (x[0] - p[0]) + (x[1] - p[1]) * (x[1] - p[1]);
        const double dq = (x[0] - q[0]) * (x[0] - q[0]) + (x[1] - q[1]) * (x[1] - q[1]);
        both = both && std::abs(dp - dq) <= 1e-9 * scale * scale;
      }
      if (both) on = f.neighbor;
    }
    if (on == INT64_MIN) on = nearest;
    m.facets[on] += len;
  };
  for (const PolygonWithHoles& piece : pieces) {
    m.volume += CGAL::to_double(piece.outer_boundary().area());
    for (auto e = piece.outer_boundary().edges_begin(); e != piece.outer_boundary().edges_end(); ++e) edge(*e);
    for (auto h = piece.holes_begin(); h != piece.holes_end(); ++h) {
      m.volume += CGAL::to_double(h->area());  // holes are clockwise: negative area
      for (auto e = h->edges_begin(); e != h->edges_end(); ++e) edge(*e);
    }
  }
  return m;
}

void compare(const Measures& got, const Measures& want, double volume_scale, double area_scale, std::uint32_t seed) {
  EXPECT_NEAR(got.volume, want.volume, 1e-9 * volume_scale) << "seed " << seed;
  std::map<std::int64_t, std::pair<double, double>> all;
  for (const auto& [k, a] : got.facets) all[k].first = a;
  for (const auto& [k, a] : want.facets) all[k].second = a;
  for (const auto& [k, a] : all) {
    EXPECT_NEAR(a.first, a.second, 1e-9 * area_scale)
        << "seed " << seed << (k >= 0 ? " neighbour " : " wall face ") << (k >= 0 ? k : -1 - k);
  }
}

// Every seed's cell against CGAL's.
void against_cgal(const PointSet& ps, const ShapeDomain& shape, const PolygonWithHoles* polygon = nullptr) {
  const KdTree tree(ps);
  auto box = ShapeClipper::box(ps, shape);
  ASSERT_TRUE(box.is_ok());
  ClippedCellBuilder builder(tree, box.value());
  ShapeClipper clipper(ps, shape);
  const int d = ps.dimension();
  for (std::uint32_t s = 0; s < ps.size(); ++s) {
    VoronoiCell convex;
    ASSERT_TRUE(builder.cell(s, convex).is_ok());
    VoronoiCell cell = convex;
    clipper.clip(s, cell);
    const Measures want = d == 3 ? cgal_3d(ps, s, convex, shape) : cgal_2d(ps, s, convex, shape, *polygon);
    const double vs = convex.volume, as = std::pow(convex.volume, (d - 1.0) / d);
    compare(ours(cell), want, vs, as, s);
  }
}

TEST(ShapeOracle, CubeWithCavityAgainstCorefinement) {
  const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1}, centre[3] = {0.45, 0.5, 0.55};
  const ShapeDomain shape = Mesh::cube_with_cavity(lo, hi, 2, centre, 0.3, 8, 12).solid("cube-cavity");
  against_cgal(seeds_inside(shape, 40, 11, 4), shape);
}

TEST(ShapeOracle, TorusAgainstCorefinement) {
  Mesh m;
  m.torus(1.0, 0.4, 16, 8);
  const ShapeDomain shape = m.solid("torus");
  against_cgal(seeds_inside(shape, 40, 12, 4), shape);
}

TEST(ShapeOracle, LPartGridAgainstCorefinement) {
  Mesh m;
  m.l_part(1.0);
  const ShapeDomain shape = m.solid("l-part");
  std::vector<double> g;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 2; ++k) g.insert(g.end(), {0.25 + 0.5 * i, 0.25 + 0.5 * j, 0.25 + 0.5 * k});
  PointSet grid(3, g);
  ASSERT_TRUE(grid.validate("grid").is_ok());
  against_cgal(grid, shape);
}

TEST(ShapeOracle, PolygonWithThreeHolesAgainstBooleanSetOperations) {
  const ShapeDomain shape = three_holes();
  // The same polygon for CGAL: the outer ring counter-clockwise, holes clockwise.
  // Rebuild from the faces: walk each ring's edges (oriented outward from the domain).
  std::vector<Polygon> rings;
  std::vector<bool> used(shape.face_count(), false);
  for (std::size_t f0 = 0; f0 < shape.face_count(); ++f0) {
    if (used[f0]) continue;
    Polygon poly;
    std::size_t f = f0;
    while (!used[f]) {
      used[f] = true;
      const double* a = &shape.vertices()[2 * shape.faces()[2 * f]];
      poly.push_back(K::Point_2(a[0], a[1]));
      const std::uint32_t next = shape.faces()[2 * f + 1];
      for (std::size_t g = 0; g < shape.face_count(); ++g) {
        if (shape.faces()[2 * g] == next) {
          f = g;
          break;
        }
      }
    }
    rings.push_back(poly);
  }
  std::size_t outer = 0;
  for (std::size_t r = 0; r < rings.size(); ++r) {
    if (rings[r].orientation() == CGAL::COUNTERCLOCKWISE) outer = r;
  }
  PolygonWithHoles domain(rings[outer]);
  for (std::size_t r = 0; r < rings.size(); ++r) {
    if (r != outer) domain.add_hole(rings[r]);
  }
  against_cgal(seeds_inside(shape, 120, 13, 10), shape, &domain);
  std::vector<double> g;
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j) g.insert(g.end(), {0.5 + i, 0.5 + j});
  PointSet grid(2, g);
  ASSERT_TRUE(grid.validate("grid").is_ok());
  against_cgal(grid, shape, &domain);
}

}  // namespace
}  // namespace spokemesh
