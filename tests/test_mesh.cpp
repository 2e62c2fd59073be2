// Whole meshes: identical for any thread count and seed partition; equal simplex for
// simplex to CGAL's Delaunay triangulations (random, grid, cospherical; d = 2..6)
// and to Qhull's on random inputs; accepted by `check`, which rejects corruptions.

#include <gmpxx.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <random>
#include <thread>

#include "cgal_oracle.hpp"
#include "spokemesh/facet_cache.hpp"
#include "spokemesh/validate.hpp"
#include "spokemesh/voronoi.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;

struct Case {
  std::string name;
  int d;
  std::vector<double> coords;
};

std::vector<Case> cgal_cases() {
  std::vector<Case> cases = {
      {"uniform-2d", 2, uniform_points(2, 3000, 21)},
      {"uniform-3d", 3, uniform_points(3, 1500, 22)},
      {"uniform-4d", 4, uniform_points(4, 400, 23)},
      {"uniform-5d", 5, uniform_points(5, 120, 24)},
      {"uniform-6d", 6, uniform_points(6, 60, 25)},
      {"grid-2d", 2, grid_points(2, 30)},
      {"grid-3d", 3, grid_points(3, 8)},
      {"grid-4d", 4, grid_points(4, 4)},
      {"grid-5d", 5, grid_points(5, 3)},
      {"cube-6d", 6, grid_points(6, 2)},
      {"linspace-grid-2d", 2, scaled_grid_points(2, 25, linspace_value)},
      {"linspace-grid-3d", 3, scaled_grid_points(3, 8, linspace_value)},
      {"decimal-grid-3d", 3, scaled_grid_points(3, 7, decimal_value)},
      {"dyadic-grid-3d", 3, scaled_grid_points(3, 7, dyadic_value)},
      {"linspace-grid-4d", 4, scaled_grid_points(4, 4, linspace_value)},
      {"circle-2d", 2, sphere_points(2, 325, true)},
      {"sphere-3d", 3, sphere_points(3, 50, true)},
      {"sphere-4d", 4, sphere_points(4, 12, false)},
  };
  // Grid with random points mixed in: degenerate and generic together.
  auto mixed = grid_points(3, 5);
  const auto extra = uniform_points(3, 40, 26);
  for (double v : extra) mixed.push_back(v * 4);
  cases.push_back({"grid+uniform-3d", 3, mixed});
  // Body-centred cubic lattice: every tetrahedron's circumsphere holds extra points.
  std::vector<double> bcc = grid_points(3, 4);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) bcc.insert(bcc.end(), {i + 0.5, j + 0.5, k + 0.5});
  cases.push_back({"bcc-3d", 3, bcc});
  return cases;
}

TEST(MeshVsCgal, SimplexForSimplex) {
  for (const Case& c : cgal_cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Tuples ours = as_set(mesh_all(tree, 2), c.d + 1);
    EXPECT_EQ(ours, cgal_dd(ps)) << "vs CGAL Delaunay_triangulation (dD)";
    if (c.d == 2) {
      EXPECT_EQ(ours, cgal_2(ps)) << "vs CGAL Delaunay_triangulation_2";
    }
    if (c.d == 3) {
      EXPECT_EQ(ours, cgal_3(ps)) << "vs CGAL Delaunay_triangulation_3";
    }
  }
}

TEST(StarVsCgal, EveryStarIsCgalsIncidentSimplices) {
  for (const Case& c : cgal_cases()) {
    if (c.coords.size() / c.d > 800) continue;
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Tuples cgal = cgal_dd(ps);
    std::vector<Tuples> incident(ps.size());
    for (const auto& t : cgal) {
      for (std::uint32_t v : t) incident[v].insert(t);
    }
    StarWalker walker(tree);
    Star star;
    for (std::uint32_t s = 0; s < ps.size(); s += 1 + static_cast<std::uint32_t>(ps.size() / 60)) {
      ASSERT_TRUE(walker.compute(s, star).is_ok());
      EXPECT_EQ(as_set(star.simplices, c.d + 1), incident[s]) << "seed " << s;
    }
  }
}

// --- Qhull ------------------------------------------------------------------------

Tuples qhull_mesh(const PointSet& ps) {
  const std::string in = ::testing::TempDir() + "/qhull_in.txt";
  {
    std::ofstream f(in);
    f.precision(17);
    f << ps.dimension() << "\n" << ps.size() << "\n";
    for (std::size_t i = 0; i < ps.size(); ++i) {
      for (int c = 0; c < ps.dimension(); ++c) f << ps.point(i)[c] << (c + 1 == ps.dimension() ? "\n" : " ");
    }
  }
  Tuples out;
  std::FILE* p = ::popen(("qdelaunay Qt i < " + in).c_str(), "r");
  if (p == nullptr) return out;
  char line[4096];
  bool first = true;
  while (std::fgets(line, sizeof line, p) != nullptr) {
    if (first) {  // the simplex count
      first = false;
      continue;
    }
    std::vector<std::uint32_t> t;
    for (char* s = line; *s;) {
      char* end;
      const unsigned long v = std::strtoul(s, &end, 10);
      if (end == s) break;
      t.push_back(static_cast<std::uint32_t>(v));
      s = end;
    }
    std::sort(t.begin(), t.end());
    out.insert(t);
  }
  ::pclose(p);
  return out;
}

