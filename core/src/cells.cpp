#include "spokemesh/cells.hpp"

#include "box_cell_3d.hpp"
#include "cell_polytope.hpp"

#include <algorithm>
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
  std::vector<std::uint32_t> applied;
  std::vector<const double*> coords;
};

namespace {
// A cell whose security ball holds more points than this goes to the star instead (a
// seed far from a dense cluster, say): it bounds the direct route's work.
constexpr std::size_t kMaxDirectCandidates = 16384;
}  // namespace

ClippedCellBuilder::ClippedCellBuilder(const KdTree& tree, const Domain& domain, StarOptions star_options,
                                       CellRoute route)
    : tree_(tree), domain_(domain), star_options_(star_options), scratch_(std::make_unique<Scratch>()) {
  const int d = tree.points().dimension();
  // The one dispatch point. Measured (bench/README.md, single thread): in 3-d the
  // direct route is faster than the star's and needs no facet cache (1M points: 36 s
  // and 150 MB against 38 s and 396 MB on 2 threads); in 2-d the star's ring walk is
  // 2.5x faster; in 4-d they tie; from 6-d on the box's 2^d corners and the clipped
  // polytope's vertex count make the direct route far slower.
  const bool wanted = route == CellRoute::kDirect || (route == CellRoute::kAuto && d == 3);
  direct_ok_ = wanted && domain.is_box() && domain.dimension() == d;
  if (direct_ok_) {
    const std::vector<double> lo = domain.lower(), hi = domain.upper();
    for (int c = 0; c < d; ++c) direct_ok_ = direct_ok_ && lo[c] < hi[c];
  }
}

ClippedCellBuilder::~ClippedCellBuilder() = default;

StarWalker& ClippedCellBuilder::walker() {
  if (!walker_) walker_ = std::make_unique<StarWalker>(tree_, star_options_);
  return *walker_;
}

Result<VoronoiCell> ClippedCellBuilder::cell(std::uint32_t seed) {
  const PointSet& points = tree_.points();
  if (star_options_.cancel != nullptr && star_options_.cancel->load(std::memory_order_relaxed)) {
    return cancelled("cell computation cancelled");
  }
  if (direct_ok_ && seed < points.size() && domain_.violated_wall(points.point(seed)) < 0) {
    VoronoiCell out;
    if (direct(seed, out)) return out;
  }
  ++star_fallbacks_;
  if (Status st = walker().compute(seed, star_); !st.is_ok()) return st;
  return voronoi_cell(points, star_, domain_);
}

bool ClippedCellBuilder::direct(std::uint32_t seed, VoronoiCell& out) {
  const PointSet& points = tree_.points();
  Scratch& sc = *scratch_;
  if (points.dimension() == 3) {
    // The specialised 3-d cell first; it gives up (rarely, off grids) where its error
    // bounds cannot certify a decision, and the generic polytope decides exactly.
    if (!sc.box_cell_3d) sc.box_cell_3d.emplace(points, domain_);
    detail::BoxCell3d& cell = *sc.box_cell_3d;
    cell.reset(seed);
    if (clip_by_neighbours(seed, cell)) {
      cell.assemble(out, measures_only_);
      return true;
    }
    ++generic_fallbacks_;
  }
  if (!sc.polytope) {
    sc.polytope.emplace(points, seed, domain_);
  } else {
    sc.polytope->reset_to_box(seed);
  }
  detail::CellPolytope& poly = *sc.polytope;
  if (!clip_by_neighbours(seed, poly)) return false;
  poly.refine_voronoi_vertices();
  out = detail::assemble_clipped(poly, seed, points.dimension());
  return true;
}

template <class Polytope>
bool ClippedCellBuilder::clip_by_neighbours(std::uint32_t seed, Polytope& poly) {
  const PointSet& points = tree_.points();
  const int d = points.dimension();
  const std::uint32_t n = static_cast<std::uint32_t>(points.size());
  Scratch& sc = *scratch_;
  const double* x = points.point(seed);
  sc.applied.clear();
  // Whether every point not yet applied lies farther than twice the security radius,
  // given that none closer than dist2 (nanoflann's, kDistanceMargin) is left.
  auto beyond = [&](double dist2, double r2) { return dist2 * (1 - kDistanceMargin) > 4 * r2; };
  // Nearest points first, k at a time, each clip shrinking the security radius (the
  // cell's farthest vertex from the seed, bounded above) until the next point lies
  // beyond twice it. A later round lists only points within twice the radius it
  // starts with (which only shrinks) and repeats the earlier ones, skipped as applied.
  std::size_t k = std::min<std::size_t>(n, d <= 2 ? 16 : d == 3 ? 40 : 32u << (d - 3));
  double r2 = poly.radius2_upper();
  for (int round = 0;; ++round) {
    sc.ids.resize(k);
    sc.dist2.resize(k);
    sc.coords.resize(k);
    const double bound2 = round == 0 ? std::numeric_limits<double>::infinity() : 4 * r2 * (1 + 4 * kDistanceMargin);
    const std::size_t count = tree_.knn(x, k, sc.ids.data(), sc.dist2.data(), sc.coords.data(), bound2);
    if (round == 0 && count > 1) poly.set_scale(std::sqrt(sc.dist2[1]) / 2);
    bool closed = false;
    for (std::size_t i = 0; i < count; ++i) {
      const std::uint32_t j = sc.ids[i];
      if (j == seed) continue;
      if (beyond(sc.dist2[i], r2)) {
        closed = true;
        break;
      }
      if (round > 0 && std::find(sc.applied.begin(), sc.applied.end(), j) != sc.applied.end()) continue;
      if (!poly.clip(j, sc.coords[i])) return false;  // a vertex on (or too near) the bisector
      sc.applied.push_back(j);
      if (poly.changed()) r2 = poly.radius2_upper();
    }
    if (closed || count < k || k >= n) break;
    if (k >= kMaxDirectCandidates) return false;
    k = std::min<std::size_t>(2 * k, n);
  }
  return true;
}

