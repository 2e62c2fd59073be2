// Where a weighted seed's star walk starts.
//
// The spokes of StarWalker::first_simplex rotate a plane through lifted x that has
// every other lifted point above it. Unweighted, the tangent plane h = 0 is one: every
// height |q|^2 is positive. With power weights a height |q|^2 - (w_p - w_x) can be
// negative: x may lie outside its own power cell (a small particle beside a large one),
// or its cell may be empty (x is hidden: its lifted point is above the lower hull of
// the others'). A plane h = slope . q with every other lifted point strictly above it
// exists exactly when the cell of x has an interior point c (slope = 2 (c - x)).
//
// The plane is found by a small linear programme over the seed's candidates,
//   maximize b  subject to  q_p . a + b <= H_p  for the candidates p,
// the lower hull of the others' lifted points above x: b > 0 gives a plane a (every
// candidate above it by b), b < 0 a simplex of candidates (the basis) whose lifted
// plane passes below lifted x. Both are then decided exactly: a plane is accepted only
// when the k-d tree certifies, with the exact sign, that no point of the whole set is
// on or below it (a point that is joins the programme, which is solved again); a
// simplex proves x hidden when it contains x and the exact perturbed power test puts x
// outside its orthogonal sphere (more points only lower the hull). The programme only
// proposes; nothing it computes in floating point decides the star.
//
// The programme is a few dozen constraints in d + 1 unknowns, solved through its dual
// by the revised simplex method (written here: it runs once per seed outside its own
// cell, in the walker's thread, on data it already holds, in microseconds; an LP
// library would add a dependency and an allocation-heavy model for a problem of d + 1
// rows).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numeric>

#include <gmpxx.h>

#include "base/invariant.hpp"
#include "spokemesh/circumcentre.hpp"
#include "spokemesh/periodic_cover.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh {
namespace {

// Squared distances from `centre` to a k-d tree box (floats rounded outwards) and to
// a point: the balls of the start's tree queries prune with them.
double box_distance2(const float* lo, const float* hi, const double* centre, int d) {
  double near2 = 0;
  for (int c = 0; c < d; ++c) {
    const double gap = std::max({lo[c] - centre[c], 0.0, centre[c] - hi[c]});
    near2 += gap * gap;
  }
  return near2;
}
double point_distance2(const double* p, const double* centre, int d) {
  double near2 = 0;
  for (int c = 0; c < d; ++c) near2 += (p[c] - centre[c]) * (p[c] - centre[c]);
  return near2;
}

// The programme's dual, solved by the revised simplex method: d + 1 rows, so each step
// costs a pass over the columns and (d + 1)^2 for the basis. Its columns are the points
// (q_p, 1) with cost H_p, the slope's box (+-e_c, cost R: |a_c| <= R) and the lift's
// cap (e_d, cost 1: b <= 1), in coordinates scaled by L (the largest |q|) and heights
// by L^2. Minimizing sum_p l_p H_p + ... subject to sum_p l_p (q_p, 1) + ... = (0, 1),
// l >= 0, has the primal (a, b) as its dual values: the optimum's basis is the face of
// the points' lower hull above x (x = sum_p l_p p over its points), and (a, b) its plane.
// The box and the cap start the basis (x is then "above" only virtual points), so no
// first phase is needed.
class StartProgramme {
 public:
  // q: rows of d scaled coordinates; h: scaled heights (points may be appended to both
  // between solves: the basis stays feasible, so solve() goes on from it); box: R.
  void reset(int d, const std::vector<double>& q, const std::vector<double>& h, double box) {
    d_ = d;
    rows_ = d + 1;
    virtuals_ = 2 * d + 1;
    q_ = &q;
    h_ = &h;
    box_ = box;
    inverse_.assign(static_cast<std::size_t>(rows_ * rows_), 0.0);
    basis_.resize(rows_);
    value_.assign(rows_, 0.0);
    for (int k = 0; k < rows_; ++k) {
      inverse_[k * rows_ + k] = 1;
      basis_[k] = k < d ? k : 2 * d;  // +e_c, then the cap e_d
    }
    value_[d] = 1;  // the cap holds the whole unit: b <= 1 binds
    dual_.assign(rows_, 0.0);
  }

