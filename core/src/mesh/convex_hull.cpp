#include "spokemesh/convex_hull.hpp"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <utility>

#include <gmpxx.h>

#include "spokemesh/locate.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {
namespace {

constexpr std::uint32_t kNone = 0xFFFFFFFFu;

// The exact sign of det[v1 - v0, ..., v(d-1) - v0, x - v0] (the filter's fallback),
// 0 when x lies on the hyperplane: orientation_of (locate.hpp) of v and x.
int exact_side(const double* c, int d, const std::uint32_t* v, std::size_t x) {
  std::array<const double*, kMaxDimension + 1> p{};
  for (int r = 0; r < d; ++r) p[static_cast<std::size_t>(r)] = c + static_cast<std::size_t>(v[r]) * d;
  p[static_cast<std::size_t>(d)] = c + x * static_cast<std::size_t>(d);
  return orientation_of(p, d);
}

// A facet's hyperplane for the filter, stored flat in 3d + 1 doubles: the cofactors n
// of the rows v_i - v0 (so that n . (x - v0) = det[v_i - v0; x - v0]), computed in
// BoundedDouble (predicates.hpp), their magnitudes, v0's coordinates, and the rounding
// depth of n . (x - v0) (the cofactors' deepest + 2 + (d - 1); -1 when a cofactor had
// no bound). filtered_side() evaluates n . (x - v0) in plain doubles with the bound
// BoundedDouble's operators would give. Invariant: it returns the exact sign of the
// determinant or kUnknownSign, never a wrong sign.
std::size_t plane_doubles(int d) { return static_cast<std::size_t>(3 * d + 1); }

void plane_of(const double* c, int d, const std::uint32_t* v, double* out) {
  const double* p0 = c + static_cast<std::size_t>(v[0]) * d;
  std::array<BoundedDouble, kMaxDimension> n;
  if (d == 3) {
    // The cross product of a = v1 - v0 and b = v2 - v0: the cofactors for d = 3.
    const double* p1 = c + static_cast<std::size_t>(v[1]) * 3;
    const double* p2 = c + static_cast<std::size_t>(v[2]) * 3;
    BoundedDouble a[3], b[3];
    for (int k = 0; k < 3; ++k) {
      a[k] = BoundedDouble::difference(p1[k], p0[k]);
      b[k] = BoundedDouble::difference(p2[k], p0[k]);
    }
    n[0] = a[1] * b[2] - a[2] * b[1];
    n[1] = a[2] * b[0] - a[0] * b[2];
    n[2] = a[0] * b[1] - a[1] * b[0];
  } else {
    std::array<BoundedDouble, kMaxDimension * kMaxDimension> m{};
    std::array<BoundedDouble, 1u << kMaxDimension> table;
    for (int r = 0; r + 1 < d; ++r) {
      const double* p = c + static_cast<std::size_t>(v[r + 1]) * d;
      for (int k = 0; k < d; ++k) m[static_cast<std::size_t>(r * d + k)] = BoundedDouble::difference(p[k], p0[k]);
    }
    minors_table(m.data(), d - 1, d, table.data());
    const unsigned all = (1u << d) - 1u;
    for (int k = 0; k < d; ++k) {
      const BoundedDouble& minor = table[all ^ (1u << k)];
      n[static_cast<std::size_t>(k)] = (d - 1 + k) % 2 == 0 ? minor : -minor;
    }
  }
  int deepest = 0;
  bool safe = true;
  for (int k = 0; k < d; ++k) {
    const BoundedDouble& nk = n[static_cast<std::size_t>(k)];
    out[k] = nk.value;
    out[d + k] = nk.magnitude;
    out[2 * d + k] = p0[k];
    deepest = std::max(deepest, nk.depth);
    safe = safe && nk.depth < BoundedDouble::kUnsafe && nk.magnitude <= DBL_MAX;
  }
  out[3 * d] = safe ? deepest + 2 + (d - 1) : -1.0;
}

// The filtered sign of x against a plane, and n . (x - v0) in double (the furthest
// point's measure). The magnitude's guard (filter::is_certifiable) also covers the
// products' underflow (predicates.hpp: fewer than 2^13 operations).
int filtered_side(const double* pl, const double* x, int d, double& value) {
  double v = 0, a = 0;
  for (int k = 0; k < d; ++k) {
    const double dx = x[k] - pl[2 * d + k];
    v += pl[k] * dx;
    a += pl[d + k] * std::fabs(dx);
  }
  value = v;
  if (pl[3 * d] < 0) return BoundedDouble::kUnknownSign;
  return filter::certified_sign(v, a, static_cast<int>(pl[3 * d]));
}

// The exact side of point x of c against the facet v with plane pl: the filter, then
// exact_side where it cannot tell; `value` is the filter's n . (x - v0).
int side_of(const double* pl, const double* c, int d, const std::uint32_t* v, std::size_t x, double& value) {
  const int s = filtered_side(pl, c + x * static_cast<std::size_t>(d), d, value);
  return s != BoundedDouble::kUnknownSign ? s : exact_side(c, d, v, x);
}

// Facets' planes, flat (plane_of's layout), indexed like the facets.
class PlaneStore {
 public:
  explicit PlaneStore(int d) : d_(d), stride_(plane_doubles(d)) {}
  std::size_t size() const { return data_.size() / stride_; }
  const double* operator[](std::size_t f) const { return data_.data() + f * stride_; }
  void push(const double* c, const std::uint32_t* v) {
    data_.resize(data_.size() + stride_);
    plane_of(c, d_, v, data_.data() + data_.size() - stride_);
  }
  void move(std::size_t to, std::size_t from) {
    std::copy_n(data_.data() + from * stride_, stride_, data_.data() + to * stride_);
  }
  void resize(std::size_t n) { data_.resize(n * stride_); }

