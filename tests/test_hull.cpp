// ConvexHull (core/include/spokemesh/convex_hull.hpp) against brute force: in general
// position the facets are exactly the d-subsets with every other point strictly on one
// side; on degenerate sets (grids, points on flat faces, equal points) every point is
// beneath or on every facet, neighbours are mutual, and the facets do not depend on the
// input order. Seeds are fixed and printed on failure; rapidcheck draws the rest.
#include <gtest/gtest.h>
#include <rapidcheck.h>
#include <rapidcheck/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>
#include <set>
#include <vector>

#include "spokemesh/convex_hull.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {
namespace {

using Facets = std::set<std::vector<std::uint32_t>>;

std::vector<double> random_points(std::size_t n, int d, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<double> c(n * static_cast<std::size_t>(d));
  for (double& x : c) x = u(rng);
  return c;
}

// The exact sign of det[v_i - v0; x - v0] (rationals throughout).
int exact_sign(const std::vector<double>& c, int d, const std::vector<std::uint32_t>& v, std::size_t x) {
  std::vector<mpq_class> m;
  for (int r = 0; r < d; ++r) {
    const std::size_t p = r + 1 < d ? v[static_cast<std::size_t>(r + 1)] : x;
    for (int k = 0; k < d; ++k) m.push_back(mpq_class(c[p * d + k]) - mpq_class(c[v[0] * d + k]));
  }
  return sgn(exact_determinant(m, d));
}

Facets sorted_facets(const ConvexHull& hull, const std::vector<std::uint32_t>* back = nullptr) {
  const int d = hull.dimension();
  const std::vector<std::uint32_t> rows = hull.facet_vertices();
  Facets out;
  for (std::size_t f = 0; f < hull.facet_count(); ++f) {
    std::vector<std::uint32_t> v(rows.begin() + f * d, rows.begin() + (f + 1) * d);
    if (back != nullptr) {
      for (auto& x : v) x = (*back)[x];
    }
    std::sort(v.begin(), v.end());
    out.insert(v);
  }
  return out;
}

// Brute force in general position: the d-subsets with every other point strictly on
// one side.
Facets brute_force(const std::vector<double>& c, int d) {
  const std::size_t n = c.size() / d;
  Facets out;
  std::vector<char> pick(n, 0);
  std::fill(pick.begin(), pick.begin() + d, 1);
  do {
    std::vector<std::uint32_t> v;
    for (std::size_t i = 0; i < n; ++i) {
      if (pick[i]) v.push_back(static_cast<std::uint32_t>(i));
    }
    int side = 0;
    bool facet = true;
    for (std::size_t x = 0; x < n && facet; ++x) {
      if (pick[x]) continue;
      const int s = exact_sign(c, d, v, x);
      if (s == 0 || (side != 0 && s != side)) facet = false;
      side = s;
    }
    if (facet) out.insert(v);
  } while (std::prev_permutation(pick.begin(), pick.end()));
  return out;
}

// What holds on any input: every point beneath or on every facet (exactly), every
// facet's vertices distinct, neighbours mutual and sharing the d - 1 other vertices.
void expect_valid(const ConvexHull& hull, const std::vector<double>& c, const std::string& what) {
  const int d = hull.dimension();
  const std::size_t n = c.size() / d;
  const std::vector<std::uint32_t> rows = hull.facet_vertices();
  const std::vector<std::int32_t> nb = hull.facet_neighbors();
  ASSERT_GE(hull.facet_count(), static_cast<std::size_t>(d + 1)) << what;
  for (std::size_t f = 0; f < hull.facet_count(); ++f) {
    std::vector<std::uint32_t> v(rows.begin() + f * d, rows.begin() + (f + 1) * d);
    for (std::size_t x = 0; x < n; ++x) ASSERT_LE(hull.side(c, f, x), 0) << what << ": point " << x << ", facet " << f;
    for (int k = 0; k < d; ++k) {
      const std::int32_t g = nb[f * d + k];
      ASSERT_GE(g, 0) << what;
      ASSERT_NE(static_cast<std::size_t>(g), f) << what;
      const auto back = std::count(nb.begin() + g * d, nb.begin() + (g + 1) * d, static_cast<std::int32_t>(f));
      ASSERT_EQ(back, 1) << what << ": facets " << f << " and " << g << " are not mutual neighbours";
      std::vector<std::uint32_t> ridge = v;
      ridge.erase(ridge.begin() + k);
      for (const std::uint32_t r : ridge) {
        ASSERT_NE(std::find(rows.begin() + g * d, rows.begin() + (g + 1) * d, r), rows.begin() + (g + 1) * d) << what;
      }
    }
    std::sort(v.begin(), v.end());
    ASSERT_EQ(std::unique(v.begin(), v.end()), v.end()) << what;
  }
}

TEST(ConvexHull, EqualsBruteForceInGeneralPosition) {
  for (int d = 2; d <= 5; ++d) {
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
      const std::size_t n = static_cast<std::size_t>(d + 1 + 2 * seed);
      const std::vector<double> c = random_points(n, d, 1000 * d + seed);
      auto hull = ConvexHull::build(c, d);
      ASSERT_TRUE(hull.is_ok()) << hull.status().message();
      const std::string what = std::to_string(d) + "-d, seed " + std::to_string(1000 * d + seed);
      EXPECT_EQ(sorted_facets(hull.value()), brute_force(c, d)) << what;
      expect_valid(hull.value(), c, what);
    }
  }
}

