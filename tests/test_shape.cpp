// Voronoi cells in domains of any shape (shape_domain.hpp), checked on every cell as
// CGAL's tests validate after every step:
//   * the cells tile the domain: volumes (areas) sum to its volume to 1e-12 relative;
//   * wall facets sum to the domain's boundary measure, face by face;
//   * facet i -> j exists iff j -> i does (beyond rounding-level slivers), equal areas;
//   * the divergence theorem per cell: sum of area x normal = 0;
//   * cells meeting no wall equal the convex clipped cells;
// for a cube with a spherical cavity, a torus, an L-shaped part (random and grid seeds,
// with ties), a 2-d polygon with three holes (and a grid), and seeds outside. Bad
// domains are refused with their fault named.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>

#include "shape_fixtures.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/shape_io.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace testing;

std::vector<VoronoiCell> shape_cells(const PointSet& ps, const ShapeDomain& shape, unsigned threads = 2) {
  const KdTree tree(ps);
  auto box = ShapeClipper::box(ps, shape);
  EXPECT_TRUE(box.is_ok());
  CellsOptions options;
  options.threads = threads;
  options.shape = &shape;
  options.measures_only = true;
  std::vector<VoronoiCell> cells;
  const Status st = compute_cells(tree, &box.value(), options, [&](std::span<const VoronoiCell> got, std::uint64_t) {
    cells.insert(cells.end(), got.begin(), got.end());
    return Status::ok();
  });
  EXPECT_TRUE(st.is_ok()) << st.message();
  return cells;
}

void check_tiling(const PointSet& ps, const ShapeDomain& shape, const std::vector<VoronoiCell>& cells,
                  const std::string& what) {
  SCOPED_TRACE(what);
  const int d = shape.dimension();
  ASSERT_EQ(cells.size(), ps.size());
  double volume = 0;
  std::vector<double> wall(shape.face_count(), 0.0);
  std::map<std::pair<std::int64_t, std::int64_t>, double> shared;
  double scale = std::pow(shape.volume() / static_cast<double>(ps.size()), (d - 1.0) / d);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const VoronoiCell& c = cells[i];
    volume += c.volume;
    std::vector<double> closure(d, 0.0);
    double area = 0;
    for (const VoronoiFacet& f : c.facets) {
      ASSERT_EQ(f.normal.size(), static_cast<std::size_t>(d));
      for (int k = 0; k < d; ++k) closure[k] += f.area * f.normal[k];
      area += f.area;
      if (f.is_wall()) {
        ASSERT_LT(f.wall(), shape.face_count());
        wall[f.wall()] += f.area;
      } else {
        shared[{static_cast<std::int64_t>(i), f.neighbor}] = f.area;
      }
    }
    for (int k = 0; k < d; ++k) EXPECT_NEAR(closure[k], 0.0, 1e-9 * std::max(area, scale)) << "cell " << i;
    if (c.volume == 0) EXPECT_TRUE(c.facets.empty()) << "cell " << i;
  }
  EXPECT_NEAR(volume, shape.volume(), 1e-12 * shape.volume());
  double walls = 0;
  for (std::size_t f = 0; f < shape.face_count(); ++f) {
    EXPECT_NEAR(wall[f], shape.face_measure(f), 1e-9 * shape.face_measure(f)) << "face " << f;
    walls += wall[f];
  }
  EXPECT_NEAR(walls, shape.boundary_measure(), 1e-12 * shape.boundary_measure());
  for (const auto& [ij, a] : shared) {
    auto back = shared.find({ij.second, ij.first});
    if (back == shared.end()) {
      EXPECT_LT(a, 1e-9 * scale) << ij.first << " -> " << ij.second << " has no twin";
    } else {
      EXPECT_NEAR(a, back->second, 1e-9 * scale) << ij.first << " <-> " << ij.second;
    }
  }
}

TEST(ShapeCells, CubeWithSphericalCavity) {
  const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1}, centre[3] = {0.5, 0.5, 0.5};
  const ShapeDomain shape = Mesh::cube_with_cavity(lo, hi, 2, centre, 0.3, 12, 24).solid("cube-cavity");
  EXPECT_EQ(shape.component_count(), 2u);
  EXPECT_LT(shape.volume(), 1.0);
  EXPECT_GT(shape.volume(), 1.0 - 4.0 / 3.0 * M_PI * 0.027);
  EXPECT_EQ(shape.locate(centre), -1);
  const PointSet ps = seeds_inside(shape, 600, 1, 40);
  check_tiling(ps, shape, shape_cells(ps, shape), "cube with cavity");
}

