#include "mesh/delaunay_sweep.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "base/dimension.hpp"
#include "base/mixing.hpp"
#include "mesh/ball_bounds.hpp"
#include "mesh/insertion_order.hpp"
#include "mesh/ordered_run.hpp"
#include "mesh/triangulation.hpp"
#include "mesh/whole.hpp"
#include "search/split_index.hpp"
#include "spokemesh/certify.hpp"

namespace spokemesh::detail {

namespace {

using ball_bounds::Interval;

// A region's box E starts as the region's bounding box widened by a margin: this
// many times the typical reach of a seed's balls (the median, over kMarginSamples
// seeds of the region triangulated alone, of how far the parts of their balls inside
// the set's box reach from them): on a scan, the distance to the next scan line, not
// to the next point along it.
constexpr double kMarginReaches = 1.0;
constexpr std::size_t kMarginSamples = 31;
// Before the rest of a region, its first BRIO rounds (an eighth of its points, at least
// kMarginSampleAtLeast) are triangulated alone: if their balls' reach (at that lower
// density: on a surface reach follows the shape) would put three quarters of the set in
// E, the balls reach across the set and the run takes the whole set at once.
constexpr std::size_t kMarginSampleAtLeast = 512;
// The balls and hull facets that fail against E are asked of the k-d tree one by one
// while the points those queries test stay below kQueryWork times the region's points
// in a round. Beyond that: when the queries skimmed more than kQueryWorkPerBall points
// each (huge balls nearly following a long curve or surface: a wider E would not hold
// them either), or when E's margin, doubled, would add more than kGrowFactor times the
// region's points (and kGrowAtLeast) or hold most of the set, the run takes the whole
// set; otherwise (scan lines: many cheap queries) E's margin doubles. A region taking
// more than kMaxRounds rounds also turns to the whole set.
constexpr std::size_t kGrowFactor = 2;
constexpr std::size_t kGrowAtLeast = 4096;
constexpr std::size_t kQueryWork = 16;
constexpr std::size_t kQueryWorkPerBall = 4096;
// A query returns at most this many of the points in a ball (the deepest).
constexpr std::size_t kQueryTakeAtMost = 8;
constexpr int kMaxRounds = 64;
// A region with fewer than 1/kWalkShare of its points wanted as seeds (a --seeds range
// that cuts it, a batch of seeds) has its seeds' stars walked instead, as long as that
// takes less time than triangulating the region would: about kSecondsPerPoint[d] a
// point of the region (measured: one thread, margins included). The time is read every
// walk. (The rows are the same either way: only the time is measured.)
constexpr std::size_t kWalkShare = 16;
constexpr double kSecondsPerPoint[4] = {0, 0, 1.5e-6, 5e-6};
constexpr std::size_t kWalksKnown = 4;  // walks of the run before their mean decides (Run::walks_dearer)
// Cancellation and the memory reserved are looked at every this many insertions.
constexpr std::uint32_t kCancelEvery = 4096;
// MeshEngine::kAuto takes the star walk when a probe of this many points of the sweep
// needs more than kTiesPerPoint exact evaluations a point (ties_dominate).
constexpr std::uint64_t kTieProbePoints = 4096;
constexpr double kTiesPerPoint = 2.0;
// A run asks MeshOptions::reserve_bytes for memory in steps of at least this.
constexpr std::size_t kReserveStep = std::size_t{16} << 20;

template <int D>
using Box = std::array<double, 2 * D>;  // D lows, then D highs

template <int D>
bool in_box(const Box<D>& b, const double* x) {
  for (int k = 0; k < D; ++k) {
    if (x[k] < b[k] || x[k] > b[D + k]) return false;
  }
  return true;
}

// A k-d tree box (floats, holding its points) inside b.
template <int D>
bool box_within(const float* lo, const float* hi, const Box<D>& b) {
  for (int k = 0; k < D; ++k) {
    if (static_cast<double>(lo[k]) < b[k] || static_cast<double>(hi[k]) > b[D + k]) return false;
  }
  return true;
}

template <int D>
bool box_meets(const float* lo, const float* hi, const Box<D>& b) {
  for (int k = 0; k < D; ++k) {
    if (static_cast<double>(hi[k]) < b[k] || static_cast<double>(lo[k]) > b[D + k]) return false;
  }
  return true;
}

template <int D>
bool contains(const Box<D>& outer, const Box<D>& inner) {
  for (int k = 0; k < D; ++k) {
    if (inner[k] < outer[k] || inner[D + k] > outer[D + k]) return false;
  }
  return true;
}

// What a run shares: the set, its order, the options, and the triangulation of every
// point once a region's balls have reached across the set (or kept from an earlier run).
template <int D, class Index>
struct Run {
  const Index& index;  // box queries: the caller's KdTree, or the split's own index
  const KdTree* tree;  // the caller's, if any (the star walks' fallback builds one)
  const PointSet& ps;
  const SpaceSplit& split;
  const MeshOptions& options;
  std::shared_ptr<const Predicates> shared_pred;  // shared with the whole set's triangulation
  const Predicates& pred;
  // What this process lacks of a larger set (MeshOptions::held), or null when its
  // points are the whole set; the whole set's size.
  const HeldRegion* held;
  std::uint64_t whole_points;
  Box<D> bounds;  // the (whole) set's bounding box (exact)
  std::atomic<std::uint64_t> deferred{0};
  std::uint32_t seed_begin, seed_end;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> regions;  // sweep positions [first, second)

  std::once_flag whole_once;
  std::shared_ptr<const Whole<D>> whole;  // null until built, and when its memory was refused
  Status whole_status;
  std::atomic<bool> use_whole{false};      // `whole` was built: every region takes it
  std::atomic<bool> whole_wanted{false};   // a region found balls across the set: others stop trying
  std::atomic<bool> whole_refused{false};  // its memory was refused: such regions walk their stars
  std::size_t whole_reserved = 0;
  std::size_t whole_inserted = 0;  // the points ensure_whole inserted (a donor held the rest)
  std::mutex reserve_mu;
  // The walks of the run so far (RegionMesher::walk): how many, and their time. A region
  // with few seeds wanted walks them only while the run's mean walk says that costs less
  // than triangulating it (each region learning it anew walked 16 seeds a region:
  // on a sphere's surface, where a walk takes 20 ms, that was every seed of a batch).
  // A walk stopped at its region's deadline (one star dearer than the region) sets
  // walks_stopped: the run's regions are triangulated from then on.
  std::atomic<std::uint64_t> walks{0}, walk_nanos{0};
  std::atomic<bool> walks_stopped{false};
  bool walks_dearer(std::size_t seeds, double region_seconds) const {
    if (walks_stopped.load(std::memory_order_relaxed)) return true;
    const std::uint64_t count = walks.load(std::memory_order_relaxed);
    if (count < kWalksKnown) return false;
    const double mean =
        1e-9 * static_cast<double>(walk_nanos.load(std::memory_order_relaxed)) / static_cast<double>(count);
    return mean * static_cast<double>(seeds) > region_seconds;
  }

