#include "spokemesh/predicates.hpp"

#include "spokemesh/periodic_box.hpp"

#include <gmpxx.h>
#include <boost/multiprecision/cpp_int.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

namespace spokemesh {

void minors_table(const BoundedDouble* m, int rows, int cols, BoundedDouble* table) {
  minors_table_loop(m, rows, cols, table);
}

mpq_class exact_determinant(std::vector<mpq_class> m, int k) {
  mpq_class det = 1;
  for (int col = 0; col < k; ++col) {
    int pivot = -1;
    for (int r = col; r < k; ++r) {
      if (sgn(m[r * k + col]) != 0) {
        pivot = r;
        break;
      }
    }
    if (pivot < 0) return 0;
    if (pivot != col) {
      for (int c = 0; c < k; ++c) std::swap(m[pivot * k + c], m[col * k + c]);
      det = -det;
    }
    det *= m[col * k + col];
    for (int r = col + 1; r < k; ++r) {
      if (sgn(m[r * k + col]) == 0) continue;
      const mpq_class f = m[r * k + col] / m[col * k + col];
      for (int c = col; c < k; ++c) m[r * k + c] -= f * m[col * k + c];
    }
  }
  return det;
}

void approx_row(const PointSet& ps, std::uint32_t origin, const Row& given, int cols, BoundedDouble* out,
                const PointExtras& extras) {
  const int d = ps.dimension();
  const Row row = resolve_image(given, extras, d);
  if (row.is_point()) {
    const double* p = ps.point(static_cast<std::size_t>(row.point));
    const double* x = ps.point(origin);
    BoundedDouble norm2{};
    for (int c = 0; c < d; ++c) {
      out[c] = BoundedDouble::difference(p[c], x[c]);
      // An image: + k (HI - LO), the side's length rounded once, the product and the
      // sum once each (k is an exact small integer).
      if (row.offset != nullptr && row.offset[c] != 0) {
        const BoundedDouble side = BoundedDouble::difference(extras.box->hi()[c], extras.box->lo()[c]);
        out[c] = out[c] + BoundedDouble::exact(static_cast<double>(row.offset[c])) * side;
      }
      norm2 = (c == 0) ? out[c] * out[c] : norm2 + out[c] * out[c];
    }
    // The power height: |p - x|^2 - (w_p - w_x), the weights' difference rounded once
    // and subtracted once (two more levels of the bound).
    if (extras.weights != nullptr) {
      norm2 = norm2 - BoundedDouble::difference(extras.weights[row.point], extras.weights[origin]);
    }
    if (cols > d) out[d] = norm2;
  } else {
    for (int c = 0; c < d; ++c) out[c] = BoundedDouble::exact(row.dir[c]);
    if (cols > d) {
      out[d] = BoundedDouble::exact(0.0);
      if (extras.slope != nullptr) {
        for (int c = 0; c < d; ++c) {
          const BoundedDouble term = BoundedDouble::exact(extras.slope[c]) * out[c];
          out[d] = c == 0 ? term : out[d] + term;
        }
      }
    }
  }
}

namespace {

constexpr int kMaxCols = kMaxDimension + 1;
__extension__ using i128 = __int128;  // 128-bit integers are a GCC/Clang extension
__extension__ using u128 = unsigned __int128;

// Sign of the determinant of a k x k integer matrix by fraction-free (Bareiss)
// elimination. Every intermediate is a minor of the matrix, so with Hadamard's bound
// H (product of row norms) each product formed (two minors) is below H^2: in 64-bit
// integers when H < 2^30 (grids and near neighbours: almost every tie a mesh meets),
// else in 128-bit integers when H < 2^61, where nothing overflows either. Returns
// kUnknownSign when H >= 2^61.
template <class Int>
int bareiss_sign(const std::array<i128, kMaxCols * kMaxCols>& entries, int k) {
  std::array<Int, kMaxCols * kMaxCols> m;
  for (int i = 0; i < k * k; ++i) m[i] = static_cast<Int>(entries[i]);
  int sign = 1;
  Int previous = 1;
  for (int col = 0; col < k; ++col) {
    int pivot = -1;
    for (int r = col; r < k; ++r) {
      if (m[r * k + col] != 0) {
        pivot = r;
        break;
      }
    }
    if (pivot < 0) return 0;
    if (pivot != col) {
      for (int c = 0; c < k; ++c) std::swap(m[pivot * k + c], m[col * k + c]);
      sign = -sign;
    }
    for (int r = col + 1; r < k; ++r) {
      for (int c = col + 1; c < k; ++c) {
        m[r * k + c] = (m[r * k + c] * m[col * k + col] - m[r * k + col] * m[col * k + c]) / previous;
      }
      m[r * k + col] = 0;
    }
    previous = m[col * k + col];
  }
  const Int det = m[(k - 1) * k + (k - 1)];
  return det > 0 ? sign : det < 0 ? -sign : 0;
}

int sign_of_integer_determinant(const std::array<i128, kMaxCols * kMaxCols>& m, int k) {
  // Entries here are below 2^63 (the caller checks 62 bits), so their doubles carry
  // a relative error under 2^-52; 1.0001 and the +1 per row absorb it and sqrt's.
  double bound = 1;
  for (int r = 0; r < k; ++r) {
    double norm2 = 0;
    for (int c = 0; c < k; ++c) {
      const double v = static_cast<double>(m[r * k + c]);
      norm2 += v * v;
    }
    bound *= std::sqrt(norm2) * 1.0001 + 1;
  }
  if (bound < 0x1p30) return bareiss_sign<std::int64_t>(m, k);
  if (bound < 0x1p61) return bareiss_sign<i128>(m, k);
  return BoundedDouble::kUnknownSign;
}

// An integer-valued double below 2^120 as a 128-bit integer: by a 64-bit conversion
// (one instruction) when it fits, the library's 128-bit one (a call) otherwise.
inline i128 to_i128(double v) {
  return std::fabs(v) < 0x1p62 ? i128{static_cast<std::int64_t>(v)} : static_cast<i128>(v);
}

// v 2^-e, exactly, for an integer-valued result: one multiplication by a power of two
// when 2^-e is a normal double, ldexp otherwise.
inline double unscale(double v, double inverse_scale, int e) {
  return inverse_scale != 0 ? v * inverse_scale : std::ldexp(v, -e);
}

// Fixed-width integers for the determinants of scaled coordinates: stack storage,
// no allocation and no gcd per operation, unlike GMP rationals (which were 80% of a
// linspace grid's mesh time). Entries are at most 2^122 (coordinates) and 2^248
// (lifted heights, d <= 8); by Hadamard's bound on columns a 9 x 9 determinant or
// any of its minors then needs at most 8 (122 + 2) + 250 + 4 < 1,250 bits. Each
// determinant runs in the narrowest width its own entries allow (3-d linspace
// grids: 256 bits for orientations, 512 for lifted tests), since every operation
// and copy costs in proportion to the width.
template <unsigned Bits>
using FixedInt = boost::multiprecision::number<
    boost::multiprecision::cpp_int_backend<Bits, Bits, boost::multiprecision::signed_magnitude,
                                           boost::multiprecision::unchecked, void>,
    boost::multiprecision::et_off>;
using Height = FixedInt<256>;  // a lifted height: a sum of <= 8 squares below 2^244
// Largest scaled coordinate accepted for the integer path: differences then fit in
// 122 bits, their squares' sums in 248.
constexpr int kMaxScaledBits = 120;

// Per-thread scratch for one width: the gathered matrix and the minors table (kept
// between calls: constructing 2^9 fixed-width integers zeroes every limb).
template <class W>
struct FixedScratch {
  std::vector<W> matrix = std::vector<W>(kMaxCols * kMaxCols);
  std::vector<W> table = std::vector<W>(std::size_t{1} << kMaxCols);
};

// The integer types the hardware has (else a Boost.Multiprecision number).
template <class W>
constexpr bool kBuiltinInt = std::is_same_v<W, std::int64_t> || std::is_same_v<W, i128>;

template <class W>
bool is_zero_of(const W& v) {
  if constexpr (kBuiltinInt<W>) {
    return v == 0;
  } else {
    return v.is_zero();
  }
}

// The minors of an rows x cols row-major matrix m (rows <= cols) by Laplace expansion
// over column subsets, minors_table's recurrence on W: table[mask] (popcount j <=
// rows) is the determinant of the bottom j rows on the columns in mask. No division:
// every value is a minor or a partial sum of at most cols terms of one.
template <class W>
void fill_minors(const W* m, int rows, int cols, W* table) {
  table[0] = 1;
  const unsigned full = (1u << cols) - 1u;
  for (unsigned mask = 1; mask <= full; ++mask) {
    const int j = detail::kPopCounts.of[mask];
    if (j > rows) continue;
    const W* row = m + (rows - j) * cols;
    W& acc = table[mask];
    acc = 0;
    int t = 0;
    for (unsigned rest = mask; rest != 0; rest &= rest - 1, ++t) {
      const int c = __builtin_ctz(rest);
      if (is_zero_of(row[c])) continue;
      const W& minor = table[mask ^ (1u << c)];
      if (is_zero_of(minor)) continue;
      if (t % 2 == 0) {
        acc += row[c] * minor;
      } else {
        acc -= row[c] * minor;
      }
    }
  }
}

// Sign of det(m) (k x k, row-major, set by entry(i, j, out)) by Laplace expansion
// over column subsets (minors_table's recurrence on W): no division, so every
// intermediate is a minor or a partial sum of at most k terms of one, all within the
// Hadamard bound the caller checked against W's width.
template <class W, class Entry>
int sign_of_fixed_determinant(int k, Entry&& entry) {
  thread_local FixedScratch<W> scratch;
  W* m = scratch.matrix.data();
  W* table = scratch.table.data();
  for (int i = 0; i < k; ++i) {
    for (int j = 0; j < k; ++j) entry(i, j, m[i * k + j]);
  }
  fill_minors(m, k, k, table);
  return table[(1u << k) - 1u].sign();
}

// Exact entries of one predicate matrix. When the point set has an integer scale
// (PointSet::scale_exponent), every entry is an integer after scaling the spatial
// columns by 2^-E and the height column by 2^-2E (a direction row is scaled by its
// own power of two instead): positive factors, so every sign is unchanged. Those
// integers are kept in 128 bits when they are small (integer grids: the Bareiss
// fast path) and in fixed-width integers otherwise; only a set without a usable scale (coordinates
// spanning more than 2^120) falls back to GMP rationals.
class ExactMatrix {
 public:
  ExactMatrix(const PointSet& ps, std::uint32_t origin, std::span<const Row> rows, int cols,
              const PointExtras& extras = {})
      : ps_(&ps), extras_(extras), origin_(origin), k_(static_cast<int>(rows.size())), cols_(cols) {
    // Weighted heights (and tilted directions) are not the scaled integers' sums of squares, nor are images'
    // coordinates on the points' scale: rationals.
    scaled_ = ps.integer_bits() <= kMaxScaledBits &&
              ((extras.weights == nullptr && extras.slope == nullptr) || cols <= ps.dimension());
    std::array<Row, kMaxCols + 2> resolved;
    for (int r = 0; r < k_; ++r) {
      resolved[r] = resolve_image(rows[r], extras, ps.dimension());
      scaled_ = scaled_ && resolved[r].offset == nullptr;
    }
    for (int r = 0; r < k_ && scaled_; ++r) scaled_ = scaled_row(ps, origin, resolved[r], r);
    if (scaled_) return;
    rats_.resize(static_cast<std::size_t>(k_ * cols_));
    for (int r = 0; r < k_; ++r) exact_row(ps, origin, resolved[r], &rats_[r * cols_]);
  }

