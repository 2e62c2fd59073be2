#include "search/split_index.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace spokemesh::detail {

SplitIndex::SplitIndex(const PointSet& points, const SpaceSplit& split)
    : points_(points), split_(split), d_(points.dimension()) {
  nodes_.reserve(split.size() / 4 + 16);
  bounds_.reserve((split.size() / 4 + 16) * 2 * static_cast<std::size_t>(d_));
  std::uint32_t begin = 0;
  for (const std::uint32_t end : split.piece_ends()) {
    if (end > begin) build(begin, end);
    begin = end;
  }
  if (split.size() > begin) build(begin, split.size());  // a distributed run's held points
}

void SplitIndex::build(std::uint32_t begin, std::uint32_t end) {
  const auto d = static_cast<std::size_t>(d_);
  const std::size_t at = nodes_.size();
  nodes_.push_back({begin, end, 0});
  bounds_.resize(bounds_.size() + 2 * d);
  float* box = &bounds_[at * 2 * d];
  if (end - begin <= kLeafPoints) {
    // Rounded outwards: nextafter past the nearest float, so every point lies inside.
    for (std::size_t c = 0; c < d; ++c) {
      double lo = std::numeric_limits<double>::infinity(), hi = -lo;
      for (std::uint32_t r = begin; r < end; ++r) {
        const double v = points_.point(split_.point_at(r))[c];
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
      box[c] = std::nextafter(static_cast<float>(lo), -std::numeric_limits<float>::infinity());
      box[d + c] = std::nextafter(static_cast<float>(hi), std::numeric_limits<float>::infinity());
    }
  } else {
    const std::uint32_t mid = begin + (end - begin) / 2;
    const std::size_t left = nodes_.size();
    build(begin, mid);
    const std::size_t right = nodes_.size();
    build(mid, end);
    box = &bounds_[at * 2 * d];  // the children's growth moved it
    for (std::size_t c = 0; c < d; ++c) {
      box[c] = std::min(bounds_[left * 2 * d + c], bounds_[right * 2 * d + c]);
      box[d + c] = std::max(bounds_[left * 2 * d + d + c], bounds_[right * 2 * d + d + c]);
    }
  }
  nodes_[at].skip = static_cast<std::uint32_t>(nodes_.size());
}

}  // namespace spokemesh::detail
