#include "spokemesh/circumcentre.hpp"

#include <gmpxx.h>
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <climits>
#include <cmath>
#include <limits>

#include "base/invariant.hpp"
#include "predicates/circumcentre_exact.hpp"
#include "predicates/cramer.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {

namespace {

constexpr int kMaxCols = kMaxDimension + 1;

// The exact circumcentre, rounded once: by integers for triangles and tetrahedra
// without weights, in rationals otherwise (circumcentre_exact.hpp; the same value).
std::vector<double> circumcentre_exact(const PointSet& points, const std::uint32_t* ids, int k, const double* weights) {
  // Triangles and tetrahedra (the slivers of scans and surfaces come here): by integers.
  if (weights == nullptr && k == points.dimension()) {
    std::vector<double> centre(static_cast<std::size_t>(k));
    if (detail::circumcentre_integer(points, ids, k, centre.data())) return centre;
  }
  return detail::circumcentre_rational(points, ids, k, weights);
}

}  // namespace

namespace detail {

// The face's points are doubles, so differences, squared norms and the normal
// equations G l = b / 2 (G = V V^T) are exact in mpq, and the only error is the final
// rounding. Gaussian elimination with the first non-zero pivot: exact arithmetic needs
// no pivoting for accuracy, and G is positive definite.
std::vector<double> circumcentre_rational(const PointSet& points, const std::uint32_t* ids, int k,
                                          const double* weights) {
  const int d = points.dimension();
  const double* p0 = points.point(ids[0]);
  std::vector<mpq_class> v(static_cast<std::size_t>(k * d));
  for (int i = 0; i < k; ++i) {
    for (int c = 0; c < d; ++c) v[i * d + c] = mpq_class(points.point(ids[i + 1])[c]) - mpq_class(p0[c]);
  }
  // Augmented [G | b / 2], k x (k + 1).
  std::vector<mpq_class> a(static_cast<std::size_t>(k * (k + 1)));
  for (int i = 0; i < k; ++i) {
    for (int j = 0; j < k; ++j) {
      mpq_class dot = 0;
      for (int c = 0; c < d; ++c) dot += v[i * d + c] * v[j * d + c];
      a[i * (k + 1) + j] = dot;
      if (i == j) {
        // Power centre: v_i . y = (|v_i|^2 - (w_i - w_0)) / 2.
        a[i * (k + 1) + k] = weights == nullptr
                                 ? mpq_class(dot / 2)
                                 : mpq_class((dot - (mpq_class(weights[ids[i + 1]]) - mpq_class(weights[ids[0]]))) / 2);
      }
    }
  }
  for (int col = 0; col < k; ++col) {
    int pivot = col;
    while (pivot < k && sgn(a[pivot * (k + 1) + col]) == 0) ++pivot;
    if (pivot == k) continue;  // a flat face: no circumcentre (never for a Delaunay face)
    if (pivot != col) {
      for (int j = 0; j <= k; ++j) std::swap(a[col * (k + 1) + j], a[pivot * (k + 1) + j]);
    }
    for (int r = 0; r < k; ++r) {
      if (r == col || sgn(a[r * (k + 1) + col]) == 0) continue;
      const mpq_class f = a[r * (k + 1) + col] / a[col * (k + 1) + col];
      for (int j = col; j <= k; ++j) a[r * (k + 1) + j] -= f * a[col * (k + 1) + j];
    }
  }
  std::vector<double> centre(static_cast<std::size_t>(d));
  for (int c = 0; c < d; ++c) {
    mpq_class x = p0[c];
    for (int i = 0; i < k; ++i) {
      if (sgn(a[i * (k + 1) + i]) == 0) continue;
      x += a[i * (k + 1) + k] / a[i * (k + 1) + i] * v[i * d + c];
    }
    centre[c] = x.get_d();
  }
  return centre;
}

bool circumcentre_integer(const PointSet& points, const std::uint32_t* ids, int k, double* out) {
  const int d = points.dimension();
  if (k != d || (d != 2 && d != 3)) return false;
  // Every coordinate is m 2^e with an integer m (|m| < 2^53): with E the least such e,
  // each is the integer m 2^(e - E) in units of 2^E, exactly.
  double m[4][3];  // the integers m (0 for a coordinate 0)
  int e[4][3] = {};
  int least = INT_MAX;
  for (int i = 0; i <= k; ++i) {
    for (int c = 0; c < d; ++c) {
      const double x = points.point(ids[i])[c];
      m[i][c] = std::ldexp(std::frexp(x, &e[i][c]), 53);  // exact: 53 bits
      e[i][c] -= 53;
      if (x != 0) least = std::min(least, e[i][c]);
    }
  }
  if (least == INT_MAX) return false;  // every coordinate 0: flat
  mpz_class X[4][3];
  for (int i = 0; i <= k; ++i) {
    for (int c = 0; c < d; ++c) {
      if (m[i][c] == 0) continue;
      X[i][c] = mpz_class(m[i][c]);
      X[i][c] <<= static_cast<mp_bitcnt_t>(e[i][c] - least);
    }
  }
  // V y = b / 2 with rows v_i = X_i - X_0 and b_i = |v_i|^2 (units 2^E and 2^2E):
  // y_j = det(V with column j replaced by b) / (2 det V), in units of 2^E.
  mpz_class v[3][3], b[3];
  for (int i = 0; i < k; ++i) {
    b[i] = 0;
    for (int c = 0; c < d; ++c) {
      v[i][c] = X[i + 1][c] - X[0][c];
      b[i] += v[i][c] * v[i][c];
    }
  }
  const auto det2 = [](const mpz_class& a, const mpz_class& b1, const mpz_class& c, const mpz_class& e) {
    return mpz_class(a * e - b1 * c);
  };
  const auto det3 = [&](const mpz_class m[3][3]) {
    return mpz_class(m[0][0] * det2(m[1][1], m[1][2], m[2][1], m[2][2]) -
                     m[0][1] * det2(m[1][0], m[1][2], m[2][0], m[2][2]) +
                     m[0][2] * det2(m[1][0], m[1][1], m[2][0], m[2][1]));
  };
  const mpz_class det = d == 2 ? det2(v[0][0], v[0][1], v[1][0], v[1][1]) : det3(v);
  if (sgn(det) == 0) return false;  // flat: the rational path says what it says
  for (int j = 0; j < d; ++j) {
    mpz_class m[3][3];
    for (int i = 0; i < d; ++i) {
      for (int c = 0; c < d; ++c) m[i][c] = c == j ? b[i] : v[i][c];
    }
    const mpz_class num = d == 2 ? det2(m[0][0], m[0][1], m[1][0], m[1][1]) : det3(m);
    // x_0 + y_j = (2 det X_0 + num) / (2 det), times 2^E.
    mpq_class centre(mpz_class(2 * det * X[0][j] + num), mpz_class(2 * det));
    centre.canonicalize();
    if (least >= 0) {
      mpq_mul_2exp(centre.get_mpq_t(), centre.get_mpq_t(), static_cast<mp_bitcnt_t>(least));
    } else {
      mpq_div_2exp(centre.get_mpq_t(), centre.get_mpq_t(), static_cast<mp_bitcnt_t>(-least));
    }
    out[j] = centre.get_d();
  }
  return true;
}

}  // namespace detail

