// SpaceSplit and CountSelect (docs/distributed.md): the order and blocks a distributed
// run can reproduce, and the median step it computes across processes. It must be a permutation whose blocks tile it in
// compact, balanced, non-overlapping boxes, and a function of the point set alone: the same coordinates at every
// position whatever the input order, grids (ties along every axis) included.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "spokemesh/count_select.hpp"
#include "spokemesh/space_split.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using testing::grid_points;
using testing::make_points;
using testing::uniform_points;

// Gaussian clumps: most of the space empty, the points in a few dense balls.
std::vector<double> clustered_points(int d, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> where(0, 1);
  std::normal_distribution<double> spread(0, 0.01);
  std::vector<double> centres(10 * static_cast<std::size_t>(d));
  for (double& c : centres) c = where(rng);
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t k = i % 10;
    for (int j = 0; j < d; ++j)
      c.push_back(centres[k * static_cast<std::size_t>(d) + static_cast<std::size_t>(j)] + spread(rng));
  }
  return c;
}

void expect_valid_split(const std::string& name, const PointSet& ps, std::uint32_t block) {
  SCOPED_TRACE(name + ", block " + std::to_string(block));
  const SpaceSplit split(ps, block, 8);
  const std::uint32_t n = split.size();
  ASSERT_EQ(n, ps.size());
  std::vector<bool> seen(n, false);
  for (std::uint32_t i = 0; i < n; ++i) {
    const std::uint32_t id = split.point_at(i);
    ASSERT_LT(id, n);
    ASSERT_FALSE(seen[id]) << "not a permutation at " << i;
    seen[id] = true;
    ASSERT_EQ(split.position_of(id), i);
  }
  const int d = ps.dimension();
  ASSERT_GE(split.block_count(), 1u);
  ASSERT_EQ(split.begin(0), 0u);
  ASSERT_EQ(split.end(split.block_count() - 1), n);
  for (std::uint32_t b = 0; b < split.block_count(); ++b) {
    const std::uint32_t size = split.end(b) - split.begin(b);
    ASSERT_GT(size, 0u);
    ASSERT_LE(size, block);
    // Maximal: the parent held more than `block`, so each half holds at least half.
    if (n > block) {
      EXPECT_GE(size, (block + 1) / 2) << "block " << b;
    }
    if (b + 1 < split.block_count()) {
      ASSERT_EQ(split.end(b), split.begin(b + 1));
    }
    const std::span<const double> box = split.box(b);
    // The blocks are the split's nodes of at most `block` points, which the counts alone fix.
    ASSERT_EQ(split.nodes_of_at_most(block)[b], std::make_pair(split.begin(b), split.end(b)));
    for (std::uint32_t i = split.begin(b); i < split.end(b); ++i) {
      ASSERT_EQ(split.block_of(i), b);
      ASSERT_EQ(split.position_of(split.point_at(i)), i);
      const double* p = ps.point(split.point_at(i));
      for (int c = 0; c < d; ++c) {
        ASSERT_GE(p[c], box[static_cast<std::size_t>(c)]);
        ASSERT_LE(p[c], box[static_cast<std::size_t>(d + c)]);
      }
    }
  }
  // Boxes never overlap: two blocks' boxes meet at most on a face (a split plane
  // that points on both sides share, as on grids).
  for (std::uint32_t a = 0; a < split.block_count(); ++a) {
    for (std::uint32_t b = a + 1; b < split.block_count(); ++b) {
      bool apart = false;
      for (int c = 0; c < d && !apart; ++c) {
        apart = split.box(a)[static_cast<std::size_t>(d + c)] <= split.box(b)[static_cast<std::size_t>(c)] ||
                split.box(b)[static_cast<std::size_t>(d + c)] <= split.box(a)[static_cast<std::size_t>(c)];
      }
      ASSERT_TRUE(apart) << "blocks " << a << " and " << b << " overlap";
    }
  }
}

TEST(SpaceSplit, BlocksTileTheOrderInCompactBalancedBoxes) {
  expect_valid_split("uniform 2-d", make_points(2, uniform_points(2, 5000, 1)), 256);
  expect_valid_split("uniform 3-d", make_points(3, uniform_points(3, 6000, 2)), 300);
  expect_valid_split("uniform 5-d", make_points(5, uniform_points(5, 3000, 3)), 100);
  expect_valid_split("clustered 3-d", make_points(3, clustered_points(3, 6000, 4)), 256);
  expect_valid_split("grid 2-d", make_points(2, grid_points(2, 40)), 64);
  expect_valid_split("grid 3-d", make_points(3, grid_points(3, 12)), 100);
  expect_valid_split("one block", make_points(3, uniform_points(3, 50, 5)), 64);
  expect_valid_split("block of one leaf", make_points(2, uniform_points(2, 500, 6)), 8);
  // Large enough for the two halves to be split on two threads.
  expect_valid_split("uniform 2-d, two threads", make_points(2, uniform_points(2, 70000, 9)), 512);
}