Status compute_cells(const KdTree& tree, const Domain* domain, const CellsOptions& options, const CellSink& sink) {
  const PointSet& points = tree.points();
  const std::uint64_t n = points.size();
  const std::uint64_t begin = std::min<std::uint64_t>(options.seed_begin, n);
  const std::uint64_t end = std::clamp<std::uint64_t>(options.seed_end, begin, n);
  const unsigned threads = std::max(1u, options.threads);
  const std::uint64_t block = std::max<std::uint32_t>(1, options.block_size);
  if (domain != nullptr && domain->dimension() != points.dimension()) {
    return invalid_argument("domain: dimension " + std::to_string(domain->dimension()) + " does not match the points' " +
                            std::to_string(points.dimension()));
  }
  struct Worker {
    std::unique_ptr<StarWalker> walker;            // unclipped cells
    std::unique_ptr<ClippedCellBuilder> builder;  // clipped cells
    Star star;
    std::vector<VoronoiCell> cells;
    Status status;
  };
  // The run's stars share their wraps through a RunCache, as whole meshes do
  // (mesh.hpp): each star is the same with or without it. (Clipped cells in a box
  // mostly need no star; the cache's pages are only committed where stars touch them.)
  std::optional<RunCache> cache;
  StarOptions star_options = options.star;
  if (options.facet_cache_bytes != 0) {
    cache.emplace(points.dimension(), static_cast<std::uint32_t>(n), static_cast<std::uint32_t>(begin),
                  static_cast<std::uint32_t>(end), options.facet_cache_bytes, static_cast<std::uint32_t>(block));
    if (cache->enabled()) star_options.cache = &*cache;
  }
  std::vector<Worker> workers(threads);
  for (Worker& w : workers) {
    if (domain == nullptr) {
      w.walker = std::make_unique<StarWalker>(tree, star_options);
    } else {
      w.builder = std::make_unique<ClippedCellBuilder>(tree, *domain, star_options);
      w.builder->set_measures_only(options.measures_only);
    }
  }
  auto run = [&](Worker& w, std::uint64_t from, std::uint64_t to) {
    w.cells.clear();
    w.status = Status::ok();
    for (std::uint64_t s = from; s < to; ++s) {
      if (domain == nullptr) {
        if (Status st = w.walker->compute(static_cast<std::uint32_t>(s), w.star); !st.is_ok()) {
          w.status = std::move(st);
          return;
        }
        w.cells.push_back(voronoi_cell(points, w.star));
      } else {
        auto cell = w.builder->cell(static_cast<std::uint32_t>(s));
        if (!cell.is_ok()) {
          w.status = cell.status();
          return;
        }
        w.cells.push_back(std::move(cell).value());
      }
      if (options.measures_only) {
        VoronoiCell& c = w.cells.back();
        c.vertices = {};
        c.vertex_simplices = {};
        for (VoronoiFacet& f : c.facets) f.vertices = {};
      }
    }
  };
  for (std::uint64_t at = begin; at < end;) {
    std::vector<std::pair<std::uint64_t, std::uint64_t>> ranges;
    for (unsigned t = 0; t < threads && at < end; ++t) {
      ranges.emplace_back(at, std::min(end, at + block));
      at = ranges.back().second;
    }
    std::vector<std::thread> pool;
    for (std::size_t t = 1; t < ranges.size(); ++t) {
      pool.emplace_back(run, std::ref(workers[t]), ranges[t].first, ranges[t].second);
    }
    run(workers[0], ranges[0].first, ranges[0].second);
    for (std::thread& th : pool) th.join();
    for (std::size_t t = 0; t < ranges.size(); ++t) {
      if (!workers[t].status.is_ok()) return workers[t].status;
      if (Status s = sink(workers[t].cells, ranges[t].second - begin); !s.is_ok()) return s;
    }
  }
  return Status::ok();
}

}  // namespace spokemesh