  std::once_flag tree_once;
  std::unique_ptr<KdTree> own_tree;

  Run(const Index& i, const KdTree* t, const PointSet& points, const SpaceSplit& s, const MeshOptions& o)
      : index(i),
        tree(t),
        ps(points),
        split(s),
        options(o),
        shared_pred(std::make_shared<const Predicates>(points)),
        pred(*shared_pred),
        held(o.held != nullptr && !o.held->holds_all() ? o.held : nullptr),
        whole_points(held != nullptr ? held->whole_points() : points.size()) {
    // A triangulation of every point kept from an earlier run on these points: every
    // region reads it, nothing is built.
    if (auto kept = std::dynamic_pointer_cast<const Whole<D>>(o.whole); kept != nullptr && kept->points == &points) {
      whole = std::move(kept);
      use_whole.store(true);
      std::call_once(whole_once, [] {});
    }
  }

  // The k-d tree the star walks need: the caller's, or one built on first use (only
  // seeds that fall back to walks need it).
  const KdTree& walk_tree() {
    if (tree != nullptr) return *tree;
    std::call_once(tree_once, [&] { own_tree = std::make_unique<KdTree>(ps); });
    return *own_tree;
  }

  bool cancelled() const {
    return options.star.cancel != nullptr && options.star.cancel->load(std::memory_order_relaxed);
  }

  // A seed whose star this process cannot certify from the points it holds.
  void defer(std::uint32_t seed, StarCertificate certificate) {
    deferred.fetch_add(1, std::memory_order_relaxed);
    if (options.defer) options.defer(seed, std::move(certificate));
  }
  // ...because the balls reach across the whole set: it should hold all of it.
  void defer_to_whole_set(std::uint32_t seed) {
    StarCertificate c;
    c.reach.assign(held->whole_box().begin(), held->whole_box().end());
    defer(seed, std::move(c));
  }
  // A walked star of a run over held points: true when certified against what the
  // process lacks, else deferred.
  bool certified_walk(const Star& star) {
    if (held == nullptr) return true;
    StarCertificate c = held->certify(ps, star);
    if (c.certified) return true;
    defer(star.seed, std::move(c));
    return false;
  }

  // Whether a triangulation that holds `now` bytes, of which `mine` are reserved, may
  // go on: MeshOptions::reserve_bytes is asked for the difference (at least
  // kReserveStep), and `mine` grows by what it granted. Always when nothing is asked.
  bool reserve(std::size_t& mine, std::size_t now) {
    if (now <= mine) return true;
    if (!options.reserve_bytes) {
      mine = now;
      return true;
    }
    const std::size_t ask = std::max(now - mine, kReserveStep);
    std::lock_guard lock(reserve_mu);
    if (!options.reserve_bytes(ask)) return false;
    mine += ask;
    return true;
  }

  // Builds the triangulation of every point (once; concurrent callers wait). When its
  // memory is refused, it is dropped and whole_refused set. The caller that builds it
  // may give its own region's triangulation (`donor`, with the memory reserved for it):
  // any Delaunay triangulation of some of the points is a start, so the points it holds
  // are not inserted again (contour lines: a region triangulated before its balls
  // showed they reach across the set). The donor is left empty.
  const Status& ensure_whole(Triangulation<D>* donor = nullptr, std::size_t* donor_reserved = nullptr) {
    std::call_once(whole_once, [&] {
      const auto n = static_cast<std::uint32_t>(ps.size());
      auto w = std::make_shared<Whole<D>>();
      w->pred = shared_pred;
      w->points = &ps;
      if (donor != nullptr && donor->vertex_count() > 1) {
        w->tri = std::make_unique<Triangulation<D>>(std::move(*donor));
        donor->clear();
        whole_reserved = std::exchange(*donor_reserved, 0);
      } else {
        w->tri = std::make_unique<Triangulation<D>>(ps, pred);
      }
      Triangulation<D>& t = *w->tri;
      w->local.assign(n, 0);  // 0: not inserted yet (local id 0 is infinity)
      for (std::uint32_t local = 1; local < t.vertex_count(); ++local) w->local[t.global(local)] = local;
      std::vector<std::uint32_t> order, scratch;
      order.reserve(n - (t.vertex_count() - 1));
      for (std::uint32_t r = 0; r < n; ++r) {
        if (w->local[split.point_at(r)] == 0) order.push_back(split.point_at(r));
      }
      insertion_order<D>(order, scratch);
      whole_inserted = order.size();
      t.reserve(n);
      auto granted = [&] {
        if (reserve(whole_reserved, w->bytes())) return true;
        whole_refused.store(true);
        return false;
      };
      auto inserted = insert_into<D>(*w, order, kCancelEvery, granted, [&] { return cancelled(); });
      if (!inserted.is_ok()) {
        whole_status = spokemesh::cancelled("mesh cancelled");
        return;
      }
      if (!inserted.value()) return;
      if (!options.accept) {
        index_owners(*w);
        if (!granted()) return;
      }
      whole = w;
      use_whole.store(true);
      if (options.keep_whole) options.keep_whole(std::move(w));
    });
    return whole_status;
  }
};

// The rows a region hands on.
struct RegionRows {
  std::uint64_t seeds = 0;
  std::vector<std::uint32_t> simplices;
};

// A cell's certificate in its triangulation's tag: not looked at (a new cell's), its
// ball or hull facet certified, failed this round, or failed and to be asked of the
// k-d tree.
constexpr std::uint32_t kUnknown = 0, kCertified = 1, kFailed = 2, kAskTree = 3;
// A run over held points (MeshOptions::held): the cell holds no held point in its ball
// (or beyond its hull facet), but the process lacks points that could be there. Its
// seeds are deferred.
constexpr std::uint32_t kRemote = 4;
// A region point: not a seed of the run, a seed whose star is not yet certified, done.
constexpr std::uint8_t kNotSeed = 0, kPendingSeed = 1, kDoneSeed = 2;

// A worker: triangulates regions one at a time and emits their seeds' stars.
template <int D, class Index>
class RegionMesher {
 public:
  RegionMesher(Run<D, Index>& run, MeshStats& total) : run_(run), total_(total), tri_(run.ps, run.pred) {}

