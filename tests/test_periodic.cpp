// Periodic boxes: Delaunay triangulations of the flat torus, simplex for
// simplex with offsets (up to a lattice translation) against CGAL's
// Periodic_2_Delaunay_triangulation_2 and Periodic_3_Delaunay_triangulation_3 in their
// 1-sheeted covering; and, in every dimension, checked on their own: every simplex
// positively oriented (exactly, on the images), volumes summing to the box's, every
// facet shared by exactly two simplices, the same rows for any thread count, and the
// same triangulation for any input order.
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Periodic_2_Delaunay_triangulation_2.h>
#include <CGAL/Periodic_2_Delaunay_triangulation_traits_2.h>
#include <CGAL/Periodic_2_triangulation_face_base_2.h>
#include <CGAL/Periodic_2_triangulation_vertex_base_2.h>
#include <CGAL/Periodic_3_Delaunay_triangulation_3.h>
#include <CGAL/Periodic_3_Delaunay_triangulation_traits_3.h>
#include <CGAL/Periodic_3_regular_triangulation_3.h>
#include <CGAL/Periodic_3_regular_triangulation_traits_3.h>
#include <CGAL/Periodic_3_triangulation_ds_cell_base_3.h>
#include <CGAL/Periodic_3_triangulation_ds_vertex_base_3.h>
#include <CGAL/Regular_triangulation_cell_base_3.h>
#include <CGAL/Regular_triangulation_vertex_base_3.h>
#include <CGAL/Triangulation_cell_base_3.h>
#include <CGAL/Triangulation_vertex_base_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <random>

#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "spokemesh/predicates.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;
using K = CGAL::Exact_predicates_inexact_constructions_kernel;

// A torus triangulation as the set of its simplices, each a sorted list of
// (point, offset...) vertices translated so that its first vertex in that order (the
// smallest point, at its smallest offset) sits at offset 0: a lattice translation and
// the vertex order do not change it.
using Vertex = std::vector<std::int64_t>;  // point, then d offsets
using Torus = std::set<std::vector<Vertex>>;

std::vector<Vertex> canonical(std::vector<Vertex> simplex) {
  std::sort(simplex.begin(), simplex.end());
  const Vertex first = simplex.front();
  for (Vertex& v : simplex) {
    for (std::size_t c = 1; c < v.size(); ++c) v[c] -= first[c];
  }
  std::sort(simplex.begin(), simplex.end());
  return simplex;
}

struct Rows {
  std::vector<std::uint32_t> simplices;
  std::vector<std::int32_t> offsets;
  PeriodicMeshStats stats;
};

Rows mesh(const PointSet& ps, const PeriodicBox& box, unsigned threads = 1, std::span<const double> weights = {}) {
  Rows out;
  MeshOptions options;
  options.threads = threads;
  options.star.weights = weights;
  auto result = mesh_periodic(
      ps, box, options,
      [&](std::span<const std::uint32_t> s, std::span<const std::int32_t> o, std::uint64_t) {
        out.simplices.insert(out.simplices.end(), s.begin(), s.end());
        out.offsets.insert(out.offsets.end(), o.begin(), o.end());
        return Status::ok();
      },
      [&] {
        out.simplices.clear();
        out.offsets.clear();
        return Status::ok();
      },
      "test points");
  EXPECT_TRUE(result.is_ok()) << result.status().message();
  if (result.is_ok()) out.stats = result.value();
  return out;
}

Torus as_torus(const Rows& rows, int d, const std::vector<std::uint32_t>* rename = nullptr) {
  Torus t;
  const auto w = static_cast<std::size_t>(d + 1);
  for (std::size_t s = 0; s * w < rows.simplices.size(); ++s) {
    std::vector<Vertex> simplex;
    for (std::size_t v = 0; v < w; ++v) {
      Vertex vertex{rename ? (*rename)[rows.simplices[s * w + v]] : rows.simplices[s * w + v]};
      for (int c = 0; c < d; ++c) vertex.push_back(rows.offsets[(s * w + v) * static_cast<std::size_t>(d) + c]);
      simplex.push_back(vertex);
    }
    const std::size_t before = t.size();
    t.insert(canonical(simplex));
    EXPECT_EQ(t.size(), before + 1) << "simplex " << s << " written twice";
  }
  return t;
}