// Points on a small integer grid, many on flat faces and several equal.
std::vector<double> grid_points(std::size_t n, int d, int side, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> u(0, side);
  std::vector<double> c(n * static_cast<std::size_t>(d));
  for (double& x : c) x = u(rng);
  return c;
}

RC_GTEST_PROP(ConvexHull, ValidAndIndependentOfInputOrderOnGrids, ()) {
  const int d = *rc::gen::inRange(2, 6);
  const int side = *rc::gen::inRange(1, 4);
  const std::size_t n = *rc::gen::inRange<std::size_t>(static_cast<std::size_t>(d + 1), 40);
  const auto seed = *rc::gen::arbitrary<std::uint32_t>();
  std::vector<double> c = grid_points(n, d, side, seed);
  // Distinct points only (equal points are tested below): keep first occurrences.
  std::set<std::vector<double>> seen;
  std::vector<double> distinct;
  for (std::size_t i = 0; i < n; ++i) {
    std::vector<double> p(c.begin() + i * d, c.begin() + (i + 1) * d);
    if (seen.insert(p).second) distinct.insert(distinct.end(), p.begin(), p.end());
  }
  auto hull = ConvexHull::build(distinct, d);
  if (!hull.is_ok()) {
    // Flat, or fewer than d + 1 distinct points.
    RC_ASSERT(hull.status().message().find("the hull is flat") != std::string::npos ||
              hull.status().message().find("needs at least") != std::string::npos);
    return;
  }
  expect_valid(hull.value(), distinct, "grid seed " + std::to_string(seed));
  // The same points reversed and rotated: the same facets, mapped back.
  const std::size_t m = distinct.size() / d;
  std::vector<std::uint32_t> order(m);
  std::iota(order.begin(), order.end(), 0u);
  std::reverse(order.begin(), order.end());
  std::rotate(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(seed % m), order.end());
  std::vector<double> shuffled;
  for (const std::uint32_t i : order)
    shuffled.insert(shuffled.end(), distinct.begin() + i * d, distinct.begin() + (i + 1) * d);
  auto again = ConvexHull::build(shuffled, d);
  RC_ASSERT(again.is_ok());
  RC_ASSERT(sorted_facets(again.value(), &order) == sorted_facets(hull.value()));
}

