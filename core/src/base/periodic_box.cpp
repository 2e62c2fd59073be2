#include "spokemesh/periodic_box.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <utility>

#include "spokemesh/units.hpp"

namespace spokemesh {

namespace {

std::string number_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// The sum of `count` (<= 8) finite doubles rounded once to nearest (ties to even).
// Written here rather than taken from a library: it is the classic error-free
// summation (Shewchuk's non-overlapping partials, as Python's math.fsum keeps them),
// then a sum of the partials from the largest down, which is exact until the first
// rounding, with the half-way correction that fsum applies when the remaining partials
// would break a tie. Terms are far below overflow (|p|, |lo|, |hi| <= 1e100, |k| <= 2^20).
double rounded_sum(const double* terms, int count) {
  std::array<double, 16> partials;
  int m = 0;
  for (int t = 0; t < count; ++t) {
    double x = terms[t];
    int kept = 0;
    for (int j = 0; j < m; ++j) {
      double y = partials[static_cast<std::size_t>(j)];
      if (std::fabs(x) < std::fabs(y)) std::swap(x, y);
      const double high = x + y;
      const double low = y - (high - x);
      if (low != 0) partials[static_cast<std::size_t>(kept++)] = low;
      x = high;
    }
    m = kept;
    partials[static_cast<std::size_t>(m++)] = x;
  }
  if (m == 0) return 0;
  int j = m - 1;
  double high = partials[static_cast<std::size_t>(j--)];
  double low = 0;
  while (j >= 0) {
    const double x = high, y = partials[static_cast<std::size_t>(j--)];
    high = x + y;
    low = y - (high - x);
    if (low != 0) break;
  }
  // A half-way case rounded to even: if the partials below push past the tie, round
  // the other way.
  if (j >= 0 && ((low < 0 && partials[static_cast<std::size_t>(j)] < 0) ||
                 (low > 0 && partials[static_cast<std::size_t>(j)] > 0))) {
    const double y = low * 2;
    const double x = high + y;
    if (y == x - high) high = x;
  }
  return high;
}

}  // namespace

double image_difference(double p, std::int32_t k, double lo, double hi, double x) {
  if (k == 0) return p - x;
  // k hi and k lo exactly, each as a product and its rounding error (fma).
  const double kd = static_cast<double>(k);
  const double a = kd * hi, b = kd * lo;
  const double terms[6] = {p, -x, a, std::fma(kd, hi, -a), -b, -std::fma(kd, lo, -b)};
  return rounded_sum(terms, 6);
}

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
