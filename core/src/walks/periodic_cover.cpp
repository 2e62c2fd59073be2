#include "spokemesh/periodic_cover.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace spokemesh {

const std::int32_t* PeriodicCover::offset_of(std::uint32_t id) const {
  if (id < n_) return zeros_.data();
  return image_offset_.data() + static_cast<std::size_t>(id - n_) * static_cast<std::size_t>(base_.dimension());
}

Result<std::unique_ptr<PeriodicCover>> PeriodicCover::build(const PointSet& points, const PeriodicBox& box,
                                                            std::span<const double> margin, const std::string& source,
                                                            std::span<const double> weights) {
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
  cover->pad_ = 4 * filter::kUnitRoundoff * magnitude;

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
    return invalid_argument(source +
                            ": the periodic images of the points cannot be told apart in double precision "
                            "(points closer together than the rounding of the box's coordinates, about " +
                            std::to_string(cover->pad_) + "): " + s.message());
  }
  if (!weights.empty()) {
    cover->weights_.assign(weights.begin(), weights.end());
    for (const std::uint32_t p : cover->image_point_) cover->weights_.push_back(weights[p]);
    cover->max_weight_ = *std::max_element(weights.begin(), weights.end());
  }
  cover->tree_ = std::make_unique<KdTree>(cover->cover_, cover->n_, cover->pad_);
  return cover;
}

}  // namespace spokemesh
