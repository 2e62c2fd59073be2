// Certified bounds on the circumballs of simplices in 2-d and 3-d: an interval box
// around the exact circumcentre, an upper bound on the squared radius, and tests of
// such a ball against boxes, all rounded outwards so that every answer is
// conservative. Shared by the distributed run's StarCertifier (certify.cpp) and the
// whole mesh's local triangulations (delaunay_sweep.cpp), which both prove a simplex
// Delaunay in the whole set by showing that its ball holds no point they lack.
//
// Thread safety: pure functions.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <gmpxx.h>

namespace spokemesh::ball_bounds {

// Relative error bound of every filtered quantity below, times its magnitude: about 90
// units in the last place, far above the longest chain of roundings (11 for d = 3,
// the inputs' subtraction included).
constexpr double kGamma = 1e-14;
// Outward rounding of a few further operations on bounds.
constexpr double kUlps = 8 * std::numeric_limits<double>::epsilon();

// Outward rounding: each moves v by 8 ulps and a little more than the least
// subnormal; the subtraction's own rounding (half an ulp) cannot undo that.
constexpr double kTiny = 1e-300;
inline double down(double v) { return v - std::fabs(v) * kUlps - kTiny; }
inline double up(double v) { return v + std::fabs(v) * kUlps + kTiny; }

struct Interval {
  double lo, hi;
};

// n / d for intervals with 0 outside d, rounded outwards.
inline Interval divide(Interval n, Interval d) {
  const double q[4] = {n.lo / d.lo, n.lo / d.hi, n.hi / d.lo, n.hi / d.hi};
  return {down(*std::min_element(q, q + 4)), up(*std::max_element(q, q + 4))};
}

// A value and the magnitude that bounds its rounding error (error <= kGamma * mag).
struct Filtered {
  double value = 0, mag = 0;
  Interval interval() const {
    const double e = kGamma * mag;
    return {down(value - e), up(value + e)};
  }
};

// The circumcentre of a star simplex, as an interval box around the exact one, and an
// upper bound on the squared circumradius. False when the bounds cannot separate D
// from 0 (a nearly flat simplex).
template <int D>
inline bool circumball(const double* s, const std::array<const double*, D>& v, std::array<Interval, D>& centre,
                       double& radius2_up) {
  // Offsets from the seed (rounded: the input error is in kGamma's chain).
  std::array<std::array<double, D>, D> a{};
  std::array<std::array<double, D>, D> m{};  // their magnitudes
  std::array<double, D> w{}, wm{};           // |a_i|^2
  for (int i = 0; i < D; ++i) {
    for (int k = 0; k < D; ++k) {
      a[i][k] = v[i][k] - s[k];
      m[i][k] = std::fabs(a[i][k]);
      w[i] += a[i][k] * a[i][k];
    }
    wm[i] = w[i];
  }
  std::array<Filtered, D> n{};
  Filtered den;
  if constexpr (D == 2) {
    den.value = 2 * (a[0][0] * a[1][1] - a[0][1] * a[1][0]);
    den.mag = 2 * (m[0][0] * m[1][1] + m[0][1] * m[1][0]);
    n[0] = {w[0] * a[1][1] - w[1] * a[0][1], wm[0] * m[1][1] + wm[1] * m[0][1]};
    n[1] = {w[1] * a[0][0] - w[0] * a[1][0], wm[1] * m[0][0] + wm[0] * m[1][0]};
  } else {
    // N = |a|^2 (b x c) + |b|^2 (c x a) + |c|^2 (a x b), D = 2 a . (b x c).
    auto cross = [](const std::array<double, 3>& p, const std::array<double, 3>& q, bool absolute) {
      if (absolute) {
        return std::array<double, 3>{p[1] * q[2] + p[2] * q[1], p[2] * q[0] + p[0] * q[2], p[0] * q[1] + p[1] * q[0]};
      }
      return std::array<double, 3>{p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]};
    };
    const auto bc = cross(a[1], a[2], false), ca = cross(a[2], a[0], false), ab = cross(a[0], a[1], false);
    const auto bcm = cross(m[1], m[2], true), cam = cross(m[2], m[0], true), abm = cross(m[0], m[1], true);
    den.value = 2 * (a[0][0] * bc[0] + a[0][1] * bc[1] + a[0][2] * bc[2]);
    den.mag = 2 * (m[0][0] * bcm[0] + m[0][1] * bcm[1] + m[0][2] * bcm[2]);
    for (int k = 0; k < 3; ++k) {
      n[k] = {w[0] * bc[k] + w[1] * ca[k] + w[2] * ab[k], wm[0] * bcm[k] + wm[1] * cam[k] + wm[2] * abm[k]};
    }
  }
  const Interval dd = den.interval();
  if (dd.lo <= 0 && dd.hi >= 0) return false;
  radius2_up = 0;
  for (int k = 0; k < D; ++k) {
    const Interval x = divide(n[k].interval(), dd);  // the centre's offset from the seed
    centre[k] = {down(s[k] + x.lo), up(s[k] + x.hi)};
    const double big = std::max(std::fabs(x.lo), std::fabs(x.hi));
    radius2_up += big * big;
  }
  radius2_up = up(radius2_up);
  return true;
}

