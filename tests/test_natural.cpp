// Natural neighbours and Sibson coordinates (core/include/spokemesh/natural_neighbors.hpp)
// against CGAL's natural_neighbor_coordinates_2 and sibson_natural_neighbor_coordinates_3
// on the same points: the same neighbours, weights within 1e-12; and the properties
// (non-negative, summing to 1, reproducing linear functions) on grids, where the
// in-sphere tests meet exact ties. Seeds are fixed and printed.
#include <gtest/gtest.h>

#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/natural_neighbor_coordinates_2.h>
#include <CGAL/natural_neighbor_coordinates_3.h>

#include <Eigen/Dense>
#include <map>
#include <random>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/natural_neighbors.hpp"
#include "spokemesh/point_queries.hpp"
#include "spokemesh/voronoi_diagram.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using testing::make_points;
using testing::mesh_all;

struct Mesh {
  PointSet points;
  std::vector<std::uint32_t> simplices;
  std::vector<std::int32_t> adjacency;
  DelaunayArrays arrays() const { return {&points, simplices, adjacency}; }
};

Mesh mesh_of(int d, std::vector<double> coords) {
  Mesh m{make_points(d, std::move(coords)), {}, {}};
  KdTree tree(m.points);
  m.simplices = mesh_all(tree);
  m.adjacency = simplex_adjacency(m.simplices, d);
  return m;
}

// The simplex holding q, by barycentric coordinates in double (queries here are never
// near a face).
std::int32_t containing(const Mesh& m, const double* q) {
  const int d = m.points.dimension(), w = d + 1;
  for (std::size_t s = 0; s * w < m.simplices.size(); ++s) {
    Eigen::MatrixXd a(d, d);
    Eigen::VectorXd r(d);
    const double* p0 = m.points.point(m.simplices[s * w]);
    for (int j = 0; j < d; ++j) {
      for (int k = 0; k < d; ++k) a(k, j) = m.points.point(m.simplices[s * w + j + 1])[k] - p0[k];
      r(j) = q[j] - p0[j];
    }
    const Eigen::VectorXd x = a.partialPivLu().solve(r);
    if (x.minCoeff() >= -1e-12 && x.sum() <= 1 + 1e-12) return static_cast<std::int32_t>(s);
  }
  return -1;
}

std::vector<double> random_coords(std::size_t n, int d, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> c(n * d);
  for (double& x : c) x = u(rng);
  return c;
}

void expect_sibson_properties(const Mesh& m, const NaturalCoordinates& nn, const double* q, const std::string& what) {
  const int d = m.points.dimension();
  double sum = 0;
  std::vector<double> centre(d, 0.0);
  for (std::size_t i = 0; i < nn.neighbors.size(); ++i) {
    EXPECT_GE(nn.weights[i], 0.0) << what;
    sum += nn.weights[i];
    for (int k = 0; k < d; ++k) centre[k] += nn.weights[i] * m.points.point(nn.neighbors[i])[k];
  }
  EXPECT_NEAR(sum, 1.0, 1e-12) << what;
  for (int k = 0; k < d; ++k) EXPECT_NEAR(centre[k], q[k], 1e-12) << what << " coordinate " << k;
}

