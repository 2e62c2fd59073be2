// Exact geometric predicates for Delaunay meshing in any dimension 2..8.
//
// Every predicate is a sign of a determinant whose rows are taken relative to an
// origin point x (in the star walk, the seed):
//   a point p contributes the row (p - x, |p - x|^2)   -- its lift onto the paraboloid
//   a direction w contributes (w, 0)                   -- a vector of the lifted hyperplane
// The "spatial" determinant uses only the first d columns; the "lifted" determinant
// uses all d + 1. Staging (as Shewchuk's orient3d -> orient3dadapt):
//   1. filter: the determinant in double precision, carrying a rigorous bound on its
//      rounding error (class BoundedDouble below);
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
#include <array>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include <gmpxx.h>

#include "spokemesh/point_set.hpp"

namespace spokemesh {

// The floating-point filter's one error bound and one underflow guard.
//
// A value computed in double by sums, differences and products of exact inputs has a
// rounding depth n: the most roundings any monomial of its expansion passes through.
// Then (Higham, "Accuracy and Stability of Numerical Algorithms", 3.1) the computed v
// and the exact E satisfy |v - E| <= gamma_n sum|T_k|, gamma_n = n u / (1 - n u),
// u = 2^-53, and `magnitude` a (the same computation on |inputs|, itself rounded)
// bounds sum|T_k| within the same factor. error_bound(a, n) = (n + 2) u a (1.01)
// covers gamma_n / (1 - gamma_n)^2 and the roundings of the bound itself for every
// depth the predicates reach (n < 2^20 << 1 / u).
//
// Underflow breaks the relative model: a product that lands in the subnormal range
// is off by up to 2^-1075 absolutely. The guard: every product is taken with a
// magnitude >= kUnderflowGuard = 2^-900 (smaller ones mark the value unsafe, or send
// the caller to the exact stage). A predicate performs fewer than 2^13 operations
// (8-d: 9 2^9 minors), so underflow adds at most 2^-1062 <= 2^-162 a, far inside
// the 1.01 slack (>= 2^-60 a). Overflow shows as a non-finite magnitude, which
// is_certifiable() rejects. Sums of doubles never underflow.
namespace filter {
// The unit roundoff of a floating type, half its epsilon: every bound in the core is
// stated in it (2^-53 for double; 2^-64 for x87 long double, the extended stage's).
template <class T>
inline constexpr T kUnitRoundoffOf = std::numeric_limits<T>::epsilon() / 2;
inline constexpr double kUnitRoundoff = kUnitRoundoffOf<double>;
static_assert(kUnitRoundoff == 0x1p-53);
inline constexpr double kUnderflowGuard = 0x1p-900;
// (depth + 2) u (1.01): the bound's factor per unit of magnitude.
inline constexpr double kErrorPerLevel = kUnitRoundoff * 1.01;
inline constexpr double kDepthSlack = 2;
// The pencil scan's SIMD lanes evaluate this formula per lane from these constants.
inline constexpr double relative_error(double depth) { return (depth + kDepthSlack) * kErrorPerLevel; }
inline constexpr double error_bound(double magnitude, int depth) {
  return magnitude * relative_error(static_cast<double>(depth));
}
// The magnitude lets the bound hold: no product below the guard, no overflow.
inline constexpr bool is_certifiable(double magnitude) { return magnitude >= kUnderflowGuard && magnitude <= DBL_MAX; }
inline constexpr int kUnknownSign = 2;
// +1 / -1 when the computed value's sign is certain, else kUnknownSign.
inline int certified_sign(double value, double magnitude, int depth) {
  if (!is_certifiable(magnitude)) return kUnknownSign;
  const double err = error_bound(magnitude, depth);
  if (value > err) return 1;
  if (value < -err) return -1;
  return kUnknownSign;
}
}  // namespace filter

// A double together with what certifies it: the magnitude and rounding depth of the
// filter's error bound above. Invariant: unless depth == kUnsafe, the exact result of
// the same computation on exact inputs lies within filter::error_bound(magnitude,
// depth) of value. Leaves are exact doubles (depth 0) or rounded differences
// fl(p - x) (depth 1).
//
// Trivially constructible on purpose: predicate scratch arrays are large and must not
// be zero-filled on every call. BoundedDouble{} is zero.
// Thread safety: a value type.
struct BoundedDouble {
  double value;      // computed value
  double magnitude;  // computed bound on the sum of magnitudes of the monomials
  int depth;         // rounding depth (kUnsafe: no bound)

