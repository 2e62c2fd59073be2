// The sweep's pieces: the block decomposition (tiling, boxes, maximality), the
// front's memo (what a block records reaches later blocks once, and nothing reaches a
// block that has begun), and the front's bound (it grows with the surface, not with n).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>

#include "inputs.hpp"  // bench/: the shape families
#include "spokemesh/certify.hpp"
#include "spokemesh/front_cache.hpp"
#include "spokemesh/mesh.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using testing::make_points;
using testing::mesh_all;
using testing::uniform_points;

TEST(SweepOrder, ConsecutiveBlocksAreCloseInSpace) {
  // The sweep's order is a space-filling order: on average consecutive blocks' boxes
  // touch far more often than random pairs would.
  const PointSet ps = make_points(3, uniform_points(3, 20000, 7));
  const SpaceSplit blocks(ps, 256);
  const auto gap = [&](std::uint32_t a, std::uint32_t b) {
    double g2 = 0;
    const auto x = blocks.box(a), y = blocks.box(b);
    for (int c = 0; c < 3; ++c) {
      const double g = std::max({0.0, static_cast<double>(y[c] - x[3 + c]), static_cast<double>(x[c] - y[3 + c])});
      g2 += g * g;
    }
    return std::sqrt(g2);
  };
  // Consecutive blocks are siblings or cousins in the split: most touch (a depth-first
  // order of a k-d split jumps across a subtree now and then, as a Z order does).
  const std::uint32_t m = blocks.block_count();
  std::size_t touching = 0, random_touching = 0;
  for (std::uint32_t b = 0; b + 1 < m; ++b) {
    touching += gap(b, b + 1) < 0.02 ? 1 : 0;
    random_touching += gap(b, (b * 7919u + 13u) % m) < 0.02 ? 1 : 0;
  }
  EXPECT_GT(touching, (m - 1) * 3 / 4);
  EXPECT_GT(touching, 4 * random_touching) << touching << " consecutive, " << random_touching << " random pairs touch";
}

TEST(FrontCache, RecordsReachLaterSeedsOnceAndNeverABlockThatBegan) {
  const PointSet ps = make_points(3, uniform_points(3, 2000, 11));
  const SpaceSplit blocks(ps, 100);
  ASSERT_GE(blocks.block_count(), 4u);
  FrontMail mail(3, blocks, 1 << 20);
  const RunOrder run{0, 2000, 1, &blocks, 0, 2000};
  FrontCache first(3, blocks, mail, run), later(3, blocks, mail, run);
  const auto at = [&](std::uint32_t block, std::uint32_t k) { return blocks.point_at(blocks.begin(block) + k); };
  // A facet of two points of block 0 and one of block 2, recorded by block 0's first.
  std::array<std::uint32_t, 3> f{at(0, 0), at(0, 1), at(2, 0)};
  std::sort(f.begin(), f.end());
  const std::uint32_t x = blocks.position_of(at(0, 0)) < blocks.position_of(at(0, 1)) ? at(0, 0) : at(0, 1);
  const std::uint32_t y = x == at(0, 0) ? at(0, 1) : at(0, 0);
  first.begin_block(0);
  EXPECT_TRUE(first.wanted(x, f.data()));
  EXPECT_FALSE(first.wanted(at(2, 0), f.data())) << "block 2's point is the facet's last";
  first.insert(x, f.data(), first.hash(f.data()), 17, FacetMemo::kHull);
  std::uint32_t across = 0;
  ASSERT_TRUE(first.lookup(y, f.data(), first.hash(f.data()), 17, across)) << "a later seed of the same block";
  EXPECT_EQ(across, FacetMemo::kHull);
  std::array<std::uint32_t, 3> facet{};
  std::uint32_t a = 0, b = 0;
  ASSERT_TRUE(first.start(y, facet.data(), a, b));
  EXPECT_EQ(facet, f);
  EXPECT_EQ(a, 17u);
  EXPECT_FALSE(first.start(at(1, 0), facet.data(), a, b)) << "not in the block";
  // Recorded twice (a facet closed without a wrap): still one entry, one post.
  first.insert(x, f.data(), first.hash(f.data()), 17, FacetMemo::kHull);
  // A facet of block 0 and block 1, recorded while block 1 has already begun.
  std::array<std::uint32_t, 3> g{at(0, 0), at(0, 1), at(1, 0)};
  std::sort(g.begin(), g.end());
  later.begin_block(1);
  first.insert(x, g.data(), first.hash(g.data()), 5, 6);
  first.end_block();
  EXPECT_GT(mail.held_bytes(), 0u);
  EXPECT_FALSE(later.lookup(at(1, 0), g.data(), later.hash(g.data()), 5, across)) << "posted after block 1 began";
  later.end_block();
  // Block 2 reads its post once: its point finds the facet and starts from it.
  later.begin_block(2);
  EXPECT_EQ(mail.held_bytes(), 0u) << "a block's mail is dropped when it begins";
  ASSERT_TRUE(later.lookup(at(2, 0), f.data(), later.hash(f.data()), FacetMemo::kHull, across));
  EXPECT_EQ(across, 17u);
  ASSERT_TRUE(later.start(at(2, 0), facet.data(), a, b));
  EXPECT_EQ(facet, f);
  EXPECT_FALSE(later.lookup(at(2, 0), g.data(), later.hash(g.data()), 5, across)) << "g was not for block 2";
  later.end_block();
}