  // Runs the method; false when it does not finish (it should: the programme is
  // feasible and bounded, and after a while Bland's rule, which cannot cycle, picks).
  // careful: Bland's rule from the start, and B^-1 and the values computed afresh from
  // the basis at every step, so that rounding drift in the updated inverse cannot make
  // the rule cycle (integer weights on a grid, all ties, did: a seed's start failed).
  bool solve(bool careful = false) {
    constexpr double kEps = 1e-12;
    const int points = static_cast<int>(h_->size());
    const int columns = virtuals_ + points;
    std::array<double, kMaxDimension + 1> a, u;
    for (int iteration = 0; iteration < 20 * (columns + rows_); ++iteration) {
      if (careful && !refactor()) return false;
      // y = c_B B^-1: the plane (a, b).
      std::fill(dual_.begin(), dual_.end(), 0.0);
      for (int k = 0; k < rows_; ++k) {
        const double c = cost(basis_[k]);
        for (int r = 0; r < rows_; ++r) dual_[r] += c * inverse_[k * rows_ + r];
      }
      const bool bland = careful || iteration >= 64;
      int enter = -1;
      double best = 0;
      auto consider = [&](int j, double r, double scale) {
        if (r >= -kEps * scale) return false;
        if (enter < 0 || r < best) {
          enter = j;
          best = r;
        }
        return bland;  // Bland's rule takes the first
      };
      bool taken = false;
      for (int c = 0; c < d_ && !taken; ++c) taken = consider(c, box_ - dual_[c], box_ + std::fabs(dual_[c]));
      for (int c = 0; c < d_ && !taken; ++c) taken = consider(d_ + c, box_ + dual_[c], box_ + std::fabs(dual_[c]));
      if (!taken) taken = consider(2 * d_, 1 - dual_[d_], 1 + std::fabs(dual_[d_]));
      const double* q = q_->data();
      for (int i = 0; i < points && !taken; ++i) {
        double r = (*h_)[i] - dual_[d_], scale = std::fabs((*h_)[i]) + std::fabs(dual_[d_]);
        for (int c = 0; c < d_; ++c) {
          const double t = dual_[c] * q[i * d_ + c];
          r -= t;
          scale += std::fabs(t);
        }
        taken = consider(virtuals_ + i, r, scale);
      }
      if (enter < 0) return true;
      column(enter, a.data());
      for (int k = 0; k < rows_; ++k) {
        u[k] = 0;
        for (int r = 0; r < rows_; ++r) u[k] += inverse_[k * rows_ + r] * a[r];
      }
      int leave = -1;
      double ratio = 0;
      for (int k = 0; k < rows_; ++k) {
        if (u[k] <= kEps) continue;
        const double t = std::max(0.0, value_[k]) / u[k];
        if (leave < 0 || t < ratio || (t == ratio && basis_[k] < basis_[leave])) {
          leave = k;
          ratio = t;
        }
      }
      if (leave < 0) return false;  // unbounded: impossible with the box and the cap
      for (int k = 0; k < rows_; ++k) value_[k] -= ratio * u[k];
      value_[leave] = ratio;
      const double pivot = u[leave];
      for (int r = 0; r < rows_; ++r) inverse_[leave * rows_ + r] /= pivot;
      for (int k = 0; k < rows_; ++k) {
        if (k == leave || u[k] == 0) continue;
        for (int r = 0; r < rows_; ++r) inverse_[k * rows_ + r] -= u[k] * inverse_[leave * rows_ + r];
      }
      basis_[leave] = enter;
    }
    return false;
  }