 private:
  int d_;
  std::size_t stride_;
  std::vector<double> data_;
};

// a after b in lexicographic order (point_set.hpp's lex_less, turned round).
bool lex_greater(const double* a, const double* b, int d) { return lex_less(b, a, d); }

}  // namespace

// One build or extension: the facets with their planes and outside sets while
// Quickhull runs.
class ConvexHull::Builder {
 public:
  Builder(const double* c, int d, std::size_t n, const HullOptions& options)
      : c_(c),
        d_(d),
        n_(n),
        options_(options),
        threads_(options.threads != 0 ? options.threads : std::max(1u, std::thread::hardware_concurrency())),
        planes_(d) {}

  std::vector<Facet> facets;

  Status initial_simplex();
  // An axis-aligned box strictly inside the hull (lo < x < hi in every coordinate).
  struct Box {
    std::array<double, kMaxDimension> lo, hi;
  };
  // Assigns points [first, n) (but the excluded one, `skip`, and those in `box`) to
  // the facets.
  void assign_new_points(std::size_t first, const std::vector<std::uint32_t>& skip, const Box* box = nullptr);
  // Akl and Toussaint's throw-away, with a box so that its test is 2d comparisons: the
  // hull of the points extreme in the 3^d - 1 directions of -1, 0, 1 coordinates (of at
  // most kBoxSample evenly spaced points), and the
  // largest of a few boxes shrunk about its vertices' centroid whose corners are all
  // certified strictly beneath its facets. False where there is none (d > 4, few
  // points, flat extremes).
  bool inner_box(Box& box) const;
  static constexpr int kMaxBoxDimension = 4;
  static constexpr std::size_t kBoxAtLeast = 1024;
  static constexpr std::size_t kBoxSample = 1 << 18;  // at least; an eighth of large sets
  Status run();
  // The live facets, renumbered in creation order.
  std::vector<Facet> compacted() const;

  // The exact side of x against facet f, and its measure n . (x - v0) in double.
  int side(std::uint32_t f, std::size_t x, double& value) const {
    return side_of(planes_[f], c_, d_, facets[f].v.data(), x, value);
  }
  int side(std::uint32_t f, std::size_t x) const {
    double value;
    return side(f, x, value);
  }
  void add_planes_up_to_date() {
    for (std::size_t f = planes_.size(); f < facets.size(); ++f) planes_.push(c_, facets[f].v.data());
    outside_.resize(facets.size());
    furthest_.resize(facets.size(), kNone);
    furthest_value_.resize(facets.size(), 0.0);
  }

 private:
  const double* point(std::size_t i) const { return c_ + i * static_cast<std::size_t>(d_); }
  // Puts x in the first facet of [first, end) it lies strictly beyond; false if none.
  bool assign(std::size_t x, std::size_t first, std::size_t end);
  // Whether x (measure `value`) goes before `best` as the furthest point of a facet:
  // the larger measure, then the lexicographically larger point, then the smaller id.
  bool better(std::size_t x, double value, std::uint32_t best, double best_value) const {
    if (value != best_value) return value > best_value;
    if (lex_greater(point(x), point(best), d_)) return true;
    if (lex_greater(point(best), point(x), d_)) return false;
    return x < best;
  }
  bool further(std::size_t x, double value, std::uint32_t f) const {
    return furthest_[f] == kNone || better(x, value, furthest_[f], furthest_value_[f]);
  }
  bool stopped() const { return options_.cancel != nullptr && options_.cancel->load(std::memory_order_relaxed); }
  void add_point(std::uint32_t f);
  // Drops the dead facets, keeping the live ones' order; returns facet `keep`'s new id.
  std::size_t compact(std::size_t keep);
  static constexpr std::size_t kCompactAtLeast = 4096;
  std::size_t dead_ = 0;
  // Assigns each of xs to the first facet of [first, end) it lies strictly beyond, on
  // threads when there are many.
  void distribute(const std::vector<std::uint32_t>& xs, std::size_t first, std::size_t end);
  static constexpr std::size_t kPointsPerThread = 32768;

  const double* c_;
  int d_;
  std::size_t n_;
  HullOptions options_;
  unsigned threads_;
  PlaneStore planes_;
  std::vector<std::vector<std::uint32_t>> outside_;
  std::vector<std::uint32_t> furthest_;
  std::vector<double> furthest_value_;
  // Scratch of add_point.
  std::vector<std::uint32_t> visit_;  // visit_[f] == stamp_: tested for this point
  std::vector<char> visible_;
  std::uint32_t stamp_ = 0;
  std::vector<std::uint32_t> queue_;
  std::vector<std::pair<std::uint32_t, int>> horizon_;
  struct RidgeKey {
    std::array<std::uint32_t, kMaxDimension> v;
    std::uint32_t facet;
    int slot;
  };
  std::vector<RidgeKey> ridges_;
  std::vector<std::uint32_t> order_;
};

