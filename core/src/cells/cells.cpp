#include "spokemesh/cells.hpp"

#include "base/dimension.hpp"
#include "cells/box_cell_3d.hpp"
#include "cells/cell_polytope.hpp"
#include "mesh/ball_bounds.hpp"
#include "mesh/delaunay_sweep.hpp"
#include "spokemesh/space_split.hpp"

#include <algorithm>
#include <chrono>
#include <limits>
#include <memory>
#include <optional>
#include <thread>
#include <vector>

namespace spokemesh {

struct ClippedCellBuilder::Scratch {
  std::optional<detail::BoxCell3d> box_cell_3d;
  std::optional<detail::CellPolytope> polytope;
  std::vector<std::uint32_t> ids;
  std::vector<double> dist2;
  std::vector<const double*> coords;
};

namespace {
// A cell whose security ball holds more points than this goes to the star instead (a
// seed at the edge of a void, say): it bounds the direct route's work on clustered
// sets and costs uniform ones nothing (bench/README.md, "Tuning history").
constexpr std::size_t kMaxDirectCandidates = 256;
}  // namespace

bool ClippedCellBuilder::takes_direct_route(int dimension, const Domain& domain, CellRoute route) {
  // The one dispatch point; the dimension policy (base/dimension.hpp) says where the
  // direct route is the default. In 3-d it is faster than the star's and needs no
  // facet cache (bench/README.md, "Tuning history").
  const bool wanted =
      route == CellRoute::kDirect || (route == CellRoute::kAuto && detail::policy(dimension).direct_cells);
  if (!wanted || !domain.is_box() || domain.dimension() != dimension) return false;
  const std::vector<double> lo = domain.lower(), hi = domain.upper();
  for (int c = 0; c < dimension; ++c) {
    if (!(lo[c] < hi[c])) return false;
  }
  return true;
}

ClippedCellBuilder::ClippedCellBuilder(const KdTree& tree, const Domain& domain, StarOptions star_options,
                                       CellRoute route)
    : tree_(tree),
      domain_(domain),
      star_options_(star_options),
      // Power cells (weights) go directly only in 3-d (BoxCell3d clips by power
      // bisectors; the generic polytope by plain ones): elsewhere through their stars.
      // So do the cells of a periodic cover (images: BoxCell3d reads them exactly).
      direct_ok_(((star_options.weights.empty() && star_options.cover == nullptr) || tree.points().dimension() == 3) &&
                 takes_direct_route(tree.points().dimension(), domain, route)),
      scratch_(std::make_unique<Scratch>()) {}

ClippedCellBuilder::~ClippedCellBuilder() = default;

StarWalker& ClippedCellBuilder::walker() {
  if (!walker_) walker_ = std::make_unique<StarWalker>(tree_, star_options_);
  return *walker_;
}

Result<VoronoiCell> ClippedCellBuilder::cell(std::uint32_t seed) {
  VoronoiCell out;
  if (Status st = cell(seed, out); !st.is_ok()) return st;
  return out;
}

Status ClippedCellBuilder::cell(std::uint32_t seed, VoronoiCell& out) {
  const PointSet& points = tree_.points();
  if (star_options_.cancel != nullptr && star_options_.cancel->load(std::memory_order_relaxed)) {
    return cancelled("cell computation cancelled");
  }
  last_from_star_ = false;
  last_reach2_ = 0;
  bool have_star = false;
  if (seed < points.size()) {
    if (Status st = check_seed_in_domain(points, seed, domain_); !st.is_ok()) return st;
    if (direct_ok_) {
      have_star = stars_ != nullptr && skip_doomed_;
      if (!(have_star && direct_gives_up(seed)) && direct(seed, out)) return Status::ok();
    }
  }
  ++star_fallbacks_;
  last_from_star_ = true;
  if (!have_star) {
    const Status st = stars_ != nullptr ? stars_->star(seed, star_) : walker().compute(seed, star_);
    if (!st.is_ok()) return st;
  }
  auto cell = voronoi_cell(points, star_, domain_, star_options_.weights);
  if (!cell.is_ok()) return cell.status();
  out = std::move(cell).value();
  return Status::ok();
}

bool ClippedCellBuilder::builds_directly(std::uint32_t seed) {
  if (!direct_ok_ || seed >= tree_.points().size()) return false;
  if (!check_seed_in_domain(tree_.points(), seed, domain_).is_ok()) return false;
  VoronoiCell scratch;
  return direct(seed, scratch);
}

bool ClippedCellBuilder::direct_gives_up(std::uint32_t seed) {
  const PointSet& points = tree_.points();
  const int d = points.dimension();
  if (!stars_->star(seed, star_).is_ok() || (d != 2 && d != 3)) return false;
  // The rounds' list sizes: the last one's is what the route lists before it gives up.
  const std::size_t n = points.size();
  std::size_t k = std::min<std::size_t>(n, detail::policy(d).cell_candidates);
  while (k < kMaxDirectCandidates && k < n) k = std::min<std::size_t>(2 * k, n);
  if (k >= n) return false;
  // The farthest Voronoi vertex inside the box, by a lower bound on its distance: the
  // circumcentres' certified intervals (ball_bounds), each wholly inside the box.
  const std::vector<double> lo = domain_.lower(), hi = domain_.upper();
  const double* s = points.point(seed);
  double reach2 = 0;  // a lower bound on the cell's farthest vertex's squared distance
  detail::dispatch_2d_3d(d, 0, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    using namespace ball_bounds;
    for (std::size_t t = 0; t < star_.size(); ++t) {
      const std::uint32_t* simplex = star_.simplex(t);
      std::array<const double*, D> v{};
      for (int j = 0, at = 0; j <= D; ++j) {
        if (simplex[j] == seed) continue;
        v[static_cast<std::size_t>(at++)] = points.point(simplex[j]);
      }
      std::array<Interval, D> centre{};
      double radius2_up = 0;
      if (!circumball<D>(s, v, centre, radius2_up)) continue;  // nearly flat: not counted
      double gap2 = 0;
      bool inside = true;
      for (int c = 0; c < D && inside; ++c) {
        const auto k2 = static_cast<std::size_t>(c);
        inside = centre[k2].lo >= lo[k2] && centre[k2].hi <= hi[k2];
        const double g = std::max({0.0, down(centre[k2].lo - s[c]), down(s[c] - centre[k2].hi)});
        gap2 += g * g;
      }
      if (inside) reach2 = std::max(reach2, down(gap2));
    }
    return 0;
  });
  if (!(reach2 > 0)) return false;
  // Points within twice that (with room for the tree's rounding of distances): k of
  // them, the seed included, and no list of the route can reach past them.
  const double limit2 = 4 * reach2 * (1 - 1e-9);
  std::size_t within = 0;
  tree_.find_first(
      [&](const float* blo, const float* bhi) {
        double gap2 = 0;
        for (int c = 0; c < d; ++c) {
          const double g = std::max({0.0, static_cast<double>(blo[c]) - s[c], s[c] - static_cast<double>(bhi[c])});
          gap2 += g * g;
        }
        return gap2 <= limit2;
      },
      [&](std::uint32_t, const double* p) {
        double d2 = 0;
        for (int c = 0; c < d; ++c) d2 += (p[c] - s[c]) * (p[c] - s[c]);
        if (d2 <= limit2) ++within;
        return within >= k;
      });
  return within >= k;
}

