// Weighted points: the stars and whole meshes of the regular (weighted
// Delaunay) triangulation, simplex for simplex against CGAL's Regular_triangulation_2
// and _3 and dD (hidden points included) and against exhaustive search in 4-d; equal weights
// give back the Delaunay mesh; the result does not depend on input order.
#include <CGAL/Epick_d.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Regular_triangulation_3.h>
#include <CGAL/Regular_triangulation_cell_base_3.h>
#include <CGAL/Regular_triangulation_face_base_2.h>
#include <CGAL/Regular_triangulation_vertex_base_2.h>
#include <CGAL/Regular_triangulation_vertex_base_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>

#include <algorithm>
#include <map>
#include <numeric>
#include <random>

#include "spokemesh/cells.hpp"
#include "spokemesh/domain.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;
using Tuples = std::set<std::vector<std::uint32_t>>;
using K = CGAL::Exact_predicates_inexact_constructions_kernel;

// A regular triangulation: its simplices (sorted vertex lists) and its hidden points.
struct Regular {
  Tuples simplices;
  std::set<std::uint32_t> hidden;
};

// The simplices and hidden points of a CGAL triangulation, from its finite vertices
// and cells: `id` reads a vertex's point index from a handle or an iterator.
template <class VertexIt, class CellIt, class Id>
Regular collect(std::size_t n, VertexIt v, VertexIt v_end, CellIt c, CellIt c_end, int corners, Id id) {
  Regular out;
  std::set<std::uint32_t> vertices;
  for (; v != v_end; ++v) vertices.insert(id(v));
  for (std::uint32_t i = 0; i < n; ++i) {
    if (!vertices.count(i)) out.hidden.insert(i);
  }
  for (; c != c_end; ++c) {
    std::vector<std::uint32_t> t;
    for (int k = 0; k < corners; ++k) t.push_back(id(c->vertex(k)));
    std::sort(t.begin(), t.end());
    out.simplices.insert(t);
  }
  return out;
}

Regular cgal_regular_2(const PointSet& ps, const std::vector<double>& w) {
  using Vb0 = CGAL::Regular_triangulation_vertex_base_2<K>;
  using Vb = CGAL::Triangulation_vertex_base_with_info_2<std::uint32_t, K, Vb0>;
  using Fb = CGAL::Regular_triangulation_face_base_2<K>;
  using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
  using RT = CGAL::Regular_triangulation_2<K, Tds>;
  std::vector<std::pair<K::Weighted_point_2, std::uint32_t>> points;
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    points.emplace_back(K::Weighted_point_2(K::Point_2(ps.point(i)[0], ps.point(i)[1]), w[i]), i);
  }
  const RT rt(points.begin(), points.end());
  return collect(ps.size(), rt.finite_vertices_begin(), rt.finite_vertices_end(), rt.finite_faces_begin(),
                 rt.finite_faces_end(), 3, [](const auto& h) { return h->info(); });
}

Regular cgal_regular_3(const PointSet& ps, const std::vector<double>& w) {
  using Vb0 = CGAL::Regular_triangulation_vertex_base_3<K>;
  using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::uint32_t, K, Vb0>;
  using Cb = CGAL::Regular_triangulation_cell_base_3<K>;
  using Tds = CGAL::Triangulation_data_structure_3<Vb, Cb>;
  using RT = CGAL::Regular_triangulation_3<K, Tds>;
  std::vector<std::pair<K::Weighted_point_3, std::uint32_t>> points;
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    const double* p = ps.point(i);
    points.emplace_back(K::Weighted_point_3(K::Point_3(p[0], p[1], p[2]), w[i]), i);
  }
  const RT rt(points.begin(), points.end());
  return collect(ps.size(), rt.finite_vertices_begin(), rt.finite_vertices_end(), rt.finite_cells_begin(),
                 rt.finite_cells_end(), 4, [](const auto& h) { return h->info(); });
}

