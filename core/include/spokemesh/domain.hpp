// Domain: the convex region Voronoi cells are clipped to (docs/cells.md).
//
// A domain is a list of walls, halfspaces a_k . x <= b_k (closed), numbered from 0.
// An axis-aligned box [lo, hi] is the 2d walls x_c >= lo_c (wall c) and x_c <= hi_c
// (wall d + c), in that order, so a facet's wall index says which side it is.
// A halfspace domain need not be bounded: cells it leaves unbounded are reported as
// such (volume +inf), as without a domain.
//
// Units: those of the point coordinates. Ownership: a value type.
// Thread safety: immutable after construction; share freely between threads.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/units.hpp"

namespace spokemesh {

// Most walls a halfspace domain may have (each is tested against every cell vertex).
inline constexpr std::size_t kMaxDomainWalls = 4096;

class Domain {
 public:
  Domain() = default;

  // The box [lo, hi] (d each). Errors (INVALID_ARGUMENT, naming the coordinate): sizes
  // differ or are outside [2, kMaxDimension], a bound is not finite, or lo_c > hi_c.
  static Result<Domain> box(const std::vector<double>& lo, const std::vector<double>& hi);
  // The points' bounding box: the default domain of `spokemesh cells`.
  static Domain bounding_box(const PointSet& points);
  // Walls a_k . x <= b_k; `normals` holds d values per wall. Errors name the wall:
  // a normal that is zero or not finite, an offset that is not finite, sizes that do
  // not match, or more than kMaxDomainWalls walls.
  static Result<Domain> halfspaces(int dimension, std::vector<double> normals, std::vector<double> offsets);
  // Parses "LO1,...,LOd,HI1,...,HId" (the CLI's --box).
  static Result<Domain> parse_box(const std::string& text);

  bool empty() const { return d_ == 0; }
  int dimension() const { return d_; }
  std::size_t wall_count() const { return offsets_.size(); }
  const double* normal(std::size_t wall) const { return normals_.data() + wall * static_cast<std::size_t>(d_); }
  double offset(std::size_t wall) const { return offsets_[wall]; }
  bool is_box() const { return is_box_; }
  // Box corners (is_box() only).
  std::vector<double> lower() const;
  std::vector<double> upper() const;

  // The first wall that x (d coordinates) lies strictly outside of, decided exactly,
  // or none when x is in the closed domain.
  std::optional<std::size_t> violated_wall(const double* x) const;
  // "box [lo, hi]" or "N halfspaces", for messages.
  std::string describe() const;

 private:
  int d_ = 0;
  bool is_box_ = false;
  std::vector<double> normals_;  // d per wall
  std::vector<double> offsets_;
};

// Exact sign of a . x - b for doubles a, x (d each) and b: -1, 0 or +1. A filter in
// double with a bound on its rounding error, then rationals where it cannot decide.
int plane_side(const double* a, double b, const double* x, int d);

}  // namespace spokemesh