  Status operator()(std::uint64_t unit, RegionRows& out) {
    out.simplices.clear();
    out.seeds = 0;
    const auto [first, last] = run_.regions[unit];
    wanted_.clear();
    const auto& seeds = run_.options.seeds;
    for (std::uint32_t r = first; r < last; ++r) {
      const std::uint32_t id = run_.split.point_at(r);
      if (id < run_.seed_begin || id >= run_.seed_end) continue;
      if (!seeds.empty() && !std::binary_search(seeds.begin(), seeds.end(), id)) continue;
      wanted_.push_back(r);
    }
    out.seeds = wanted_.size();
    if (wanted_.empty()) return Status::ok();
    if (run_.cancelled()) return cancelled("mesh cancelled");
    if (run_.held != nullptr && run_.whole_wanted.load()) return defer_to_whole_set();
    // (Not once balls were found to reach across the set: the triangulation of every
    // point is being built, and answers every seed.)
    if (!run_.use_whole.load() && !run_.whole_wanted.load() && wanted_.size() * kWalkShare < last - first) {
      // Few seeds wanted: walk their stars while that costs less than triangulating the
      // region would; when walking proves dearer (stars reaching far: a sphere's
      // surface, contour lines), the rest of the region is triangulated.
      const double region_seconds = kSecondsPerPoint[D] * (last - first);
      if (!run_.walks_dearer(wanted_.size(), region_seconds)) {
        auto walked = walk(out, region_seconds);
        if (!walked.is_ok()) return walked.status();
        if (walked.value() == wanted_.size()) return Status::ok();
        wanted_.erase(wanted_.begin(), wanted_.begin() + static_cast<std::ptrdiff_t>(walked.value()));
      }
    }
    if (!run_.use_whole.load() && !run_.whole_wanted.load()) {
      ++stats_.regions;
      Result<Outcome> local = triangulate(first, last);
      if (!local.is_ok()) return local.status();
      stats_.peak_bytes = std::max(stats_.peak_bytes, tri_.bytes());
      if (local.value() == Outcome::kOverBudget) return walk(out).status();
      if (local.value() == Outcome::kFetch) {  // (over held points only)
        for (const std::uint32_t r : wanted_) {
          StarCertificate c;
          c.reach.assign(fetch_box_.begin(), fetch_box_.end());
          run_.defer(run_.split.point_at(r), std::move(c));
        }
        return Status::ok();
      }
      if (local.value() == Outcome::kDone) {
        if (run_.held != nullptr) defer_pending(first);
        if (run_.options.accept) {  // whole stars, one at a time
          for (const std::uint32_t r : wanted_) {
            cells_.clear();
            tri_.incident_cells(local_[r - first], cells_, seen_);
            emit(tri_, cells_, run_.split.point_at(r), out.simplices);
          }
        } else {
          emit_owned(first, out.simplices);
        }
        return Status::ok();
      }
    }
    // Over held points, the whole set is what this process should hold: deferred.
    if (run_.held != nullptr) return defer_to_whole_set();
    if (run_.whole_refused.load()) return walk(out).status();
    if (const Status& s = run_.ensure_whole(&tri_, &reserved_); !s.is_ok()) return s;
    if (run_.whole == nullptr) return walk(out).status();  // refused just now
    stats_.whole_set = true;
    const Whole<D>& whole = *run_.whole;
    for (const std::uint32_t r : wanted_) {
      const std::uint32_t id = run_.split.point_at(r);
      if (!run_.options.accept && !whole.owned_start.empty()) {
        emit_whole_owned(whole, id, out.simplices);
        continue;
      }
      cells_.clear();
      whole.tri->incident_cells(whole.local[id], cells_, seen_);
      emit(*whole.tri, cells_, id, out.simplices);
    }
    return Status::ok();
  }

  void finish() {
    TriangulationStats& t = total_.triangulation;
    t.regions += stats_.regions;
    t.inserted += stats_.inserted;
    t.margin_rounds += stats_.margin_rounds;
    t.ball_queries += stats_.ball_queries;
    t.walked_seeds += stats_.walked_seeds;
    t.whole_set = t.whole_set || stats_.whole_set;
    t.exact_calls += tri_.stats().exact_calls;
    t.peak_bytes += stats_.peak_bytes;
    if (walker_) total_.star += walker_->stats();
  }

 private:
  // Which points of the set are in the triangulation: those in E, the region's, and
  // the extras that queries found. E first: the coordinates are at hand, while the
  // region's position is one more random read.
  bool inserted(std::uint32_t id, const double* x) const {
    if (in_box<D>(e_, x)) return true;
    const std::uint32_t r = run_.split.position_of(id);
    if (r >= first_ && r < last_) return true;
    return std::binary_search(extras_.begin(), extras_.end(), id);
  }

  // The margin of a region's box E at the density of the points inserted so far (the
  // first `inserted` of the region in BRIO order, alone): the median over sample seeds
  // among them of how far the boxes of their balls' parts inside the set's box reach
  // from them, times kMarginReaches. 0 when there is no simplex yet.
  double margin(std::size_t inserted) {
    if (!tri_.full()) return 0;
    std::vector<double> reaches;
    for (std::size_t s = 0; s < kMarginSamples; ++s) {
      const std::uint32_t local = local_[order_[(2 * s + 1) * inserted / (2 * kMarginSamples)]];
      const double* x = tri_.coords(local);
      cells_.clear();
      tri_.incident_cells(local, cells_, seen_);
      double reach = 0;
      for (const std::uint32_t c : cells_) {
        if (tri_.infinite_index(c) >= 0) continue;
        const Check check = certify(c);
        for (int k = 0; k < D; ++k) {
          reach = std::max({reach, x[k] - check.extent[static_cast<std::size_t>(k)],
                            check.extent[static_cast<std::size_t>(D + k)] - x[k]});
        }
      }
      reaches.push_back(reach);
    }
    std::nth_element(reaches.begin(), reaches.begin() + static_cast<std::ptrdiff_t>(reaches.size() / 2), reaches.end());
    return kMarginReaches * reaches[reaches.size() / 2];
  }

  // Box b widened by `margin` on every side, within the set's box.
  Box<D> margin_box(const Box<D>& b, double margin) const {
    Box<D> e{};
    for (int k = 0; k < D; ++k) {
      e[static_cast<std::size_t>(k)] =
          std::max(run_.bounds[static_cast<std::size_t>(k)], b[static_cast<std::size_t>(k)] - margin);
      e[static_cast<std::size_t>(D + k)] =
          std::min(run_.bounds[static_cast<std::size_t>(D + k)], b[static_cast<std::size_t>(D + k)] + margin);
    }
    return e;
  }

  // Every point of box g not yet inserted (with E = e_), into `out`; false (and `out`
  // incomplete) when there are more than `cap`.
  bool collect_box(const Box<D>& g, std::vector<std::uint32_t>& out, std::size_t cap) {
    out.clear();
    bool over = false;
    run_.index.find_first(
        [&](const float* lo, const float* hi) { return box_meets<D>(lo, hi, g) && !box_within<D>(lo, hi, e_); },
        [&](std::uint32_t id, const double* x) {
          if (!in_box<D>(g, x) || inserted(id, x)) return false;
          out.push_back(id);
          over = out.size() > cap;
          return over;
        });
    return !over;
  }

