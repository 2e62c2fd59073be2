// Triangulation<D> (core/src/mesh/triangulation.hpp), the whole mesh's kernel in 2-d
// and 3-d: valid after every insertion on small inputs, equal to CGAL's Delaunay
// triangulation simplex for simplex (random, grids, cospherical, the shape families of
// bench/shapes.py), and the same for any insertion order.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "cgal_oracle.hpp"
#include "inputs.hpp"  // bench/: the shape families
#include "mesh/triangulation.hpp"
#include "predicates/circumcentre_exact.hpp"
#include "spokemesh/space_split.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;

template <int D>
Tuples finite_cells(const detail::Triangulation<D>& t) {
  Tuples out;
  std::vector<bool> live(1, true);
  // Live cells: those reachable from the vertices' incident cells.
  std::vector<std::uint32_t> cells, seen;
  for (std::uint32_t v = 1; v < t.vertex_count(); ++v) t.incident_cells(v, cells, seen);
  for (const std::uint32_t c : cells) {
    if (t.is_infinite(c)) continue;
    std::vector<std::uint32_t> tuple;
    for (const std::uint32_t v : t.cell(c).v) tuple.push_back(t.global(v));
    std::sort(tuple.begin(), tuple.end());
    out.insert(tuple);
  }
  return out;
}

template <int D>
Tuples triangulate(const PointSet& ps, const std::vector<std::uint32_t>& order, bool check_each = false) {
  const Predicates pred(ps);
  detail::Triangulation<D> t(ps, pred);
  for (const std::uint32_t id : order) {
    t.insert(id);
    if (check_each) {
      std::string why;
      EXPECT_TRUE(t.valid(&why)) << why << " after point " << id;
    }
  }
  std::string why;
  EXPECT_TRUE(t.valid(&why)) << why;
  return finite_cells(t);
}

struct Case {
  std::string name;
  int d;
  std::vector<double> coords;
};

std::vector<double> on_sphere(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g;
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    double v[3] = {g(rng), g(rng), g(rng)};
    const double r = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    c.insert(c.end(), {v[0] / r, v[1] / r, v[2] / r});
  }
  return c;
}

std::vector<double> contour_lines(int curves, double step, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> phase(0, 6.283185307179586);
  std::vector<double> c;
  for (int k = 0; k < curves; ++k) {
    const double r0 = 5 + 8 * k, ph = phase(rng);
    const int count = static_cast<int>(6.283185307179586 * r0 / step);
    for (int i = 0; i < count; ++i) {
      const double t = 6.283185307179586 * i / count;
      const double r = r0 * (1 + 0.05 * std::sin(3 * t + ph));
      c.push_back(std::round(r * std::cos(t) * 1000) / 1000);
      c.push_back(std::round(r * std::sin(t) * 1000) / 1000);
    }
  }
  return c;
}

std::vector<Case> cases() {
  std::vector<Case> out = {
      {"uniform-2d", 2, uniform_points(2, 3000, 21)},
      {"uniform-3d", 3, uniform_points(3, 2000, 22)},
      {"grid-2d", 2, grid_points(2, 30)},
      {"grid-3d", 3, grid_points(3, 9)},
      {"linspace-grid-2d", 2, scaled_grid_points(2, 25, linspace_value)},
      {"linspace-grid-3d", 3, scaled_grid_points(3, 8, linspace_value)},
      {"decimal-grid-3d", 3, scaled_grid_points(3, 7, decimal_value)},
      {"circle-2d", 2, sphere_points(2, 325, true)},
      {"sphere-3d", 3, sphere_points(3, 50, true)},
      {"float-sphere-3d", 3, on_sphere(1500, 5)},
      {"contours-2d", 2, contour_lines(6, 0.5, 7)},
  };
  std::vector<double> bcc = grid_points(3, 4);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) bcc.insert(bcc.end(), {i + 0.5, j + 0.5, k + 0.5});
  out.push_back({"bcc-3d", 3, bcc});
  // A flat square of grid points with a few points off the plane: coplanar hull faces.
  std::vector<double> slab = grid_points(2, 12);
  std::vector<double> slab3;
  for (std::size_t i = 0; i < slab.size(); i += 2) slab3.insert(slab3.end(), {slab[i], slab[i + 1], 0.0});
  slab3.insert(slab3.end(), {5.5, 5.5, 3.0, 2.0, 7.0, -1.5, 12.5, 3.0, 0.0, -2.0, -2.0, 0.0});
  out.push_back({"flat-grid+apexes-3d", 3, slab3});
  return out;
}