bool ConvexHull::Builder::assign(std::size_t x, std::size_t first, std::size_t end) {
  for (std::size_t f = first; f < end; ++f) {
    double value;
    if (side(static_cast<std::uint32_t>(f), x, value) <= 0) continue;
    outside_[f].push_back(static_cast<std::uint32_t>(x));
    if (further(x, value, static_cast<std::uint32_t>(f))) {
      furthest_[f] = static_cast<std::uint32_t>(x);
      furthest_value_[f] = value;
    }
    return true;
  }
  return false;
}

Status ConvexHull::Builder::initial_simplex() {
  const int d = d_;
  std::vector<std::uint32_t> chosen;
  auto usable = [&](std::size_t i) { return static_cast<std::int64_t>(i) != options_.exclude; };
  std::uint32_t lo = kNone, hi = kNone;
  for (std::size_t i = 0; i < n_; ++i) {
    if (!usable(i)) continue;
    if (lo == kNone || lex_greater(point(lo), point(i), d)) lo = static_cast<std::uint32_t>(i);
    if (hi == kNone || lex_greater(point(i), point(hi), d)) hi = static_cast<std::uint32_t>(i);
  }
  chosen.push_back(lo);
  if (!lex_greater(point(hi), point(lo), d)) {
    return invalid_argument(
        "points: every point is the same point: the hull is flat (0-dimensional; Qhull's "
        "QH6154 initial simplex is flat)");
  }
  chosen.push_back(hi);
  // Then the furthest point from the span of those chosen, in double (Gram-Schmidt);
  // the simplex is checked exactly below.
  std::vector<double> basis;  // orthonormal rows
  auto residual = [&](const double* x, double* r) {
    for (int k = 0; k < d; ++k) r[k] = x[k] - point(lo)[k];
    for (std::size_t b = 0; b < basis.size() / static_cast<std::size_t>(d); ++b) {
      const double* e = basis.data() + b * static_cast<std::size_t>(d);
      double dot = 0;
      for (int k = 0; k < d; ++k) dot += r[k] * e[k];
      for (int k = 0; k < d; ++k) r[k] -= dot * e[k];
    }
  };
  std::array<double, kMaxDimension> r{};
  auto add_basis = [&](std::uint32_t x) {
    residual(point(x), r.data());
    double norm = 0;
    for (int k = 0; k < d; ++k) norm += r[k] * r[k];
    norm = std::sqrt(norm);
    for (int k = 0; k < d; ++k) basis.push_back(norm > 0 ? r[k] / norm : 0.0);
  };
  add_basis(hi);
  for (int dim = 2; dim <= d; ++dim) {
    std::uint32_t best = kNone;
    double best_dist = 0;
    for (std::size_t i = 0; i < n_; ++i) {
      if (!usable(i)) continue;
      residual(point(i), r.data());
      double dist = 0;
      for (int k = 0; k < d; ++k) dist += r[k] * r[k];
      if (dist > best_dist || (best != kNone && dist == best_dist && lex_greater(point(i), point(best), d))) {
        best = static_cast<std::uint32_t>(i);
        best_dist = dist;
      }
    }
    if (best == kNone) break;
    chosen.push_back(best);
    add_basis(best);
  }
  bool full = static_cast<int>(chosen.size()) == d + 1 && exact_side(c_, d, chosen.data(), chosen[d]) != 0;
  if (!full) {
    // Exactly, in input order (rationals; only near-flat and flat sets come here).
    chosen.clear();
    std::vector<std::vector<mpq_class>> rows;
    std::vector<int> pivots;
    std::vector<mpq_class> v(static_cast<std::size_t>(d));
    for (std::size_t i = 0; i < n_ && static_cast<int>(chosen.size()) < d + 1; ++i) {
      if (!usable(i)) continue;
      if (i % 4096 == 0 && stopped()) return cancelled("convex hull cancelled");
      if (chosen.empty()) {
        chosen.push_back(static_cast<std::uint32_t>(i));
        continue;
      }
      for (int k = 0; k < d; ++k) v[k] = mpq_class(point(i)[k]) - mpq_class(point(chosen[0])[k]);
      for (std::size_t b = 0; b < rows.size(); ++b) {
        const int pc = pivots[b];
        if (sgn(v[pc]) == 0) continue;
        const mpq_class f = v[pc] / rows[b][pc];
        for (int k = 0; k < d; ++k) v[k] -= f * rows[b][k];
      }
      int pc = -1;
      for (int k = 0; k < d && pc < 0; ++k) {
        if (sgn(v[k]) != 0) pc = k;
      }
      if (pc < 0) continue;
      rows.push_back(v);
      pivots.push_back(pc);
      chosen.push_back(static_cast<std::uint32_t>(i));
    }
    if (static_cast<int>(chosen.size()) < d + 1) {
      return invalid_argument("points: all " + std::to_string(n_ - (options_.exclude >= 0 ? 1 : 0)) +
                              " points lie in a " + std::to_string(chosen.size() - 1) +
                              "-dimensional affine subspace of R^" + std::to_string(d) +
                              ": the hull is flat (Qhull's QH6154 initial simplex is flat)");
    }
  }
  // Facet i: the simplex without chosen[i], ordered so that chosen[i] is beneath it.
  facets.assign(static_cast<std::size_t>(d + 1), Facet{});
  for (int i = 0; i <= d; ++i) {
    Facet& f = facets[static_cast<std::size_t>(i)];
    int k = 0;
    for (int j = 0; j <= d; ++j) {
      if (j == i) continue;
      f.v[static_cast<std::size_t>(k)] = chosen[static_cast<std::size_t>(j)];
      f.nb[static_cast<std::size_t>(k)] = static_cast<std::uint32_t>(j);  // the facet without chosen[j]
      ++k;
    }
    if (exact_side(c_, d, f.v.data(), chosen[static_cast<std::size_t>(i)]) > 0) {
      std::swap(f.v[0], f.v[1]);
      std::swap(f.nb[0], f.nb[1]);
    }
  }
  add_planes_up_to_date();
  Box box;
  const bool boxed = inner_box(box);
  assign_new_points(0, chosen, boxed ? &box : nullptr);
  return Status::ok();
}