  static constexpr int kUnsafe = 1 << 20;
  static constexpr int kUnknownSign = filter::kUnknownSign;

  static BoundedDouble exact(double x) { return {x, std::fabs(x), 0}; }
  static BoundedDouble difference(double p, double x) {
    const double v = p - x;
    return {v, std::fabs(v), 1};
  }

  // +1 / -1 when the sign of the exact value is certain, 0 when it is certainly zero
  // (all monomials vanish), kUnknownSign otherwise.
  int certified_sign() const {
    if (depth >= kUnsafe || !(magnitude <= DBL_MAX)) return kUnknownSign;
    if (magnitude == 0) return 0;
    const double err = filter::error_bound(magnitude, depth);
    if (value > err) return 1;
    if (value < -err) return -1;
    return kUnknownSign;
  }
};

inline BoundedDouble operator+(const BoundedDouble& x, const BoundedDouble& y) {
  return {x.value + y.value, x.magnitude + y.magnitude,
          std::min(std::max(x.depth, y.depth) + 1, BoundedDouble::kUnsafe)};
}
inline BoundedDouble operator-(const BoundedDouble& x, const BoundedDouble& y) {
  return {x.value - y.value, x.magnitude + y.magnitude,
          std::min(std::max(x.depth, y.depth) + 1, BoundedDouble::kUnsafe)};
}
inline BoundedDouble operator-(const BoundedDouble& x) { return {-x.value, x.magnitude, x.depth}; }
inline BoundedDouble operator*(const BoundedDouble& x, const BoundedDouble& y) {
  const double a = x.magnitude * y.magnitude;
  int n = std::min(x.depth + y.depth + 1, BoundedDouble::kUnsafe);
  // The underflow guard (a product of zero is exact and safe).
  if (a < filter::kUnderflowGuard && x.magnitude != 0 && y.magnitude != 0) n = BoundedDouble::kUnsafe;
  return {x.value * y.value, a, n};
}

// Minors by Laplace expansion memoised over column subsets: for every mask over
// `cols` columns with popcount(mask) <= rows, table[mask] = det(last popcount(mask)
// rows of the row-major rows x cols matrix m, columns in mask). O(cols 2^cols)
// operations and no division, so the BoundedDouble error bound applies. `table` holds
// 2^cols entries. With rows == cols, table[2^cols - 1] is det(m).
void minors_table(const BoundedDouble* m, int rows, int cols, BoundedDouble* table);

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
[[gnu::always_inline]] inline void minors_table_loop(const BoundedDouble* m, int rows, int cols, BoundedDouble* table) {
  table[0] = BoundedDouble{1.0, 1.0, 0};
  const unsigned full = (1u << cols) - 1u;
  for (unsigned mask = 1; mask <= full; ++mask) {
    const int j = detail::kPopCounts.of[mask];
    if (j > rows) continue;
    const BoundedDouble* row = m + (rows - j) * cols;
    unsigned rest = mask;
    int c = __builtin_ctz(rest);
    BoundedDouble acc = row[c] * table[mask ^ (1u << c)];
    rest &= rest - 1;
    for (int t = 1; rest != 0; rest &= rest - 1, ++t) {
      c = __builtin_ctz(rest);
      const BoundedDouble term = row[c] * table[mask ^ (1u << c)];
      acc = (t % 2 == 0) ? acc + term : acc - term;
    }
    table[mask] = acc;
  }
}

// minors_table for sizes known at compile time (the star walk's kernels).
template <int Rows, int Cols>
inline void minors_table_fixed(const BoundedDouble* m, BoundedDouble* table) {
  minors_table_loop(m, Rows, Cols, table);
}

// Exact determinant of a k x k rational matrix (Gaussian elimination; m is consumed).
mpq_class exact_determinant(std::vector<mpq_class> m, int k);

// One row of a predicate matrix: a point (index into the PointSet) or a direction. A
// point row may name an image of the point on a flat torus: p + offset (HI - LO) for
// the Predicates' PeriodicBox (offset: d integers, not owned; null for p itself).
struct Row {
  std::int64_t point = -1;      // >= 0: point index
  const double* dir = nullptr;  // when point < 0: d exact doubles (not owned)
  const std::int32_t* offset = nullptr;

