#include "cells/cell_polytope.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>

#include "base/invariant.hpp"
#include "predicates/cramer.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::detail {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

double dot(const double* a, const double* b, int d) {
  double s = 0;
  for (int c = 0; c < d; ++c) s += a[c] * b[c];
  return s;
}

double norm(const double* a, int d) { return std::sqrt(dot(a, a, d)); }

double max_abs(const double* a, int d) {
  double m = 0;
  for (int c = 0; c < d; ++c) m = std::max(m, std::abs(a[c]));
  return m;
}

// Solves rows x = rhs (rows: r x d, row-major) in rationals by Gauss-Jordan
// elimination. Returns the solution when r == d and the system is regular; with
// r == d - 1 and full rank, returns a non-zero vector of the null space instead.
std::optional<std::vector<mpq_class>> gauss_jordan(std::vector<mpq_class> a, int rows, int d,
                                                   std::vector<mpq_class> rhs) {
  std::vector<int> pivot_col;
  int row = 0;
  for (int col = 0; col < d && row < rows; ++col) {
    int p = row;
    while (p < rows && sgn(a[p * d + col]) == 0) ++p;
    if (p == rows) continue;
    if (p != row) {
      for (int c = 0; c < d; ++c) std::swap(a[row * d + c], a[p * d + c]);
      std::swap(rhs[row], rhs[p]);
    }
    const mpq_class inv = 1 / a[row * d + col];
    for (int c = 0; c < d; ++c) a[row * d + c] *= inv;
    rhs[row] *= inv;
    for (int r = 0; r < rows; ++r) {
      if (r == row || sgn(a[r * d + col]) == 0) continue;
      const mpq_class f = a[r * d + col];
      for (int c = 0; c < d; ++c) a[r * d + c] -= f * a[row * d + c];
      rhs[r] -= f * rhs[row];
    }
    pivot_col.push_back(col);
    ++row;
  }
  std::vector<mpq_class> x(static_cast<std::size_t>(d));
  if (rows == d) {
    if (row != d) return std::nullopt;
    for (int r = 0; r < d; ++r) x[pivot_col[r]] = rhs[r];
    return x;
  }
  if (row != d - 1) return std::nullopt;
  int free_col = 0;
  while (std::find(pivot_col.begin(), pivot_col.end(), free_col) != pivot_col.end()) ++free_col;
  x[free_col] = 1;
  for (int r = 0; r < row; ++r) x[pivot_col[r]] = -a[r * d + free_col];
  return x;
}

// Orders a closed walk of vertex ids so that it starts just after its last ideal
// vertex, and drops the ideal ones (an unbounded face: the path of its real vertices).
template <class IsIdeal>
std::vector<std::uint32_t> open_at_infinity(std::vector<std::uint32_t> cycle, IsIdeal is_ideal) {
  std::size_t last = cycle.size();
  for (std::size_t i = 0; i < cycle.size(); ++i) {
    if (is_ideal(cycle[i]) && !is_ideal(cycle[(i + 1) % cycle.size()])) last = i;
  }
  if (last == cycle.size()) return cycle;
  std::rotate(cycle.begin(), cycle.begin() + static_cast<std::ptrdiff_t>(last + 1), cycle.end());
  cycle.erase(std::remove_if(cycle.begin(), cycle.end(), is_ideal), cycle.end());
  return cycle;
}

}  // namespace

std::size_t CellPolytope::add_vertex() {
  const std::size_t v = size();
  x_.resize(x_.size() + d_, 0.0);
  label_.resize(label_.size() + d_, 0);
  next_.resize(next_.size() + d_, 0);
  error_.push_back(0.0);
  ideal_.push_back(-1);
  if (from_box_) radius_.push_back(0.0);
  return v;
}

int CellPolytope::position_of(std::size_t v, std::uint32_t label) const {
  for (int k = 0; k < d_; ++k) {
    if (label_[v * d_ + k] == label) return k;
  }
  return -1;
}

void CellPolytope::normal_of(std::uint32_t label, double* out) const {
  if (is_wall_label(label)) {
    const double* a = domain_->normal(label - kWallLabel0);
    std::copy(a, a + d_, out);
    return;
  }
  const double* p = point_of(label);
  const double* s = ps_.point(seed_);
  for (int c = 0; c < d_; ++c) out[c] = p[c] - s[c];
}

void CellPolytope::exact_plane(std::uint32_t label, std::vector<mpq_class>& n, mpq_class& c) const {
  n.resize(static_cast<std::size_t>(d_));
  if (is_wall_label(label)) {
    const std::size_t k = label - kWallLabel0;
    for (int i = 0; i < d_; ++i) n[i] = domain_->normal(k)[i];
    c = domain_->offset(k);
    return;
  }
  // The bisector of s and p: |x - s|^2 <= |x - p|^2, i.e. (p - s) . x <= (|p|^2 - |s|^2) / 2;
  // with weights the power bisector, |x - s|^2 - w_s <= |x - p|^2 - w_p: c loses (w_p - w_s) / 2.
  const double* p = point_of(label);
  const double* s = ps_.point(seed_);
  c = 0;
  for (int i = 0; i < d_; ++i) {
    const mpq_class pi(p[i]), si(s[i]);
    n[i] = pi - si;
    c += pi * pi - si * si;
  }
  if (weights_ != nullptr) c -= mpq_class(weights_[label]) - mpq_class(weights_[seed_]);
  c /= 2;
}

std::optional<std::vector<mpq_class>> CellPolytope::exact_vertex(std::size_t v) const {
  std::vector<mpq_class> a(static_cast<std::size_t>(d_ * d_)), rhs(static_cast<std::size_t>(d_)), n;
  for (int k = 0; k < d_; ++k) {
    exact_plane(label_[v * d_ + k], n, rhs[k]);
    for (int c = 0; c < d_; ++c) a[k * d_ + c] = n[c];
  }
  return gauss_jordan(std::move(a), d_, d_, std::move(rhs));
}