bool ClippedCellBuilder::direct(std::uint32_t seed, VoronoiCell& out) {
  const PointSet& points = tree_.points();
  Scratch& sc = *scratch_;
  if (points.dimension() == 3) {
    // The specialised 3-d cell first; it gives up (rarely, off grids) where its error
    // bounds cannot certify a decision, and the generic polytope decides exactly.
    if (!star_options_.weights.empty()) {
      // A hidden seed's cell is empty: said by the start of its star walk (power_start,
      // usually one tree query), without clipping a box to nothing first. Its record
      // is the star route's (voronoi_cell of a hidden star), so every caller agrees.
      auto hidden = walker().hidden(seed);
      if (!hidden.is_ok()) return false;  // the star route reports the error
      if (hidden.value()) {
        star_.seed = seed;
        star_.dimension = points.dimension();
        star_.simplices.clear();
        star_.hull_facets = 0;
        star_.hidden = true;
        auto empty = voronoi_cell(points, star_, domain_, star_options_.weights);
        if (!empty.is_ok()) return false;
        out = std::move(empty).value();
        return true;
      }
    }
    if (!sc.box_cell_3d) sc.box_cell_3d.emplace(points, domain_, star_options_.weights, star_options_.cover);
    detail::BoxCell3d& cell = *sc.box_cell_3d;
    cell.reset(seed);
    const Clipped clipped = clip_by_neighbours(seed, cell);
    // An empty power cell: hidden, or only outside the domain; the star tells which.
    if (clipped == Clipped::kDone && cell.size() != 0) {
      cell.assemble(out, measures_only_);
      return true;
    }
    // (The generic polytope takes neither power bisectors nor images: the star's way.)
    if (clipped == Clipped::kTooMany || !star_options_.weights.empty() || star_options_.cover != nullptr) return false;
    ++generic_fallbacks_;
  }
  if (!sc.polytope) {
    sc.polytope.emplace(points, seed, domain_);
  } else {
    sc.polytope->reset_to_box(seed);
  }
  detail::CellPolytope& poly = *sc.polytope;
  if (clip_by_neighbours(seed, poly) != Clipped::kDone) return false;
  poly.refine_voronoi_vertices();
  out = detail::assemble_clipped(poly, seed, points.dimension());
  return true;
}