  // Sign of the determinant of the square matrix formed by `row_ids` and `col_ids`,
  // where a column id of -1 stands for the point-row indicator column.
  int sign(std::span<const int> row_ids, std::span<const int> col_ids, std::span<const Row> rows) const {
    const int k = static_cast<int>(row_ids.size());
    auto indicator = [&](int r) { return rows[r].is_point() ? 1 : 0; };
    if (scaled_) {
      bool small = true;
      for (int i = 0; i < k && small; ++i) {
        for (int j = 0; j < k; ++j) small &= col_ids[j] < 0 || bits_[row_ids[i] * cols_ + col_ids[j]] <= 62;
      }
      if (small) {
        std::array<i128, kMaxCols * kMaxCols> m;
        for (int i = 0; i < k; ++i) {
          for (int j = 0; j < k; ++j) {
            m[i * k + j] = col_ids[j] < 0 ? i128{indicator(row_ids[i])} : ints_[row_ids[i] * cols_ + col_ids[j]];
          }
        }
        const int s = sign_of_integer_determinant(m, k);
        if (s != BoundedDouble::kUnknownSign) return s;
      }
      // The narrowest width that holds every minor (Hadamard on columns; sqrt(k) < 4).
      std::array<int, kMaxCols> col_bits{};
      int bound = 4;  // partial sums of <= 9 terms
      for (int j = 0; j < k; ++j) {
        for (int i = 0; i < k; ++i) {
          col_bits[j] = std::max(col_bits[j], col_ids[j] < 0 ? 1 : bits_[row_ids[i] * cols_ + col_ids[j]]);
        }
        bound += col_bits[j] + 2;
      }
      auto entry = [&](int i, int j, auto& out) {
        const int r = row_ids[i], c = col_ids[j];
        if (c < 0) {
          out = indicator(r);
        } else if (c == ps_->dimension() && ((wide_height_ >> r) & 1u) != 0) {
          out = static_cast<std::remove_reference_t<decltype(out)>>(heights_[r]);
        } else {
          out = ints_[r * cols_ + c];
        }
      };
      if (bound < 255) return sign_of_fixed_determinant<FixedInt<256>>(k, entry);
      if (bound < 511) return sign_of_fixed_determinant<FixedInt<512>>(k, entry);
      if (bound < 1535) return sign_of_fixed_determinant<FixedInt<1536>>(k, entry);
      // Unreachable with the entry bounds above; the rationals below are always right.
      rats_.resize(static_cast<std::size_t>(k_ * cols_));
      for (int r = 0; r < k_; ++r) exact_row(*ps_, origin_, rows[r], &rats_[r * cols_]);
    }
    std::vector<mpq_class> m(static_cast<std::size_t>(k * k));
    for (int i = 0; i < k; ++i) {
      for (int j = 0; j < k; ++j) {
        m[i * k + j] = col_ids[j] < 0 ? mpq_class(indicator(row_ids[i])) : rats_[row_ids[i] * cols_ + col_ids[j]];
      }
    }
    return sgn(exact_determinant(std::move(m), k));
  }