TEST(NaturalNeighbors, EqualCgalsIn2d) {
  const std::uint64_t seed = 2026120601;
  const std::vector<double> c = random_coords(2000, 2, seed);
  const Mesh m = mesh_of(2, c);
  CGAL::Delaunay_triangulation_2<K> dt;
  std::map<std::pair<double, double>, std::uint32_t> id;
  for (std::uint32_t i = 0; i < 2000; ++i) {
    dt.insert(K::Point_2(c[2 * i], c[2 * i + 1]));
    id[{c[2 * i], c[2 * i + 1]}] = i;
  }
  std::mt19937_64 rng(seed + 1);
  std::uniform_real_distribution<double> u(0.1, 0.9);
  for (int t = 0; t < 200; ++t) {
    const double q[2] = {u(rng), u(rng)};
    auto ours = natural_neighbors(m.arrays(), containing(m, q), q);
    ASSERT_TRUE(ours.is_ok()) << ours.status().message();
    ASSERT_EQ(ours.value().where, NaturalCoordinates::Where::kInside);
    std::vector<std::pair<K::Point_2, K::FT>> theirs;
    auto r = CGAL::natural_neighbor_coordinates_2(dt, K::Point_2(q[0], q[1]), std::back_inserter(theirs));
    ASSERT_TRUE(r.third);
    std::map<std::uint32_t, double> expected;
    for (const auto& [p, w] : theirs) expected[id.at({p.x(), p.y()})] = w / r.second;
    const std::string what = "seed " + std::to_string(seed) + " query " + std::to_string(t);
    ASSERT_EQ(ours.value().neighbors.size(), expected.size()) << what;
    for (std::size_t i = 0; i < ours.value().neighbors.size(); ++i) {
      ASSERT_TRUE(expected.count(ours.value().neighbors[i])) << what;
      EXPECT_NEAR(ours.value().weights[i], expected[ours.value().neighbors[i]], 1e-12) << what;
    }
    expect_sibson_properties(m, ours.value(), q, what);
  }
}

TEST(NaturalNeighbors, EqualCgalsIn3d) {
  const std::uint64_t seed = 2026120602;
  const std::vector<double> c = random_coords(3000, 3, seed);
  const Mesh m = mesh_of(3, c);
  CGAL::Delaunay_triangulation_3<K> dt;
  std::map<std::array<double, 3>, std::uint32_t> id;
  for (std::uint32_t i = 0; i < 3000; ++i) {
    dt.insert(K::Point_3(c[3 * i], c[3 * i + 1], c[3 * i + 2]));
    id[{c[3 * i], c[3 * i + 1], c[3 * i + 2]}] = i;
  }
  std::mt19937_64 rng(seed + 1);
  std::uniform_real_distribution<double> u(0.15, 0.85);
  for (int t = 0; t < 100; ++t) {
    const double q[3] = {u(rng), u(rng), u(rng)};
    auto ours = natural_neighbors(m.arrays(), containing(m, q), q);
    ASSERT_TRUE(ours.is_ok()) << ours.status().message();
    std::vector<std::pair<CGAL::Delaunay_triangulation_3<K>::Vertex_handle, K::FT>> theirs;
    K::FT norm;
    auto r =
        CGAL::sibson_natural_neighbor_coordinates_3(dt, K::Point_3(q[0], q[1], q[2]), std::back_inserter(theirs), norm);
    ASSERT_TRUE(r.third);
    std::map<std::uint32_t, double> expected;
    for (const auto& [v, w] : theirs) {
      if (w > 0) expected[id.at({v->point().x(), v->point().y(), v->point().z()})] = w / norm;
    }
    const std::string what = "seed " + std::to_string(seed) + " query " + std::to_string(t);
    std::size_t positive = 0;
    for (std::size_t i = 0; i < ours.value().neighbors.size(); ++i) {
      const auto e = expected.find(ours.value().neighbors[i]);
      const double want = e == expected.end() ? 0.0 : e->second;
      EXPECT_NEAR(ours.value().weights[i], want, 1e-12) << what << " neighbour " << ours.value().neighbors[i];
      positive += ours.value().weights[i] > 0;
    }
    EXPECT_EQ(positive, expected.size()) << what;
    expect_sibson_properties(m, ours.value(), q, what);
  }
}