Regular cgal_regular_dd(const PointSet& ps, const std::vector<double>& w) {
  using Kd = CGAL::Epick_d<CGAL::Dynamic_dimension_tag>;
  using Traits = CGAL::Regular_triangulation_traits_adapter<Kd>;
  using Vb = CGAL::Triangulation_vertex<Traits, std::uint32_t>;
  using Cb = CGAL::Triangulation_full_cell<Traits>;
  using Tds = CGAL::Triangulation_data_structure<CGAL::Dynamic_dimension_tag, Vb, Cb>;
  using RT = CGAL::Regular_triangulation<Kd, Tds>;
  const int d = ps.dimension();
  RT rt(d);
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    const auto v = rt.insert(RT::Weighted_point(Kd::Point_d(d, ps.point(i), ps.point(i) + d), w[i]));
    if (v != RT::Vertex_handle()) v->data() = i;  // a hidden point has no vertex
  }
  return collect(ps.size(), rt.finite_vertices_begin(), rt.finite_vertices_end(), rt.finite_full_cells_begin(),
                 rt.finite_full_cells_end(), d + 1, [](const auto& h) { return h->data(); });
}

// Every seed's star by one walker (no run caches): the simplices and the seeds whose
// star says hidden. Checks each star against itself: hidden exactly when empty.
Regular our_stars(const KdTree& tree, const std::vector<double>& w) {
  StarOptions options;
  options.weights = w;
  StarWalker walker(tree, options);
  Regular out;
  Star star;
  const int width = tree.points().dimension() + 1;
  for (std::uint32_t s = 0; s < tree.points().size(); ++s) {
    const Status st = walker.compute(s, star);
    EXPECT_TRUE(st.is_ok()) << "seed " << s << ": " << st.message();
    EXPECT_EQ(star.hidden, star.size() == 0) << "seed " << s;
    if (star.hidden) out.hidden.insert(s);
    for (const auto& t : as_set(star.simplices, width)) out.simplices.insert(t);
  }
  return out;
}

// The whole mesh of a weighted set with the run caches (two threads).
Simplices weighted_mesh(const KdTree& tree, const std::vector<double>& w, unsigned threads = 2) {
  MeshOptions options;
  options.threads = threads;
  options.star.weights = w;
  Simplices out;
  const auto r = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
    out.insert(out.end(), block.begin(), block.end());
    return Status::ok();
  });
  EXPECT_TRUE(r.is_ok()) << r.status().message();
  return out;
}

std::vector<double> uniform_weights(std::size_t n, double lo, double hi, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  std::vector<double> w(n);
  for (double& v : w) v = u(rng);
  return w;
}

struct Case {
  std::string name;
  int d;
  std::vector<double> coords, weights;
};