  // B^-1 and the basic values (B^-1 e_d) from the basis, by Gauss-Jordan elimination
  // with partial pivoting; false when B is singular to working precision.
  bool refactor() {
    const int r = rows_;
    std::array<double, (kMaxDimension + 1) * 2 * (kMaxDimension + 1)> m{};
    std::array<double, kMaxDimension + 1> a;
    const int w = 2 * r;
    for (int k = 0; k < r; ++k) {  // B's column k is basis_[k]'s column
      column(basis_[k], a.data());
      for (int i = 0; i < r; ++i) m[i * w + k] = a[i];
      m[k * w + r + k] = 1;
    }
    for (int c = 0; c < r; ++c) {
      int pivot = c;
      for (int i = c + 1; i < r; ++i) {
        if (std::fabs(m[i * w + c]) > std::fabs(m[pivot * w + c])) pivot = i;
      }
      if (!(std::fabs(m[pivot * w + c]) > 1e-300)) return false;
      if (pivot != c) {
        for (int j = 0; j < w; ++j) std::swap(m[c * w + j], m[pivot * w + j]);
      }
      const double inv = 1 / m[c * w + c];
      for (int j = 0; j < w; ++j) m[c * w + j] *= inv;
      for (int i = 0; i < r; ++i) {
        if (i == c || m[i * w + c] == 0) continue;
        const double f = m[i * w + c];
        for (int j = 0; j < w; ++j) m[i * w + j] -= f * m[c * w + j];
      }
    }
    for (int k = 0; k < r; ++k) {
      for (int j = 0; j < r; ++j) inverse_[k * r + j] = m[k * w + r + j];
      value_[k] = std::max(0.0, inverse_[k * r + d_]);
    }
    return true;
  }

  // The optimum: a (d values, in scaled units) and b.
  double slope(int c) const { return dual_[c]; }
  double lift() const { return dual_[d_]; }
  bool slope_boxed() const {
    for (int k = 0; k < rows_; ++k) {
      if (basis_[k] < 2 * d_ && value_[k] > 0) return true;
    }
    return false;
  }
  // The weight of point i in the optimum's face (> 0: the face holds it).
  double weight(int i) const {
    for (int k = 0; k < rows_; ++k) {
      if (basis_[k] == virtuals_ + i) return value_[k];
    }
    return 0;
  }
  // Point i's height above the optimum's plane, H_i - a . q_i - b (scaled).
  double slack(int i) const {
    double r = (*h_)[i] - dual_[d_];
    for (int c = 0; c < d_; ++c) r -= dual_[c] * (*q_)[i * d_ + c];
    return r;
  }

 private:
  double cost(int j) const { return j < 2 * d_ ? box_ : j == 2 * d_ ? 1.0 : (*h_)[j - virtuals_]; }
  void column(int j, double* a) const {
    std::fill(a, a + rows_, 0.0);
    if (j < d_) {
      a[j] = 1;
    } else if (j < 2 * d_) {
      a[j - d_] = -1;
    } else if (j == 2 * d_) {
      a[d_] = 1;
    } else {
      const int i = j - virtuals_;
      for (int c = 0; c < d_; ++c) a[c] = (*q_)[i * d_ + c];
      a[d_] = 1;
    }
  }

  int d_ = 0, rows_ = 0, virtuals_ = 0;
  const std::vector<double>* q_ = nullptr;
  const std::vector<double>* h_ = nullptr;
  double box_ = 0;
  std::vector<double> inverse_;  // B^-1, rows_ x rows_
  std::vector<int> basis_;       // the column of each row
  std::vector<double> value_;    // the basic variables' values
  std::vector<double> dual_;     // (a, b)
};

}  // namespace

mpq_class StarWalker::exact_coordinate(std::uint32_t id, int c) const {
  if (id < image_first_) return mpq_class(ps_.point(id)[c]);
  // An image of a periodic cover: its point plus k (HI - LO), exactly.
  const PeriodicCover& cover = *options_.cover;
  const auto cu = static_cast<std::size_t>(c);
  return mpq_class(ps_.point(cover.point_of(id))[c]) +
         mpq_class(cover.offset_of(id)[c]) * (mpq_class(cover.box().hi()[cu]) - mpq_class(cover.box().lo()[cu]));
}