  // The lifted determinant's sign and the signs of its derivatives in every height
  // (the symbolic perturbation's coefficients), from one table of spatial minors, for
  // a scaled matrix of k = d + 1 rows; false when the matrix is not scaled (the
  // caller then takes the general route). Writes signs[0] = sign det M, signs[1] =
  // d det / d delta_origin and signs[2 + r] = d det / d delta_r (0 for a direction row).
  // Laplace along the height column: det M = sum_r (-1)^(r+d) h_r C_r, where C_r is
  // the spatial determinant of the other rows; d/d delta_r = (-1)^(r+d) C_r and
  // d/d delta_origin = -sum_r (-1)^(r+d) [r is a point] C_r. A grid's tie needs the
  // determinant and often several coefficients (cospherical points are often coplanar
  // too): one pass instead of a separate elimination for each.
  bool lifted_signs(std::span<const Row> rows, std::array<int, kMaxCols + 2>& signs) const {
    if (!scaled_ || k_ != cols_) return false;
    const int d = cols_ - 1;
    // Every C_r and partial minor is within Hadamard's bound on the spatial columns
    // (sqrt(k) <= 3 < 2^2 per column); a product h_r C_r adds the height's bits, the
    // sum of k <= 9 of them 4 more, and the sign one.
    int bound = 5;
    int height_bits = 0;
    for (int r = 0; r < k_; ++r) height_bits = std::max(height_bits, bits_[r * cols_ + d]);
    for (int c = 0; c < d; ++c) {
      int widest = 0;
      for (int r = 0; r < k_; ++r) widest = std::max(widest, bits_[r * cols_ + c]);
      bound += widest + 2;
    }
    bound += height_bits;
    if (bound <= 62 && wide_height_ == 0) return lifted_signs_in<std::int64_t>(rows, signs);
    if (bound <= 126 && wide_height_ == 0) return lifted_signs_in<i128>(rows, signs);
    if (bound < 255) return lifted_signs_in<FixedInt<256>>(rows, signs);
    if (bound < 511) return lifted_signs_in<FixedInt<512>>(rows, signs);
    return lifted_signs_in<FixedInt<1536>>(rows, signs);
  }