std::vector<Case> cgal_cases() {
  std::vector<Case> cases;
  // Weights about the squared spacing: some seeds outside their own cells, some hidden.
  cases.push_back({"small-2d", 2, uniform_points(2, 1500, 301), uniform_weights(1500, 0, 2e-4, 302)});
  cases.push_back({"large-2d", 2, uniform_points(2, 1500, 303), uniform_weights(1500, 0, 4e-3, 304)});
  cases.push_back({"signed-2d", 2, uniform_points(2, 800, 305), uniform_weights(800, -2e-3, 2e-3, 306)});
  cases.push_back({"small-3d", 3, uniform_points(3, 1200, 311), uniform_weights(1200, 0, 3e-3, 312)});
  cases.push_back({"large-3d", 3, uniform_points(3, 1200, 313), uniform_weights(1200, 0, 3e-2, 314)});
  cases.push_back({"signed-3d", 3, uniform_points(3, 600, 315), uniform_weights(600, -1e-2, 1e-2, 316)});
  // Grids: every sphere of the unweighted grid is degenerate (CGAL's perturbation),
  // and the weights hide some points; in 2-d, the weights of a binary mixture.
  cases.push_back({"grid-3d", 3, grid_points(3, 6), uniform_weights(216, 0, 0.6, 317)});
  // Small integer weights on a grid: exact ties everywhere, in the power tests and in
  // where seeds start (cells of no volume that only the perturbation keeps or hides).
  for (const int d : {2, 3}) {
    std::mt19937_64 rng(318 + d);
    std::uniform_int_distribution<int> wi(0, 3);
    Case grid{"integer-weights-grid-" + std::to_string(d) + "d", d, grid_points(d, d == 2 ? 20 : 7), {}};
    for (std::size_t i = 0; i < grid.coords.size() / d; ++i) grid.weights.push_back(wi(rng));
    cases.push_back(grid);
  }
  {
    // Weights 0..2 on an 8^3 grid: one seed's start met a cycling programme, another a
    // cell of no volume whose star lies past its 12 nearest points (both found by the
    // direct power cells' test, and fixed in power_start.cpp).
    std::mt19937_64 rng(403);
    Case grid{"integer-weights-grid-8-3d", 3, {}, {}};
    for (int i = 0; i < 8; ++i) {
      for (int j = 0; j < 8; ++j) {
        for (int k = 0; k < 8; ++k) {
          grid.coords.insert(grid.coords.end(), {double(i), double(j), double(k)});
          grid.weights.push_back(static_cast<double>(rng() % 3));
        }
      }
    }
    cases.push_back(grid);
  }
  {
    Case mixture{"binary-grid-2d", 2, grid_points(2, 12), {}};
    for (std::size_t i = 0; i < 144; ++i) mixture.weights.push_back(i % 3 == 0 ? 0.16 : 0.04);
    cases.push_back(mixture);
  }
  return cases;
}

TEST(Weighted, StarsEqualCgalRegularTriangulationsWithHiddenPoints) {
  for (const Case& c : cgal_cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Regular ours = our_stars(tree, c.weights);
    const Regular theirs = c.d == 2 ? cgal_regular_2(ps, c.weights) : cgal_regular_3(ps, c.weights);
    EXPECT_EQ(ours.hidden, theirs.hidden) << c.name << ": hidden points";
    if (c.name.starts_with("large")) {
      EXPECT_GT(theirs.hidden.size(), 10u) << "the case should hide points";
    }
    // The whole mesh (run caches, two threads) is the union of the stars.
    EXPECT_EQ(as_set(weighted_mesh(tree, c.weights), c.d + 1), ours.simplices) << c.name << ": whole mesh";
  }
}

TEST(Weighted, SeedsOutsideTheirOwnCellsAreMet) {
  // The cases above are only a test of the start's programme if seeds lie outside
  // their own power cells: count them (a point nearer in power to another site).
  const PointSet ps = make_points(3, uniform_points(3, 1200, 311));
  const auto w = uniform_weights(1200, 0, 3e-3, 312);
  int outside = 0;
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    for (std::uint32_t j = 0; j < ps.size(); ++j) {
      if (i == j) continue;
      double d2 = 0;
      for (int c = 0; c < 3; ++c) d2 += (ps.point(i)[c] - ps.point(j)[c]) * (ps.point(i)[c] - ps.point(j)[c]);
      if (d2 - w[j] < -w[i]) {
        ++outside;
        break;
      }
    }
  }
  EXPECT_GT(outside, 20);
}

