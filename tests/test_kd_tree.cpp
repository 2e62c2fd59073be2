// KdTree against brute force (as nanoflann tests itself): k nearest (also cut at a
// distance bound) and radius queries on random, tied (grid) and awkwardly scaled
// inputs, including those that stress the Z-order pre-sort of the build (a flat
// coordinate, a huge span, tiny coordinates, one point).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <numeric>
#include <random>

#include <gmpxx.h>

#include "spokemesh/approx.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;

double dist2(const PointSet& ps, std::size_t i, std::size_t j) {
  double s = 0;
  for (int c = 0; c < ps.dimension(); ++c) {
    const double e = ps.point(i)[c] - ps.point(j)[c];
    s += e * e;
  }
  return s;
}

// The tree of `ps` grown as insertion grows it: built whole over its first points,
// then extended (KdTree::extended) to each further prefix of the points in turn, the
// last ps itself; each step adds at most a sixteenth, so each adds a part.
std::unique_ptr<KdTree> grown_tree(const PointSet& ps, std::size_t steps) {
  const std::size_t n = ps.size(), d = static_cast<std::size_t>(ps.dimension());
  std::vector<std::size_t> sizes{n};
  for (std::size_t s = 0; s < steps && sizes.back() > 8; ++s) sizes.push_back(sizes.back() - sizes.back() / 17);
  std::reverse(sizes.begin(), sizes.end());
  std::vector<std::unique_ptr<PointSet>> prefixes;
  for (std::size_t i = 0; i + 1 < sizes.size(); ++i) {
    prefixes.push_back(std::make_unique<PointSet>(
        ps.dimension(), std::vector<double>(ps.coordinates().begin(),
                                            ps.coordinates().begin() + static_cast<std::ptrdiff_t>(sizes[i] * d))));
  }
  std::unique_ptr<KdTree> tree = std::make_unique<KdTree>(prefixes.empty() ? ps : *prefixes[0]);
  for (std::size_t i = 1; i < sizes.size(); ++i)
    tree = KdTree::extended(*tree, i + 1 < sizes.size() ? *prefixes[i] : ps);
  std::size_t parts = 1;  // each step extends the tree, or builds it whole past kMaxParts
  for (std::size_t i = 1; i < sizes.size(); ++i) parts = parts >= KdTree::kMaxParts ? 1 : parts + 1;
  EXPECT_EQ(tree->parts(), parts);
  return tree;
}

// Every point's k nearest: ascending, the brute-force distances, and every point
// strictly nearer than the k-th among them (ties at the k-th may go either way).
// With `grown`, of a tree grown by that many extensions (grown_tree).
void expect_knn_matches_brute_force(const std::string& name, int d, std::vector<double> coords, std::size_t k,
                                    std::size_t grown = 0) {
  // Validated as the approximate path does (no span check: flat inputs are allowed).
  PointSet ps(d, std::move(coords));
  const Status valid = ps.validate(name, kMaxApproxDimension, /*check_span=*/false);
  ASSERT_TRUE(valid.is_ok()) << valid.message();
  const std::unique_ptr<KdTree> owned = grown == 0 ? std::make_unique<KdTree>(ps) : grown_tree(ps, grown);
  const KdTree& tree = *owned;
  const std::size_t n = ps.size();
  std::uint32_t tiled = 0;  // subtrees_of_at_most's ranges tile [0, n) in order
  for (const KdTree::Subtree& sub : tree.subtrees_of_at_most(40)) {
    ASSERT_EQ(sub.begin, tiled) << name;
    tiled = sub.end;
  }
  ASSERT_EQ(tiled, n) << name;
  std::vector<bool> seen_rank(n, false);
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint32_t r = tree.leaf_rank(static_cast<std::uint32_t>(i));
    ASSERT_LT(r, n) << name;
    ASSERT_FALSE(seen_rank[r]) << name << ": leaf ranks are not a permutation";
    seen_rank[r] = true;
  }
  std::vector<std::uint32_t> ids(k);
  std::vector<double> d2(k);
  std::vector<const double*> coords_of(k);
  for (std::size_t q = 0; q < n; ++q) {
    const std::size_t got = tree.knn(ps.point(q), k, ids.data(), d2.data(), coords_of.data());
    ASSERT_EQ(got, std::min(k, n)) << name << " query " << q;
    std::vector<double> all(n);
    for (std::size_t j = 0; j < n; ++j) all[j] = dist2(ps, q, j);
    std::vector<double> sorted = all;
    std::sort(sorted.begin(), sorted.end());
    for (std::size_t i = 0; i < got; ++i) {
      ASSERT_EQ(d2[i], all[ids[i]]) << name << " query " << q << " rank " << i;
      ASSERT_EQ(d2[i], sorted[i]) << name << " query " << q << " rank " << i;
      for (int c = 0; c < d; ++c) ASSERT_EQ(coords_of[i][c], ps.point(ids[i])[c]) << name;
    }
    const double kth = d2[got - 1];
    for (std::size_t j = 0; j < n; ++j) {
      if (all[j] < kth) {
        ASSERT_NE(std::find(ids.begin(), ids.begin() + static_cast<std::ptrdiff_t>(got), j),
                  ids.begin() + static_cast<std::ptrdiff_t>(got))
            << name << " query " << q << " misses point " << j;
      }
    }
    // within(): exactly the points strictly nearer than the k-th.
    std::vector<std::pair<std::uint32_t, double>> near;
    tree.within(ps.point(q), kth, near);
    std::size_t expected = 0;
    for (std::size_t j = 0; j < n; ++j) expected += all[j] < kth ? 1 : 0;
    ASSERT_EQ(near.size(), expected) << name << " query " << q;
    for (const auto& [j, e] : near) ASSERT_LT(all[j], kth) << name;
    // knn() with a bound: the same nearest, cut at the bound (strictly closer only),
    // for bounds below, at and above the k-th distance.
    for (const double bound : {sorted[std::min(got, n) / 2], kth, kth * 1.5}) {
      std::vector<std::uint32_t> bounded_ids(k);
      std::vector<double> bounded_d2(k);
      const std::size_t cut = tree.knn(ps.point(q), k, bounded_ids.data(), bounded_d2.data(), nullptr, bound);
      std::size_t closer = 0;
      for (std::size_t j = 0; j < n; ++j) closer += all[j] < bound ? 1 : 0;
      ASSERT_EQ(cut, std::min(closer, got)) << name << " query " << q << " bound " << bound;
      for (std::size_t i = 0; i < cut; ++i) {
        ASSERT_EQ(bounded_d2[i], sorted[i]) << name << " query " << q << " bound " << bound << " rank " << i;
        ASSERT_LT(bounded_d2[i], bound) << name;
      }
    }
  }
}