TEST(Triangulation, EqualsCgalInAnyOrder) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    std::vector<std::uint32_t> order(ps.size());
    std::iota(order.begin(), order.end(), 0u);
    const Tuples cgal = c.d == 2 ? cgal_2(ps) : cgal_3(ps);
    const Tuples ours = c.d == 2 ? triangulate<2>(ps, order) : triangulate<3>(ps, order);
    EXPECT_EQ(ours.size(), cgal.size());
    EXPECT_TRUE(ours == cgal) << "index order";
    for (std::uint64_t seed : {1u, 2u}) {
      std::mt19937_64 rng(seed);
      std::shuffle(order.begin(), order.end(), rng);
      const Tuples shuffled = c.d == 2 ? triangulate<2>(ps, order) : triangulate<3>(ps, order);
      EXPECT_TRUE(shuffled == cgal) << "shuffled order, seed " << seed;
    }
  }
}

TEST(Triangulation, ValidAfterEveryInsertion) {
  // Small sets, checked whole after each point (degenerate starts included: the first
  // points of a grid in index order are collinear, then coplanar).
  for (const Case& c :
       {Case{"grid-3d", 3, grid_points(3, 4)}, Case{"grid-2d", 2, grid_points(2, 6)},
        Case{"uniform-3d", 3, uniform_points(3, 60, 3)}, Case{"sphere-3d", 3, sphere_points(3, 9, true)}}) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    std::vector<std::uint32_t> order(ps.size());
    std::iota(order.begin(), order.end(), 0u);
    const Tuples ours = c.d == 2 ? triangulate<2>(ps, order, true) : triangulate<3>(ps, order, true);
    EXPECT_TRUE(ours == (c.d == 2 ? cgal_2(ps) : cgal_3(ps)));
  }
}

// The triangulation of every point built on its own (triangulate_whole), read star by
// star: every seed's star the star walk's, simplex for simplex, for kAll and kOwned, on
// every degenerate case and shape family (ties on grids and spheres included); its
// owner index holds each finite cell once.
TEST(WholeTriangulation, StarsAreTheStarWalks) {
  std::vector<Case> all = cases();
  for (auto& shape : bench::shape_families(1200, 43)) all.push_back({shape.name, shape.d, std::move(shape.coords)});
  for (const Case& c : all) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    auto whole = triangulate_whole(ps);
    ASSERT_TRUE(whole.is_ok()) << whole.status().message();
    EXPECT_EQ(&whole.value()->point_set(), &ps);
    EXPECT_GT(whole.value()->bytes(), ps.size() * 8);
    WholeStarReader reader(*whole.value());
    StarWalker walker(tree);
    Star a, b;
    // (Seeds spread over the set: a star walk on a surface takes milliseconds.)
    const std::uint32_t stride = std::max<std::uint32_t>(1, static_cast<std::uint32_t>(ps.size() / 200));
    for (std::uint32_t seed = 0; seed < ps.size(); seed += stride) {
      ASSERT_TRUE(walker.compute(seed, a, StarPart::kAll).is_ok());
      ASSERT_TRUE(reader.star(seed, b, StarPart::kAll).is_ok());
      ASSERT_EQ(a.simplices, b.simplices) << "seed " << seed << " (all)";
      ASSERT_EQ(a.hull_facets, b.hull_facets) << "seed " << seed;
      // The owned part: the suffix of the whole star.
      const auto owned = owned_simplices(a);
      ASSERT_TRUE(reader.star(seed, b, StarPart::kOwned).is_ok());
      ASSERT_TRUE(std::equal(owned.begin(), owned.end(), b.simplices.begin(), b.simplices.end())) << "seed " << seed;
    }
    EXPECT_EQ(reader.star(static_cast<std::uint32_t>(ps.size()), b).code(), Code::kOutOfRange);
  }
  // Outside 2-d and 3-d, refused by name; a refused reservation, by name.
  const PointSet four = make_points(4, uniform_points(4, 50, 1));
  EXPECT_EQ(triangulate_whole(four).status().code(), Code::kInvalidArgument);
  const PointSet big = make_points(3, uniform_points(3, 20000, 2));
  WholeOptions refuse;
  refuse.reserve_bytes = [](std::size_t) { return false; };
  EXPECT_EQ(triangulate_whole(big, refuse).status().code(), Code::kResourceExhausted);
}