TEST(FrontCache, TheMailCapDropsPostsAndChangesNoSimplex) {
  const PointSet ps = make_points(3, uniform_points(3, 4000, 12));
  const KdTree tree(ps);
  const auto whole =
      mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, MeshOptions{}.facet_cache_bytes, 200, MeshEngine::kStars);
  for (const std::size_t cap : {std::size_t{1}, std::size_t{4096}, std::size_t{1} << 16}) {
    SCOPED_TRACE("cap " + std::to_string(cap));
    EXPECT_EQ(mesh_all(tree, 2, 0, 0xFFFFFFFFu, 0x5eed, cap, 200, MeshEngine::kStars), whole);
  }
}

// A whole mesh of n uniform points in d dimensions on two threads with blocks of
// `block` points by the star walk's sweep (whose front this measures), its output
// discarded: the run's statistics, printed.
MeshStats sweep_of_uniform(int d, std::size_t n, std::uint64_t seed, std::uint32_t block) {
  const PointSet ps = make_points(d, uniform_points(d, n, seed));
  const KdTree tree(ps);
  MeshOptions options;
  options.threads = 2;
  options.engine = MeshEngine::kStars;
  options.block_size = block;
  auto r = mesh_seeds(tree, options, [](std::span<const std::uint32_t>, std::uint64_t) { return Status::ok(); });
  EXPECT_TRUE(r.is_ok());
  const MeshStats stats = r.is_ok() ? r.value() : MeshStats{};
  std::printf(
      "%d-d n %zu: front peak %zu bytes (%.1f per point), memo %zu bytes (%.1f per point), %.2f cached wraps per "
      "seed\n",
      d, n, stats.front_peak_bytes, static_cast<double>(stats.front_peak_bytes) / static_cast<double>(n),
      stats.facet_cache_bytes, static_cast<double>(stats.facet_cache_bytes) / static_cast<double>(n),
      static_cast<double>(stats.star.cached_wraps) / static_cast<double>(n));
  return stats;
}