// A tree extended by new points' trees (as incremental insertion grows it) answers
// as one built whole: uniform, grid (ties) and 9-d (the generic search) sets.
TEST(KdTree, ExtendedTreeMatchesBruteForce) {
  expect_knn_matches_brute_force("uniform-2d grown 3", 2, uniform_points(2, 300, 21), 17, 3);
  expect_knn_matches_brute_force("uniform-3d grown 7", 3, uniform_points(3, 400, 22), 30, 7);
  expect_knn_matches_brute_force("grid-3d grown 2", 3, grid_points(3, 6), 27, 2);
  expect_knn_matches_brute_force("uniform-9d grown 2", 9, uniform_points(9, 150, 23), 20, 2);
  // Past kMaxParts extensions the tree is built whole again.
  PointSet ps(2, uniform_points(2, 500, 24));
  ASSERT_TRUE(ps.validate("many").is_ok());
  EXPECT_EQ(grown_tree(ps, 9)->parts(), 2u);
}

TEST(KdTree, NearestMatchBruteForce) {
  expect_knn_matches_brute_force("uniform-2d", 2, uniform_points(2, 300, 1), 17);
  expect_knn_matches_brute_force("uniform-3d", 3, uniform_points(3, 300, 2), 49);
  expect_knn_matches_brute_force("uniform-5d", 5, uniform_points(5, 200, 3), 60);
  expect_knn_matches_brute_force("uniform-9d", 9, uniform_points(9, 120, 4), 30);  // the generic search
}

// A set large enough for the two halves to be built on two threads: a sample of
// queries (some of them not points of the set) against brute force.
TEST(KdTree, LargeSetBuiltInParallelMatchesBruteForce) {
  const int d = 2;
  PointSet ps(d, uniform_points(d, 70000, 11));
  ASSERT_TRUE(ps.validate("large").is_ok());
  const KdTree tree(ps);
  const std::size_t n = ps.size(), k = 17;
  std::vector<std::uint32_t> ids(k);
  std::vector<double> d2(k);
  for (std::size_t q = 0; q < n; q += 350) {
    for (const double shift : {0.0, 0.37}) {  // a point of the set, or beside it
      const double query[2] = {ps.point(q)[0] + shift * 1e-3, ps.point(q)[1] - shift * 1e-3};
      std::vector<double> all(n);
      for (std::size_t j = 0; j < n; ++j) {
        const double a = query[0] - ps.point(j)[0], b = query[1] - ps.point(j)[1];
        all[j] = a * a + b * b;
      }
      std::partial_sort(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(k), all.end());
      ASSERT_EQ(tree.knn(query, k, ids.data(), d2.data()), k);
      for (std::size_t i = 0; i < k; ++i)
        ASSERT_EQ(d2[i], all[i]) << "query " << q << " shift " << shift << " rank " << i;
    }
  }
}