  // A cell's certificate: every point of the set that could be inside its ball (or
  // beyond its hull facet) is inserted. For a finite cell, also the box around the
  // part of its ball inside the set's box (`extent`), and the ball itself.
  struct Check {
    bool ok = false;
    std::array<Interval, D> centre{};
    double radius2 = 0;
    Box<D> extent{};
  };
  Check certify(std::uint32_t c) const {
    Check out;
    const auto& cell = tri_.cell(c);
    const int inf = tri_.infinite_index(c);
    if (inf < 0) {
      std::array<const double*, D> v{};
      for (int k = 0; k < D; ++k) v[static_cast<std::size_t>(k)] = tri_.coords(cell.v[static_cast<std::size_t>(k) + 1]);
      const double* s = tri_.coords(cell.v[0]);
      if (!ball_bounds::circumball<D>(s, v, out.centre, out.radius2))
        ball_bounds::exact_circumball<D>(s, v, out.centre, out.radius2);
      out.extent = ball_bounds::clipped_extent<D>(out.centre, out.radius2, run_.bounds.data());
      out.ok = ball_bounds::inside<D>(out.extent, e_.data());
      return out;
    }
    if (e_covers_all_) {
      out.ok = true;
      return out;
    }
    // The hull facet's outer side must miss every point outside E: the slabs of the
    // set's box beyond E's sides.
    std::array<const double*, D> f{};
    for (int k = 0, j = 0; k <= D; ++k) {
      if (k != inf) f[static_cast<std::size_t>(j++)] = tri_.coords(cell.v[static_cast<std::size_t>(k)]);
    }
    const double* inner = apex_across(c, inf);
    for (int k = 0; k < D; ++k) {
      for (int side = 0; side < 2; ++side) {
        Box<D> slab = run_.bounds;
        if (side == 0) {
          if (!(e_[k] > run_.bounds[k])) continue;
          slab[D + k] = e_[k];
        } else {
          if (!(e_[D + k] < run_.bounds[D + k])) continue;
          slab[k] = e_[D + k];
        }
        if (StarCertifier::may_be_beyond(D, f.data(), inner, slab.data())) return out;
      }
    }
    out.ok = true;
    return out;
  }
  // The coordinates of the vertex of the finite cell across infinite cell c's hull
  // facet (at index inf) that is not on the facet.
  const double* apex_across(std::uint32_t c, int inf) const {
    const std::uint32_t nb = tri_.cell(c).n[static_cast<std::size_t>(inf)];
    const auto& v = tri_.cell(nb).v;
    const auto& mine = tri_.cell(c).v;
    for (const std::uint32_t x : v) {
      if (std::find(mine.begin(), mine.end(), x) == mine.end()) return tri_.coords(x);
    }
    return tri_.coords(v[0]);  // unreachable
  }
  // The same vertex's local id.
  std::uint32_t apex_local_across(std::uint32_t c, int inf) const {
    const std::uint32_t nb = tri_.cell(c).n[static_cast<std::size_t>(inf)];
    const auto& v = tri_.cell(nb).v;
    const auto& mine = tri_.cell(c).v;
    for (const std::uint32_t x : v) {
      if (std::find(mine.begin(), mine.end(), x) == mine.end()) return x;
    }
    return v[0];  // unreachable
  }

  // A point of the set not inserted that conflicts with cell c (inside its ball, or
  // beyond its hull facet), appended to `out`; none when no point does (then c is
  // certified). Of several, the one deepest inside the ball, or farthest beyond the
  // hull facet (a vertex of the whole set's hull, as Quickhull picks it): inserting it
  // destroys c, and its new cells are nearer the answer than those of an arbitrary
  // one (inserting every conflicting point would take whole slabs of points behind a
  // hull facet of the region). The choice is a heuristic in double; any choice is
  // correct.
  void query(std::uint32_t c, const Check& check, std::vector<std::uint32_t>& out) {
    ++stats_.ball_queries;
    const int inf = tri_.infinite_index(c);
    std::array<const double*, D> f{};
    const double* inner = nullptr;
    std::array<double, D> mid{};
    if (inf >= 0) {
      for (int k = 0, j = 0; k <= D; ++k) {
        if (k != inf) f[static_cast<std::size_t>(j++)] = tri_.coords(tri_.cell(c).v[static_cast<std::size_t>(k)]);
      }
      inner = apex_across(c, inf);
    } else {
      for (int k = 0; k < D; ++k) {
        mid[static_cast<std::size_t>(k)] =
            check.centre[static_cast<std::size_t>(k)].lo / 2 + check.centre[static_cast<std::size_t>(k)].hi / 2;
      }
    }
    // How deep inside the ball (|x - centre|^2 - r^2) or how far beyond the facet
    // (minus the orientation against the inner apex): lower is better.
    auto depth = [&](const double* x) {
      if (inf < 0) {
        double d2 = 0;
        for (int k = 0; k < D; ++k)
          d2 += (x[k] - mid[static_cast<std::size_t>(k)]) * (x[k] - mid[static_cast<std::size_t>(k)]);
        return d2 - check.radius2;
      }
      std::array<std::array<double, D>, D> m{};
      for (int i = 1; i < D; ++i) {
        for (int k = 0; k < D; ++k)
          m[static_cast<std::size_t>(i - 1)][static_cast<std::size_t>(k)] = f[static_cast<std::size_t>(i)][k] - f[0][k];
      }
      auto volume = [&](const double* q) {
        for (int k = 0; k < D; ++k) m[D - 1][static_cast<std::size_t>(k)] = q[k] - f[0][k];
        if constexpr (D == 2) {
          return m[0][0] * m[1][1] - m[0][1] * m[1][0];
        } else {
          return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                 m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        }
      };
      const double in = volume(inner);
      return in > 0 ? volume(x) : -volume(x);  // beyond: the inner apex's opposite sign
    };
    // Conflicting points with their depths: a ball keeps its kQueryTakeAtMost deepest (a
    // ball reaching into a clump holds many, all of them wanted soon), a hull facet its
    // farthest.
    taken_.clear();
    const std::size_t keep = inf >= 0 ? 1 : kQueryTakeAtMost;
    const std::size_t work_before = query_work_;
    run_.index.find_first(
        [&](const float* lo, const float* hi) {
          if (box_within<D>(lo, hi, e_)) return false;
          Box<D> b;
          for (int k = 0; k < D; ++k) {
            b[static_cast<std::size_t>(k)] = lo[k];
            b[static_cast<std::size_t>(D + k)] = hi[k];
          }
          if (inf >= 0) return StarCertifier::may_be_beyond(D, f.data(), inner, b.data());
          return !ball_bounds::misses<D>(check.centre, check.radius2, b.data());
        },
        [&](std::uint32_t id, const double* x) {
          ++query_work_;
          if (inserted(id, x)) return false;
          const double dx = depth(x);
          if (taken_.size() == keep && dx >= taken_.front().first) return false;  // not among the deepest
          if (!tri_.in_conflict(c, id)) return false;
          if (taken_.size() == keep) {
            std::pop_heap(taken_.begin(), taken_.end());
            taken_.pop_back();
          }
          taken_.emplace_back(dx, id);
          std::push_heap(taken_.begin(), taken_.end());  // the shallowest kept on top
          return false;
        });
    for (const auto& t : taken_) out.push_back(t.second);
    if (taken_.empty()) {  // certified: what the queries that found nothing cost
      empty_work_ += query_work_ - work_before;
      ++empty_queries_;
    }
  }

  // A run over held points whose balls reach across the whole set: every wanted seed
  // of the region is deferred (the process should hold the whole set).
  Status defer_to_whole_set() {
    for (const std::uint32_t r : wanted_) run_.defer_to_whole_set(run_.split.point_at(r));
    wanted_.clear();
    return Status::ok();
  }