TEST(MeshVsQhull, RandomInputs) {
  for (int d = 2; d <= 5; ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const std::size_t n = d == 2 ? 2000 : d == 3 ? 800 : d == 4 ? 250 : 100;
    const PointSet ps = make_points(d, uniform_points(d, n, 300 + d));
    const KdTree tree(ps);
    const Tuples q = qhull_mesh(ps);
    ASSERT_FALSE(q.empty()) << "qdelaunay (qhull-bin) did not run";
    EXPECT_EQ(as_set(mesh_all(tree), d + 1), q);
  }
}

// --- Determinism and partitions ----------------------------------------------------

TEST(Mesh, ByteIdenticalForAnyThreadCountOrBlockSizeInSweepOrder) {
  for (int d = 2; d <= 4; ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const PointSet ps = make_points(d, uniform_points(d, d == 4 ? 300 : 1500, 40 + d));
    const KdTree tree(ps);
    const Simplices one = mesh_all(tree, 1);
    EXPECT_EQ(mesh_all(tree, 2), one);
    EXPECT_EQ(mesh_all(tree, 7), one);
    // The star walk's sweep and the local triangulations' (d = 2, 3) write the same bytes.
    EXPECT_EQ(mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, 0, MeshEngine::kStars), one);
    EXPECT_EQ(mesh_all(tree, 3, 0, 0xFFFFFFFFu, /*random_seed=*/12345), one);
    for (const std::uint32_t block : {1u, 17u, 100u, 100000u}) {
      SCOPED_TRACE("block " + std::to_string(block));
      EXPECT_EQ(mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, block), one);
    }
    const int w = d + 1;
    const Predicates pred(ps);
    const SpaceSplit split(ps, 64);
    const auto sorted = [&](std::size_t i) {
      std::vector<std::uint32_t> s(one.begin() + i, one.begin() + i + w);
      std::sort(s.begin(), s.end());
      return s;
    };
    for (std::size_t i = 0; i < one.size(); i += w) {
      // Positively oriented, ascending but for the last two vertices.
      ASSERT_GT(pred.orientation(std::span<const std::uint32_t>(one.data() + i, w)), 0);
      ASSERT_TRUE(std::is_sorted(one.begin() + i, one.begin() + i + w - 1));
      ASSERT_EQ(one[i], sorted(i)[0]);
      // Sweep order: owners by SpaceSplit position, an owner's simplices lexicographic.
      if (i + w < one.size()) {
        ASSERT_LE(split.position_of(one[i]), split.position_of(one[i + w]));
        if (one[i] == one[i + w]) {
          ASSERT_LT(sorted(i), sorted(i + w));
        }
      }
    }
  }
}

// The FacetCache (and in 2-d the EdgeCache) only saves work: with it, without it, and
// with a table so small that it fills up early, every mesh (degenerate inputs
// included) is the same, for any thread count. circle-2d's centre has 325 neighbours,
// far more posts than an EdgeCache point keeps.
TEST(Mesh, FacetCacheChangesNoSimplex) {
  constexpr auto kStars = MeshEngine::kStars;
  const std::size_t cache = MeshOptions{}.facet_cache_bytes;
  for (const Case& c : cgal_cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Simplices without = mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, /*facet_cache_bytes=*/0, 0, kStars);
    const std::size_t tiny = ps.size() * 4 + 1024 * (c.d + 3) * 4;  // the smallest table: 1,024 slots
    EXPECT_EQ(mesh_all(tree, 1, 0, 0xFFFFFFFFu, 0x5eed, cache, 0, kStars), without);
    EXPECT_EQ(mesh_all(tree, 7, 0, 0xFFFFFFFFu, 0x5eed, cache, 0, kStars), without);
    EXPECT_EQ(mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, tiny, 0, kStars), without);
    // A partial run shares only among its own seeds.
    const auto third = static_cast<std::uint32_t>(ps.size() / 3);
    EXPECT_EQ(mesh_all(tree, 2, third, 2 * third, 0x5eed, cache, 0, kStars),
              mesh_all(tree, 2, third, 2 * third, 0x5eed, 0, 0, kStars));
  }
}