// CGAL's periodic triangulations, in the 1-sheeted covering (asserted).
Torus cgal_torus_2(const PointSet& ps, const PeriodicBox& box) {
  using Gt = CGAL::Periodic_2_Delaunay_triangulation_traits_2<K>;
  using Vbb = CGAL::Periodic_2_triangulation_vertex_base_2<Gt>;
  using Vb = CGAL::Triangulation_vertex_base_with_info_2<std::uint32_t, Gt, Vbb>;
  using Fb = CGAL::Periodic_2_triangulation_face_base_2<Gt>;
  using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
  using PDT = CGAL::Periodic_2_Delaunay_triangulation_2<Gt, Tds>;
  PDT t(Gt::Iso_rectangle_2(box.lo()[0], box.lo()[1], box.hi()[0], box.hi()[1]));
  std::vector<std::pair<K::Point_2, std::uint32_t>> points;
  for (std::uint32_t i = 0; i < ps.size(); ++i) points.emplace_back(K::Point_2(ps.point(i)[0], ps.point(i)[1]), i);
  t.insert(points.begin(), points.end());
  EXPECT_TRUE(t.is_1_cover());
  Torus out;
  for (auto f = t.faces_begin(); f != t.faces_end(); ++f) {
    std::vector<Vertex> simplex;
    for (int i = 0; i < 3; ++i) {
      const auto pp = t.periodic_point(f, i);
      simplex.push_back({f->vertex(i)->info(), pp.second.x(), pp.second.y()});
    }
    out.insert(canonical(simplex));
  }
  return out;
}

Torus cgal_torus_3(const PointSet& ps, const PeriodicBox& box) {
  using Gt = CGAL::Periodic_3_Delaunay_triangulation_traits_3<K>;
  using VbDS = CGAL::Periodic_3_triangulation_ds_vertex_base_3<>;
  using Vbb = CGAL::Triangulation_vertex_base_3<Gt, VbDS>;
  using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::uint32_t, Gt, Vbb>;
  using CbDS = CGAL::Periodic_3_triangulation_ds_cell_base_3<>;
  using Cb = CGAL::Triangulation_cell_base_3<Gt, CbDS>;
  using Tds = CGAL::Triangulation_data_structure_3<Vb, Cb>;
  using PDT = CGAL::Periodic_3_Delaunay_triangulation_3<Gt, Tds>;
  PDT t(Gt::Iso_cuboid_3(box.lo()[0], box.lo()[1], box.lo()[2], box.hi()[0], box.hi()[1], box.hi()[2]));
  // (Periodic_3 takes no (point, info) pairs: one by one, naming each vertex.)
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    t.insert(K::Point_3(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]))->info() = i;
  }
  EXPECT_TRUE(t.is_1_cover());
  Torus out;
  for (auto c = t.cells_begin(); c != t.cells_end(); ++c) {
    std::vector<Vertex> simplex;
    for (int i = 0; i < 4; ++i) {
      const auto pp = t.periodic_point(c, i);
      simplex.push_back({c->vertex(i)->info(), pp.second.x(), pp.second.y(), pp.second.z()});
    }
    out.insert(canonical(simplex));
  }
  return out;
}

// CGAL's Periodic_3_regular_triangulation_3 (weights in [0, side^2 / 64), its
// precondition), and the points it hides.
std::pair<Torus, std::set<std::uint32_t>> cgal_regular_torus_3(const PointSet& ps, const PeriodicBox& box,
                                                               const std::vector<double>& w) {
  using Gt = CGAL::Periodic_3_regular_triangulation_traits_3<K>;
  using Vb0 = CGAL::Regular_triangulation_vertex_base_3<Gt, CGAL::Periodic_3_triangulation_ds_vertex_base_3<>>;
  using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::uint32_t, Gt, Vb0>;
  using Cb = CGAL::Regular_triangulation_cell_base_3<Gt, CGAL::Periodic_3_triangulation_ds_cell_base_3<>>;
  using Tds = CGAL::Triangulation_data_structure_3<Vb, Cb>;
  using PRT = CGAL::Periodic_3_regular_triangulation_3<Gt, Tds>;
  PRT t(Gt::Iso_cuboid_3(box.lo()[0], box.lo()[1], box.lo()[2], box.hi()[0], box.hi()[1], box.hi()[2]));
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    const auto v = t.insert(Gt::Weighted_point_3(K::Point_3(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]), w[i]));
    if (v != PRT::Vertex_handle()) v->info() = i;
  }
  EXPECT_TRUE(t.is_1_cover());
  Torus out;
  std::set<std::uint32_t> hidden;
  for (std::uint32_t i = 0; i < ps.size(); ++i) hidden.insert(i);
  for (auto v = t.vertices_begin(); v != t.vertices_end(); ++v) hidden.erase(v->info());
  for (auto c = t.cells_begin(); c != t.cells_end(); ++c) {
    std::vector<Vertex> simplex;
    for (int i = 0; i < 4; ++i) {
      const auto pp = t.periodic_point(c, i);
      simplex.push_back({c->vertex(i)->info(), pp.second.x(), pp.second.y(), pp.second.z()});
    }
    out.insert(canonical(simplex));
  }
  return {out, hidden};
}

