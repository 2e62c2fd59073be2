// Stars: equal to the brute-force Delaunay star on random, grid and cospherical
// inputs; consistent between seeds; independent of the random spoke directions; found
// by one wrap per simplex (the walk follows a spanning tree of the star).
#include <gtest/gtest.h>
#include <rapidcheck/gtest.h>

#include <cmath>
#include <numeric>

#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;

std::set<std::vector<std::uint32_t>> star_set(StarWalker& walker, std::uint32_t seed, int d) {
  Star star;
  const Status s = walker.compute(seed, star);
  EXPECT_TRUE(s.is_ok()) << s.message();
  return as_set(star.simplices, d + 1);
}

struct Case {
  std::string name;
  int d;
  std::vector<double> coords;
};

std::vector<Case> small_cases() {
  return {
      {"uniform-2d", 2, uniform_points(2, 40, 11)},
      {"uniform-3d", 3, uniform_points(3, 30, 12)},
      {"uniform-4d", 4, uniform_points(4, 22, 13)},
      {"grid-2d", 2, grid_points(2, 6)},
      {"grid-3d", 3, grid_points(3, 3)},
      {"circle+centre-2d", 2, sphere_points(2, 25, true)},
      {"sphere-3d", 3, sphere_points(3, 9, false)},
      {"cube+centre-4d", 4,
       [] {
         auto c = grid_points(4, 2);
         c.insert(c.end(), {0.5, 0.5, 0.5, 0.5});
         return c;
       }()},
  };
}

// Also: the walk rotates only about facets whose far side is still unknown. Without a
// facet cache each simplex but the first is found by exactly one wrap, and each hull
// facet costs one wrap that finds nothing; the first simplex takes d to 2 d spoke
// wraps (one per level, two when a spoke's first side is empty).
TEST(Star, EqualsBruteForceOnEverySeedWithOneWrapPerSimplex) {
  for (const Case& c : small_cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    StarWalker walker(tree);
    const auto d = static_cast<std::uint64_t>(c.d);
    for (std::uint32_t seed = 0; seed < ps.size(); ++seed) {
      const std::uint64_t before = walker.stats().wraps;
      Star star;
      ASSERT_TRUE(walker.compute(seed, star).is_ok());
      ASSERT_EQ(as_set(star.simplices, c.d + 1), brute_force_star(ps, seed)) << "seed " << seed;
      const std::uint64_t walk = star.size() - 1 + star.hull_facets;
      const std::uint64_t wraps = walker.stats().wraps - before;
      EXPECT_GE(wraps, walk + d) << "seed " << seed;
      EXPECT_LE(wraps, walk + 2 * d) << "seed " << seed;
    }
  }
}

// d = 7 and 8, the largest dimensions meshed exactly: random points, and the
// cross-polytope with its centre (2d + 1 points, 2d of them cospherical: every star
// simplex there is decided by the symbolic perturbation), every seed against the
// brute force.
TEST(Star, EqualsBruteForceInSevenAndEightDimensions) {
  for (const int d : {7, 8}) {
    std::vector<double> cross(static_cast<std::size_t>(d), 0.0);  // the centre
    for (int axis = 0; axis < d; ++axis) {
      for (const double sign : {-1.0, 1.0}) {
        for (int c = 0; c < d; ++c) cross.push_back(c == axis ? sign : 0.0);
      }
    }
    for (const auto& [name, coords] : {std::pair{std::string("uniform"), uniform_points(d, d + 6, 70 + d)},
                                       std::pair{std::string("cross+centre"), cross}}) {
      SCOPED_TRACE(name + " d " + std::to_string(d));
      const PointSet ps = make_points(d, coords);
      const KdTree tree(ps);
      StarWalker walker(tree);
      for (std::uint32_t seed = 0; seed < ps.size(); ++seed) {
        ASSERT_EQ(star_set(walker, seed, d), brute_force_star(ps, seed)) << "seed " << seed;
      }
    }
  }
}

