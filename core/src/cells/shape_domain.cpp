#include "spokemesh/shape_domain.hpp"

#include <gmpxx.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <unordered_map>

#include "cells/shape_index.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {

namespace {

constexpr double kEps = filter::kUnitRoundoff;
// Shewchuk's static bounds (predicates.c, ccwerrboundA and o3derrboundA): the computed
// determinant is within bound x permanent of the exact one, differences included.
constexpr double kOrient2dBound = (3.0 + 16.0 * kEps) * kEps;
constexpr double kOrient3dBound = (7.0 + 56.0 * kEps) * kEps;

int sign_of(const mpq_class& q) { return sgn(q); }

std::string vertex_text(const double* x, int d) {
  std::ostringstream s;
  s.precision(17);
  s << "(";
  for (int c = 0; c < d; ++c) s << (c ? ", " : "") << x[c];
  s << ")";
  return s.str();
}

}  // namespace

int orient2d_exact(const double* a, const double* b, const double* c) {
  // Invariant: returns the sign of the exact determinant of the doubles given.
  const double l = (b[0] - a[0]) * (c[1] - a[1]);
  const double r = (b[1] - a[1]) * (c[0] - a[0]);
  const double det = l - r;
  const double bound = kOrient2dBound * (std::abs(l) + std::abs(r));
  if (det > bound) return 1;
  if (det < -bound) return -1;
  const mpq_class e =
      (mpq_class(b[0]) - a[0]) * (mpq_class(c[1]) - a[1]) - (mpq_class(b[1]) - a[1]) * (mpq_class(c[0]) - a[0]);
  return sign_of(e);
}

int orient3d_exact(const double* a, const double* b, const double* c, const double* q) {
  // det[b - a, c - a, q - a]; filter as orient3d's stage A (with a as the origin).
  const double ux = b[0] - a[0], uy = b[1] - a[1], uz = b[2] - a[2];
  const double vx = c[0] - a[0], vy = c[1] - a[1], vz = c[2] - a[2];
  const double wx = q[0] - a[0], wy = q[1] - a[1], wz = q[2] - a[2];
  const double m1 = vy * wz, m2 = vz * wy, m3 = vz * wx, m4 = vx * wz, m5 = vx * wy, m6 = vy * wx;
  const double det = ux * (m1 - m2) + uy * (m3 - m4) + uz * (m5 - m6);
  const double permanent = std::abs(ux) * (std::abs(m1) + std::abs(m2)) + std::abs(uy) * (std::abs(m3) + std::abs(m4)) +
                           std::abs(uz) * (std::abs(m5) + std::abs(m6));
  const double bound = kOrient3dBound * permanent;
  if (det > bound) return 1;
  if (det < -bound) return -1;
  const mpq_class Ux = mpq_class(b[0]) - a[0], Uy = mpq_class(b[1]) - a[1], Uz = mpq_class(b[2]) - a[2];
  const mpq_class Vx = mpq_class(c[0]) - a[0], Vy = mpq_class(c[1]) - a[1], Vz = mpq_class(c[2]) - a[2];
  const mpq_class Wx = mpq_class(q[0]) - a[0], Wy = mpq_class(q[1]) - a[1], Wz = mpq_class(q[2]) - a[2];
  const mpq_class e = Ux * (Vy * Wz - Vz * Wy) + Uy * (Vz * Wx - Vx * Wz) + Uz * (Vx * Wy - Vy * Wx);
  return sign_of(e);
}

int distance_compare_exact(const double* x, const double* p, const double* q, int d) {
  // Each squared distance is a sum of d rounded squares of rounded differences: within
  // (d + 2) u of its exact value relative to itself; doubled for the bound's rounding.
  double sp = 0, sq = 0;
  for (int c = 0; c < d; ++c) {
    sp += (x[c] - p[c]) * (x[c] - p[c]);
    sq += (x[c] - q[c]) * (x[c] - q[c]);
  }
  const double diff = sp - sq, bound = 2 * (d + 3) * kEps * (sp + sq);
  if (diff > bound) return 1;
  if (diff < -bound) return -1;
  mpq_class e = 0;
  for (int c = 0; c < d; ++c) {
    const mpq_class dp = mpq_class(x[c]) - p[c], dq = mpq_class(x[c]) - q[c];
    e += dp * dp - dq * dq;
  }
  return sign_of(e);
}

