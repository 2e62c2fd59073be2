// Approximate Delaunay neighbours (ApproxWalker, delaunay_graph): precision is 1 always
// (against exact stars in low d, and against the LP oracle in high d), recall is 1 on
// small 2-d/3-d inputs with a generous budget, and answers do not depend on threads.
#include <atomic>
#include <cmath>
#include <random>
#include <set>

#include "lp_oracle.hpp"
#include "spokemesh/approx.hpp"
#include "spokemesh/graph.hpp"
#include "spokemesh/voronoi.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using testing::grid_points;
using testing::lp_delaunay_neighbors;
using testing::uniform_points;

struct Set {
  PointSet points;
  std::unique_ptr<KdTree> tree;
  Set(int d, std::vector<double> coords) : points(d, std::move(coords)) {
    const Status s = points.validate("test", kMaxApproxDimension, d <= kMaxDimension);
    EXPECT_TRUE(s.is_ok()) << s.message();
    tree = std::make_unique<KdTree>(points);
  }
};

std::vector<std::uint32_t> exact_neighbors(const KdTree& tree, std::uint32_t seed) {
  StarWalker walker(tree);
  Star star;
  EXPECT_TRUE(walker.compute(seed, star).is_ok());
  return star_neighbors(star);
}

bool subset(const std::vector<std::uint32_t>& a, const std::vector<std::uint32_t>& b) {
  return std::includes(b.begin(), b.end(), a.begin(), a.end());
}

TEST(LpOracle, AgreesWithExactStars) {
  const auto c = uniform_points(3, 150, 1);
  Set s(3, c);
  for (std::uint32_t seed : {0u, 7u, 42u, 149u}) {
    EXPECT_EQ(lp_delaunay_neighbors(c, 3, seed), exact_neighbors(*s.tree, seed)) << "seed " << seed;
  }
}

TEST(Approx, RecallOneAndPrecisionOneIn2dAnd3d) {
  for (int d : {2, 3}) {
    Set s(d, uniform_points(d, 600, 10 + d));
    for (auto mode : {ApproxOptions::Mode::kRsd}) {
      ApproxOptions o;
      o.mode = mode;
      o.max_misses = 1000;
      ApproxWalker walker(*s.tree, o);
      for (std::uint32_t seed = 0; seed < 600; seed += 7) {
        ApproxNeighbors a;
        ASSERT_TRUE(walker.compute(seed, a).is_ok());
        EXPECT_EQ(a.neighbors, exact_neighbors(*s.tree, seed))
            << "d=" << d << " seed " << seed << " (points seed " << 10 + d << ")";
        EXPECT_EQ(a.uncertified, 0u);
      }
    }
  }
}

// walk_exhausted means complete: whenever it is set, the neighbours are the exact set
// (a 2-d grid's seed 143 with 50 misses claimed it with a neighbour missing).
TEST(Approx, ExhaustedMeansEveryNeighbourWasFound) {
  struct Input {
    const char* name;
    int d;
    std::vector<double> coords;
  };
  const std::vector<Input> inputs = {{"grid 12x12", 2, grid_points(2, 12)},
                                     {"grid 6^3", 3, grid_points(3, 6)},
                                     {"uniform 2-d", 2, uniform_points(2, 300, 5)},
                                     {"uniform 4-d", 4, uniform_points(4, 200, 6)}};
  for (const Input& in : inputs) {
    Set s(in.d, in.coords);
    int exhausted = 0;
    for (const std::uint32_t misses : {5u, 20u, 50u, 1000u}) {
      ApproxOptions o;
      o.max_misses = misses;
      ApproxWalker walker(*s.tree, o);
      for (std::uint32_t seed = 0; seed < s.points.size(); ++seed) {
        ApproxNeighbors a;
        ASSERT_TRUE(walker.compute(seed, a).is_ok());
        if (!a.exhausted) continue;
        ++exhausted;
        // Complete: every neighbour whose Voronoi facet has positive measure is found.
        // Neighbours across facets of measure zero (grid diagonals: which of two ties
        // the exact mesh takes is its symbolic perturbation's choice) may or may not be.
        StarWalker star_walker(*s.tree);
        Star star;
        ASSERT_TRUE(star_walker.compute(seed, star).is_ok());
        // Clipped to a box far around the points, so unbounded facets have finite
        // areas (a degenerate one, a ray between grid diagonals, has area 0).
        std::vector<double> lo(in.d, -10.0), hi(in.d, 20.0);
        const VoronoiCell cell = voronoi_cell(s.points, star, Domain::box(lo, hi).value()).value();
        std::vector<std::uint32_t> needed;
        for (const VoronoiFacet& f : cell.facets) {
          if (!f.is_wall() && f.area > 1e-9) needed.push_back(static_cast<std::uint32_t>(f.neighbor));
        }
        EXPECT_TRUE(subset(needed, a.neighbors)) << in.name << ", seed " << seed << ", misses " << misses;
        EXPECT_TRUE(subset(a.neighbors, exact_neighbors(*s.tree, seed))) << in.name << ", seed " << seed;
      }
    }
    EXPECT_GT(exhausted, 0) << in.name;
  }
}