// A two-point neighbourhood sends nearly every wrap to the k-d tree's sphere and
// hull queries and triggers the neighbourhood growth; coordinates far from the
// origin stress the certified error terms of the pencil keys and of the sphere
// pruning (the centre's rounding grows with |x|).
TEST(Star, EqualsBruteForceWithTinyNeighbourhoodsAndFarCoordinates) {
  for (const Case& c : small_cases()) {
    // Far away only for the random cases: rounding there turns grids and spheres
    // into near-degenerate inputs that the brute force can only decide exactly.
    for (const double offset : {0.0, 1e6}) {
      if (offset != 0.0 && c.name.rfind("uniform", 0) != 0) continue;
      SCOPED_TRACE(c.name + " offset " + std::to_string(offset));
      std::vector<double> coords = c.coords;
      if (offset != 0.0) {
        for (double& v : coords) v = offset + v * 0x1p-10;
      }
      const PointSet ps = make_points(c.d, coords);
      const KdTree tree(ps);
      StarWalker walker(tree, StarOptions{.initial_candidates = 2});
      for (std::uint32_t seed = 0; seed < ps.size(); ++seed) {
        ASSERT_EQ(star_set(walker, seed, c.d), brute_force_star(ps, seed)) << "seed " << seed;
      }
      EXPECT_GT(walker.stats().sphere_queries, 0u);
    }
  }
}

// Scaling by a power of two changes no predicate, so the stars must not change. At
// 2^250 the coordinates are beyond float's range and at 2^-250 below its smallest
// value: the k-d tree keeps its boxes as floats rounded outwards, and the tiny
// neighbourhood sends most wraps to those boxes.
TEST(Star, UnchangedByPowerOfTwoScalingBeyondFloatRange) {
  for (const int d : {2, 3}) {
    const std::vector<double> base = uniform_points(d, 24, 31 + d);
    const PointSet ps = make_points(d, base);
    const KdTree tree(ps);
    StarWalker walker(tree, StarOptions{.initial_candidates = 2});
    for (const int e : {250, -250}) {
      SCOPED_TRACE("d " + std::to_string(d) + " scale 2^" + std::to_string(e));
      std::vector<double> scaled = base;
      for (double& v : scaled) v = std::ldexp(v, e);
      const PointSet ps_scaled = make_points(d, scaled);
      const KdTree tree_scaled(ps_scaled);
      StarWalker walker_scaled(tree_scaled, StarOptions{.initial_candidates = 2});
      for (std::uint32_t seed = 0; seed < ps.size(); ++seed) {
        ASSERT_EQ(star_set(walker_scaled, seed, d), star_set(walker, seed, d)) << "seed " << seed;
      }
      EXPECT_GT(walker_scaled.stats().sphere_queries, 0u);
    }
  }
}

TEST(Star, SimplicesAppearInTheStarOfEachVertex) {
  for (int d = 2; d <= 5; ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const std::size_t n = d <= 3 ? 400 : 120;
    const PointSet ps = make_points(d, uniform_points(d, n, 100 + d));
    const KdTree tree(ps);
    StarWalker walker(tree);
    std::vector<std::set<std::vector<std::uint32_t>>> stars(n);
    for (std::uint32_t s = 0; s < n; ++s) stars[s] = star_set(walker, s, d);
    for (std::uint32_t s = 0; s < n; ++s) {
      for (const auto& simplex : stars[s]) {
        for (std::uint32_t v : simplex) ASSERT_TRUE(stars[v].count(simplex)) << "seed " << s << " vertex " << v;
      }
    }
  }
}

TEST(Star, DoesNotDependOnTheRandomSpokes) {
  const PointSet ps = make_points(3, uniform_points(3, 300, 7));
  const KdTree tree(ps);
  StarWalker a(tree, StarOptions{.random_seed = 1}), b(tree, StarOptions{.random_seed = 999});
  StarWalker small(tree, StarOptions{.random_seed = 5, .initial_candidates = 4});
  for (std::uint32_t s = 0; s < ps.size(); s += 7) {
    const auto expected = star_set(a, s, 3);
    EXPECT_EQ(star_set(b, s, 3), expected) << "seed " << s;
    EXPECT_EQ(star_set(small, s, 3), expected) << "seed " << s << " (tiny first neighbourhood)";
  }
}

TEST(Star, RefusesSeedsOutOfRange) {
  const PointSet ps = make_points(2, uniform_points(2, 10, 1));
  const KdTree tree(ps);
  StarWalker walker(tree);
  Star star;
  const Status s = walker.compute(10, star);
  EXPECT_EQ(s.code(), Code::kOutOfRange);
  EXPECT_NE(s.message().find("seed 10"), std::string::npos);
}