// The process's mapped address space (VmSize), from /proc/self/status, in kB.
long vm_size_kb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmSize:", 0) == 0) return std::stol(line.substr(7));
  }
  return -1;
}

// Every whole mesh maps a FacetCache (3-d) or EdgeCache (2-d) and must return it: a
// deleter that recorded a zero length (munmap then fails) leaked the whole table on
// every run, which a server meshing for months cannot afford. Twenty meshes of one
// set must leave neither mapped cache bytes nor address space behind.
TEST(FacetCache, WholeMeshesReturnTheirCacheMemory) {
  for (const int d : {2, 3}) {
    SCOPED_TRACE(d);
    const PointSet ps = make_points(d, uniform_points(d, 20000, 7));
    const KdTree tree(ps);
    EXPECT_EQ(mapped_cache_bytes(), 0u);
    const Simplices first = mesh_all(tree, 2);  // warms up the allocator and threads
    const long before = vm_size_kb();
    ASSERT_GT(before, 0);
    for (int run = 0; run < 20; ++run) {
      MeshOptions options;
      options.threads = 2;
      options.engine = MeshEngine::kStars;  // the run-wide caches are the star walk's
      std::size_t cache_bytes = 0;
      auto r = mesh_seeds(tree, options, [](std::span<const std::uint32_t>, std::uint64_t) { return Status::ok(); });
      ASSERT_TRUE(r.is_ok());
      cache_bytes = r.value().facet_cache_bytes;
      ASSERT_GT(cache_bytes, 0u) << "the run must use a cache for this test to mean anything";
      EXPECT_EQ(mapped_cache_bytes(), 0u) << "run " << run;
    }
    // A leak of even the smallest table each run would add > 20 x 600 kB.
    EXPECT_LT(vm_size_kb() - before, 4096) << "address space grew across 20 meshes";
    EXPECT_EQ(mesh_all(tree, 2), first);
  }
}

TEST(FacetCache, KeepsFacetsForLaterSeedsAndAnswersEitherSide) {
  // 3-d: facets are triples. Seeds [10, 100) are meshed.
  FacetCache cache(3, 200, 10, 100, 1 << 20);
  ASSERT_TRUE(cache.enabled());
  const std::uint32_t f[3] = {12, 40, 150};
  std::uint32_t across = 0;
  EXPECT_FALSE(cache.wanted(40, f)) << "no later vertex below 100";
  EXPECT_TRUE(cache.wanted(12, f)) << "40 comes later";
  ASSERT_EQ(cache.reserve(2), 2u);
  cache.insert(12, f, cache.hash(f), 7, FacetCache::kHull);
  EXPECT_FALSE(cache.lookup(12, f, cache.hash(f), 7, across)) << "no vertex before 12 can have recorded it";
  ASSERT_TRUE(cache.lookup(40, f, cache.hash(f), 7, across));
  EXPECT_EQ(across, FacetCache::kHull);
  const std::uint32_t g[3] = {12, 40, 60};
  cache.insert(12, g, cache.hash(g), 5, 6);
  ASSERT_TRUE(cache.lookup(60, g, cache.hash(g), 6, across));
  EXPECT_EQ(across, 5u);
  EXPECT_FALSE(cache.lookup(60, g, cache.hash(g), 99, across)) << "an apex the facet does not have";
  // Starts: 40 and 60 have one; 12 (the inserting seed) and 150 (not meshed) none.
  std::uint32_t facet[3], a = 0, b = 0;
  ASSERT_TRUE(cache.start(60, facet, a, b));
  EXPECT_EQ(std::vector<std::uint32_t>(facet, facet + 3), std::vector<std::uint32_t>(g, g + 3));
  EXPECT_EQ(std::make_pair(a, b), std::make_pair(5u, 6u));
  EXPECT_TRUE(cache.start(40, facet, a, b));
  EXPECT_FALSE(cache.start(12, facet, a, b));
  EXPECT_FALSE(cache.start(150, facet, a, b));
  // Blocks of 10 seeds whose insides run in any order: within a block, a lower index
  // may come later (and record for a higher one), and is looked up too.
  FacetCache blocks(3, 200, 0, 200, 1 << 20, /*block=*/10);
  const std::uint32_t h[3] = {5, 12, 15};
  EXPECT_TRUE(blocks.wanted(15, h)) << "12 shares 15's block, so it may come later";
  EXPECT_FALSE(FacetCache(3, 200, 0, 200, 1 << 20).wanted(15, h)) << "in index order 5 and 12 came before";
  ASSERT_EQ(blocks.reserve(1), 1u);
  blocks.insert(15, h, blocks.hash(h), 3, 4);
  ASSERT_TRUE(blocks.lookup(12, h, blocks.hash(h), 4, across)) << "15 shares 12's block";
  EXPECT_EQ(across, 3u);
  EXPECT_TRUE(blocks.start(12, facet, a, b));
  // Too little memory for a table: disabled, every call a no-op.
  FacetCache none(3, 200, 0, 200, 1000);
  EXPECT_FALSE(none.enabled());
  EXPECT_EQ(none.reserve(10), 0u);
  // The smallest table, 1,024 slots, takes 716 entries (load 0.7), then no more.
  FacetCache small(3, 200, 0, 200, 200 * 4 + 1024 * 6 * 4);
  ASSERT_TRUE(small.enabled());
  EXPECT_EQ(small.reserve(500), 500u);
  EXPECT_EQ(small.reserve(500), 216u);
  EXPECT_EQ(small.reserve(1), 0u);
  EXPECT_FALSE(none.wanted(0, g));
  EXPECT_FALSE(none.lookup(60, g, none.hash(g), 6, across));
}

