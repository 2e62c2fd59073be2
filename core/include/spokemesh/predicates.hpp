// Exact geometric predicates for Delaunay meshing in any dimension 2..8.
//
// Every predicate is a sign of a determinant whose rows are taken relative to an
// origin point x (in the star walk, the seed):
//   a point p contributes the row (p - x, |p - x|^2)   -- its lift onto the paraboloid
//   a direction w contributes (w, 0)                   -- a vector of the lifted hyperplane
// The "spatial" determinant uses only the first d columns; the "lifted" determinant
// uses all d + 1. Staging (as Shewchuk's orient3d -> orient3dadapt):
//   1. filter: the determinant in double precision, carrying a rigorous bound on its
//      rounding error (class Approx below);
//   2. exact: GMP rationals, when the filter cannot certify the sign;
//   3. symbolic perturbation, when the exact lifted determinant is zero: point p's
//      height becomes |p - x|^2 + delta_p (with x's own delta subtracted), where the
//      deltas are infinitesimals ordered by the lexicographic rank of the points, the
//      largest point's the most significant. This is CGAL's
//      perturbed_side_of_positive_sphere (Devillers & Teillaud 2011), so ties resolve
//      as in CGAL's Delaunay triangulations, and the mesh depends only on the point set.
//
// Thread safety: Predicates is immutable; concurrent calls are safe.
#pragma once

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include <gmpxx.h>

#include "spokemesh/point_set.hpp"

namespace spokemesh {

// A floating-point value with a certified error bound.
//
// Invariant: if the computation is evaluated exactly on exact inputs, the result E
// satisfies |v - E| <= err() (unless depth() reports unsafe). Proof sketch (Higham,
// "Accuracy and Stability of Numerical Algorithms", 3.1): every monomial of the
// expanded computation passes through at most n roundings, so v = sum T_k prod(1+d_i)
// with |d_i| <= u = 2^-53, hence |v - E| <= gamma_n sum|T_k|, and `a` (the same
// computation on magnitudes) bounds sum|T_k| up to the same factor. Leaves are exact
// doubles (n = 0) or rounded differences fl(p - x) (n = 1). A product that could
// underflow (0 < a < 2^-960) loses the relative-error model and marks the value
// unsafe; overflow shows as a non-finite `a`. Sums of doubles never underflow.
//
// Trivially constructible on purpose: predicate scratch arrays are large and must not
// be zero-filled on every call. Approx{} is zero.
struct Approx {
  double v;  // computed value
  double a;  // computed bound on the sum of magnitudes of the monomials
  int n;     // rounding depth (kUnsafe: no bound)

  static constexpr int kUnsafe = 1 << 20;

  static Approx exact(double x) { return {x, std::fabs(x), 0}; }
  static Approx difference(double p, double x) {
    const double v = p - x;
    return {v, std::fabs(v), 1};
  }