TEST(NaturalNeighbors, GridsDataPointsHullAndOutside) {
  // A 5 x 5 grid: every square's four corners are cocircular (exact ties).
  std::vector<double> c;
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 5; ++j) c.insert(c.end(), {double(i), double(j)});
  }
  const Mesh m = mesh_of(2, c);
  const double centre[2] = {1.5, 2.5};  // a square's centre: its four corners, a quarter each
  auto nn = natural_neighbors(m.arrays(), containing(m, centre), centre);
  ASSERT_TRUE(nn.is_ok());
  ASSERT_EQ(nn.value().neighbors.size(), 4u);
  for (double w : nn.value().weights) EXPECT_NEAR(w, 0.25, 1e-14);
  const double on_point[2] = {2.0, 3.0};
  nn = natural_neighbors(m.arrays(), containing(m, on_point), on_point);
  ASSERT_TRUE(nn.is_ok());
  EXPECT_EQ(nn.value().neighbors, (std::vector<std::uint32_t>{13}));
  const double on_hull[2] = {0.0, 1.25};  // on the hull's left edge: linear along it
  nn = natural_neighbors(m.arrays(), containing(m, on_hull), on_hull);
  ASSERT_TRUE(nn.is_ok());
  EXPECT_EQ(nn.value().where, NaturalCoordinates::Where::kOnHull);
  expect_sibson_properties(m, nn.value(), on_hull, "on the hull");
  nn = natural_neighbors(m.arrays(), -1, on_hull);
  ASSERT_TRUE(nn.is_ok());
  EXPECT_EQ(nn.value().where, NaturalCoordinates::Where::kOutside);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.05, 3.95);
  for (int t = 0; t < 300; ++t) {
    const double q[2] = {u(rng), std::round(u(rng) * 2) / 2};  // many on grid lines
    nn = natural_neighbors(m.arrays(), containing(m, q), q);
    ASSERT_TRUE(nn.is_ok());
    expect_sibson_properties(m, nn.value(), q, "grid query " + std::to_string(t));
  }
}

TEST(NaturalNeighbors, Grids3dEveryStartSameBits) {
  // A 4 x 4 x 4 grid: every cube's corners are cospherical, and many bisectors meet in
  // one old Voronoi vertex. Sibson's coordinates keep their properties there, and the
  // answer is the same bits from every simplex holding q (point_queries' promise).
  std::vector<double> c;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      for (int k = 0; k < 4; ++k) c.insert(c.end(), {double(i), double(j), double(k)});
    }
  }
  const Mesh m = mesh_of(3, c);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.05, 2.95);
  for (int t = 0; t < 200; ++t) {
    // Half of them on grid planes (shared faces and edges).
    double q[3] = {u(rng), u(rng), t % 2 == 0 ? std::round(u(rng) * 2) / 2 : u(rng)};
    const std::string what = "grid query " + std::to_string(t) + " (seed 11)";
    std::vector<std::int32_t> holding;
    for (std::size_t s = 0; s * 4 < m.simplices.size(); ++s) {
      std::array<double, kMaxDimension + 1> b{};
      barycentric_coordinates(m.points, &m.simplices[s * 4], q, b.data());
      if (*std::min_element(b.begin(), b.begin() + 4) >= -1e-12) holding.push_back(static_cast<std::int32_t>(s));
    }
    ASSERT_FALSE(holding.empty()) << what;
    auto first = natural_neighbors(m.arrays(), holding[0], q);
    ASSERT_TRUE(first.is_ok()) << what;
    expect_sibson_properties(m, first.value(), q, what);
    const std::int32_t canonical = canonical_simplex(m.arrays(), holding[0], q);
    for (const std::int32_t s : holding) {
      EXPECT_EQ(canonical_simplex(m.arrays(), s, q), canonical) << what;
      auto other = natural_neighbors(m.arrays(), s, q);
      ASSERT_TRUE(other.is_ok()) << what;
      EXPECT_EQ(other->neighbors, first->neighbors) << what;
      EXPECT_EQ(other->weights, first->weights) << what;  // bit for bit
    }
  }
}

TEST(NaturalNeighbors, InSphereIsExact) {
  // The unit square's fourth corner lies on the circle through the other three; points
  // an ulp inside and outside are told apart.
  const PointSet points = make_points(2, {0, 0, 1, 0, 1, 1, 0, 1});
  const std::uint32_t tri[3] = {0, 1, 2};
  const double on[2] = {0.0, 1.0};
  const double inside[2] = {0.0, 1.0 - 0x1p-53};
  const double outside[2] = {0.0, 1.0 + 0x1p-52};
  EXPECT_EQ(in_circumsphere(points, tri, on), 0);
  EXPECT_EQ(in_circumsphere(points, tri, inside), 1);
  EXPECT_EQ(in_circumsphere(points, tri, outside), -1);
}

}  // namespace
}  // namespace spokemesh