template <class Polytope>
ClippedCellBuilder::Clipped ClippedCellBuilder::clip_by_neighbours(std::uint32_t seed, Polytope& poly) {
  const PointSet& points = tree_.points();
  const int d = points.dimension();
  const std::uint32_t n = static_cast<std::uint32_t>(points.size());
  Scratch& sc = *scratch_;
  const double* x = points.point(seed);
  std::size_t applied = 0;  // points clipped by so far: a prefix of every round's list
  // Whether every point not yet applied lies farther than twice the security radius,
  // given that none closer than dist2 (nanoflann's, kDistanceMargin) is left. With
  // weights, a point p cuts a vertex at distance r from the seed only if |p - s| - r <
  // sqrt(r^2 + w_p - w_s): the reach is r + sqrt(r^2 + W), W bounding w_p - w_s.
  double weight_reach = 0;
  if constexpr (requires { poly.weight_reach(); }) weight_reach = poly.weight_reach();
  auto reach2 = [&](double r2) {
    if (weight_reach == 0) return 4 * r2;
    const double r = std::sqrt(r2), far = r + std::sqrt(r2 + weight_reach);
    return far * far * (1 + 1e-12);
  };
  // A periodic cover's images are stored within pad of their positions per axis: their
  // listed distances are within sqrt(d) pad of the true ones.
  const double pad =
      star_options_.cover != nullptr ? star_options_.cover->pad() * std::sqrt(static_cast<double>(d)) : 0.0;
  auto beyond = [&](double dist2, double r2) {
    if (pad == 0) return dist2 * (1 - kDistanceMargin) > reach2(r2);
    const double lower = std::sqrt(dist2 * (1 - kDistanceMargin)) - pad;
    return lower > 0 && lower * lower > reach2(r2);
  };
  auto listed2 = [&](double r2) {  // the listed distance within which every point that may cut lies
    if (pad == 0) return reach2(r2) * (1 + 4 * kDistanceMargin);
    const double far = std::sqrt(reach2(r2)) + pad;
    return far * far * (1 + 4 * kDistanceMargin);
  };
  // Nearest points first, k at a time, each clip shrinking the security radius (the
  // cell's farthest vertex from the seed, bounded above) until the next point lies
  // beyond twice it. A later round lists only points within twice the radius it
  // starts with (which only shrinks) and repeats the earlier ones, skipped as applied.
  std::size_t k = std::min<std::size_t>(n, detail::policy(d).cell_candidates);
  double r2 = poly.radius2_upper();
  for (int round = 0;; ++round) {
    sc.ids.resize(k);
    sc.dist2.resize(k);
    sc.coords.resize(k);
    const double bound2 = round == 0 ? std::numeric_limits<double>::infinity() : listed2(r2);
    const std::size_t count = tree_.knn(x, k, sc.ids.data(), sc.dist2.data(), sc.coords.data(), bound2);
    // Points at equal distances come in the tree's order, which depends on the rest of
    // the set: put each such run in index order, and when the list is full leave the
    // run at its end (some of its points may be missing) to the next round. The
    // points applied, and their order, are then a function of the set within reach.
    for (std::size_t i = 0; i + 1 < count;) {
      std::size_t j = i + 1;
      while (j < count && sc.dist2[j] == sc.dist2[i]) ++j;
      for (std::size_t t = i + 1; t < j; ++t) {  // insertion sort: runs are short
        for (std::size_t u = t; u > i && sc.ids[u - 1] > sc.ids[u]; --u) {
          std::swap(sc.ids[u - 1], sc.ids[u]);
          std::swap(sc.coords[u - 1], sc.coords[u]);
        }
      }
      i = j;
    }
    if (round == 0 && count > 1) poly.set_scale(std::sqrt(sc.dist2[1]) / 2);
    // A full list may lack points at its last distance: that run is only looked at to
    // see whether it lies beyond (then so does everything unlisted), and is otherwise
    // applied in the next round, in its place.
    const bool full = count == k && k < n;
    std::size_t usable = count;
    if (full) {
      while (usable > 0 && sc.dist2[usable - 1] == sc.dist2[count - 1]) --usable;
    }
    bool closed = false;
    // The points applied so far are the first of this list after the seed: the order
    // is the same total one every round, and earlier rounds applied a prefix of it (a
    // point since fallen beyond the bound is not listed, nor is anything after it).
    std::size_t i = round == 0 ? 0 : std::min(count, applied + 1);
    for (; i < count; ++i) {
      const std::uint32_t j = sc.ids[i];
      if (j == seed) continue;
      if (beyond(sc.dist2[i], r2)) {
        closed = true;
        break;
      }
      if (i >= usable) break;
      if (!poly.clip(j, sc.coords[i])) {  // a vertex on (or too near) the bisector
        last_reach2_ = std::max(last_reach2_, sc.dist2[i]);
        return Clipped::kUndecided;
      }
      ++applied;
      if (poly.changed()) r2 = poly.radius2_upper();
      // An empty power cell stays empty: the caller asks the star (hidden, or the cell
      // lies outside the domain).
      if constexpr (requires { poly.weight_reach(); }) {
        if (poly.changed() && poly.size() == 0) return Clipped::kDone;
      }
    }
    // What this round rested on: the points up to the distance where it stopped; a
    // list cut short by the bound, everything within it; one that listed the whole
    // set, there being no other point.
    last_reach2_ = std::max(last_reach2_, count == 0       ? bound2
                                          : closed || full ? sc.dist2[std::min(i, count - 1)]
                                          : count < k      ? bound2
                                                           : std::numeric_limits<double>::infinity());
    if (closed || !full) break;
    if (k >= kMaxDirectCandidates) return Clipped::kTooMany;
    k = std::min<std::size_t>(2 * k, n);
  }
  return Clipped::kDone;
}

