#include "spokemesh/periodic.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>

#include "mesh/periodic_runs.hpp"

namespace spokemesh {

using periodic_runs::is_representative;
using periodic_runs::MarginPlan;
using periodic_runs::power_sphere_of;
using periodic_runs::with_growing_margins;

Result<PeriodicMeshStats> mesh_periodic(const PointSet& points, const PeriodicBox& box, const MeshOptions& options,
                                        const PeriodicSink& sink, const std::function<Status()>& restart,
                                        const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  PeriodicMeshStats stats;
  auto runs = with_growing_margins(
      points, box, options.star.weights, source, restart, [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
        MeshOptions run = options;
        run.star.weights = cover.weights();
        // The points' seed range (the images are never seeds); the sweep is the cover's.
        run.seed_begin = std::min(options.seed_begin, cover.point_count());
        run.seed_end = std::min(options.seed_end, cover.point_count());
        run.sweep_begin = 0;
        run.sweep_end = 0xFFFFFFFFu;
        run.split = nullptr;
        run.star.cover = &cover;
        run.accept = [&](const Star& star) {
          if (!star.bounded_cell()) {
            plan.unbounded();
            return true;
          }
          const auto owned = owned_simplices(star);
          for (std::size_t at = 0; at < owned.size(); at += du + 1) {
            const std::uint32_t* s = owned.data() + at;
            if (is_representative(cover, s, d)) power_sphere_of(cover, s, d, plan);
          }
          return true;
        };
        std::vector<std::uint32_t> kept;
        std::vector<std::int32_t> offsets;
        std::uint64_t written = 0;
        auto result = mesh_seeds(cover.tree(), run, [&](std::span<const std::uint32_t> rows, std::uint64_t done) {
          kept.clear();
          offsets.clear();
          for (std::size_t at = 0; at < rows.size(); at += du + 1) {
            const std::uint32_t* s = rows.data() + at;
            if (!is_representative(cover, s, d)) continue;
            for (std::size_t v = 0; v <= du; ++v) {
              kept.push_back(cover.point_of(s[v]));
              const std::int32_t* k = cover.offset_of(s[v]);
              offsets.insert(offsets.end(), k, k + d);
            }
          }
          canonicalize_periodic_rows(d, kept, offsets, false);
          written += kept.size() / (du + 1);
          return sink(kept, offsets, done);
        });
        if (!result.is_ok()) return result.status();
        stats.mesh = result.value();
        stats.mesh.simplices = written;  // the torus's (the run's rows less the translates)
        stats.images = cover.image_count();
        stats.margin = cover.margin();
        return Status::ok();
      });
  if (!runs.is_ok()) return runs.status();
  stats.runs = runs.value();
  return stats;
}

void canonicalize_periodic_rows(int d, std::vector<std::uint32_t>& simplices, std::vector<std::int32_t>& offsets,
                                bool sort_rows) {
  const auto du = static_cast<std::size_t>(d);
  const std::size_t width = du + 1, rows = simplices.size() / width;
  // Vertex a of a row before vertex b: by point, then offset lexicographically.
  auto before = [&](std::size_t a, std::size_t b) {
    if (simplices[a] != simplices[b]) return simplices[a] < simplices[b];
    return std::lexicographical_compare(offsets.begin() + static_cast<std::ptrdiff_t>(a * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>((a + 1) * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>(b * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>((b + 1) * du));
  };
  auto swap_vertices = [&](std::size_t a, std::size_t b) {
    std::swap(simplices[a], simplices[b]);
    std::swap_ranges(offsets.begin() + static_cast<std::ptrdiff_t>(a * du),
                     offsets.begin() + static_cast<std::ptrdiff_t>((a + 1) * du),
                     offsets.begin() + static_cast<std::ptrdiff_t>(b * du));
  };
  for (std::size_t r = 0; r < rows; ++r) {
    const std::size_t first = r * width;
    // Insertion sort (d + 1 <= 9 vertices), counting transpositions: the parity says
    // whether the sorted order has the row's orientation.
    bool odd = false;
    for (std::size_t i = 1; i < width; ++i) {
      for (std::size_t j = i; j > 0 && before(first + j, first + j - 1); --j) {
        swap_vertices(first + j, first + j - 1);
        odd = !odd;
      }
    }
    if (odd) swap_vertices(first + width - 2, first + width - 1);
  }
  if (!sort_rows || rows < 2) return;
  std::vector<std::size_t> order(rows);
  for (std::size_t r = 0; r < rows; ++r) order[r] = r;
  auto row_before = [&](std::size_t a, std::size_t b) {
    for (std::size_t v = 0; v < width; ++v) {
      if (before(a * width + v, b * width + v)) return true;
      if (before(b * width + v, a * width + v)) return false;
    }
    return false;
  };
  std::sort(order.begin(), order.end(), row_before);
  std::vector<std::uint32_t> s2;
  std::vector<std::int32_t> o2;
  s2.reserve(simplices.size());
  o2.reserve(offsets.size());
  for (const std::size_t r : order) {
    s2.insert(s2.end(), simplices.begin() + static_cast<std::ptrdiff_t>(r * width),
              simplices.begin() + static_cast<std::ptrdiff_t>((r + 1) * width));
    o2.insert(o2.end(), offsets.begin() + static_cast<std::ptrdiff_t>(r * width * du),
              offsets.begin() + static_cast<std::ptrdiff_t>((r + 1) * width * du));
  }
  simplices = std::move(s2);
  offsets = std::move(o2);
}

}  // namespace spokemesh
