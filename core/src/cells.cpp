#include "spokemesh/cells.hpp"

#include <algorithm>
#include <memory>
#include <optional>
#include <thread>
#include <vector>

namespace spokemesh {

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
    std::unique_ptr<StarWalker> walker;
    Star star;
    std::vector<VoronoiCell> cells;
    Status status;
  };
  // The run's stars share their wraps through a RunCache, as whole meshes do
  // (mesh.hpp): each star is the same with or without it.
  std::optional<RunCache> cache;
  StarOptions star_options = options.star;
  if (options.facet_cache_bytes != 0) {
    cache.emplace(points.dimension(), static_cast<std::uint32_t>(n), static_cast<std::uint32_t>(begin),
                  static_cast<std::uint32_t>(end), options.facet_cache_bytes, static_cast<std::uint32_t>(block));
    if (cache->enabled()) star_options.cache = &*cache;
  }
  std::vector<Worker> workers(threads);
  for (Worker& w : workers) w.walker = std::make_unique<StarWalker>(tree, star_options);
  auto run = [&](Worker& w, std::uint64_t from, std::uint64_t to) {
    w.cells.clear();
    w.status = Status::ok();
    for (std::uint64_t s = from; s < to; ++s) {
      if (Status st = w.walker->compute(static_cast<std::uint32_t>(s), w.star); !st.is_ok()) {
        w.status = std::move(st);
        return;
      }
      if (domain == nullptr) {
        w.cells.push_back(voronoi_cell(points, w.star));
      } else {
        auto cell = voronoi_cell(points, w.star, *domain);
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