  // +1 / -1 when the sign of the exact value is certain, 0 when it is certainly zero
  // (all monomials vanish), kUnknownSign otherwise.
  static constexpr int kUnknownSign = 2;
  int certified_sign() const {
    if (n >= kUnsafe || !(a <= DBL_MAX)) return kUnknownSign;
    if (a == 0) return 0;
    // (n + 2) u (1.01) covers gamma_n / (1 - gamma_n)^2 and the three roundings here.
    const double err = a * (static_cast<double>(n + 2) * 0x1p-53) * 1.01;
    if (v > err) return 1;
    if (v < -err) return -1;
    return kUnknownSign;
  }
};

inline Approx operator+(const Approx& x, const Approx& y) {
  return {x.v + y.v, x.a + y.a, std::min(std::max(x.n, y.n) + 1, Approx::kUnsafe)};
}
inline Approx operator-(const Approx& x, const Approx& y) {
  return {x.v - y.v, x.a + y.a, std::min(std::max(x.n, y.n) + 1, Approx::kUnsafe)};
}
inline Approx operator-(const Approx& x) { return {-x.v, x.a, x.n}; }
inline Approx operator*(const Approx& x, const Approx& y) {
  const double a = x.a * y.a;
  int n = std::min(x.n + y.n + 1, Approx::kUnsafe);
  if (a < 0x1p-960 && x.a != 0 && y.a != 0) n = Approx::kUnsafe;
  return {x.v * y.v, a, n};
}

// Minors by Laplace expansion memoised over column subsets: for every mask over
// `cols` columns with popcount(mask) <= rows, table[mask] = det(last popcount(mask)
// rows of the row-major rows x cols matrix m, columns in mask). O(cols 2^cols)
// operations and no division, so the Approx error bound applies. `table` holds
// 2^cols entries. With rows == cols, table[2^cols - 1] is det(m).
void minors_table(const Approx* m, int rows, int cols, Approx* table);

namespace detail {
struct PopCounts {
  std::uint8_t of[1u << (kMaxDimension + 1)] = {};
  constexpr PopCounts() {
    for (unsigned m = 1; m < sizeof of; ++m) of[m] = static_cast<std::uint8_t>(of[m >> 1] + (m & 1u));
  }
};
// Population counts of column masks (the build targets baseline x86-64, where
// __builtin_popcount is a library call).
inline constexpr PopCounts kPopCounts;
}  // namespace detail

// The loop behind minors_table; inlined so that minors_table_fixed gets the sizes as
// compile-time constants.
[[gnu::always_inline]] inline void minors_table_loop(const Approx* m, int rows, int cols, Approx* table) {
  table[0] = Approx{1.0, 1.0, 0};
  const unsigned full = (1u << cols) - 1u;
  for (unsigned mask = 1; mask <= full; ++mask) {
    const int j = detail::kPopCounts.of[mask];
    if (j > rows) continue;
    const Approx* row = m + (rows - j) * cols;
    unsigned rest = mask;
    int c = __builtin_ctz(rest);
    Approx acc = row[c] * table[mask ^ (1u << c)];
    rest &= rest - 1;
    for (int t = 1; rest != 0; rest &= rest - 1, ++t) {
      c = __builtin_ctz(rest);
      const Approx term = row[c] * table[mask ^ (1u << c)];
      acc = (t % 2 == 0) ? acc + term : acc - term;
    }
    table[mask] = acc;
  }
}

// minors_table for sizes known at compile time (the star walk's kernels).
template <int Rows, int Cols>
inline void minors_table_fixed(const Approx* m, Approx* table) {
  minors_table_loop(m, Rows, Cols, table);
}

// Exact determinant of a k x k rational matrix (Gaussian elimination; m is consumed).
mpq_class exact_determinant(std::vector<mpq_class> m, int k);

// One row of a predicate matrix: a point (index into the PointSet) or a direction.
struct Row {
  std::int64_t point = -1;        // >= 0: point index
  const double* dir = nullptr;    // when point < 0: d exact doubles (not owned)

  static Row of_point(std::uint32_t i) { return {static_cast<std::int64_t>(i), nullptr}; }
  static Row of_direction(const double* w) { return {-1, w}; }
  bool is_point() const { return point >= 0; }
};

// The Approx entries of one predicate row relative to `origin`: (p - x, |p - x|^2) for
// a point, (w, 0) for a direction; `cols` is d (spatial) or d + 1 (lifted).
void approx_row(const PointSet& ps, std::uint32_t origin, const Row& row, int cols, Approx* out);

// Exact predicates over one PointSet (which must outlive this object).
class Predicates {
 public:
  explicit Predicates(const PointSet& points) : ps_(points) {}

  const PointSet& points() const { return ps_; }

  // Sign of det[spatial parts of rows] relative to origin; rows.size() == d.
  int spatial_sign(std::uint32_t origin, std::span<const Row> rows) const;
  // Perturbed sign of the lifted determinant; rows.size() == d + 1. Never 0 when
  // the rows hold at least one point whose perturbation coefficient is non-zero,
  // which holds for every call the star walk and the validator make.
  int lifted_sign(std::uint32_t origin, std::span<const Row> rows) const;
  // Exact sign only (no perturbation): 0 on exact ties. For tests and diagnostics.
  int lifted_sign_unperturbed(std::uint32_t origin, std::span<const Row> rows) const;

  // Orientation of a simplex given as d + 1 point indices: sign of det[s_i - s_0].
  int orientation(std::span<const std::uint32_t> simplex) const;
  // Normal of the hyperplane through origin spanned by d - 1 rows: for any q,
  // sign(sum_c normal[c] (q - origin)_c) = sign det[rows; q - origin].
  void spatial_normal(std::uint32_t origin, std::span<const Row> rows, Approx* normal) const;
  // +1 if q lies outside the perturbed circumsphere of the (non-degenerate) simplex,
  // -1 if inside. Never 0 for q not a vertex of the simplex.
  int side_of_sphere(std::span<const std::uint32_t> simplex, std::uint32_t q) const;

  // The exact stages on their own (the filter is inlined by callers on hot paths).
  int spatial_sign_exact(std::uint32_t origin, std::span<const Row> rows) const;
  int lifted_sign_exact(std::uint32_t origin, std::span<const Row> rows, bool perturb) const;

 private:
  const PointSet& ps_;
};

}  // namespace spokemesh