// The order depends on the point set only: input shuffled, the same coordinates come
// at every position and the blocks are the same.
TEST(SpaceSplit, TheOrderIsAFunctionOfThePointSet) {
  for (const auto& [name, d, coords] : std::vector<std::tuple<std::string, int, std::vector<double>>>{
           {"uniform 3-d", 3, uniform_points(3, 4000, 7)},
           {"grid 3-d", 3, grid_points(3, 10)},
           {"grid 2-d", 2, grid_points(2, 30)},
           {"clustered 2-d", 2, clustered_points(2, 3000, 8)},
           {"uniform 3-d, two threads", 3, uniform_points(3, 70000, 10)}}) {
    for (std::uint64_t seed = 1; seed <= 3; ++seed) {
      SCOPED_TRACE(name + ", shuffle " + std::to_string(seed));
      const std::size_t n = coords.size() / static_cast<std::size_t>(d);
      std::vector<std::size_t> perm(n);
      std::iota(perm.begin(), perm.end(), std::size_t{0});
      std::mt19937_64 rng(seed);
      std::shuffle(perm.begin(), perm.end(), rng);
      std::vector<double> shuffled;
      for (const std::size_t i : perm) {
        shuffled.insert(shuffled.end(), coords.begin() + static_cast<std::ptrdiff_t>(i * d),
                        coords.begin() + static_cast<std::ptrdiff_t>((i + 1) * d));
      }
      const PointSet a = make_points(d, coords), b = make_points(d, shuffled);
      const SpaceSplit sa(a, 128), sb(b, 128);
      ASSERT_EQ(sa.block_count(), sb.block_count());
      for (std::uint32_t k = 0; k < sa.block_count(); ++k) ASSERT_EQ(sa.end(k), sb.end(k));
      for (std::uint32_t i = 0; i < sa.size(); ++i) {
        const double* p = a.point(sa.point_at(i));
        const double* q = b.point(sb.point_at(i));
        for (int c = 0; c < d; ++c) ASSERT_EQ(p[c], q[c]) << "position " << i;
      }
    }
  }
}

// The k-th point across P parts by rounds of counts (CountSelect), simulated here part
// by part in lockstep as MPI will run them: the point a sort of the whole set gives,
// for every P and k, on uniform points and on a grid (ties along every axis), within
// O(log n) rounds; and SpaceSplit's first cut is at the point it selects.
struct SelectRun {
  std::uint64_t id = 0;
  int rounds = 0;
};

SelectRun select_across_parts(const PointSet& ps, int axis, std::uint64_t k, int parts, std::uint64_t seed) {
  const int d = ps.dimension();
  std::vector<std::vector<double>> coords(static_cast<std::size_t>(parts));
  std::vector<std::vector<std::uint64_t>> ids(static_cast<std::size_t>(parts));
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> part_of(0, parts - 1);
  for (std::uint64_t i = 0; i < ps.size(); ++i) {
    const auto p = static_cast<std::size_t>(part_of(rng));
    coords[p].insert(coords[p].end(), ps.point(i), ps.point(i) + d);
    ids[p].push_back(i);
  }
  std::vector<CountSelect> selects;
  for (int p = 0; p < parts; ++p)
    selects.emplace_back(d, axis, coords[static_cast<std::size_t>(p)], ids[static_cast<std::size_t>(p)]);
  SelectRun run;
  for (;;) {
    ++run.rounds;
    std::vector<CountSelect::Proposal> proposals;  // MPI_Allgather
    for (CountSelect& s : selects) proposals.push_back(s.propose());
    const CountSelect::Key pivot = CountSelect::pivot_of(proposals, axis);
    CountSelect::Counts total;  // MPI_Allreduce (sum)
    for (const CountSelect& s : selects) {
      const CountSelect::Counts c = s.count(pivot);
      total.below += c.below;
      total.at += c.at;
    }
    const CountSelect::Side side = CountSelect::decide(k, total);
    if (side == CountSelect::Side::kFound) {
      run.id = pivot.id;
      return run;
    }
    for (CountSelect& s : selects) s.narrow(pivot, side);
    if (run.rounds > 200) return run;  // a bug: the test fails below
  }
}