TEST(FacetCache, FacetHashesOfASimplexEqualEachFacetsHash) {
  // The walker hashes a queued simplex's facets through x in one go and looks them up
  // with those hashes; whatever inserted them used the same: both must equal hash().
  FacetCache cache(4, 1000, 0, 1000, 1 << 22);
  const std::uint32_t x = 500, others[4] = {912, 3, 77, 501};  // any order, x excluded
  std::uint64_t hashes[4];
  cache.facet_hashes(x, others, hashes);
  for (int k = 0; k < 4; ++k) {
    std::vector<std::uint32_t> facet{x};
    for (int j = 0; j < 4; ++j) {
      if (j != k) facet.push_back(others[j]);
    }
    std::sort(facet.begin(), facet.end());
    EXPECT_EQ(hashes[k], cache.hash(facet.data())) << "facet without " << others[k];
    for (int j = 0; j < k; ++j) EXPECT_NE(hashes[k], hashes[j]);
  }
}

TEST(FacetCache, ConcurrentWritersAndReadersSeeOnlyWholeEntries) {
  // Four threads insert overlapping sets of 4-d facets (apexes derived from the key)
  // while reading each other's; a table of 1,024 slots also overflows on purpose.
  constexpr std::uint32_t kPoints = 4000;
  for (std::size_t bytes : {std::size_t{8} << 20, std::size_t{kPoints} * 4 + 1024 * 7 * 4}) {
    FacetCache cache(4, kPoints, 0, kPoints, bytes);
    ASSERT_TRUE(cache.enabled());
    std::atomic<std::uint64_t> found{0}, wrong{0};
    auto work = [&](std::uint32_t t) {
      std::mt19937_64 rng(1234 + t);
      for (int i = 0; i < 20000; ++i) {
        std::uint32_t f[4];
        const std::uint64_t r = rng();
        f[0] = static_cast<std::uint32_t>(r % 1000);
        for (int c = 1; c < 4; ++c) f[c] = f[c - 1] + 1 + static_cast<std::uint32_t>((r >> (12 * c)) % 900);
        const std::uint32_t a = f[3] + 1, b = (f[0] * 7 + f[3]) % 2 == 0 ? FacetCache::kHull : f[3] + 2;
        if (cache.wanted(f[0], f) && cache.reserve(1) == 1) cache.insert(f[0], f, cache.hash(f), a, b);
        std::uint32_t across = 0;
        if (cache.lookup(f[3], f, cache.hash(f), a, across)) {
          ++found;
          if (across != b) ++wrong;
        }
        std::uint32_t facet[4], sa = 0, sb = 0;
        if (cache.start(f[2], facet, sa, sb)) {
          const bool contains = std::find(facet, facet + 4, f[2]) != facet + 4;
          if (!contains || sa != facet[3] + 1) ++wrong;
        }
      }
    };
    std::vector<std::thread> pool;
    for (std::uint32_t t = 0; t < 4; ++t) pool.emplace_back(work, t % 2);  // two pairs race on the same keys
    for (auto& th : pool) th.join();
    EXPECT_EQ(wrong.load(), 0u);
    EXPECT_GT(found.load(), 0u);
  }
}

// In 2-d the posts of earlier stars answer most wraps: every triangle but those in
// the gaps between posts is read, not computed.
TEST(Mesh, EdgeCacheAnswersMostWrapsIn2d) {
  const PointSet ps = make_points(2, uniform_points(2, 3000, 31));
  const KdTree tree(ps);
  auto run = [&](std::size_t bytes, Simplices& out) {
    MeshOptions options;
    options.threads = 2;
    options.engine = MeshEngine::kStars;  // the posts are the star walk's
    options.facet_cache_bytes = bytes;
    auto r = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
      out.insert(out.end(), block.begin(), block.end());
      return Status::ok();
    });
    EXPECT_TRUE(r.is_ok());
    return r.value();
  };
  Simplices with, without;
  const MeshStats cached = run(MeshOptions{}.facet_cache_bytes, with), plain = run(0, without);
  EXPECT_EQ(with, without);
  // The posts' resident peak: some of the boxes (64 bytes a point), never more than all
  // of them (whole pages), since those behind the sweep are given back.
  EXPECT_GT(cached.facet_cache_bytes, 0u);
  EXPECT_LE(cached.facet_cache_bytes, (3000u * 64u + 4095u) / 4096u * 4096u);
  EXPECT_EQ(plain.star.cached_wraps, 0u);
  EXPECT_GT(cached.star.cached_starts, 3000u / 2) << "most stars begin at an earlier star's posts";
  EXPECT_LT(cached.star.wraps * 10, plain.star.wraps * 6) << "posts answer the wraps of earlier stars";
}

