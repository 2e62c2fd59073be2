#include "spokemesh/domain.hpp"

#include <gmpxx.h>

#include <cmath>
#include <limits>
#include <sstream>

#include "spokemesh/predicates.hpp"

namespace spokemesh {

int plane_side(const double* a, double b, const double* x, int d) {
  // Filter: with u the unit roundoff, the computed sum of d + 1 terms (one product each)
  // is within (d + 2) u (sum |a_c x_c| + |b|) of the exact one (Higham, 3.1), doubled
  // for margin against the error bound's own rounding.
  double f = -b, magnitude = std::abs(b);
  for (int c = 0; c < d; ++c) {
    f += a[c] * x[c];
    magnitude += std::abs(a[c] * x[c]);
  }
  constexpr double u = filter::kUnitRoundoff;
  const double bound = 2 * (d + 2) * u * magnitude;
  if (f > bound) return 1;
  if (f < -bound) return -1;
  mpq_class exact = -mpq_class(b);
  for (int c = 0; c < d; ++c) exact += mpq_class(a[c]) * mpq_class(x[c]);
  return sgn(exact);
}

Result<Domain> Domain::box(const std::vector<double>& lo, const std::vector<double>& hi) {
  const std::size_t d = lo.size();
  if (d != hi.size()) {
    return invalid_argument("box: " + std::to_string(lo.size()) + " lower bounds but " + std::to_string(hi.size()) +
                            " upper bounds");
  }
  if (d < 2 || d > static_cast<std::size_t>(kMaxDimension)) {
    return invalid_argument("box: dimension " + std::to_string(d) + " is outside [2, " + std::to_string(kMaxDimension) +
                            "]");
  }
  Domain out;
  out.d_ = static_cast<int>(d);
  out.is_box_ = true;
  out.normals_.assign(2 * d * d, 0.0);
  out.offsets_.resize(2 * d);
  for (std::size_t c = 0; c < d; ++c) {
    if (!std::isfinite(lo[c]) || !std::isfinite(hi[c])) {
      return invalid_argument("box: coordinate " + std::to_string(c) + " has a bound that is not finite");
    }
    if (lo[c] > hi[c]) {
      std::ostringstream m;
      m.precision(17);
      m << "box: coordinate " << c << " has lower bound " << lo[c] << " above upper bound " << hi[c];
      return invalid_argument(m.str());
    }
    out.normals_[c * d + c] = -1.0;  // x_c >= lo_c, i.e. -x_c <= -lo_c
    out.offsets_[c] = -lo[c];
    out.normals_[(d + c) * d + c] = 1.0;
    out.offsets_[d + c] = hi[c];
  }
  return out;
}

Domain Domain::bounding_box(const PointSet& points) {
  const int d = points.dimension();
  std::vector<double> lo(points.point(0), points.point(0) + d), hi = lo;
  for (std::size_t i = 1; i < points.size(); ++i) {
    const double* p = points.point(i);
    for (int c = 0; c < d; ++c) {
      lo[c] = std::min(lo[c], p[c]);
      hi[c] = std::max(hi[c], p[c]);
    }
  }
  return std::move(box(lo, hi).value());
}

Result<Domain> Domain::halfspaces(int dimension, std::vector<double> normals, std::vector<double> offsets) {
  if (dimension < 2 || dimension > kMaxDimension) {
    return invalid_argument("halfspaces: dimension " + std::to_string(dimension) + " is outside [2, " +
                            std::to_string(kMaxDimension) + "]");
  }
  const auto d = static_cast<std::size_t>(dimension);
  if (normals.size() != offsets.size() * d) {
    return invalid_argument("halfspaces: " + std::to_string(offsets.size()) + " offsets need " +
                            std::to_string(offsets.size() * d) + " normal coordinates, got " +
                            std::to_string(normals.size()));
  }
  if (offsets.empty()) return invalid_argument("halfspaces: no walls");
  if (offsets.size() > kMaxDomainWalls) {
    return invalid_argument("halfspaces: " + std::to_string(offsets.size()) + " walls exceed the limit of " +
                            std::to_string(kMaxDomainWalls));
  }
  for (std::size_t k = 0; k < offsets.size(); ++k) {
    bool zero = true;
    for (std::size_t c = 0; c < d; ++c) {
      const double v = normals[k * d + c];
      if (!std::isfinite(v) || std::abs(v) > kMaxCoordinate) {
        return invalid_argument("halfspaces: wall " + std::to_string(k) + ", normal coordinate " + std::to_string(c) +
                                " is not finite or exceeds 1e100");
      }
      zero = zero && v == 0;
    }
    if (zero) return invalid_argument("halfspaces: wall " + std::to_string(k) + " has a zero normal");
    if (!std::isfinite(offsets[k]) || std::abs(offsets[k]) > kMaxCoordinate) {
      return invalid_argument("halfspaces: wall " + std::to_string(k) +
                              " has an offset that is not finite or exceeds 1e100");
    }
  }
  Domain out;
  out.d_ = dimension;
  out.normals_ = std::move(normals);
  out.offsets_ = std::move(offsets);
  return out;
}

Result<Domain> Domain::parse_box(const std::string& text) {
  auto parsed = parse_number_list(text, "--box", 2 * kMaxDimension);
  if (!parsed.is_ok()) return parsed.status();
  const std::vector<double>& values = parsed.value();
  if (values.size() % 2 != 0) {
    return invalid_argument("--box: needs LO1,...,LOd,HI1,...,HId (an even count), got " +
                            std::to_string(values.size()) + " values");
  }
  const auto half = static_cast<std::ptrdiff_t>(values.size() / 2);
  return box(std::vector<double>(values.begin(), values.begin() + half),
             std::vector<double>(values.begin() + half, values.end()));
}

std::vector<double> Domain::lower() const {
  std::vector<double> lo(static_cast<std::size_t>(d_));
  for (int c = 0; c < d_; ++c) lo[c] = -offsets_[c];
  return lo;
}

std::vector<double> Domain::upper() const { return {offsets_.begin() + d_, offsets_.begin() + 2 * d_}; }

std::optional<std::size_t> Domain::violated_wall(const double* x) const {
  for (std::size_t k = 0; k < wall_count(); ++k) {
    if (plane_side(normal(k), offset(k), x, d_) > 0) return k;
  }
  return std::nullopt;
}

std::string Domain::describe() const {
  std::ostringstream m;
  m.precision(17);
  if (is_box_) {
    m << "box [";
    for (int c = 0; c < d_; ++c) m << (c ? "," : "") << -offsets_[c];
    m << "] x [";
    for (int c = 0; c < d_; ++c) m << (c ? "," : "") << offsets_[d_ + c];
    m << "]";
  } else {
    m << wall_count() << " halfspaces";
  }
  return m.str();
}

}  // namespace spokemesh