 private:
  template <class W>
  static int sign_of(const W& v) {
    if constexpr (kBuiltinInt<W>) {
      return v > 0 ? 1 : v < 0 ? -1 : 0;
    } else {
      return v.sign();
    }
  }

  template <class W>
  bool lifted_signs_in(std::span<const Row> rows, std::array<int, kMaxCols + 2>& signs) const {
    const int d = cols_ - 1, k = k_;
    thread_local FixedScratch<W> scratch;
    // The transposed spatial part (d x k) and the minors of its bottom rows over
    // every subset of its columns (the matrix's rows): those with d columns are C_r.
    W* st = scratch.matrix.data();
    W* table = scratch.table.data();
    for (int r = 0; r < k; ++r) {
      for (int c = 0; c < d; ++c) st[c * k + r] = static_cast<W>(ints_[r * cols_ + c]);
    }
    const unsigned full = (1u << k) - 1u;
    fill_minors(st, d, k, table);
    W det = 0, origin = 0;
    for (int r = 0; r < k; ++r) {
      const W& cofactor = table[full ^ (1u << r)];
      const bool plus = (r + d) % 2 == 0;
      const int s = sign_of(cofactor);
      signs[2 + r] = rows[r].is_point() ? (plus ? s : -s) : 0;
      if (s == 0) continue;
      W height = static_cast<W>(ints_[r * cols_ + d]);
      if constexpr (!kBuiltinInt<W>) {
        if (((wide_height_ >> r) & 1u) != 0) height = static_cast<W>(heights_[r]);
      }
      if (plus) {
        det += height * cofactor;
      } else {
        det -= height * cofactor;
      }
      if (rows[r].is_point()) {
        if (plus) {
          origin -= cofactor;
        } else {
          origin += cofactor;
        }
      }
    }
    signs[0] = sign_of(det);
    signs[1] = sign_of(origin);
    return true;
  }