TEST(EdgeCache, KeepsPostsForLaterSeedsInOrderUntilFull) {
  // Seeds [10, 100) are meshed.
  EdgeCache cache(200, 10, 100, 1 << 20);
  ASSERT_TRUE(cache.enabled());
  EXPECT_EQ(cache.reserved_bytes(), 200u * 64u);
  EXPECT_TRUE(cache.wanted(12, 40)) << "40 comes after 12";
  EXPECT_FALSE(cache.wanted(40, 12)) << "12 came before 40";
  EXPECT_FALSE(cache.wanted(12, 150)) << "150 is not meshed";
  EXPECT_FALSE(cache.wanted(12, 12));
  std::array<EdgeCache::Post, EdgeCache::kPostsPerPoint> posts{};
  EXPECT_EQ(cache.read(40, posts.data()), 0);
  cache.post(40, {12, 7, EdgeCache::kHull});
  ASSERT_EQ(cache.read(40, posts.data()), 1);
  EXPECT_EQ(posts[0].from, 12u);
  EXPECT_EQ(posts[0].a, 7u);
  EXPECT_EQ(posts[0].b, EdgeCache::kHull);
  // More posts than fit: the first kPostsPerPoint are kept, in order.
  for (std::uint32_t from = 20; from < 28; ++from) cache.post(50, {from, from + 100, from + 101});
  ASSERT_EQ(cache.read(50, posts.data()), EdgeCache::kPostsPerPoint);
  for (int i = 0; i < EdgeCache::kPostsPerPoint; ++i) {
    EXPECT_EQ(posts[static_cast<std::size_t>(i)].from, 20u + static_cast<std::uint32_t>(i));
    EXPECT_EQ(posts[static_cast<std::size_t>(i)].b, 121u + static_cast<std::uint32_t>(i));
  }
  // Blocks of 10 seeds whose insides run in any order: a lower index in the same block
  // may come later.
  EdgeCache blocks(200, 0, 200, 1 << 20, /*block=*/10);
  EXPECT_TRUE(blocks.wanted(15, 12));
  EXPECT_FALSE(blocks.wanted(25, 12));
  // Too little memory for 64 bytes per point: disabled, every call a no-op.
  EdgeCache none(200, 0, 200, 200 * 64 - 1);
  EXPECT_FALSE(none.enabled());
  EXPECT_FALSE(none.wanted(0, 5));
  none.post(5, {0, 1, 2});
  EXPECT_EQ(none.read(5, posts.data()), 0);
  EXPECT_EQ(none.reserved_bytes(), 0u);
}

TEST(EdgeCache, ConcurrentPostersAndReadersSeeOnlyWholePosts) {
  // Four threads post to random points (the apexes derived from the sender) while
  // reading each other's; most points overflow on purpose.
  constexpr std::uint32_t kPoints = 2000;
  EdgeCache cache(kPoints, 0, kPoints, 1 << 20);
  ASSERT_TRUE(cache.enabled());
  std::atomic<std::uint64_t> found{0}, wrong{0};
  auto work = [&](std::uint32_t t) {
    std::mt19937_64 rng(4321 + t);
    std::array<EdgeCache::Post, EdgeCache::kPostsPerPoint> posts{};
    for (int i = 0; i < 20000; ++i) {
      const std::uint64_t r = rng();
      const auto from = static_cast<std::uint32_t>(r % kPoints), to = static_cast<std::uint32_t>((r >> 20) % kPoints);
      cache.post(to, {from, from * 3 + 1, from % 2 == 0 ? EdgeCache::kHull : from * 3 + 2});
      const int got = cache.read(static_cast<std::uint32_t>((r >> 40) % kPoints), posts.data());
      for (int k = 0; k < got; ++k) {
        const EdgeCache::Post& p = posts[static_cast<std::size_t>(k)];
        ++found;
        if (p.a != p.from * 3 + 1 || p.b != (p.from % 2 == 0 ? EdgeCache::kHull : p.from * 3 + 2)) ++wrong;
      }
    }
  };
  std::vector<std::thread> pool;
  for (std::uint32_t t = 0; t < 4; ++t) pool.emplace_back(work, t);
  for (auto& th : pool) th.join();
  EXPECT_EQ(wrong.load(), 0u);
  EXPECT_GT(found.load(), 0u);
}