// The front's bound: with blocks of a fixed size, the mailboxes' peak follows the
// surface between the blocks done and the blocks to come. Eight times the points
// give about 8^(2/3) = 4 times the front in 3-d; a memo kept for the whole run (as
// the FacetCache was) grows 8 times.
TEST(Sweep, TheFrontGrowsWithTheSurfaceNotWithTheMesh) {
  const MeshStats small = sweep_of_uniform(3, 25000, 5, 512), large = sweep_of_uniform(3, 200000, 5, 512);
  ASSERT_GT(small.front_peak_bytes, 0u);
  const double growth = static_cast<double>(large.front_peak_bytes) / static_cast<double>(small.front_peak_bytes);
  EXPECT_LT(growth, 6.0) << "the front grew " << growth << "x for 8x the points: it follows n, not the surface";
  EXPECT_LT(large.front_peak_bytes, 200000u * 40) << "more than 40 bytes per point";
  // And the memo still does its work: most wraps are answered, not recomputed.
  EXPECT_GT(large.star.cached_wraps, 2 * large.star.wraps);
}

// In 2-d the memo is the EdgeCache: posts per point, kept in sweep order so that the
// boxes behind the sweep go back to the OS. What stays resident is the blocks in
// flight and the posts to points ahead (the front): about sqrt(8) = 2.8 times as much
// for 8 times the points, where the boxes of every point (64 bytes each, as before)
// would grow 8 times.
TEST(Sweep, TwoDimensionalPostsFollowTheFrontNotTheMesh) {
  const MeshStats small = sweep_of_uniform(2, 50000, 7, 1024), large = sweep_of_uniform(2, 400000, 7, 1024);
  ASSERT_GT(small.facet_cache_bytes, 0u);
  const double growth = static_cast<double>(large.facet_cache_bytes) / static_cast<double>(small.facet_cache_bytes);
  EXPECT_LT(growth, 5.0) << "the posts grew " << growth << "x for 8x the points: they follow n, not the front";
  EXPECT_LT(large.facet_cache_bytes, 400000u * 16) << "more than 16 bytes per point (every box is 64)";
  EXPECT_GT(large.star.cached_wraps, large.star.wraps) << "the posts still answer most of the ring";
}

}  // namespace
}  // namespace spokemesh

namespace spokemesh {
namespace {

using testing::make_points;
using testing::mesh_all;
using testing::Simplices;
using testing::sorted_rows;
using testing::uniform_points;

// A whole mesh whose stars are all offered to `accept`: the same rows when every star
// is accepted, and none of a refused seed's.
TEST(Sweep, AcceptSeesWholeStarsAndRefusedSeedsEmitNothing) {
  for (int d = 2; d <= 3; ++d) {  // the 2-d ring walk and the general walk
    SCOPED_TRACE("d " + std::to_string(d) + " (seed 31)");
    const PointSet ps = make_points(d, uniform_points(d, 3000, 31));
    const KdTree tree(ps);
    const auto whole = mesh_all(tree, 2);
    MeshOptions options;
    options.threads = 2;
    std::atomic<std::uint64_t> whole_stars{0};
    options.accept = [&](const Star& star) {
      // The whole star: every simplex through the seed, the owned ones last.
      StarWalker walker(tree);
      Star reference;
      EXPECT_TRUE(walker.compute(star.seed, reference).is_ok());
      // The same simplices as vertex sets (only the owned ones need be oriented).
      const auto as_sets = [&](std::vector<std::uint32_t> flat) {
        for (std::size_t i = 0; i < flat.size(); i += static_cast<std::size_t>(d + 1)) {
          std::sort(flat.begin() + static_cast<std::ptrdiff_t>(i),
                    flat.begin() + static_cast<std::ptrdiff_t>(i + d + 1));
        }
        return sorted_rows(flat, d + 1);
      };
      whole_stars += as_sets(star.simplices) == as_sets(reference.simplices) ? 1 : 0;
      return star.seed % 7 != 3;
    };
    Simplices kept;
    auto r = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
      kept.insert(kept.end(), block.begin(), block.end());
      return Status::ok();
    });
    ASSERT_TRUE(r.is_ok());
    EXPECT_EQ(whole_stars.load(), 3000u);
    Simplices expected;
    const auto w = static_cast<std::size_t>(d + 1);
    for (std::size_t i = 0; i < whole.size(); i += w) {
      if (whole[i] % 7 != 3) {
        expected.insert(expected.end(), whole.begin() + static_cast<std::ptrdiff_t>(i),
                        whole.begin() + static_cast<std::ptrdiff_t>(i + w));
      }
    }
    EXPECT_EQ(kept, expected);
  }
}