// The checks that need no peer: exact positive orientation of every simplex, volumes
// summing to the box's, every facet in exactly two simplices (as translation classes).
void check_torus(const PointSet& ps, const PeriodicBox& box, const Rows& rows, const std::string& what) {
  SCOPED_TRACE(what);
  const int d = ps.dimension();
  const auto w = static_cast<std::size_t>(d + 1);
  const Predicates predicates(ps, {}, &box);
  double volume = 0, box_volume = 1, factorial = 1;
  for (int c = 0; c < d; ++c) {
    box_volume *= box.hi()[c] - box.lo()[c];
    factorial *= c + 1;
  }
  std::map<std::vector<Vertex>, int> facets;
  for (std::size_t s = 0; s * w < rows.simplices.size(); ++s) {
    std::vector<Image> images(w);
    std::vector<std::vector<double>> at(w, std::vector<double>(static_cast<std::size_t>(d)));
    for (std::size_t v = 0; v < w; ++v) {
      images[v].point = rows.simplices[s * w + v];
      for (int c = 0; c < d; ++c) {
        images[v].offset[static_cast<std::size_t>(c)] = rows.offsets[(s * w + v) * static_cast<std::size_t>(d) + c];
        at[v][static_cast<std::size_t>(c)] =
            ps.point(images[v].point)[c] + images[v].offset[static_cast<std::size_t>(c)] * (box.hi()[c] - box.lo()[c]);
      }
    }
    ASSERT_EQ(predicates.orientation(images), 1) << "simplex " << s << " is not positively oriented";
    ASSERT_EQ(images[0].offset, Image{}.offset) << "the owner is not at offset 0";
    Eigen::MatrixXd m(d, d);
    for (int r = 0; r < d; ++r) {
      for (int c = 0; c < d; ++c)
        m(r, c) = at[static_cast<std::size_t>(r + 1)][static_cast<std::size_t>(c)] - at[0][static_cast<std::size_t>(c)];
    }
    volume += m.determinant() / factorial;
    for (std::size_t skip = 0; skip < w; ++skip) {
      std::vector<Vertex> facet;
      for (std::size_t v = 0; v < w; ++v) {
        if (v == skip) continue;
        Vertex vertex{images[v].point};
        for (int c = 0; c < d; ++c) vertex.push_back(images[v].offset[static_cast<std::size_t>(c)]);
        facet.push_back(vertex);
      }
      ++facets[canonical(facet)];
    }
  }
  EXPECT_NEAR(volume, box_volume, 1e-12 * box_volume);
  for (const auto& [facet, count] : facets) ASSERT_EQ(count, 2) << "a facet in " << count << " simplices";
}

PointSet uniform_in(const PeriodicBox& box, std::size_t n, std::uint64_t seed) {
  const int d = box.dimension();
  std::mt19937_64 rng(seed);
  std::vector<double> coords(n * static_cast<std::size_t>(d));
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < d; ++c) {
      std::uniform_real_distribution<double> u(box.lo()[c], box.hi()[c]);
      double v = u(rng);
      if (v >= box.hi()[c]) v = box.lo()[c];
      coords[i * static_cast<std::size_t>(d) + c] = v;
    }
  }
  return make_points(d, std::move(coords));
}

PeriodicBox cube(int d, double lo, double hi) {
  return PeriodicBox::of(std::vector<double>(static_cast<std::size_t>(d), lo),
                         std::vector<double>(static_cast<std::size_t>(d), hi), "box")
      .value();
}

