#include "spokemesh/point_set.hpp"

#include <gmpxx.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace spokemesh {

bool lex_less(const double* a, const double* b, int d) {
  for (int c = 0; c < d; ++c) {
    if (a[c] < b[c]) return true;
    if (a[c] > b[c]) return false;
  }
  return false;
}

void widen_binary_span(double v, int& lowest, int& highest) {
  if (v == 0) return;
  // frexp: v = f 2^e with 0.5 <= |f| < 1, so |v| < 2^e and v's 53-bit integer
  // mantissa f 2^53 has its lowest set bit at 2^(e - 53 + ctz).
  int e = 0;
  const double f = std::frexp(std::fabs(v), &e);
  lowest = std::min(lowest, e - 53 + __builtin_ctzll(static_cast<std::uint64_t>(std::ldexp(f, 53))));
  highest = std::max(highest, e);
}

PointSet::PointSet(int dimension, std::vector<double> coordinates) : d_(dimension), coords_(std::move(coordinates)) {}

namespace {

// Point indices in lexicographic order of their coordinates, equal points in input
// order. Sorted as (first coordinate, index) records: the first coordinate nearly
// always decides, so a comparison rarely reads the points themselves (a sort of bare
// indices reads both points at random per comparison: bench/README.md, "Tuning
// history"). Coordinates must be finite (no NaN).
std::vector<std::uint32_t> lex_order(const PointSet& ps) {
  struct Entry {
    double first;
    std::uint32_t index;
  };
  const std::size_t n = ps.size();
  const int d = ps.dimension();
  std::vector<Entry> entries(n);
  for (std::size_t i = 0; i < n; ++i) entries[i] = {ps.point(i)[0], static_cast<std::uint32_t>(i)};
  std::sort(entries.begin(), entries.end(), [&](const Entry& a, const Entry& b) {
    if (a.first != b.first) return a.first < b.first;
    const double* p = ps.point(a.index) + 1;
    const double* q = ps.point(b.index) + 1;
    if (lex_less(p, q, d - 1)) return true;
    if (lex_less(q, p, d - 1)) return false;
    return a.index < b.index;  // equal points: input order, so "first occurrence" is defined
  });
  std::vector<std::uint32_t> order(n);
  for (std::size_t k = 0; k < n; ++k) order[k] = entries[k].index;
  return order;
}

bool equal_points(const double* a, const double* b, int d) { return std::equal(a, a + d, b); }

// INVALID_ARGUMENT naming the first coordinate of points [from, to) that is not finite
// or beyond kMaxCoordinate; OK otherwise.
Status check_coordinates(const PointSet& ps, std::size_t from, std::size_t to, const std::string& source) {
  for (std::size_t i = from; i < to; ++i) {
    for (int c = 0; c < ps.dimension(); ++c) {
      const double v = ps.point(i)[c];
      if (!std::isfinite(v)) {
        return invalid_argument(source + ": point " + std::to_string(i) + ", coordinate " + std::to_string(c) +
                                " is not finite");
      }
      if (std::fabs(v) > kMaxCoordinate) {
        return invalid_argument(source + ": point " + std::to_string(i) + ", coordinate " + std::to_string(c) +
                                " has magnitude above 1e100");
      }
    }
  }
  return Status::ok();
}

// DUPLICATE_POINTS for the first two consecutive equal points of `order` (a
// lexicographic order), naming the smaller index first; OK when there are none.
Status check_distinct(const PointSet& ps, const std::vector<std::uint32_t>& order, const std::string& source) {
  for (std::size_t k = 1; k < order.size(); ++k) {
    if (equal_points(ps.point(order[k - 1]), ps.point(order[k]), ps.dimension())) {
      const auto a = std::min(order[k - 1], order[k]);
      const auto b = std::max(order[k - 1], order[k]);
      // Callers add the advice that fits them (the CLI: --merge-duplicates).
      return invalid_argument(source + ": points " + std::to_string(a) + " and " + std::to_string(b) + " are equal")
          .with_reason("DUPLICATE_POINTS");
    }
  }
  return Status::ok();
}

}  // namespace

Status PointSet::check_count(std::uint64_t n, int d, const std::string& source) {
  if (n < static_cast<std::uint64_t>(d) + 1) {
    return invalid_argument(source + ": " + std::to_string(n) + " points given; a " + std::to_string(d) +
                            "-d mesh needs at least " + std::to_string(d + 1));
  }
  if (n > 0xFFFFFFF0u) return invalid_argument(source + ": more than 2^32 - 16 points");
  return Status::ok();
}

Status PointSet::validate(const std::string& source, int max_dimension, bool check_span) {
  const std::size_t n = size();
  if (d_ < 2 || d_ > max_dimension) {
    return invalid_argument(source + ": dimension " + std::to_string(d_) + " is not supported (supported: 2.." +
                            std::to_string(max_dimension) + ")");
  }
  if (Status s = check_coordinates(*this, 0, n, source); !s.is_ok()) return s;
  if (Status count = check_count(n, d_, source); !count.is_ok()) return count;

  const std::vector<std::uint32_t> order = lex_order(*this);
  if (Status s = check_distinct(*this, order, source); !s.is_ok()) return s;
  // The common scale: the lowest set bit over all coordinates, and the highest.
  int lowest = std::numeric_limits<int>::max(), highest = std::numeric_limits<int>::min();
  for (const double v : coords_) widen_binary_span(v, lowest, highest);
  set_ranks_and_scale(order, lowest, highest);
  return check_span ? check_affine_span(source) : Status::ok();
}