TEST(Star, HonoursCancellation) {
  const PointSet ps = make_points(3, uniform_points(3, 200, 3));
  const KdTree tree(ps);
  std::atomic<bool> cancel{true};
  StarWalker walker(tree, StarOptions{.cancel = &cancel});
  Star star;
  EXPECT_EQ(walker.compute(0, star).code(), Code::kCancelled);
}

// A deadline that has passed stops a walk with DEADLINE_EXCEEDED (the walker stays
// usable: the next compute without it gives the star); a deadline far off changes
// nothing; the 2-d ring walk honours it too.
TEST(Star, HonoursItsDeadline) {
  for (const int d : {2, 3}) {
    SCOPED_TRACE(d);
    const PointSet ps = make_points(d, uniform_points(d, 300, 4));
    const KdTree tree(ps);
    StarWalker plain(tree);
    Star expected, star;
    ASSERT_TRUE(plain.compute(7, expected).is_ok());
    StarWalker walker(tree, StarOptions{.deadline = std::chrono::steady_clock::now() - std::chrono::seconds(1)});
    EXPECT_EQ(walker.compute(7, star).code(), Code::kDeadlineExceeded);
    walker.set_deadline(std::chrono::steady_clock::now() + std::chrono::hours(1));
    ASSERT_TRUE(walker.compute(7, star).is_ok());
    EXPECT_EQ(star.simplices, expected.simplices);
    std::atomic<bool> cancel{true};
    StarWalker both(
        tree, StarOptions{.cancel = &cancel, .deadline = std::chrono::steady_clock::now() - std::chrono::seconds(1)});
    EXPECT_EQ(both.compute(7, star).code(), Code::kCancelled) << "cancellation first";
  }
}

// Shuffles the points with `seed`, meshes both orders (the shuffled one with
// `threads` threads and the seed as the spoke seed) and asserts the same simplices
// once mapped back through the shuffle.
void assert_permutation_invariant(int d, const std::vector<double>& coords, std::uint64_t seed, unsigned threads) {
  const std::size_t count = coords.size() / d;
  std::vector<std::uint32_t> perm(count);
  std::iota(perm.begin(), perm.end(), 0u);
  std::shuffle(perm.begin(), perm.end(), std::mt19937_64(seed));
  std::vector<double> shuffled(coords.size());
  for (std::size_t i = 0; i < count; ++i) {
    std::copy_n(&coords[perm[i] * d], d, &shuffled[i * d]);  // shuffled point i = original perm[i]
  }
  PointSet a(d, coords), b(d, shuffled);
  RC_ASSERT(a.validate("a").is_ok());
  RC_ASSERT(b.validate("b").is_ok());
  const KdTree ta(a), tb(b);
  Simplices mb = mesh_all(tb, threads, 0, 0xFFFFFFFFu, seed);
  for (auto& v : mb) v = perm[v];
  RC_ASSERT(as_set(mesh_all(ta), d + 1) == as_set(mb, d + 1));
}

// Property: shuffling the input gives the same mesh, mapped back through the shuffle.
RC_GTEST_PROP(MeshProperty, PermutationInvariant, ()) {
  const int d = *rc::gen::inRange(2, 5);
  const int n = *rc::gen::inRange(d + 2, d <= 3 ? 60 : 30);
  const bool on_grid = *rc::gen::arbitrary<bool>();
  const std::uint64_t seed = *rc::gen::arbitrary<std::uint64_t>();
  assert_permutation_invariant(d, on_grid ? grid_points(d, 3) : uniform_points(d, n, seed), seed, 1);
}

// Property: grids written every way the benchmark writes them (integer, linspace,
// decimal steps, dyadic) mesh to the same simplices after shuffling, at every side
// from 2 up; ties there are decided only by the symbolic perturbation.
RC_GTEST_PROP(MeshProperty, GridsArePermutationInvariant, ()) {
  const int d = *rc::gen::inRange(2, 5);
  const int side = *rc::gen::inRange(2, d == 2 ? 16 : d == 3 ? 7 : 4);
  const int kind = *rc::gen::inRange(0, 4);
  const std::uint64_t seed = *rc::gen::arbitrary<std::uint64_t>();
  double (*const scales[])(double, int) = {[](double v, int) { return v; }, linspace_value, decimal_value,
                                           dyadic_value};
  assert_permutation_invariant(d, scaled_grid_points(d, side, scales[kind]), seed, 2);
}

}  // namespace
}  // namespace spokemesh