int StarWalker::sign_above_slope(std::uint32_t p, const double* slope) const {
  const int d = d_;
  std::array<BoundedDouble, kMaxDimension + 1> row;
  approx_row(ps_, x_, Row::of_point(p), d + 1, row.data(), extras_);
  BoundedDouble v = row[d];
  for (int c = 0; c < d; ++c) v = v - BoundedDouble::exact(slope[c]) * row[c];
  const int s = v.certified_sign();
  if (s != BoundedDouble::kUnknownSign) return s;
  ++const_cast<StarStats&>(stats_).exact_fallbacks;
  const double* x = ps_.point(x_);
  mpq_class h = -(mpq_class(extras_.weights[p]) - mpq_class(extras_.weights[x_]));
  for (int c = 0; c < d; ++c) {
    const mpq_class q = exact_coordinate(p, c) - mpq_class(x[c]);
    h += q * q - mpq_class(slope[c]) * q;
  }
  return sgn(h);
}

std::size_t StarWalker::points_not_above(const double* slope, std::uint32_t* out, std::size_t most) const {
  // On or below the plane: |q|^2 - (w_p - w_x) <= slope . q, i.e.
  // |q - slope / 2|^2 <= |slope / 2|^2 + w_p - w_x <= |slope / 2|^2 + weight_excess_:
  // a ball about x + slope / 2, enlarged for the rounding of its centre.
  const int d = d_;
  const double* x = ps_.point(x_);
  std::array<double, kMaxDimension> centre{};
  double half2 = 0, c_max = 0;
  for (int c = 0; c < d; ++c) {
    const double half = slope[c] / 2;  // exact (a halving)
    half2 += half * half;
    centre[c] = x[c] + half;
    c_max = std::max(c_max, std::fabs(centre[c]));
  }
  const double r = std::sqrt(half2 + weight_excess_) * (1 + 1e-12) + c_max * 4 * filter::kUnitRoundoff * d;
  const double r2 = r * r * (1 + 1e-9);
  std::size_t found = 0;
  tree_.find_first([&](const float* lo, const float* hi) { return box_distance2(lo, hi, centre.data(), d) <= r2; },
                   [&](std::uint32_t p, const double* pp) {
                     // (An image's stored coordinates are not its position: the exact test decides it.)
                     if (p == x_ || (p < image_first_ && point_distance2(pp, centre.data(), d) > r2) ||
                         sign_above_slope(p, slope) > 0) {
                       return false;
                     }
                     out[found++] = p;
                     return found == most;
                   });
  return found;
}

namespace {

// Gaussian elimination of a rows x cols rational matrix in place; returns its rank and
// leaves it in row echelon form with the pivot columns in `pivots`.
int echelon(std::vector<mpq_class>& m, int rows, int cols, std::vector<int>* pivots = nullptr) {
  int rank = 0;
  for (int c = 0; c < cols && rank < rows; ++c) {
    int p = rank;
    while (p < rows && sgn(m[p * cols + c]) == 0) ++p;
    if (p == rows) continue;
    for (int j = 0; j < cols; ++j) std::swap(m[p * cols + j], m[rank * cols + j]);
    for (int r = 0; r < rows; ++r) {
      if (r == rank || sgn(m[r * cols + c]) == 0) continue;
      const mpq_class f = m[r * cols + c] / m[rank * cols + c];
      for (int j = 0; j < cols; ++j) m[r * cols + j] -= f * m[rank * cols + j];
    }
    if (pivots != nullptr) pivots->push_back(c);
    ++rank;
  }
  return rank;
}

}  // namespace

