// PeriodicBox: the axis-aligned box [LO, HI) whose opposite sides are identified, the
// fundamental domain of a flat torus. A point set meshed on the torus lies in
// it; an image of point p is p + k (HI - LO) for an integer vector k (its offset).
//
// Preconditions checked by of() and parse(): 2 <= d <= kMaxApproxDimension, finite
// sides with LO < HI on every axis, |LO|, |HI| <= kMaxCoordinate.
// Thread safety: immutable after construction; concurrent reads are safe.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

class PeriodicBox {
 public:
  // The box from its corners. `what` names the input in messages ("--periodic").
  // INVALID_ARGUMENT naming the axis when a side is not finite, too large, or
  // LO >= HI; or when the corners' dimensions differ or are out of range.
  static Result<PeriodicBox> of(std::vector<double> lo, std::vector<double> hi, const std::string& what);
  // "LO1,...,LOd,HI1,...,HId", comma-separated, as the CLI's --box writes a box.
  static Result<PeriodicBox> parse(const std::string& text, const std::string& what);

  int dimension() const { return static_cast<int>(lo_.size()); }
  const std::vector<double>& lo() const { return lo_; }
  const std::vector<double>& hi() const { return hi_; }

  // OK when every point lies in [LO, HI) and the dimensions agree; otherwise
  // INVALID_ARGUMENT naming the first point outside (its index, the axis, the
  // coordinate and the side), `source` naming the points ("points.txt").
  Status check_contains(const PointSet& points, const std::string& source) const;

 private:
  std::vector<double> lo_, hi_;
};

// The coordinate of an image relative to x, p + k (hi - lo) - x, rounded once to the
// nearest double (ties to even): as accurate as fl(p - x) is for a point, so the star
// walk's filters, which bound fl(p - x) by one rounding, bound an image's coordinate
// the same way. p, lo, hi, x: finite doubles; |k| <= 2^20.
double image_difference(double p, std::int32_t k, double lo, double hi, double x);

}  // namespace spokemesh