TEST(ShapeCells, Torus) {
  Mesh m;
  m.torus(1.0, 0.35, 40, 16);
  const ShapeDomain shape = m.solid("torus");
  const PointSet ps = seeds_inside(shape, 800, 2);
  check_tiling(ps, shape, shape_cells(ps, shape), "torus");
}

TEST(ShapeCells, LShapedPartRandomAndGridSeeds) {
  Mesh m;
  m.l_part(1.0);
  const ShapeDomain shape = m.solid("l-part");
  EXPECT_DOUBLE_EQ(shape.volume(), 3.0);
  EXPECT_DOUBLE_EQ(shape.boundary_measure(), 14.0);
  const PointSet ps = seeds_inside(shape, 500, 3);
  check_tiling(ps, shape, shape_cells(ps, shape), "L random");
  // A grid of seeds over the whole box, some outside the L and some on its walls:
  // ties everywhere, bisectors lying on walls.
  std::vector<double> g;
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 8; ++j)
      for (int k = 0; k < 4; ++k) g.insert(g.end(), {0.125 + 0.25 * i, 0.125 + 0.25 * j, 0.125 + 0.25 * k});
  PointSet grid(3, g);
  ASSERT_TRUE(grid.validate("grid").is_ok());
  const auto cells = shape_cells(grid, shape);
  check_tiling(grid, shape, cells, "L grid");
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const double* p = grid.point(i);
    const bool out = p[0] > 1 && p[1] > 1;
    EXPECT_NEAR(cells[i].volume, out ? 0.0 : 0.25 * 0.25 * 0.25, 1e-15) << i;
  }
}

TEST(ShapeCells, PolygonWithThreeHoles) {
  const ShapeDomain shape = three_holes();
  EXPECT_EQ(shape.component_count(), 4u);
  const PointSet ps = seeds_inside(shape, 1500, 4, 60);
  check_tiling(ps, shape, shape_cells(ps, shape), "three holes");
  std::vector<double> g;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j) g.insert(g.end(), {0.25 + 0.5 * i, 0.25 + 0.5 * j});
  PointSet grid(2, g);
  ASSERT_TRUE(grid.validate("grid").is_ok());
  check_tiling(grid, shape, shape_cells(grid, shape), "three holes grid");
}

TEST(ShapeCells, SameCellsWhateverTheThreads) {
  const ShapeDomain shape = three_holes();
  const PointSet ps = seeds_inside(shape, 700, 5, 30);
  const auto one = shape_cells(ps, shape, 1), three = shape_cells(ps, shape, 3);
  ASSERT_EQ(one.size(), three.size());
  for (std::size_t i = 0; i < one.size(); ++i) {
    EXPECT_EQ(one[i].volume, three[i].volume);
    ASSERT_EQ(one[i].facets.size(), three[i].facets.size());
    for (std::size_t k = 0; k < one[i].facets.size(); ++k) EXPECT_EQ(one[i].facets[k].area, three[i].facets[k].area);
  }
}