int StarWalker::affine_rank(std::span<const std::uint32_t> points) const {
  const int d = d_;
  const int k = static_cast<int>(points.size());
  if (k <= 1) return 0;
  std::vector<mpq_class> m(static_cast<std::size_t>((k - 1) * d));
  for (int i = 1; i < k; ++i) {
    for (int c = 0; c < d; ++c) m[(i - 1) * d + c] = exact_coordinate(points[i], c) - exact_coordinate(points[0], c);
  }
  return echelon(m, k - 1, d);
}

int StarWalker::face_side(std::span<const std::uint32_t> face) const {
  // The barycentric coordinates l of x in the face: sum_i l_i (p_i - x) = 0 and
  // sum_i l_i = 1, solved exactly; then sum_i l_i height_i is the lifted face's height
  // above lifted x (at height 0).
  const int d = d_;
  const int k = static_cast<int>(face.size());
  if (k == 0) return 2;
  const int cols = k + 1;  // the unknowns, then the right-hand side
  std::vector<mpq_class> m(static_cast<std::size_t>((d + 1) * cols));
  std::vector<mpq_class> heights(static_cast<std::size_t>(k));
  const double* x = ps_.point(x_);
  for (int i = 0; i < k; ++i) {
    mpq_class h = -(mpq_class(extras_.weights[face[i]]) - mpq_class(extras_.weights[x_]));
    for (int c = 0; c < d; ++c) {
      const mpq_class q = exact_coordinate(face[i], c) - mpq_class(x[c]);
      m[c * cols + i] = q;
      h += q * q;
    }
    m[d * cols + i] = 1;
    heights[i] = h;
  }
  m[d * cols + k] = 1;
  std::vector<int> pivots;
  const int rank = echelon(m, d + 1, cols, &pivots);
  // Inconsistent (a pivot in the right-hand side) or not unique: x is not a single
  // combination of the face's points.
  if (rank != k || (!pivots.empty() && pivots.back() == k)) return 2;
  mpq_class height = 0;
  for (int r = 0; r < k; ++r) {
    const mpq_class l = m[r * cols + k] / m[r * cols + pivots[r]];
    if (sgn(l) < 0) return 2;  // x outside the face
    height += l * heights[pivots[r]];
  }
  return sgn(height);
}

bool StarWalker::power_sphere_empty(std::span<const std::uint32_t> simplex) const {
  // Inside the power sphere (centre c, squared radius R^2 = |c - s_0|^2 - w_s0) lie the
  // points with |p - c|^2 < R^2 + w_p <= R^2 + max w: a ball about the computed centre,
  // enlarged for its error (circumcentre()'s bound: 1e-12 of the simplex's size).
  const int d = d_;
  const std::vector<double> c = circumcentre(ps_, simplex.data(), d + 1, extras_.weights);
  const double r2 = point_distance2(ps_.point(simplex[0]), c.data(), d) - extras_.weights[simplex[0]];
  double size = 0;
  for (const std::uint32_t v : simplex) size = std::max(size, std::sqrt(point_distance2(ps_.point(v), c.data(), d)));
  // Slack for the centre's error (1e-12 of size moves R^2 by 2e-12 size^2 and each
  // distance by 1e-12 size) and for the roundings of R^2 + max w (a few units of the
  // weights' magnitudes).
  const double slack2 =
      1e-9 * size * size +
      8 * filter::kUnitRoundoff * (std::fabs(extras_.weights[simplex[0]]) + std::fabs(max_weight_) + std::fabs(r2));
  // (An image's stored coordinates lie within image_pad_ of its position, per axis.)
  const double reach = std::sqrt(std::max(0.0, r2 + max_weight_) + slack2) * (1 + 1e-9) + 1e-9 * size +
                       4 * image_pad_ * std::sqrt(static_cast<double>(d));
  const double reach2 = reach * reach;
  const std::optional<std::uint32_t> inside = tree_.find_first(
      [&](const float* lo, const float* hi) { return box_distance2(lo, hi, c.data(), d) <= reach2; },
      [&](std::uint32_t p, const double* pp) {
        if (std::find(simplex.begin(), simplex.end(), p) != simplex.end()) return false;
        return point_distance2(pp, c.data(), d) <= reach2 && predicates_.side_of_sphere(simplex, p) < 0;
      });
  return !inside.has_value();
}