std::vector<mpq_class> CellPolytope::exact_ray(const std::uint32_t* labels, std::uint32_t away_from) const {
  // The line where the d - 1 finite planes meet, pointed into the cell across the plane
  // the ray leaves (n_away . r < 0: moving along r goes deeper into that halfspace).
  std::vector<mpq_class> a, n, rhs(static_cast<std::size_t>(d_ - 1));
  mpq_class c;
  for (int k = 0; k < d_; ++k) {
    if (labels[k] == kInfinityLabel) continue;
    exact_plane(labels[k], n, c);
    a.insert(a.end(), n.begin(), n.end());
  }
  std::vector<mpq_class> r =
      gauss_jordan(std::move(a), d_ - 1, d_, std::move(rhs)).value_or(std::vector<mpq_class>(d_));
  exact_plane(away_from, n, c);
  mpq_class s = 0;
  for (int i = 0; i < d_; ++i) s += n[i] * r[i];
  if (sgn(s) > 0) {
    for (auto& v : r) v = -v;
  }
  return r;
}

CellPolytope::CellPolytope(const PointSet& points, const Star& star, const Domain* domain, const double* weights)
    : ps_(points), domain_(domain), weights_(weights), seed_(star.seed), d_(points.dimension()) {
  const int d = d_;
  const std::size_t m = star.size();
  const double* s = ps_.point(seed_);
  x_.reserve(m * d);
  for (std::size_t i = 0; i < m; ++i) {
    const std::uint32_t* simplex = star.simplex(i);
    const std::size_t v = add_vertex();
    int k = 0;
    for (int j = 0; j <= d; ++j) {
      if (simplex[j] != seed_) label_[v * d + k++] = simplex[j];
    }
    const std::vector<double> c = circumcentre(ps_, simplex, d + 1, weights_);
    std::copy(c.begin(), c.end(), &x_[v * d]);
    double r2 = 0;
    for (int i2 = 0; i2 < d; ++i2) r2 += (c[i2] - s[i2]) * (c[i2] - s[i2]);
    // circumcentre()'s bound for power centres is against the face's size too.
    if (weights_ != nullptr) r2 = std::max(r2, face_size2(ps_, simplex, d + 1));
    const double r = std::sqrt(r2);
    // circumcentre(): within 1e-12 of the circumradius plus one ulp per coordinate.
    error_[v] = 1e-12 * r + std::sqrt(d) * 2 * filter::kUnitRoundoff * max_abs(c.data(), d);
    scale_ = std::max(scale_, r);
  }
  // Pair the vertices' edges: the edge leaving plane k of v goes to the vertex with the
  // same d - 1 other planes. A key met once is an unbounded edge (a hull facet of the
  // star), which ends at a new ideal vertex.
  struct Edge {
    std::array<std::uint32_t, kMaxDimension> key{};
    std::uint32_t vertex;
    int position;
    bool operator<(const Edge& o) const { return key != o.key ? key < o.key : vertex < o.vertex; }
  };
  auto pair_up = [&](std::size_t from, std::size_t to, [[maybe_unused]] bool open_rays) {
    std::vector<Edge> edges;
    for (std::size_t v = from; v < to; ++v) {
      for (int k = 0; k < d; ++k) {
        if (ideal_[v] >= 0 && label_[v * d + k] == kInfinityLabel) continue;
        Edge e;
        int w = 0;
        for (int j = 0; j < d; ++j) {
          if (j != k) e.key[w++] = label_[v * d + j];
        }
        for (int i = 1; i < d - 1; ++i) {  // insertion sort: d - 1 <= 7 labels
          for (int j = i; j > 0 && e.key[j - 1] > e.key[j]; --j) std::swap(e.key[j - 1], e.key[j]);
        }
        e.vertex = static_cast<std::uint32_t>(v);
        e.position = k;
        edges.push_back(e);
      }
    }
    std::stable_sort(edges.begin(), edges.end());
    for (std::size_t i = 0; i < edges.size();) {
      if (i + 1 < edges.size() && edges[i + 1].key == edges[i].key) {
        next_[edges[i].vertex * d + edges[i].position] = edges[i + 1].vertex;
        next_[edges[i + 1].vertex * d + edges[i + 1].position] = edges[i].vertex;
        i += 2;
        continue;
      }
      SPOKEMESH_INVARIANT(open_rays, "every edge at infinity joins two ideal vertices");
      const std::size_t v = edges[i].vertex;
      const int k = edges[i].position;
      const std::size_t u = add_vertex();
      for (int j = 0; j < d; ++j) label_[u * d + j] = label_[v * d + j];
      label_[u * d + k] = kInfinityLabel;
      next_[u * d + k] = static_cast<std::uint32_t>(v);
      next_[v * d + k] = static_cast<std::uint32_t>(u);
      ideal_[u] = static_cast<int>(rays_.size());
      rays_.push_back(exact_ray(&label_[u * d], label_[v * d + k]));
      double len = 0;
      for (int c = 0; c < d; ++c) len = std::max(len, std::abs(rays_.back()[c].get_d()));
      for (int c = 0; c < d; ++c) x_[u * d + c] = rays_.back()[c].get_d() / len;
      const double l2 = norm(&x_[u * d], d);
      for (int c = 0; c < d; ++c) x_[u * d + c] /= l2;
      ++i;
    }
  };
  pair_up(0, m, true);
  if (size() > m) pair_up(m, size(), false);
  if (scale_ == 0) scale_ = 1;
}

bool CellPolytope::bounded() const {
  return std::all_of(ideal_.begin(), ideal_.end(), [](int r) { return r < 0; });
}

CellPolytope::Plane CellPolytope::plane_of(std::uint32_t label) const {
  Plane pl;
  pl.label = label;
  if (is_wall_label(label)) {
    const std::size_t k = label - kWallLabel0;
    std::copy(domain_->normal(k), domain_->normal(k) + d_, pl.a.begin());
    pl.b = domain_->offset(k);
    pl.b_magnitude = std::abs(pl.b);
  } else {
    // The bisector relative to the seed s: q . (x - s) <= |q|^2 / 2 with q = p - s.
    const double* p = point_of(label);
    pl.origin = ps_.point(seed_);
    double q2 = 0;
    for (int c = 0; c < d_; ++c) {
      pl.a[c] = p[c] - pl.origin[c];
      q2 += pl.a[c] * pl.a[c];
    }
    const double excess = weights_ != nullptr ? weights_[label] - weights_[seed_] : 0.0;
    pl.b = (q2 - excess) / 2;
    pl.b_magnitude = (q2 + std::abs(excess)) / 2;
  }
  pl.a_norm = norm(pl.a.data(), d_);
  return pl;
}