Status shape_cell(const KdTree& tree, const ShapeDomain& shape, const Domain& box, std::uint32_t seed, VoronoiCell& out,
                  StarOptions star, StarSource* stars, bool skip_doomed) {
  ClippedCellBuilder builder(tree, box, std::move(star));
  builder.set_stars(stars, skip_doomed);
  if (Status s = builder.cell(seed, out); !s.is_ok()) return s;
  ShapeClipper clipper(tree.points(), shape);
  clipper.set_geometry(true);
  clipper.clip(seed, out);
  return Status::ok();
}

namespace {

// How many seeds of a sample the direct route is tried on. The seeds it gives up on are
// walked, timed: the triangulation of every point serves the run's stars when walking
// the share of the run's seeds the route would give up on would take longer than
// triangulating every point (about kTriangulationSeconds[d] a point, one thread).
// Where the route gives up on most seeds (kDoomedShare: surfaces), each seed's star is
// read first and the seeds the route would certainly give up on go straight to it.
constexpr std::uint32_t kRouteProbeSeeds = 64;
constexpr double kTriangulationSeconds[4] = {0, 0, 1e-6, 4e-6};
constexpr double kDoomedShare = 0.5;

}  // namespace

CellStarPlan plan_cell_stars(const KdTree& tree, const Domain* domain, const CellsOptions& options,
                             std::span<const std::uint32_t> sample, std::uint64_t seeds) {
  const PointSet& points = tree.points();
  const int d = points.dimension();
  CellStarPlan plan;
  if (options.stars == MeshEngine::kStars || (d != 2 && d != 3) || !options.star.weights.empty() ||
      options.star.cover != nullptr || seeds == 0) {
    return plan;
  }
  const bool direct = domain != nullptr && ClippedCellBuilder::takes_direct_route(d, *domain, CellRoute::kAuto);
  double gave_up_share = 1;
  if (direct) {
    // Where cells are built directly, only the seeds the route gives up on need stars:
    // the sample says how many, and what a walk of one costs.
    ClippedCellBuilder probe(tree, *domain, options.star);
    StarWalker walker(tree, options.star);
    Star star;
    std::uint32_t gave_up = 0;
    double walk_seconds = 0;
    for (const std::uint32_t seed : sample) {
      if (probe.builds_directly(seed)) continue;
      ++gave_up;
      const auto t0 = std::chrono::steady_clock::now();
      if (!walker.compute(seed, star).is_ok()) break;  // (the run reports it)
      walk_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    }
    gave_up_share = sample.empty() ? 0 : static_cast<double>(gave_up) / static_cast<double>(sample.size());
    const double walks = gave_up == 0 ? 0
                                      : gave_up_share * static_cast<double>(seeds) * walk_seconds / gave_up /
                                            std::max(1u, options.threads);
    if (options.stars == MeshEngine::kAuto && walks < kTriangulationSeconds[d] * static_cast<double>(points.size())) {
      return plan;
    }
  }
  plan.triangulate = true;
  plan.skip_doomed = direct && gave_up_share >= kDoomedShare;
  return plan;
}

