// Where a weighted seed's star walk starts (issue 28).
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
// The programme is a few dozen constraints in d + 1 unknowns, solved by a dense
// simplex tableau with Bland's rule (written here: it runs once per seed outside its
// own cell, in the walker's thread, on data it already holds; an LP library would add
// a dependency and an allocation-heavy model for a 9-column problem).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

#include <gmpxx.h>

#include "base/invariant.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh {
namespace {

// The programme in the variables z = (u, v) >= 0 with a = (u - R) L and
// b = (v - B0) L^2: coordinates scaled by L (the candidates' largest |q|), the slope
// boxed to |a_c| / L <= R and b / L^2 <= 1 (so it is bounded), and B0 large enough that
// z = 0 is feasible (no first phase).
class StartProgramme {
 public:
  // q: rows of d scaled coordinates; h: scaled heights.
  StartProgramme(int d, const std::vector<double>& q, const std::vector<double>& h, double box)
      : d_(d), rows_(static_cast<int>(h.size()) + d + 1), cols_(d + 1 + rows_ + 1), box_(box) {
    const int points = static_cast<int>(h.size());
    offset_ = 1;
    for (int i = 0; i < points; ++i) {
      double reach = std::fabs(h[i]);
      for (int c = 0; c < d; ++c) reach += box * std::fabs(q[i * d + c]);
      offset_ = std::max(offset_, reach + 1);
    }
    t_.assign(static_cast<std::size_t>((rows_ + 1) * cols_), 0.0);
    basis_.resize(rows_);
    for (int i = 0; i < rows_; ++i) {
      double* row = &t_[static_cast<std::size_t>(i * cols_)];
      if (i < points) {
        double rhs = h[i] + offset_;
        for (int c = 0; c < d; ++c) {
          row[c] = q[i * d + c];
          rhs += box * q[i * d + c];
        }
        row[d] = 1;
        row[cols_ - 1] = rhs;
      } else if (i < points + d) {
        row[i - points] = 1;
        row[cols_ - 1] = 2 * box;
      } else {
        row[d] = 1;
        row[cols_ - 1] = 1 + offset_;
      }
      row[d + 1 + i] = 1;
      basis_[i] = d + 1 + i;
    }
    objective()[d] = -1;  // maximize v
  }

  // Runs the simplex method; false when it does not finish (it should always: the
  // programme is feasible and bounded, and Bland's rule does not cycle).
  bool solve() {
    constexpr double kEps = 1e-12;
    for (int iteration = 0; iteration < 50 * (rows_ + cols_); ++iteration) {
      int enter = -1;
      for (int j = 0; j + 1 < cols_; ++j) {
        if (objective()[j] < -kEps) {
          enter = j;
          break;
        }
      }
      if (enter < 0) return true;
      int leave = -1;
      double best = 0;
      for (int i = 0; i < rows_; ++i) {
        const double a = at(i, enter);
        if (a <= kEps) continue;
        const double ratio = at(i, cols_ - 1) / a;
        if (leave < 0 || ratio < best || (ratio == best && basis_[i] < basis_[leave])) {
          leave = i;
          best = ratio;
        }
      }
      if (leave < 0) return false;  // unbounded: impossible with the boxes
      pivot(leave, enter);
    }
    return false;
  }

  // The optimum: a (d values, in scaled units) and b.
  double slope(int c) const { return value(c) - box_; }
  double lift() const { return value(d_) - offset_; }
  bool slope_boxed() const {
    for (int c = 0; c < d_; ++c) {
      if (std::fabs(slope(c)) >= box_ * (1 - 1e-9)) return true;
    }
    return false;
  }
  // Dual value of point row i (> 0: the constraint holds the optimum).
  double dual(int i) const { return objective()[d_ + 1 + i]; }
  // Slack of point row i at the optimum.
  double slack(int i) const {
    for (int r = 0; r < rows_; ++r) {
      if (basis_[r] == d_ + 1 + i) return at(r, cols_ - 1);
    }
    return 0;
  }

 private:
  double* objective() { return &t_[static_cast<std::size_t>(rows_ * cols_)]; }
  const double* objective() const { return &t_[static_cast<std::size_t>(rows_ * cols_)]; }
  double at(int i, int j) const { return t_[static_cast<std::size_t>(i * cols_ + j)]; }
  double value(int j) const {
    for (int r = 0; r < rows_; ++r) {
      if (basis_[r] == j) return at(r, cols_ - 1);
    }
    return 0;
  }
  void pivot(int leave, int enter) {
    double* p = &t_[static_cast<std::size_t>(leave * cols_)];
    const double inv = 1 / p[enter];
    for (int j = 0; j < cols_; ++j) p[j] *= inv;
    p[enter] = 1;
    for (int i = 0; i <= rows_; ++i) {
      if (i == leave) continue;
      double* row = &t_[static_cast<std::size_t>(i * cols_)];
      const double f = row[enter];
      if (f == 0) continue;
      for (int j = 0; j < cols_; ++j) row[j] -= f * p[j];
      row[enter] = 0;
    }
    basis_[leave] = enter;
  }

  int d_, rows_, cols_;
  double box_, offset_ = 1;
  std::vector<double> t_;  // rows_ constraint rows, then the objective row
  std::vector<int> basis_;
};

}  // namespace