double CellPolytope::plane_value(const Plane& pl, const double* x, double& rounding) const {
  double f = -pl.b, magnitude = std::abs(pl.b);
  if (pl.origin == nullptr) {
    for (int c = 0; c < d_; ++c) {
      f += pl.a[c] * x[c];
      magnitude += std::abs(pl.a[c] * x[c]);
    }
    // A dot product of d terms and an offset: 2 (d + 2) units of its magnitude.
    rounding = 2 * (d_ + 2) * filter::kUnitRoundoff * magnitude;
    return f;
  }
  for (int c = 0; c < d_; ++c) {
    const double w = x[c] - pl.origin[c];
    f += pl.a[c] * w;
    magnitude += std::abs(pl.a[c] * w);
  }
  // Besides the sum's own rounding, q = p - s and x - s are rounded (one unit of each
  // coordinate) and |q|^2 / 2 is a rounded sum: each perturbs f by at most a few units
  // of sum |q_c| |w_c| + |q|^2, which is at most 2 x magnitude (with weights, w_p - w_s
  // and its subtraction are two more roundings of b's magnitude).
  rounding = 4 * (d_ + 4) * filter::kUnitRoundoff * (magnitude + pl.b_magnitude);
  return f;
}

int CellPolytope::side(std::size_t v, const Plane& pl, const std::vector<int>& sides) const {
  if (ideal_[v] >= 0) {
    const std::vector<mpq_class>& r = rays_[ideal_[v]];
    std::vector<mpq_class> n;
    mpq_class c;
    exact_plane(pl.label, n, c);
    mpq_class s = 0;
    for (int i = 0; i < d_; ++i) {
      if (sgn(n[i]) != 0) s += n[i] * r[i];
    }
    if (sgn(s) != 0) return sgn(s);
    // Along the wall: the ray stays on its base's side.
    return sides[next_[v * d_ + position_of(v, kInfinityLabel)]];
  }
  double rounding = 0;
  const double f = plane_value(pl, &x_[v * d_], rounding);
  // |computed f - exact value at the exact vertex| <= rounding + |a| |x - exact x|.
  const double bound = rounding + pl.a_norm * error_[v] * (1 + 4 * d_ * filter::kUnitRoundoff);
  if (f > bound) return 1;
  if (f < -bound) return -1;
  const auto exact = exact_vertex(v);
  if (!exact) return f > 0 ? 1 : f < 0 ? -1 : 0;  // planes that coincide: the double value
  std::vector<mpq_class> n;
  mpq_class g;
  exact_plane(pl.label, n, g);
  g = -g;
  for (int c = 0; c < d_; ++c) g += n[c] * (*exact)[c];
  return sgn(g);
}

std::size_t CellPolytope::cut(std::size_t in, int position, std::size_t out, const Plane& pl) {
  const int d = d_;
  const std::size_t u = add_vertex();
  for (int j = 0; j < d; ++j) label_[u * d + j] = label_[in * d + j];
  label_[u * d + position] = pl.label;
  next_[u * d + position] = static_cast<std::uint32_t>(in);
  next_[in * d + position] = static_cast<std::uint32_t>(u);
  const double* a = pl.a.data();
  const double a_norm = pl.a_norm;
  auto value = [&](std::size_t v, double& rounding) { return plane_value(pl, &x_[v * d], rounding); };
  if (ideal_[in] >= 0 && ideal_[out] >= 0) {
    // Two directions on either side of the wall: their combination along it.
    const std::vector<mpq_class>& rv = rays_[ideal_[in]];
    const std::vector<mpq_class>& rw = rays_[ideal_[out]];
    std::vector<mpq_class> n;
    mpq_class offset;
    exact_plane(pl.label, n, offset);
    mpq_class av = 0, aw = 0;
    for (int c = 0; c < d; ++c) {
      av += n[c] * rv[c];
      aw += n[c] * rw[c];
    }
    std::vector<mpq_class> r(static_cast<std::size_t>(d));
    if (sgn(av) == 0 && sgn(aw) == 0) {
      // Both rays run along the wall, kept or dropped by their bases' sides (side()).
      // Truncate the cell far away, each ray at the same L1 length R from its base:
      // the wall crosses the edge between the two far ends at the fraction t of the
      // bases' plane values, whatever R, so the direction is (1 - t) rv + t rw with
      // both unit in L1. (aw rv - av rw would be the zero vector here.)
      auto base_value = [&](std::size_t v) {
        const std::size_t base = next_[v * d + position_of(v, kInfinityLabel)];
        double rounding = 0;
        return ideal_[base] >= 0 ? 0.0 : plane_value(pl, &x_[base * d], rounding);
      };
      const double fv = std::min(base_value(in), 0.0), fw = std::max(base_value(out), 0.0);
      const mpq_class t =
          fw - fv > 0 ? mpq_class(std::clamp(-fv / (fw - fv), 1.0 / 1024, 1 - 1.0 / 1024)) : mpq_class(1, 2);
      mpq_class lv = 0, lw = 0;
      for (int c = 0; c < d; ++c) {
        lv += abs(rv[c]);
        lw += abs(rw[c]);
      }
      for (int c = 0; c < d; ++c) r[c] = (1 - t) * rv[c] / lv + t * rw[c] / lw;
    } else {
      for (int c = 0; c < d; ++c) r[c] = aw * rv[c] - av * rw[c];
    }
    ideal_[u] = static_cast<int>(rays_.size());
    rays_.push_back(std::move(r));
    double len = 0;
    for (int c = 0; c < d; ++c) len = std::max(len, std::abs(rays_.back()[c].get_d()));
    for (int c = 0; c < d; ++c) x_[u * d + c] = len > 0 ? rays_.back()[c].get_d() / len : 0.0;
    const double l2 = norm(&x_[u * d], d);
    for (int c = 0; c < d; ++c) x_[u * d + c] = l2 > 0 ? x_[u * d + c] / l2 : 0.0;
    return u;
  }
  double* x = &x_[u * d];
  // The direct route in 3-d: a vertex on three bisectors is solved in closed form,
  // which needs no interpolation.
  if (from_box_ && d == 3 && ideal_[in] < 0 && ideal_[out] < 0 && solve_bisectors_3d(u)) {
    radius_[u] = vertex_radius(u);
    return u;
  }
  double error = kInf;
  if (ideal_[in] < 0 && ideal_[out] < 0) {
    double rv = 0, rw = 0;
    const double fv = value(in, rv), fw = value(out, rw);
    const double den = fw - fv;
    double span = 0;
    for (int c = 0; c < d; ++c) span += (x_[out * d + c] - x_[in * d + c]) * (x_[out * d + c] - x_[in * d + c]);
    span = std::sqrt(span);
    const double t = den > 0 ? std::clamp(-fv / den, 0.0, 1.0) : 0.5;
    for (int c = 0; c < d; ++c) x[c] = x_[in * d + c] + t * (x_[out * d + c] - x_[in * d + c]);
    if (den > 0) {
      const double ev = error_[in], ew = error_[out];
      error = std::max(ev, ew) + span * (a_norm * (ev + ew) + rv + rw) / den +
              8 * filter::kUnitRoundoff * std::sqrt(d) * (max_abs(x, d) + span);
    }
  } else {
    // A ray (ideal end r) from its real end: x = base + t r with a . x = b.
    const std::size_t base = ideal_[in] >= 0 ? out : in;
    const std::size_t ray = ideal_[in] >= 0 ? in : out;
    double rb = 0;
    const double fb = value(base, rb);
    const double* r = &x_[ray * d];
    const double ar = dot(a, r, d);
    const double t = ar != 0 ? std::max(0.0, -fb / ar) : 0.0;
    for (int c = 0; c < d; ++c) x[c] = x_[base * d + c] + t * r[c];
    if (ar != 0) {
      error = error_[base] + (a_norm * error_[base] + rb) / std::abs(ar) +
              8 * filter::kUnitRoundoff * std::sqrt(d) * (max_abs(x, d) + t * (1 + a_norm / std::abs(ar)));
    }
  }
  // On an axis-aligned wall (a box's) the coordinate across it is known exactly.
  if (pl.origin == nullptr) {
    int axis = -1, nonzero = 0;
    for (int c = 0; c < d; ++c) {
      if (a[c] != 0) axis = c, ++nonzero;
    }
    if (nonzero == 1 && std::abs(a[axis]) == 1) x[axis] = a[axis] * pl.b;
  }
  error_[u] = error;
  // Built from a box (the direct route), vertices descend from long chains of cuts,
  // whose interpolation bounds compound: solve each from its own d planes instead.
  if (from_box_ && !is_ideal(u) && !(error_[u] <= 1e-11 * scale_)) solve_vertex(u);
  // Where the bound is loose (edges nearly parallel to the wall), construct exactly.
  if (!(error_[u] <= 1e-10 * scale_)) {
    if (const auto exact = exact_vertex(u)) {
      for (int c = 0; c < d; ++c) x[c] = (*exact)[c].get_d();
      error_[u] = std::sqrt(d) * 2 * filter::kUnitRoundoff * max_abs(x, d);
    }
  }
  if (from_box_) radius_[u] = vertex_radius(u);
  return u;
}