TEST(Periodic, Uniform2dEqualsCgal) {
  for (const auto& [lo, hi, seed] : {std::tuple{0.0, 1.0, 1u}, std::tuple{-2.0, 3.0, 2u}, std::tuple{0.1, 0.7, 3u}}) {
    const PeriodicBox box = cube(2, lo, hi);
    const PointSet ps = uniform_in(box, 600, seed);
    const Rows rows = mesh(ps, box);
    SCOPED_TRACE("seed " + std::to_string(seed));
    check_torus(ps, box, rows, "uniform 2-d");
    EXPECT_EQ(rows.simplices.size(), 2 * ps.size() * 3);  // Euler: 2n triangles on the torus
    EXPECT_EQ(as_torus(rows, 2), cgal_torus_2(ps, box));
  }
}

TEST(Periodic, Uniform3dEqualsCgal) {
  for (const auto& [lo, hi, seed] : {std::tuple{0.0, 1.0, 4u}, std::tuple{0.5, 2.5, 5u}}) {
    const PeriodicBox box = cube(3, lo, hi);
    const PointSet ps = uniform_in(box, 1500, seed);
    const Rows rows = mesh(ps, box, 2);
    SCOPED_TRACE("seed " + std::to_string(seed));
    check_torus(ps, box, rows, "uniform 3-d");
    EXPECT_EQ(as_torus(rows, 3), cgal_torus_3(ps, box));
  }
}

// Grids: every circle and sphere degenerate, resolved by the perturbation on the
// images' order. Integer and decimal steps (whose translates are not exact doubles).
TEST(Periodic, GridsEqualCgal) {
  {
    const PointSet ps = make_points(2, grid_points(2, 12));  // 0..11 on each axis
    const PeriodicBox box = cube(2, 0, 12);
    const Rows rows = mesh(ps, box);
    check_torus(ps, box, rows, "integer grid 2-d");
    EXPECT_EQ(as_torus(rows, 2), cgal_torus_2(ps, box));
  }
  {
    const PointSet ps = make_points(2, scaled_grid_points(2, 10, decimal_value));  // 0, 0.1, ..., 0.9
    const PeriodicBox box = cube(2, 0, 1);
    const Rows rows = mesh(ps, box);
    check_torus(ps, box, rows, "decimal grid 2-d");
    EXPECT_EQ(as_torus(rows, 2), cgal_torus_2(ps, box));
  }
  {
    const PointSet ps = make_points(3, grid_points(3, 6));
    const PeriodicBox box = cube(3, 0, 6);
    const Rows rows = mesh(ps, box, 2);
    check_torus(ps, box, rows, "integer grid 3-d");
    EXPECT_EQ(rows.simplices.size() / 4, 6u * 216);  // each unit cube in 6 tetrahedra
    EXPECT_EQ(as_torus(rows, 3), cgal_torus_3(ps, box));
  }
  {
    const PointSet ps = make_points(3, scaled_grid_points(3, 5, decimal_value));
    const PeriodicBox box = cube(3, 0, 0.5);
    const Rows rows = mesh(ps, box);
    check_torus(ps, box, rows, "decimal grid 3-d");
    EXPECT_EQ(as_torus(rows, 3), cgal_torus_3(ps, box));
  }
}

// Higher dimensions have no peer: the torus's own invariants.
TEST(Periodic, FourAndFiveDimensions) {
  for (int d : {4, 5}) {
    const PeriodicBox box = cube(d, 0, 1);
    const PointSet ps = uniform_in(box, d == 4 ? 400 : 250, 7u + static_cast<unsigned>(d));
    check_torus(ps, box, mesh(ps, box, 2), std::to_string(d) + "-d");
  }
  const PointSet grid = make_points(4, grid_points(4, 4));
  check_torus(grid, cube(4, 0, 4), mesh(grid, cube(4, 0, 4)), "4-d grid");
}