// A cell with more neighbours than the walk lists at first (512 d = 1,536 in 3-d):
// x at the centre of 2,000 points on a sphere, every one of which is a neighbour, and
// 1,000 farther points, none of which is. The walk lists more as it finds them.
TEST(Approx, CellsWithMoreNeighboursThanTheListAreWalkedWhole) {
  std::vector<double> c = {0, 0, 0};
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> next(0, 1);
  for (int i = 0; i < 3000; ++i) {
    double p[3], r2 = 0;
    do {
      r2 = 0;
      for (double& v : p) {
        v = 2 * next(rng) - 1;
        r2 += v * v;
      }
    } while (r2 > 1 || r2 < 1e-3);
    const double scale = (i < 2000 ? 1.0 : 3.0 + next(rng)) / std::sqrt(r2);
    for (double v : p) c.push_back(v * scale);
  }
  Set s(3, c);
  const auto truth = exact_neighbors(*s.tree, 0);
  ASSERT_EQ(truth.size(), 2000u);
  ApproxOptions o;
  o.max_misses = 100;
  ApproxWalker walker(*s.tree, o);
  ApproxNeighbors a;
  ASSERT_TRUE(walker.compute(0, a).is_ok());
  EXPECT_EQ(a.neighbors, truth);
}

// Points near a curved 2-d surface in 10-d, whose cells are long and have most of their
// facets far from the first vertex: precision 1 and recall 0.99 against the LP oracle
// at the default budget.
TEST(Approx, NearAManifoldRecallIsHighAtTheDefaultBudget) {
  const int D = 10;
  const std::size_t n = 500;  // the LP oracle takes about a second here
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> freq(2 * D), phase(D), c;
  for (double& v : freq) v = 2 * g(rng);
  for (double& v : phase) v = 6.283185307179586 * u(rng);
  for (std::size_t i = 0; i < n; ++i) {
    const double a = u(rng), b = u(rng);
    for (int j = 0; j < D; ++j) c.push_back(std::sin(phase[j] + freq[2 * j] * a + freq[2 * j + 1] * b) + 0.01 * g(rng));
  }
  Set s(D, c);
  ApproxWalker walker(*s.tree, ApproxOptions{});
  std::size_t found = 0, total = 0;
  for (std::uint32_t seed : {0u, 123u, 321u, 499u}) {
    const auto truth = lp_delaunay_neighbors(c, D, seed);
    ApproxNeighbors a;
    ASSERT_TRUE(walker.compute(seed, a).is_ok());
    EXPECT_TRUE(subset(a.neighbors, truth)) << "seed " << seed << " (points seed 5)";
    found += a.neighbors.size();
    total += truth.size();
  }
  EXPECT_GE(static_cast<double>(found), 0.99 * static_cast<double>(total)) << found << " of " << total;
}

TEST(Approx, PrecisionOneOnGridsWithTies) {
  // Cospherical everywhere: walks meet ties, certification must still never accept a
  // non-edge (exact neighbours here are those of the perturbed triangulation).
  for (int d : {2, 3}) {
    Set s(d, grid_points(d, d == 2 ? 9 : 5));
    for (auto mode : {ApproxOptions::Mode::kRsd, ApproxOptions::Mode::kSpokes}) {
      ApproxOptions o;
      o.mode = mode;
      o.max_misses = 200;
      ApproxWalker walker(*s.tree, o);
      for (std::uint32_t seed = 0; seed < s.points.size(); seed += 3) {
        ApproxNeighbors a;
        ASSERT_TRUE(walker.compute(seed, a).is_ok());
        EXPECT_TRUE(subset(a.neighbors, exact_neighbors(*s.tree, seed))) << "d=" << d << " seed " << seed;
        EXPECT_GE(a.neighbors.size(), 1u) << "d=" << d << " seed " << seed;
      }
    }
  }
}

TEST(Approx, PrecisionOneInHighDimensionsAgainstTheLpOracle) {
  for (int d : {5, 8, 12}) {
    const std::size_t n = 160;
    const auto c = uniform_points(d, n, 20 + d);
    Set s(d, c);
    for (std::uint32_t seed : {0u, 77u}) {
      const auto truth = lp_delaunay_neighbors(c, d, seed);
      for (auto mode : {ApproxOptions::Mode::kRsd, ApproxOptions::Mode::kSpokes}) {
        ApproxOptions o;
        o.mode = mode;
        o.max_misses = 100;
        ApproxWalker walker(*s.tree, o);
        ApproxNeighbors a;
        ASSERT_TRUE(walker.compute(seed, a).is_ok());
        EXPECT_TRUE(subset(a.neighbors, truth))
            << "d=" << d << " seed " << seed << " mode " << static_cast<int>(mode) << " (points seed " << 20 + d << ")";
        EXPECT_FALSE(a.neighbors.empty());
        RecordProperty("recall_d" + std::to_string(d) + "_seed" + std::to_string(seed) + "_mode" +
                           std::to_string(static_cast<int>(mode)),
                       std::to_string(double(a.neighbors.size()) / double(truth.size())));
      }
    }
  }
}