bool ConvexHull::Builder::inner_box(Box& box) const {
  const int d = d_;
  if (d > kMaxBoxDimension || n_ < kBoxAtLeast) return false;
  // The points extreme (at a tie the lexicographically larger) in every direction of
  // -1, 0, 1 coordinates but 0 (3^d - 1 of them: axes, diagonals of faces and of the
  // cube), and their hull.
  int count = 1;
  for (int k = 0; k < d; ++k) count *= 3;
  std::vector<std::array<signed char, kMaxDimension>> directions;
  for (int j = 0; j < count; ++j) {
    std::array<signed char, kMaxDimension> u{};
    bool zero = true;
    for (int k = 0, r = j; k < d; ++k, r /= 3) {
      u[static_cast<std::size_t>(k)] = static_cast<signed char>(r % 3 - 1);
      zero = zero && r % 3 == 1;
    }
    if (!zero) directions.push_back(u);
  }
  count = static_cast<int>(directions.size());
  const int diagonals = 1 << d;  // the box's corners, below
  std::vector<double> best(static_cast<std::size_t>(count), -std::numeric_limits<double>::infinity());
  std::vector<std::uint32_t> at(static_cast<std::size_t>(count), kNone);
  // On a sample of the points (any points' hull lies inside the hull): every point of
  // small sets, evenly spaced ones of large sets.
  const std::size_t stride = std::max<std::size_t>(1, n_ / std::max(kBoxSample, n_ / 8));
  for (std::size_t i = 0; i < n_; i += stride) {
    if (static_cast<std::int64_t>(i) == options_.exclude) continue;
    const double* x = point(i);
    for (int j = 0; j < count; ++j) {
      double dot = 0;
      for (int k = 0; k < d; ++k) dot += directions[static_cast<std::size_t>(j)][static_cast<std::size_t>(k)] * x[k];
      const std::uint32_t b = at[static_cast<std::size_t>(j)];
      if (dot > best[static_cast<std::size_t>(j)] ||
          (dot == best[static_cast<std::size_t>(j)] && lex_greater(x, point(b), d))) {
        best[static_cast<std::size_t>(j)] = dot;
        at[static_cast<std::size_t>(j)] = static_cast<std::uint32_t>(i);
      }
    }
  }
  std::sort(at.begin(), at.end());
  at.erase(std::unique(at.begin(), at.end()), at.end());
  std::vector<double> small;
  for (const std::uint32_t i : at) small.insert(small.end(), point(i), point(i) + d);
  HullOptions one;
  one.threads = 1;
  auto hull = ConvexHull::build(small, d, one);
  if (!hull.is_ok()) return false;
  PlaneStore planes(d);
  std::array<double, kMaxDimension> centre{}, lo, hi;
  lo.fill(std::numeric_limits<double>::infinity());
  hi.fill(-std::numeric_limits<double>::infinity());
  const std::vector<std::uint32_t> vertices = hull.value().vertices();
  for (const std::uint32_t v : vertices) {
    for (int k = 0; k < d; ++k) {
      const double x = small[static_cast<std::size_t>(v) * d + k];
      centre[static_cast<std::size_t>(k)] += x / static_cast<double>(vertices.size());
      lo[static_cast<std::size_t>(k)] = std::min(lo[static_cast<std::size_t>(k)], x);
      hi[static_cast<std::size_t>(k)] = std::max(hi[static_cast<std::size_t>(k)], x);
    }
  }
  for (const Facet& f : hull.value().facets_) planes.push(small.data(), f.v.data());
  // The largest of the boxes shrunk about the centre whose corners are all certified
  // strictly beneath every facet: the box is then strictly inside the hull.
  for (const double scale :
       {0.99, 0.985, 0.98, 0.975, 0.97, 0.96, 0.95, 0.93, 0.9, 0.85, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3}) {
    for (int k = 0; k < d; ++k) {
      const std::size_t j = static_cast<std::size_t>(k);
      box.lo[j] = centre[j] + scale * (lo[j] - centre[j]);
      box.hi[j] = centre[j] + scale * (hi[j] - centre[j]);
    }
    bool inside = true;
    std::array<double, kMaxDimension> corner{};
    for (int m = 0; m < diagonals && inside; ++m) {
      for (int k = 0; k < d; ++k)
        corner[static_cast<std::size_t>(k)] =
            (m >> k & 1) ? box.hi[static_cast<std::size_t>(k)] : box.lo[static_cast<std::size_t>(k)];
      for (std::size_t f = 0; f < planes.size(); ++f) {
        double value;
        if (filtered_side(planes[f], corner.data(), d, value) != -1) {
          inside = false;
          break;
        }
      }
    }
    if (inside) return true;
  }
  return false;
}