  // A run over held points, once the region's rounds are over: each wanted seed still
  // pending (blocked by cells tagged kRemote only) is deferred with those cells' balls
  // and hull facets, and wanted_ keeps the seeds done.
  void defer_pending(std::uint32_t first) {
    if (pending_.empty()) return;
    for (const std::uint32_t x : pending_) {
      StarCertificate c;
      cells_.clear();
      tri_.incident_cells(x, cells_, seen_);
      for (const std::uint32_t cell : cells_) {
        if (tri_.tag(cell) != kRemote) continue;
        const int inf = tri_.infinite_index(cell);
        if (inf < 0) {
          // The ball, as StarCertifier asks for it: the middle of the centre's interval,
          // the radius grown by the interval's spread.
          const Check check = certify(cell);
          double spread2 = 0;
          for (int k = 0; k < D; ++k) {
            const auto& ck = check.centre[static_cast<std::size_t>(k)];
            const double mid = ck.lo / 2 + ck.hi / 2;
            c.balls.push_back(mid);
            const double half = std::max(ball_bounds::up(ck.hi - mid), ball_bounds::up(mid - ck.lo));
            spread2 += half * half;
          }
          c.balls.push_back(ball_bounds::up(ball_bounds::up(ball_bounds::up(std::sqrt(check.radius2)) +
                                                            ball_bounds::up(std::sqrt(ball_bounds::up(spread2))))) *
                            (1 + 1e-12));
        } else {
          const auto ids = hull_facet_ids(cell, inf);
          c.hull_facets.insert(c.hull_facets.end(), ids.begin(), ids.end());
          c.hull_facets.push_back(tri_.global(apex_local_across(cell, inf)));
        }
      }
      run_.defer(tri_.global(x), std::move(c));
    }
    wanted_.erase(std::remove_if(wanted_.begin(), wanted_.end(),
                                 [&](std::uint32_t r) { return state_[local_[r - first]] != kDoneSeed; }),
                  wanted_.end());
  }

  // The point ids of infinite cell c's hull facet (inf: its infinite vertex's index),
  // ascending.
  std::array<std::uint32_t, D> hull_facet_ids(std::uint32_t c, int inf) const {
    std::array<std::uint32_t, D> ids{};
    for (int k = 0, j = 0; k <= D; ++k) {
      if (k != inf) ids[static_cast<std::size_t>(j++)] = tri_.global(tri_.cell(c).v[static_cast<std::size_t>(k)]);
    }
    std::sort(ids.begin(), ids.end());
    return ids;
  }

  // Whether every point of the whole set that could conflict with cell c is held: its
  // ball (check: certify(c)) or its hull facet's outer side (a run over held points).
  bool held_by_process(std::uint32_t c, const Check& check) const {
    const int inf = tri_.infinite_index(c);
    if (inf < 0) {
      std::array<double, D> lo{}, hi{};
      for (int k = 0; k < D; ++k) {
        lo[static_cast<std::size_t>(k)] = check.centre[static_cast<std::size_t>(k)].lo;
        hi[static_cast<std::size_t>(k)] = check.centre[static_cast<std::size_t>(k)].hi;
      }
      return run_.held->ball_held(lo.data(), hi.data(), check.radius2);
    }
    std::array<const double*, D> f{};
    for (int k = 0, j = 0; k <= D; ++k) {
      if (k != inf) f[static_cast<std::size_t>(j++)] = tri_.coords(tri_.cell(c).v[static_cast<std::size_t>(k)]);
    }
    const auto ids = hull_facet_ids(c, inf);
    return run_.held->beyond_held(f.data(), apex_across(c, inf), ids);
  }

  // What became of a region: every wanted seed's star certified; the balls reach across
  // the set (the run then takes the triangulation of every point); or its memory was
  // refused (its seeds' stars are then walked).
  // Over held points (MeshOptions::held) a fourth: E would reach past what the process
  // holds (fetch_box_): the region's seeds are deferred with that box to fetch, as one
  // process's E would take in those points, rather than ball by ball.
  enum class Outcome { kDone, kWhole, kOverBudget, kFetch };

  // Inserts the points, in insertion_order, as long as the memory reserved allows.
  Result<bool> insert_points(std::vector<std::uint32_t>& ids) {
    // In the split's order first (queries hand their points over sorted by id, which
    // is no order in space), so that each round walks from point to nearby point.
    std::sort(ids.begin(), ids.end(),
              [&](std::uint32_t a, std::uint32_t b) { return run_.split.position_of(a) < run_.split.position_of(b); });
    insertion_order<D>(ids, scratch_);
    return insert_range(
        ids.size(), [&](std::size_t k) { return ids[k]; }, [](std::size_t, std::uint32_t) {});
  }
  // Inserts points id_at(0), ..., id_at(count - 1), handing each one's local id to
  // inserted(k, local), as long as the memory reserved allows.
  template <class IdAt, class Inserted>
  Result<bool> insert_range(std::size_t count, IdAt&& id_at, Inserted&& inserted) {
    for (std::size_t k = 0; k < count; ++k) {
      if ((k + 1) % kCancelEvery == 0) {
        if (run_.cancelled()) return cancelled("mesh cancelled");
        if (!run_.reserve(reserved_, tri_.bytes())) return false;
      }
      if (k + Triangulation<D>::kPrefetchAhead < count) tri_.prefetch(id_at(k + Triangulation<D>::kPrefetchAhead));
      inserted(k, tri_.insert(id_at(k)));
    }
    stats_.inserted += count;
    return run_.reserve(reserved_, tri_.bytes());
  }