// A set with points appended (extend_whole): the first set's triangulation copied and
// the rest inserted gives every star the triangulation of all the points gives (the
// service's :append keeps its parent's triangulation this way), on every degenerate
// case and shape family, with 1% to half of the points new; a set that does not begin
// with the first's points is refused by name.
TEST(WholeTriangulation, ExtendingItIsBuildingItAgain) {
  std::vector<Case> all = cases();
  for (auto& shape : bench::shape_families(1200, 44)) all.push_back({shape.name, shape.d, std::move(shape.coords)});
  for (const Case& c : all) {
    const PointSet ps = make_points(c.d, c.coords);
    const auto whole = triangulate_whole(ps);
    ASSERT_TRUE(whole.is_ok()) << c.name;
    WholeStarReader expected(*whole.value());
    for (const double kept : {0.5, 0.99}) {
      SCOPED_TRACE(c.name + ", the first " + std::to_string(kept) + " of it kept");
      auto n0 = static_cast<std::size_t>(kept * static_cast<double>(ps.size()));
      // The first set must be full-dimensional on its own (as a stored set is).
      std::shared_ptr<const WholeTriangulation> base;
      std::optional<PointSet> first;
      for (; n0 <= ps.size() && base == nullptr; ++n0) {
        first.emplace(c.d, std::vector<double>(c.coords.begin(), c.coords.begin() + n0 * c.d));
        if (!first->validate("first").is_ok()) continue;  // flat
        if (auto b = triangulate_whole(*first); b.is_ok()) base = std::move(b).value();
      }
      ASSERT_NE(base, nullptr);
      std::size_t charged = 0;
      WholeOptions count;
      count.reserve_bytes = [&](std::size_t bytes) {
        charged += bytes;
        return true;
      };
      auto extended = extend_whole(*base, ps, count);
      ASSERT_TRUE(extended.is_ok()) << extended.status().message();
      EXPECT_GE(charged, extended.value()->bytes()) << "what it holds is charged";
      WholeStarReader reader(*extended.value());
      Star a, b;
      for (std::uint32_t seed = 0; seed < ps.size(); ++seed) {
        ASSERT_TRUE(expected.star(seed, a).is_ok());
        ASSERT_TRUE(reader.star(seed, b).is_ok());
        ASSERT_EQ(a.simplices, b.simplices) << "seed " << seed;
        ASSERT_EQ(a.hull_facets, b.hull_facets) << "seed " << seed;
        ASSERT_TRUE(reader.star(seed, b, StarPart::kOwned).is_ok());
        ASSERT_TRUE(expected.star(seed, a, StarPart::kOwned).is_ok());
        ASSERT_EQ(a.simplices, b.simplices) << "seed " << seed << " (owned)";
      }
      // The base is untouched: its own stars are still its set's.
      WholeStarReader before(*base);
      ASSERT_TRUE(before.star(0, b).is_ok());
    }
  }
  const PointSet a = make_points(3, uniform_points(3, 400, 5)), b = make_points(3, uniform_points(3, 800, 6));
  const auto base = triangulate_whole(a).value();
  EXPECT_EQ(extend_whole(*base, b).status().code(), Code::kInvalidArgument) << "not its points first";
  const PointSet smaller = make_points(3, uniform_points(3, 200, 5));
  EXPECT_EQ(extend_whole(*base, smaller).status().code(), Code::kInvalidArgument);
  WholeOptions refuse;
  refuse.reserve_bytes = [](std::size_t) { return false; };
  std::vector<double> more = uniform_points(3, 400, 5), extra = uniform_points(3, 100, 7);
  more.insert(more.end(), extra.begin(), extra.end());
  const PointSet grown = make_points(3, more);
  EXPECT_EQ(extend_whole(*base, grown, refuse).status().code(), Code::kResourceExhausted);
  EXPECT_TRUE(extend_whole(*base, grown).is_ok());
}