TEST(KdTree, NearestMatchBruteForceWithTies) {
  expect_knn_matches_brute_force("grid-2d", 2, grid_points(2, 12), 13);
  expect_knn_matches_brute_force("grid-3d", 3, grid_points(3, 5), 27);
}

TEST(KdTree, NearestMatchBruteForceOnAwkwardInputs) {
  // One coordinate the same everywhere (its Z-order cell is always 0).
  std::vector<double> flat = uniform_points(3, 150, 5);
  for (std::size_t i = 0; i < flat.size(); i += 3) flat[i + 1] = 0.25;
  expect_knn_matches_brute_force("flat-y", 3, flat, 20);
  // A span near the largest accepted coordinates, and tiny coordinates.
  std::vector<double> huge = uniform_points(2, 150, 6), tiny = huge;
  for (double& v : huge) v = (v - 0.5) * 1.9e100;
  for (double& v : tiny) v = std::ldexp(v, -250);
  expect_knn_matches_brute_force("huge", 2, huge, 16);
  expect_knn_matches_brute_force("tiny", 2, tiny, 16);
  // Fewer points than asked for, down to the fewest accepted.
  expect_knn_matches_brute_force("three", 2, {0, 0, 1, 0, 0, 1}, 8);
  expect_knn_matches_brute_force("five-4d", 4, uniform_points(4, 5, 7), 9);
}

// any_beyond and find_first against brute force: for hyperplanes through a point x
// (random normals, and axis-aligned ones that grids' faces produce, where whole boxes
// lie on the hyperplane and are skipped as flat), whether some point lies strictly on
// side sigma must match an exact rational scan, and any point returned must be such a
// point. find_first with an accept-all box test must visit every point.
TEST(KdTree, AnyBeyondMatchesBruteForce) {
  for (int d = 2; d <= 4; ++d) {
    for (const bool on_grid : {false, true}) {
      const std::vector<double> coords = on_grid ? grid_points(d, d == 2   ? 20
                                                                  : d == 3 ? 8
                                                                           : 5)
                                                 : uniform_points(d, 600, 40 + d);
      const PointSet ps = make_points(d, coords);
      for (const std::size_t grown : {0, 3}) {  // a tree built whole, and one extended 3 times
        SCOPED_TRACE(grown == 0 ? "built whole" : "extended");
        const std::unique_ptr<KdTree> owned = grown == 0 ? std::make_unique<KdTree>(ps) : grown_tree(ps, grown);
        const KdTree& tree = *owned;
        std::mt19937_64 rng(1000 + d);
        std::uniform_int_distribution<std::size_t> any_point(0, ps.size() - 1);
        std::uniform_int_distribution<int> axis(0, d - 1), small(-2, 2);
        for (int trial = 0; trial < 200; ++trial) {
          const std::size_t origin = any_point(rng);
          const double* x = ps.point(origin);
          std::vector<double> n(static_cast<std::size_t>(d), 0.0);
          if (trial % 2 == 0) {
            n[static_cast<std::size_t>(axis(rng))] = 1.0;  // axis-aligned
          } else {
            for (double& v : n) v = small(rng) * 0.5;
          }
          std::vector<BoundedDouble> normal;
          for (const double v : n) normal.push_back(BoundedDouble::exact(v));
          auto exact_side = [&](std::uint32_t p) {
            mpq_class s = 0;
            for (int c = 0; c < d; ++c) s += mpq_class(n[c]) * (mpq_class(ps.point(p)[c]) - mpq_class(x[c]));
            return sgn(s);
          };
          for (const int sigma : {-1, 1}) {
            SCOPED_TRACE("d " + std::to_string(d) + (on_grid ? " grid" : " uniform") + " trial " +
                         std::to_string(trial) + " sigma " + std::to_string(sigma));
            bool expected = false;
            for (std::uint32_t p = 0; p < ps.size() && !expected; ++p) expected = exact_side(p) == sigma;
            const std::optional<std::uint32_t> got = tree.any_beyond(x, normal.data(), sigma, exact_side);
            EXPECT_EQ(got.has_value(), expected);
            if (got) {
              EXPECT_EQ(exact_side(*got), sigma);
            }
          }
        }
        std::size_t visited = 0;
        tree.find_first([](const float*, const float*) { return true; },
                        [&](std::uint32_t) {
                          ++visited;
                          return false;
                        });
        EXPECT_EQ(visited, ps.size());
      }
    }
  }
}

}  // namespace
}  // namespace spokemesh