namespace {

// Where the stars of compute_cells come from (CellsOptions::stars): a plan on a sample
// of the seeds, evenly spread, then the triangulation (kept, or built here).
struct CellStars {
  std::shared_ptr<const WholeTriangulation> whole;  // null: star walks
  bool skip_doomed = false;
};

Result<CellStars> stars_from_triangulation(const KdTree& tree, const Domain* domain, const CellsOptions& options,
                                           std::uint64_t begin, std::uint64_t end) {
  const PointSet& points = tree.points();
  const int d = points.dimension();
  std::vector<std::uint32_t> sample;
  const std::uint64_t count = end > begin ? end - begin : 0,
                      step = std::max<std::uint64_t>(1, count / kRouteProbeSeeds);
  for (std::uint64_t seed = begin; seed < end && sample.size() < kRouteProbeSeeds; seed += step) {
    sample.push_back(static_cast<std::uint32_t>(seed));
  }
  const CellStarPlan plan = plan_cell_stars(tree, domain, options, sample, count);
  CellStars out;
  if (!plan.triangulate) return out;
  out.skip_doomed = plan.skip_doomed;
  if (options.whole && &options.whole->point_set() == &points) {
    out.whole = options.whole;
    return out;
  }
  const SpaceSplit split(points, SpaceSplit::default_block_points(d, points.size()));
  if (options.stars == MeshEngine::kAuto && detail::ties_dominate(points, split)) return CellStars{};
  WholeOptions whole;
  whole.split = &split;
  whole.cancel = options.star.cancel;
  whole.reserve_bytes = options.reserve_bytes;
  whole.owner_index = false;
  auto built = triangulate_whole(points, whole);
  if (!built.is_ok()) {
    if (built.status().code() == Code::kCancelled) return built.status();
    return CellStars{};  // refused (or a flat set): walks, the same cells
  }
  if (options.keep_whole) options.keep_whole(built.value());
  out.whole = std::move(built).value();
  return out;
}

}  // namespace