// --- The whole mesh by local triangulations (delaunay_sweep.cpp) --------------------

constexpr auto kStars = MeshEngine::kStars;
constexpr auto kTriangulations = MeshEngine::kTriangulations;

Simplices sweep(const KdTree& tree, unsigned threads, std::uint32_t region_points, MeshStats* stats = nullptr,
                std::uint32_t seed_begin = 0, std::uint32_t seed_end = 0xFFFFFFFFu, std::uint32_t sweep_begin = 0,
                std::uint32_t sweep_end = 0xFFFFFFFFu) {
  MeshOptions options;
  options.engine = kTriangulations;
  options.threads = threads;
  options.region_points = region_points;
  options.seed_begin = seed_begin;
  options.seed_end = seed_end;
  options.sweep_begin = sweep_begin;
  options.sweep_end = sweep_end;
  return mesh_rows(tree, options, stats);
}

// Every shape family and every degenerate case, at a few thousand points,
// with regions small enough that margins, tree queries and the triangulation of every
// point all serve: the same bytes as the star walk's sweep, for any thread count and
// region size, and CGAL's simplices.
TEST(TriangulationSweep, SameBytesAsTheStarWalkOnEveryShape) {
  std::vector<Case> all = cases();
  for (auto& shape : bench::shape_families(3000, 41)) all.push_back({shape.name, shape.d, std::move(shape.coords)});
  for (const Case& c : all) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Simplices stars = mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, 0, kStars);
    EXPECT_TRUE(as_set(stars, c.d + 1) == (c.d == 2 ? cgal_2(ps) : cgal_3(ps)));
    for (const std::uint32_t region : {0u, 97u, 600u}) {
      for (const unsigned threads : {1u, 3u}) {
        SCOPED_TRACE("region " + std::to_string(region) + ", threads " + std::to_string(threads));
        EXPECT_EQ(sweep(tree, threads, region), stars);
      }
    }
  }
}

// Without a k-d tree (mesh_seeds over the points: the split's own index answers the
// region's box queries), the same bytes; the star walk's sweep builds its tree.
TEST(TriangulationSweep, WithoutATreeTheSameBytes) {
  for (auto& shape : bench::shape_families(3000, 13)) {
    if (shape.name != "rings" && shape.name != "sphere" && shape.name != "contours" && shape.name != "contrast")
      continue;
    SCOPED_TRACE(shape.name);
    const PointSet ps = make_points(shape.d, shape.coords);
    const KdTree tree(ps);
    for (const std::uint32_t region : {0u, 400u}) {
      MeshOptions options;
      options.threads = 2;
      options.region_points = region;
      EXPECT_EQ(mesh_rows(ps, options), sweep(tree, 2, region)) << "region " << region;
    }
  }
}

// A batch of seeds: only those seeds' stars, each whole and canonical (accept_part
// kAll) as StarWalker::compute gives it on its own, from both engines.
TEST(TriangulationSweep, SeedListsGiveWholeStars) {
  for (auto& shape : bench::shape_families(1200, 17)) {
    if (shape.name != "terrain" && shape.name != "sphere" && shape.name != "contours") continue;
    SCOPED_TRACE(shape.name);
    const PointSet ps = make_points(shape.d, shape.coords);
    const KdTree tree(ps);
    std::vector<std::uint32_t> seeds;
    for (std::uint32_t s = 3; s < ps.size(); s += 7) seeds.push_back(s);
    StarWalker walker(tree);
    for (const MeshEngine engine : {kStars, kTriangulations}) {
      MeshOptions options;
      options.engine = engine;
      options.threads = 2;
      options.region_points = 500;
      options.seeds = seeds;
      options.accept_part = StarPart::kAll;
      std::mutex mu;
      std::map<std::uint32_t, Star> stars;
      options.accept = [&](const Star& star) {
        std::lock_guard lock(mu);
        stars[star.seed] = star;
        return false;  // no rows: the stars are the answer
      };
      EXPECT_TRUE(mesh_rows(tree, options).empty());
      ASSERT_EQ(stars.size(), seeds.size());
      Star expected;
      for (const std::uint32_t s : seeds) {
        ASSERT_TRUE(walker.compute(s, expected).is_ok());
        EXPECT_EQ(stars[s].simplices, expected.simplices) << "seed " << s;
        EXPECT_EQ(stars[s].hull_facets, expected.hull_facets) << "seed " << s;
      }
    }
  }
}