void ConvexHull::Builder::assign_new_points(std::size_t first, const std::vector<std::uint32_t>& skip, const Box* box) {
  std::vector<std::uint32_t> xs;
  xs.reserve(n_ - first);
  const int d = d_;
  auto in_box = [&](const double* x) {
    for (int k = 0; k < d; ++k) {
      if (!(x[k] > box->lo[static_cast<std::size_t>(k)] && x[k] < box->hi[static_cast<std::size_t>(k)])) return false;
    }
    return true;
  };
  for (std::size_t x = first; x < n_; ++x) {
    if (static_cast<std::int64_t>(x) == options_.exclude) continue;
    if (box != nullptr && in_box(point(x))) continue;  // strictly inside the hull
    if (std::find(skip.begin(), skip.end(), static_cast<std::uint32_t>(x)) != skip.end()) continue;
    xs.push_back(static_cast<std::uint32_t>(x));
  }
  distribute(xs, 0, facets.size());
}

void ConvexHull::Builder::distribute(const std::vector<std::uint32_t>& xs, std::size_t first, std::size_t end) {
  const unsigned threads = std::min<std::size_t>(threads_, xs.size() / kPointsPerThread);
  if (threads <= 1) {
    for (const std::uint32_t x : xs) assign(x, first, end);
    return;
  }
  // Parts of xs on threads, each into its own outside sets; then joined in part order,
  // so each set lists its points as one thread would, and the furthest by the same rule.
  struct Part {
    std::vector<std::vector<std::uint32_t>> outside;
    std::vector<std::uint32_t> furthest;
    std::vector<double> value;
  };
  std::vector<Part> parts(threads);
  auto work = [&](unsigned t) {
    Part& part = parts[t];
    part.outside.resize(end - first);
    part.furthest.assign(end - first, kNone);
    part.value.assign(end - first, 0.0);
    const std::size_t lo = xs.size() * t / threads, hi = xs.size() * (t + 1) / threads;
    for (std::size_t i = lo; i < hi; ++i) {
      const std::uint32_t x = xs[i];
      for (std::size_t f = first; f < end; ++f) {
        double value;
        if (side(static_cast<std::uint32_t>(f), x, value) <= 0) continue;
        const std::size_t at = f - first;
        part.outside[at].push_back(x);
        if (part.furthest[at] == kNone || better(x, value, part.furthest[at], part.value[at])) {
          part.furthest[at] = x;
          part.value[at] = value;
        }
        break;
      }
    }
  };
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work, t);
  work(0);
  for (std::thread& th : pool) th.join();
  for (std::size_t f = first; f < end; ++f) {
    const std::size_t j = f - first;
    std::size_t total = outside_[f].size();
    for (const Part& part : parts) total += part.outside[j].size();
    outside_[f].reserve(total);
    for (Part& part : parts) {
      outside_[f].insert(outside_[f].end(), part.outside[j].begin(), part.outside[j].end());
      std::vector<std::uint32_t>().swap(part.outside[j]);
      if (part.furthest[j] != kNone && further(part.furthest[j], part.value[j], static_cast<std::uint32_t>(f))) {
        furthest_[f] = part.furthest[j];
        furthest_value_[f] = part.value[j];
      }
    }
  }
}