// A star computed from the points in a box is certified only if it is the whole set's
// star: against brute force over every seed, in 2-d and 3-d.
TEST(StarCertifier, CertifiesOnlyTheWholeSetsStars) {
  for (int d = 2; d <= 3; ++d) {
    SCOPED_TRACE("d " + std::to_string(d) + " (seed 40 + d)");
    const std::size_t n = d == 2 ? 4000 : 12000;
    const std::vector<double> coords = uniform_points(d, n, 40 + static_cast<std::uint64_t>(d));
    const PointSet all = make_points(d, coords);
    const KdTree all_tree(all);
    // Held: the points in [0.2, 0.7]^d; unheld: the unit box less that, as slabs.
    std::vector<double> held_box, sub, unheld;
    std::vector<std::uint32_t> global;
    for (int c = 0; c < d; ++c) held_box.push_back(0.2);
    for (int c = 0; c < d; ++c) held_box.push_back(0.7);
    for (std::uint32_t i = 0; i < n; ++i) {
      bool in = true;
      for (int c = 0; c < d; ++c) in = in && all.point(i)[c] >= 0.2 && all.point(i)[c] <= 0.7;
      if (!in) continue;
      sub.insert(sub.end(), all.point(i), all.point(i) + d);
      global.push_back(i);
    }
    for (int c = 0; c < d; ++c) {
      std::vector<double> lo_slab(2 * static_cast<std::size_t>(d)), hi_slab;
      for (int k = 0; k < d; ++k) {
        lo_slab[static_cast<std::size_t>(k)] = 0;
        lo_slab[static_cast<std::size_t>(d + k)] = 1;
      }
      hi_slab = lo_slab;
      lo_slab[static_cast<std::size_t>(d + c)] = 0.2;
      hi_slab[static_cast<std::size_t>(c)] = 0.7;
      unheld.insert(unheld.end(), lo_slab.begin(), lo_slab.end());
      unheld.insert(unheld.end(), hi_slab.begin(), hi_slab.end());
    }
    PointSet part = make_points(d, sub);
    const KdTree part_tree(part);
    std::vector<double> whole_box;
    for (int c = 0; c < d; ++c) whole_box.push_back(0);
    for (int c = 0; c < d; ++c) whole_box.push_back(1);
    const StarCertifier certifier(part, whole_box);
    StarWalker part_walker(part_tree), all_walker(all_tree);
    std::size_t certified = 0;
    for (std::uint32_t k = 0; k < part.size(); ++k) {
      Star mine, truth;
      ASSERT_TRUE(part_walker.compute(k, mine).is_ok());
      if (!certifier.certified(mine, held_box, unheld)) continue;
      ++certified;
      ASSERT_TRUE(all_walker.compute(global[k], truth).is_ok());
      std::vector<std::uint32_t> mapped = mine.simplices;
      for (auto& v : mapped) v = global[v];
      ASSERT_EQ(sorted_rows(mapped, d + 1), sorted_rows(truth.simplices, d + 1)) << "point " << global[k];
    }
    // Many held points are far enough from the box's sides (in 3-d about a third: a
    // star reaches a few spacings).
    EXPECT_GT(certified, part.size() / 4);
  }
}

}  // namespace
}  // namespace spokemesh

