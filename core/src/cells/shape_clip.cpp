// ShapeClipper (shape_domain.hpp): a convex cell intersected with a non-convex domain
// by a signed sum of convex clips. See the header for the identity it rests on.
#include <algorithm>
#include <array>
#include <cmath>

#include "cells/shape_index.hpp"
#include "spokemesh/shape_domain.hpp"

namespace spokemesh {

namespace {

using V3 = std::array<double, 3>;

V3 sub(const V3& a, const V3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
V3 add(const V3& a, const V3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
V3 scale(const V3& a, double s) { return {a[0] * s, a[1] * s, a[2] * s}; }
double dot(const V3& a, const V3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
V3 cross(const V3& a, const V3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

// A closed halfspace n . x <= c (relative coordinates).
struct Plane {
  V3 n{};
  double c = 0;
};

// Sutherland-Hodgman: the part of a polygon (a loop; in 2-d the third coordinate is 0)
// on the kept side of `p`. Points where an edge crosses the plane are appended to
// `cut` (when given): they outline the cap a convex polyhedron gets there.
void clip_loop(const std::vector<V3>& in, const Plane& p, std::vector<V3>& out, std::vector<V3>* cut) {
  out.clear();
  const std::size_t n = in.size();
  if (n == 0) return;
  double prev_s = dot(p.n, in[n - 1]) - p.c;
  for (std::size_t i = 0; i < n; ++i) {
    const V3& a = in[(i + n - 1) % n];
    const V3& b = in[i];
    const double s = dot(p.n, b) - p.c;
    if ((prev_s < 0 && s > 0) || (prev_s > 0 && s < 0)) {
      const double t = prev_s / (prev_s - s);
      const V3 x = add(a, scale(sub(b, a), t));
      out.push_back(x);
      if (cut) cut->push_back(x);
    }
    if (s <= 0) {
      out.push_back(b);
      if (s == 0 && cut) cut->push_back(b);
    }
    prev_s = s;
  }
  if (out.size() < 3) out.clear();
}

// A convex polyhedron as its faces' loops, counter-clockwise seen from outside.
struct Polyhedron {
  std::vector<std::vector<V3>> faces;
};

void clip_polyhedron(Polyhedron& poly, const Plane& p, std::vector<V3>& tmp, std::vector<V3>& cut) {
  cut.clear();
  std::size_t kept = 0;
  for (std::size_t f = 0; f < poly.faces.size(); ++f) {
    clip_loop(poly.faces[f], p, tmp, &cut);
    if (tmp.size() >= 3) std::swap(poly.faces[kept++], tmp);
  }
  poly.faces.resize(kept);
  if (cut.size() < 3) return;
  // The cap: the cut points ordered around their mean, counter-clockwise about n.
  V3 mean{0, 0, 0};
  for (const V3& x : cut) mean = add(mean, x);
  mean = scale(mean, 1.0 / static_cast<double>(cut.size()));
  const V3 n = scale(p.n, 1 / std::sqrt(dot(p.n, p.n)));  // planes' normals are not unit
  V3 u = std::abs(n[0]) < 0.9 ? cross(n, V3{1, 0, 0}) : cross(n, V3{0, 1, 0});
  const V3 v = cross(n, u);
  std::vector<std::pair<double, V3>> around;
  around.reserve(cut.size());
  for (const V3& x : cut) {
    const V3 r = sub(x, mean);
    around.emplace_back(std::atan2(dot(r, v), dot(r, u)), x);
  }
  std::sort(around.begin(), around.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<V3> cap;
  for (const auto& [angle, x] : around) {
    if (!cap.empty() && cap.back() == x) continue;
    cap.push_back(x);
  }
  if (cap.size() >= 2 && cap.front() == cap.back()) cap.pop_back();
  if (cap.size() >= 3) poly.faces.push_back(std::move(cap));
}

// Volume and first moment (about the origin) of a closed polyhedron: tetrahedra from
// the origin over each face's fan.
void measure_polyhedron(const Polyhedron& poly, double& volume, V3& moment) {
  volume = 0;
  moment = {0, 0, 0};
  for (const auto& loop : poly.faces) {
    for (std::size_t i = 1; i + 1 < loop.size(); ++i) {
      const double v = dot(loop[0], cross(loop[i], loop[i + 1])) / 6;
      volume += v;
      moment = add(moment, scale(add(add(loop[0], loop[i]), loop[i + 1]), v / 4));
    }
  }
}

// Area of a planar loop (3-d), along unit normal n.
double loop_area(const std::vector<V3>& loop, const V3& n) {
  V3 a{0, 0, 0};
  for (std::size_t i = 1; i + 1 < loop.size(); ++i) a = add(a, cross(sub(loop[i], loop[0]), sub(loop[i + 1], loop[0])));
  return std::abs(dot(a, n)) / 2;
}

// 2-d: area and moment of a counter-clockwise polygon (shoelace, about the origin).
void measure_polygon(const std::vector<V3>& poly, double& area, V3& moment) {
  area = 0;
  moment = {0, 0, 0};
  const std::size_t n = poly.size();
  for (std::size_t i = 0; i < n; ++i) {
    const V3& a = poly[i];
    const V3& b = poly[(i + 1) % n];
    const double cr = a[0] * b[1] - a[1] * b[0];
    area += cr / 2;
    moment[0] += (a[0] + b[0]) * cr / 6;
    moment[1] += (a[1] + b[1]) * cr / 6;
  }
}

// The parameters [t0, t1] of the part of segment ab on the kept side of every plane
// (skipping plane `skip`); false when none.
bool segment_range(const V3& a, const V3& b, const Plane* planes, std::size_t count, double& t0, double& t1,
                   std::size_t skip = SIZE_MAX) {
  t0 = 0;
  t1 = 1;
  for (std::size_t k = 0; k < count && t0 <= t1; ++k) {
    if (k == skip) continue;
    const double sa = dot(planes[k].n, a) - planes[k].c, sb = dot(planes[k].n, b) - planes[k].c;
    if (sa > 0 && sb > 0) return false;
    if (sa <= 0 && sb <= 0) continue;
    const double t = sa / (sa - sb);
    if (sa > 0)
      t0 = std::max(t0, t);
    else
      t1 = std::min(t1, t);
  }
  return t1 > t0;
}

// 2-d: length of the part of segment ab on the kept side of every plane.
double segment_length(const V3& a, const V3& b, const Plane* planes, std::size_t count) {
  double t0, t1;
  if (!segment_range(a, b, planes, count, t0, t1)) return 0;
  return std::hypot(b[0] - a[0], b[1] - a[1]) * (t1 - t0);
}

V3 lerp(const V3& a, const V3& b, double t) { return add(a, scale(sub(b, a), t)); }

}  // namespace

struct ShapeClipper::Scratch {
  std::vector<std::uint32_t> stamp;
  std::uint32_t epoch = 0;
  std::vector<std::uint32_t> candidates;
  Polyhedron cell, work;
  std::vector<V3> polygon, tmp, tmp2, cut;
  std::vector<Plane> planes;           // the cell's facets' planes
  std::vector<std::vector<V3>> facet;  // each facet's loop (3-d) or segment (2-d)
  std::vector<double> facet_area;      // of the facet inside the domain
  std::vector<double> facet_full;      // of the whole facet
  struct Wall {
    std::uint32_t face;
    double area;
    std::vector<V3> outline;  // with geometry: its loop (3-d) or its two ends (2-d)
  };
  std::vector<Wall> walls;
  std::vector<std::pair<double, int>> crossings;
  double origin[3] = {0, 0, 0};  // o: the cell's coordinates are relative to it
  double volume = 0;             // the clipped cell's, and its first moment about o
  V3 moment{0, 0, 0};
};

ShapeClipper::ShapeClipper(const PointSet& points, const ShapeDomain& shape)
    : points_(points), shape_(shape), scratch_(std::make_unique<Scratch>()) {
  scratch_->stamp.assign(shape.face_count(), 0);
}

ShapeClipper::~ShapeClipper() = default;

Result<Domain> ShapeClipper::box(const PointSet& points, const ShapeDomain& shape) {
  const int d = points.dimension();
  std::vector<double> lo(d, INFINITY), hi(d, -INFINITY);
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (int c = 0; c < d; ++c) {
      lo[c] = std::min(lo[c], points.point(i)[c]);
      hi[c] = std::max(hi[c], points.point(i)[c]);
    }
  }
  return box(std::move(lo), std::move(hi), shape);
}

Result<Domain> ShapeClipper::box(std::vector<double> lo, std::vector<double> hi, const ShapeDomain& shape) {
  const int d = shape.dimension();
  if (static_cast<int>(lo.size()) != d || static_cast<int>(hi.size()) != d) {
    return invalid_argument("the domain is " + std::to_string(d) + "-d (" + shape.describe() + "); the points are " +
                            std::to_string(lo.size()) + "-d");
  }
  // The union of both boxes, grown by 2^-10 of its largest extent on every side: no
  // wall of the box touches the domain, and the cells of seeds at the set's edge stay
  // small (grown by an eighth, a 1M grid's cells took 2.4x as long: bench/README.md).
  double extent = 0;
  for (int c = 0; c < d; ++c) {
    lo[c] = std::min(lo[c], shape.lower()[c]);
    hi[c] = std::max(hi[c], shape.upper()[c]);
    extent = std::max(extent, hi[c] - lo[c]);
  }
  for (int c = 0; c < d; ++c) {
    lo[c] -= std::ldexp(extent, -10);
    hi[c] += std::ldexp(extent, -10);
  }
  return Domain::box(lo, hi);
}

// clip() in steps: the faces near the cell (scan_faces), the cell's origin and its
// winding number (place_origin), the cell as loops and planes relative to it
// (load_cell), each face's wall and shadow (cut_by_face), then the facets and measures
// (assemble). The steps share Scratch.
void ShapeClipper::clip(std::uint32_t seed, VoronoiCell& cell) {
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  const FaceScan scan = scan_faces(cell);
  cell.clipped = true;
  cell.bounded = true;
  bool overlap = true;
  for (int c = 0; c < d; ++c) overlap = overlap && scan.hi[c] >= ix.lo[c] && scan.lo[c] <= ix.hi[c];
  if (!overlap || (!scan.any_face && scan.winding_hint == 0)) {
    // Beyond the domain's box, or no face near and outside: nothing of the domain.
    cell.volume = 0;
    cell.centroid.clear();
    cell.facets.clear();
    keep_measures_only(cell);
    cell.vertices.clear();
    return;
  }
  if (!scan.any_face && scan.winding_hint == 1) {
    // No face near and inside: the cell is wholly in the domain.
    if (!geometry_) keep_measures_only(cell);
    return;
  }
  const int w = place_origin(seed, cell);
  load_cell(seed, cell, w);
  bool cut = false;
  for (const std::uint32_t f : s.candidates) cut = cut_by_face(seed, cell, f) || cut;
  if (cut) ++cut_cells_;
  if (!cut && w == 1) {
    // Inside, meeting no face: the convex cell itself (its geometry too, when asked).
    std::vector<VoronoiFacet> kept;
    for (VoronoiFacet& f : cell.facets) {
      if (f.neighbor >= 0) kept.push_back(std::move(f));
    }
    cell.facets = std::move(kept);
    if (!geometry_) keep_measures_only(cell);
    return;
  }
  assemble(cell, w);
}

ShapeClipper::FaceScan ShapeClipper::scan_faces(const VoronoiCell& cell) {
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  // Faces whose boxes meet the cell's box.
  FaceScan scan;
  const std::size_t nv = cell.vertex_count();
  for (std::size_t v = 0; v < nv; ++v) {
    for (int c = 0; c < d; ++c) {
      scan.lo[c] = std::min(scan.lo[c], cell.vertices[v * d + c]);
      scan.hi[c] = std::max(scan.hi[c], cell.vertices[v * d + c]);
    }
  }
  if (++s.epoch == 0) {
    std::fill(s.stamp.begin(), s.stamp.end(), 0);
    s.epoch = 1;
  }
  s.candidates.clear();
  int from[3], to[3];
  ix.cell_range(scan.lo, scan.hi, from, to);
  int at[3];
  for (at[2] = from[2]; at[2] <= to[2]; ++at[2]) {
    for (at[1] = from[1]; at[1] <= to[1]; ++at[1]) {
      for (at[0] = from[0]; at[0] <= to[0]; ++at[0]) {
        const std::size_t id = ix.cell_id(at);
        if (ix.cell_start[id] == ix.cell_start[id + 1]) {
          const int w = ix.cell_winding[id];
          scan.winding_hint = scan.winding_hint == -2 ? w : (scan.winding_hint == w ? w : -3);
          continue;
        }
        scan.any_face = true;
        for (std::uint32_t k = ix.cell_start[id]; k < ix.cell_start[id + 1]; ++k) {
          const std::uint32_t f = ix.cell_faces[k];
          if (s.stamp[f] == s.epoch) continue;
          s.stamp[f] = s.epoch;
          s.candidates.push_back(f);
        }
      }
    }
  }
  return scan;
}

int ShapeClipper::place_origin(std::uint32_t seed, const VoronoiCell& cell) {
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  const double* p = points_.point(seed);
  const std::size_t nv = cell.vertex_count();
  // The origin o: the seed, or (when the seed lies on the boundary) a point nudged
  // from it towards the cell's vertex mean, which stays inside the convex cell.
  double* o = s.origin;
  o[0] = p[0];
  o[1] = p[1];
  o[2] = d > 2 ? p[2] : 0;
  int w = ix.winding(o, s.stamp, s.epoch);
  if (w == 2) {
    double mean[3] = {0, 0, 0};
    for (std::size_t v = 0; v < nv; ++v)
      for (int c = 0; c < d; ++c) mean[c] += cell.vertices[v * d + c] / static_cast<double>(nv);
    for (int k = 10; w == 2 && k < 60; k += 10) {
      for (int c = 0; c < d; ++c) o[c] = p[c] + std::ldexp(mean[c] - p[c], -k);
      w = ix.winding(o, s.stamp, s.epoch);
    }
  }
  return w;
}

void ShapeClipper::load_cell(std::uint32_t seed, const VoronoiCell& cell, int w) {
  Scratch& s = *scratch_;
  const int d = shape_.index().d;
  const double* p = points_.point(seed);
  const double* o = s.origin;
  // Relative coordinates (to o): the cell, its facets and planes.
  auto rel = [&](const double* x) { return V3{x[0] - o[0], x[1] - o[1], d > 2 ? x[2] - o[2] : 0.0}; };
  const std::size_t nfacets = cell.facets.size();
  s.planes.resize(nfacets);
  s.facet.resize(nfacets);
  s.facet_area.assign(nfacets, 0.0);
  s.facet_full.assign(nfacets, 0.0);
  s.cell.faces.clear();
  for (std::size_t k = 0; k < nfacets; ++k) {
    const VoronoiFacet& f = cell.facets[k];
    auto& loop = s.facet[k];
    loop.clear();
    for (std::uint32_t v : f.vertices) loop.push_back(rel(&cell.vertices[static_cast<std::size_t>(v) * d]));
    V3 n{f.normal[0], f.normal[1], d > 2 ? f.normal[2] : 0.0};
    V3 mean{0, 0, 0};
    for (const V3& x : loop) mean = add(mean, x);
    if (!loop.empty()) mean = scale(mean, 1.0 / static_cast<double>(loop.size()));
    if (f.neighbor >= 0) {
      // The bisector itself: (q - p) . x <= |q - p|^2 / 2 relative to p, moved to o.
      const double* q = points_.point(static_cast<std::size_t>(f.neighbor));
      V3 qp{q[0] - p[0], q[1] - p[1], d > 2 ? q[2] - p[2] : 0.0};
      const V3 po{p[0] - o[0], p[1] - o[1], d > 2 ? p[2] - o[2] : 0.0};
      s.planes[k].n = qp;
      s.planes[k].c = dot(qp, qp) / 2 + dot(qp, po);
    } else {
      s.planes[k].n = n;
      s.planes[k].c = dot(n, mean);
    }
    if (d == 3) {
      s.facet_full[k] = loop.size() >= 3 ? loop_area(loop, n) : 0;
      if (loop.size() >= 3) s.cell.faces.push_back(loop);
    } else {
      s.facet_full[k] = loop.size() == 2 ? std::hypot(loop[1][0] - loop[0][0], loop[1][1] - loop[0][1]) : 0;
    }
  }
  std::vector<V3>& polygon = s.polygon;
  if (d == 2) {
    polygon.clear();
    for (std::size_t v = 0; v < cell.vertex_count(); ++v) polygon.push_back(rel(&cell.vertices[v * 2]));
  }
  // The measures of the cell counted w times (its origin's winding number); each face's
  // shadow then adds or takes away its part.
  s.volume = 0;
  s.moment = V3{0, 0, 0};
  if (d == 3) {
    measure_polyhedron(s.cell, s.volume, s.moment);
  } else {
    measure_polygon(polygon, s.volume, s.moment);
  }
  s.volume *= w;
  s.moment = scale(s.moment, w);
  for (std::size_t k = 0; k < nfacets; ++k) s.facet_area[k] = w * s.facet_full[k];
  s.walls.clear();
}

bool ShapeClipper::cut_by_face(std::uint32_t seed, const VoronoiCell& cell, std::uint32_t f) {
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  const double* p = points_.point(seed);
  const double* o = s.origin;
  auto rel = [&](const double* x) { return V3{x[0] - o[0], x[1] - o[1], d > 2 ? x[2] - o[2] : 0.0}; };
  const std::size_t nfacets = cell.facets.size();
  const std::uint32_t* fv = ix.face(f);
  const double* a = ix.vertex(fv[0]);
  const double* b = ix.vertex(fv[1]);
  const double* c = d == 3 ? ix.vertex(fv[2]) : nullptr;
  // The face inside the cell.
  double wall_area = 0;
  if (d == 3) {
    s.tmp = {rel(a), rel(b), rel(c)};
    for (std::size_t k = 0; k < nfacets && !s.tmp.empty(); ++k) {
      clip_loop(s.tmp, s.planes[k], s.tmp2, nullptr);
      std::swap(s.tmp, s.tmp2);
    }
    if (s.tmp.size() < 3) return false;
    const V3 n{ix.normals[3 * f], ix.normals[3 * f + 1], ix.normals[3 * f + 2]};
    wall_area = loop_area(s.tmp, n);
    if (geometry_) s.cut = s.tmp;
  } else {
    double t0, t1;
    if (!segment_range(rel(a), rel(b), s.planes.data(), nfacets, t0, t1)) return false;  // a point at most
    wall_area = std::hypot(b[0] - a[0], b[1] - a[1]) * (t1 - t0);
    if (!(wall_area > 0)) return false;
    if (geometry_) s.cut = {lerp(rel(a), rel(b), t0), lerp(rel(a), rel(b), t1)};
  }
  // On a neighbour facet's bisector (every vertex equidistant, exactly)? Then the
  // face is a wall of this cell only when the domain lies on the cell's side.
  std::size_t on_facet = nfacets;
  for (std::size_t k = 0; k < nfacets && on_facet == nfacets; ++k) {
    const std::int64_t nb = cell.facets[k].neighbor;
    if (nb < 0) continue;
    const double* q = points_.point(static_cast<std::size_t>(nb));
    bool all = distance_compare_exact(a, p, q, d) == 0 && distance_compare_exact(b, p, q, d) == 0 &&
               (c == nullptr || distance_compare_exact(c, p, q, d) == 0);
    if (all) on_facet = k;
  }
  const double* nt = &ix.normals[static_cast<std::size_t>(f) * d];
  if (on_facet != nfacets) {
    const double* nf = cell.facets[on_facet].normal.data();
    double agree = 0;
    for (int k = 0; k < d; ++k) agree += nt[k] * nf[k];
    if (agree > 0) {
      s.walls.push_back({f, wall_area, geometry_ ? s.cut : std::vector<V3>()});
      s.facet_area[on_facet] -= wall_area;  // that part of the facet is wall, not shared
    }
    return true;
  }
  s.walls.push_back({f, wall_area, geometry_ ? s.cut : std::vector<V3>()});
  // The shadow of the face from o, and its sign.
  const int side = d == 3 ? orient3d_exact(a, b, c, o) : -orient2d_exact(a, b, o);
  if (side == 0) return true;  // o on the face's line or plane: the shadow is flat
  const double sign = side < 0 ? -1.0 : 1.0;
  Plane shadow[4];
  int planes = 0;
  const V3 ra = rel(a), rb = rel(b);
  const double sigma = -side;
  if (d == 3) {
    const V3 rc = rel(c);
    shadow[planes++] = {scale(cross(ra, rb), -sigma), 0};
    shadow[planes++] = {scale(cross(rb, rc), -sigma), 0};
    shadow[planes++] = {scale(cross(rc, ra), -sigma), 0};
    const V3 N = cross(sub(rb, ra), sub(rc, ra));
    shadow[planes++] = {scale(N, side), side * dot(N, ra)};
  } else {
    shadow[planes++] = {V3{ra[1] * sigma, -ra[0] * sigma, 0}, 0};  // sigma cross(a, x) >= 0
    shadow[planes++] = {V3{-rb[1] * sigma, rb[0] * sigma, 0}, 0};  // sigma cross(x, b) >= 0
    const V3 N{rb[1] - ra[1], ra[0] - rb[0], 0};
    shadow[planes++] = {scale(N, side), side * dot(N, ra)};
  }
  double sv = 0;
  V3 sm{0, 0, 0};
  if (d == 3) {
    s.work = s.cell;
    for (int k = 0; k < planes && !s.work.faces.empty(); ++k) clip_polyhedron(s.work, shadow[k], s.tmp, s.cut);
    if (!s.work.faces.empty()) measure_polyhedron(s.work, sv, sm);
  } else {
    s.tmp = s.polygon;
    for (int k = 0; k < planes && !s.tmp.empty(); ++k) {
      clip_loop(s.tmp, shadow[k], s.tmp2, nullptr);
      std::swap(s.tmp, s.tmp2);
    }
    if (s.tmp.size() >= 3) measure_polygon(s.tmp, sv, sm);
  }
  s.volume += sign * sv;
  s.moment = add(s.moment, scale(sm, sign));
  for (std::size_t k = 0; k < nfacets; ++k) {
    if (s.facet_full[k] == 0) continue;
    double part = 0;
    if (d == 3) {
      s.tmp = s.facet[k];
      for (int m = 0; m < planes && !s.tmp.empty(); ++m) {
        clip_loop(s.tmp, shadow[m], s.tmp2, nullptr);
        std::swap(s.tmp, s.tmp2);
      }
      if (s.tmp.size() >= 3)
        part = loop_area(s.tmp, V3{cell.facets[k].normal[0], cell.facets[k].normal[1], cell.facets[k].normal[2]});
    } else if (s.facet[k].size() == 2) {
      part = segment_length(s.facet[k][0], s.facet[k][1], shadow, static_cast<std::size_t>(planes));
    }
    s.facet_area[k] += sign * part;
  }
  return true;
}

void ShapeClipper::assemble(VoronoiCell& cell, int w) {
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  const V3 origin{s.origin[0], s.origin[1], s.origin[2]};
  // Neighbour facets with area inside the domain, then the walls by face.
  std::vector<double> vertices;
  auto add_vertex = [&](const V3& x) {
    for (int c = 0; c < d; ++c) vertices.push_back(origin[c] + x[c]);
    return static_cast<std::uint32_t>(vertices.size() / d - 1);
  };
  std::vector<VoronoiFacet> facets;
  for (std::size_t k = 0; k < cell.facets.size(); ++k) {
    VoronoiFacet& f = cell.facets[k];
    if (f.neighbor < 0) continue;  // the box's walls lie outside the domain
    const double area = s.facet_area[k];
    if (!(area > 1e-12 * s.facet_full[k])) continue;
    VoronoiFacet out;
    out.neighbor = f.neighbor;
    out.area = area;
    out.normal = f.normal;
    if (geometry_) {
      for (const auto& [from, to] : neighbour_outline(k, w)) {
        out.vertices.push_back(add_vertex(from));
        out.vertices.push_back(add_vertex(to));
      }
    }
    facets.push_back(std::move(out));
  }
  std::sort(s.walls.begin(), s.walls.end(), [](const auto& x, const auto& y) { return x.face < y.face; });
  for (const auto& wall : s.walls) {
    if (!(wall.area > 1e-12 * ix.measures[wall.face])) continue;
    VoronoiFacet out;
    out.neighbor = -1 - static_cast<std::int64_t>(wall.face);
    out.area = wall.area;
    out.normal.assign(&ix.normals[static_cast<std::size_t>(wall.face) * d],
                      &ix.normals[static_cast<std::size_t>(wall.face) * d] + d);
    for (const V3& x : wall.outline) out.vertices.push_back(add_vertex(x));
    facets.push_back(std::move(out));
  }
  cell.facets = std::move(facets);
  cell.vertex_simplices.clear();
  cell.vertices = std::move(vertices);
  if (s.volume > 0) {
    cell.volume = s.volume;
    cell.centroid.assign(d, 0);
    for (int c = 0; c < d; ++c) cell.centroid[c] = origin[c] + s.moment[c] / s.volume;
  } else {
    cell.volume = 0;
    cell.centroid.clear();
    cell.facets.clear();
    cell.vertices.clear();
  }
}

std::vector<std::pair<std::array<double, 3>, std::array<double, 3>>> ShapeClipper::neighbour_outline(std::size_t k,
                                                                                                     int w) {
  // For drawing only (double precision): the pieces of facet k inside the domain's
  // closure, as segments: its edges' parts inside, and the faces' traces across it.
  Scratch& s = *scratch_;
  const ShapeDomain::Index& ix = shape_.index();
  const int d = ix.d;
  const double* o = s.origin;
  auto rel = [&](const double* x) { return V3{x[0] - o[0], x[1] - o[1], d > 2 ? x[2] - o[2] : 0.0}; };
  std::vector<std::pair<V3, V3>> out;
  // Signed crossings of segment p -> q with the faces that meet the cell: (t, change
  // of the winding number).
  auto crossings = [&](const V3& p, const V3& q) {
    s.crossings.clear();
    for (std::uint32_t f : s.candidates) {
      const std::uint32_t* fv = ix.face(f);
      const V3 A = rel(ix.vertex(fv[0])), B = rel(ix.vertex(fv[1]));
      const double* nn = &ix.normals[static_cast<std::size_t>(f) * d];
      const V3 N{nn[0], nn[1], d > 2 ? nn[2] : 0.0};
      const double dp = dot(N, sub(p, A)), dq = dot(N, sub(q, A));
      if ((dp <= 0 && dq <= 0) || (dp >= 0 && dq >= 0)) continue;
      const double t = dp / (dp - dq);
      const V3 x = lerp(p, q, t);
      bool inside;
      if (d == 2) {
        const V3 e = sub(B, A);
        const double u = dot(sub(x, A), e) / dot(e, e);
        inside = u >= 0 && u <= 1;
      } else {
        const V3 C = rel(ix.vertex(fv[2]));
        const double s1 = dot(N, cross(sub(B, A), sub(x, A))), s2 = dot(N, cross(sub(C, B), sub(x, B))),
                     s3 = dot(N, cross(sub(A, C), sub(x, C)));
        inside = s1 >= 0 && s2 >= 0 && s3 >= 0;
      }
      if (inside) s.crossings.emplace_back(t, dp < 0 ? -1 : 1);  // out through it: -1
    }
    std::sort(s.crossings.begin(), s.crossings.end());
  };
  auto winding_at = [&](const V3& x) {
    crossings(V3{0, 0, 0}, x);
    int wx = w;
    for (const auto& c : s.crossings) wx += c.second;
    return wx;
  };
  auto inside_parts = [&](const V3& p, const V3& q) {
    int wx = winding_at(p);
    crossings(p, q);
    double from = 0;
    for (const auto& [t, change] : s.crossings) {
      if (wx > 0 && t > from) out.emplace_back(lerp(p, q, from), lerp(p, q, t));
      wx += change;
      from = t;
    }
    if (wx > 0 && from < 1) out.emplace_back(lerp(p, q, from), q);
  };
  const std::vector<V3>& loop = s.facet[k];
  if (d == 2) {
    if (loop.size() == 2) inside_parts(loop[0], loop[1]);
    return out;
  }
  for (std::size_t i = 0; i < loop.size(); ++i) inside_parts(loop[i], loop[(i + 1) % loop.size()]);
  // Faces' traces on the facet's plane, within the facet.
  const Plane& plane = s.planes[k];
  for (std::uint32_t f : s.candidates) {
    const std::uint32_t* fv = ix.face(f);
    const V3 t[3] = {rel(ix.vertex(fv[0])), rel(ix.vertex(fv[1])), rel(ix.vertex(fv[2]))};
    double h[3];
    for (int j = 0; j < 3; ++j) h[j] = dot(plane.n, t[j]) - plane.c;
    std::vector<V3> ends;
    for (int j = 0; j < 3; ++j) {
      const int m = (j + 1) % 3;
      if (h[j] == 0) ends.push_back(t[j]);
      if ((h[j] < 0 && h[m] > 0) || (h[j] > 0 && h[m] < 0)) ends.push_back(lerp(t[j], t[m], h[j] / (h[j] - h[m])));
    }
    if (ends.size() != 2) continue;  // misses the plane, touches it at a point, or lies in it
    double t0, t1;
    if (!segment_range(ends[0], ends[1], s.planes.data(), s.planes.size(), t0, t1, k)) continue;
    out.emplace_back(lerp(ends[0], ends[1], t0), lerp(ends[0], ends[1], t1));
  }
  return out;
}

}  // namespace spokemesh