namespace {

// The sign of the orient2d of the (y, z) projections, and of other axis pairs.
int orient_proj(const double* a, const double* b, const double* c, int u, int v) {
  const double pa[2] = {a[u], a[v]}, pb[2] = {b[u], b[v]}, pc[2] = {c[u], c[v]};
  return orient2d_exact(pa, pb, pc);
}

// Whether q (coplanar with triangle abc, which is not degenerate) lies in the closed
// triangle: decided in a projection where the triangle keeps a nonzero area.
bool in_closed_triangle(const double* a, const double* b, const double* c, const double* q) {
  static constexpr int kPairs[3][2] = {{1, 2}, {0, 2}, {0, 1}};
  for (const auto& pr : kPairs) {
    const int s = orient_proj(a, b, c, pr[0], pr[1]);
    if (s == 0) continue;
    const int s1 = orient_proj(a, b, q, pr[0], pr[1]), s2 = orient_proj(b, c, q, pr[0], pr[1]),
              s3 = orient_proj(c, a, q, pr[0], pr[1]);
    return s1 != -s && s2 != -s && s3 != -s;
  }
  return false;
}

// Whether q lies on the closed segment ab, given that the three are collinear.
bool within_segment_box(const double* a, const double* b, const double* q, int d) {
  for (int c = 0; c < d; ++c) {
    if (q[c] < std::min(a[c], b[c]) || q[c] > std::max(a[c], b[c])) return false;
  }
  return true;
}

// Whether the closed segment pq meets the closed triangle abc (3-d, exact).
bool segment_meets_triangle(const double* p, const double* q, const double* a, const double* b, const double* c) {
  const int sp = orient3d_exact(a, b, c, p), sq = orient3d_exact(a, b, c, q);
  if (sp != 0 && sp == sq) return false;
  if (sp == 0 && sq == 0) {  // coplanar: an endpoint inside, or the segment crosses an edge
    if (in_closed_triangle(a, b, c, p) || in_closed_triangle(a, b, c, q)) return true;
    static constexpr int kPairs[3][2] = {{1, 2}, {0, 2}, {0, 1}};
    for (const auto& pr : kPairs) {
      if (orient_proj(a, b, c, pr[0], pr[1]) == 0) continue;
      const double* tri[3] = {a, b, c};
      for (int e = 0; e < 3; ++e) {
        const double* u = tri[e];
        const double* v = tri[(e + 1) % 3];
        const int o1 = orient_proj(p, q, u, pr[0], pr[1]), o2 = orient_proj(p, q, v, pr[0], pr[1]);
        const int o3 = orient_proj(u, v, p, pr[0], pr[1]), o4 = orient_proj(u, v, q, pr[0], pr[1]);
        if (o1 * o2 <= 0 && o3 * o4 <= 0) {
          if (o1 == 0 && o2 == 0) {  // collinear: overlapping boxes
            if (within_segment_box(p, q, u, 3) || within_segment_box(p, q, v, 3) || within_segment_box(u, v, p, 3))
              return true;
            continue;
          }
          return true;
        }
      }
      return false;
    }
    return false;
  }
  const int s1 = orient3d_exact(p, q, a, b), s2 = orient3d_exact(p, q, b, c), s3 = orient3d_exact(p, q, c, a);
  const bool pos = s1 > 0 || s2 > 0 || s3 > 0, neg = s1 < 0 || s2 < 0 || s3 < 0;
  return !(pos && neg);
}

bool triangles_meet(const double* t[3], const double* u[3]) {
  for (int e = 0; e < 3; ++e) {
    if (segment_meets_triangle(t[e], t[(e + 1) % 3], u[0], u[1], u[2])) return true;
    if (segment_meets_triangle(u[e], u[(e + 1) % 3], t[0], t[1], t[2])) return true;
  }
  return false;
}

// Whether closed segments ab and cd (2-d) meet.
bool segments_meet(const double* a, const double* b, const double* c, const double* d) {
  const int o1 = orient2d_exact(a, b, c), o2 = orient2d_exact(a, b, d);
  const int o3 = orient2d_exact(c, d, a), o4 = orient2d_exact(c, d, b);
  if (o1 * o2 < 0 && o3 * o4 < 0) return true;
  if (o1 == 0 && within_segment_box(a, b, c, 2)) return true;
  if (o2 == 0 && within_segment_box(a, b, d, 2)) return true;
  if (o3 == 0 && within_segment_box(c, d, a, 2)) return true;
  if (o4 == 0 && within_segment_box(c, d, b, 2)) return true;
  return false;
}

// The ray from x along +x, its start perturbed to x + (0, e, e^2) for an infinitesimal
// e (Simulation of Simplicity): it then meets no edge or vertex of triangle abc. 0 when
// it misses the triangle (or runs parallel to it), else the sign of the triangle's
// normal's x component (+1: the ray leaves through it). x must not lie on the triangle.
int ray_crossing_3d(const double* a, const double* b, const double* c, const double* x) {
  const int sp = orient_proj(a, b, c, 1, 2);
  if (sp == 0) return 0;  // parallel to the ray
  const double* tri[3] = {a, b, c};
  for (int e = 0; e < 3; ++e) {
    const double* u = tri[e];
    const double* v = tri[(e + 1) % 3];
    int s = orient_proj(u, v, x, 1, 2);
    // On the edge's line in projection: the perturbation's e term, then its e^2 term.
    if (s == 0) s = u[2] != v[2] ? (u[2] > v[2] ? 1 : -1) : (v[1] > u[1] ? 1 : (v[1] < u[1] ? -1 : 0));
    if (s != sp) return 0;
  }
  // Ahead of x when x lies on the side opposite to the normal's x component.
  return orient3d_exact(a, b, c, x) == -sp ? sp : 0;
}

// The same in 2-d for edge ab, the start perturbed to x + (0, e): 0 when the ray
// misses it, else the sign of the edge's rise (+1: the ray leaves through it).
int ray_crossing_2d(const double* a, const double* b, const double* x) {
  if ((a[1] > x[1]) == (b[1] > x[1])) return 0;
  const int up = b[1] > a[1] ? 1 : -1;
  return orient2d_exact(a, b, x) == up ? up : 0;  // the crossing lies to the right of x
}

}  // namespace

