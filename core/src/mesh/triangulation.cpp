#include "mesh/triangulation.hpp"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <limits>
#include <string>

#include "base/invariant.hpp"

namespace spokemesh::detail {

namespace {

// In 3-d, the two vertex positions of a cell other than i and k (i != k): a ridge.
constexpr int kOthers[4][4][2] = {{{0, 0}, {2, 3}, {1, 3}, {1, 2}},
                                  {{2, 3}, {0, 0}, {0, 3}, {0, 2}},
                                  {{1, 3}, {0, 3}, {0, 0}, {0, 1}},
                                  {{1, 2}, {0, 2}, {0, 1}, {0, 0}}};
constexpr int kUnknown = filter::kUnknownSign;

// The filters. Each evaluates, in floating type T, the same determinant as the exact
// stage (Predicates::spatial_sign_exact / lifted_sign_exact with origin p[0]) together
// with the sum of its monomials' magnitudes, computed alike on absolute values, and
// its rounding depth in BoundedDouble's model (a difference of inputs: 1; a product:
// the sum of its factors' depths + 1; a sum: the larger depth + 1). The sign is
// certified when |value| exceeds (depth + 2) u (1.01) times the magnitude (the bound
// of predicates.hpp, u being T's unit roundoff), and kUnknownSign is returned
// otherwise (also when the magnitude could have underflowed or overflowed).
//
// Two stages: double (u = 2^-53), then x87 extended precision (long double, u = 2^-64
// on x86-64: 2,048 times tighter) before the exact stage. Points on a sphere or a
// closed surface make nearly every in-sphere test a near tie (the determinant is the
// coordinates' rounding, about 1e-16 of the magnitude): the double filter fails, the
// extended one decides nearly all of them at a few times a double's cost, instead of
// the microsecond of an exact evaluation.
template <class T>
struct Precision;
template <>
struct Precision<double> {
  static constexpr double kUnit = filter::kUnitRoundoffOf<double>;
};
template <>
struct Precision<long double> {
  static_assert(std::numeric_limits<long double>::digits >= 64, "the second stage assumes x87 extended precision");
  static constexpr long double kUnit = filter::kUnitRoundoffOf<long double>;
};

template <class T>
inline int certified(T value, T magnitude, int depth) {
  if (!(magnitude >= static_cast<T>(filter::kUnderflowGuard) && magnitude <= static_cast<T>(DBL_MAX))) return kUnknown;
  const T err = magnitude * (static_cast<T>(depth) + 2) * Precision<T>::kUnit * static_cast<T>(1.01);
  if (value > err) return 1;
  if (value < -err) return -1;
  return kUnknown;
}

// det[b - a, c - a]: depth 4.
template <class T>
inline int orient2_filter(const double* a, const double* b, const double* c) {
  const T bx = T(b[0]) - T(a[0]), by = T(b[1]) - T(a[1]), cx = T(c[0]) - T(a[0]), cy = T(c[1]) - T(a[1]);
  const T l = bx * cy, r = by * cx;
  return certified<T>(l - r, std::fabs(l) + std::fabs(r), 4);
}

// det[b - a, c - a, d - a]: 2x2 minors depth 4, times a coordinate 6, sum of three 8.
template <class T>
inline int orient3_filter(const double* a, const double* b, const double* c, const double* d) {
  const T bx = T(b[0]) - T(a[0]), by = T(b[1]) - T(a[1]), bz = T(b[2]) - T(a[2]);
  const T cx = T(c[0]) - T(a[0]), cy = T(c[1]) - T(a[1]), cz = T(c[2]) - T(a[2]);
  const T dx = T(d[0]) - T(a[0]), dy = T(d[1]) - T(a[1]), dz = T(d[2]) - T(a[2]);
  const T m0l = cy * dz, m0r = cz * dy, m1l = cz * dx, m1r = cx * dz, m2l = cx * dy, m2r = cy * dx;
  const T v = bx * (m0l - m0r) + by * (m1l - m1r) + bz * (m2l - m2r);
  const T m = std::fabs(bx) * (std::fabs(m0l) + std::fabs(m0r)) + std::fabs(by) * (std::fabs(m1l) + std::fabs(m1r)) +
              std::fabs(bz) * (std::fabs(m2l) + std::fabs(m2r));
  return certified<T>(v, m, 8);
}

// The lifted determinant with origin a and rows (p - a, |p - a|^2) for p = b, c, q:
// expanded along the height column, + h_b det(c, q) - h_c det(b, q) + h_q det(b, c).
// Heights depth 4 (two squares summed), 2x2 minors 4, products 9, sum of three 11.
template <class T>
inline int insphere2_filter(const double* a, const double* b, const double* c, const double* q) {
  const T bx = T(b[0]) - T(a[0]), by = T(b[1]) - T(a[1]), cx = T(c[0]) - T(a[0]), cy = T(c[1]) - T(a[1]);
  const T qx = T(q[0]) - T(a[0]), qy = T(q[1]) - T(a[1]);
  const T hb = bx * bx + by * by, hc = cx * cx + cy * cy, hq = qx * qx + qy * qy;
  const T cq_l = cx * qy, cq_r = cy * qx, bq_l = bx * qy, bq_r = by * qx, bc_l = bx * cy, bc_r = by * cx;
  const T v = hb * (cq_l - cq_r) - hc * (bq_l - bq_r) + hq * (bc_l - bc_r);
  const T m = hb * (std::fabs(cq_l) + std::fabs(cq_r)) + hc * (std::fabs(bq_l) + std::fabs(bq_r)) +
              hq * (std::fabs(bc_l) + std::fabs(bc_r));
  return certified<T>(v, m, 11);
}

// The lifted determinant with origin a and rows b, c, d, q (4 x 4), expanded along
// the height column: -h_b M_b + h_c M_c - h_d M_d + h_q M_q, M_r the 3 x 3 spatial
// determinant of the other three rows (triple products over shared cross products).
// Heights depth 5, triple products 8, products 14, sum of four 17.
template <class T>
inline int insphere3_filter(const double* a, const double* b, const double* c, const double* d, const double* q) {
  T r[4][3], h[4];
  const double* p[4] = {b, c, d, q};
  for (int i = 0; i < 4; ++i) {
    for (int k = 0; k < 3; ++k) r[i][k] = T(p[i][k]) - T(a[k]);
    h[i] = r[i][0] * r[i][0] + r[i][1] * r[i][1] + r[i][2] * r[i][2];
  }
  auto cross = [](const T* u, const T* w, T* out, T* mag) {
    const T l0 = u[1] * w[2], r0 = u[2] * w[1], l1 = u[2] * w[0], r1 = u[0] * w[2], l2 = u[0] * w[1], r2 = u[1] * w[0];
    out[0] = l0 - r0;
    out[1] = l1 - r1;
    out[2] = l2 - r2;
    mag[0] = std::fabs(l0) + std::fabs(r0);
    mag[1] = std::fabs(l1) + std::fabs(r1);
    mag[2] = std::fabs(l2) + std::fabs(r2);
  };
  auto dot = [](const T* u, const T* w) { return u[0] * w[0] + u[1] * w[1] + u[2] * w[2]; };
  auto dot_abs = [](const T* u, const T* w) {
    return std::fabs(u[0]) * w[0] + std::fabs(u[1]) * w[1] + std::fabs(u[2]) * w[2];
  };
  T dq[3], dqm[3], cd[3], cdm[3], bc[3], bcm[3];
  cross(r[2], r[3], dq, dqm);  // d x q
  cross(r[1], r[2], cd, cdm);  // c x d
  cross(r[0], r[1], bc, bcm);  // b x c
  // M_b = det(c, d, q) = c . (d x q); M_c = det(b, d, q) = b . (d x q);
  // M_d = det(b, c, q) = q . (b x c); M_q = det(b, c, d) = b . (c x d).
  const T mb = dot(r[1], dq), mc = dot(r[0], dq), md = dot(r[3], bc), mq = dot(r[0], cd);
  const T mbm = dot_abs(r[1], dqm), mcm = dot_abs(r[0], dqm), mdm = dot_abs(r[3], bcm), mqm = dot_abs(r[0], cdm);
  const T v = -h[0] * mb + h[1] * mc - h[2] * md + h[3] * mq;
  const T m = h[0] * mbm + h[1] * mcm + h[2] * mdm + h[3] * mqm;
  return certified<T>(v, m, 17);
}

template <int D, class T>
int orient_filter(const std::array<const double*, D + 1>& x) {
  if constexpr (D == 2) {
    return orient2_filter<T>(x[0], x[1], x[2]);
  } else {
    return orient3_filter<T>(x[0], x[1], x[2], x[3]);
  }
}
template <int D, class T>
int insphere_filter(const std::array<const double*, D + 1>& x, const double* q) {
  if constexpr (D == 2) {
    return insphere2_filter<T>(x[0], x[1], x[2], q);
  } else {
    return insphere3_filter<T>(x[0], x[1], x[2], x[3], q);
  }
}

}  // namespace

template <int D>
Triangulation<D>::Triangulation(const PointSet& points, const Predicates& predicates) : ps_(points), pred_(predicates) {
  SPOKEMESH_INVARIANT(points.dimension() == D, "a triangulation of the set's dimension");
  clear();
}

template <int D>
Triangulation<D>::Triangulation(const Triangulation& from, const PointSet& points, const Predicates& predicates)
    : ps_(points),
      pred_(predicates),
      full_(from.full_),
      pending_(from.pending_),
      basis_(from.basis_),
      basis_size_(from.basis_size_),
      free_(from.free_),
      gen_(from.gen_),
      hint_(from.hint_),
      stats_(from.stats_) {
  SPOKEMESH_INVARIANT(points.dimension() == D && points.size() >= from.ps_.size(),
                      "a copy over a set that extends the original");
  // Room for every point of the new set first: the arrays are then written once (a
  // copy and a reallocation after it each cost as much: first touches of the pages).
  reserve(points.size());
  global_.assign(from.global_.begin(), from.global_.end());
  coords_.assign(from.coords_.begin(), from.coords_.end());
  cells_.assign(from.cells_.begin(), from.cells_.end());
  vcell_.assign(from.vcell_.begin(), from.vcell_.end());
}

template <int D>
void Triangulation<D>::clear() {
  full_ = false;
  global_.assign(1, 0xFFFFFFFFu);
  coords_.assign(D, 0.0);
  pending_.clear();
  basis_size_ = 0;
  cells_.clear();
  free_.clear();
  vcell_.assign(1, kNone);
  gen_ = 0;
  hint_ = kNone;
}

template <int D>
void Triangulation<D>::reserve(std::size_t points) {
  const double per_point = D == 2 ? 2.1 : 7.0;
  const auto cells = static_cast<std::size_t>(per_point * static_cast<double>(points)) + 64;
  if (cells > cells_.capacity()) cells_.reserve(cells);
  if (points + 1 > global_.capacity()) {
    global_.reserve(points + 1);
    vcell_.reserve(points + 1);
    coords_.reserve((points + 1) * D);
  }
}

template <int D>
std::size_t Triangulation<D>::bytes() const {
  return cells_.capacity() * sizeof(Cell) + free_.capacity() * 4 + vcell_.capacity() * 4 + global_.capacity() * 8 +
         coords_.capacity() * sizeof(double);
}

template <int D>
bool Triangulation<D>::is_infinite(std::uint32_t c) const {
  for (const std::uint32_t v : cells_[c].v) {
    if (v == kInfinite) return true;
  }
  return false;
}

template <int D>
int Triangulation<D>::infinite_index(std::uint32_t c) const {
  for (int i = 0; i <= D; ++i) {
    if (cells_[c].v[i] == kInfinite) return i;
  }
  return -1;
}

template <int D>
std::uint32_t Triangulation<D>::new_cell() {
  std::uint32_t c;
  if (!free_.empty()) {
    c = free_.back();
    free_.pop_back();
  } else {
    c = static_cast<std::uint32_t>(cells_.size());
    cells_.emplace_back();
  }
  cells_[c].mark = 0;
  cells_[c].tag = 0;
  return c;
}

template <int D>
template <class IdsFn>
int Triangulation<D>::orient_at(const Points& x, IdsFn&& ids) const {
  int s = orient_filter<D, double>(x);
  if (s != kUnknown) [[likely]]
    return s;
  s = orient_filter<D, long double>(x);
  if (s != kUnknown) return s;
  ++stats_.exact_calls;
  const Ids id = ids();
  std::array<Row, D> rows;
  for (int r = 0; r < D; ++r) rows[r] = Row::of_point(id[r + 1]);
  return pred_.spatial_sign_exact(id[0], std::span<const Row>(rows.data(), D));
}

template <int D>
template <class IdsFn>
int Triangulation<D>::sphere_at(const Points& x, IdsFn&& ids, const double* q, std::uint32_t q_id) const {
  int s = insphere_filter<D, double>(x, q);
  if (s != kUnknown) [[likely]]
    return s;
  s = insphere_filter<D, long double>(x, q);
  if (s != kUnknown) return s;
  ++stats_.exact_calls;
  const Ids id = ids();
  std::array<Row, D + 1> rows;
  for (int r = 0; r < D; ++r) rows[r] = Row::of_point(id[r + 1]);
  rows[D] = Row::of_point(q_id);
  // A positive cell: the lifted sign is the side (Predicates::side_of_sphere).
  return pred_.lifted_sign_exact(id[0], std::span<const Row>(rows.data(), D + 1), /*perturb=*/true);
}

template <int D>
typename Triangulation<D>::Points Triangulation<D>::points_of(const std::array<std::uint32_t, D + 1>& v) const {
  Points x;
  for (int k = 0; k <= D; ++k) x[k] = coords(v[k]);
  return x;
}

template <int D>
typename Triangulation<D>::Ids Triangulation<D>::ids_of(const std::array<std::uint32_t, D + 1>& v) const {
  Ids ids;
  for (int k = 0; k <= D; ++k) ids[k] = global_[v[k]];
  return ids;
}

template <int D>
int Triangulation<D>::orient_points(const std::array<std::uint32_t, D + 1>& v) const {
  return orient_at(points_of(v), [&] { return ids_of(v); });
}

template <int D>
int Triangulation<D>::orient_with(std::uint32_t c, int i, const double* p, std::uint32_t p_id) const {
  const auto& v = cells_[c].v;
  Points x = points_of(v);
  x[i] = p;
  return orient_at(x, [&] {
    Ids ids = ids_of(v);
    ids[i] = p_id;
    return ids;
  });
}

template <int D>
int Triangulation<D>::side_of_sphere(std::uint32_t c, const double* p, std::uint32_t p_id) const {
  const auto& v = cells_[c].v;
  return sphere_at(
      points_of(v), [&] { return ids_of(v); }, p, p_id);
}

template <int D>
bool Triangulation<D>::conflict_at(std::uint32_t c, const double* p, std::uint32_t p_id) const {
  const int inf = infinite_index(c);
  if (inf < 0) return side_of_sphere(c, p, p_id) < 0;
  const int o = orient_with(c, inf, p, p_id);
  if (o != 0) return o > 0;
  return side_of_sphere(cells_[c].n[inf], p, p_id) < 0;  // on the hull facet's plane
}

template <int D>
bool Triangulation<D>::in_conflict(std::uint32_t c, std::uint32_t id) const {
  return conflict_at(c, ps_.point(id), id);
}

template <int D>
std::uint32_t Triangulation<D>::insert(std::uint32_t id) {
  const auto p = static_cast<std::uint32_t>(global_.size());
  global_.push_back(id);
  coords_.insert(coords_.end(), ps_.point(id), ps_.point(id) + D);
  vcell_.push_back(kNone);
  if (full_) {
    insert_local(p);
  } else {
    pending_.push_back(p);
    start();
  }
  return p;
}

template <int D>
void Triangulation<D>::start() {
  // A greedy affine basis among the buffered points, grown one point per call: the
  // newest must leave the span of those kept (exact orientation signs; only points
  // before the first simplex pass here, each tested once).
  auto& basis = basis_;
  int& have = basis_size_;
  const std::uint32_t q = pending_.back();
  if (have == 0) {
    basis[have++] = q;
    return;
  }
  // Independent of the basis so far when some orientation with the basis, q and
  // D - have further coordinate-axis directions is non-zero: equivalently, when the
  // rank of the differences grows. Decided exactly by the Predicates on rows.
  bool independent = false;
  if (have == D) {
    std::array<std::uint32_t, D + 1> v{};
    for (int k = 0; k < D; ++k) v[k] = basis[k];
    v[D] = q;
    independent = orient_points(v) != 0;
  } else {
    // Fewer than D basis points: try directions e_c as the missing rows.
    const int missing = D - have;  // rows still to fill after q
    std::array<std::array<double, D>, D> dirs{};
    for (int c = 0; c < D; ++c) dirs[c][c] = 1.0;
    std::array<int, D> pick{};
    for (int k = 0; k < missing; ++k) pick[k] = k;
    // Every combination of `missing` axes.
    for (;;) {
      std::array<Row, D> rows;
      int r = 0;
      for (int k = 1; k < have; ++k) rows[r++] = Row::of_point(global_[basis[k]]);
      rows[r++] = Row::of_point(global_[q]);
      for (int k = 0; k < missing; ++k) rows[r++] = Row::of_direction(dirs[pick[k]].data());
      ++stats_.exact_calls;
      if (pred_.spatial_sign_exact(global_[basis[0]], std::span<const Row>(rows.data(), D)) != 0) {
        independent = true;
        break;
      }
      int k = missing - 1;
      while (k >= 0 && pick[k] == D - missing + k) --k;
      if (k < 0) break;
      ++pick[k];
      for (int j = k + 1; j < missing; ++j) pick[j] = pick[j - 1] + 1;
    }
  }
  if (independent) basis[have++] = q;
  if (have <= D) return;  // still in a hyperplane
  if (orient_points(basis) < 0) std::swap(basis[0], basis[1]);
  // The first cell and, across each of its facets, an infinite cell (oriented as in
  // the header: the first cell's vertex beyond the facet gives a negative sign, so
  // two of the infinite cell's finite vertices are swapped).
  const std::uint32_t c0 = new_cell();
  cells_[c0].v = basis;
  std::array<std::uint32_t, D + 1> inf{};
  for (int i = 0; i <= D; ++i) {
    inf[i] = new_cell();
    auto v = basis;
    v[i] = kInfinite;
    const int a = i == 0 ? 1 : 0, b = i == D ? D - 1 : (i == 0 ? 2 : D);
    std::swap(v[a], v[b]);
    cells_[inf[i]].v = v;
  }
  // Neighbours by matching facets (D + 2 cells: brute force).
  const std::uint32_t first = c0, last = inf[D];
  for (std::uint32_t x = first; x <= last; ++x) {
    for (int i = 0; i <= D; ++i) {
      const auto fx = sorted_facet(cells_[x].v, i);
      for (std::uint32_t y = first; y <= last; ++y) {
        if (y == x) continue;
        for (int j = 0; j <= D; ++j) {
          if (sorted_facet(cells_[y].v, j) == fx) cells_[x].n[i] = y;
        }
      }
    }
  }
  for (std::uint32_t x = first; x <= last; ++x) {
    for (const std::uint32_t v : cells_[x].v) vcell_[v] = x;
  }
  full_ = true;
  hint_ = c0;
  std::vector<std::uint32_t> rest;
  rest.reserve(pending_.size());
  for (const std::uint32_t r : pending_) {
    if (std::find(basis.begin(), basis.end(), r) == basis.end()) rest.push_back(r);
  }
  pending_.clear();
  have = 0;
  for (const std::uint32_t r : rest) insert_local(r);
}

template <int D>
std::array<std::uint32_t, D> Triangulation<D>::sorted_facet(const std::array<std::uint32_t, D + 1>& v, int i) {
  std::array<std::uint32_t, D> f{};
  for (int k = 0, r = 0; k <= D; ++k) {
    if (k != i) f[r++] = v[k];
  }
  std::sort(f.begin(), f.end());
  return f;
}

template <int D>
std::uint32_t Triangulation<D>::locate(std::uint32_t p) const {
  // A visibility walk: from the hint, step into any neighbour across a facet that has
  // p strictly on its far side; it ends in a cell containing p (closed) or in an
  // infinite cell whose hull facet has p strictly beyond it. In a Delaunay
  // triangulation such a walk cannot cycle (Edelsbrunner 1990). The facet tested first
  // turns from walk to walk.
  std::uint32_t c = hint_;
  if (int inf = infinite_index(c); inf >= 0) c = cells_[c].n[inf];
  std::uint32_t from = kNone;
  for (;;) {
    bool moved = false;
    const int turn = static_cast<int>(walk_turn_++ % (D + 1));
    for (int j = 0; j <= D; ++j) {
      const int i = (j + turn) % (D + 1);
      const std::uint32_t nb = cells_[c].n[i];
      if (nb == from) continue;  // p is on c's side of the facet it came through
      if (orient_with(c, i, coords(p), global_[p]) < 0) {
        ++stats_.walk_steps;
        from = c;
        c = nb;
        moved = true;
        break;
      }
    }
    if (!moved) return c;
    if (infinite_index(c) >= 0) return c;
  }
}

template <int D>
void Triangulation<D>::insert_local(std::uint32_t p) {
  const std::uint32_t start_cell = locate(p);
  // Marks: 2 gen in conflict, 2 gen + 1 tested and not.
  if (gen_ >= 0x7FFFFFF0u) {
    for (Cell& c : cells_) c.mark = 0;
    for (Ridge& r : ridges_) r.gen = 0;
    gen_ = 0;
  }
  ++gen_;
  const std::uint32_t in = 2 * gen_, out = 2 * gen_ + 1;
  const double* px = coords(p);
  const std::uint32_t pid = global_[p];
  stack_.clear();
  cavity_.clear();
  boundary_.clear();
  SPOKEMESH_INVARIANT(conflict_at(start_cell, coords(p), global_[p]), "the cell holding a new point conflicts with it");
  cells_[start_cell].mark = in;
  stack_.push_back(start_cell);
  while (!stack_.empty()) {
    const std::uint32_t c = stack_.back();
    stack_.pop_back();
    cavity_.push_back(c);
    for (int i = 0; i <= D; ++i) {
      const std::uint32_t nb = cells_[c].n[i];
      const std::uint32_t m = cells_[nb].mark;
      if (m == in) continue;
      if (m != out && conflict_at(nb, px, pid)) {
        cells_[nb].mark = in;
        stack_.push_back(nb);
        continue;
      }
      cells_[nb].mark = out;
      boundary_.push_back({c, i});
    }
  }
  // One new cell per boundary facet: the cavity cell with p in place of the vertex
  // opposite that facet (p sees the facet from the cavity's side, so the orientation
  // is kept). Its neighbour across that facet is the cell outside; across each other
  // facet (all through p) it is the new cell on the same ridge, paired by hashing the
  // ridge (the facet's vertices but one).
  const std::size_t count = boundary_.size();
  std::size_t table = 64;
  while (table < 4 * count * D) table *= 2;
  if (ridges_.size() < table) ridges_.assign(table, Ridge{0, 0, 0, 0});
  const std::size_t mask = table - 1;
  // The table holds entries of this insertion only (gen_ stamps them).
  std::uint32_t last = kNone;
  for (const Boundary& b : boundary_) {
    const std::uint32_t nc = new_cell();
    last = nc;
    Cell& cell = cells_[nc];
    const Cell& old = cells_[b.cell];
    cell.v = old.v;
    cell.v[b.facet] = p;
    const std::uint32_t outside = old.n[b.facet];
    cell.n[b.facet] = outside;
    Cell& across = cells_[outside];
    for (int j = 0; j <= D; ++j) {
      if (across.n[j] == b.cell) {
        across.n[j] = nc;
        break;
      }
    }
    for (int k = 0; k <= D; ++k) {
      if (k == b.facet) continue;
      // The ridge: the vertices other than v[facet] (now p) and v[k].
      std::uint64_t key;
      if constexpr (D == 2) {
        key = cell.v[3 - b.facet - k];
      } else {
        const std::uint32_t r0 = cell.v[kOthers[b.facet][k][0]], r1 = cell.v[kOthers[b.facet][k][1]];
        key = r0 < r1 ? (std::uint64_t{r0} << 32 | r1) : (std::uint64_t{r1} << 32 | r0);
      }
      std::size_t s = (key * 0x9E3779B97F4A7C15ull) >> 40 & mask;
      for (;;) {
        Ridge& e = ridges_[s];
        if (e.gen != gen_) {
          e = Ridge{key, nc, gen_, k};
          break;
        }
        if (e.key == key) {
          cell.n[k] = e.cell;
          cells_[e.cell].n[e.facet] = nc;
          e.key = ~0ull;  // paired (a ridge has exactly two new cells)
          break;
        }
        s = (s + 1) & mask;
      }
    }
    for (const std::uint32_t v : cell.v) vcell_[v] = nc;
  }
  for (const std::uint32_t c : cavity_) {
    cells_[c].v[0] = kNone;
    free_.push_back(c);
  }
  ++stats_.insertions;
  stats_.cavity_cells += cavity_.size();
  hint_ = last;
}

template <int D>
void Triangulation<D>::incident_cells(std::uint32_t v, std::vector<std::uint32_t>& out,
                                      std::vector<std::uint32_t>& seen) const {
  // A search over the cells around v across the facets through v; `seen` is a small
  // open-addressing set of the cells met, kept at most half full (the caller's, so
  // concurrent reads each bring their own).
  const std::size_t first = out.size();
  seen.assign(64, kNone);
  auto insert_seen = [&](std::uint32_t c) {
    const std::size_t mask = seen.size() - 1;
    std::size_t s = (c * 0x9E3779B1u) & mask;
    while (seen[s] != kNone) {
      if (seen[s] == c) return false;
      s = (s + 1) & mask;
    }
    seen[s] = c;
    return true;
  };
  out.push_back(vcell_[v]);
  insert_seen(vcell_[v]);
  for (std::size_t i = first; i < out.size(); ++i) {
    const Cell& cell = cells_[out[i]];
    for (int k = 0; k <= D; ++k) {
      if (cell.v[k] == v) continue;
      if (2 * (out.size() - first + 1) > seen.size()) {
        seen.assign(seen.size() * 4, kNone);
        for (std::size_t j = first; j < out.size(); ++j) insert_seen(out[j]);
      }
      if (insert_seen(cell.n[k])) out.push_back(cell.n[k]);
    }
  }
}

template <int D>
bool Triangulation<D>::valid(std::string* why) const {
  auto fail = [&](const std::string& what) {
    if (why != nullptr) *why = what;
    return false;
  };
  if (!full_) return true;
  std::vector<bool> dead(cells_.size(), false);
  for (const std::uint32_t c : free_) dead[c] = true;
  for (std::uint32_t c = 0; c < cells_.size(); ++c) {
    if (dead[c]) continue;
    const Cell& cell = cells_[c];
    const int inf = infinite_index(c);
    if (inf < 0 && orient_points(cell.v) <= 0) return fail("a finite cell is not positively oriented");
    for (int i = 0; i <= D; ++i) {
      const std::uint32_t nb = cell.n[i];
      if (nb >= cells_.size() || dead[nb]) return fail("a neighbour is not a live cell");
      int back = -1;
      for (int j = 0; j <= D; ++j) {
        if (cells_[nb].n[j] == c) back = j;
      }
      if (back < 0) return fail("neighbours are not mutual");
      // The shared facet: the same vertices.
      if (sorted_facet(cell.v, i) != sorted_facet(cells_[nb].v, back)) return fail("neighbours do not share the facet");
      const std::uint32_t apex = cells_[nb].v[back];
      if (inf < 0 && apex != kInfinite && side_of_sphere(c, coords(apex), global_[apex]) < 0)
        return fail("a facet is not locally Delaunay");
      if (inf >= 0 && i == inf && orient_with(c, inf, coords(apex), global_[apex]) >= 0)
        return fail("an infinite cell is misoriented");
    }
  }
  return true;
}

template class Triangulation<2>;
template class Triangulation<3>;

}  // namespace spokemesh::detail