// Seed ranges and sweep ranges: the parts are the star walk's parts, and consecutive
// sweep ranges concatenate to the whole run.
TEST(TriangulationSweep, PartsAreTheStarWalksParts) {
  for (auto& shape : bench::shape_families(2500, 7)) {
    if (shape.name != "rings" && shape.name != "contours" && shape.name != "clustered") continue;
    SCOPED_TRACE(shape.name);
    const PointSet ps = make_points(shape.d, shape.coords);
    const KdTree tree(ps);
    const auto n = static_cast<std::uint32_t>(ps.size());
    const Simplices whole = sweep(tree, 2, 300);
    for (const auto& [b, e] : {std::pair{0u, n / 3}, std::pair{n / 3, n / 3 + 40}, std::pair{n - 5, n}}) {
      EXPECT_EQ(sweep(tree, 2, 300, nullptr, b, e),
                mesh_all(tree, 2, b, e, 0x5eed, MeshOptions{}.facet_cache_bytes, 0, kStars));
    }
    Simplices joined;
    for (std::uint32_t at = 0; at < n; at += 777) {
      const Simplices part = sweep(tree, 2, 300, nullptr, 0, 0xFFFFFFFFu, at, at + 777);
      joined.insert(joined.end(), part.begin(), part.end());
    }
    EXPECT_EQ(joined, whole);
  }
}

// The input's order does not matter: a permuted set's mesh, mapped back, is the same
// set of oriented simplices (rows are in sweep order by owner: mapped back, sorted),
// and CGAL's, on every shape family.
TEST(TriangulationSweep, PermutedInputMapsBack) {
  for (auto& shape : bench::shape_families(2000, 9)) {
    SCOPED_TRACE(shape.name);
    const int d = shape.d;
    const std::size_t n = shape.coords.size() / d;
    std::vector<std::uint32_t> perm(n);
    std::iota(perm.begin(), perm.end(), 0u);
    std::shuffle(perm.begin(), perm.end(), std::mt19937_64(3));
    std::vector<double> permuted(shape.coords.size());
    for (std::size_t i = 0; i < n; ++i) std::copy_n(&shape.coords[perm[i] * d], d, &permuted[i * d]);
    const PointSet a = make_points(d, shape.coords), b = make_points(d, permuted);
    const KdTree ta(a), tb(b);
    Simplices mapped = sweep(tb, 2, 250);
    for (auto& v : mapped) v = perm[v];
    const Tuples original = as_set(sweep(ta, 2, 250), d + 1);
    EXPECT_TRUE(as_set(mapped, d + 1) == original);
    EXPECT_TRUE(original == (d == 2 ? cgal_2(a) : cgal_3(a)));
  }
}