void ShapeDomain::Index::cell_range(const double* box_lo, const double* box_hi, int* from, int* to) const {
  for (int c = 0; c < 3; ++c) {
    if (c >= d) {
      from[c] = to[c] = 0;
      continue;
    }
    // A relative pad of 1e-9 cell: a point on a cell's side lands in both cells, so a
    // face is found from any cell its box touches whatever the rounding of the division.
    const double a = std::floor((box_lo[c] - lo[c]) / size[c] - 1e-9);
    const double b = std::floor((box_hi[c] - lo[c]) / size[c] + 1e-9);
    from[c] = static_cast<int>(std::clamp(a, 0.0, static_cast<double>(cells[c] - 1)));
    to[c] = static_cast<int>(std::clamp(b, 0.0, static_cast<double>(cells[c] - 1)));
  }
}

void ShapeDomain::Index::build() {
  const std::size_t nf = faces.size() / static_cast<std::size_t>(d);
  normals.assign(nf * static_cast<std::size_t>(d), 0.0);
  measures.assign(nf, 0.0);
  volume = boundary = 0;
  for (std::size_t f = 0; f < nf; ++f) {
    const double* a = vertex(face(f)[0]);
    const double* b = vertex(face(f)[1]);
    double* n = normals.data() + f * static_cast<std::size_t>(d);
    if (d == 2) {
      n[0] = b[1] - a[1];
      n[1] = a[0] - b[0];
      measures[f] = std::hypot(n[0], n[1]);
      volume += 0.5 * (a[0] * b[1] - a[1] * b[0]);
    } else {
      const double* c = vertex(face(f)[2]);
      const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
      n[0] = u[1] * v[2] - u[2] * v[1];
      n[1] = u[2] * v[0] - u[0] * v[2];
      n[2] = u[0] * v[1] - u[1] * v[0];
      const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      measures[f] = 0.5 * len;
      volume += (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) +
                 a[2] * (b[0] * c[1] - b[1] * c[0])) /
                6;
    }
    const double len = d == 2 ? measures[f] : 2 * measures[f];
    for (int c = 0; c < d; ++c) n[c] /= len;
    boundary += measures[f];
  }
  lo.assign(d, INFINITY);
  hi.assign(d, -INFINITY);
  for (std::size_t v = 0; v < vertices.size() / static_cast<std::size_t>(d); ++v) {
    for (int c = 0; c < d; ++c) {
      lo[c] = std::min(lo[c], vertex(static_cast<std::uint32_t>(v))[c]);
      hi[c] = std::max(hi[c], vertex(static_cast<std::uint32_t>(v))[c]);
    }
  }
  // About one face per grid cell, cells as cubic as the box allows, at most 2^8 a side
  // (2-d: 2^11).
  double box_measure = 1;
  for (int c = 0; c < d; ++c) box_measure *= std::max(hi[c] - lo[c], 1e-300);
  const double h = std::pow(box_measure / static_cast<double>(std::max<std::size_t>(nf, 1)), 1.0 / d);
  const int most = d == 2 ? 2048 : 256;
  for (int c = 0; c < 3; ++c) {
    if (c >= d) {
      cells[c] = 1;
      size[c] = 1;
      continue;
    }
    const double extent = hi[c] - lo[c];
    cells[c] = static_cast<int>(std::clamp(std::ceil(extent / h), 1.0, static_cast<double>(most)));
    size[c] = extent > 0 ? extent / cells[c] : 1;
  }
  const std::size_t total = static_cast<std::size_t>(cells[0]) * cells[1] * cells[2];
  std::vector<std::uint32_t> count(total + 1, 0);
  auto each_cell = [&](std::size_t f, auto&& visit) {
    double flo[3], fhi[3];
    for (int c = 0; c < d; ++c) {
      flo[c] = INFINITY;
      fhi[c] = -INFINITY;
      for (int k = 0; k < d; ++k) {
        flo[c] = std::min(flo[c], vertex(face(f)[k])[c]);
        fhi[c] = std::max(fhi[c], vertex(face(f)[k])[c]);
      }
    }
    int from[3], to[3];
    cell_range(flo, fhi, from, to);
    int at[3];
    for (at[2] = from[2]; at[2] <= to[2]; ++at[2])
      for (at[1] = from[1]; at[1] <= to[1]; ++at[1])
        for (at[0] = from[0]; at[0] <= to[0]; ++at[0]) visit(cell_id(at));
  };
  for (std::size_t f = 0; f < nf; ++f) each_cell(f, [&](std::size_t id) { ++count[id + 1]; });
  for (std::size_t i = 0; i < total; ++i) count[i + 1] += count[i];
  cell_start = count;
  cell_faces.assign(cell_start[total], 0);
  for (std::size_t f = 0; f < nf; ++f) {
    each_cell(f, [&](std::size_t id) { cell_faces[count[id]++] = static_cast<std::uint32_t>(f); });
  }
  // The winding number of each cell no face touches: the same all over it (no boundary
  // passes through), so one ray a run of such cells along x.
  cell_winding.assign(total, -1);
  std::vector<std::uint32_t> stamp(nf, 0);
  std::uint32_t epoch = 0;
  for (int k = 0; k < cells[2]; ++k) {
    for (int j = 0; j < cells[1]; ++j) {
      int known = -1;
      for (int i = 0; i < cells[0]; ++i) {
        const int at[3] = {i, j, k};
        const std::size_t id = cell_id(at);
        if (cell_start[id] != cell_start[id + 1]) {
          known = -1;
          continue;
        }
        if (known < 0) {
          double centre[3];
          for (int c = 0; c < d; ++c) centre[c] = lo[c] + (at[c] + 0.5) * size[c];
          known = winding(centre, stamp, epoch);
        }
        cell_winding[id] = static_cast<std::int8_t>(known);
      }
    }
  }
}