TEST(Mesh, AnySeedPartitionUnitesToTheWholeMeshOnce) {
  const PointSet ps = make_points(3, uniform_points(3, 700, 77));
  const KdTree tree(ps);
  const Simplices whole = mesh_all(tree, 2);
  for (const std::vector<std::uint32_t>& cuts :
       {std::vector<std::uint32_t>{0, 700}, {0, 1, 350, 351, 700}, {0, 100, 200, 333, 600, 699, 700}}) {
    Simplices joined;
    for (std::size_t k = 0; k + 1 < cuts.size(); ++k) {
      const Simplices part = mesh_all(tree, 1 + k % 3, cuts[k], cuts[k + 1]);
      for (std::size_t i = 0; i < part.size(); i += 4) {
        ASSERT_GE(part[i], cuts[k]);  // owner = smallest vertex, inside the range
        ASSERT_LT(part[i], cuts[k + 1]);
      }
      joined.insert(joined.end(), part.begin(), part.end());
    }
    // The same rows, each once (each part in its own sweep order).
    EXPECT_EQ(sorted_rows(joined, 4), sorted_rows(whole, 4));
  }
}

// --- Validation --------------------------------------------------------------------

TEST(Check, AcceptsOurMeshes) {
  for (const Case& c : cgal_cases()) {
    if (c.coords.size() / c.d > 1000) continue;
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const MeshCheck check = check_mesh(tree, mesh_all(tree, 2));
    EXPECT_TRUE(check.valid) << (check.violations.empty() ? "" : check.violations.front());
  }
}

TEST(Check, RejectsCorruptedMeshes) {
  const PointSet ps = make_points(2, uniform_points(2, 200, 5));
  const KdTree tree(ps);
  const Simplices good = mesh_all(tree);
  auto expect_invalid = [&](Simplices bad, const std::string& what, const std::string& needle) {
    const MeshCheck check = check_mesh(tree, bad);
    EXPECT_FALSE(check.valid) << what;
    ASSERT_FALSE(check.violations.empty()) << what;
    EXPECT_NE(check.violations.front().find(needle), std::string::npos) << what << ": " << check.violations.front();
  };
  {  // a missing simplex leaves a hole: its facets become boundary facets inside the hull
    Simplices bad = good;
    bad.erase(bad.begin() + 3 * 50, bad.begin() + 3 * 51);
    expect_invalid(bad, "dropped simplex", "not on the convex hull");
  }
  {  // a duplicated simplex
    Simplices bad = good;
    bad.insert(bad.end(), good.begin(), good.begin() + 3);
    expect_invalid(bad, "duplicate", "shared by 3");
  }
  {  // an out-of-range index
    Simplices bad = good;
    bad[7] = 5000;
    expect_invalid(bad, "index", "out of range");
  }
  {  // flip an interior edge: still a triangulation, no longer Delaunay
    const Predicates pred(ps);
    Simplices bad = good;
    bool flipped = false;
    const auto tuples = as_set(good, 3);
    for (std::size_t i = 0; i < good.size() && !flipped; i += 3) {
      for (std::size_t j = i + 3; j < good.size() && !flipped; j += 3) {
        std::vector<std::uint32_t> a(good.begin() + i, good.begin() + i + 3), b(good.begin() + j, good.begin() + j + 3);
        std::vector<std::uint32_t> shared;
        std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(shared));
        if (shared.size() != 2) continue;
        std::uint32_t pa = 0, pb = 0;
        for (auto v : a)
          if (v != shared[0] && v != shared[1]) pa = v;
        for (auto v : b)
          if (v != shared[0] && v != shared[1]) pb = v;
        // Flip only a convex quadrilateral: the new diagonal separates the old one.
        const std::array<std::uint32_t, 3> t1 = {pa, pb, shared[0]}, t2 = {pa, pb, shared[1]};
        if (pred.orientation(t1) * pred.orientation(t2) >= 0) continue;
        std::array<std::uint32_t, 3> n1 = t1, n2 = t2;
        std::sort(n1.begin(), n1.end());
        std::sort(n2.begin(), n2.end());
        std::copy(n1.begin(), n1.end(), bad.begin() + i);
        std::copy(n2.begin(), n2.end(), bad.begin() + j);
        flipped = true;
      }
    }
    ASSERT_TRUE(flipped);
    expect_invalid(bad, "flipped edge", "not locally Delaunay");
  }
  {  // a degenerate simplex
    const PointSet line = make_points(2, {0, 0, 1, 0, 2, 0, 0, 1});
    const KdTree t(line);
    const MeshCheck check = check_mesh(t, Simplices{0, 1, 2});
    EXPECT_FALSE(check.valid);
    EXPECT_NE(check.violations.front().find("degenerate"), std::string::npos);
  }
}