  // Row r as scaled integers (see the class comment); false when a direction row
  // spans more than kMaxScaledBits bits. Spatial entries (< 2^122) are kept in 128
  // bits; a height in 128 bits when it fits, else in 256.
  bool scaled_row(const PointSet& ps, std::uint32_t origin, const Row& row, int r) {
    const int d = ps.dimension();
    i128* out = &ints_[r * cols_];
    int* bits = &bits_[r * cols_];
    auto bits_of = [](i128 v) {
      const u128 u = v < 0 ? -static_cast<u128>(v) : static_cast<u128>(v);
      const auto high = static_cast<std::uint64_t>(u >> 64), low = static_cast<std::uint64_t>(u);
      return high != 0 ? 128 - __builtin_clzll(high) : low != 0 ? 64 - __builtin_clzll(low) : 0;
    };
    if (row.is_point()) {
      // v 2^-E is an integer below 2^120: exact as a double, and so as an i128.
      const int e = ps.scale_exponent();
      // 2^-e as a normal double, or 0 when it is not one (then ldexp scales).
      const double inverse_scale = (e > -1023 && e < 1023) ? std::ldexp(1.0, -e) : 0.0;
      const double* p = ps.point(static_cast<std::size_t>(row.point));
      const double* x = ps.point(origin);
      int widest = 0;
      if (ps.integer_bits() <= 52 && inverse_scale != 0) {
        // Small integers (grids): p - x = (k_p - k_x) 2^E with |k| < 2^52 is exact in
        // double, and so is its scaling; the result fits 64 bits.
        for (int c = 0; c < d; ++c) {
          const auto v = static_cast<std::int64_t>((p[c] - x[c]) * inverse_scale);
          out[c] = v;
          bits[c] = v == 0 ? 0 : 64 - __builtin_clzll(static_cast<std::uint64_t>(v < 0 ? -v : v));
          widest = std::max(widest, bits[c]);
        }
      } else {
        for (int c = 0; c < d; ++c) {
          out[c] = to_i128(unscale(p[c], inverse_scale, e)) - to_i128(unscale(x[c], inverse_scale, e));
          bits[c] = bits_of(out[c]);
          widest = std::max(widest, bits[c]);
        }
      }
      if (cols_ > d) {
        if (widest <= 60) {  // d <= 8 squares below 2^120 each: the sum fits
          i128 norm2 = 0;
          for (int c = 0; c < d; ++c) norm2 += out[c] * out[c];
          out[d] = norm2;
          bits[d] = bits_of(norm2);
        } else {
          Height& norm2 = heights_[r];
          norm2 = 0;
          for (int c = 0; c < d; ++c) norm2 += Height(out[c]) * Height(out[c]);
          wide_height_ |= 1u << r;
          bits[d] = static_cast<int>(boost::multiprecision::msb(norm2)) + 1;  // > 0: some |q_c| >= 2^60
        }
      }
      return true;
    }
    int lowest = std::numeric_limits<int>::max(), highest = std::numeric_limits<int>::min();
    for (int c = 0; c < d; ++c) widen_binary_span(row.dir[c], lowest, highest);
    if (highest >= lowest && highest - lowest > kMaxScaledBits) return false;
    for (int c = 0; c < d; ++c) {
      out[c] = row.dir[c] == 0 ? i128{0} : to_i128(std::ldexp(row.dir[c], -lowest));
      bits[c] = bits_of(out[c]);
    }
    if (cols_ > d) {
      out[d] = 0;
      bits[d] = 0;
    }
    return true;
  }

