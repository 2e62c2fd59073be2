#include "spokemesh/periodic_cells.hpp"

#include <algorithm>
#include <optional>

#include "mesh/periodic_runs.hpp"
#include "spokemesh/domain.hpp"

namespace spokemesh {

using periodic_runs::MarginPlan;
using periodic_runs::with_growing_margins;

Result<PeriodicCellsStats> compute_periodic_cells(const PointSet& points, const PeriodicBox& box,
                                                  const CellsOptions& options, const CellSink& sink,
                                                  const std::function<Status()>& restart, const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  PeriodicCellsStats stats;
  std::vector<VoronoiCell> mapped;
  auto runs = with_growing_margins(
      points, box, options.star.weights, source, restart, [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
        CellsOptions run = options;
        run.star.weights = cover.weights();
        run.seed_begin = 0;
        run.seed_end = cover.point_count();
        run.measures_only = false;  // the vertices certify the cells (then are dropped if asked)
        // Rounds of 2048 cells a thread: their vertices are held until certified (larger
        // rounds hold more for no speed: bench/README.md, "Tuning history").
        if (run.block_size == 0) run.block_size = 2048;
        run.star.cover = &cover;
        stats.images = cover.image_count();
        stats.margin = cover.margin();
        // In 3-d, cells are built directly (cells.hpp): the cover's region, a box, clipped by
        // the bisectors of points and images. A cell that keeps a facet on the region's
        // walls reaches past the margin: the run is then thin, as for an unbounded cell.
        std::optional<Domain> region;
        if (d == 3) {
          std::vector<double> lo(du), hi(du);
          for (std::size_t c = 0; c < du; ++c) {
            lo[c] = box.lo()[c] - cover.margin()[c];
            hi[c] = box.hi()[c] + cover.margin()[c];
          }
          auto made = Domain::box(lo, hi);
          if (made.is_ok()) region = std::move(made).value();
        }
        return compute_cells(cover.tree(), region ? &*region : nullptr, run,
                             [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
                               // Copied into records kept across rounds (their buffers reused), and without the
                               // vertices when the caller wants measures only: the vertices certify the cell first.
                               mapped.resize(cells.size());
                               for (std::size_t i = 0; i < cells.size(); ++i) {
                                 const VoronoiCell& from = cells[i];
                                 VoronoiCell& cell = mapped[i];
                                 const bool on_wall = std::any_of(from.facets.begin(), from.facets.end(),
                                                                  [](const VoronoiFacet& f) { return f.is_wall(); });
                                 if (!from.bounded || on_wall) {
                                   plan.unbounded();
                                   continue;
                                 }
                                 // Every vertex is the centre of a (power) sphere through the seed.
                                 const double* x = cover.points().point(from.seed);
                                 const double w = cover.weights().empty() ? 0 : cover.weights()[from.seed];
                                 for (std::size_t v = 0; v < from.vertex_count(); ++v) {
                                   const double* c = from.vertices.data() + v * du;
                                   double r2 = 0;
                                   for (std::size_t k = 0; k < du; ++k) r2 += (c[k] - x[k]) * (c[k] - x[k]);
                                   plan.power_sphere(c, r2 - w, cover.max_weight(), cover.pad());
                                 }
                                 if (options.measures_only) {
                                   cell.seed = from.seed;
                                   cell.dimension = from.dimension;
                                   cell.vertices.clear();
                                   cell.vertex_simplices.clear();
                                   cell.bounded = from.bounded;
                                   cell.volume = from.volume;
                                   cell.centroid = from.centroid;
                                   cell.hidden = from.hidden;
                                   cell.facets.resize(from.facets.size());
                                   for (std::size_t f = 0; f < from.facets.size(); ++f) {
                                     cell.facets[f].neighbor = from.facets[f].neighbor;
                                     cell.facets[f].vertices.clear();
                                     cell.facets[f].area = from.facets[f].area;
                                     cell.facets[f].normal = from.facets[f].normal;
                                   }
                                 } else {
                                   cell = from;
                                 }
                                 cell.clipped = false;  // the region's walls cut nothing
                                 cell.facet_offsets.clear();
                                 for (VoronoiFacet& f : cell.facets) {
                                   const auto id = static_cast<std::uint32_t>(f.neighbor);
                                   const std::int32_t* k = cover.offset_of(id);
                                   cell.facet_offsets.insert(cell.facet_offsets.end(), k, k + d);
                                   f.neighbor = cover.point_of(id);
                                 }
                               }
                               return sink(mapped, done);
                             });
      });
  if (!runs.is_ok()) return runs.status();
  stats.runs = runs.value();
  return stats;
}

}  // namespace spokemesh