double face_size2(const PointSet& points, const std::uint32_t* ids, int count) {
  const int d = points.dimension();
  const double* p0 = points.point(ids[0]);
  double size2 = 0;
  for (int i = 1; i < count; ++i) {
    double len2 = 0;
    for (int c = 0; c < d; ++c) len2 += (points.point(ids[i])[c] - p0[c]) * (points.point(ids[i])[c] - p0[c]);
    size2 = std::max(size2, len2);
  }
  return size2;
}

namespace {

// The centre of a triangle in 2-d or a tetrahedron in 3-d (count = d + 1) by Cramer's
// rule on the coordinate differences, with its forward error bound (cramer.hpp), in
// double and then (slivers: the flat tetrahedra of scans and surfaces) in x87 extended
// precision: written to `centre` (holding p0 on entry) and true where the bound meets
// the target (1e-12 of the radius); false, `centre` untouched, where it does not (the
// QR and the exact path decide). About 10x cheaper than the QR.
bool cramer_centre(const PointSet& points, const std::uint32_t* ids, int count, const double* weights, double* centre) {
  const int d = points.dimension();
  const double* p0 = points.point(ids[0]);
  auto excess = [&](int i) { return weights == nullptr ? 0.0 : weights[ids[i + 1]] - weights[ids[0]]; };
  auto solve = [&](auto zero) -> bool {
    using T = decltype(zero);
    T y[3] = {0, 0, 0}, bound = 0;
    bool solved = false;
    if (d == 2) {
      T a[2][2], c[2], y2[2];
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) a[i][j] = T(points.point(ids[i + 1])[j]) - T(p0[j]);
        c[i] = T(0.5) * (a[i][0] * a[i][0] + a[i][1] * a[i][1] - T(excess(i)));
      }
      solved = detail::cramer_solve(a, c, y2, bound);
      y[0] = y2[0], y[1] = y2[1];
    } else {
      T a[3][3], c[3];
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) a[i][j] = T(points.point(ids[i + 1])[j]) - T(p0[j]);
        c[i] = T(0.5) * (a[i][0] * a[i][0] + a[i][1] * a[i][1] + a[i][2] * a[i][2] - T(excess(i)));
      }
      solved = detail::cramer_solve(a, c, y, bound);
    }
    T radius = 0;
    for (int j = 0; j < d; ++j) radius += y[j] * y[j];
    // A power centre's distance from p0 may be far below the face's size (its
    // right-hand side cancels): the target is 1e-12 of the larger.
    if (weights != nullptr) radius = std::max(radius, T(face_size2(points, ids, count)));
    // Euclidean: sqrt(d) x the infinity-norm bound, against 1e-12 of the radius.
    if (!solved || !(std::sqrt(T(d)) * bound <= T(1e-12) * std::sqrt(radius))) return false;
    for (int j = 0; j < d; ++j) centre[j] = static_cast<double>(T(centre[j]) + y[j]);
    return true;
  };
  return solve(0.0) || solve(0.0L);
}