TEST(Weighted, HigherDimensionalStarsEqualCgalAndExhaustiveSearch) {
  // 4-d to 6-d against CGAL's dD Regular_triangulation (weights large enough to hide
  // points), and a small 4-d set against exhaustive search over every 4-subset.
  for (const int d : {4, 5, 6}) {
    const std::size_t n = d == 4 ? 400 : d == 5 ? 200 : 80;
    const PointSet ps = make_points(d, uniform_points(d, n, 320 + d));
    const auto w = uniform_weights(n, 0, d == 4 ? 0.04 : d == 5 ? 0.3 : 0.6, 330 + d);
    const KdTree tree(ps);
    const Regular ours = our_stars(tree, w);
    const Regular theirs = cgal_regular_dd(ps, w);
    EXPECT_EQ(ours.hidden, theirs.hidden) << d << "-d: hidden points";
    EXPECT_EQ(ours.simplices, theirs.simplices) << d << "-d: simplices";
    EXPECT_GT(theirs.hidden.size(), 0u) << d << "-d: the weights should hide some points";
    EXPECT_EQ(as_set(weighted_mesh(tree, w), d + 1), ours.simplices) << d << "-d: whole mesh";
  }
  const std::size_t n = 30;
  const PointSet ps = make_points(4, uniform_points(4, n, 324));
  const auto w = uniform_weights(n, 0, 0.3, 334);
  const KdTree tree(ps);
  StarOptions options;
  options.weights = w;
  StarWalker walker(tree, options);
  Star star;
  for (std::uint32_t s = 0; s < n; ++s) {
    ASSERT_TRUE(walker.compute(s, star).is_ok());
    EXPECT_EQ(as_set(star.simplices, 5), brute_force_star(ps, s, w)) << "4-d seed " << s;
  }
}

TEST(Weighted, EqualWeightsGiveTheDelaunayMesh) {
  for (const int d : {2, 3, 4}) {
    for (const bool grid : {false, true}) {
      const PointSet ps = make_points(d, grid ? grid_points(d, d == 4 ? 4 : 6) : uniform_points(d, 500, 340 + d));
      const KdTree tree(ps);
      const std::vector<double> w(ps.size(), 0.25);
      EXPECT_EQ(weighted_mesh(tree, w), mesh_all(tree, 2)) << d << "-d " << (grid ? "grid" : "uniform");
    }
  }
}

TEST(Weighted, PermutedInputGivesTheSameMesh) {
  // Uniform points, and a grid with integer weights (every tie decided by the
  // perturbation, which follows the points' lexicographic order, not their indices).
  for (const int d : {2, 3}) {
    for (const bool grid : {false, true}) {
      const auto coords = grid ? grid_points(d, d == 2 ? 16 : 6) : uniform_points(d, 600, 350 + d);
      const std::size_t n = coords.size() / static_cast<std::size_t>(d);
      std::vector<double> w = uniform_weights(n, 0, d == 2 ? 4e-3 : 3e-2, 360 + d);
      if (grid) {
        for (double& v : w) v = std::floor(v * 4 / (d == 2 ? 4e-3 : 3e-2));  // 0 .. 3
      }
      std::vector<std::uint32_t> perm(n);
      std::iota(perm.begin(), perm.end(), 0u);
      std::shuffle(perm.begin(), perm.end(), std::mt19937_64(370 + d));
      std::vector<double> pc, pw;
      for (const std::uint32_t i : perm) {
        pc.insert(pc.end(), coords.begin() + i * d, coords.begin() + (i + 1) * d);
        pw.push_back(w[i]);
      }
      const PointSet a = make_points(d, coords), b = make_points(d, pc);
      const KdTree ta(a), tb(b);
      Tuples mapped;
      for (const auto& t : as_set(weighted_mesh(tb, pw), d + 1)) {
        std::vector<std::uint32_t> u;
        for (const std::uint32_t v : t) u.push_back(perm[v]);
        std::sort(u.begin(), u.end());
        mapped.insert(u);
      }
      EXPECT_EQ(mapped, as_set(weighted_mesh(ta, w), d + 1)) << d << "-d " << (grid ? "grid" : "uniform");
    }
  }
}