// With geometry (for drawing): each wall facet's loop (ends in 2-d) measures its area,
// and in 2-d a neighbour facet's segments sum to its length.
TEST(ShapeCells, GeometryMatchesTheMeasures) {
  for (int d : {2, 3}) {
    SCOPED_TRACE(d);
    Mesh m;
    m.l_part(1.0);
    const ShapeDomain shape = d == 2 ? three_holes() : m.solid("l-part");
    const PointSet ps = seeds_inside(shape, 200, 6, 20);
    const KdTree tree(ps);
    auto box = ShapeClipper::box(ps, shape);
    ASSERT_TRUE(box.is_ok());
    ClippedCellBuilder builder(tree, box.value());
    ShapeClipper drawn(ps, shape), plain(ps, shape);
    drawn.set_geometry(true);
    for (std::uint32_t s = 0; s < ps.size(); ++s) {
      VoronoiCell a, b;
      ASSERT_TRUE(builder.cell(s, a).is_ok());
      b = a;
      drawn.clip(s, a);
      plain.clip(s, b);
      ASSERT_EQ(a.volume, b.volume);
      ASSERT_EQ(a.facets.size(), b.facets.size());
      for (std::size_t k = 0; k < a.facets.size(); ++k) {
        const VoronoiFacet& f = a.facets[k];
        EXPECT_EQ(f.area, b.facets[k].area);
        auto at = [&](std::uint32_t v) { return &a.vertices[static_cast<std::size_t>(v) * d]; };
        double measured = 0;
        if (d == 2) {
          for (std::size_t i = 0; i + 1 < f.vertices.size(); i += 2) {
            measured += std::hypot(at(f.vertices[i + 1])[0] - at(f.vertices[i])[0],
                                   at(f.vertices[i + 1])[1] - at(f.vertices[i])[1]);
          }
        } else if (f.is_wall()) {
          double n[3] = {0, 0, 0};
          const double* o = at(f.vertices[0]);
          for (std::size_t i = 1; i + 1 < f.vertices.size(); ++i) {
            const double* p = at(f.vertices[i]);
            const double* q = at(f.vertices[i + 1]);
            const double u[3] = {p[0] - o[0], p[1] - o[1], p[2] - o[2]}, v[3] = {q[0] - o[0], q[1] - o[1], q[2] - o[2]};
            n[0] += u[1] * v[2] - u[2] * v[1];
            n[1] += u[2] * v[0] - u[0] * v[2];
            n[2] += u[0] * v[1] - u[1] * v[0];
          }
          measured = (n[0] * f.normal[0] + n[1] * f.normal[1] + n[2] * f.normal[2]) / 2;  // positive: outward loop
        } else {
          continue;  // a 3-d neighbour facet's outline is drawn, not measured
        }
        if (a.vertices.empty()) continue;  // a whole convex cell: its own geometry
        EXPECT_NEAR(measured, f.area, 1e-9 * std::max(1.0, f.area)) << "seed " << s << " facet " << k;
      }
    }
  }
}

TEST(ShapeDomains, Locate) {
  const ShapeDomain shape = three_holes();
  const double inside[2] = {5, 4.5}, hole[2] = {2, 2}, wall[2] = {0, 5}, corner[2] = {10, 10}, far[2] = {20, 2};
  EXPECT_EQ(shape.locate(inside), 1);
  EXPECT_EQ(shape.locate(hole), -1);
  EXPECT_EQ(shape.locate(wall), 0);
  EXPECT_EQ(shape.locate(corner), 0);
  EXPECT_EQ(shape.locate(far), -1);
  // Rays through vertices and along edges: the points level with the square hole's corners.
  const double level[2] = {0.5, 1}, level2[2] = {0.5, 3}, beside[2] = {3.5, 1};
  EXPECT_EQ(shape.locate(level), 1);
  EXPECT_EQ(shape.locate(level2), 1);
  EXPECT_EQ(shape.locate(beside), 1);
  Mesh m;
  const double lo[3] = {0, 0, 0}, hi[3] = {2, 2, 2};
  m.box(lo, hi, 2);
  const ShapeDomain cube = m.solid("cube");
  const double c[3] = {1, 1, 1}, edge_ray[3] = {0.5, 1, 1}, face[3] = {0, 1, 1}, out[3] = {3, 1, 1};
  EXPECT_EQ(cube.locate(c), 1);
  EXPECT_EQ(cube.locate(edge_ray), 1);  // its ray runs through the x = 2 side's vertex (2, 1, 1)
  EXPECT_EQ(cube.locate(face), 0);
  EXPECT_EQ(cube.locate(out), -1);
}

std::string refusal(const std::string& text, const std::string& name) {
  auto s = parse_shape_domain(text, name);
  return s.is_ok() ? std::string("accepted") : s.status().message();
}

