#include "spokemesh/locate.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>

#include <gmpxx.h>

#include "spokemesh/predicates.hpp"

namespace spokemesh {

namespace {

// 2-d and 3-d: the determinant written out, with the value, magnitude and rounding
// depth BoundedDouble's operators would give it (predicates.hpp): differences depth 1,
// 2 x 2 minors 4, the 3 x 3 sum of products 8; kUnknownSign when it cannot tell.
int orientation_filtered(const std::array<const double*, kMaxDimension + 1>& p, int d) {
  const double* a = p[0];
  if (d == 2) {
    const double bx = p[1][0] - a[0], by = p[1][1] - a[1], cx = p[2][0] - a[0], cy = p[2][1] - a[1];
    const double l = bx * cy, r = by * cx;
    return filter::certified_sign(l - r, std::fabs(l) + std::fabs(r), 4);
  }
  const double bx = p[1][0] - a[0], by = p[1][1] - a[1], bz = p[1][2] - a[2];
  const double cx = p[2][0] - a[0], cy = p[2][1] - a[1], cz = p[2][2] - a[2];
  const double dx = p[3][0] - a[0], dy = p[3][1] - a[1], dz = p[3][2] - a[2];
  const double m1 = cy * dz - cz * dy, m2 = cx * dz - cz * dx, m3 = cx * dy - cy * dx;
  const double value = bx * m1 - by * m2 + bz * m3;
  const double magnitude = std::fabs(bx) * (std::fabs(cy * dz) + std::fabs(cz * dy)) +
                           std::fabs(by) * (std::fabs(cx * dz) + std::fabs(cz * dx)) +
                           std::fabs(bz) * (std::fabs(cx * dy) + std::fabs(cy * dx));
  return filter::certified_sign(value, magnitude, 8);
}

}  // namespace

int orientation_of(const std::array<const double*, kMaxDimension + 1>& p, int d) {
  if (d == 2 || d == 3) {
    const int s = orientation_filtered(p, d);
    if (s != filter::kUnknownSign) return s;
  }
  std::array<double, kMaxDimension * kMaxDimension> m{};
  double hadamard = 1;
  for (int r = 0; r < d; ++r) {
    double n2 = 0;
    for (int c = 0; c < d; ++c) {
      m[r * d + c] = p[r + 1][c] - p[0][c];
      n2 += m[r * d + c] * m[r * d + c];
    }
    hadamard *= std::sqrt(n2);
  }
  double det = 1;
  for (int c = 0; c < d; ++c) {
    int pivot = c;
    for (int r = c + 1; r < d; ++r) {
      if (std::abs(m[r * d + c]) > std::abs(m[pivot * d + c])) pivot = r;
    }
    if (pivot != c) {
      for (int k = 0; k < d; ++k) std::swap(m[c * d + k], m[pivot * d + k]);
      det = -det;
    }
    det *= m[c * d + c];
    if (m[c * d + c] == 0) break;
    for (int r = c + 1; r < d; ++r) {
      const double f = m[r * d + c] / m[c * d + c];
      for (int k = c; k < d; ++k) m[r * d + k] -= f * m[c * d + k];
    }
  }
  if (std::abs(det) > 1e-10 * hadamard) return det > 0 ? 1 : -1;
  std::vector<mpq_class> a(static_cast<std::size_t>(d * d));
  for (int r = 0; r < d; ++r) {
    for (int c = 0; c < d; ++c) a[r * d + c] = mpq_class(p[r + 1][c]) - mpq_class(p[0][c]);
  }
  int sign = 1;
  for (int c = 0; c < d; ++c) {
    int pivot = c;
    while (pivot < d && sgn(a[pivot * d + c]) == 0) ++pivot;
    if (pivot == d) return 0;
    if (pivot != c) {
      for (int k = 0; k < d; ++k) std::swap(a[c * d + k], a[pivot * d + k]);
      sign = -sign;
    }
    if (sgn(a[c * d + c]) < 0) sign = -sign;
    for (int r = c + 1; r < d; ++r) {
      if (sgn(a[r * d + c]) == 0) continue;
      const mpq_class f = a[r * d + c] / a[c * d + c];
      for (int k = c; k < d; ++k) a[r * d + k] -= f * a[c * d + k];
    }
  }
  return sign;
}

void barycentric_coordinates(const PointSet& points, const std::uint32_t* s, const double* q, double* out) {
  const int d = points.dimension();
  const double* p0 = points.point(s[0]);
  std::array<std::array<double, kMaxDimension + 1>, kMaxDimension> a{};  // [A | q - p0]
  for (int r = 0; r < d; ++r) {
    for (int c = 0; c < d; ++c) a[r][c] = points.point(s[c + 1])[r] - p0[r];
    a[r][d] = q[r] - p0[r];
  }
  for (int c = 0; c < d; ++c) {
    int pivot = c;
    for (int r = c + 1; r < d; ++r) {
      if (std::fabs(a[r][c]) > std::fabs(a[pivot][c])) pivot = r;
    }
    std::swap(a[c], a[pivot]);
    for (int r = c + 1; r < d; ++r) {
      const double f = a[c][c] != 0 ? a[r][c] / a[c][c] : 0.0;
      for (int k = c; k <= d; ++k) a[r][k] -= f * a[c][k];
    }
  }
  double rest = 1;
  for (int c = d - 1; c >= 0; --c) {
    double t = a[c][d];
    for (int k = c + 1; k < d; ++k) t -= a[c][k] * out[k + 1];
    out[c + 1] = a[c][c] != 0 ? t / a[c][c] : 0.0;
    rest -= out[c + 1];
  }
  out[0] = rest;
}

std::vector<std::uint32_t> morton_order(const double* x, std::size_t count, int d) {
  std::vector<std::uint32_t> order(count);
  for (std::size_t i = 0; i < count; ++i) order[i] = static_cast<std::uint32_t>(i);
  if (count < 2) return order;
  std::vector<double> lo(static_cast<std::size_t>(d), std::numeric_limits<double>::infinity());
  std::vector<double> hi(static_cast<std::size_t>(d), -std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < count; ++i) {
    for (int k = 0; k < d; ++k) {
      lo[static_cast<std::size_t>(k)] = std::min(lo[static_cast<std::size_t>(k)], x[i * d + k]);
      hi[static_cast<std::size_t>(k)] = std::max(hi[static_cast<std::size_t>(k)], x[i * d + k]);
    }
  }
  const int bits = std::max(1, 63 / d);
  const double cells = std::ldexp(1.0, bits) - 1;
  std::vector<std::uint64_t> key(count, 0);
  for (std::size_t i = 0; i < count; ++i) {
    std::array<std::uint64_t, kMaxDimension> cell{};
    for (int k = 0; k < d; ++k) {
      const double span = hi[static_cast<std::size_t>(k)] - lo[static_cast<std::size_t>(k)];
      const double t = span > 0 ? (x[i * d + k] - lo[static_cast<std::size_t>(k)]) / span : 0.0;
      cell[static_cast<std::size_t>(k)] = static_cast<std::uint64_t>(std::clamp(t, 0.0, 1.0) * cells);
    }
    std::uint64_t kv = 0;
    for (int b = bits - 1; b >= 0; --b) {
      for (int k = 0; k < d; ++k) kv = (kv << 1) | ((cell[static_cast<std::size_t>(k)] >> b) & 1u);
    }
    key[i] = kv;
  }
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return key[a] < key[b] || (key[a] == key[b] && a < b); });
  return order;
}