// The rest of circumcentre() below, past Cramer's rule: the QR, or the exact centre.
std::vector<double> qr_centre(const PointSet& points, const std::uint32_t* ids, int count, const double* weights) {
  const int d = points.dimension();
  const int k = count - 1;
  const double* p0 = points.point(ids[0]);
  std::vector<double> centre(p0, p0 + d);
  if (d > kMaxCols) return circumcentre_exact(points, ids, k, weights);
  // With weights, the right-hand side (|v_i|^2 - (w_i - w_0)) / 2 carries two more
  // roundings; the bounds below are relative to |y| (which may be small: the power
  // centre can sit near p0), and where they miss the target the exact path decides.
  auto excess = [&](int i) { return weights == nullptr ? 0.0 : weights[ids[i + 1]] - weights[ids[0]]; };
  // Dynamic sizes with fixed capacity: no heap allocation per vertex.
  using Matrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::ColMajor, kMaxCols, kMaxCols>;
  using Vector = Eigen::Matrix<double, Eigen::Dynamic, 1, Eigen::ColMajor, kMaxCols, 1>;
  Matrix a(d, k);
  Vector half_b(k);
  for (int i = 0; i < k; ++i) {
    for (int c = 0; c < d; ++c) a(c, i) = points.point(ids[i + 1])[c] - p0[c];
    half_b(i) = 0.5 * (a.col(i).squaredNorm() - excess(i));
  }
  const Eigen::ColPivHouseholderQR<Matrix> qr(a);
  const Matrix r = qr.matrixR().topLeftCorner(k, k).triangularView<Eigen::Upper>();
  const double largest = std::abs(r(0, 0)), smallest = std::abs(r(k - 1, k - 1));
  constexpr double kRelativeTarget = 1e-12;
  // 4 d: a margin over the first-order bound (the differences and b carry a rounding).
  if (!(smallest > 0) || largest / smallest * filter::kUnitRoundoff * 4 * d > kRelativeTarget) {
    return circumcentre_exact(points, ids, k, weights);
  }
  const Vector pb = qr.colsPermutation().transpose() * half_b;
  const Vector z = r.transpose().triangularView<Eigen::Lower>().solve(pb);
  Vector padded = Vector::Zero(d);
  padded.head(k) = z;
  const Vector y = qr.householderQ() * padded;
  for (int c = 0; c < d; ++c) centre[c] += y(c);
  return centre;
}

}  // namespace

void circumcentre(const PointSet& points, const std::uint32_t* ids, int count, const double* weights, double* out) {
  // c = p0 + y with y in the span of v_i = p_i - p0 and v_i . y = |v_i|^2 / 2. With the
  // column-pivoting QR A P = Q R of A = [v_1 ... v_k] (d x k), y = Q_1 z where
  // R_1^T z = P^T b / 2: the system is solved on the coordinate differences themselves,
  // so its error grows with cond(A), not with cond(A^T A) as through the normal
  // equations (which put a jittered grid's vertices 0.57 cells off).
  //
  // Error bound: the computed y has relative error about cond(A) u d (Higham, Accuracy
  // and Stability, 19.5), cond(A) estimated by |R_11| / |R_kk|. Where that could exceed
  // kRelativeTarget, the centre is computed exactly instead (circumcentre_exact): every
  // result is then within 1e-12 of the face's size plus one ulp of the coordinate.
  const int d = points.dimension();
  const int k = count - 1;
  const double* p0 = points.point(ids[0]);
  std::copy(p0, p0 + d, out);
  if (k == 0) return;
  // Triangles in 2-d and tetrahedra in 3-d (k = d): Cramer's rule where its bound
  // meets the target; the QR takes the rest.
  if (k == d && (d == 2 || d == 3) && cramer_centre(points, ids, count, weights, out)) return;
  const std::vector<double> centre = qr_centre(points, ids, count, weights);
  std::copy(centre.begin(), centre.end(), out);
}

std::vector<double> circumcentre(const PointSet& points, const std::uint32_t* ids, int count, const double* weights) {
  std::vector<double> centre(static_cast<std::size_t>(points.dimension()));
  circumcentre(points, ids, count, weights, centre.data());
  return centre;
}

}  // namespace spokemesh