  // Triangulates region [first, last) with a margin until every wanted seed's star is
  // certified.
  Result<Outcome> triangulate(std::uint32_t first, std::uint32_t last) {
    first_ = first;
    last_ = last;
    tri_.clear();
    extras_.clear();
    // The region's points in BRIO order, their local ids kept by position.
    Box<D> region{};
    for (int k = 0; k < D; ++k) {
      region[static_cast<std::size_t>(k)] = HUGE_VAL;
      region[static_cast<std::size_t>(D + k)] = -HUGE_VAL;
    }
    ids_.clear();
    for (std::uint32_t r = first; r < last; ++r) {
      const std::uint32_t id = run_.split.point_at(r);
      ids_.push_back(id);
      const double* x = run_.ps.point(id);
      for (int k = 0; k < D; ++k) {
        region[static_cast<std::size_t>(k)] = std::min(region[static_cast<std::size_t>(k)], x[k]);
        region[static_cast<std::size_t>(D + k)] = std::max(region[static_cast<std::size_t>(D + k)], x[k]);
      }
    }
    // The region's points in BRIO order, their local ids kept by position. The first
    // rounds (an eighth in 3-d, a quarter in 2-d: a sample spread over the region) come
    // first, and give the margin: the reach of their seeds' balls, scaled to the
    // region's density.
    const std::uint32_t region_points = last - first;
    order_.resize(region_points);
    for (std::uint32_t i = 0; i < region_points; ++i) order_[i] = i;
    insertion_order<D>(order_, scratch_, [&](std::uint32_t i) { return ids_[i]; });
    local_.assign(region_points, 0);
    tri_.reserve(region_points + region_points / 2);  // the region and a typical margin
    const std::size_t sample = std::min<std::size_t>(
        region_points, std::max<std::size_t>(kMarginSampleAtLeast, region_points >> kRoundBits[D]));
    // Region items [from, from + count) of the order.
    auto insert_region = [&](std::size_t from, std::size_t count) {
      return insert_range(
          count, [&](std::size_t k) { return ids_[order_[from + k]]; },
          [&](std::size_t k, std::uint32_t local) { local_[order_[from + k]] = local; });
    };
    for (int k = 0; k < D; ++k) {  // nothing is in E until its points are (certify then fails every ball)
      e_[static_cast<std::size_t>(k)] = HUGE_VAL;
      e_[static_cast<std::size_t>(D + k)] = -HUGE_VAL;
    }
    if (auto in = insert_region(0, sample); !in.is_ok() || !in.value()) {
      if (!in.is_ok()) return in.status();
      return Outcome::kOverBudget;
    }
    // Whether the balls reach across the set, judged early: the sample's reach as it is
    // (on a surface, reach follows the shape, not the density) would put most of the
    // set in E. Then the region stops here and the run takes the whole set.
    // (Over held points, the points the process lacks in the box count too, by estimate.)
    const std::size_t most = 3 * run_.whole_points / 4;
    const Box<D> reach = margin_box(region, margin(sample));
    const std::size_t lacking =
        run_.held != nullptr ? static_cast<std::size_t>(run_.held->lacking_in(reach.data())) : 0;
    if (region_points < run_.whole_points &&
        (region_points + lacking > most || !collect_box(reach, found_, most - region_points - lacking))) {
      run_.whole_wanted.store(true);
      return Outcome::kWhole;
    }
    if (auto in = insert_region(sample, region_points - sample); !in.is_ok() || !in.value()) {
      if (!in.is_ok()) return in.status();
      return Outcome::kOverBudget;
    }
    if (run_.whole_wanted.load()) return Outcome::kWhole;  // another region found balls across the set
    // E: the margin at the region's own density.
    const double margin = this->margin(region_points);
    Box<D> e = margin_box(region, margin);
    if (run_.held != nullptr && !run_.held->box_held(e.data())) {
      fetch_box_ = e;
      return Outcome::kFetch;
    }
    collect_box(e, found_, static_cast<std::size_t>(-1));
    e_ = e;
    if (auto in = insert_points(found_); !in.is_ok() || !in.value()) {
      if (!in.is_ok()) return in.status();
      return Outcome::kOverBudget;
    }
    e_covers_all_ = contains<D>(e_, run_.bounds);
    double grown = std::max(margin, 0.0);  // E's next growth on each side
    // The region's points have local ids 1 .. region_points (inserted first): their
    // states, and the wanted ones pending.
    state_.assign(region_points + 1, kNotSeed);
    blocked_.assign(region_points + 1, 0);
    pending_.clear();
    for (const std::uint32_t r : wanted_) {
      const std::uint32_t x = local_[r - first];
      state_[x] = kPendingSeed;
      pending_.push_back(x);
    }
    for (int round = 0;; ++round) {
      if (run_.cancelled()) return cancelled("mesh cancelled");
      if (!tri_.full()) return Outcome::kWhole;
      if (e_covers_all_) return Outcome::kDone;  // every point is in: every cell is one of the set's
      // Certify the cells around every seed still pending, in one pass over the cells
      // (in memory order: a pass per seed chased its cells at random); the failures'
      // boxes and balls are kept. A seed none of whose cells failed is done: no later
      // insertion can touch its cells (no point outside is inside their balls).
      fails_.clear();
      std::fill(blocked_.begin(), blocked_.end(), 0);
      for (std::uint32_t c = 0; c < tri_.cell_slots(); ++c) {
        if (!tri_.is_live(c) || tri_.tag(c) == kCertified) continue;
        const auto& v = tri_.cell(c).v;
        bool mine = false;
        for (const std::uint32_t x : v) mine = mine || (x <= region_points && state_[x] == kPendingSeed);
        if (!mine) continue;
        if (tri_.tag(c) == kUnknown) {
          const Check check = certify(c);
          tri_.set_tag(c, check.ok ? kCertified : kFailed);
          if (check.ok) continue;
          fails_.push_back({c, check});
        }
        for (const std::uint32_t x : v) {
          if (x <= region_points) blocked_[x] = 1;
        }
      }
      std::size_t still = 0;
      for (const std::uint32_t x : pending_) {
        if (blocked_[x] != 0) {
          pending_[still++] = x;
        } else {
          state_[x] = kDoneSeed;
        }
      }
      pending_.resize(still);
      if (pending_.empty()) return Outcome::kDone;
      // Over held points, seeds blocked only by cells whose balls reach past what the
      // process holds (kRemote): deferred (defer_pending).
      if (run_.held != nullptr && fails_.empty()) return Outcome::kDone;
      if (round == kMaxRounds || run_.whole_wanted.load()) return Outcome::kWhole;
      // Each failing ball and hull facet is asked of the tree (a query tests the few
      // points around a small ball). When the queries of a round test more than
      // kQueryWork times the region's points (a scan: most balls of the region's edge
      // reach the next scan line, each query skimming it), E grows instead: its margin
      // doubles.
      for (const auto& f : fails_) tri_.set_tag(f.first, kAskTree);
      found_.clear();
      query_work_ = 0;
      bool over = false;
      empty_work_ = empty_queries_ = 0;
      for (const auto& f : fails_) {
        if (over || query_work_ > kQueryWork * region_points) {
          over = true;
          tri_.set_tag(f.first, kUnknown);  // looked at again next round
          continue;
        }
        const std::size_t before = found_.size();
        query(f.first, f.second, found_);
        // Nothing inside: certified (over held points, if the process lacks nothing there).
        std::uint32_t tag = found_.size() == before ? kCertified : kUnknown;
        if (tag == kCertified && run_.held != nullptr && !held_by_process(f.first, f.second)) tag = kRemote;
        tri_.set_tag(f.first, tag);
      }
      std::sort(found_.begin(), found_.end());
      found_.erase(std::unique(found_.begin(), found_.end()), found_.end());
      std::vector<std::uint32_t> merged;
      std::merge(extras_.begin(), extras_.end(), found_.begin(), found_.end(), std::back_inserter(merged));
      extras_.swap(merged);
      if (auto in = insert_points(found_); !in.is_ok() || !in.value()) {
        if (!in.is_ok()) return in.status();
        return Outcome::kOverBudget;
      }
      if (!over) continue;
      // Empty balls whose queries skimmed thousands of points each (huge balls nearly
      // following a long smooth curve or surface): a wider E would not hold them
      // either. Many cheap ones (scan lines): E grows.
      if (empty_queries_ != 0 && empty_work_ > kQueryWorkPerBall * empty_queries_) {
        run_.whole_wanted.store(true);
        return Outcome::kWhole;
      }
      const Box<D> g = margin_box(e_, grown);
      grown *= 2;
      const double lacking_in_g = run_.held != nullptr ? run_.held->lacking_in(g.data()) : 0;
      if (!collect_box(g, found_, std::max(kGrowAtLeast, kGrowFactor * region_points)) ||
          4 * (static_cast<double>(tri_.vertex_count() + found_.size()) + lacking_in_g) >
              3 * static_cast<double>(run_.whole_points)) {
        run_.whole_wanted.store(true);
        return Outcome::kWhole;
      }
      // Over held points, a wider E the process does not hold is fetched first.
      if (run_.held != nullptr && !run_.held->box_held(g.data())) {
        fetch_box_ = g;
        return Outcome::kFetch;
      }
      e_ = g;
      e_covers_all_ = contains<D>(e_, run_.bounds);
      if (auto in = insert_points(found_); !in.is_ok() || !in.value()) {
        if (!in.is_ok()) return in.status();
        return Outcome::kOverBudget;
      }
      ++stats_.margin_rounds;
    }
  }