const double* CellPolytope::point_of(std::uint32_t label) const {
  // From the back: the label just clipped, or one of a new vertex's recent planes.
  for (auto it = known_points_.rbegin(); it != known_points_.rend(); ++it) {
    if (it->first == label) return it->second;
  }
  return ps_.point(label);
}

double CellPolytope::vertex_radius(std::size_t v) const {
  const double* s = ps_.point(seed_);
  double r2 = 0;
  for (int c = 0; c < d_; ++c) {
    const double t = x_[v * d_ + c] - s[c];
    r2 += t * t;
  }
  // sqrt of a rounded sum of d rounded squares of rounded differences: a relative
  // error below (d + 3) units; 1e-12 covers it for every d <= 8 with room to spare.
  return std::sqrt(r2) * (1 + 1e-12) + error_[v];
}

bool CellPolytope::solve_bisectors_3d(std::size_t v) {
  // The vertex on the bisectors of s with a, b, c (relative: q_i = p_i - s) is s + y
  // with q_i . y = |q_i|^2 / 2: the circumcentre of the tetrahedron, by Cramer's rule
  // with its forward error bound (cramer.hpp).
  const std::uint32_t* l = &label_[v * 3];
  if (is_wall_label(l[0]) || is_wall_label(l[1]) || is_wall_label(l[2])) return false;
  const double* s = ps_.point(seed_);
  double q[3][3], half_n2[3], y[3];
  for (int i = 0; i < 3; ++i) {
    const double* p = point_of(l[i]);
    double n2 = 0;
    for (int c = 0; c < 3; ++c) {
      q[i][c] = p[c] - s[c];
      n2 += q[i][c] * q[i][c];
    }
    half_n2[i] = n2 / 2;
  }
  double forward = 0;
  if (!cramer_solve(q, half_n2, y, forward)) return false;  // nearly flat: the generic path decides
  double* x = &x_[v * 3];
  for (int c = 0; c < 3; ++c) x[c] = s[c] + y[c];
  error_[v] = std::sqrt(3.0) * (forward + 2 * filter::kUnitRoundoff * max_abs(x, 3));
  return true;
}

