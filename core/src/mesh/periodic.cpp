#include "spokemesh/periodic.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>

#include "spokemesh/voronoi.hpp"

namespace spokemesh {

namespace {

constexpr double kUnit = 0x1p-53;
// The first margin, in mean spacings (V / n)^(1/d). The circumspheres of well-spread
// points reach about twice the spacing; a margin that proves too thin is measured and
// the run repeated (mesh_periodic).
constexpr double kFirstMarginSpacings = 3.5;
// A margin beyond this many box lengths means too few points for the torus.
constexpr double kMostMarginBoxes = 3;

}  // namespace

const std::int32_t* PeriodicCover::offset_of(std::uint32_t id) const {
  if (id < n_) return zeros_.data();
  return image_offset_.data() + static_cast<std::size_t>(id - n_) * static_cast<std::size_t>(base_.dimension());
}

Result<std::unique_ptr<PeriodicCover>> PeriodicCover::build(const PointSet& points, const PeriodicBox& box,
                                                            std::span<const double> margin, const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  std::unique_ptr<PeriodicCover> cover(new PeriodicCover(points, box));
  cover->n_ = static_cast<std::uint32_t>(points.size());
  cover->margin_.assign(margin.begin(), margin.end());
  cover->zeros_.assign(du, 0);
  const auto& lo = box.lo();
  const auto& hi = box.hi();
  // Per axis, the offsets an image may have: |k| <= ceil(margin / side).
  std::vector<int> reach(du);
  double magnitude = 0;
  for (std::size_t c = 0; c < du; ++c) {
    const double side = hi[c] - lo[c];
    reach[c] = static_cast<int>(std::min(64.0, std::ceil(margin[c] / side)));
    magnitude = std::max({magnitude, std::fabs(lo[c] - margin[c]), std::fabs(hi[c] + margin[c])});
  }
  // An image's stored coordinate is its exact one rounded once: within u |coordinate|.
  // Twice that, plus the rounding of the tree's widened boxes, is the pad.
  cover->pad_ = 4 * kUnit * magnitude;

  std::vector<double> coords(points.coordinates().begin(), points.coordinates().end());
  std::vector<std::int32_t> k(du);
  std::vector<double> at(du);
  for (std::uint32_t i = 0; i < cover->n_; ++i) {
    const double* p = points.point(i);
    // Odometer over k in [-reach, reach]^d, skipping k = 0 and coordinates outside the region.
    for (std::size_t c = 0; c < du; ++c) k[c] = -reach[c];
    for (;;) {
      bool inside = false;
      bool zero = true;
      for (std::size_t c = 0; c < du; ++c) zero = zero && k[c] == 0;
      if (!zero) {
        inside = true;
        for (std::size_t c = 0; c < du && inside; ++c) {
          at[c] = image_difference(p[c], k[c], lo[c], hi[c], 0.0);
          inside = at[c] >= lo[c] - margin[c] && at[c] <= hi[c] + margin[c];
        }
      }
      if (inside) {
        coords.insert(coords.end(), at.begin(), at.end());
        cover->image_point_.push_back(i);
        cover->image_offset_.insert(cover->image_offset_.end(), k.begin(), k.end());
      }
      std::size_t c = 0;
      while (c < du && k[c] == reach[c]) {
        k[c] = -reach[c];
        ++c;
      }
      if (c == du) break;
      ++k[c];
    }
  }
  if (coords.size() / du > std::numeric_limits<std::uint32_t>::max() - 1) {
    return invalid_argument(source + ": the periodic images of " + std::to_string(points.size()) +
                            " points are too many for 32-bit indices");
  }
  cover->cover_ = PointSet(d, std::move(coords));
  if (Status s = cover->cover_.validate(source); !s.is_ok()) {
    // The points are valid, so two images (or an image and a point) fell on the same
    // double: points closer than the box's coordinates can resolve.
    return invalid_argument(source + ": the periodic images of the points cannot be told apart in double precision "
                            "(points closer together than the rounding of the box's coordinates, about " +
                            std::to_string(cover->pad_) + "): " + s.message());
  }
  cover->tree_ = std::make_unique<KdTree>(cover->cover_, cover->n_, cover->pad_);
  return cover;
}

namespace {

// Whether a simplex of the cover (ids, owner first at offset 0) is the representative
// its owner writes: no vertex stands for a smaller point, and the owner's other images
// in it have offsets lexicographically above zero.
bool is_representative(const PeriodicCover& cover, const std::uint32_t* s, int d) {
  const std::uint32_t owner = s[0];
  for (int v = 1; v <= d; ++v) {
    const std::uint32_t p = cover.point_of(s[v]);
    if (p < owner) return false;
    if (p == owner) {
      const std::int32_t* k = cover.offset_of(s[v]);
      for (int c = 0; c < d; ++c) {
        if (k[c] != 0) {
          if (k[c] < 0) return false;
          break;
        }
      }
    }
  }
  return true;
}

// Raises `slot` to at least v (atomically; rarely contended: only a larger need writes).
void raise_to(std::atomic<double>& slot, double v) {
  double seen = slot.load(std::memory_order_relaxed);
  while (v > seen && !slot.compare_exchange_weak(seen, v, std::memory_order_relaxed)) {
  }
}

}  // namespace

Result<PeriodicMeshStats> mesh_periodic(const PointSet& points, const PeriodicBox& box, const MeshOptions& options,
                                        const PeriodicSink& sink, const std::function<Status()>& restart,
                                        const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  if (!options.star.weights.empty()) {
    return invalid_argument("weighted points on a periodic box are not supported yet");
  }
  double volume = 1;
  for (std::size_t c = 0; c < du; ++c) volume *= box.hi()[c] - box.lo()[c];
  const double spacing = std::pow(volume / static_cast<double>(points.size()), 1.0 / d);
  std::vector<double> margin(du);
  for (std::size_t c = 0; c < du; ++c) {
    margin[c] = std::min(kFirstMarginSpacings * spacing, kMostMarginBoxes * (box.hi()[c] - box.lo()[c]));
  }
  PeriodicMeshStats stats;
  for (;;) {
    ++stats.runs;
    auto cover_or = PeriodicCover::build(points, box, margin, source);
    if (!cover_or.is_ok()) return cover_or.status();
    const PeriodicCover& cover = *cover_or.value();
    // What the run's spheres needed: per axis, how far the farthest reached past the box.
    std::vector<std::atomic<double>> needed(du);
    for (auto& v : needed) v.store(0);
    std::atomic<bool> unbounded{false};
    MeshOptions run = options;
    run.seed_begin = 0;
    run.seed_end = cover.point_count();
    run.sweep_begin = 0;
    run.sweep_end = 0xFFFFFFFFu;
    run.split = nullptr;
    run.star.cover = &cover;
    const auto& lo = box.lo();
    const auto& hi = box.hi();
    run.accept = [&](const Star& star) {
      if (!star.bounded_cell()) {
        unbounded.store(true, std::memory_order_relaxed);
        return true;
      }
      const auto owned = owned_simplices(star);
      for (std::size_t at = 0; at < owned.size(); at += du + 1) {
        const std::uint32_t* s = owned.data() + at;
        if (!is_representative(cover, s, d)) continue;
        // Its circumsphere, from the cover's coordinates (within pad of the images'):
        // within 1e-12 of the radius plus an ulp (circumcentre()), widened for both.
        const std::vector<double> centre = circumcentre(cover.points(), s, d + 1);
        const double* x = cover.points().point(s[0]);
        double r2 = 0, size = 0;
        for (std::size_t c = 0; c < du; ++c) {
          r2 += (centre[c] - x[c]) * (centre[c] - x[c]);
          size = std::max(size, std::fabs(centre[c]));
        }
        const double r = std::sqrt(r2) * (1 + 1e-9) + 4 * cover.pad() + 8 * kUnit * size;
        for (std::size_t c = 0; c < du; ++c) {
          const double reach = std::max(lo[c] - (centre[c] - r), (centre[c] + r) - hi[c]);
          if (reach > 0) raise_to(needed[c], (reach + 2 * cover.pad()) * (1 + 1e-9));
        }
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
      written += kept.size() / (du + 1);
      return sink(kept, offsets, done);
    });
    if (!result.is_ok()) return result.status();
    // A sphere measured in a cover too thin may be far larger than the torus's (its
    // far side is missing): a need beyond twice the margin only doubles it.
    bool thin = unbounded.load(), can_grow = false;
    std::vector<double> next(margin);
    for (std::size_t c = 0; c < du; ++c) {
      const double need = needed[c].load();
      const double most = kMostMarginBoxes * (box.hi()[c] - box.lo()[c]);
      // Strictly inside the region the cover holds every image of.
      if (need >= margin[c] || unbounded.load()) {
        thin = true;
        next[c] = std::min(most, need <= 2 * margin[c] ? std::max(need * 1.25 + 0.5 * spacing, margin[c])
                                                      : 2 * margin[c]);
        can_grow = can_grow || next[c] > margin[c];
      }
    }
    if (!thin) {
      stats.mesh = result.value();
      stats.mesh.simplices = written;  // the torus's (the run's rows less the translates)
      stats.images = cover.image_count();
      stats.margin = margin;
      return stats;
    }
    if (!can_grow) {
      return invalid_argument(source + ": too few points for a periodic Delaunay triangulation of this box: the "
                              "circumspheres reach more than " + std::to_string(static_cast<int>(kMostMarginBoxes)) +
                              " box lengths beyond it (add points)");
    }
    margin = next;
    if (restart) {
      if (Status s = restart(); !s.is_ok()) return s;
    }
  }
}

}  // namespace spokemesh