Status PointSet::validate_appended(const PointSet& parent, const std::string& source) {
  const std::size_t n = size(), n_old = parent.size();
  if (parent.d_ != d_ || n_old > n || parent.rank_.size() != n_old) {
    return internal_error(source + ": validate_appended needs the validated parent set of the same dimension");
  }
  if (Status s = check_coordinates(*this, n_old, n, source); !s.is_ok()) return s;
  if (Status count = check_count(n, d_, source); !count.is_ok()) return count;
  // The new points in lexicographic order (equal ones by index), merged with the
  // parent's order; at a tie the old point (the smaller index) comes first, as in
  // validate()'s stable order, so the first equal pair found is the one it reports.
  std::vector<std::uint32_t> fresh(n - n_old);
  std::iota(fresh.begin(), fresh.end(), static_cast<std::uint32_t>(n_old));
  std::sort(fresh.begin(), fresh.end(), [&](std::uint32_t a, std::uint32_t b) {
    if (lex_less(point(a), point(b), d_)) return true;
    if (lex_less(point(b), point(a), d_)) return false;
    return a < b;
  });
  std::vector<std::uint32_t> old_order(n_old);
  for (std::size_t i = 0; i < n_old; ++i) old_order[parent.rank_[i]] = static_cast<std::uint32_t>(i);
  std::vector<std::uint32_t> order;
  order.reserve(n);
  std::merge(old_order.begin(), old_order.end(), fresh.begin(), fresh.end(), std::back_inserter(order),
             [&](std::uint32_t a, std::uint32_t b) {
               if (lex_less(point(a), point(b), d_)) return true;
               if (lex_less(point(b), point(a), d_)) return false;
               return a < b;
             });
  if (Status s = check_distinct(*this, order, source); !s.is_ok()) return s;
  int lowest = std::numeric_limits<int>::max(), highest = std::numeric_limits<int>::min();
  if (parent.integer_bits_ != kNoIntegerScale) {
    lowest = parent.scale_exponent_;
    highest = parent.scale_exponent_ + parent.integer_bits_;
  }
  for (std::size_t i = n_old * static_cast<std::size_t>(d_); i < coords_.size(); ++i) {
    widen_binary_span(coords_[i], lowest, highest);
  }
  set_ranks_and_scale(order, lowest, highest);
  return Status::ok();
}

void PointSet::set_ranks_and_scale(const std::vector<std::uint32_t>& order, int lowest, int highest) {
  rank_.assign(order.size(), 0);
  for (std::size_t k = 0; k < order.size(); ++k) rank_[order[k]] = static_cast<std::uint32_t>(k);
  if (highest >= lowest) {
    scale_exponent_ = lowest;
    integer_bits_ = highest - lowest;
  } else {
    scale_exponent_ = 0;
    integer_bits_ = kNoIntegerScale;
  }
}

// Exact rank of {p_i - p_0} by incremental row echelon over the rationals. For
// non-degenerate inputs it reaches rank d after a few points and stops; only a
// degenerate set is scanned whole, and that is an error path.
std::vector<std::uint32_t> PointSet::affine_basis() const {
  const std::size_t n = size();
  std::vector<std::uint32_t> kept;
  if (n == 0) return kept;
  kept.push_back(0);
  std::vector<std::vector<mpq_class>> basis;  // rows in echelon form
  std::vector<int> pivot_col;
  std::vector<mpq_class> v(static_cast<std::size_t>(d_));
  for (std::size_t i = 1; i < n && static_cast<int>(basis.size()) < d_; ++i) {
    for (int c = 0; c < d_; ++c) v[c] = mpq_class(point(i)[c]) - mpq_class(point(0)[c]);
    for (std::size_t b = 0; b < basis.size(); ++b) {
      const int pc = pivot_col[b];
      if (sgn(v[pc]) == 0) continue;
      const mpq_class f = v[pc] / basis[b][pc];
      for (int c = 0; c < d_; ++c) v[c] -= f * basis[b][c];
    }
    int pc = -1;
    for (int c = 0; c < d_; ++c) {
      if (sgn(v[c]) != 0) {
        pc = c;
        break;
      }
    }
    if (pc >= 0) {
      basis.push_back(v);
      pivot_col.push_back(pc);
      kept.push_back(static_cast<std::uint32_t>(i));
    }
  }
  return kept;
}

Status PointSet::check_affine_span(const std::string& source) const {
  const int rank = static_cast<int>(affine_basis().size()) - 1;
  if (rank < d_) {
    return invalid_argument(source + ": the points span only a " + std::to_string(rank) +
                            "-dimensional affine subspace of R^" + std::to_string(d_) + " (a " + std::to_string(d_) +
                            "-d mesh needs full dimension)");
  }
  return Status::ok();
}

std::vector<std::uint32_t> PointSet::merge_duplicates() {
  const std::size_t n = size();
  const std::vector<std::uint32_t> order = lex_order(*this);
  std::vector<std::uint32_t> first(n);
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint32_t i = order[k];
    // order is stable: the first of a run of equal points has the smallest index.
    first[i] = (k > 0 && equal_points(point(order[k - 1]), point(i), d_)) ? first[order[k - 1]] : i;
  }
  std::vector<std::uint32_t> new_index(n);
  std::vector<double> kept;
  kept.reserve(coords_.size());
  std::uint32_t next = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (first[i] == i) {
      new_index[i] = next++;
      kept.insert(kept.end(), point(i), point(i) + d_);
    }
  }
  std::vector<std::uint32_t> map(n);
  for (std::size_t i = 0; i < n; ++i) map[i] = new_index[first[i]];
  coords_ = std::move(kept);
  rank_.clear();
  return map;
}

}  // namespace spokemesh