void ConvexHull::Builder::add_point(std::uint32_t start) {
  const std::uint32_t p = furthest_[start];
  const std::size_t d = static_cast<std::size_t>(d_);
  // The facets p lies strictly beyond, found from `start` across ridges; the horizon
  // is each ridge between a visible facet and one that is not.
  if (++stamp_ == 0) {
    std::fill(visit_.begin(), visit_.end(), 0);
    stamp_ = 1;
  }
  visit_.resize(facets.size(), 0);
  visible_.resize(facets.size(), 0);
  queue_.assign(1, start);
  visit_[start] = stamp_;
  visible_[start] = 1;
  horizon_.clear();
  for (std::size_t q = 0; q < queue_.size(); ++q) {
    const std::uint32_t f = queue_[q];
    for (std::size_t k = 0; k < d; ++k) {
      const std::uint32_t g = facets[f].nb[k];
      if (visit_[g] != stamp_) {
        visit_[g] = stamp_;
        visible_[g] = side(g, p) > 0;
        if (visible_[g]) queue_.push_back(g);
      }
      if (!visible_[g]) horizon_.emplace_back(f, static_cast<int>(k));
    }
  }
  // A new facet on each horizon ridge: the visible facet's vertices with p in place of
  // the one across the ridge (p beyond, that vertex beneath: the orientation holds).
  const std::size_t first_new = facets.size();
  ridges_.clear();
  for (const auto& [f, k] : horizon_) {
    Facet n = facets[f];
    n.v[static_cast<std::size_t>(k)] = p;
    const std::uint32_t g = facets[f].nb[static_cast<std::size_t>(k)];
    const std::uint32_t id = static_cast<std::uint32_t>(facets.size());
    for (std::size_t j = 0; j < d; ++j) {
      if (facets[g].nb[j] == f) facets[g].nb[j] = id;
    }
    for (std::size_t j = 0; j < d; ++j) {
      if (static_cast<int>(j) == k) continue;
      n.nb[j] = kNone;
      RidgeKey key{};
      // The ridge's vertices ascending (insertion sort; at most 7), the rest 0.
      std::size_t m = 0;
      for (std::size_t i = 0; i < d && m < kMaxDimension; ++i) {
        if (i == j) continue;
        std::size_t at = m++;
        for (; at > 0 && key.v[at - 1] > n.v[i]; --at) key.v[at] = key.v[at - 1];
        key.v[at] = n.v[i];
      }
      key.facet = id;
      key.slot = static_cast<int>(j);
      ridges_.push_back(key);
    }
    facets.push_back(n);
  }
  // The new facets meet each other across the ridges through p: pair equal keys.
  order_.resize(ridges_.size());
  for (std::size_t i = 0; i < order_.size(); ++i) order_[i] = static_cast<std::uint32_t>(i);
  std::sort(order_.begin(), order_.end(),
            [&](std::uint32_t a, std::uint32_t b) { return ridges_[a].v < ridges_[b].v; });
  for (std::size_t i = 0; i + 1 < order_.size(); i += 2) {
    const RidgeKey& a = ridges_[order_[i]];
    const RidgeKey& b = ridges_[order_[i + 1]];
    facets[a.facet].nb[static_cast<std::size_t>(a.slot)] = b.facet;
    facets[b.facet].nb[static_cast<std::size_t>(b.slot)] = a.facet;
  }
  add_planes_up_to_date();
  visit_.resize(facets.size(), 0);
  visible_.resize(facets.size(), 0);
  // The visible facets' outside points go to the new facets they lie beyond, or are
  // inside the new hull.
  std::size_t waiting = 0;
  for (const std::uint32_t f : queue_) waiting += outside_[f].size();
  if (waiting < 2 * kPointsPerThread) {
    for (const std::uint32_t f : queue_) {
      facets[f].live = false;
      ++dead_;
      for (const std::uint32_t x : outside_[f]) {
        if (x != p) assign(x, first_new, facets.size());
      }
      std::vector<std::uint32_t>().swap(outside_[f]);
    }
    return;
  }
  std::vector<std::uint32_t> xs;
  xs.reserve(waiting);
  for (const std::uint32_t f : queue_) {
    facets[f].live = false;
    ++dead_;
    for (const std::uint32_t x : outside_[f]) {
      if (x != p) xs.push_back(x);
    }
    std::vector<std::uint32_t>().swap(outside_[f]);
  }
  distribute(xs, first_new, facets.size());
}

Status ConvexHull::Builder::run() {
  for (std::size_t f = 0; f < facets.size(); ++f) {
    if (!facets[f].live || outside_[f].empty()) continue;
    if (stopped()) return cancelled("convex hull cancelled");
    // Dead facets dropped once they outnumber the live ones (a surface's points are
    // nearly all vertices, and each buries a few facets): memory follows the hull.
    if (dead_ > kCompactAtLeast && dead_ > facets.size() - dead_) f = compact(f);
    add_point(static_cast<std::uint32_t>(f));
  }
  return Status::ok();
}

std::size_t ConvexHull::Builder::compact(std::size_t keep) {
  std::vector<std::uint32_t> renumber(facets.size(), kNone);
  std::size_t live = 0;
  for (std::size_t f = 0; f < facets.size(); ++f) {
    if (facets[f].live) renumber[f] = static_cast<std::uint32_t>(live++);
  }
  for (std::size_t f = 0; f < facets.size(); ++f) {
    const std::uint32_t to = renumber[f];
    if (to == kNone) continue;
    Facet& facet = facets[f];
    for (int k = 0; k < d_; ++k)
      facet.nb[static_cast<std::size_t>(k)] = renumber[facet.nb[static_cast<std::size_t>(k)]];
    facets[to] = facet;
    planes_.move(to, f);
    if (to != f) outside_[to] = std::move(outside_[f]);
    furthest_[to] = furthest_[f];
    furthest_value_[to] = furthest_value_[f];
  }
  facets.resize(live);
  planes_.resize(live);
  outside_.resize(live);
  furthest_.resize(live);
  furthest_value_.resize(live);
  visit_.assign(live, 0);
  visible_.assign(live, 0);
  stamp_ = 0;
  dead_ = 0;
  return renumber[keep];  // `keep` is live: the facet about to be processed
}

std::vector<ConvexHull::Facet> ConvexHull::Builder::compacted() const {
  std::vector<std::uint32_t> renumber(facets.size(), kNone);
  std::vector<Facet> out;
  for (std::size_t f = 0; f < facets.size(); ++f) {
    if (!facets[f].live) continue;
    renumber[f] = static_cast<std::uint32_t>(out.size());
    out.push_back(facets[f]);
  }
  for (Facet& f : out) {
    for (int k = 0; k < d_; ++k) f.nb[static_cast<std::size_t>(k)] = renumber[f.nb[static_cast<std::size_t>(k)]];
  }
  return out;
}