// Weighted points on the torus: the regular triangulation, simplex for simplex with
// offsets and hidden points, against CGAL's Periodic_3_regular_triangulation_3; in 2-d
// and 4-d the torus's invariants; equal weights give the Delaunay rows, byte for byte.
TEST(Periodic, WeightedEqualsCgalRegular) {
  const PeriodicBox box = cube(3, 0, 1);
  const PointSet ps = uniform_in(box, 3000, 31);
  std::mt19937_64 rng(32);
  const double spacing2 = std::pow(1.0 / 3000, 2.0 / 3);
  for (double spread : {0.5, 1.5}) {
    std::vector<double> w(ps.size());
    for (double& v : w) v = std::uniform_real_distribution<double>(0, spread * spacing2)(rng);
    SCOPED_TRACE("spread " + std::to_string(spread));
    const Rows rows = mesh(ps, box, 2, w);
    check_torus(ps, box, rows, "weighted 3-d");
    const auto [theirs, hidden] = cgal_regular_torus_3(ps, box, w);
    EXPECT_EQ(as_torus(rows, 3), theirs);
    std::set<std::uint32_t> used(rows.simplices.begin(), rows.simplices.end());
    std::set<std::uint32_t> ours_hidden;
    for (std::uint32_t i = 0; i < ps.size(); ++i) {
      if (!used.count(i)) ours_hidden.insert(i);
    }
    EXPECT_EQ(ours_hidden, hidden);
    if (spread > 1) {
      EXPECT_GT(hidden.size(), 5u) << "the larger weights should hide points";
    }
  }
  for (int d : {2, 4}) {
    const PeriodicBox b = cube(d, 0, 1);
    const PointSet p = uniform_in(b, d == 2 ? 600 : 300, 33u + static_cast<unsigned>(d));
    std::vector<double> w(p.size());
    for (double& v : w) v = std::uniform_real_distribution<double>(-0.5, 1.5)(rng) * std::pow(1.0 / p.size(), 2.0 / d);
    check_torus(p, b, mesh(p, b, 2, w), std::to_string(d) + "-d weighted");
  }
  const PointSet grid = make_points(3, grid_points(3, 5));
  const std::vector<double> equal(grid.size(), 0.125);
  const Rows plain = mesh(grid, cube(3, 0, 5)), weighted = mesh(grid, cube(3, 0, 5), 1, equal);
  EXPECT_EQ(plain.simplices, weighted.simplices);
  EXPECT_EQ(plain.offsets, weighted.offsets);
}

TEST(Periodic, ThreadsGiveTheSameRows) {
  const PeriodicBox box = cube(3, 0, 1);
  const PointSet ps = uniform_in(box, 3000, 11);
  const Rows one = mesh(ps, box, 1), two = mesh(ps, box, 2);
  EXPECT_EQ(one.simplices, two.simplices);
  EXPECT_EQ(one.offsets, two.offsets);
}

TEST(Periodic, InputOrderDoesNotMatter) {
  for (int d : {2, 3}) {
    const PeriodicBox box = cube(d, 0, 4);
    const PointSet ps = d == 2 ? make_points(2, grid_points(2, 4 * 2)) : uniform_in(box, 800, 13);
    // A grid of step 0.5 in 2-d: degenerate everywhere.
    std::vector<double> coords(ps.coordinates().begin(), ps.coordinates().end());
    if (d == 2) {
      for (double& v : coords) v *= 0.5;
    }
    const PointSet original = make_points(d, coords);
    std::vector<std::uint32_t> perm(original.size());
    std::iota(perm.begin(), perm.end(), 0u);
    std::shuffle(perm.begin(), perm.end(), std::mt19937_64(99));
    std::vector<double> shuffled;
    for (std::uint32_t i : perm) {
      shuffled.insert(shuffled.end(), original.point(i), original.point(i) + d);
    }
    const PointSet permuted = make_points(d, shuffled);
    SCOPED_TRACE(std::to_string(d) + "-d, shuffle seed 99");
    EXPECT_EQ(as_torus(mesh(original, box), d), as_torus(mesh(permuted, box), d, &perm));
  }
}

// Clustered points leave the first margin too thin: the run is repeated with the
// margin it measured, and the result is still a triangulation of the torus.
TEST(Periodic, ThinMarginsAreWidened) {
  const PeriodicBox box = cube(3, 0, 1);
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> u(0, 0.3);
  std::vector<double> coords;
  for (int i = 0; i < 400; ++i) {
    for (int c = 0; c < 3; ++c) coords.push_back(u(rng));
  }
  const PointSet ps = make_points(3, coords);
  const Rows rows = mesh(ps, box);
  EXPECT_GT(rows.stats.runs, 1);
  check_torus(ps, box, rows, "clustered");
  // Very few points: the torus still has a Delaunay triangulation (not a simplicial
  // complex, but each simplex written once).
  const PointSet few = make_points(2, {0.1, 0.2, 0.6, 0.3, 0.4, 0.8, 0.85, 0.55});
  check_torus(few, cube(2, 0, 1), mesh(few, cube(2, 0, 1)), "four points");
}