// --- Voronoi cells -----------------------------------------------------------------

// Issue 18, part 2: every Voronoi vertex (circumcentre) within 1e-12 of its
// circumradius plus one ulp of the coordinate of the exact one, on inputs where the
// normal equations failed: grids jittered by 1e-9, and tiny cells far from the origin.
// The reference solves the d x d system V y = |v|^2 / 2 in rationals (Gaussian
// elimination on the differences, not the normal equations the code's fallback uses).
TEST(Voronoi, CircumcentresAgreeWithExactRationalOnes) {
  const auto exact_centre = [](const PointSet& ps, const std::uint32_t* s) {
    const int d = ps.dimension();
    std::vector<mpq_class> a(static_cast<std::size_t>(d * (d + 1)));
    for (int i = 0; i < d; ++i) {
      mpq_class norm = 0;
      for (int c = 0; c < d; ++c) {
        const mpq_class v = mpq_class(ps.point(s[i + 1])[c]) - mpq_class(ps.point(s[0])[c]);
        a[i * (d + 1) + c] = v;
        norm += v * v;
      }
      a[i * (d + 1) + d] = norm / 2;
    }
    for (int col = 0; col < d; ++col) {
      int p = col;
      while (sgn(a[p * (d + 1) + col]) == 0) ++p;  // a Delaunay simplex is never flat
      for (int j = 0; j <= d; ++j) std::swap(a[col * (d + 1) + j], a[p * (d + 1) + j]);
      for (int r = 0; r < d; ++r) {
        if (r == col) continue;
        const mpq_class f = a[r * (d + 1) + col] / a[col * (d + 1) + col];
        for (int j = col; j <= d; ++j) a[r * (d + 1) + j] -= f * a[col * (d + 1) + j];
      }
    }
    std::vector<mpq_class> y(static_cast<std::size_t>(d));
    for (int c = 0; c < d; ++c) y[c] = a[c * (d + 1) + d] / a[c * (d + 1) + c];
    return y;  // the centre minus s[0]
  };
  struct Input {
    const char* name;
    int d;
    std::vector<double> coords;
  };
  std::vector<Input> cases;
  std::mt19937_64 rng(2026);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (int d = 2; d <= 5; ++d) {
    const int side = d == 2 ? 10 : d == 3 ? 5 : 4;
    const std::size_t n = d == 2 ? 300 : d == 3 ? 120 : d == 4 ? 80 : 60;
    if (d <= 4) {  // a 5-d jittered grid's mesh alone takes seconds (exact predicates)
      std::vector<double> jittered = grid_points(d, side);
      for (double& x : jittered) x += 1e-9 * unit(rng);
      cases.push_back({"grid jittered by 1e-9", d, jittered});
    }
    std::vector<double> far = uniform_points(d, n, 90 + d);
    for (double& x : far) x = 1e6 + 1e-4 * x;
    cases.push_back({"tiny cells at 1e6", d, far});
    cases.push_back({"uniform", d, uniform_points(d, n, 80 + d)});
  }
  for (const Input& c : cases) {
    SCOPED_TRACE(std::string(c.name) + ", d " + std::to_string(c.d));
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    const Simplices simplices = mesh_all(tree);
    const int w = c.d + 1;
    double worst = 0;
    for (std::size_t i = 0; i < simplices.size(); i += w) {
      const std::uint32_t* s = &simplices[i];
      const std::vector<double> got = circumcentre(ps, s, w);
      const std::vector<mpq_class> y = exact_centre(ps, s);
      double radius2 = 0;
      for (int k = 0; k < c.d; ++k) radius2 += y[k].get_d() * y[k].get_d();
      for (int k = 0; k < c.d; ++k) {
        const mpq_class exact = mpq_class(ps.point(s[0])[k]) + y[k];
        const double error = std::abs(mpq_class(mpq_class(got[k]) - exact).get_d());
        const double ulp = std::nextafter(std::abs(exact.get_d()), INFINITY) - std::abs(exact.get_d());
        const double allowed = 1e-12 * std::sqrt(radius2) + ulp;
        worst = std::max(worst, error / allowed);
        ASSERT_LE(error, allowed) << "simplex " << i / w << ", coordinate " << k;
      }
    }
    std::printf("[ %-22s d=%d ] worst error / allowed = %.3g\n", c.name, c.d, worst);
  }
}