void CellPolytope::solve_vertex(std::size_t v) {
  // Rows a_k . y = c_k for y = x - s: a bisector q . y = |q|^2 / 2 (q = p - s), a
  // wall a . y = b - a . s. Gaussian elimination with partial pivoting in double is
  // backward stable: the computed y solves a system whose every entry is off by at
  // most eta = 3 d rho u relative (rho = 2^(d-1), the worst growth), on top of the
  // rounding of the rows themselves (a few units). The forward error is then at most
  // kappa (eta' |y| + |dc| / |A|), kappa = |A| |A^-1| (infinity norms), estimated
  // from the computed inverse with a factor 2 to spare.
  const int d = d_;
  const double* s = ps_.point(seed_);
  std::array<double, kMaxDimension * kMaxDimension> a{}, inv{};
  std::array<double, kMaxDimension> c{}, dc{}, y{};
  double a_norm = 0;
  for (int k = 0; k < d; ++k) {
    const Plane pl = plane_of(label_[v * d + k]);
    double row = 0, cs = pl.b, mag = std::abs(pl.b);
    for (int i = 0; i < d; ++i) {
      a[k * d + i] = pl.a[i];
      row += std::abs(pl.a[i]);
      if (pl.origin == nullptr) {
        cs -= pl.a[i] * s[i];
        mag += std::abs(pl.a[i] * s[i]);
      }
    }
    // Rows scaled by a power of two (exactly) to similar sizes: a wall's unit normal
    // next to bisectors of length |q| would otherwise inflate the condition number.
    const int e = row > 0 ? std::ilogb(row) : 0;
    for (int i = 0; i < d; ++i) a[k * d + i] = std::ldexp(a[k * d + i], -e);
    c[k] = std::ldexp(cs, -e);
    dc[k] = std::ldexp(4 * (d + 4) * filter::kUnitRoundoff * (mag + std::abs(cs)), -e);
    a_norm = std::max(a_norm, std::ldexp(row, -e));
  }
  // LU with partial pivoting, in place; then y and the inverse's columns.
  std::array<int, kMaxDimension> perm{};
  for (int i = 0; i < d; ++i) perm[i] = i;
  std::array<double, kMaxDimension* kMaxDimension> lu = a;
  for (int col = 0; col < d; ++col) {
    int p = col;
    for (int r = col + 1; r < d; ++r) {
      if (std::abs(lu[r * d + col]) > std::abs(lu[p * d + col])) p = r;
    }
    if (lu[p * d + col] == 0) return;  // singular in double: keep the interpolation
    if (p != col) {
      for (int i = 0; i < d; ++i) std::swap(lu[p * d + i], lu[col * d + i]);
      std::swap(perm[p], perm[col]);
    }
    for (int r = col + 1; r < d; ++r) {
      const double f = lu[r * d + col] / lu[col * d + col];
      lu[r * d + col] = f;
      for (int i = col + 1; i < d; ++i) lu[r * d + i] -= f * lu[col * d + i];
    }
  }
  auto solve = [&](const double* rhs, double* out) {
    std::array<double, kMaxDimension> z{};
    for (int r = 0; r < d; ++r) {
      double t = rhs[perm[r]];
      for (int i = 0; i < r; ++i) t -= lu[r * d + i] * z[i];
      z[r] = t;
    }
    for (int r = d - 1; r >= 0; --r) {
      double t = z[r];
      for (int i = r + 1; i < d; ++i) t -= lu[r * d + i] * out[i];
      out[r] = t / lu[r * d + r];
    }
  };
  solve(c.data(), y.data());
  std::array<double, kMaxDimension> e{}, column{};
  for (int j = 0; j < d; ++j) {
    e.fill(0);
    e[j] = 1;
    solve(e.data(), column.data());
    for (int i = 0; i < d; ++i) inv[i * d + j] = column[i];
  }
  double inv_norm = 0, y_norm = 0, dc_norm = 0;
  for (int i = 0; i < d; ++i) {
    double row = 0;
    for (int j = 0; j < d; ++j) row += std::abs(inv[i * d + j]);
    inv_norm = std::max(inv_norm, row);
    y_norm = std::max(y_norm, std::abs(y[i]));
    dc_norm = std::max(dc_norm, dc[i]);
  }
  inv_norm *= 2;
  const double eta = (3.0 * d * static_cast<double>(1 << (d - 1)) + 8) * filter::kUnitRoundoff;
  const double kappa = a_norm * inv_norm;
  if (!(kappa * eta < 1e-3) || !std::isfinite(y_norm)) return;  // ill-conditioned: keep the interpolation
  const double forward = inv_norm * (eta * a_norm * y_norm + dc_norm) / (1 - kappa * eta);
  double* x = &x_[v * d];
  for (int i = 0; i < d; ++i) x[i] = s[i] + y[i];
  // An axis-aligned wall fixes its coordinate exactly.
  for (int k = 0; k < d; ++k) {
    const std::uint32_t l = label_[v * d + k];
    if (!is_wall_label(l)) continue;
    const double* n = domain_->normal(l - kWallLabel0);
    int axis = -1, nonzero = 0;
    for (int i = 0; i < d; ++i) {
      if (n[i] != 0) axis = i, ++nonzero;
    }
    if (nonzero == 1 && std::abs(n[axis]) == 1) x[axis] = n[axis] * domain_->offset(l - kWallLabel0);
  }
  // Euclidean: sqrt(d) x the infinity-norm bound, plus the rounding of s + y.
  const double bound = std::sqrt(d) * (forward + 2 * filter::kUnitRoundoff * max_abs(x, d));
  if (bound < error_[v]) error_[v] = bound;
}

std::size_t CellPolytope::walk_to_partner(std::size_t u, int wall_position, int m, std::size_t first_new) const {
  // The 2-face of planes S = labels(u) without the wall and label m: walk its kept
  // boundary from u's kept end until it reaches the other new vertex on it.
  const int d = d_;
  std::array<std::uint32_t, kMaxDimension> s{};
  int s_count = 0;
  for (int k = 0; k < d; ++k) {
    if (k != wall_position && k != m) s[s_count++] = label_[u * d + k];
  }
  auto in_s = [&](std::uint32_t l) { return std::find(s.begin(), s.begin() + s_count, l) != s.begin() + s_count; };
  std::size_t prev = u, cur = next_[u * d + wall_position];
  for (std::size_t steps = 0; steps <= size(); ++steps) {
    std::size_t ways[2] = {prev, prev};
    int found = 0;
    for (int k = 0; k < d && found < 2; ++k) {
      if (!in_s(label_[cur * d + k])) ways[found++] = next_[cur * d + k];
    }
    const std::size_t nxt = ways[0] == prev ? ways[1] : ways[0];
    if (nxt >= first_new) return nxt;
    prev = cur;
    cur = nxt;
  }
  SPOKEMESH_INVARIANT(false, "the kept part of a 2-face ends at a new vertex");
  return u;
}