namespace spokemesh {
namespace {

using testing::grid_points;
using testing::make_points;
using testing::mesh_all;
using testing::Simplices;
using testing::uniform_points;

// Incremental insertion equals the whole set meshed at once, byte for byte, chunk after
// chunk: random points (2-d to 4-d, a chunk of one point among them) and a 3-d integer
// grid (every sphere degenerate: the symbolic perturbation decides, as for the whole).
// Small chunks recompute stars; large ones sweep the whole set (InsertStats::whole).
TEST(InsertPoints, EqualsTheWholeSetMeshedAtOnce) {
  struct Case {
    const char* name;
    int d;
    std::vector<double> coords;
    std::vector<std::uint32_t> sizes;  // the set after each chunk
  };
  const std::vector<Case> cases = {
      {"2-d uniform, seed 61", 2, uniform_points(2, 3000, 61), {2000, 2001, 2030, 2600, 3000}},
      {"3-d uniform, seed 62", 3, uniform_points(3, 3000, 62), {1000, 1010, 3000}},
      {"3-d integer grid 12^3", 3, grid_points(3, 12), {500, 1700, 1710, 1728}},
      {"4-d uniform, seed 64", 4, uniform_points(4, 600, 64), {300, 301, 600}},
      // The shapes the local triangulations serve (their new stars come from them):
      // a closed surface, a scan and contour lines, points added in file order.
      {"sphere surface", 3, bench::sphere_surface(4000, 65), {3000, 3030, 3500, 4000}},
      {"scanner rings", 3, bench::scanner_rings(8, 500, 0, 66), {3000, 3040, 4000}},
      {"contour lines", 2, bench::contours(10, 0.5, 67), {1500, 1530, 2000}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const auto w = static_cast<std::size_t>(c.d + 1);
    Simplices rows;
    // The tree of each step extended from the last one's (as add_points does): small
    // chunks add parts to it, large ones build it whole (KdTree::extended).
    auto points = std::make_unique<PointSet>(
        make_points(c.d, std::vector<double>(c.coords.begin(), c.coords.begin() + c.sizes[0] * c.d)));
    auto tree = std::make_unique<KdTree>(*points);
    rows = mesh_all(*tree, 2);
    for (std::size_t k = 1; k < c.sizes.size(); ++k) {
      SCOPED_TRACE(std::to_string(c.sizes[k - 1]) + " -> " + std::to_string(c.sizes[k]) + " points");
      auto now = std::make_unique<PointSet>(
          make_points(c.d, std::vector<double>(c.coords.begin(), c.coords.begin() + c.sizes[k] * c.d)));
      const std::size_t parts_before = tree->parts();
      std::unique_ptr<KdTree> extended = KdTree::extended(*tree, *now);
      tree = std::move(extended);  // the previous tree goes first, then its points
      points = std::move(now);
      const std::uint32_t added = c.sizes[k] - c.sizes[k - 1];
      EXPECT_EQ(tree->parts(), added * KdTree::kRebuildBeyondShare > c.sizes[k] ? 1u : parts_before + 1);
      const SpaceSplit split(*points, SpaceSplit::default_block_points(c.d, points->size()));
      MeshOptions options;
      options.threads = 2;
      options.star.random_seed = 0x5eed;
      const KdTree built_whole(*points);
      const Simplices whole = mesh_all(built_whole, 2);
      // Every route gives the same rows: walks forced, the whole sweep forced, and the
      // probe's choice (checked below).
      for (const MeshEngine forced : {MeshEngine::kStars, MeshEngine::kTriangulations}) {
        options.engine = forced;
        Rows by;
        auto forced_stats = insert_points(*tree, split, c.sizes[k - 1], rows, options, by);
        ASSERT_TRUE(forced_stats.is_ok()) << forced_stats.status().message();
        EXPECT_TRUE(std::equal(by.begin(), by.end(), whole.begin(), whole.end())) << "engine " << int(forced);
        const bool few = c.sizes[k] - c.sizes[k - 1] <= c.sizes[k - 1] / 50;
        if (forced == MeshEngine::kStars && few) EXPECT_FALSE(forced_stats.value().whole);
        if (forced == MeshEngine::kTriangulations && c.d <= 3) EXPECT_TRUE(forced_stats.value().whole);
      }
      options.engine = MeshEngine::kAuto;
      Rows out;
      auto stats = insert_points(*tree, split, c.sizes[k - 1], rows, options, out);
      ASSERT_TRUE(stats.is_ok()) << stats.status().message();
      ASSERT_EQ(out.size(), whole.size());
      EXPECT_TRUE(std::equal(out.begin(), out.end(), whole.begin())) << "the rows differ from the whole set's";
      EXPECT_EQ(mesh_all(*tree, 2), whole) << "the extended tree's whole mesh differs";
      // Only the stars that change were computed: the new points' and some of the old
      // (a small chunk leaves most stars alone; a large one may touch every old point).
      EXPECT_LE(stats.value().stars, points->size());
      if (c.sizes[k] - c.sizes[k - 1] <= c.sizes[k - 1] / 50 && !stats.value().whole) {
        EXPECT_LT(stats.value().stars, points->size() / 2);
        EXPECT_GT(stats.value().rows_kept, out.size() / w / 2);
      }
      EXPECT_EQ(out.size() % w, 0u);
      // The stars computed are the new points' only (rows of old points are filtered),
      // or with walks dear (surfaces, scans, contours) the whole set's.
      if (!stats.value().whole) {
        EXPECT_EQ(stats.value().stars, c.sizes[k] - c.sizes[k - 1]);
      }

      rows.assign(out.begin(), out.end());
    }
  }
}

// validate_appended: the state validate() gives (ranks that key the perturbation, the
// integer scale) and its first error, from the parent's order merged with the new points.
TEST(InsertPoints, ValidatingAnAppendedSetEqualsValidatingTheWhole) {
  struct Case {
    const char* name;
    int d;
    std::vector<double> coords;
    std::uint32_t n_old;
  };
  std::vector<double> grid = grid_points(2, 9);
  std::vector<double> dyadic = uniform_points(3, 400, 71);
  for (std::size_t i = 1200 / 2; i < dyadic.size(); ++i) dyadic[i] = std::ldexp(std::round(dyadic[i] * 64), -7);
  const std::vector<Case> cases = {
      {"2-d grid 9^2, seed none", 2, grid, 40},
      {"3-d uniform then dyadic, seed 71", 3, dyadic, 200},
      {"4-d uniform, seed 72", 4, uniform_points(4, 300, 72), 299},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    PointSet parent(c.d, std::vector<double>(c.coords.begin(), c.coords.begin() + c.n_old * c.d));
    ASSERT_TRUE(parent.validate("parent").is_ok());
    PointSet whole(c.d, c.coords), appended(c.d, c.coords);
    ASSERT_TRUE(whole.validate("points").is_ok());
    ASSERT_TRUE(appended.validate_appended(parent, "points").is_ok());
    for (std::size_t i = 0; i < whole.size(); ++i) ASSERT_EQ(whole.lex_rank(i), appended.lex_rank(i)) << "point " << i;
    EXPECT_EQ(whole.scale_exponent(), appended.scale_exponent());
    EXPECT_EQ(whole.integer_bits(), appended.integer_bits());
    // Equal points, old with new and new with new: the same message.
    for (const std::uint32_t twin : {c.n_old / 2, static_cast<std::uint32_t>(whole.size() - 1)}) {
      std::vector<double> more = c.coords;
      more.insert(more.end(), c.coords.begin() + twin * c.d, c.coords.begin() + (twin + 1) * c.d);
      PointSet a(c.d, more), b(c.d, more);
      const Status sa = a.validate("points"), sb = b.validate_appended(parent, "points");
      ASSERT_FALSE(sa.is_ok());
      EXPECT_EQ(sa.message(), sb.message());
      EXPECT_EQ(sb.reason(), "DUPLICATE_POINTS");
    }
  }
}

}  // namespace
}  // namespace spokemesh
