#include "spokemesh/predicates.hpp"

#include <gmpxx.h>

#include <array>
#include <vector>

namespace spokemesh {

void minors_table(const Approx* m, int rows, int cols, Approx* table) {
  table[0] = Approx{1.0, 1.0, 0};
  const unsigned full = (1u << cols) - 1u;
  for (unsigned mask = 1; mask <= full; ++mask) {
    const int j = __builtin_popcount(mask);
    if (j > rows) continue;
    const Approx* row = m + (rows - j) * cols;
    Approx acc{};
    int t = 0;
    for (unsigned rest = mask; rest != 0; rest &= rest - 1, ++t) {
      const int c = __builtin_ctz(rest);
      const Approx term = row[c] * table[mask ^ (1u << c)];
      if (t == 0) acc = (t % 2 == 0) ? term : -term;
      else acc = (t % 2 == 0) ? acc + term : acc - term;
    }
    table[mask] = acc;
  }
}

namespace {

constexpr int kMaxCols = kMaxDimension + 1;

// Sign of the determinant of a k x k rational matrix by Gaussian elimination.
int sign_of_determinant(std::vector<mpq_class>& m, int k) {
  int sign = 1;
  for (int col = 0; col < k; ++col) {
    int pivot = -1;
    for (int r = col; r < k; ++r) {
      if (sgn(m[r * k + col]) != 0) { pivot = r; break; }
    }
    if (pivot < 0) return 0;
    if (pivot != col) {
      for (int c = 0; c < k; ++c) std::swap(m[pivot * k + c], m[col * k + c]);
      sign = -sign;
    }
    sign *= sgn(m[col * k + col]);
    for (int r = col + 1; r < k; ++r) {
      if (sgn(m[r * k + col]) == 0) continue;
      const mpq_class f = m[r * k + col] / m[col * k + col];
      for (int c = col; c < k; ++c) m[r * k + c] -= f * m[col * k + c];
    }
  }
  return sign;
}

// Exact row (p - x, |p - x|^2) or (w, 0) with `cols` columns (d or d + 1).
void exact_row(const PointSet& ps, std::uint32_t origin, const Row& row, int cols, mpq_class* out) {
  const int d = ps.dimension();
  if (row.is_point()) {
    const double* p = ps.point(static_cast<std::size_t>(row.point));
    const double* x = ps.point(origin);
    mpq_class norm2 = 0;
    for (int c = 0; c < d; ++c) {
      out[c] = mpq_class(p[c]) - mpq_class(x[c]);
      norm2 += out[c] * out[c];
    }
    if (cols > d) out[d] = norm2;
  } else {
    for (int c = 0; c < d; ++c) out[c] = mpq_class(row.dir[c]);
    if (cols > d) out[d] = 0;
  }
}

void approx_row(const PointSet& ps, std::uint32_t origin, const Row& row, int cols, Approx* out) {
  const int d = ps.dimension();
  if (row.is_point()) {
    const double* p = ps.point(static_cast<std::size_t>(row.point));
    const double* x = ps.point(origin);
    Approx norm2{};
    for (int c = 0; c < d; ++c) {
      out[c] = Approx::difference(p[c], x[c]);
      norm2 = (c == 0) ? out[c] * out[c] : norm2 + out[c] * out[c];
    }
    if (cols > d) out[d] = norm2;
  } else {
    for (int c = 0; c < d; ++c) out[c] = Approx::exact(row.dir[c]);
    if (cols > d) out[d] = Approx::exact(0.0);
  }
}

int filtered_sign(const PointSet& ps, std::uint32_t origin, std::span<const Row> rows, int k) {
  std::array<Approx, kMaxCols * kMaxCols> m;
  std::array<Approx, 1u << kMaxCols> table;
  for (int r = 0; r < k; ++r) approx_row(ps, origin, rows[r], k, &m[r * k]);
  minors_table(m.data(), k, k, table.data());
  return table[(1u << k) - 1u].certified_sign();
}

}  // namespace

int Predicates::spatial_sign_exact(std::uint32_t origin, std::span<const Row> rows) const {
  const int d = ps_.dimension();
  std::vector<mpq_class> m(static_cast<std::size_t>(d * d));
  for (int r = 0; r < d; ++r) exact_row(ps_, origin, rows[r], d, &m[r * d]);
  return sign_of_determinant(m, d);
}

int Predicates::spatial_sign(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension());
  return s != Approx::kUnknownSign ? s : spatial_sign_exact(origin, rows);
}