// The circumball of a nearly flat simplex, which the filtered bounds cannot place:
// its centre solved exactly in rationals (2 (v_i - s) . c = |v_i - s|^2), then rounded
// outwards. Rare (a simplex whose volume is below about 1e-14 of its edges' product).
template <int D>
inline void exact_circumball(const double* s, const std::array<const double*, D>& v, std::array<Interval, D>& centre,
                             double& radius2_up) {
  std::array<std::array<mpq_class, D + 1>, D> m;
  for (int i = 0; i < D; ++i) {
    mpq_class norm2 = 0;
    for (int k = 0; k < D; ++k) {
      const mpq_class a = mpq_class(v[i][k]) - mpq_class(s[k]);
      m[i][k] = 2 * a;
      norm2 += a * a;
    }
    m[i][D] = norm2;
  }
  for (int col = 0; col < D; ++col) {  // Gauss-Jordan (the simplex is not flat: pivots exist)
    int pivot = col;
    while (sgn(m[pivot][col]) == 0) ++pivot;
    std::swap(m[pivot], m[col]);
    for (int r = 0; r < D; ++r) {
      if (r == col || sgn(m[r][col]) == 0) continue;
      const mpq_class f = m[r][col] / m[col][col];
      for (int k = col; k <= D; ++k) m[r][k] -= f * m[col][k];
    }
  }
  mpq_class r2 = 0;
  for (int k = 0; k < D; ++k) {
    const mpq_class c = m[k][D] / m[k][k];
    r2 += c * c;
    const double x = mpq_class(c + mpq_class(s[k])).get_d();  // truncated: within an ulp
    centre[static_cast<std::size_t>(k)] = {std::nextafter(x, -HUGE_VAL), std::nextafter(x, HUGE_VAL)};
  }
  radius2_up = up(std::nextafter(r2.get_d(), HUGE_VAL));
}

// Whether the closed ball (centre interval, radius^2 <= radius2_up) misses box b.
template <int D>
inline bool misses(const std::array<Interval, D>& centre, double radius2_up, const double* box) {
  double gap2 = 0;
  for (int k = 0; k < D; ++k) {
    const double below = box[k] - centre[k].hi, above = centre[k].lo - box[D + k];
    const double g = std::max({0.0, down(below), down(above)});
    gap2 += g * g;
  }
  return down(gap2) > radius2_up;
}

// The box around the part of the ball inside the whole set's box g (where points can
// be): along axis k, the ball's chord over the nearest point of g's other axes. The
// huge balls of nearly flat simplices at the hull cut only a thin cap out of g.
template <int D>
inline std::array<double, 2 * D> clipped_extent(const std::array<Interval, D>& centre, double radius2_up,
                                                const double* g) {
  std::array<double, D> gap{};
  for (int j = 0; j < D; ++j) {
    gap[static_cast<std::size_t>(j)] = std::max({0.0, down(g[j] - centre[j].hi), down(centre[j].lo - g[D + j])});
  }
  std::array<double, 2 * D> out{};
  for (int k = 0; k < D; ++k) {
    double gap2 = 0;
    for (int j = 0; j < D; ++j)
      gap2 += j == k ? 0.0 : gap[static_cast<std::size_t>(j)] * gap[static_cast<std::size_t>(j)];
    const double h = up(std::sqrt(std::max(0.0, up(radius2_up - down(gap2)))));
    out[static_cast<std::size_t>(k)] = std::max(g[k], down(centre[k].lo - h));
    out[static_cast<std::size_t>(D + k)] = std::min(g[D + k], up(centre[k].hi + h));
  }
  return out;
}

// Whether the part of the ball inside g lies inside the box (every point of it is held).
template <int D>
inline bool inside(const std::array<double, 2 * D>& extent, const double* box) {
  for (int k = 0; k < D; ++k) {
    if (extent[static_cast<std::size_t>(k)] < box[k] || extent[static_cast<std::size_t>(D + k)] > box[D + k])
      return false;
  }
  return true;
}

}  // namespace spokemesh::ball_bounds