// Power cells through compute_cells: clipped to the unit box they tile it (volumes
// sum to 1 within 1e-12), hidden seeds' cells are empty and said so, the facets pair
// up (i lists j iff j lists i, with equal areas), and equal weights give the Voronoi
// cells. Voro++'s -r is the peer in tests/python/test_cells.py (3-d).
TEST(Weighted, PowerCellsTileTheBoxInEveryDimension) {
  for (const int d : {2, 3, 4}) {
    const std::size_t n = d == 2 ? 2000 : d == 3 ? 1000 : 300;
    const PointSet ps = make_points(d, uniform_points(d, n, 380 + d));
    const KdTree tree(ps);
    const Domain box = Domain::box(std::vector<double>(d, 0.0), std::vector<double>(d, 1.0)).value();
    for (const bool equal : {false, true}) {
      const auto w = equal ? std::vector<double>(n, 0.3)
                           : uniform_weights(n, 0,
                                             d == 2   ? 4e-3
                                             : d == 3 ? 2e-2
                                                      : 0.05,
                                             390 + d);
      std::vector<VoronoiCell> cells;
      for (const bool weighted : {true, false}) {
        if (!weighted && !equal) continue;
        CellsOptions options;
        options.threads = 2;
        if (weighted) options.star.weights = w;
        std::vector<VoronoiCell> got;
        const Status s = compute_cells(tree, &box, options, [&](std::span<const VoronoiCell> part, std::uint64_t) {
          got.insert(got.end(), part.begin(), part.end());
          return Status::ok();
        });
        ASSERT_TRUE(s.is_ok()) << s.message();
        ASSERT_EQ(got.size(), n);
        if (!weighted) {  // equal weights against the plain cells
          for (std::size_t i = 0; i < n; ++i) {
            EXPECT_NEAR(got[i].volume, cells[i].volume, 1e-12) << d << "-d cell " << i;
            ASSERT_EQ(got[i].facets.size(), cells[i].facets.size()) << d << "-d cell " << i;
            for (std::size_t f = 0; f < got[i].facets.size(); ++f) {
              EXPECT_EQ(got[i].facets[f].neighbor, cells[i].facets[f].neighbor);
            }
          }
          continue;
        }
        cells = std::move(got);
      }
      double total = 0;
      std::size_t hidden = 0;
      std::map<std::pair<std::int64_t, std::int64_t>, double> areas;
      for (const VoronoiCell& c : cells) {
        total += c.volume;
        if (c.hidden) {
          ++hidden;
          EXPECT_EQ(c.volume, 0);
          EXPECT_TRUE(c.facets.empty());
        }
        for (const VoronoiFacet& f : c.facets) {
          if (!f.is_wall()) areas[{c.seed, f.neighbor}] = f.area;
        }
      }
      EXPECT_NEAR(total, 1.0, 1e-12) << d << "-d";
      for (const auto& [key, area] : areas) {
        const auto back = areas.find({key.second, key.first});
        ASSERT_NE(back, areas.end()) << d << "-d facet " << key.first << "-" << key.second << " has no partner";
        EXPECT_NEAR(area, back->second, 1e-11) << d << "-d facet " << key.first << "-" << key.second;
      }
      if (!equal) {
        EXPECT_GT(hidden, 0u) << d << "-d: the weights should hide some points";
      }
    }
  }
}