int StarWalker::sign_above_slope(std::uint32_t p, const double* slope) const {
  const int d = d_;
  std::array<BoundedDouble, kMaxDimension + 1> row;
  approx_row(ps_, x_, Row::of_point(p), d + 1, row.data(), extras_);
  BoundedDouble v = row[d];
  for (int c = 0; c < d; ++c) v = v - BoundedDouble::exact(slope[c]) * row[c];
  const int s = v.certified_sign();
  if (s != BoundedDouble::kUnknownSign) return s;
  ++const_cast<StarStats&>(stats_).exact_fallbacks;
  const double* pp = ps_.point(p);
  const double* x = ps_.point(x_);
  mpq_class h = -(mpq_class(extras_.weights[p]) - mpq_class(extras_.weights[x_]));
  for (int c = 0; c < d; ++c) {
    const mpq_class q = mpq_class(pp[c]) - mpq_class(x[c]);
    h += q * q - mpq_class(slope[c]) * q;
  }
  return sgn(h);
}

std::optional<std::uint32_t> StarWalker::point_not_above(const double* slope) const {
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
  return tree_.find_first(
      [&](const float* lo, const float* hi) {
        double near2 = 0;
        for (int c = 0; c < d; ++c) {
          const double gap = std::max({lo[c] - centre[c], 0.0, centre[c] - hi[c]});
          near2 += gap * gap;
        }
        return near2 <= r2;
      },
      [&](std::uint32_t p, const double* pp) {
        if (p == x_) return false;
        double near2 = 0;
        for (int c = 0; c < d; ++c) near2 += (pp[c] - centre[c]) * (pp[c] - centre[c]);
        if (near2 > r2) return false;
        return sign_above_slope(p, slope) <= 0;
      });
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
  const double* p0 = ps_.point(points[0]);
  for (int i = 1; i < k; ++i) {
    const double* p = ps_.point(points[i]);
    for (int c = 0; c < d; ++c) m[(i - 1) * d + c] = mpq_class(p[c]) - mpq_class(p0[c]);
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
    const double* p = ps_.point(face[i]);
    mpq_class h = -(mpq_class(extras_.weights[face[i]]) - mpq_class(extras_.weights[x_]));
    for (int c = 0; c < d; ++c) {
      const mpq_class q = mpq_class(p[c]) - mpq_class(x[c]);
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

Status StarWalker::power_start(bool& hidden) {
  const int d = d_;
  hidden = false;
  std::array<double, kMaxDimension> zero{};
  std::optional<std::uint32_t> below = point_not_above(zero.data());
  if (!below) return Status::ok();  // x is in its own power cell: the tangent plane
  ++stats_.start_programmes;

  // The programme's points: the candidates and every point found on or below a
  // proposed plane. Coordinates scaled by L, heights by L^2.
  ensure_candidates();
  std::vector<std::uint32_t> ids(cand_id_.begin(), cand_id_.end());
  if (std::find(ids.begin(), ids.end(), *below) == ids.end()) ids.push_back(*below);
  double scale = 0;
  for (const double v : cand_q_) scale = std::max(scale, std::fabs(v));
  {
    const double* pp = ps_.point(*below);
    const double* x = ps_.point(x_);
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
  for (int round = 0; round < 200; ++round) {
    StartProgramme lp(d, q, h, box);
    if (!lp.solve()) return internal_error("the start of a weighted seed's walk did not converge");
    const double b = lp.lift();
    constexpr double kTolerance = 1e-9;
    if (b > kTolerance) {
      std::array<double, kMaxDimension> slope{};
      for (int c = 0; c < d; ++c) slope[c] = lp.slope(c) * scale;
      below = point_not_above(slope.data());
      if (!below) {
        slope_ = slope;
        extras_.slope = slope_.data();
        predicates_.set_direction_slope(slope_.data());
        return Status::ok();
      }
      if (std::find(ids.begin(), ids.end(), *below) != ids.end()) {
        return internal_error("the start plane of weighted seed " + std::to_string(x_) +
                              " misses a point the programme holds (its power cell is too thin to place in double)");
      }
      ids.push_back(*below);
      add_row(*below);
      continue;
    }
    // The lower hull of the programme's points passes below (or through) lifted x at
    // the face whose constraints hold the optimum (positive duals): decided exactly.
    std::vector<std::uint32_t> face;
    std::vector<std::pair<double, std::uint32_t>> tight;
    double top = 0;
    for (int i = 0; i < static_cast<int>(ids.size()); ++i) top = std::max(top, lp.dual(i));
    for (int i = 0; i < static_cast<int>(ids.size()); ++i) {
      if (lp.dual(i) > top * 1e-9) {
        face.push_back(ids[i]);
      } else {
        tight.push_back({lp.slack(i), ids[i]});
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
      return internal_error("weighted seed " + std::to_string(x_) +
                            " has a power cell of no volume that only the symbolic perturbation keeps; such "
                            "seeds are not supported yet");
    }
    if (lp.slope_boxed() && box < 1e12) {
      box *= 64;  // the optimum may lie beyond the slope's box
      continue;
    }
    return internal_error("could not decide whether weighted seed " + std::to_string(x_) +
                          " is hidden (its power cell is empty or thinner than double precision resolves)");
  }
  return internal_error("the start of a weighted seed's walk did not converge");
}

}  // namespace spokemesh