namespace {

Status check_input(std::span<const double> c, int d, std::size_t from) {
  if (d < 2 || d > kMaxDimension) {
    return invalid_argument("points: dimension " + std::to_string(d) + " is not supported (supported: 2.." +
                            std::to_string(kMaxDimension) + ")");
  }
  if (c.size() % static_cast<std::size_t>(d) != 0) {
    return invalid_argument("points: " + std::to_string(c.size()) + " coordinates are not rows of " +
                            std::to_string(d));
  }
  const std::size_t n = c.size() / static_cast<std::size_t>(d);
  if (Status s = PointSet::check_count(n, d, "points"); !s.is_ok()) return s;
  for (std::size_t i = from * static_cast<std::size_t>(d); i < c.size(); ++i) {
    if (!std::isfinite(c[i]) || std::fabs(c[i]) > kMaxCoordinate) {
      return invalid_argument("points[" + std::to_string(i / static_cast<std::size_t>(d)) + "][" +
                              std::to_string(i % static_cast<std::size_t>(d)) +
                              "]: " + (std::isfinite(c[i]) ? "|coordinate| above 1e100" : "not a finite number"));
    }
  }
  return Status::ok();
}

}  // namespace

Result<ConvexHull> ConvexHull::build(std::span<const double> coordinates, int d, const HullOptions& options) {
  if (Status s = check_input(coordinates, d, 0); !s.is_ok()) return s;
  const std::size_t n = coordinates.size() / static_cast<std::size_t>(d);
  if (options.exclude >= 0 && (static_cast<std::size_t>(options.exclude) >= n || n < static_cast<std::size_t>(d) + 2)) {
    return invalid_argument("QG" + std::to_string(options.exclude) + ": the viewpoint must be one of the " +
                            std::to_string(n) + " points, with d + 1 others");
  }
  Builder b(coordinates.data(), d, n, options);
  if (Status s = b.initial_simplex(); !s.is_ok()) return s;
  if (Status s = b.run(); !s.is_ok()) return s;
  ConvexHull hull;
  hull.d_ = d;
  hull.n_ = n;
  hull.facets_ = b.compacted();
  return hull;
}

Status ConvexHull::extend(std::span<const double> coordinates, const HullOptions& options) {
  if (Status s = check_input(coordinates, d_, n_); !s.is_ok()) return s;
  const std::size_t n = coordinates.size() / static_cast<std::size_t>(d_);
  if (n < n_) return invalid_argument("points: fewer than the hull's " + std::to_string(n_));
  Builder b(coordinates.data(), d_, n, options);
  b.facets = facets_;
  b.add_planes_up_to_date();
  b.assign_new_points(n_, {});
  if (Status s = b.run(); !s.is_ok()) return s;
  facets_ = b.compacted();
  n_ = n;
  return Status::ok();
}

std::vector<std::uint32_t> ConvexHull::facet_vertices() const {
  std::vector<std::uint32_t> out;
  out.reserve(facets_.size() * static_cast<std::size_t>(d_));
  for (const Facet& f : facets_) out.insert(out.end(), f.v.begin(), f.v.begin() + d_);
  return out;
}

std::vector<std::int32_t> ConvexHull::facet_neighbors() const {
  std::vector<std::int32_t> out;
  out.reserve(facets_.size() * static_cast<std::size_t>(d_));
  for (const Facet& f : facets_) {
    for (int k = 0; k < d_; ++k) out.push_back(static_cast<std::int32_t>(f.nb[static_cast<std::size_t>(k)]));
  }
  return out;
}

std::vector<double> ConvexHull::facet_equations(std::span<const double> coordinates) const {
  std::vector<double> out;
  out.reserve(facets_.size() * static_cast<std::size_t>(d_ + 1));
  const int d = d_;
  for (const Facet& f : facets_) {
    std::array<double, 3 * kMaxDimension + 1> pl;
    plane_of(coordinates.data(), d, f.v.data(), pl.data());
    // The cofactors to 1e-12 of their norm: the filter's bound says when the double ones
    // are (a sliver facet's cancel); else they are computed in rationals and rounded.
    double norm2 = 0, worst = pl[static_cast<std::size_t>(3 * d)] < 0 ? INFINITY : 0.0;
    const int depth = std::max(0, static_cast<int>(pl[static_cast<std::size_t>(3 * d)]) - 2 - (d - 1));  // a cofactor's
    for (int k = 0; k < d; ++k) {
      const double nk = pl[static_cast<std::size_t>(k)];
      norm2 += nk * nk;
      worst = std::max(worst, filter::error_bound(pl[static_cast<std::size_t>(d + k)], depth));
    }
    if (!(worst <= 1e-12 * std::sqrt(norm2))) {
      std::vector<mpq_class> rows(static_cast<std::size_t>((d - 1) * d));
      const double* p0 = coordinates.data() + static_cast<std::size_t>(f.v[0]) * d;
      for (int r = 0; r + 1 < d; ++r) {
        const double* p = coordinates.data() + static_cast<std::size_t>(f.v[static_cast<std::size_t>(r + 1)]) * d;
        for (int c = 0; c < d; ++c) rows[static_cast<std::size_t>(r * d + c)] = mpq_class(p[c]) - mpq_class(p0[c]);
      }
      for (int k = 0; k < d; ++k) {
        std::vector<mpq_class> minor;
        for (int r = 0; r + 1 < d; ++r) {
          for (int c = 0; c < d; ++c) {
            if (c != k) minor.push_back(rows[static_cast<std::size_t>(r * d + c)]);
          }
        }
        const mpq_class det = d == 1 ? mpq_class(1) : exact_determinant(std::move(minor), d - 1);
        pl[static_cast<std::size_t>(k)] = ((d - 1 + k) % 2 == 0 ? det : mpq_class(-det)).get_d();
      }
    }
    double norm = 0;
    for (int k = 0; k < d; ++k) norm += pl[static_cast<std::size_t>(k)] * pl[static_cast<std::size_t>(k)];
    norm = std::sqrt(norm);
    double offset = 0;
    for (int k = 0; k < d; ++k) {
      const double u = norm > 0 ? pl[static_cast<std::size_t>(k)] / norm : 0.0;
      out.push_back(u);
      offset -= u * pl[static_cast<std::size_t>(2 * d + k)];
    }
    out.push_back(offset);
  }
  return out;
}