bool CellPolytope::clip(std::uint32_t label, const double* coordinates) {
  if (coordinates != nullptr) known_points_.emplace_back(label, coordinates);
  const int d = d_;
  const std::size_t n = size();
  const Plane pl = plane_of(label);
  std::vector<int>& sides = sides_;
  sides.assign(n, 0);
  bool tie = false, any_out = false;
  // A bisector lies |q| / 2 from the seed: a vertex closer than that (with its error)
  // is strictly inside, with no need to evaluate the plane.
  const double reach = from_box_ && pl.origin != nullptr ? pl.a_norm / 2 * (1 - 1e-12) : -1.0;
  for (std::size_t v = 0; v < n; ++v) {
    if (ideal_[v] < 0) {
      if (radius_.size() == n && radius_[v] < reach) {
        sides[v] = -1;
        continue;
      }
      sides[v] = side(v, pl, sides);
      tie |= sides[v] == 0;
      any_out |= sides[v] > 0;
    }
  }
  for (std::size_t v = 0; v < n; ++v) {
    if (ideal_[v] >= 0) {
      sides[v] = side(v, pl, sides);
      any_out |= sides[v] > 0;
    }
  }
  changed_ = any_out;
  if (!any_out) return !tie;
  const std::size_t first_new = n;
  for (std::size_t v = 0; v < n; ++v) {
    if (sides[v] > 0) continue;
    for (int k = 0; k < d; ++k) {
      const std::size_t w = next_[v * d + k];
      if (w < first_new && sides[w] > 0) cut(v, k, w, pl);
    }
  }
  for (std::size_t u = first_new; u < size(); ++u) {
    const int p = position_of(u, label);
    for (int k = 0; k < d; ++k) {
      if (k != p) next_[u * d + k] = static_cast<std::uint32_t>(walk_to_partner(u, p, k, first_new));
    }
  }
  // Drop the vertices outside; renumber.
  std::vector<std::uint32_t>& index = index_;
  index.assign(size(), 0);
  std::size_t kept = 0;
  for (std::size_t v = 0; v < size(); ++v) {
    if (v >= n || sides[v] <= 0) index[v] = static_cast<std::uint32_t>(kept++);
  }
  std::size_t w = 0;
  for (std::size_t v = 0; v < size(); ++v) {
    if (v < n && sides[v] > 0) continue;
    for (int k = 0; k < d; ++k) {
      x_[w * d + k] = x_[v * d + k];
      label_[w * d + k] = label_[v * d + k];
      next_[w * d + k] = index[next_[v * d + k]];
    }
    error_[w] = error_[v];
    ideal_[w] = ideal_[v];
    if (from_box_) radius_[w] = radius_[v];
    ++w;
  }
  x_.resize(w * d);
  label_.resize(w * d);
  next_.resize(w * d);
  error_.resize(w);
  ideal_.resize(w);
  if (from_box_) radius_.resize(w);
  return !tie;
}

void CellPolytope::clip_all() {
  for (std::size_t k = 0; k < domain_->wall_count(); ++k) clip(kWallLabel0 + static_cast<std::uint32_t>(k));
}

CellPolytope::CellPolytope(const PointSet& points, std::uint32_t seed, const Domain& box)
    : ps_(points), domain_(&box), seed_(seed), d_(points.dimension()) {
  reset_to_box(seed);
}

void CellPolytope::reset_to_box(std::uint32_t seed) {
  const int d = d_;
  seed_ = seed;
  const std::size_t corners = std::size_t{1} << d;
  x_.resize(corners * d);
  label_.resize(corners * d);
  next_.resize(corners * d);
  error_.assign(corners, 0.0);
  ideal_.assign(corners, -1);
  rays_.clear();
  memo_.clear();
  known_points_.clear();
  from_box_ = true;
  // Corner v has bit c set when it lies on the upper wall of axis c (wall d + c);
  // leaving that wall flips the bit.
  double diagonal2 = 0;
  for (int c = 0; c < d; ++c) {
    const double lo = -domain_->offset(static_cast<std::size_t>(c));
    const double hi = domain_->offset(static_cast<std::size_t>(d + c));
    diagonal2 += (hi - lo) * (hi - lo);
    for (std::size_t v = 0; v < corners; ++v) {
      const bool upper = (v >> c) & 1;
      x_[v * d + c] = upper ? hi : lo;
      label_[v * d + c] = kWallLabel0 + static_cast<std::uint32_t>(upper ? d + c : c);
      next_[v * d + c] = static_cast<std::uint32_t>(v ^ (std::size_t{1} << c));
    }
  }
  scale_ = diagonal2 > 0 ? std::sqrt(diagonal2) : 1.0;
  radius_.resize(corners);
  for (std::size_t v = 0; v < corners; ++v) radius_[v] = vertex_radius(v);
}

double CellPolytope::radius2_upper() const {
  double r = 0;
  for (std::size_t v = 0; v < size(); ++v) r = std::max(r, from_box_ ? radius_[v] : vertex_radius(v));
  return r * r * (1 + 1e-12);
}

void CellPolytope::refine_voronoi_vertices() {
  std::array<std::uint32_t, kMaxDimension + 1> ids{};
  for (std::size_t v = 0; v < size(); ++v) {
    if (ideal_[v] >= 0) continue;
    const std::uint32_t* l = &label_[v * d_];
    if (std::any_of(l, l + d_, [](std::uint32_t x) { return is_wall_label(x) || x == kInfinityLabel; })) continue;
    // Already within circumcentre()'s bound (1e-12 of the radius plus an ulp): keep.
    double r2 = 0;
    for (int c = 0; c < d_; ++c) {
      const double t = x_[v * d_ + c] - ps_.point(seed_)[c];
      r2 += t * t;
    }
    if (error_[v] <= 1e-12 * std::sqrt(r2)) continue;
    ids[0] = seed_;
    std::copy(l, l + d_, ids.begin() + 1);
    for (int i = 1; i <= d_; ++i) {  // insertion sort: at most 9 ids
      for (int j = i; j > 0 && ids[j - 1] > ids[j]; --j) std::swap(ids[j - 1], ids[j]);
    }
    const std::vector<double> c = circumcentre(ps_, ids.data(), d_ + 1, weights_);
    std::copy(c.begin(), c.end(), &x_[v * d_]);
  }
}

std::vector<double> CellPolytope::facet_normal(std::uint32_t label) const {
  std::vector<double> n(static_cast<std::size_t>(d_));
  normal_of(label, n.data());
  const double l = norm(n.data(), d_);
  for (double& v : n) v /= l;
  return n;
}