// The 3-d direct route (a box clipped by power bisectors, BoxCell3d) against the star
// route: the same facets (neighbours and walls), volumes, centroids and hidden seeds,
// for weights that hide many points and put seeds outside their own cells, and for a
// grid with integer weights (exact ties everywhere: those seeds go to the star).
TEST(Weighted, PowerCellsBuiltDirectlyEqualTheStarsCells) {
  struct WeightedCase {
    std::string name;
    std::vector<double> coords, weights;
  };
  std::vector<WeightedCase> cases;
  for (const double spread : {2e-2, 0.2}) {
    cases.push_back({"uniform, spread " + std::to_string(spread), uniform_points(3, 1500, 401),
                     uniform_weights(1500, 0, spread, 402)});
  }
  {
    WeightedCase grid{"integer grid, integer weights", {}, {}};
    std::mt19937_64 rng(403);
    for (int i = 0; i < 7; ++i) {
      for (int j = 0; j < 7; ++j) {
        for (int k = 0; k < 7; ++k) {
          grid.coords.insert(grid.coords.end(), {double(i), double(j), double(k)});
          grid.weights.push_back(static_cast<double>(rng() % 3));
        }
      }
    }
    cases.push_back(std::move(grid));
  }
  for (const WeightedCase& c : cases) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(3, c.coords);
    const KdTree tree(ps);
    const Domain box = Domain::bounding_box(ps);
    StarOptions options;
    options.weights = c.weights;
    ClippedCellBuilder direct(tree, box, options, CellRoute::kDirect);
    ClippedCellBuilder star(tree, box, options, CellRoute::kStar);
    std::size_t hidden = 0;
    double total = 0;
    for (std::uint32_t s = 0; s < ps.size(); ++s) {
      SCOPED_TRACE("seed " + std::to_string(s));
      auto a = direct.cell(s);
      auto b = star.cell(s);
      ASSERT_TRUE(a.is_ok() && b.is_ok());
      EXPECT_EQ(a->hidden, b->hidden);
      hidden += b->hidden ? 1 : 0;
      total += a->volume;
      EXPECT_NEAR(a->volume, b->volume, 1e-12 * std::max(1.0, b->volume));
      ASSERT_EQ(a->facets.size(), b->facets.size());
      for (std::size_t f = 0; f < a->facets.size(); ++f) {
        EXPECT_EQ(a->facets[f].neighbor, b->facets[f].neighbor);
        EXPECT_NEAR(a->facets[f].area, b->facets[f].area, 1e-9 * std::max(1.0, b->facets[f].area));
      }
      ASSERT_EQ(a->centroid.size(), b->centroid.size());
      for (std::size_t k = 0; k < a->centroid.size(); ++k) EXPECT_NEAR(a->centroid[k], b->centroid[k], 1e-9);
    }
    const std::vector<double> lo = box.lower(), hi = box.upper();
    EXPECT_NEAR(total, (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]), 1e-9);
    // A whole run in small rounds: every cell exactly the single builder's (the route
    // is a function of the set and the seed, not of the run), and the star's to rounding.
    CellsOptions run;
    run.threads = 2;
    run.block_size = 64;
    run.star.weights = c.weights;
    std::vector<VoronoiCell> got;
    ASSERT_TRUE(compute_cells(tree, &box, run, [&](std::span<const VoronoiCell> part, std::uint64_t) {
                  got.insert(got.end(), part.begin(), part.end());
                  return Status::ok();
                }).is_ok());
    ASSERT_EQ(got.size(), ps.size());
    ClippedCellBuilder single(tree, box, options);
    for (std::uint32_t s = 0; s < ps.size(); ++s) {
      const VoronoiCell same = single.cell(s).value();
      EXPECT_EQ(got[s].volume, same.volume) << "run, seed " << s;
      EXPECT_EQ(got[s].vertices, same.vertices) << "run, seed " << s;
      const VoronoiCell want = star.cell(s).value();
      EXPECT_EQ(got[s].hidden, want.hidden) << "run, seed " << s;
      EXPECT_NEAR(got[s].volume, want.volume, 1e-12 * std::max(1.0, want.volume)) << "run, seed " << s;
      EXPECT_EQ(got[s].facets.size(), want.facets.size()) << "run, seed " << s;
    }
    // Off the grid, most cells were built directly (hidden ones go to the star, which
    // says so); on it, every cell meets a tie and goes to the star.
    if (c.name.rfind("uniform", 0) == 0) {
      EXPECT_LT(direct.star_fallbacks(), hidden + ps.size() / 5) << direct.star_fallbacks() << " of " << ps.size();
    }
    std::printf("[ info ] %s: %zu hidden, %llu of %zu cells from stars\n", c.name.c_str(), hidden,
                static_cast<unsigned long long>(direct.star_fallbacks()), ps.size());
  }
}

}  // namespace
}  // namespace spokemesh
