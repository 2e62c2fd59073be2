#include "spokemesh/periodic_cells.hpp"

#include <algorithm>
#include <cmath>

#include "mesh/periodic_runs.hpp"
#include "spokemesh/circumcentre.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

using periodic_runs::MarginPlan;
using periodic_runs::power_sphere_of;
using periodic_runs::with_growing_margins;

namespace {

// One seed's star on a cover, mapped to points and offsets (canonical form), with its
// cell and centres when asked; every sphere recorded in `plan`.
Status star_on_cover(const PeriodicCover& cover, MarginPlan& plan, std::uint32_t seed, const StarOptions& options,
                     VoronoiCell* cell, bool centres, PeriodicStar& out) {
  const int d = cover.points().dimension();
  StarOptions run = options;
  run.cover = &cover;
  run.weights = cover.weights();
  StarWalker walker(cover.tree(), run);
  Star star;
  if (Status s = walker.compute(seed, star); !s.is_ok()) return s;
  if (!star.bounded_cell()) plan.unbounded();
  for (std::size_t i = 0; i < star.size(); ++i) power_sphere_of(cover, star.simplex(i), d, plan);
  out = PeriodicStar{};
  out.seed = seed;
  out.hidden = star.hidden;
  for (const std::uint32_t id : star.simplices) {
    out.simplices.push_back(cover.point_of(id));
    const std::int32_t* k = cover.offset_of(id);
    out.offsets.insert(out.offsets.end(), k, k + d);
  }
  canonicalize_periodic_rows(d, out.simplices, out.offsets, true);
  if (centres) {
    // From the images' coordinates relative to the seed (each rounded once), so every
    // copy of a vertex has the same centre up to its translate.
    const auto du = static_cast<std::size_t>(d);
    const double* x = cover.points().point(seed);
    const double* w = cover.weights().empty() ? nullptr : cover.weights().data();
    std::vector<double> local((du + 1) * du);
    std::vector<double> local_w(du + 1);
    std::vector<std::uint32_t> ids(du + 1);
    for (std::size_t r = 0; r < out.size(d); ++r) {
      for (std::size_t v = 0; v <= du; ++v) {
        const std::uint32_t p = out.simplices[r * (du + 1) + v];
        const std::int32_t* k = out.offsets.data() + (r * (du + 1) + v) * du;
        for (std::size_t c = 0; c < du; ++c) {
          local[v * du + c] =
              image_difference(cover.points().point(p)[c], k[c], cover.box().lo()[c], cover.box().hi()[c], x[c]);
        }
        local_w[v] = w != nullptr ? w[p] : 0;
        ids[v] = static_cast<std::uint32_t>(v);
      }
      const PointSet simplex(d, std::vector<double>(local));
      std::vector<double> c = circumcentre(simplex, ids.data(), d + 1, w != nullptr ? local_w.data() : nullptr);
      for (std::size_t k = 0; k < du; ++k) out.centres.push_back(c[k] + x[k]);
    }
  }
  if (cell != nullptr) {
    *cell = voronoi_cell(cover.points(), star, cover.weights());
    cell->vertex_simplices.clear();  // the cover's ids: the star's rows say it with offsets
    cell->facet_offsets.clear();
    for (VoronoiFacet& f : cell->facets) {
      const auto id = static_cast<std::uint32_t>(f.neighbor);
      const std::int32_t* k = cover.offset_of(id);
      cell->facet_offsets.insert(cell->facet_offsets.end(), k, k + d);
      f.neighbor = cover.point_of(id);
    }
  }
  return Status::ok();
}

}  // namespace

Result<PeriodicStar> periodic_star(const PointSet& points, const PeriodicBox& box, std::uint32_t seed,
                                   const StarOptions& options, const std::string& source, VoronoiCell* cell) {
  if (seed >= points.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(points.size()) + " points)");
  }
  PeriodicStar out;
  auto runs = with_growing_margins(points, box, options.weights, source, nullptr,
                                   [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
                                     return star_on_cover(cover, plan, seed, options, cell, false, out);
                                   });
  if (!runs.is_ok()) return runs.status();
  return out;
}

void periodic_neighbors(const PeriodicStar& star, int d, std::vector<std::uint32_t>& points,
                        std::vector<std::int32_t>& offsets) {
  const auto du = static_cast<std::size_t>(d);
  std::vector<std::vector<std::int64_t>> images;
  for (std::size_t v = 0; v < star.simplices.size(); ++v) {
    std::vector<std::int64_t> image{star.simplices[v]};
    bool self = star.simplices[v] == star.seed;
    for (std::size_t c = 0; c < du; ++c) {
      image.push_back(star.offsets[v * du + c]);
      self = self && star.offsets[v * du + c] == 0;
    }
    if (!self) images.push_back(std::move(image));
  }
  std::sort(images.begin(), images.end());
  images.erase(std::unique(images.begin(), images.end()), images.end());
  points.clear();
  offsets.clear();
  for (const auto& image : images) {
    points.push_back(static_cast<std::uint32_t>(image[0]));
    for (std::size_t c = 0; c < du; ++c) offsets.push_back(static_cast<std::int32_t>(image[c + 1]));
  }
}

Result<std::unique_ptr<PeriodicStars>> PeriodicStars::build(const PointSet& points, const PeriodicBox& box,
                                                            std::span<const double> weights, std::string source) {
  auto stars = std::unique_ptr<PeriodicStars>(new PeriodicStars(points, box, weights, std::move(source)));
  const MarginPlan plan(points, box);
  auto cover = PeriodicCover::build(points, box, plan.margin(), stars->source_, weights);
  if (!cover.is_ok()) return cover.status();
  stars->cover_ = std::move(cover).value();
  return stars;
}

std::uint64_t PeriodicStars::estimated_bytes(std::uint64_t n, int d) {
  // The first margin is 3.5 spacings on each side of n^(1/d) spacings per axis (at
  // most 3 box lengths): (1 + 7 / n^(1/d))^d times the points, each as a tree holds
  // it (coordinates twice, boxes, ranks: about 20 d + 40 bytes) plus an image's
  // point and offset (4 + 4 d).
  const double per_axis = std::pow(static_cast<double>(std::max<std::uint64_t>(n, 1)), 1.0 / d);
  const double factor = std::pow(std::min(7.0, 1 + 7 / per_axis), d);
  return static_cast<std::uint64_t>(factor * static_cast<double>(n) * (24.0 * d + 44));
}

Result<PeriodicStar> PeriodicStars::star(std::uint32_t seed, const StarOptions& options, VoronoiCell* cell,
                                         bool centres) const {
  if (seed >= points_.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(points_.size()) + " points)");
  }
  // Always from the kept (first) cover: a seed's answer does not depend on which seeds
  // were asked before, on this server or another.
  std::shared_ptr<const PeriodicCover> cover = cover_;
  PeriodicStar out;
  auto runs = with_growing_margins(
      points_, box_, weights_, source_, nullptr,
      [&](const PeriodicCover& c, MarginPlan& plan) -> Status {
        return star_on_cover(c, plan, seed, options, cell, centres, out);
      },
      &cover);
  if (!runs.is_ok()) return runs.status();
  return out;
}

}  // namespace spokemesh