// The certificates each serve where they should: on uniform points, margins and a
// few tree queries (never every point at once); on a sphere's surface, whose every
// Delaunay ball is the sphere itself, the triangulation of every point.
TEST(TriangulationSweep, EachCertificateWhereItBelongs) {
  {
    const PointSet ps = make_points(3, uniform_points(3, 60000, 5));
    const KdTree tree(ps);
    MeshStats stats;
    sweep(tree, 2, 20000, &stats);
    EXPECT_FALSE(stats.triangulation.whole_set);
    EXPECT_GE(stats.triangulation.regions, 4u);
    EXPECT_GT(stats.triangulation.ball_queries, 0u);
    EXPECT_LT(stats.triangulation.inserted, 2 * ps.size()) << "margins should be a fraction of the regions";
  }
  {
    const PointSet ps = make_points(3, bench::sphere_surface(20000, 5));
    const KdTree tree(ps);
    MeshStats stats;
    sweep(tree, 2, 2000, &stats);
    EXPECT_TRUE(stats.triangulation.whole_set);
  }
  {
    // The whole set's rows come from its owner index: the star walk's bytes.
    const PointSet ps = make_points(3, bench::sphere_surface(1500, 7));
    const KdTree tree(ps);
    MeshStats stats;
    const Simplices rows = sweep(tree, 2, 300, &stats);
    EXPECT_TRUE(stats.triangulation.whole_set);
    EXPECT_EQ(rows, mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, 0, MeshEngine::kStars));

    // Kept (MeshOptions::keep_whole) by a run that offers whole stars, as the service's
    // batches do, then given to later runs (MeshOptions::whole): they build nothing and
    // give the same rows, with or without the owner index; a set that is not the one it
    // was built on ignores it.
    std::shared_ptr<const WholeTriangulation> kept;
    MeshOptions options;
    options.engine = kTriangulations;
    options.threads = 2;
    options.region_points = 300;
    options.accept_part = StarPart::kAll;
    std::map<std::uint32_t, std::vector<std::uint32_t>> stars, again;
    std::mutex mu;
    auto collect = [&](std::map<std::uint32_t, std::vector<std::uint32_t>>& into) {
      return [&](const Star& star) {
        std::lock_guard lock(mu);
        into[star.seed] = star.simplices;
        return true;
      };
    };
    options.accept = collect(stars);
    options.keep_whole = [&](std::shared_ptr<const WholeTriangulation> w) { kept = std::move(w); };
    mesh_rows(tree, options, nullptr);
    ASSERT_NE(kept, nullptr);
    EXPECT_GT(kept->bytes(), 0u);
    options.keep_whole = nullptr;
    options.whole = kept;
    options.accept = collect(again);
    MeshStats with_kept;
    mesh_rows(tree, options, &with_kept);
    EXPECT_EQ(again, stars);
    EXPECT_TRUE(with_kept.triangulation.whole_set);
    EXPECT_EQ(with_kept.triangulation.inserted, 0u) << "a kept triangulation is read, not rebuilt";
    MeshOptions rows_only;
    rows_only.engine = kTriangulations;
    rows_only.threads = 3;
    rows_only.region_points = 300;
    rows_only.whole = kept;  // built without the owner index: its rows by the cells around each seed
    MeshStats rows_stats;
    EXPECT_EQ(mesh_rows(tree, rows_only, &rows_stats), rows);
    EXPECT_EQ(rows_stats.triangulation.inserted, 0u);
    const PointSet copy = make_points(3, bench::sphere_surface(1500, 7));  // equal points, another object
    const KdTree copy_tree(copy);
    MeshStats copy_stats;
    EXPECT_EQ(mesh_rows(copy_tree, rows_only, &copy_stats), rows);
    EXPECT_GT(copy_stats.triangulation.inserted, 0u) << "another set's triangulation is ignored";
  }
}

// Memory refused (MeshOptions::reserve_bytes): the regions, or only the triangulation
// of every point that a sphere's surface needs, give way to star walks; the same rows.
TEST(TriangulationSweep, RefusedMemoryWalksTheStars) {
  for (const bool sphere : {false, true}) {
    SCOPED_TRACE(sphere ? "sphere" : "uniform");
    const PointSet ps = make_points(3, sphere ? bench::sphere_surface(800, 2) : uniform_points(3, 3000, 2));
    const KdTree tree(ps);
    const Simplices stars = mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, 0, kStars);
    // Nothing granted; or the first requests granted (16 MiB covers a region here:
    // each worker asks once), and the rest, the triangulation of every point's among
    // them, refused.
    for (const std::size_t grants : {0u, 1u, 2u, 3u}) {
      MeshOptions options;
      options.engine = kTriangulations;
      options.threads = 2;
      options.region_points = 300;
      std::size_t asked = 0;
      options.reserve_bytes = [&](std::size_t) { return ++asked <= grants; };
      MeshStats stats;
      EXPECT_EQ(mesh_rows(tree, options, &stats), stars) << grants << " grants";
      if (grants == 0) {
        EXPECT_EQ(stats.triangulation.walked_seeds, ps.size()) << "every region refused: every star walked";
      }
      if (asked > grants) {
        EXPECT_GT(stats.triangulation.walked_seeds, 0u) << "a refusal walks stars";
      }
    }
  }
}

