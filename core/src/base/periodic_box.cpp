#include "spokemesh/periodic_box.hpp"

#include <cmath>
#include <cstdio>

#include "spokemesh/domain.hpp"

namespace spokemesh {

namespace {

std::string number_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

}  // namespace

Result<PeriodicBox> PeriodicBox::of(std::vector<double> lo, std::vector<double> hi, const std::string& what) {
  if (lo.size() != hi.size()) {
    return invalid_argument(what + ": " + std::to_string(lo.size()) + " low sides and " + std::to_string(hi.size()) +
                            " high sides");
  }
  const auto d = static_cast<int>(lo.size());
  if (d < 2 || d > kMaxApproxDimension) {
    return invalid_argument(what + ": a " + std::to_string(d) + "-d box; the dimension must be between 2 and " +
                            std::to_string(kMaxApproxDimension));
  }
  for (int c = 0; c < d; ++c) {
    const double a = lo[static_cast<std::size_t>(c)], b = hi[static_cast<std::size_t>(c)];
    if (!std::isfinite(a) || !std::isfinite(b) || std::fabs(a) > kMaxCoordinate || std::fabs(b) > kMaxCoordinate) {
      return invalid_argument(what + ": axis " + std::to_string(c) + ": the sides must be finite, at most 1e100");
    }
    if (!(a < b)) {
      return invalid_argument(what + ": axis " + std::to_string(c) + ": LO " + number_text(a) + " is not below HI " +
                              number_text(b));
    }
  }
  PeriodicBox box;
  box.lo_ = std::move(lo);
  box.hi_ = std::move(hi);
  return box;
}

Result<PeriodicBox> PeriodicBox::parse(const std::string& text, const std::string& what) {
  auto parsed = parse_number_list(text, what, 2 * static_cast<std::size_t>(kMaxApproxDimension));
  if (!parsed.is_ok()) return parsed.status();
  const std::vector<double>& values = parsed.value();
  if (values.size() % 2 != 0) {
    return invalid_argument(what + ": needs LO1,...,LOd,HI1,...,HId (an even count), got " +
                            std::to_string(values.size()) + " values");
  }
  const auto half = static_cast<std::ptrdiff_t>(values.size() / 2);
  return of(std::vector<double>(values.begin(), values.begin() + half),
            std::vector<double>(values.begin() + half, values.end()), what);
}

Status PeriodicBox::check_contains(const PointSet& points, const std::string& source) const {
  const int d = points.dimension();
  if (d != dimension()) {
    return invalid_argument(source + ": the points are " + std::to_string(d) + "-d and the periodic box " +
                            std::to_string(dimension()) + "-d");
  }
  for (std::size_t i = 0; i < points.size(); ++i) {
    const double* p = points.point(i);
    for (int c = 0; c < d; ++c) {
      const double lo = lo_[static_cast<std::size_t>(c)], hi = hi_[static_cast<std::size_t>(c)];
      if (p[c] >= lo && p[c] < hi) continue;
      return invalid_argument(source + ": point " + std::to_string(i) + " lies outside the periodic box: coordinate " +
                              std::to_string(c) + " is " + number_text(p[c]) +
                              (p[c] < lo ? ", below LO " + number_text(lo) : ", not below HI " + number_text(hi)) +
                              " (the box is [LO, HI) on every axis)");
    }
  }
  return Status::ok();
}

}  // namespace spokemesh