TEST(ConvexHull, EqualPointsAndPointsOnFacesAreNotVertices) {
  // The unit cube's corners, its centre, the centres of its faces, and each corner twice.
  std::vector<double> c;
  for (int i = 0; i < 8; ++i) c.insert(c.end(), {double(i & 1), double((i >> 1) & 1), double((i >> 2) & 1)});
  c.insert(c.end(), {0.5, 0.5, 0.5, 0.5, 0.5, 0.0, 0.5, 0.5, 1.0, 0.0, 0.5, 0.5, 1.0, 0.5, 0.5});
  for (int i = 0; i < 8; ++i) c.insert(c.end(), {double(i & 1), double((i >> 1) & 1), double((i >> 2) & 1)});
  auto hull = ConvexHull::build(c, 3);
  ASSERT_TRUE(hull.is_ok()) << hull.status().message();
  expect_valid(hull.value(), c, "cube");
  EXPECT_EQ(hull.value().vertices(), (std::vector<std::uint32_t>{0, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(hull.value().facet_count(), 12u);
  // The cube's six faces, two triangles each, found exactly.
  const std::vector<std::uint32_t> groups = hull.value().facet_groups(c);
  std::vector<int> per_group(6, 0);
  for (const std::uint32_t g : groups) {
    ASSERT_LT(g, 6u);
    ++per_group[g];
  }
  EXPECT_EQ(per_group, std::vector<int>(6, 2));
  // Qc's coplanar points: the four face centres and the eight second corners, not the centre.
  const auto coplanar = hull.value().coplanar(c);
  std::vector<std::uint32_t> points;
  for (const auto& row : coplanar) {
    points.push_back(row[0]);
    EXPECT_EQ(hull.value().side(c, row[1], row[0]), 0);
  }
  EXPECT_EQ(points, (std::vector<std::uint32_t>{9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20}));
  for (const auto& row : coplanar) {
    if (row[0] >= 13) {
      EXPECT_EQ(row[2], row[0] - 13);  // an equal corner's nearest vertex is that corner
    }
  }
}

TEST(ConvexHull, ExtendKeepsSurvivorsInOrderAndEqualsABuild) {
  for (int d = 2; d <= 4; ++d) {
    const std::vector<double> all = random_points(60, d, 77 + d);
    const std::vector<double> first(all.begin(), all.begin() + 20 * d);
    auto hull = ConvexHull::build(first, d);
    ASSERT_TRUE(hull.is_ok());
    const std::vector<std::uint32_t> before = hull.value().facet_vertices();
    ASSERT_TRUE(hull.value().extend(all).is_ok());
    auto whole = ConvexHull::build(all, d);
    ASSERT_TRUE(whole.is_ok());
    EXPECT_EQ(sorted_facets(hull.value()), sorted_facets(whole.value())) << d << "-d";
    expect_valid(hull.value(), all, std::to_string(d) + "-d extended");
    // The surviving old facets come first, in their old order.
    const std::vector<std::uint32_t> after = hull.value().facet_vertices();
    std::vector<std::vector<std::uint32_t>> old_rows, new_rows;
    for (std::size_t f = 0; f < before.size() / d; ++f)
      old_rows.emplace_back(before.begin() + f * d, before.begin() + (f + 1) * d);
    for (std::size_t f = 0; f < after.size() / d; ++f)
      new_rows.emplace_back(after.begin() + f * d, after.begin() + (f + 1) * d);
    std::vector<std::vector<std::uint32_t>> survivors;
    for (const auto& r : old_rows) {
      if (std::find(new_rows.begin(), new_rows.end(), r) != new_rows.end()) survivors.push_back(r);
    }
    ASSERT_LE(survivors.size(), new_rows.size());
    EXPECT_TRUE(std::equal(survivors.begin(), survivors.end(), new_rows.begin())) << d << "-d";
  }
}

TEST(ConvexHull, ErrorsNameWhatAndWhere) {
  // Flat: points on a plane in 3-d.
  std::vector<double> flat;
  for (int i = 0; i < 10; ++i) flat.insert(flat.end(), {double(i), double(i * i % 7), double(i + i * i % 7)});
  auto f = ConvexHull::build(flat, 3);
  ASSERT_FALSE(f.is_ok());
  EXPECT_NE(f.status().message().find("2-dimensional affine subspace of R^3"), std::string::npos)
      << f.status().message();
  EXPECT_NE(f.status().message().find("the hull is flat"), std::string::npos);
  std::vector<double> nan = random_points(10, 2, 3);
  nan[7] = std::numeric_limits<double>::quiet_NaN();
  auto n = ConvexHull::build(nan, 2);
  ASSERT_FALSE(n.is_ok());
  EXPECT_EQ(n.status().message(), "points[3][1]: not a finite number");
  auto few = ConvexHull::build(random_points(3, 3, 1), 3);
  ASSERT_FALSE(few.is_ok());
  EXPECT_NE(few.status().message().find("at least 4"), std::string::npos) << few.status().message();
  auto high = ConvexHull::build(random_points(20, 9, 1), 9);
  ASSERT_FALSE(high.is_ok());
  EXPECT_NE(high.status().message().find("dimension 9"), std::string::npos);
}

TEST(ConvexHull, AViewpointIsLeftOutAndThreadsChangeNothing) {
  const std::vector<double> c = random_points(200000, 3, 9);
  HullOptions one;
  one.threads = 1;
  auto a = ConvexHull::build(c, 3, one);
  auto b = ConvexHull::build(c, 3);
  ASSERT_TRUE(a.is_ok() && b.is_ok());
  EXPECT_EQ(a.value().facet_vertices(), b.value().facet_vertices());
  EXPECT_EQ(a.value().facet_neighbors(), b.value().facet_neighbors());
  const std::uint32_t far = a.value().vertices().front();
  HullOptions without;
  without.exclude = far;
  auto w = ConvexHull::build(c, 3, without);
  ASSERT_TRUE(w.is_ok());
  const auto v = w.value().vertices();
  EXPECT_EQ(std::find(v.begin(), v.end(), far), v.end());
  int visible = 0;
  for (std::size_t f = 0; f < w.value().facet_count(); ++f) visible += w.value().side(c, f, far) > 0;
  EXPECT_GT(visible, 0);  // it was a vertex: outside the hull of the others
}

}  // namespace
}  // namespace spokemesh