// The work per point follows the stars, not the shape around them: eight
// times the points on a sphere's surface (where every Delaunay ball is the sphere
// itself, and a global query per ball visited every point) or on a terrain cost the
// same per point, in insertions and in k-d tree queries, with no star's sphere queried
// against the whole set.
TEST(TriangulationSweep, WorkPerPointDoesNotGrowWithN) {
  struct Family {
    const char* name;
    std::vector<double> (*make)(std::size_t);
  };
  const Family families[] = {
      {"sphere", [](std::size_t n) { return bench::sphere_surface(n, 7); }},
      {"terrain", [](std::size_t n) { return bench::terrain(n, 1000 * std::sqrt(n / 200000.0), 7); }},
      {"uniform", [](std::size_t n) { return uniform_points(3, n, 7); }},
  };
  for (const Family& f : families) {
    double per_point[2][2] = {};
    for (int k = 0; k < 2; ++k) {
      const std::size_t n = k == 0 ? 12000 : 96000;
      const PointSet ps = make_points(3, f.make(n));
      const KdTree tree(ps);
      MeshStats stats;
      sweep(tree, 2, 3000, &stats);
      per_point[k][0] = static_cast<double>(stats.triangulation.inserted) / static_cast<double>(n);
      per_point[k][1] = static_cast<double>(stats.triangulation.ball_queries) / static_cast<double>(n);
      std::printf("%s n %zu: %.2f insertions and %.3f tree queries per point, %llu sphere queries\n", f.name, n,
                  per_point[k][0], per_point[k][1], static_cast<unsigned long long>(stats.star.sphere_queries));
      EXPECT_EQ(stats.star.sphere_queries, 0u) << f.name << ": no star walked";
    }
    EXPECT_LT(per_point[1][0], 1.5 * per_point[0][0] + 0.05) << f.name << ": insertions per point grew with n";
    EXPECT_LT(per_point[1][1], 1.5 * per_point[0][1] + 0.05) << f.name << ": tree queries per point grew with n";
  }
}

// MeshEngine::kAuto: local triangulations, but the star walk where exact ties dominate
// (grids), and wherever triangulations do not apply (4-d, weights); explicit choices stand.
TEST(TriangulationSweep, AutoTakesTheStarWalkOnGrids) {
  auto engine = [](int d, std::vector<double> coords, MeshEngine asked = MeshEngine::kAuto) {
    const PointSet ps = make_points(d, std::move(coords));
    const SpaceSplit split(ps, 4096);
    MeshOptions options;
    options.engine = asked;
    return engine_for(ps, split, options);
  };
  EXPECT_EQ(engine(3, uniform_points(3, 5000, 1)), kTriangulations);
  EXPECT_EQ(engine(2, uniform_points(2, 5000, 1)), kTriangulations);
  EXPECT_EQ(engine(3, bench::sphere_surface(5000, 1)), kTriangulations);
  EXPECT_EQ(engine(3, grid_points(3, 20)), kStars);
  EXPECT_EQ(engine(2, grid_points(2, 80)), kStars);
  EXPECT_EQ(engine(3, scaled_grid_points(3, 20, linspace_value)), kStars);
  EXPECT_EQ(engine(4, uniform_points(4, 500, 1)), kStars);
  EXPECT_EQ(engine(3, grid_points(3, 20), kTriangulations), kTriangulations);
  EXPECT_EQ(engine(3, uniform_points(3, 5000, 1), kStars), kStars);
}