  void exact_row(const PointSet& ps, std::uint32_t origin, const Row& row, mpq_class* out) const {
    const int d = ps.dimension();
    if (row.is_point()) {
      const double* p = ps.point(static_cast<std::size_t>(row.point));
      const double* x = ps.point(origin);
      mpq_class norm2 = 0;
      for (int c = 0; c < d; ++c) {
        out[c] = mpq_class(p[c]) - mpq_class(x[c]);
        if (row.offset != nullptr && row.offset[c] != 0) {
          out[c] += mpq_class(row.offset[c]) * (mpq_class(extras_.box->hi()[c]) - mpq_class(extras_.box->lo()[c]));
        }
        norm2 += out[c] * out[c];
      }
      if (extras_.weights != nullptr) {
        norm2 -= mpq_class(extras_.weights[row.point]) - mpq_class(extras_.weights[origin]);
      }
      if (cols_ > d) out[d] = norm2;
    } else {
      for (int c = 0; c < d; ++c) out[c] = mpq_class(row.dir[c]);
      if (cols_ > d) {
        out[d] = 0;
        if (extras_.slope != nullptr) {
          for (int c = 0; c < d; ++c) out[d] += mpq_class(extras_.slope[c]) * out[c];
        }
      }
    }
  }

  const PointSet* ps_;
  PointExtras extras_;
  std::uint32_t origin_;
  int k_, cols_;
  bool scaled_ = false;
  std::array<i128, kMaxCols * kMaxCols> ints_;
  std::array<int, kMaxCols * kMaxCols> bits_{};
  unsigned wide_height_ = 0;  // bit r: row r's height is in heights_[r]
  std::array<Height, kMaxCols> heights_;
  mutable std::vector<mpq_class> rats_;
};

int filtered_sign(const PointSet& ps, std::uint32_t origin, std::span<const Row> rows, int k,
                  const PointExtras& extras = {}) {
  std::array<BoundedDouble, kMaxCols * kMaxCols> m;
  std::array<BoundedDouble, 1u << kMaxCols> table;
  for (int r = 0; r < k; ++r) approx_row(ps, origin, rows[r], k, &m[r * k], extras);
  minors_table(m.data(), k, k, table.data());
  return table[(1u << k) - 1u].certified_sign();
}

}  // namespace

int Predicates::spatial_sign_exact(std::uint32_t origin, std::span<const Row> rows) const {
  const int d = ps_.dimension();
  const ExactMatrix m(ps_, origin, rows.first(d), d, extras_);
  std::array<int, kMaxCols> ids;
  std::iota(ids.begin(), ids.begin() + d, 0);
  return m.sign(std::span<const int>(ids.data(), d), std::span<const int>(ids.data(), d), rows);
}

int Predicates::spatial_sign(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension(), extras_);
  return s != BoundedDouble::kUnknownSign ? s : spatial_sign_exact(origin, rows);
}