  // Every wanted seed's rows in sweep order, from one pass over the region's
  // triangulation: each finite cell goes to its owner (its smallest point id) when the
  // owner is a wanted seed of the region, then each seed's rows are sorted.
  void emit_owned(std::uint32_t first, std::vector<std::uint32_t>& rows) {
    constexpr std::size_t w = D + 1;
    // The wanted index of each region position (kNotWanted otherwise).
    constexpr std::uint32_t kNotWanted = 0xFFFFFFFFu;
    index_of_.assign(last_ - first_, kNotWanted);
    for (std::uint32_t k = 0; k < wanted_.size(); ++k) index_of_[wanted_[k] - first] = k;
    // Pass 1: each cell's owner among the wanted seeds (its tag, now free: 1 + the
    // wanted index, or 0), and how many rows each owner has.
    bucket_.assign(wanted_.size() + 1, 0);
    for (std::uint32_t c = 0; c < tri_.cell_slots(); ++c) {
      if (!tri_.is_live(c)) continue;
      const std::uint32_t owner = owner_of(tri_, c);
      std::uint32_t tag = 0;
      if (owner != kNoOwner) {
        const std::uint32_t r = run_.split.position_of(owner);
        if (r >= first && r < last_ && index_of_[r - first] != kNotWanted) tag = index_of_[r - first] + 1;
      }
      tri_.set_tag(c, tag);
      if (tag != 0) ++bucket_[tag];
    }
    for (std::size_t k = 0; k < wanted_.size(); ++k) bucket_[k + 1] += bucket_[k];
    // Pass 2: the rows straight into place, owner by owner; then each owner's rows
    // sorted: lexicographic by their sorted vertex lists (compare the last two sorted).
    const std::size_t at = rows.size();
    rows.resize(at + bucket_[wanted_.size()] * w);
    Row* out = reinterpret_cast<Row*>(rows.data() + at);
    for (std::uint32_t c = 0; c < tri_.cell_slots(); ++c) {
      if (!tri_.is_live(c) || tri_.tag(c) == 0) continue;
      out[bucket_[tri_.tag(c) - 1]++] = row_of<D>(tri_, c);
    }
    std::size_t begin = 0;
    for (std::size_t k = 0; k < wanted_.size(); ++k) {
      const std::size_t end = bucket_[k];
      sort_rows<D>(out + begin, out + end);
      begin = end;
    }
  }

  using Row = std::array<std::uint32_t, D + 1>;
  static_assert(sizeof(Row) == (D + 1) * sizeof(std::uint32_t));

  // Seed `id`'s rows from the whole set's triangulation and its owner index.
  void emit_whole_owned(const Whole<D>& whole, std::uint32_t id, std::vector<std::uint32_t>& rows) {
    const Triangulation<D>& t = *whole.tri;
    const std::uint32_t begin = whole.owned_start[id], end = whole.owned_start[id + 1];
    const std::size_t at = rows.size();
    rows.resize(at + static_cast<std::size_t>(end - begin) * (D + 1));
    Row* out = reinterpret_cast<Row*>(rows.data() + at);
    for (std::uint32_t k = begin; k < end; ++k) out[k - begin] = row_of<D>(t, whole.owned[k]);
    sort_rows<D>(out, out + (end - begin));
  }

  // The seed's rows (owned simplices, canonical) appended to `rows`, from its cells in
  // `t`; with an accept callback, its whole star is offered first.
  void emit(const Triangulation<D>& t, std::span<const std::uint32_t> cells, std::uint32_t seed,
            std::vector<std::uint32_t>& rows) {
    const bool accept = static_cast<bool>(run_.options.accept);
    const StarPart part = !accept                                      ? StarPart::kOwned
                          : run_.options.accept_part == StarPart::kAll ? StarPart::kAll
                                                                       : StarPart::kWhole;
    star_of<D>(t, cells, seed, part, star_, star_scratch_);
    if (accept && !run_.options.accept(star_)) return;
    const auto owned = owned_simplices(star_);
    rows.insert(rows.end(), owned.begin(), owned.end());
  }

  // Few seeds of the region wanted: their stars walked, as the star walk's sweep does.
  // Walks the wanted seeds' stars in order, rows to `out`; stops once more than
  // `seconds` have passed (read after each star: on a sphere's surface one star can
  // cost more than triangulating the region). Returns how many were walked.
  Result<std::size_t> walk(RegionRows& out, double seconds = HUGE_VAL) {
    if (!walker_) walker_.emplace(run_.walk_tree(), run_.options.star);
    const auto start = std::chrono::steady_clock::now();
    // A walk is stopped once it alone has cost what the region's triangulation would.
    const bool bounded = seconds != HUGE_VAL;
    walker_->set_deadline(bounded ? start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                std::chrono::duration<double>(seconds))
                                  : std::chrono::steady_clock::time_point::max());
    for (std::size_t k = 0; k < wanted_.size(); ++k) {
      if (k > 0 && std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() > seconds) {
        return k;
      }
      const std::uint32_t s = run_.split.point_at(wanted_[k]);
      ++stats_.walked_seeds;
      // (Over held points the whole star is certified first.)
      const StarPart part = run_.options.accept    ? run_.options.accept_part
                            : run_.held != nullptr ? StarPart::kWhole
                                                   : StarPart::kOwned;
      const auto began = std::chrono::steady_clock::now();
      if (Status st = walker_->compute(s, star_, part); !st.is_ok()) {
        if (bounded && st.code() == Code::kDeadlineExceeded) {
          run_.walks_stopped.store(true, std::memory_order_relaxed);
          return k;  // this seed and the rest: the region's triangulation
        }
        return st;
      }
      run_.walks.fetch_add(1, std::memory_order_relaxed);
      run_.walk_nanos.fetch_add(
          static_cast<std::uint64_t>(
              std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - began).count()),
          std::memory_order_relaxed);
      if (!run_.certified_walk(star_)) continue;
      if (run_.options.accept && !run_.options.accept(star_)) continue;
      const auto owned = owned_simplices(star_);
      out.simplices.insert(out.simplices.end(), owned.begin(), owned.end());
    }
    return wanted_.size();
  }