int ShapeDomain::Index::winding(const double* x, std::vector<std::uint32_t>& stamp, std::uint32_t& epoch) const {
  // The ray from x along +x, its start perturbed to x + (0, e, e^2) (3-d) or x + (0, e)
  // (2-d) for an infinitesimal e: it then meets no edge or vertex, and crosses a face's
  // interior exactly when the tests below say so. Winding = exits - entries along it.
  for (int c = 0; c < d; ++c) {
    if (x[c] < lo[c] || x[c] > hi[c]) {
      if (c == 0 && x[c] > hi[c]) return 0;
      if (c > 0) return 0;
    }
  }
  if (++epoch == 0) {
    std::fill(stamp.begin(), stamp.end(), 0);
    epoch = 1;
  }
  int from[3], to[3];
  const double top[3] = {hi[0], d > 1 ? x[1] : 0, d > 2 ? x[2] : 0};
  cell_range(x, top, from, to);
  int w = 0;
  int at[3] = {0, 0, 0};
  for (at[2] = from[2]; at[2] <= to[2]; ++at[2]) {
    for (at[1] = from[1]; at[1] <= to[1]; ++at[1]) {
      for (at[0] = from[0]; at[0] <= to[0]; ++at[0]) {
        const std::size_t id = cell_id(at);
        for (std::uint32_t k = cell_start[id]; k < cell_start[id + 1]; ++k) {
          const std::uint32_t f = cell_faces[k];
          if (stamp[f] == epoch) continue;
          stamp[f] = epoch;
          const std::uint32_t* fv = face(f);
          if (d == 2) {
            const double* a = vertex(fv[0]);
            const double* b = vertex(fv[1]);
            if (orient2d_exact(a, b, x) == 0 && within_segment_box(a, b, x, 2)) return 2;
            w += ray_crossing_2d(a, b, x);
            continue;
          }
          const double* a = vertex(fv[0]);
          const double* b = vertex(fv[1]);
          const double* c = vertex(fv[2]);
          if (orient3d_exact(a, b, c, x) == 0 && in_closed_triangle(a, b, c, x)) return 2;
          w += ray_crossing_3d(a, b, c, x);
        }
      }
    }
  }
  return w;
}

ShapeDomain::ShapeDomain() : index_(std::make_unique<Index>()) {}
ShapeDomain::~ShapeDomain() = default;
ShapeDomain::ShapeDomain(ShapeDomain&&) noexcept = default;
ShapeDomain& ShapeDomain::operator=(ShapeDomain&&) noexcept = default;

int ShapeDomain::dimension() const { return index_->d; }
std::size_t ShapeDomain::face_count() const { return index_->face_count(); }
std::size_t ShapeDomain::vertex_count() const {
  return index_->d == 0 ? 0 : index_->vertices.size() / static_cast<std::size_t>(index_->d);
}
const std::vector<double>& ShapeDomain::vertices() const { return index_->vertices; }
const std::vector<std::uint32_t>& ShapeDomain::faces() const { return index_->faces; }
double ShapeDomain::face_measure(std::size_t face) const { return index_->measures[face]; }
const double* ShapeDomain::face_normal(std::size_t face) const {
  return index_->normals.data() + face * static_cast<std::size_t>(index_->d);
}
std::size_t ShapeDomain::component_count() const { return index_->components; }
double ShapeDomain::volume() const { return index_->volume; }
double ShapeDomain::boundary_measure() const { return index_->boundary; }
const std::vector<double>& ShapeDomain::lower() const { return index_->lo; }
const std::vector<double>& ShapeDomain::upper() const { return index_->hi; }
const std::string& ShapeDomain::source() const { return index_->source; }
std::size_t ShapeDomain::memory_bytes() const {
  const Index& ix = *index_;
  return sizeof(Index) + ix.vertices.capacity() * sizeof(double) + ix.faces.capacity() * sizeof(std::uint32_t) +
         ix.normals.capacity() * sizeof(double) + ix.measures.capacity() * sizeof(double) +
         ix.component_of_face.capacity() * sizeof(std::uint32_t) + ix.cell_start.capacity() * sizeof(std::uint32_t) +
         ix.cell_faces.capacity() * sizeof(std::uint32_t) + ix.cell_winding.capacity();
}
const ShapeDomain::Index& ShapeDomain::index() const { return *index_; }