// A refused star emits nothing, as in the star walk's sweep (spokemesh-mpi refuses the
// stars it cannot certify from the points it holds); accepted stars are whole.
TEST(TriangulationSweep, AcceptSeesWholeStars) {
  const PointSet ps = make_points(3, uniform_points(3, 3000, 8));
  const KdTree tree(ps);
  auto run = [&](MeshEngine engine) {
    MeshOptions options;
    options.engine = engine;
    options.threads = 2;
    options.region_points = 400;
    std::mutex mu;
    std::map<std::uint32_t, std::set<std::vector<std::uint32_t>>> stars;
    options.accept = [&](const Star& star) {
      std::set<std::vector<std::uint32_t>> s;
      for (std::size_t i = 0; i < star.size(); ++i) {
        std::vector<std::uint32_t> t(star.simplex(i), star.simplex(i) + 4);
        std::sort(t.begin(), t.end());
        s.insert(t);
      }
      std::lock_guard lock(mu);
      stars[star.seed] = std::move(s);
      return star.seed % 3 != 0;
    };
    const Simplices out = mesh_rows(tree, options);
    return std::pair{out, stars};
  };
  const auto [stars_rows, stars_seen] = run(kStars);
  const auto [tri_rows, tri_seen] = run(kTriangulations);
  EXPECT_EQ(tri_rows, stars_rows);
  EXPECT_TRUE(tri_seen == stars_seen);
  EXPECT_EQ(tri_seen.size(), ps.size());
}

// The exact circumcentre by integers (Cramer's rule on coordinates scaled to integers)
// is the rational one (Gaussian elimination in mpq) bit for bit, on what reaches the
// exact path: slivers (nearly coplanar tetrahedra, nearly collinear triangles), tiny
// simplices far from the origin, coordinates of wildly different magnitudes, zeros and
// negative values; and a flat simplex is left to the rational path. Seed printed.
TEST(CircumcentreExact, IntegersGiveTheRationalsBits) {
  const std::uint64_t seed = 52;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  std::uniform_int_distribution<int> exponent(-60, 60);
  int compared = 0;
  for (int d = 2; d <= 3; ++d) {
    for (int trial = 0; trial < 3000; ++trial) {
      std::vector<double> coords(static_cast<std::size_t>((d + 1) * d));
      const int kind = trial % 5;
      for (int i = 0; i <= d; ++i) {
        for (int c = 0; c < d; ++c) {
          double x = unit(rng);
          if (kind == 1 && c == d - 1) x = 1e-9 * x;        // a sliver: the last coordinate nearly 0
          if (kind == 2) x = 1e6 + 1e-4 * x;                // tiny, far away
          if (kind == 3) x = std::ldexp(x, exponent(rng));  // magnitudes far apart
          if (kind == 4 && (i + c) % 3 == 0) x = 0;         // zeros
          coords[static_cast<std::size_t>(i * d + c)] = x;
        }
      }
      const PointSet ps(d, coords);
      const std::uint32_t ids[4] = {0, 1, 2, 3};
      double got[3] = {0, 0, 0};
      if (!detail::circumcentre_integer(ps, ids, d, got)) continue;  // flat
      const std::vector<double> want = detail::circumcentre_rational(ps, ids, d, nullptr);
      ++compared;
      for (int c = 0; c < d; ++c) {
        ASSERT_EQ(std::memcmp(&got[c], &want[static_cast<std::size_t>(c)], sizeof(double)), 0)
            << "seed " << seed << ", d " << d << ", trial " << trial << ", coordinate " << c << ": " << got[c] << " vs "
            << want[static_cast<std::size_t>(c)];
      }
    }
  }
  EXPECT_GT(compared, 5900);
  // Flat: three collinear points in 2-d.
  const PointSet flat(2, {0, 0, 1, 1, 2, 2});
  const std::uint32_t ids[3] = {0, 1, 2};
  double out[2] = {7, 7};
  EXPECT_FALSE(detail::circumcentre_integer(flat, ids, 2, out));
  EXPECT_EQ(out[0], 7);
}

}  // namespace
}  // namespace spokemesh