double CellPolytope::face_measure(const std::vector<std::uint32_t>& verts, std::vector<std::uint32_t>& planes,
                                  std::vector<double>& basis, double* centroid, std::vector<FacetMeasure>* top) const {
  const int d = d_;
  const int dim = d - static_cast<int>(planes.size());
  if (dim == 1 || verts.size() <= 2) {
    // An edge (two vertices in a simple polytope; more only where zero-length edges
    // from a wall through a vertex coincide): its length and midpoint.
    double len = 0;
    std::size_t a = 0, b = 0;
    for (std::size_t i = 0; i < verts.size(); ++i) {
      for (std::size_t j = i + 1; j < verts.size(); ++j) {
        double l2 = 0;
        for (int c = 0; c < d; ++c) {
          const double t = x_[verts[i] * d + c] - x_[verts[j] * d + c];
          l2 += t * t;
        }
        if (l2 > len) len = l2, a = i, b = j;
      }
    }
    for (int c = 0; c < d; ++c) centroid[c] = 0.5 * (x_[verts[a] * d + c] + x_[verts[b] * d + c]);
    return dim == 1 ? std::sqrt(len) : 0.0;
  }
  std::array<double, kMaxDimension> ref{};
  for (std::uint32_t v : verts) {
    for (int c = 0; c < d; ++c) ref[c] += x_[v * d + c];
  }
  for (int c = 0; c < d; ++c) ref[c] /= static_cast<double>(verts.size());
  std::vector<std::uint32_t> sub_labels;
  for (std::uint32_t v : verts) {
    for (int k = 0; k < d; ++k) {
      const std::uint32_t l = label_[v * d + k];
      if (std::find(planes.begin(), planes.end(), l) == planes.end()) sub_labels.push_back(l);
    }
  }
  std::sort(sub_labels.begin(), sub_labels.end());
  sub_labels.erase(std::unique(sub_labels.begin(), sub_labels.end()), sub_labels.end());
  double total = 0;
  std::array<double, kMaxDimension> weighted{};
  std::array<double, kMaxDimension> sub_centroid{};
  std::array<double, kMaxDimension> u{};
  std::vector<std::uint32_t> sub;
  for (const std::uint32_t l : sub_labels) {
    sub.clear();
    for (std::uint32_t v : verts) {
      if (std::find(&label_[v * d], &label_[v * d] + d, l) != &label_[v * d] + d) sub.push_back(v);
    }
    // The facet's normal within this face: n_l without its components along the
    // normals of the planes already fixed (basis: orthonormal).
    normal_of(l, u.data());
    const double n0 = norm(u.data(), d);
    const std::size_t fixed = planes.size();
    for (std::size_t i = 0; i < fixed; ++i) {
      const double* e = &basis[i * d];
      const double p = dot(u.data(), e, d);
      for (int c = 0; c < d; ++c) u[c] -= p * e[c];
    }
    const double n1 = norm(u.data(), d);
    planes.push_back(l);
    const bool degenerate = !(n1 > 1e-12 * n0);
    if (!degenerate) {
      for (int c = 0; c < d; ++c) u[c] /= n1;
    }
    basis.insert(basis.end(), u.begin(), u.begin() + d);
    double measure = 0;
    if (!degenerate) {
      // In 4-d and up a face is reached from many parents: measure it once.
      const bool memo = d >= 4 && planes.size() >= 2 && planes.size() + 1 < static_cast<std::size_t>(d);
      std::vector<std::uint32_t> key;
      if (memo) {
        key = planes;
        std::sort(key.begin(), key.end());
        if (const auto it = memo_.find(key); it != memo_.end()) {
          measure = it->second.first;
          sub_centroid = it->second.second;
        } else {
          measure = face_measure(sub, planes, basis, sub_centroid.data(), nullptr);
          memo_.emplace(std::move(key), std::make_pair(measure, sub_centroid));
        }
      } else {
        measure = face_measure(sub, planes, basis, sub_centroid.data(), nullptr);
      }
    }
    basis.resize(basis.size() - d);
    planes.pop_back();
    if (top != nullptr) top->push_back({l, measure, {}});
    if (degenerate || measure == 0) continue;
    double h = 0;
    for (int c = 0; c < d; ++c) h += u[c] * (sub_centroid[c] - ref[c]);
    const double w = std::abs(h) * measure / dim;
    total += w;
    const double f = static_cast<double>(dim) / (dim + 1);
    for (int c = 0; c < d; ++c) weighted[c] += w * (ref[c] + f * (sub_centroid[c] - ref[c]));
  }
  for (int c = 0; c < d; ++c) centroid[c] = total > 0 ? weighted[c] / total : ref[c];
  return total;
}

PolytopeMeasures CellPolytope::measures() const {
  if (d_ == 3) return measures_3d();
  PolytopeMeasures out;
  memo_.clear();
  const int d = d_;
  std::vector<std::uint32_t> planes, verts;
  std::vector<double> basis;
  if (bounded()) {
    for (std::size_t v = 0; v < size(); ++v) verts.push_back(static_cast<std::uint32_t>(v));
    out.centroid.assign(static_cast<std::size_t>(d), 0.0);
    out.volume = face_measure(verts, planes, basis, out.centroid.data(), &out.facets);
  } else {
    out.volume = kInf;
    std::vector<std::uint32_t> labels(label_);
    std::sort(labels.begin(), labels.end());
    labels.erase(std::unique(labels.begin(), labels.end()), labels.end());
    std::array<double, kMaxDimension> c{};
    for (const std::uint32_t l : labels) {
      if (l == kInfinityLabel) continue;
      verts.clear();
      bool open = false;
      for (std::size_t v = 0; v < size(); ++v) {
        if (position_of(v, l) >= 0) {
          verts.push_back(static_cast<std::uint32_t>(v));
          open = open || ideal_[v] >= 0;
        }
      }
      double area = kInf;
      if (!open) {
        planes.assign(1, l);
        basis = facet_normal(l);
        area = face_measure(verts, planes, basis, c.data(), nullptr);
      }
      out.facets.push_back({l, area, {}});
    }
  }
  std::sort(out.facets.begin(), out.facets.end(),
            [](const FacetMeasure& a, const FacetMeasure& b) { return a.label < b.label; });
  for (FacetMeasure& f : out.facets) f.vertices = facet_vertices(f.label);
  return out;
}