// The torus's cells: volumes sum to the box's in every dimension, each facet i -> j at
// offset k has its partner j -> i at -k with the same area, and a cell's facets are its
// seed's Delaunay neighbours across the torus (the mesh's edges).
// 3-d cells of the torus are built directly (the cover's region clipped by points and
// images, BoxCell3d): each equals the seed's cell from its star (periodic_star), facet
// by facet with offsets, plain and weighted, and on a grid (ties: the star's way).
TEST(Periodic, DirectCellsEqualTheStarsCells) {
  const PeriodicBox box = cube(3, 0, 1);
  struct Set {
    std::string name;
    PointSet points;
    std::vector<double> weights;
  };
  std::vector<Set> sets;
  sets.push_back({"uniform", uniform_in(box, 700, 61), {}});
  {
    Set weighted{"weighted", uniform_in(box, 700, 62), {}};
    std::mt19937_64 rng(63);
    std::uniform_real_distribution<double> u(0, 0.004);
    for (std::size_t i = 0; i < 700; ++i) weighted.weights.push_back(u(rng));
    sets.push_back(std::move(weighted));
  }
  {
    std::vector<double> grid;
    for (int i = 0; i < 6; ++i) {
      for (int j = 0; j < 6; ++j) {
        for (int k = 0; k < 6; ++k) grid.insert(grid.end(), {i / 6.0, j / 6.0, k / 6.0});
      }
    }
    PointSet ps(3, std::move(grid));
    EXPECT_TRUE(ps.validate("grid").is_ok());
    sets.push_back({"grid", std::move(ps), {}});
  }
  for (const Set& set : sets) {
    SCOPED_TRACE(set.name);
    CellsOptions options;
    options.threads = 2;
    options.star.weights = set.weights;
    std::vector<VoronoiCell> cells;
    ASSERT_TRUE(compute_periodic_cells(
                    set.points, box, options,
                    [&](std::span<const VoronoiCell> part, std::uint64_t) {
                      cells.insert(cells.end(), part.begin(), part.end());
                      return Status::ok();
                    },
                    [&] {
                      cells.clear();
                      return Status::ok();
                    },
                    "test points")
                    .is_ok());
    ASSERT_EQ(cells.size(), set.points.size());
    StarOptions star_options;
    star_options.weights = set.weights;
    for (std::uint32_t s = 0; s < set.points.size(); ++s) {
      SCOPED_TRACE("seed " + std::to_string(s));
      VoronoiCell want;
      ASSERT_TRUE(periodic_star(set.points, box, s, star_options, "test points", &want).is_ok());
      const VoronoiCell& got = cells[s];
      EXPECT_EQ(got.hidden, want.hidden);
      EXPECT_FALSE(got.clipped);
      EXPECT_NEAR(got.volume, want.volume, 1e-12);
      ASSERT_EQ(got.facets.size(), want.facets.size());
      // Facets by (neighbour, offset): the orders of the two routes' lists may differ
      // where a point neighbours the seed through two images.
      std::map<std::pair<std::int64_t, std::vector<std::int32_t>>, double> a, b;
      for (std::size_t f = 0; f < got.facets.size(); ++f) {
        a[{got.facets[f].neighbor,
           {got.facet_offsets.begin() + 3 * static_cast<std::ptrdiff_t>(f),
            got.facet_offsets.begin() + 3 * static_cast<std::ptrdiff_t>(f + 1)}}] = got.facets[f].area;
        b[{want.facets[f].neighbor,
           {want.facet_offsets.begin() + 3 * static_cast<std::ptrdiff_t>(f),
            want.facet_offsets.begin() + 3 * static_cast<std::ptrdiff_t>(f + 1)}}] = want.facets[f].area;
      }
      ASSERT_EQ(a.size(), b.size());
      for (auto i = a.begin(), j = b.begin(); i != a.end(); ++i, ++j) {
        EXPECT_EQ(i->first, j->first);
        EXPECT_NEAR(i->second, j->second, 1e-10);
      }
    }
  }
}

