// PeriodicCover: a point set on a flat torus (periodic_box.hpp) as the walker meshes
// it: the points followed by their images that lie within a margin outside the box,
// stored as points of their own with ids from n on, with a k-d tree over all of them.
// The predicates decide an image id as its exact image (ImageMap); how meshes, stars
// and cells use the cover is told in periodic.hpp.
//
// Ownership: borrows the points and the box, which must outlive the cover.
// Thread safety: immutable after build(); any number of walkers may read it at once.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/periodic_box.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

class PeriodicCover {
 public:
  // The cover of `points` (validated, inside `box`, same dimension; both borrowed and
  // must outlive the cover) with the images whose coordinates lie within margin[c] of
  // the box on every axis c (absolute lengths, d of them). INVALID_ARGUMENT, naming
  // `source`, when the images cannot be told apart in double precision (points closer
  // than the rounding of the box's coordinates).
  // weights: the points' power weights (n of them) or empty; the images carry their
  // points' weights (weights()).
  static Result<std::unique_ptr<PeriodicCover>> build(const PointSet& points, const PeriodicBox& box,
                                                      std::span<const double> margin, const std::string& source,
                                                      std::span<const double> weights = {});

  const PointSet& points() const { return cover_; }  // the points, then the images
  const KdTree& tree() const { return *tree_; }
  const PeriodicBox& box() const { return box_; }
  std::uint32_t point_count() const { return n_; }  // ids below are points, the rest images
  std::size_t image_count() const { return image_point_.size(); }
  ImageMap images() const { return {n_, image_point_.data(), image_offset_.data()}; }
  // The point an id stands for, and its offset (d integers; zeros for a point).
  std::uint32_t point_of(std::uint32_t id) const { return id < n_ ? id : image_point_[id - n_]; }
  const std::int32_t* offset_of(std::uint32_t id) const;
  const std::vector<double>& margin() const { return margin_; }
  // How far an image's stored coordinates may lie from its exact position (per axis).
  double pad() const { return pad_; }
  // One power weight per cover point (the points', then each image's point's), or empty.
  std::span<const double> weights() const { return weights_; }
  // The largest weight (0 when unweighted).
  double max_weight() const { return max_weight_; }

 private:
  PeriodicCover(const PointSet& points, const PeriodicBox& box) : base_(points), box_(box) {}
  const PointSet& base_;
  const PeriodicBox& box_;
  std::uint32_t n_ = 0;
  std::vector<double> margin_;
  double pad_ = 0;
  PointSet cover_;
  std::vector<std::uint32_t> image_point_;
  std::vector<std::int32_t> image_offset_;  // d per image
  std::vector<std::int32_t> zeros_;
  std::vector<double> weights_;
  double max_weight_ = 0;
  std::unique_ptr<KdTree> tree_;
};

}  // namespace spokemesh