  static Row of_point(std::uint32_t i) { return {static_cast<std::int64_t>(i), nullptr, nullptr}; }
  static Row of_image(std::uint32_t i, const std::int32_t* offset) {
    return {static_cast<std::int64_t>(i), nullptr, offset};
  }
  static Row of_direction(const double* w) { return {-1, w, nullptr}; }
  bool is_point() const { return point >= 0; }
};

class PeriodicBox;
// Images of points stored as points of their own (a periodic set's cover, periodic.hpp):
// point ids >= first stand for point[id - first] + offset[(id - first) d ..] (HI - LO),
// whatever coordinates the PointSet stores for them (those are rounded). Not owned.
struct ImageMap {
  std::uint32_t first = 0xFFFFFFFFu;
  const std::uint32_t* point = nullptr;
  const std::int32_t* offset = nullptr;
  bool is_image(std::int64_t id) const { return id >= static_cast<std::int64_t>(first); }
};

// What a point row means beyond the plain PointSet, all optional, not
// owned: power weights (one per point) and the periodic box whose lattice a row's
// offset counts in, and the images stored as points.
struct PointExtras {
  const double* weights = nullptr;
  const PeriodicBox* box = nullptr;
  // Lifts a direction row w to (w, slope . w) instead of (w, 0): d exact doubles, or
  // null. A weighted seed outside its own power cell starts its walk from the plane
  // h = slope . q below every lifted point (StarWalker's start), and its spoke
  // directions must lie in that plane. Point rows are unaffected.
  const double* slope = nullptr;
  ImageMap images{};
};

// `row` with an image stored as a point (ImageMap) named as its point and offset, so
// that every predicate computes it exactly (from the point's coordinates and the box).
// Rows already naming an offset, and directions, are returned as they are.
inline Row resolve_image(const Row& row, const PointExtras& extras, int d) {
  if (!row.is_point() || !extras.images.is_image(row.point)) return row;
  const std::size_t k = static_cast<std::size_t>(row.point) - extras.images.first;
  return Row::of_image(extras.images.point[k], extras.images.offset + k * static_cast<std::size_t>(d));
}

// The BoundedDouble entries of one predicate row relative to `origin`: (p - x, |p - x|^2) for
// a point, (w, 0) (or (w, slope . w)) for a direction; `cols` is d (spatial) or d + 1 (lifted). With
// weights, a point's height is |p - x|^2 - (w_p - w_x); with a box, an image's p is
// p + offset (HI - LO) (the origin is the point itself).
void approx_row(const PointSet& ps, std::uint32_t origin, const Row& row, int cols, BoundedDouble* out,
                const PointExtras& extras = {});

// A vertex on the flat torus: a point and the lattice offset of its image (d integers).
struct Image {
  std::uint32_t point = 0;
  std::array<std::int32_t, kMaxDimension> offset{};
};

// Exact predicates over one PointSet (which must outlive this object).
//
// Weighted points (CGAL's Regular_triangulation convention): with
// `weights` (one power weight per point, finite, |w| <= kMaxWeight; not owned, must
// outlive this object), a point's height over the origin x is |p - x|^2 - w_p + w_x,
// so the lifted determinant is the power test: side_of_sphere() tells on which side of
// the orthogonal sphere of a simplex's weighted vertices a weighted point lies (its
// power distance to the sphere's centre against the sphere's squared radius), and
// lifted_sign() its star-walk form. The symbolic perturbation is the same (heights
// perturbed by infinitesimals ordered by lexicographic rank): CGAL's
// side_of_oriented_power_sphere(..., perturb = true). Equal weights give back every
// unweighted answer. The exact stage of a weighted set works in rationals (the
// integer fast path assumes unweighted heights).
//
// Periodic sets (CGAL's Periodic_3_Delaunay_triangulation_3 convention):
// with `box`, rows may name images p + k (HI - LO) (Row::of_image), computed exactly
// (the filter bounds the rounding of HI - LO, of k times it and of the sum; the exact
// stage adds them in rationals), and the perturbation orders the points of a test by
// their images' lexicographic order, as CGAL's Perturbation_order does. Every test is
// invariant under translating all its images by one lattice vector.
class Predicates {
 public:
  // images: with `box`, the ids of `points` that stand for images (ImageMap); every
  // predicate then decides them as the exact images (a star walk on a periodic set's
  // cover). An origin is never such an id.
  explicit Predicates(const PointSet& points, std::span<const double> weights = {}, const PeriodicBox* box = nullptr,
                      ImageMap images = {})
      : ps_(points), extras_{weights.empty() ? nullptr : weights.data(), box, nullptr, images} {}