// The lifted determinant is linear in every point's height. With heights
// h_p = |p - x|^2 + delta_p - delta_x, its derivative in delta_r is the cofactor of
// row r's height entry, (-1)^(r + d) det(spatial parts of the other rows), and in
// delta_x it is minus the sum of those cofactors over point rows, i.e. minus the
// determinant with the height column replaced by the point-row indicator. The
// perturbed sign is the sign of the first non-zero derivative, taking the points in
// decreasing lexicographic order (the largest point's delta dominates).
int Predicates::lifted_sign_exact(std::uint32_t origin, std::span<const Row> rows, bool perturb) const {
  return lifted_sign_staged(origin, rows, perturb ? Stage::kPerturbed : Stage::kExact);
}

int Predicates::perturbation_sign(std::uint32_t origin, std::span<const Row> rows) const {
  return lifted_sign_staged(origin, rows, Stage::kPerturbationOnly);
}

int Predicates::lifted_sign_staged(std::uint32_t origin, std::span<const Row> rows, Stage stage) const {
  const int d = ps_.dimension();
  const int k = d + 1;
  const ExactMatrix m(ps_, origin, rows.first(k), k, extras_);
  std::array<int, kMaxCols> all;
  std::iota(all.begin(), all.begin() + k, 0);
  const std::span<const int> every(all.data(), k);
  std::array<int, kMaxCols + 2> signs{};
  const bool one_pass = m.lifted_signs(rows, signs);
  if (stage != Stage::kPerturbationOnly) {
    const int s = one_pass ? signs[0] : m.sign(every, every, rows);
    if (s != 0 || stage == Stage::kExact) return s;
  }

  // Candidates for the dominant infinitesimal: the origin (-1) and every point row.
  std::array<int, kMaxCols + 1> who{};
  int count = 0;
  who[count++] = -1;
  for (int r = 0; r < k; ++r) {
    if (rows[r].is_point()) who[count++] = r;
  }
  // Decreasing lexicographic order: of the points' ranks, or of their images' exact
  // coordinates on a torus.
  std::sort(who.begin(), who.begin() + count,
            [&](int a, int b) { return image_before(origin, b < 0 ? nullptr : &rows[b], a < 0 ? nullptr : &rows[a]); });

  for (int i = 0; i < count; ++i) {
    const int w = who[i];
    int coefficient_sign = 0;
    if (one_pass) {
      coefficient_sign = signs[w < 0 ? 1 : 2 + w];
    } else if (w < 0) {
      std::array<int, kMaxCols> cols = all;
      cols[d] = -1;  // the height column replaced by the indicator
      coefficient_sign = -m.sign(every, std::span<const int>(cols.data(), k), rows);
    } else {
      std::array<int, kMaxCols> others;
      int r = 0;
      for (int j = 0; j < k; ++j) {
        if (j != w) others[r++] = j;
      }
      coefficient_sign = m.sign(std::span<const int>(others.data(), d), std::span<const int>(all.data(), d), rows) *
                         (((w + d) % 2 == 0) ? 1 : -1);
    }
    if (coefficient_sign != 0) return coefficient_sign;
  }
  return 0;  // unreachable for the configurations documented in the header
}

int Predicates::lifted_sign(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension() + 1, extras_);
  if (s == 1 || s == -1) return s;
  return lifted_sign_exact(origin, rows, /*perturb=*/true);
}

int Predicates::lifted_sign_unperturbed(std::uint32_t origin, std::span<const Row> rows) const {
  const int s = filtered_sign(ps_, origin, rows, ps_.dimension() + 1, extras_);
  if (s != BoundedDouble::kUnknownSign) return s;
  return lifted_sign_exact(origin, rows, /*perturb=*/false);
}