TEST(CountSelect, FindsTheKthPointAcrossAnyNumberOfParts) {
  for (const auto& [name, d, coords] : std::vector<std::tuple<std::string, int, std::vector<double>>>{
           {"uniform 3-d", 3, uniform_points(3, 3000, 11)},
           {"grid 3-d", 3, grid_points(3, 12)},
           {"clustered 2-d", 2, clustered_points(2, 2000, 12)}}) {
    const PointSet ps = make_points(d, coords);
    const std::uint64_t n = ps.size();
    for (int axis = 0; axis < d; ++axis) {
      std::vector<CountSelect::Key> all;
      for (std::uint64_t i = 0; i < n; ++i) all.push_back({std::vector<double>(ps.point(i), ps.point(i) + d), i});
      std::sort(all.begin(), all.end(), [&](const auto& a, const auto& b) { return CountSelect::before(a, b, axis); });
      for (const int parts : {1, 2, 3, 4, 7}) {
        for (const std::uint64_t k : {std::uint64_t{0}, n / 2, n - 1, n / 3 + 1}) {
          SCOPED_TRACE(name + ", axis " + std::to_string(axis) + ", " + std::to_string(parts) + " parts, k " +
                       std::to_string(k));
          const SelectRun run = select_across_parts(ps, axis, k, parts, 100 + static_cast<std::uint64_t>(parts));
          EXPECT_EQ(run.id, all[k].id);
          // Each round keeps at most three quarters of the candidates.
          EXPECT_LE(run.rounds,
                    static_cast<int>(std::ceil(std::log(static_cast<double>(n)) / std::log(4.0 / 3.0))) + 2);
        }
      }
    }
  }
}

TEST(CountSelect, SpaceSplitCutsAtTheSelectedMedian) {
  const PointSet ps = make_points(3, uniform_points(3, 4000, 13));
  const SpaceSplit split(ps, 64);
  // The widest side of the whole set's box, as SpaceSplit chooses it.
  int axis = 0;
  double widest = -1;
  for (int c = 0; c < 3; ++c) {
    double lo = ps.point(0)[c], hi = lo;
    for (std::uint64_t i = 0; i < ps.size(); ++i) {
      lo = std::min(lo, ps.point(i)[c]);
      hi = std::max(hi, ps.point(i)[c]);
    }
    if (hi - lo > widest) {
      widest = hi - lo;
      axis = c;
    }
  }
  const std::uint64_t half = ps.size() / 2;
  // The right half holds positions [n/2, n): its first point in the axis's order.
  std::uint64_t first_right = split.point_at(static_cast<std::uint32_t>(half));
  auto key = [&](std::uint64_t i) { return CountSelect::Key{std::vector<double>(ps.point(i), ps.point(i) + 3), i}; };
  for (std::uint32_t pos = static_cast<std::uint32_t>(half); pos < split.size(); ++pos) {
    if (CountSelect::before(key(split.point_at(pos)), key(first_right), axis)) first_right = split.point_at(pos);
  }
  for (const int parts : {1, 3, 7}) EXPECT_EQ(select_across_parts(ps, axis, half, parts, 7).id, first_right);
}

}  // namespace
}  // namespace spokemesh

namespace spokemesh {
namespace {

using testing::make_points;
using testing::uniform_points;

// A part of a larger split: the pieces' points come in the whole split's order.
TEST(SpaceSplit, PiecesOfTheWholeSplitKeepItsOrder) {
  const PointSet ps = make_points(3, uniform_points(3, 5000, 21));
  const SpaceSplit whole(ps, 300);
  // Pieces: the whole split's nodes of [0, 1250) and [2500, 5000) positions (the first
  // quarter and the second half are nodes: halving), the rest as held points.
  std::vector<std::uint32_t> members;
  for (std::uint32_t p = 0; p < 1250; ++p) members.push_back(whole.point_at(p));
  for (std::uint32_t p = 2500; p < 5000; ++p) members.push_back(whole.point_at(p));
  std::mt19937 rng(5);
  std::shuffle(members.begin(), members.begin() + 1250, rng);  // any order within a piece
  std::shuffle(members.begin() + 1250, members.end(), rng);
  const std::vector<std::uint32_t> ends{1250, 3750};
  const SpaceSplit part(ps, members, ends, 300);
  ASSERT_EQ(part.swept(), 3750u);
  for (std::uint32_t p = 0; p < 1250; ++p) ASSERT_EQ(part.point_at(p), whole.point_at(p)) << "position " << p;
  for (std::uint32_t p = 1250; p < 3750; ++p) ASSERT_EQ(part.point_at(p), whole.point_at(p + 1250)) << "position " << p;
  // The others trail as one block, split as a node of their own: here they are the
  // whole split's node of [1250, 2500), so they come in its order.
  for (std::uint32_t p = 3750; p < 5000; ++p) ASSERT_EQ(part.point_at(p), whole.point_at(p - 2500)) << "position " << p;
  EXPECT_EQ(part.end(part.block_count() - 1), 5000u);
  EXPECT_EQ(part.begin(part.block_count() - 1), 3750u);
  // The pieces' nodes are the whole split's nodes (positions shifted past the gap).
  const auto whole_nodes = whole.nodes_of_at_most(600), part_nodes = part.nodes_of_at_most(600);
  std::vector<std::pair<std::uint32_t, std::uint32_t>> expected;
  for (const auto& [b, e] : whole_nodes) {
    if (e <= 1250) expected.emplace_back(b, e);
    if (b >= 2500) expected.emplace_back(b - 1250, e - 1250);
  }
  EXPECT_EQ(part_nodes, expected);
}

}  // namespace
}  // namespace spokemesh