Status compute_cells(const KdTree& tree, const Domain* domain, const CellsOptions& options, const CellSink& sink) {
  const PointSet& points = tree.points();
  const std::uint64_t n = points.size();
  const std::uint64_t begin = std::min<std::uint64_t>(options.seed_begin, n);
  const std::uint64_t end = std::clamp<std::uint64_t>(options.seed_end, begin, n);
  const unsigned threads = std::max(1u, options.threads);
  if (options.shape != nullptr && (domain == nullptr || !options.star.weights.empty())) {
    return invalid_argument("a domain of any shape needs its box and unweighted points");
  }
  if (domain != nullptr && domain->dimension() != points.dimension()) {
    return invalid_argument("domain: dimension " + std::to_string(domain->dimension()) +
                            " does not match the points' " + std::to_string(points.dimension()));
  }
  struct Worker {
    std::unique_ptr<WholeStarReader> stars;       // stars from the triangulation of every point, if any
    std::unique_ptr<StarWalker> walker;           // unclipped cells (without it)
    std::unique_ptr<ClippedCellBuilder> builder;  // clipped cells
    std::unique_ptr<ShapeClipper> shape;          // cells in a domain of any shape
    Star star;
    Status status;             // the error of the lowest failing seed in its slice
    std::uint64_t failed = 0;  // that seed
  };
  // Seeds go in rounds of `block` per thread. Where cells are built directly, a
  // round's seeds are visited in the tree's leaf order, each thread a contiguous slice
  // of it, so that consecutive cells search the same part of the tree and read the
  // same coordinates (bench/README.md: 12% of a 3-d million's time in file order);
  // either way the round's cells are handed over in seed order. Seeds that go to the
  // star after all (grids: ties everywhere) run faster in seed order and smaller rounds,
  // as star runs do (bench/README.md, "Tuning history"), so the first
  // round_size seeds go that way, and space order follows only if most of them were
  // built directly (and stops when a round was not). Only speed depends on it.
  // Power cells (weights) go directly only in 3-d (see ClippedCellBuilder).
  const bool direct = domain != nullptr && (options.star.weights.empty() || points.dimension() == 3) &&
                      ClippedCellBuilder::takes_direct_route(points.dimension(), *domain, CellRoute::kAuto);
  const bool weighted_direct = direct && !options.star.weights.empty();
  // (A caller's block_size fixes the rounds: space order from the start, if direct.)
  const std::uint64_t small_rounds = (options.block_size != 0 ? options.block_size : 2048) * threads;
  const std::uint64_t round_size = options.block_size != 0 ? small_rounds : direct ? 8192 * threads : small_rounds;
  bool space_order = direct && options.block_size != 0;
  bool probing = direct && !space_order;  // until the first round_size seeds are done
  std::uint64_t round_now = small_rounds;
  std::uint64_t stars_before = 0, seeds_before = 0;
  // The run's stars share their wraps through a RunCache, as whole meshes do
  // (mesh.hpp): each star is the same with or without it. (Clipped cells in a box
  // mostly need no star; the cache's pages are only committed where stars touch them.)
  // Power cells built directly go to stars only for ties and cells the domain cuts
  // away, scattered over the run: the cache then holds pages all over and saves
  // nothing but its memory (bench/README.md, "Tuning history").
  auto stars = stars_from_triangulation(tree, domain, options, begin, end);
  if (!stars.is_ok()) return stars.status();
  const std::shared_ptr<const WholeTriangulation> whole = stars->whole;
  std::optional<RunCache> cache;
  StarOptions star_options = options.star;
  if (options.facet_cache_bytes != 0 && !weighted_direct && !whole) {
    cache.emplace(points.dimension(), static_cast<std::uint32_t>(n), static_cast<std::uint32_t>(begin),
                  static_cast<std::uint32_t>(end), options.facet_cache_bytes, static_cast<std::uint32_t>(round_size));
    star_options.facets = cache->facets();
    star_options.edges = cache->edges();
  }
  std::vector<Worker> workers(threads);
  for (Worker& w : workers) {
    if (whole) w.stars = std::make_unique<WholeStarReader>(*whole);
    if (domain == nullptr) {
      if (!whole) w.walker = std::make_unique<StarWalker>(tree, star_options);
    } else {
      w.builder = std::make_unique<ClippedCellBuilder>(tree, *domain, star_options);
      w.builder->set_stars(w.stars.get(), stars->skip_doomed);
      w.builder->set_measures_only(options.measures_only && options.shape == nullptr);
      if (options.shape != nullptr) {
        w.shape = std::make_unique<ShapeClipper>(points, *options.shape);
        w.shape->set_geometry(!options.measures_only);
      }
    }
  }
  auto stops = [](const Status& st) { return st.code() == Code::kCancelled || st.code() == Code::kDeadlineExceeded; };
  std::vector<VoronoiCell> cells;    // the round's, by seed; reused (their buffers too)
  std::vector<std::uint32_t> order;  // the round's seeds in leaf order
  auto run = [&](Worker& w, std::uint64_t at, std::size_t from, std::size_t to) {
    w.status = Status::ok();
    for (std::size_t i = from; i < to; ++i) {
      const std::uint32_t s = order[i];
      VoronoiCell& c = cells[s - at];
      Status st = Status::ok();
      if (domain == nullptr) {
        st = w.stars ? w.stars->star(s, w.star) : w.walker->compute(s, w.star);
        if (st.is_ok()) c = voronoi_cell(points, w.star, options.star.weights);
      } else {
        st = w.builder->cell(s, c);
        if (st.is_ok() && w.shape) w.shape->clip(s, c);
      }
      if (!st.is_ok()) {
        // Cancelled: stop. Otherwise keep going, so that the error reported is the
        // lowest failing seed's whatever the threads.
        if (w.status.is_ok() || s < w.failed) {
          w.status = std::move(st);
          w.failed = s;
        }
        if (stops(w.status)) return;
        continue;
      }
      if (options.measures_only) keep_measures_only(c);
    }
  };
  for (std::uint64_t at = begin; at < end;) {
    const std::uint64_t to = std::min(end, at + round_now);
    const std::size_t count = to - at;
    order.resize(count);
    for (std::size_t i = 0; i < count; ++i) order[i] = static_cast<std::uint32_t>(at + i);
    if (space_order) {
      std::sort(order.begin(), order.end(),
                [&](std::uint32_t a, std::uint32_t b) { return tree.leaf_rank(a) < tree.leaf_rank(b); });
    }
    cells.resize(count);
    const unsigned used = static_cast<unsigned>(std::min<std::uint64_t>(threads, count));
    std::vector<std::thread> pool;
    for (unsigned t = 1; t < used; ++t) {
      pool.emplace_back(run, std::ref(workers[t]), at, count * t / used, count * (t + 1) / used);
    }
    run(workers[0], at, 0, count / used);
    for (std::thread& th : pool) th.join();
    if (probing || space_order) {
      std::uint64_t to_star = 0;
      for (const Worker& w : workers) to_star += w.builder->star_fallbacks();
      const std::uint64_t seeds = to - begin;
      if (probing && seeds % round_size == 0) {  // rounds of round_size tile the RunCache's blocks from here
        probing = false;
        space_order = 2 * (to_star - stars_before) <= seeds - seeds_before;
        round_now = space_order ? round_size : small_rounds;
      } else if (space_order && 2 * (to_star - stars_before) > seeds - seeds_before) {
        space_order = false;
        round_now = small_rounds;
      }
      if (!probing) {
        stars_before = to_star;
        seeds_before = seeds;
      }
    }
    const Worker* first_error = nullptr;
    for (unsigned t = 0; t < used; ++t) {
      const Worker& w = workers[t];
      if (w.status.is_ok()) continue;
      if (stops(w.status)) return w.status;
      if (first_error == nullptr || w.failed < first_error->failed) first_error = &w;
    }
    if (first_error != nullptr) return first_error->status;
    if (Status s = sink(std::span<const VoronoiCell>(cells.data(), count), to - begin); !s.is_ok()) return s;
    at = to;
  }
  return Status::ok();
}

}  // namespace spokemesh