std::string ShapeDomain::describe() const {
  std::ostringstream s;
  if (index_->d == 2) {
    s << "polygon of " << index_->components << (index_->components == 1 ? " ring" : " rings") << " (" << face_count()
      << " edges)";
  } else {
    s << "solid of " << face_count() << " triangles (" << index_->components
      << (index_->components == 1 ? " component" : " components") << ")";
  }
  if (!index_->source.empty()) s << " from " << index_->source;
  return s.str();
}

int ShapeDomain::locate(const double* x) const {
  std::vector<std::uint32_t> stamp(face_count(), 0);
  std::uint32_t epoch = 0;
  const int w = index_->winding(x, stamp, epoch);
  return w == 2 ? 0 : (w != 0 ? 1 : -1);
}

namespace {

// Per component (ring), how many other components contain its first vertex: the
// parity of crossings of the perturbed ray with each other component's faces.
std::vector<int> nesting_depths(const ShapeDomain::Index& index, const std::vector<std::uint32_t>& first_vertex) {
  const std::size_t k = index.components;
  std::vector<int> depth(k, 0);
  const std::size_t nf = index.face_count();
  for (std::size_t comp = 0; comp < k; ++comp) {
    // A ray cast over the faces of each other component: rebuild a per-component sum.
    const double* x = index.vertex(first_vertex[comp]);
    std::vector<int> crossings(k, 0);
    for (std::size_t f = 0; f < nf; ++f) {
      const std::uint32_t other = index.component_of_face[f];
      if (other == comp) continue;
      const std::uint32_t* fv = index.face(f);
      const int crossing = index.d == 2
                               ? ray_crossing_2d(index.vertex(fv[0]), index.vertex(fv[1]), x)
                               : ray_crossing_3d(index.vertex(fv[0]), index.vertex(fv[1]), index.vertex(fv[2]), x);
      if (crossing != 0) crossings[other] += 1;
    }
    for (std::size_t other = 0; other < k; ++other) depth[comp] += crossings[other] % 2;
  }
  return depth;
}

// Flips components (rings) whose orientation disagrees with their nesting, so every
// face's normal points out of the domain; then rebuilds the index.
void orient_by_nesting(ShapeDomain::Index& index, const std::vector<std::uint32_t>& first_vertex) {
  const std::vector<int> depth = nesting_depths(index, first_vertex);
  std::vector<double> signed_volume(index.components, 0.0);
  const std::size_t nf = index.face_count();
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t* fv = index.face(f);
    const double* a = index.vertex(fv[0]);
    const double* b = index.vertex(fv[1]);
    double v;
    if (index.d == 2) {
      v = a[0] * b[1] - a[1] * b[0];
    } else {
      const double* c = index.vertex(fv[2]);
      v = a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0]);
    }
    signed_volume[index.component_of_face[f]] += v;
  }
  bool flipped = false;
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t comp = index.component_of_face[f];
    const bool want_positive = depth[comp] % 2 == 0;
    if ((signed_volume[comp] > 0) != want_positive) {
      std::uint32_t* fv = index.faces.data() + f * static_cast<std::size_t>(index.d);
      std::swap(fv[0], fv[1]);
      flipped = true;
    }
  }
  if (flipped) index.build();
}

// Bounded work: the pairs of faces sharing a grid cell that validation would test.
// Faces crowded into a small part of the domain's box (a tiny detailed part inside a
// large coarse one, or one stray far vertex) put many faces in one cell; beyond the
// budget the domain is refused rather than validated for minutes.
Status check_pair_budget(const ShapeDomain::Index& ix, const std::string& where) {
  const std::size_t cells = ix.cell_start.size() - 1;
  std::uint64_t pairs = 0;
  for (std::size_t id = 0; id < cells; ++id) {
    const std::uint64_t k = ix.cell_start[id + 1] - ix.cell_start[id];
    pairs += k * (k - 1) / 2;
  }
  const std::uint64_t budget = 256 * static_cast<std::uint64_t>(ix.face_count()) + 50'000'000;
  if (pairs <= budget) return Status::ok();
  return invalid_argument(where + ": its faces crowd into a small part of its bounding box (" + std::to_string(pairs) +
                          " pairs of nearby faces to check, more than " + std::to_string(budget) +
                          "); a stray far vertex, or a small detailed part in a large coarse one, does this");
}