TEST(Approx, PointsInALowerDimensionalSubspaceStillGetCertifiedNeighbours) {
  // 4-d data placed exactly in a 4-d coordinate subspace of R^10 (the other coordinates
  // are 0, so the embedding is exact and isometric): Voronoi cells have no vertices,
  // only facets, and the Delaunay neighbours are those of the 4-d points. RSD falls back
  // on its spokes' facet witnesses; nothing uncertified is reported. (A subspace reached
  // through a rounded linear map is not exact: the points then span R^10 by tiny
  // amounts, and far witnesses certify edges that the idealised data would not have.)
  const int d = 10, k = 4;
  const std::size_t n = 120;
  const auto low = uniform_points(k, n, 81);
  const int axes[k] = {7, 2, 9, 4};
  std::vector<double> c(n * d, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    for (int t = 0; t < k; ++t) c[i * d + axes[t]] = low[i * k + t];
  }
  Set s(d, c);
  Set flat(k, low);
  ApproxOptions o;
  o.max_misses = 40;
  ApproxWalker walker(*s.tree, o);
  for (std::uint32_t seed : {3u, 50u}) {
    ApproxNeighbors a;
    ASSERT_TRUE(walker.compute(seed, a).is_ok());
    EXPECT_GE(a.neighbors.size(), 3u) << "seed " << seed;
    EXPECT_TRUE(subset(a.neighbors, exact_neighbors(*flat.tree, seed))) << "seed " << seed;
  }
}

TEST(Approx, RsdBeatsPlainSpokesForTheSameBudget) {
  Set s(6, uniform_points(6, 1500, 31));
  std::size_t rsd = 0, spokes = 0;
  for (auto mode : {ApproxOptions::Mode::kRsd, ApproxOptions::Mode::kSpokes}) {
    ApproxOptions o;
    o.mode = mode;
    o.max_misses = 10;
    ApproxWalker walker(*s.tree, o);
    for (std::uint32_t seed = 0; seed < 10; ++seed) {
      ApproxNeighbors a;
      ASSERT_TRUE(walker.compute(seed, a).is_ok());
      (mode == ApproxOptions::Mode::kRsd ? rsd : spokes) += a.neighbors.size();
    }
  }
  EXPECT_GT(rsd, spokes);
}

TEST(Graph, ExactGraphIsTheMeshEdgesAndApproximateIsASubsetForAnyThreads) {
  Set s(4, uniform_points(4, 400, 41));
  GraphOptions exact;
  auto g1 = delaunay_graph(*s.tree, exact);
  ASSERT_TRUE(g1.is_ok());
  std::set<std::pair<std::uint32_t, std::uint32_t>> mesh_edges;
  ASSERT_TRUE(mesh_seeds(*s.tree, {}, [&](std::span<const std::uint32_t> b, std::uint64_t) {
                for (std::size_t i = 0; i < b.size(); i += 5) {
                  for (int p = 0; p < 5; ++p) {
                    for (int q = p + 1; q < 5; ++q) mesh_edges.emplace(std::minmax(b[i + p], b[i + q]));
                  }
                }
                return Status::ok();
              }).is_ok());
  EXPECT_EQ(Edges(mesh_edges.begin(), mesh_edges.end()), g1.value());
  GraphOptions approx;
  approx.approximate = true;
  approx.approx.max_misses = 30;
  auto a1 = delaunay_graph(*s.tree, approx);
  approx.threads = 3;
  auto a3 = delaunay_graph(*s.tree, approx);
  ASSERT_TRUE(a1.is_ok() && a3.is_ok());
  EXPECT_EQ(a1.value(), a3.value());
  for (const auto& e : a1.value()) EXPECT_TRUE(mesh_edges.count(e)) << e.first << " " << e.second;
  EXPECT_GT(a1->size() * 10, g1->size() * 9);
}

TEST(Graph, ExactRefusesHighDimensionsAndPointsToApproximate) {
  Set s(10, uniform_points(10, 50, 51));
  auto g = delaunay_graph(*s.tree, GraphOptions{});
  EXPECT_EQ(g.status().code(), Code::kInvalidArgument);
  EXPECT_NE(g.status().message().find("approximate"), std::string::npos);
}

TEST(Approx, DeterministicAndCancellable) {
  Set s(7, uniform_points(7, 800, 61));
  ApproxWalker a(*s.tree, {}), b(*s.tree, {});
  ApproxNeighbors x, y;
  ASSERT_TRUE(a.compute(5, x).is_ok());
  ASSERT_TRUE(b.compute(9, y).is_ok());
  ASSERT_TRUE(b.compute(5, y).is_ok());  // a walker's history does not matter
  EXPECT_EQ(x.neighbors, y.neighbors);
  EXPECT_EQ(x.vertices, y.vertices);
  std::atomic<bool> stop{true};
  ApproxOptions o;
  o.cancel = &stop;
  ApproxWalker c(*s.tree, o);
  EXPECT_EQ(c.compute(5, x).code(), Code::kCancelled);
  EXPECT_EQ(c.compute(800, x).code(), Code::kOutOfRange);
}

}  // namespace
}  // namespace spokemesh