SimplexLocator::SimplexLocator(const PointSet& points, std::span<const std::uint32_t> simplices,
                               std::span<const std::int32_t> adjacency, const KdTree& tree)
    : points_(points), simplices_(simplices), adjacency_(adjacency), tree_(tree), d_(points.dimension()) {
  const std::size_t w = static_cast<std::size_t>(d_ + 1);
  first_simplex_.assign(points.size(), -1);
  for (std::size_t s = 0; s * w < simplices.size(); ++s) {
    for (std::size_t k = 0; k < w; ++k) {
      std::int32_t& f = first_simplex_[simplices[s * w + k]];
      if (f < 0) f = static_cast<std::int32_t>(s);
    }
  }
}

std::int32_t SimplexLocator::locate(const double* q) const {
  std::uint32_t nearest = 0;
  double dist2 = 0;
  tree_.knn(q, 1, &nearest, &dist2);
  const std::int32_t s = locate_from(q, first_simplex_[nearest], 4 * simplices_.size() + 16);
  return s == kWalkTooLong ? -1 : s;
}

std::int32_t SimplexLocator::locate_from(const double* q, std::int32_t s, std::size_t max_steps) const {
  const int w = d_ + 1;
  std::array<const double*, kMaxDimension + 1> corners{};
  // The bound only guards against the impossible: the walk terminates.
  for (std::size_t steps = 0; s >= 0; ++steps) {
    if (steps > max_steps) return kWalkTooLong;
    const std::uint32_t* v = &simplices_[static_cast<std::size_t>(s) * w];
    int across = -1;
    for (int k = 0; k < w && across < 0; ++k) {
      for (int j = 0; j < w; ++j) corners[j] = j == k ? q : points_.point(v[j]);
      // Simplices are positively oriented: q beyond facet k makes this negative.
      if (orientation_of(corners, d_) < 0) across = k;
    }
    if (across < 0) return s;
    s = adjacency_[static_cast<std::size_t>(s) * w + across];
  }
  return -1;
}

void locate_runs(const SimplexLocator& locator, const double* queries, std::size_t count, int d, unsigned threads,
                 const std::vector<std::uint32_t>& order,
                 void (*visit)(void* context, std::size_t run, std::size_t i, std::int32_t simplex), void* context) {
  constexpr std::size_t kRun = 256;
  const std::size_t runs = (count + kRun - 1) / kRun;
  std::atomic<std::size_t> next{0};
  auto work = [&] {
    for (std::size_t r; (r = next.fetch_add(1)) < runs;) {
      std::int32_t hint = -1;
      std::size_t misses = 0;  // hinted walks that were too long in a row
      for (std::size_t at = r * kRun; at < std::min(count, (r + 1) * kRun); ++at) {
        const std::size_t i = order[at];
        const double* x = queries + i * static_cast<std::size_t>(d);
        const bool try_hint = hint >= 0 && (misses < 2 || at % 16 == 0);
        std::int32_t s = try_hint ? locator.locate_from(x, hint, 24) : locator.locate(x);
        if (s == SimplexLocator::kWalkTooLong) {
          ++misses;
          s = locator.locate(x);
        } else if (try_hint) {
          misses = 0;
        }
        visit(context, r, i, s);
        if (s >= 0) hint = s;
      }
    }
  };
  std::vector<std::thread> pool;
  const unsigned extra = runs > 4 ? std::max(1u, threads) - 1 : 0;
  for (unsigned t = 0; t < extra; ++t) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
}

}  // namespace spokemesh