int ConvexHull::side(std::span<const double> coordinates, std::size_t f, std::size_t x) const {
  std::array<double, 3 * kMaxDimension + 1> pl;
  plane_of(coordinates.data(), d_, facets_[f].v.data(), pl.data());
  double value;
  return side_of(pl.data(), coordinates.data(), d_, facets_[f].v.data(), x, value);
}

std::vector<std::uint32_t> ConvexHull::vertices() const {
  std::vector<std::uint32_t> out = facet_vertices();
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::vector<std::array<std::uint32_t, 3>> ConvexHull::coplanar(std::span<const double> coordinates,
                                                               std::int64_t exclude) const {
  const std::size_t d = static_cast<std::size_t>(d_);
  std::vector<char> is_vertex(n_, 0);
  for (const Facet& f : facets_) {
    for (std::size_t k = 0; k < d; ++k) is_vertex[f.v[k]] = 1;
  }
  PlaneStore planes(d_);
  for (const Facet& f : facets_) planes.push(coordinates.data(), f.v.data());
  std::vector<std::array<std::uint32_t, 3>> out;
  for (std::size_t x = 0; x < n_; ++x) {
    if (is_vertex[x] || static_cast<std::int64_t>(x) == exclude) continue;
    const double* px = coordinates.data() + x * d;
    // Of the facets x lies on, the one with the vertex nearest to x (an equal point's
    // own vertex), first in order at a tie.
    std::uint32_t facet = kNone, nearest = kNone;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t f = 0; f < facets_.size(); ++f) {
      double value;
      if (side_of(planes[f], coordinates.data(), d_, facets_[f].v.data(), x, value) != 0) continue;
      for (std::size_t k = 0; k < d; ++k) {
        const double* pv = coordinates.data() + static_cast<std::size_t>(facets_[f].v[k]) * d;
        double dist = 0;
        for (std::size_t c = 0; c < d; ++c) dist += (pv[c] - px[c]) * (pv[c] - px[c]);
        if (dist < best) {
          best = dist;
          facet = static_cast<std::uint32_t>(f);
          nearest = facets_[f].v[k];
        }
      }
    }
    if (facet != kNone) out.push_back({static_cast<std::uint32_t>(x), facet, nearest});
  }
  return out;
}

std::vector<std::uint32_t> ConvexHull::facet_groups(std::span<const double> coordinates) const {
  const std::size_t m = facets_.size(), d = static_cast<std::size_t>(d_);
  std::vector<std::uint32_t> parent(m);
  for (std::size_t f = 0; f < m; ++f) parent[f] = static_cast<std::uint32_t>(f);
  auto root = [&](std::uint32_t f) {
    while (parent[f] != f) f = parent[f] = parent[parent[f]];
    return f;
  };
  for (std::size_t f = 0; f < m; ++f) {
    for (std::size_t k = 0; k < d; ++k) {
      const std::uint32_t g = facets_[f].nb[k];
      if (g < f) continue;  // each ridge once
      // g's vertex that is not f's.
      std::uint32_t other = kNone;
      for (std::size_t j = 0; j < d && other == kNone; ++j) {
        const std::uint32_t v = facets_[g].v[j];
        if (std::find(facets_[f].v.begin(), facets_[f].v.begin() + d_, v) == facets_[f].v.begin() + d_) other = v;
      }
      if (other == kNone || side(coordinates, f, other) != 0) continue;
      const std::uint32_t a = root(static_cast<std::uint32_t>(f)), b = root(g);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);  // the smaller facet id roots
    }
  }
  std::vector<std::uint32_t> group(m), number(m, kNone);
  std::uint32_t next = 0;
  for (std::size_t f = 0; f < m; ++f) {
    const std::uint32_t r = root(static_cast<std::uint32_t>(f));
    if (number[r] == kNone) number[r] = next++;
    group[f] = number[r];
  }
  return group;
}

}  // namespace spokemesh