TEST(Voronoi, GridCellsAreUnitCubes) {
  for (int d = 2; d <= 4; ++d) {
    const PointSet ps = make_points(d, grid_points(d, 4));
    const KdTree tree(ps);
    StarWalker walker(tree);
    Star star;
    // An interior grid point: all coordinates 1 -> index sum of 4^k.
    std::uint32_t interior = 0;
    for (int k = 0, p = 1; k < d; ++k, p *= 4) interior += p;
    ASSERT_TRUE(walker.compute(interior, star).is_ok());
    const VoronoiCell cell = voronoi_cell(ps, star);
    EXPECT_TRUE(cell.bounded);
    EXPECT_NEAR(cell.volume, 1.0, 1e-12) << "d " << d;
    ASSERT_TRUE(walker.compute(0, star).is_ok());  // a corner: unbounded
    EXPECT_FALSE(voronoi_cell(ps, star).bounded);
  }
}

TEST(Voronoi, BodyCentredCubicCellsAreTruncatedOctahedraOfVolumeOneHalf) {
  // Unit-cube corners 0..4 plus body centres: two points per unit cube, so every
  // interior cell has volume 1/2 (a truncated octahedron with 8 hexagonal and 6 square
  // faces); the lattice is cospherical throughout, so the perturbation is exercised.
  std::vector<double> c;
  for (int i = 0; i <= 4; ++i)
    for (int j = 0; j <= 4; ++j)
      for (int k = 0; k <= 4; ++k) c.insert(c.end(), {double(i), double(j), double(k)});
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 4; ++k) c.insert(c.end(), {i + 0.5, j + 0.5, k + 0.5});
  const PointSet ps = make_points(3, c);
  const KdTree tree(ps);
  StarWalker walker(tree);
  Star star;
  const std::uint32_t corner = (2 * 5 + 2) * 5 + 2;        // (2, 2, 2)
  const std::uint32_t centre = 125 + (1 * 4 + 1) * 4 + 1;  // (1.5, 1.5, 1.5)
  for (std::uint32_t seed : {corner, centre}) {
    ASSERT_TRUE(walker.compute(seed, star).is_ok());
    const VoronoiCell cell = voronoi_cell(ps, star);
    EXPECT_TRUE(cell.bounded) << "seed " << seed;
    EXPECT_NEAR(cell.volume, 0.5, 1e-12) << "seed " << seed;
    EXPECT_EQ(cell.facets.size(), 14u) << "seed " << seed << ": 8 hexagons + 6 squares";
  }
}

TEST(Voronoi, BoundedCellVolumesMatchPolygonAreas) {
  const PointSet ps = make_points(2, uniform_points(2, 300, 9));
  const KdTree tree(ps);
  StarWalker walker(tree);
  Star star;
  int bounded = 0;
  for (std::uint32_t s = 0; s < ps.size(); ++s) {
    ASSERT_TRUE(walker.compute(s, star).is_ok());
    const VoronoiCell cell = voronoi_cell(ps, star);
    // Consecutive vertices share an edge of the cell (a path when it is unbounded).
    for (std::size_t v = 0; v + (cell.bounded ? 0 : 1) < cell.vertex_count(); ++v) {
      const auto w = static_cast<std::uint32_t>((v + 1) % cell.vertex_count());
      EXPECT_TRUE(std::any_of(cell.facets.begin(), cell.facets.end(),
                              [&](const VoronoiFacet& f) {
                                return std::count(f.vertices.begin(), f.vertices.end(), v) +
                                           std::count(f.vertices.begin(), f.vertices.end(), w) ==
                                       2;
                              }))
          << "seed " << s << ", vertices " << v << " and " << w;
    }
    if (!cell.bounded) continue;
    ++bounded;
    // Shoelace over the vertices in the cell's own order (counter-
    // clockwise, so the signed area is the volume), and that order is the angular one.
    std::vector<std::pair<double, std::size_t>> by_angle;
    const std::size_t k = cell.vertex_count();
    double area = 0;
    for (std::size_t v = 0; v < k; ++v) {
      const double* a = &cell.vertices[2 * v];
      const double* b = &cell.vertices[2 * ((v + 1) % k)];
      area += a[0] * b[1] - a[1] * b[0];
      by_angle.push_back({std::atan2(a[1] - ps.point(s)[1], a[0] - ps.point(s)[0]), v});
    }
    std::sort(by_angle.begin(), by_angle.end());
    for (std::size_t v = 0; v < k; ++v) {  // cyclically increasing angles
      EXPECT_EQ((by_angle[v].second + 1) % k, by_angle[(v + 1) % k].second) << "seed " << s;
    }
    EXPECT_NEAR(cell.volume, area / 2, 1e-9 * std::max(1.0, area)) << "seed " << s;
    EXPECT_EQ(cell.facets.size(), cell.vertex_count()) << "a bounded polygon has as many edges as vertices";
  }
  EXPECT_GT(bounded, 200);
}

}  // namespace
}  // namespace spokemesh