TEST(Periodic, CellsTileTheTorus) {
  for (int d : {2, 3, 4}) {
    const PeriodicBox box = cube(d, -1, 1);
    const PointSet ps = uniform_in(box, d == 4 ? 300 : 800, 21u + static_cast<unsigned>(d));
    SCOPED_TRACE(std::to_string(d) + "-d");
    CellsOptions options;
    options.threads = 2;
    options.measures_only = true;
    double volume = 0;
    std::map<std::tuple<std::uint32_t, std::uint32_t, std::vector<std::int32_t>>, double> facets;
    auto result = compute_periodic_cells(
        ps, box, options,
        [&](std::span<const VoronoiCell> cells, std::uint64_t) {
          for (const VoronoiCell& c : cells) {
            EXPECT_TRUE(c.bounded);
            volume += c.volume;
            EXPECT_EQ(c.facet_offsets.size(), c.facets.size() * static_cast<std::size_t>(d));
            for (std::size_t f = 0; f < c.facets.size(); ++f) {
              const auto* k = c.facet_offsets.data() + f * static_cast<std::size_t>(d);
              facets[{c.seed, static_cast<std::uint32_t>(c.facets[f].neighbor), std::vector<std::int32_t>(k, k + d)}] =
                  c.facets[f].area;
            }
          }
          return Status::ok();
        },
        [&] {
          volume = 0;
          facets.clear();
          return Status::ok();
        },
        "test points");
    ASSERT_TRUE(result.is_ok()) << result.status().message();
    EXPECT_NEAR(volume, std::pow(2.0, d), 1e-12 * std::pow(2.0, d));
    for (const auto& [key, area] : facets) {
      auto back = std::get<2>(key);
      for (auto& v : back) v = -v;
      const auto it = facets.find({std::get<1>(key), std::get<0>(key), back});
      ASSERT_NE(it, facets.end()) << "facet " << std::get<0>(key) << " -> " << std::get<1>(key) << " has no partner";
      EXPECT_NEAR(it->second, area, 1e-9 * area);
    }
    // Neighbours are the mesh's edges (as translation classes).
    const Rows rows = mesh(ps, box);
    std::set<std::tuple<std::uint32_t, std::uint32_t, std::vector<std::int32_t>>> edges;
    const auto w = static_cast<std::size_t>(d + 1);
    for (std::size_t s = 0; s * w < rows.simplices.size(); ++s) {
      for (std::size_t a = 0; a < w; ++a) {
        for (std::size_t b = 0; b < w; ++b) {
          if (a == b) continue;
          std::vector<std::int32_t> k(static_cast<std::size_t>(d));
          for (int c = 0; c < d; ++c) {
            k[static_cast<std::size_t>(c)] = rows.offsets[(s * w + b) * static_cast<std::size_t>(d) + c] -
                                             rows.offsets[(s * w + a) * static_cast<std::size_t>(d) + c];
          }
          edges.insert({rows.simplices[s * w + a], rows.simplices[s * w + b], k});
        }
      }
    }
    std::set<std::tuple<std::uint32_t, std::uint32_t, std::vector<std::int32_t>>> from_cells;
    for (const auto& [key, area] : facets) from_cells.insert(key);
    EXPECT_EQ(from_cells, edges);
  }
}

TEST(Periodic, ImageDifferenceRoundsOnce) {
  // 0.1 + 1 - 1.05: the exact value, rounded once (long arithmetic in rationals).
  const double got = image_difference(0.1, 1, 0.0, 1.0, 1.05);
  const mpq_class exact = mpq_class(0.1) + 1 - mpq_class(1.05);
  EXPECT_LE(abs(mpq_class(got) - exact), abs(exact) * mpq_class(0x1p-53));
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-3, 3);
  for (int i = 0; i < 20000; ++i) {
    const double p = u(rng), lo = u(rng), x = u(rng);
    const double hi = lo + std::fabs(u(rng)) + 1e-3;
    const int k = static_cast<int>(rng() % 7) - 3;
    const double r = image_difference(p, k, lo, hi, x);
    const mpq_class e = mpq_class(p) + k * (mpq_class(hi) - mpq_class(lo)) - mpq_class(x);
    // Correct rounding: no double lies strictly between r and e, and r is within half an ulp.
    const mpq_class err = abs(mpq_class(r) - e);
    const double ulp = std::nextafter(std::fabs(r), INFINITY) - std::fabs(r);
    ASSERT_LE(err, mpq_class(ulp) / 2) << "p " << p << " k " << k << " lo " << lo << " hi " << hi << " x " << x;
  }
}

}  // namespace
}  // namespace spokemesh