TEST(ShapeDomains, BadDomainsAreRefusedAndNamed) {
  const std::string tet = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n";
  EXPECT_EQ(refusal(tet, "tet.off"), "accepted");
  EXPECT_NE(
      refusal("OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n", "open.off").find("open boundary"),
      std::string::npos);
  EXPECT_NE(refusal("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n3 1 2 3\n3 0 3 2\n", "flip.off")
                .find("inconsistent orientation"),
            std::string::npos);
  EXPECT_NE(refusal("OFF\n4 4 0\n0 0 0\n1 0 0\n2 0 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n", "flat.off")
                .find("zero area"),
            std::string::npos);
  // Two tetrahedra passing through each other.
  const std::string two =
      "OFF\n8 8 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n0.2 0.2 0.2\n1.2 0.2 0.2\n0.2 1.2 0.2\n0.2 0.2 1.2\n"
      "3 0 2 1\n3 0 1 3\n3 1 2 3\n3 0 3 2\n3 4 6 5\n3 4 5 7\n3 5 6 7\n3 4 7 6\n";
  EXPECT_NE(refusal(two, "two.off").find("self-intersection"), std::string::npos);
  EXPECT_NE(refusal("OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 9\n3 0 3 2\n", "idx.off")
                .find("vertex index"),
            std::string::npos);
  EXPECT_NE(refusal("OFF\n4 4 0\n0 0 0\n1 0 0\n", "short.off").find("ends early"), std::string::npos);
  // 2-d: a bow tie, touching rings, a zero-area ring, a short ring, a bad number.
  EXPECT_NE(refusal("0 0\n1 1\n1 0\n0 1\n", "bow.rings").find("crosses itself"), std::string::npos);
  EXPECT_NE(refusal("0 0\n4 0\n4 4\n0 4\n\n0 0\n1 1\n1 0\n", "touch.rings").find("must not cross or touch"),
            std::string::npos);
  EXPECT_NE(refusal("0 0\n1 1\n2 2\n", "line.rings").find("zero area"), std::string::npos);
  EXPECT_NE(refusal("0 0\n1 1\n", "short.rings").find("at least 3"), std::string::npos);
  EXPECT_NE(refusal("0 0\n1 x\n1 0\n", "nan.rings").find("nan.rings:2"), std::string::npos);
  EXPECT_NE(refusal("0 0\n1 0\n1 0\n0 1\n", "dup.rings").find("zero-length edge"), std::string::npos);
  EXPECT_NE(refusal("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                    "endfacet\nendsolid\n",
                    "one.stl")
                .find("open boundary"),
            std::string::npos);
}

TEST(ShapeDomains, FormatsAgree) {
  // One tetrahedron as OFF, OBJ (a quad-free mesh, 1-based), ASCII and binary STL.
  const double v[4][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const int f[4][3] = {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}};
  std::string obj, ascii = "solid t\n", binary(80, ' ');
  for (const auto& p : v)
    obj += "v " + std::to_string(p[0]) + " " + std::to_string(p[1]) + " " + std::to_string(p[2]) + "\n";
  const std::uint32_t count = 4;
  binary.append(reinterpret_cast<const char*>(&count), 4);
  for (const auto& t : f) {
    obj +=
        "f " + std::to_string(t[0] + 1) + "/1 " + std::to_string(t[1] + 1) + "//2 " + std::to_string(t[2] + 1) + "\n";
    ascii += "facet normal 0 0 0\nouter loop\n";
    float rec[12] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      ascii += "vertex " + std::to_string(v[t[k]][0]) + " " + std::to_string(v[t[k]][1]) + " " +
               std::to_string(v[t[k]][2]) + "\n";
      for (int c = 0; c < 3; ++c) rec[3 + 3 * k + c] = static_cast<float>(v[t[k]][c]);
    }
    ascii += "endloop\nendfacet\n";
    binary.append(reinterpret_cast<const char*>(rec), 48);
    binary.append(2, '\0');
  }
  ascii += "endsolid t\n";
  for (const auto& [text, name] :
       std::vector<std::pair<std::string, std::string>>{{obj, "t.obj"}, {ascii, "t.stl"}, {binary, "b.stl"}}) {
    auto s = parse_shape_domain(text, name);
    ASSERT_TRUE(s.is_ok()) << name << ": " << s.status().message();
    EXPECT_NEAR(s->volume(), 1.0 / 6, 1e-15) << name;
    EXPECT_EQ(s->face_count(), 4u);
  }
}

}  // namespace
}  // namespace spokemesh