// Calls visit(f, g), f < g, once for each pair of faces whose boxes meet: in the grid
// cell holding the low corner of their boxes' overlap. Stops at the first error.
template <class Visit>
Status for_each_nearby_pair(const ShapeDomain::Index& ix, Visit&& visit) {
  const int d = ix.d;
  const std::size_t cells = ix.cell_start.size() - 1;
  for (std::size_t id = 0; id < cells; ++id) {
    const int at[3] = {static_cast<int>(id % ix.cells[0]), static_cast<int>((id / ix.cells[0]) % ix.cells[1]),
                       static_cast<int>(id / (static_cast<std::size_t>(ix.cells[0]) * ix.cells[1]))};
    for (std::uint32_t p = ix.cell_start[id]; p < ix.cell_start[id + 1]; ++p) {
      for (std::uint32_t q = p + 1; q < ix.cell_start[id + 1]; ++q) {
        const std::uint32_t f = std::min(ix.cell_faces[p], ix.cell_faces[q]);
        const std::uint32_t g = std::max(ix.cell_faces[p], ix.cell_faces[q]);
        double olo[3] = {0, 0, 0};
        bool apart = false;
        for (int c = 0; c < d; ++c) {
          double flo = INFINITY, fhi = -INFINITY, glo = INFINITY, ghi = -INFINITY;
          for (int k = 0; k < d; ++k) {
            flo = std::min(flo, ix.vertex(ix.face(f)[k])[c]);
            fhi = std::max(fhi, ix.vertex(ix.face(f)[k])[c]);
            glo = std::min(glo, ix.vertex(ix.face(g)[k])[c]);
            ghi = std::max(ghi, ix.vertex(ix.face(g)[k])[c]);
          }
          olo[c] = std::max(flo, glo);
          apart = apart || olo[c] > std::min(fhi, ghi);
        }
        if (apart) continue;
        int from[3], to[3];
        ix.cell_range(olo, olo, from, to);
        if (from[0] != at[0] || from[1] != at[1] || from[2] != at[2]) continue;  // another cell's pair
        if (Status st = visit(f, g); !st.is_ok()) return st;
      }
    }
  }
  return Status::ok();
}

}  // namespace

Result<ShapeDomain> ShapeDomain::polygon(std::vector<std::vector<double>> rings, const std::string& source) {
  const std::string where = source.empty() ? std::string("polygon") : source;
  if (rings.empty()) return invalid_argument(where + ": no ring");
  ShapeDomain out;
  Index& ix = *out.index_;
  ix.d = 2;
  ix.source = source;
  std::vector<std::uint32_t> first_vertex;
  for (std::size_t r = 0; r < rings.size(); ++r) {
    std::vector<double>& ring = rings[r];
    const std::string name = where + ": ring " + std::to_string(r + 1);
    if (ring.size() % 2 != 0) return invalid_argument(name + ": an odd number of coordinates");
    for (std::size_t i = 0; i < ring.size(); ++i) {
      if (!std::isfinite(ring[i])) {
        return invalid_argument(name + ", vertex " + std::to_string(i / 2 + 1) + ": a coordinate is not finite");
      }
    }
    std::size_t n = ring.size() / 2;
    if (n >= 2 && ring[0] == ring[2 * n - 2] && ring[1] == ring[2 * n - 1]) --n;  // closing vertex repeated
    if (n < 3) return invalid_argument(name + ": " + std::to_string(n) + " vertices; a ring needs at least 3");
    const std::uint32_t base = static_cast<std::uint32_t>(ix.vertices.size() / 2);
    double area2 = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t j = (i + 1) % n;
      if (ring[2 * i] == ring[2 * j] && ring[2 * i + 1] == ring[2 * j + 1]) {
        return invalid_argument(name + ": a zero-length edge (vertex " + std::to_string(i + 1) + " repeats at " +
                                vertex_text(&ring[2 * i], 2) + ")");
      }
      area2 += ring[2 * i] * ring[2 * j + 1] - ring[2 * i + 1] * ring[2 * j];
    }
    bool collinear = true;
    for (std::size_t i = 2; i < n && collinear; ++i) collinear = orient2d_exact(&ring[0], &ring[2], &ring[2 * i]) == 0;
    if (collinear) return invalid_argument(name + ": zero area (its vertices are collinear)");
    (void)area2;  // a ring of zero area that is not a line crosses itself (found below)
    first_vertex.push_back(base);
    for (std::size_t i = 0; i < n; ++i) {
      ix.vertices.push_back(ring[2 * i]);
      ix.vertices.push_back(ring[2 * i + 1]);
      ix.faces.push_back(base + static_cast<std::uint32_t>(i));
      ix.faces.push_back(base + static_cast<std::uint32_t>((i + 1) % n));
      ix.component_of_face.push_back(static_cast<std::uint32_t>(r));
    }
    if (ix.faces.size() / 2 > kMaxShapeFaces) {
      return invalid_argument(where + ": more than " + std::to_string(kMaxShapeFaces) + " edges");
    }
  }
  ix.components = rings.size();
  ix.build();
  if (Status st = check_pair_budget(ix, where); !st.is_ok()) return st;
  // Edges that meet other than at their shared vertex: crossings, touching rings, spikes.
  std::vector<std::size_t> ring_start(rings.size() + 1, 0);
  for (std::size_t f = 0; f < ix.face_count(); ++f) ring_start[ix.component_of_face[f] + 1]++;
  for (std::size_t r = 0; r < rings.size(); ++r) ring_start[r + 1] += ring_start[r];
  auto edge_name = [&](std::size_t f) {
    const std::size_t r = ix.component_of_face[f];
    return "ring " + std::to_string(r + 1) + " edge " + std::to_string(f - ring_start[r] + 1);
  };
  Status met = for_each_nearby_pair(ix, [&](std::uint32_t f, std::uint32_t g) -> Status {
    const std::uint32_t* fv = ix.face(f);
    const std::uint32_t* gv = ix.face(g);
    const double* a = ix.vertex(fv[0]);
    const double* b = ix.vertex(fv[1]);
    const double* c = ix.vertex(gv[0]);
    const double* d = ix.vertex(gv[1]);
    const bool next = fv[1] == gv[0], prev = gv[1] == fv[0];
    if (next || prev) {
      // Consecutive edges meet at their shared vertex; more only when they fold back.
      const double* far = next ? d : c;
      const double* shared = next ? b : a;
      const double* other = next ? a : b;
      if (orient2d_exact(other, shared, far) == 0) {
        // Collinear: they overlap when both run from the shared vertex the same way.
        auto cmp = [](double x, double y) { return (x > y) - (x < y); };
        const bool back =
            cmp(far[0], shared[0]) == cmp(other[0], shared[0]) && cmp(far[1], shared[1]) == cmp(other[1], shared[1]);
        if (back) {
          return invalid_argument(where + ": " + edge_name(f) + " and " + edge_name(g) +
                                  " overlap (the ring folds back at " + vertex_text(shared, 2) + ")");
        }
      }
      return Status::ok();
    }
    if (!segments_meet(a, b, c, d)) return Status::ok();
    const bool same = ix.component_of_face[f] == ix.component_of_face[g];
    return invalid_argument(
        where + ": " + edge_name(f) + " and " + edge_name(g) +
        (same ? " intersect (the ring crosses itself)" : " intersect (rings must not cross or touch)"));
  });
  if (!met.is_ok()) return met;
  orient_by_nesting(ix, first_vertex);
  if (!(ix.volume > 0)) return invalid_argument(where + ": zero area");
  return out;
}