// The lifted determinant is linear in every point's height. With heights
// h_p = |p - x|^2 + delta_p - delta_x, its derivative in delta_r is the cofactor of
// row r's height entry, (-1)^(r + d) det(spatial parts of the other rows), and in
// delta_x it is minus the sum of those cofactors over point rows, i.e. minus the
// determinant with the height column replaced by the point-row indicator. The
// perturbed sign is the sign of the first non-zero derivative, taking the points in
// decreasing lexicographic order (the largest point's delta dominates).
int Predicates::lifted_sign_exact(std::uint32_t origin, std::span<const Row> rows, bool perturb) const {
  const int d = ps_.dimension();
  const int k = d + 1;
  std::vector<mpq_class> full(static_cast<std::size_t>(k * k));
  for (int r = 0; r < k; ++r) exact_row(ps_, origin, rows[r], k, &full[r * k]);
  {
    std::vector<mpq_class> m = full;
    const int s = sign_of_determinant(m, k);
    if (s != 0 || !perturb) return s;
  }
  // Candidates for the dominant infinitesimal: the origin (-1) and every point row.
  std::array<int, kMaxCols + 1> who{};
  int count = 0;
  who[count++] = -1;
  for (int r = 0; r < k; ++r) {
    if (rows[r].is_point()) who[count++] = r;
  }
  auto rank_of = [&](int w) {
    return ps_.lex_rank(w < 0 ? origin : static_cast<std::size_t>(rows[w].point));
  };
  std::sort(who.begin(), who.begin() + count, [&](int a, int b) { return rank_of(a) > rank_of(b); });

  for (int i = 0; i < count; ++i) {
    const int w = who[i];
    int coefficient_sign = 0;
    if (w < 0) {
      std::vector<mpq_class> m = full;
      for (int r = 0; r < k; ++r) m[r * k + d] = rows[r].is_point() ? 1 : 0;
      coefficient_sign = -sign_of_determinant(m, k);
    } else {
      std::vector<mpq_class> m(static_cast<std::size_t>(d * d));
      int out = 0;
      for (int r = 0; r < k; ++r) {
        if (r == w) continue;
        for (int c = 0; c < d; ++c) m[out * d + c] = full[r * k + c];
        ++out;
      }
      coefficient_sign = sign_of_determinant(m, d) * (((w + d) % 2 == 0) ? 1 : -1);
    }
    if (coefficient_sign != 0) return coefficient_sign;
  }
  return 0;  // unreachable for the configurations documented in the header
}

int Predicates::lifted_sign(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension() + 1);
  if (s == 1 || s == -1) return s;
  return lifted_sign_exact(origin, rows, /*perturb=*/true);
}

int Predicates::lifted_sign_unperturbed(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension() + 1);
  if (s != Approx::kUnknownSign) return s;
  return lifted_sign_exact(origin, rows, /*perturb=*/false);
}

int Predicates::orientation(std::span<const std::uint32_t> simplex) const {
  const int d = ps_.dimension();
  std::array<Row, kMaxCols> rows;
  for (int r = 0; r < d; ++r) rows[r] = Row::of_point(simplex[r + 1]);
  return spatial_sign(simplex[0], std::span<const Row>(rows.data(), d));
}

void Predicates::spatial_normal(std::uint32_t origin, std::span<const Row> rows, Approx* normal) const {
  const int d = ps_.dimension();
  std::array<Approx, kMaxCols * kMaxCols> m;
  std::array<Approx, 1u << kMaxCols> table;
  for (int r = 0; r < d - 1; ++r) approx_row(ps_, origin, rows[r], d, &m[r * d]);
  minors_table(m.data(), d - 1, d, table.data());
  const unsigned all = (1u << d) - 1u;
  for (int c = 0; c < d; ++c) normal[c] = ((d - 1 + c) % 2 == 0) ? table[all ^ (1u << c)] : -table[all ^ (1u << c)];
}

int Predicates::side_of_sphere(std::span<const std::uint32_t> simplex, std::uint32_t q) const {
  const int d = ps_.dimension();
  std::array<Row, kMaxCols> rows;
  for (int r = 0; r < d; ++r) rows[r] = Row::of_point(simplex[r + 1]);
  rows[d] = Row::of_point(q);
  // The "up" direction (0, ..., 0, 1) in place of q gives det = orientation, so q is
  // outside (above the lifted hyperplane) exactly when the two signs agree.
  const int lifted = lifted_sign(simplex[0], std::span<const Row>(rows.data(), d + 1));
  return lifted * orientation(simplex);
}

}  // namespace spokemesh