bool StarWalker::star_simplex_among(const std::vector<std::uint32_t>& pool, std::uint32_t* start) const {
  const int d = d_;
  const int m = static_cast<int>(pool.size());
  if (m < d) return false;
  std::vector<int> pick(static_cast<std::size_t>(d));
  std::iota(pick.begin(), pick.end(), 0);
  std::array<std::uint32_t, kMaxDimension + 1> simplex;
  for (;;) {
    simplex[0] = x_;
    for (int k = 0; k < d; ++k) simplex[k + 1] = pool[pick[k]];
    const std::span<const std::uint32_t> s(simplex.data(), static_cast<std::size_t>(d + 1));
    if (predicates_.orientation(s) != 0 && power_sphere_empty(s)) {
      std::copy(simplex.begin() + 1, simplex.begin() + d + 1, start);
      std::sort(start, start + d);
      return true;
    }
    // The next d-subset in lexicographic order of positions.
    int k = d - 1;
    while (k >= 0 && pick[k] == m - d + k) --k;
    if (k < 0) return false;
    ++pick[k];
    for (int j = k + 1; j < d; ++j) pick[j] = pick[j - 1] + 1;
  }
}

Status StarWalker::power_start(bool& hidden, std::uint32_t* start, bool& started) {
  const int d = d_;
  hidden = false;
  started = false;
  std::array<double, kMaxDimension> zero{};
  // Points found on or below a proposed plane join the programme a few at a time
  // (fewer rounds where the nearest points say little: seeds near the hull).
  constexpr std::size_t kJoinAtOnce = 4;
  std::array<std::uint32_t, kJoinAtOnce> below;
  std::size_t below_count = points_not_above(zero.data(), below.data(), 1);
  if (below_count == 0) return Status::ok();  // x is in its own power cell: the tangent plane
  ++stats_.start_programmes;

  // The programme's points: x's nearest few (the candidates when loaded: a hidden
  // seed never needs them, so they are not loaded for it) and every point found on or
  // below a proposed plane. Coordinates scaled by L, heights by L^2.
  std::vector<std::uint32_t> ids;
  if (loaded_) {
    ids.assign(cand_id_.begin(), cand_id_.end());
  } else {
    constexpr std::size_t kNearest = 8 * (kMaxDimension + 1);
    std::array<std::uint32_t, kNearest + 1> near;
    std::array<double, kNearest + 1> near2;
    const std::size_t want = std::min<std::size_t>(8 * static_cast<std::size_t>(d + 1) + 1, ps_.size());
    const std::size_t got = tree_.knn(ps_.point(x_), want, near.data(), near2.data());
    for (std::size_t i = 0; i < got; ++i) {
      if (near[i] != x_) ids.push_back(near[i]);
    }
  }
  if (std::find(ids.begin(), ids.end(), below[0]) == ids.end()) ids.push_back(below[0]);
  double scale = 0;
  const double* x = ps_.point(x_);
  for (const std::uint32_t id : ids) {
    const double* pp = ps_.point(id);
    for (int c = 0; c < d; ++c) scale = std::max(scale, std::fabs(pp[c] - x[c]));
  }
  if (!(scale > 0)) return internal_error("a weighted seed's start has no neighbour at a positive distance");
  std::vector<double> q, h;
  auto add_row = [&](std::uint32_t id) {
    std::array<double, kMaxDimension> row;
    const Lift lift = relative_row(id, ps_.point(id), row.data());
    for (int c = 0; c < d; ++c) q.push_back(row[c] / scale);
    h.push_back(lift.height / (scale * scale));
  };
  for (const std::uint32_t id : ids) add_row(id);

  double box = 64;
  StartProgramme lp;
  lp.reset(d, q, h, box);
  for (;;) {  // ends: every round adds points, or enlarges the box (at most 5 times)
    if (!lp.solve()) {
      // Exact ties everywhere (integer weights on a grid) can make the rounded method
      // cycle. The programme's answer is only a start, checked exactly below, so it is
      // solved again from scratch on coordinates scaled otherwise (other roundings,
      // other ties), carefully; the plane found is the same one, scaled back.
      bool solved = false;
      for (const double factor : {1.3, 1.7, 2.9}) {
        scale *= factor;
        q.clear();
        h.clear();
        for (const std::uint32_t id : ids) add_row(id);
        lp.reset(d, q, h, box);
        if (lp.solve(/*careful=*/true)) {
          solved = true;
          break;
        }
      }
      if (!solved) return internal_error("the start of a weighted seed's walk did not converge");
    }
    const double b = lp.lift();
    constexpr double kTolerance = 1e-9;
    if (b > kTolerance) {
      std::array<double, kMaxDimension> slope{};
      for (int c = 0; c < d; ++c) slope[c] = lp.slope(c) * scale;
      below_count = points_not_above(slope.data(), below.data(), kJoinAtOnce);
      if (below_count == 0) {
        slope_ = slope;
        extras_.slope = slope_.data();
        predicates_.set_direction_slope(slope_.data());
        return Status::ok();
      }
      for (std::size_t k = 0; k < below_count; ++k) {
        // Each round adds a point the programme lacks (so the rounds end): one it
        // holds is below a plane the programme put above it only by rounding.
        if (std::find(ids.begin(), ids.end(), below[k]) != ids.end()) {
          return internal_error("the start plane of weighted seed " + std::to_string(x_) +
                                " misses a point the programme holds (its power cell is too thin to place in double)");
        }
        ids.push_back(below[k]);
        add_row(below[k]);
      }
      continue;
    }
    // The lower hull of the programme's points passes below (or through) lifted x at
    // the face whose constraints hold the optimum (positive duals): decided exactly.
    std::vector<std::uint32_t> face;
    std::vector<std::pair<double, std::uint32_t>> tight;
    double top = 0;
    for (int i = 0; i < static_cast<int>(ids.size()); ++i) top = std::max(top, lp.weight(i));
    for (int i = 0; i < static_cast<int>(ids.size()); ++i) {
      if (lp.weight(i) > top * 1e-9) {
        face.push_back(ids[i]);
      } else {
        tight.push_back({lp.slack(i), ids[i]});
      }
    }
    // A full simplex (the usual case) is decided by the filtered predicates: x in it
    // (closed) and outside its perturbed power sphere proves x hidden; inside, the
    // perturbed lower hull passes below x only by ties, which the rationals below sort out.
    if (face.size() == static_cast<std::size_t>(d + 1)) {
      const int o = predicates_.orientation(std::span<const std::uint32_t>(face));
      bool inside = o != 0;
      for (int k = 0; k <= d && inside; ++k) {
        std::array<std::uint32_t, kMaxDimension + 1> swapped;
        std::copy(face.begin(), face.end(), swapped.begin());
        swapped[k] = x_;
        const int sk = predicates_.orientation(std::span<const std::uint32_t>(swapped.data(), face.size()));
        inside = sk == 0 || sk == o;
      }
      if (inside && predicates_.side_of_sphere(std::span<const std::uint32_t>(face), x_) > 0) {
        ++stats_.hidden;
        hidden = true;
        return Status::ok();
      }
    }
    const int side = face_side(face);
    if (side < 0) {  // lifted x is above a lifted face of other points: hidden
      ++stats_.hidden;
      hidden = true;
      return Status::ok();
    }
    if (side == 0) {
      // Lifted x lies exactly on the face: the symbolic perturbation decides. Any
      // simplex through the face gives the perturbed face's height at x (x is a
      // combination of the face's points alone), and more points only lower the
      // perturbed hull, so "outside" proves x hidden.
      std::sort(tight.begin(), tight.end());
      std::vector<std::uint32_t> simplex = face;
      for (std::size_t k = 0; k < tight.size() && simplex.size() < static_cast<std::size_t>(d + 1); ++k) {
        simplex.push_back(tight[k].second);
        if (affine_rank(simplex) + 1 != static_cast<int>(simplex.size())) simplex.pop_back();
      }
      if (simplex.size() == static_cast<std::size_t>(d + 1) &&
          predicates_.side_of_sphere(std::span<const std::uint32_t>(simplex), x_) > 0) {
        ++stats_.hidden;
        hidden = true;
        return Status::ok();
      }
      // x may keep a cell of no volume by the perturbation alone: then no plane of
      // doubles passes below the others through lifted x, and the walk starts from a
      // simplex of x's star instead, found among x's nearest points and those on the
      // optimum's plane (the star's lifted vertices lie on planes supporting lifted x),
      // each candidate certified exactly against every point.
      // The pool: the points on the optimum's plane (to rounding) and x's nearest
      // (the programme's first points are the k-d tree's nearest, in order).
      constexpr std::size_t kMaxPool = 40;
      std::vector<std::uint32_t> pool;
      for (int i = 0; i < static_cast<int>(ids.size()) && pool.size() < kMaxPool; ++i) {
        if (std::fabs(lp.slack(i)) <= 1e-9) pool.push_back(ids[i]);
      }
      for (std::size_t i = 0; i < ids.size() && i < 3 * static_cast<std::size_t>(d + 1) && pool.size() < kMaxPool;
           ++i) {
        if (std::find(pool.begin(), pool.end(), ids[i]) == pool.end()) pool.push_back(ids[i]);
      }
      if (star_simplex_among(pool, start)) {
        started = true;
        return Status::ok();
      }
      // Wider pools of nearest points (a grid with integer weights met this: the star's
      // simplices reach past the 3 (d + 1) nearest): first all the programme's, then the
      // k-d tree's 80 nearest. Rare, and each candidate is still certified exactly.
      for (const std::size_t wanted : {kMaxPool, std::size_t{80}}) {
        std::vector<std::uint32_t> wider = pool;
        std::vector<std::uint32_t> nearest;
        if (wanted <= ids.size()) {
          nearest.assign(ids.begin(), ids.end());
        } else {
          std::vector<std::uint32_t> near(std::min<std::size_t>(wanted + 1, ps_.size()));
          std::vector<double> near2(near.size());
          near.resize(tree_.knn(ps_.point(x_), near.size(), near.data(), near2.data()));
          for (const std::uint32_t id : near) {
            if (id != x_) nearest.push_back(id);
          }
        }
        for (std::size_t i = 0; i < nearest.size() && wider.size() < wanted; ++i) {
          if (std::find(wider.begin(), wider.end(), nearest[i]) == wider.end()) wider.push_back(nearest[i]);
        }
        if (wider.size() > pool.size() && star_simplex_among(wider, start)) {
          started = true;
          return Status::ok();
        }
      }
      // No simplex of x's star among them: x is hidden unless the perturbed hull
      // passes below it elsewhere, which the pool's simplices would show. Neither was
      // found: say so rather than guess.
      return internal_error("weighted seed " + std::to_string(x_) +
                            " has a power cell of no volume that only the symbolic perturbation decides, and no "
                            "simplex of its star was found among its " +
                            std::to_string(pool.size()) + " nearest points");
    }
    if (lp.slope_boxed() && box < 1e12) {
      box *= 64;  // the optimum may lie beyond the slope's box
      lp.reset(d, q, h, box);
      continue;
    }
    return internal_error("could not decide whether weighted seed " + std::to_string(x_) +
                          " is hidden (its power cell is empty or thinner than double precision resolves)");
  }
}

}  // namespace spokemesh