  const PointSet& points() const { return ps_; }
  // The power weights, or null for an unweighted set.
  const double* weights() const { return extras_.weights; }
  const PeriodicBox* box() const { return extras_.box; }
  // Lifts direction rows onto the plane h = slope . q (PointExtras::slope; d exact
  // doubles, not owned, or null for h = 0). For the owner's star walk only.
  void set_direction_slope(const double* slope) { extras_.slope = slope; }

  // On the torus: the orientation of d + 1 images, and the side of the perturbed
  // (power) sphere through them of image q (+1 outside, -1 inside), as orientation()
  // and side_of_sphere() below. Precondition: a box was given.
  int orientation(std::span<const Image> simplex) const;
  int side_of_sphere(std::span<const Image> simplex, const Image& q) const;

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
  void spatial_normal(std::uint32_t origin, std::span<const Row> rows, BoundedDouble* normal) const;
  // +1 if q lies outside the perturbed circumsphere of the (non-degenerate) simplex,
  // -1 if inside. Never 0 for q not a vertex of the simplex.
  int side_of_sphere(std::span<const std::uint32_t> simplex, std::uint32_t q) const;

  // The exact stages on their own (the filter is inlined by callers on hot paths).
  int spatial_sign_exact(std::uint32_t origin, std::span<const Row> rows) const;
  int lifted_sign_exact(std::uint32_t origin, std::span<const Row> rows, bool perturb) const;
  // The perturbation's part alone: the sign of the leading coefficient of the lifted
  // determinant in the infinitesimals. Its coefficients depend only on the rows'
  // spatial parts, so a caller whose matrix differs from `rows` only in the heights of
  // direction rows (a wall that misses the origin, in the cells' direct route), and
  // whose exact determinant is zero, gets its perturbed sign here.
  int perturbation_sign(std::uint32_t origin, std::span<const Row> rows) const;

 private:
  enum class Stage { kExact, kPerturbed, kPerturbationOnly };
  int lifted_sign_staged(std::uint32_t origin, std::span<const Row> rows, Stage stage) const;
  // Whether row a's point (or its image) comes before row b's in lexicographic order
  // (-1: the origin itself), exactly.
  bool image_before(std::uint32_t origin, const Row* a, const Row* b) const;
  const PointSet& ps_;
  PointExtras extras_;
};

}  // namespace spokemesh