PolytopeMeasures CellPolytope::measures_3d() const {
  PolytopeMeasures out;
  const bool closed = bounded();
  // The first vertex on each plane.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> firsts;
  firsts.reserve(label_.size());
  for (std::size_t v = 0; v < size(); ++v) {
    for (int k = 0; k < 3; ++k) firsts.emplace_back(label_[v * 3 + k], static_cast<std::uint32_t>(v));
  }
  std::sort(firsts.begin(), firsts.end());
  std::array<double, 3> ref{};
  if (closed) {
    for (std::size_t v = 0; v < size(); ++v) {
      for (int c = 0; c < 3; ++c) ref[c] += x_[v * 3 + c];
    }
    for (double& r : ref) r /= static_cast<double>(size());
  }
  double volume = 0;
  std::array<double, 3> moment{};
  for (std::size_t i = 0; i < firsts.size(); ++i) {
    if (i > 0 && firsts[i].first == firsts[i - 1].first) continue;
    const std::uint32_t l = firsts[i].first;
    if (l == kInfinityLabel) continue;
    FacetMeasure f;
    f.label = l;
    std::vector<std::uint32_t> cycle = facet_cycle(l, firsts[i].second);
    const bool open = std::any_of(cycle.begin(), cycle.end(), [&](std::uint32_t v) { return ideal_[v] >= 0; });
    f.vertices = open_at_infinity(std::move(cycle), [&](std::uint32_t v) { return ideal_[v] >= 0; });
    if (open) {
      f.area = kInf;
      out.facets.push_back(std::move(f));
      continue;
    }
    // Fan from the loop's first vertex: the area vector and the area centroid.
    std::array<double, 3> n{};
    normal_of(l, n.data());
    const double nn = norm(n.data(), 3);
    for (double& c : n) c /= nn;
    std::array<double, 3> centre{};
    const double area = fan_area(
        f.vertices, [&](std::uint32_t v) { return &x_[v * 3]; }, n.data(), centre.data());
    f.area = std::max(area, 0.0);
    if (closed && area > 0) {
      for (double& c : centre) c /= area;
      const double h =
          std::abs(n[0] * (centre[0] - ref[0]) + n[1] * (centre[1] - ref[1]) + n[2] * (centre[2] - ref[2]));
      const double cone = area * h / 3;
      volume += cone;
      for (int c = 0; c < 3; ++c) moment[c] += cone * (ref[c] + 0.75 * (centre[c] - ref[c]));
    }
    out.facets.push_back(std::move(f));
  }
  if (closed) {
    out.volume = volume;
    out.centroid.assign(3, 0.0);
    for (int c = 0; c < 3; ++c) out.centroid[c] = volume > 0 ? moment[c] / volume : ref[c];
  } else {
    out.volume = kInf;
  }
  return out;
}

std::vector<std::uint32_t> CellPolytope::polygon_order() const {
  // 2-d: the cycle through every vertex, counter-clockwise by the shoelace sum (an
  // ideal vertex counts as a point far along its ray).
  std::vector<std::uint32_t> cycle;
  if (size() == 0) return cycle;
  std::size_t prev = next_[1], cur = 0;  // start towards next_[0]
  for (std::size_t steps = 0; steps < size(); ++steps) {
    cycle.push_back(static_cast<std::uint32_t>(cur));
    const std::size_t nxt = next_[cur * 2] == prev ? next_[cur * 2 + 1] : next_[cur * 2];
    prev = cur;
    cur = nxt;
    if (cur == 0) break;
  }
  auto point = [&](std::uint32_t v, int c) {
    if (ideal_[v] < 0) return x_[v * 2 + c];
    const std::size_t base = next_[v * 2 + position_of(v, kInfinityLabel)];
    return x_[base * 2 + c] + 4 * scale_ * x_[v * 2 + c];
  };
  double area2 = 0;
  for (std::size_t i = 0; i < cycle.size(); ++i) {
    const std::uint32_t a = cycle[i], b = cycle[(i + 1) % cycle.size()];
    area2 += point(a, 0) * point(b, 1) - point(b, 0) * point(a, 1);
  }
  if (area2 < 0) std::reverse(cycle.begin(), cycle.end());
  return open_at_infinity(std::move(cycle), [&](std::uint32_t v) { return ideal_[v] >= 0; });
}

std::vector<std::uint32_t> CellPolytope::facet_cycle(std::uint32_t label, std::uint32_t start) const {
  // The facet is a polygon: walk it, leaving `label` fixed, then orient it by Newell's
  // normal against the outward one (an ideal vertex counts as a point far along its ray).
  const int d = 3;
  std::vector<std::uint32_t> cycle;
  std::size_t prev = start, cur = start;
  for (std::size_t steps = 0; steps <= size(); ++steps) {
    cycle.push_back(static_cast<std::uint32_t>(cur));
    std::size_t ways[2] = {cur, cur};
    int found = 0;
    for (int k = 0; k < d && found < 2; ++k) {
      if (label_[cur * d + k] != label) ways[found++] = next_[cur * d + k];
    }
    const std::size_t nxt = ways[0] == prev ? ways[1] : ways[0];
    prev = cur;
    cur = nxt;
    if (cur == start) break;
  }
  auto point = [&](std::uint32_t v, int c) {
    if (ideal_[v] < 0) return x_[v * 3 + c];
    const std::size_t base = next_[v * 3 + position_of(v, kInfinityLabel)];
    return x_[base * 3 + c] + 4 * scale_ * x_[v * 3 + c];
  };
  std::array<double, 3> newell{};
  for (std::size_t i = 0; i < cycle.size(); ++i) {
    const std::uint32_t a = cycle[i], b = cycle[(i + 1) % cycle.size()];
    for (int c = 0; c < 3; ++c) {
      const int c1 = (c + 1) % 3, c2 = (c + 2) % 3;
      newell[c] += (point(a, c1) - point(b, c1)) * (point(a, c2) + point(b, c2));
    }
  }
  std::array<double, 3> n{};
  normal_of(label, n.data());
  if (dot(newell.data(), n.data(), 3) < 0) std::reverse(cycle.begin(), cycle.end());
  return cycle;
}

std::vector<std::uint32_t> CellPolytope::facet_vertices(std::uint32_t label) const {
  const int d = d_;
  std::vector<std::uint32_t> verts;
  for (std::size_t v = 0; v < size(); ++v) {
    if (position_of(v, label) >= 0) verts.push_back(static_cast<std::uint32_t>(v));
  }
  if (d != 3 || verts.size() < 3) {
    verts.erase(std::remove_if(verts.begin(), verts.end(), [&](std::uint32_t v) { return ideal_[v] >= 0; }),
                verts.end());
    return verts;
  }
  std::vector<std::uint32_t> cycle = facet_cycle(label, verts[0]);
  return open_at_infinity(std::move(cycle), [&](std::uint32_t v) { return ideal_[v] >= 0; });
}

}  // namespace spokemesh::detail