Result<ShapeDomain> ShapeDomain::solid(std::vector<double> vertices, std::vector<std::uint32_t> triangles,
                                       const std::string& source) {
  const std::string where = source.empty() ? std::string("mesh") : source;
  if (vertices.size() % 3 != 0) return invalid_argument(where + ": vertex coordinates are not a multiple of 3");
  if (triangles.empty() || triangles.size() % 3 != 0) return invalid_argument(where + ": no triangle");
  const std::size_t nv = vertices.size() / 3, nf = triangles.size() / 3;
  if (nf > kMaxShapeFaces)
    return invalid_argument(where + ": more than " + std::to_string(kMaxShapeFaces) + " triangles");
  for (std::size_t i = 0; i < vertices.size(); ++i) {
    if (!std::isfinite(vertices[i])) {
      return invalid_argument(where + ": vertex " + std::to_string(i / 3) + ": a coordinate is not finite");
    }
  }
  // Vertices at the same coordinates are one vertex (files often repeat them).
  std::vector<std::uint32_t> order(nv);
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return std::lexicographical_compare(&vertices[3 * a], &vertices[3 * a + 3], &vertices[3 * b],
                                        &vertices[3 * b + 3]) ||
           (std::equal(&vertices[3 * a], &vertices[3 * a + 3], &vertices[3 * b]) && a < b);
  });
  std::vector<std::uint32_t> weld(nv);
  for (std::size_t i = 0; i < nv; ++i) {
    const std::uint32_t v = order[i];
    weld[v] = (i > 0 && std::equal(&vertices[3 * v], &vertices[3 * v + 3], &vertices[3 * order[i - 1]]))
                  ? weld[order[i - 1]]
                  : v;
  }
  for (std::size_t f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t v = triangles[3 * f + k];
      if (v >= nv) {
        return invalid_argument(where + ": face " + std::to_string(f) + " names vertex " + std::to_string(v) + " of " +
                                std::to_string(nv) + " (0-based)");
      }
      triangles[3 * f + k] = weld[v];
    }
  }
  ShapeDomain out;
  Index& ix = *out.index_;
  ix.d = 3;
  ix.source = source;
  ix.vertices = std::move(vertices);
  ix.faces = std::move(triangles);
  auto face_name = [&](std::size_t f) { return "face " + std::to_string(f); };
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t* t = ix.face(f);
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      return invalid_argument(where + ": " + face_name(f) + " is degenerate (a vertex repeats: zero area)");
    }
    const double* a = ix.vertex(t[0]);
    const double* b = ix.vertex(t[1]);
    const double* c = ix.vertex(t[2]);
    if (orient_proj(a, b, c, 0, 1) == 0 && orient_proj(a, b, c, 1, 2) == 0 && orient_proj(a, b, c, 0, 2) == 0) {
      return invalid_argument(where + ": " + face_name(f) + " has zero area (its vertices " + vertex_text(a, 3) + ", " +
                              vertex_text(b, 3) + ", " + vertex_text(c, 3) + " are collinear)");
    }
  }
  // Edges: each must be run once each way, by two faces.
  struct Edge {
    std::uint32_t lo, hi, face;
    bool forward;
  };
  std::vector<Edge> edges;
  edges.reserve(3 * nf);
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t* t = ix.face(f);
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t u = t[k], v = t[(k + 1) % 3];
      edges.push_back({std::min(u, v), std::max(u, v), static_cast<std::uint32_t>(f), u < v});
    }
  }
  std::sort(edges.begin(), edges.end(), [](const Edge& a, const Edge& b) {
    return a.lo != b.lo ? a.lo < b.lo : (a.hi != b.hi ? a.hi < b.hi : a.face < b.face);
  });
  std::vector<std::uint32_t> parent(nf);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (std::size_t i = 0; i < edges.size();) {
    std::size_t j = i;
    while (j < edges.size() && edges[j].lo == edges[i].lo && edges[j].hi == edges[i].hi) ++j;
    const std::string edge =
        "the edge from " + vertex_text(ix.vertex(edges[i].lo), 3) + " to " + vertex_text(ix.vertex(edges[i].hi), 3);
    if (j - i == 1) {
      return invalid_argument(where + ": open boundary: " + edge + " belongs to " + face_name(edges[i].face) +
                              " only (the mesh must be closed)");
    }
    if (j - i > 2) {
      return invalid_argument(where + ": non-manifold edge: " + edge + " belongs to " + std::to_string(j - i) +
                              " faces (" + face_name(edges[i].face) + ", " + face_name(edges[i + 1].face) + ", " +
                              face_name(edges[i + 2].face) + ")");
    }
    if (edges[i].forward == edges[i + 1].forward) {
      return invalid_argument(where + ": inconsistent orientation: " + face_name(edges[i].face) + " and " +
                              face_name(edges[i + 1].face) + " both run " + edge +
                              " the same way (neighbouring faces must run a shared edge in opposite directions)");
    }
    parent[find(edges[i].face)] = find(edges[i + 1].face);
    i = j;
  }
  ix.component_of_face.assign(nf, 0);
  std::vector<std::uint32_t> component_id(nf, UINT32_MAX), first_vertex;
  for (std::size_t f = 0; f < nf; ++f) {
    const std::uint32_t root = find(static_cast<std::uint32_t>(f));
    if (component_id[root] == UINT32_MAX) {
      component_id[root] = static_cast<std::uint32_t>(first_vertex.size());
      first_vertex.push_back(ix.face(f)[0]);
    }
    ix.component_of_face[f] = component_id[root];
  }
  ix.components = first_vertex.size();
  ix.build();
  if (Status st = check_pair_budget(ix, where); !st.is_ok()) return st;
  // Faces that meet other than along their shared edge or at their shared vertex.
  Status met = for_each_nearby_pair(ix, [&](std::uint32_t f, std::uint32_t g) -> Status {
    const std::uint32_t* fv = ix.face(f);
    const std::uint32_t* gv = ix.face(g);
    int shared = 0, f_only = -1, g_only = -1;
    for (int a = 0; a < 3; ++a) {
      bool in_g = false, in_f = false;
      for (int b = 0; b < 3; ++b) {
        in_g = in_g || fv[a] == gv[b];
        in_f = in_f || gv[a] == fv[b];
      }
      shared += in_g;
      if (!in_g) f_only = a;
      if (!in_f) g_only = a;
    }
    const double* t[3] = {ix.vertex(fv[0]), ix.vertex(fv[1]), ix.vertex(fv[2])};
    const double* u[3] = {ix.vertex(gv[0]), ix.vertex(gv[1]), ix.vertex(gv[2])};
    bool meet = false;
    if (shared == 0) {
      meet = triangles_meet(t, u);
    } else if (shared == 1) {
      // Sharing vertex v: they meet elsewhere when the edge of either opposite v meets the other.
      int fv_at = 0, gv_at = 0;
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          if (fv[a] == gv[b]) {
            fv_at = a;
            gv_at = b;
          }
        }
      }
      meet = segment_meets_triangle(t[(fv_at + 1) % 3], t[(fv_at + 2) % 3], u[0], u[1], u[2]) ||
             segment_meets_triangle(u[(gv_at + 1) % 3], u[(gv_at + 2) % 3], t[0], t[1], t[2]);
    } else if (shared == 2) {
      // Sharing an edge: they overlap only when folded flat onto each other.
      const double* far_g = u[g_only];
      if (orient3d_exact(t[0], t[1], t[2], far_g) == 0) {
        // Coplanar: folded onto each other when both far vertices lie on one side of
        // the shared edge (in a projection where f keeps its area).
        const double* e0 = t[(f_only + 1) % 3];
        const double* e1 = t[(f_only + 2) % 3];
        static constexpr int kPairs[3][2] = {{1, 2}, {0, 2}, {0, 1}};
        for (const auto& pr : kPairs) {
          const int sf = orient_proj(e0, e1, t[f_only], pr[0], pr[1]);
          if (sf == 0) continue;
          meet = orient_proj(e0, e1, far_g, pr[0], pr[1]) == sf;
          break;
        }
      }
    }
    if (!meet) return Status::ok();
    return invalid_argument(where + ": self-intersection: " + face_name(f) + " and " + face_name(g) + " intersect");
  });
  if (!met.is_ok()) return met;
  orient_by_nesting(ix, first_vertex);
  if (!(ix.volume > 0)) return invalid_argument(where + ": zero volume");
  return out;
}

}  // namespace spokemesh