  Run<D, Index>& run_;
  MeshStats& total_;
  Triangulation<D> tri_;
  TriangulationStats stats_;
  std::optional<StarWalker> walker_;
  Star star_;
  // The region being triangulated: positions [first_, last_), box E (every point in it
  // inserted), and the points outside E that queries inserted (sorted).
  std::uint32_t first_ = 0, last_ = 0;
  Box<D> e_{};
  bool e_covers_all_ = false;
  Box<D> fetch_box_{};  // Outcome::kFetch's box
  std::vector<std::uint32_t> extras_;
  std::size_t query_work_ = 0;                           // points the queries of a round tested
  std::size_t empty_work_ = 0, empty_queries_ = 0;       // of those, the queries that found nothing
  std::vector<std::pair<double, std::uint32_t>> taken_;  // a query's deepest conflicting points (a max-heap)
  std::size_t reserved_ = 0;  // memory granted to this worker's triangulation (MeshOptions::reserve_bytes)
  // Scratch, kept between regions.
  std::vector<std::uint32_t> wanted_, ids_, order_, local_, scratch_, found_, cells_, seen_, others_;
  // Per local id of a region point: a seed still to certify, done, or not a seed of the
  // run; whether a cell around it failed this round. The seeds still pending.
  std::vector<std::uint8_t> state_, blocked_;
  std::vector<std::uint32_t> pending_;
  // emit_owned's scratch.
  std::vector<std::uint32_t> index_of_, bucket_;
  std::vector<std::pair<std::uint32_t, Check>> fails_;
  StarScratch<D> star_scratch_;  // emit's
};

template <int D, class Index>
Result<MeshStats> sweep(const Index& index, const KdTree* tree, const PointSet& points, const SpaceSplit& split,
                        const MeshOptions& options, const SimplexSink& sink) {
  const std::uint64_t n = points.size();
  Run<D, Index> run(index, tree, points, split, options);
  run.seed_begin = static_cast<std::uint32_t>(std::min<std::uint64_t>(options.seed_begin, n));
  run.seed_end = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(options.seed_end, run.seed_begin, n));
  const auto sweep_begin = static_cast<std::uint32_t>(std::min<std::uint64_t>(options.sweep_begin, n));
  const auto sweep_end = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(options.sweep_end, sweep_begin, n));
  MeshStats total;
  if (n == 0 || run.seed_begin >= run.seed_end || sweep_begin >= sweep_end) return total;
  for (int k = 0; k < D; ++k) {
    run.bounds[static_cast<std::size_t>(k)] = HUGE_VAL;
    run.bounds[static_cast<std::size_t>(D + k)] = -HUGE_VAL;
  }
  // Over held points the whole set's box: E and the balls are cut to it, and hull
  // facets are certified against its slabs.
  if (run.held != nullptr) std::copy(run.held->whole_box().begin(), run.held->whole_box().end(), run.bounds.begin());
  for (std::uint32_t b = 0; b < split.block_count() && run.held == nullptr; ++b) {
    const auto box = split.box(b);
    for (int k = 0; k < D; ++k) {
      run.bounds[static_cast<std::size_t>(k)] =
          std::min(run.bounds[static_cast<std::size_t>(k)], box[static_cast<std::size_t>(k)]);
      run.bounds[static_cast<std::size_t>(D + k)] =
          std::max(run.bounds[static_cast<std::size_t>(D + k)], box[static_cast<std::size_t>(D + k)]);
    }
  }
  // Regions: the split's nodes of at most the policy's size (compact boxes), cut to the
  // sweep range.
  const std::uint32_t region_points =
      options.region_points != 0 ? options.region_points : policy(D).triangulation_region_points;
  for (const auto& [first, last] : split.nodes_of_at_most(region_points)) {
    const std::uint32_t b = std::max(first, sweep_begin), e = std::min(last, sweep_end);
    if (b < e) run.regions.emplace_back(b, e);
  }
  const unsigned threads = std::max(1u, options.threads);
  std::uint64_t seeds_done = 0;
  const Status status = run_in_order<RegionRows>(
      run.regions.size(), threads, threads, [&] { return std::make_unique<RegionMesher<D, Index>>(run, total); },
      [&](RegionRows& rows) -> Status {
        seeds_done += rows.seeds;
        total.simplices += rows.simplices.size() / (D + 1);
        return sink(rows.simplices, seeds_done);
      });
  if (!status.is_ok()) return status;
  total.seeds = seeds_done;
  total.deferred = run.deferred.load();
  if (run.whole) {
    total.triangulation.peak_bytes += run.whole->bytes();
    total.triangulation.inserted += run.whole_inserted;
  }
  return total;
}

// What a triangulation sweep answers outside 2-d and 3-d.
Status not_2d_3d() { return invalid_argument("local triangulations mesh 2-d and 3-d sets only"); }

}  // namespace

bool triangulation_sweep_applies(const PointSet& points, const MeshOptions& options) {
  const int d = points.dimension();
  return (d == 2 || d == 3) && options.star.weights.empty() && options.star.cover == nullptr;
}

bool ties_dominate(const PointSet& points, const SpaceSplit& split) {
  // The first kTieProbePoints of the sweep (a compact node), triangulated alone: the
  // predicates the filters could not decide, per point. Grids tie on nearly every
  // in-sphere test (17 exact evaluations a point on a 3-d integer grid), which the star
  // walk's memoised integer minors decide faster; uniform points, scans and surfaces
  // stay far below 1.
  const auto count = static_cast<std::uint32_t>(std::min<std::uint64_t>(split.swept(), kTieProbePoints));
  if (count < 64) return false;
  const Predicates pred(points);
  return dispatch_2d_3d(points.dimension(), false, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    Triangulation<D> t(points, pred);
    std::vector<std::uint32_t> ids(count), scratch;
    for (std::uint32_t r = 0; r < count; ++r) ids[r] = split.point_at(r);
    insertion_order<D>(ids, scratch);
    for (std::uint32_t k = 0; k < count; ++k) t.insert_next(ids, k);
    return static_cast<double>(t.stats().exact_calls) > kTiesPerPoint * count;
  });
}

Result<MeshStats> triangulation_sweep(const KdTree& tree, const SpaceSplit& split, const MeshOptions& options,
                                      const SimplexSink& sink) {
  return dispatch_2d_3d(tree.points().dimension(), Result<MeshStats>(not_2d_3d()), [&](auto dim) {
    return sweep<decltype(dim)::value>(tree, &tree, tree.points(), split, options, sink);
  });
}

Result<MeshStats> triangulation_sweep(const PointSet& points, const SpaceSplit& split, const MeshOptions& options,
                                      const SimplexSink& sink) {
  const SplitIndex index(points, split);
  return dispatch_2d_3d(points.dimension(), Result<MeshStats>(not_2d_3d()), [&](auto dim) {
    return sweep<decltype(dim)::value>(index, nullptr, points, split, options, sink);
  });
}

}  // namespace spokemesh::detail