int Predicates::orientation(std::span<const std::uint32_t> simplex) const {
  const int d = ps_.dimension();
  std::array<Row, kMaxCols> rows;
  for (int r = 0; r < d; ++r) rows[r] = Row::of_point(simplex[r + 1]);
  return spatial_sign(simplex[0], std::span<const Row>(rows.data(), d));
}

void Predicates::spatial_normal(std::uint32_t origin, std::span<const Row> rows, BoundedDouble* normal) const {
  const int d = ps_.dimension();
  std::array<BoundedDouble, kMaxCols * kMaxCols> m{};
  std::array<BoundedDouble, 1u << kMaxCols> table;
  for (int r = 0; r < d - 1; ++r) approx_row(ps_, origin, rows[r], d, &m[r * d], extras_);
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

bool Predicates::image_before(std::uint32_t origin, const Row* given_a, const Row* given_b) const {
  Row ra, rb;
  const Row* a = given_a == nullptr ? nullptr : &(ra = resolve_image(*given_a, extras_, ps_.dimension()));
  const Row* b = given_b == nullptr ? nullptr : &(rb = resolve_image(*given_b, extras_, ps_.dimension()));
  const std::uint32_t pa = a == nullptr ? origin : static_cast<std::uint32_t>(a->point);
  const std::uint32_t pb = b == nullptr ? origin : static_cast<std::uint32_t>(b->point);
  const std::int32_t* oa = a == nullptr ? nullptr : a->offset;
  const std::int32_t* ob = b == nullptr ? nullptr : b->offset;
  const int d = ps_.dimension();
  bool same_offset = true;
  for (int c = 0; c < d && same_offset; ++c) same_offset = (oa == nullptr ? 0 : oa[c]) == (ob == nullptr ? 0 : ob[c]);
  // Images by the same lattice vector keep their points' order.
  if (same_offset) return ps_.lex_rank(pa) < ps_.lex_rank(pb);
  // Otherwise coordinate by coordinate: p_c + k_c L_c against q_c + m_c L_c, exactly.
  for (int c = 0; c < d; ++c) {
    const int ka = oa == nullptr ? 0 : oa[c], kb = ob == nullptr ? 0 : ob[c];
    const double p = ps_.point(pa)[c], q = ps_.point(pb)[c];
    if (ka == kb) {
      if (p != q) return p < q;
      continue;
    }
    const mpq_class side = mpq_class(extras_.box->hi()[c]) - mpq_class(extras_.box->lo()[c]);
    const int s = cmp(mpq_class(p) + ka * side, mpq_class(q) + kb * side);
    if (s != 0) return s < 0;
  }
  return pa < pb;  // the same image: one point (callers never compare a point with itself)
}

int Predicates::orientation(std::span<const Image> simplex) const {
  const int d = ps_.dimension();
  // Translated so that the first vertex is its point itself (the origin).
  std::array<std::array<std::int32_t, kMaxDimension>, kMaxCols> offsets{};
  std::array<Row, kMaxCols> rows;
  for (int r = 0; r < d; ++r) {
    for (int c = 0; c < d; ++c) offsets[r][c] = simplex[r + 1].offset[c] - simplex[0].offset[c];
    rows[r] = Row::of_image(simplex[r + 1].point, offsets[r].data());
  }
  return spatial_sign(simplex[0].point, std::span<const Row>(rows.data(), d));
}

int Predicates::side_of_sphere(std::span<const Image> simplex, const Image& q) const {
  const int d = ps_.dimension();
  std::array<std::array<std::int32_t, kMaxDimension>, kMaxCols> offsets{};
  std::array<Row, kMaxCols> rows;
  for (int r = 0; r <= d; ++r) {
    const Image& v = r < d ? simplex[r + 1] : q;
    for (int c = 0; c < d; ++c) offsets[r][c] = v.offset[c] - simplex[0].offset[c];
    rows[r] = Row::of_image(v.point, offsets[r].data());
  }
  const int lifted = lifted_sign(simplex[0].point, std::span<const Row>(rows.data(), d + 1));
  return lifted * orientation(simplex);
}

}  // namespace spokemesh
