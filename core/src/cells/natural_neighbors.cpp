#include "spokemesh/natural_neighbors.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>

#include <gmpxx.h>

#include "spokemesh/convex_hull.hpp"
#include "spokemesh/locate.hpp"
#include "spokemesh/point_queries.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {
namespace {

using Vec = std::array<double, 3>;

// A convex polygon clipped by halfspaces a . x <= a . m, in double, and its area: the
// 2-d fallback where Watson's construction meets a flat centre. The clipped pieces are
// a query's stolen cell parts: no decision of the mesh depends on them.
struct Halfspace {
  Vec a{}, m{};  // normal, a point on the plane
};

double height(const Halfspace& h, const Vec& x, int d) {
  double s = 0;
  for (int k = 0; k < d; ++k)
    s += h.a[static_cast<std::size_t>(k)] * (x[static_cast<std::size_t>(k)] - h.m[static_cast<std::size_t>(k)]);
  return s;
}

Vec crossing(const Vec& x, const Vec& y, double hx, double hy) {
  const double t = hx / (hx - hy);
  return {x[0] + t * (y[0] - x[0]), x[1] + t * (y[1] - x[1]), x[2] + t * (y[2] - x[2])};
}

// Sutherland-Hodgman: the part of a polygon loop with height <= 0; the new points
// (on the plane) are also appended to `cut`.
std::vector<Vec> clip_loop(const std::vector<Vec>& loop, const Halfspace& h, int d, std::vector<Vec>* cut) {
  std::vector<Vec> out;
  const std::size_t n = loop.size();
  for (std::size_t i = 0; i < n; ++i) {
    const Vec& x = loop[i];
    const Vec& y = loop[(i + 1) % n];
    const double hx = height(h, x, d), hy = height(h, y, d);
    if (hx <= 0) out.push_back(x);
    if ((hx < 0 && hy > 0) || (hx > 0 && hy < 0)) {
      const Vec c = crossing(x, y, hx, hy);
      out.push_back(c);
      if (cut != nullptr) cut->push_back(c);
    } else if (hx == 0 && cut != nullptr) {
      cut->push_back(x);
    }
  }
  return out;
}

double polygon_area(const std::vector<Vec>& p) {
  double twice = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const Vec& a = p[i];
    const Vec& b = p[(i + 1) % p.size()];
    twice += a[0] * b[1] - a[1] * b[0];
  }
  return std::fabs(twice) / 2;
}

// The circumcentre of q and a facet's d points, in double (Cramer's rule on
// differences from q); false when the simplex is flat in double.
bool circumcentre_with(const PointSet& points, const std::uint32_t* f, const double* q, Vec& out) {
  const int d = points.dimension();
  double a[3][3] = {}, b[3] = {};
  for (int r = 0; r < d; ++r) {
    const double* p = points.point(f[r]);
    for (int k = 0; k < d; ++k) {
      a[r][k] = p[k] - q[k];
      b[r] += 0.5 * a[r][k] * a[r][k];
    }
  }
  double det, y[3] = {};
  if (d == 2) {
    det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    if (!(std::fabs(det) > 0)) return false;
    y[0] = (b[0] * a[1][1] - a[0][1] * b[1]) / det;
    y[1] = (a[0][0] * b[1] - b[0] * a[1][0]) / det;
  } else {
    auto det3 = [](const double m[3][3]) {
      return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
             m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    };
    det = det3(a);
    if (!(std::fabs(det) > 0)) return false;
    for (int j = 0; j < 3; ++j) {
      double m[3][3];
      for (int r = 0; r < 3; ++r) {
        for (int k = 0; k < 3; ++k) m[r][k] = k == j ? b[r] : a[r][k];
      }
      y[j] = det3(m) / det;
    }
  }
  for (int k = 0; k < 3; ++k) out[static_cast<std::size_t>(k)] = k < d ? q[k] + y[k] : 0.0;
  return std::isfinite(out[0]) && std::isfinite(out[1]) && std::isfinite(out[2]);
}

// The filtered lifted determinant for W = d + 1 rows (sizes known at compile time, so
// no scratch is zeroed beyond them): kUnknownSign when the filter cannot tell.
template <int W>
int lifted_sign_filtered(const PointSet& points, const std::uint32_t* s, const double* q) {
  constexpr int d = W - 1;
  std::array<BoundedDouble, W * W> m;
  std::array<BoundedDouble, 1u << W> table;
  for (int r = 0; r < W; ++r) {
    const double* p = points.point(s[r]);
    BoundedDouble lift = BoundedDouble::exact(0);
    for (int k = 0; k < d; ++k) {
      const BoundedDouble diff = BoundedDouble::difference(p[k], q[k]);
      m[static_cast<std::size_t>(r * W + k)] = diff;
      lift = k == 0 ? diff * diff : lift + diff * diff;
    }
    m[static_cast<std::size_t>(r * W + d)] = lift;
  }
  minors_table_fixed<W, W>(m.data(), table.data());
  return table[(1u << W) - 1u].certified_sign();
}

// The 2-d lifted determinant written out: the same value, magnitude and rounding depth
// as BoundedDouble's operators give it (differences depth 1, lifts 3, the 2 x 2 minors
// 4, their products with the lifts 8, the sum of three 10), without its tables.
int incircle_filtered(const PointSet& points, const std::uint32_t* s, const double* q) {
  const double* a = points.point(s[0]);
  const double* b = points.point(s[1]);
  const double* c = points.point(s[2]);
  const double adx = a[0] - q[0], ady = a[1] - q[1], bdx = b[0] - q[0], bdy = b[1] - q[1];
  const double cdx = c[0] - q[0], cdy = c[1] - q[1];
  const double alift = adx * adx + ady * ady, blift = bdx * bdx + bdy * bdy, clift = cdx * cdx + cdy * cdy;
  const double bc = bdx * cdy - cdx * bdy, ca = cdx * ady - adx * cdy, ab = adx * bdy - bdx * ady;
  const double value = alift * bc + blift * ca + clift * ab;
  const double magnitude = alift * (std::fabs(bdx * cdy) + std::fabs(cdx * bdy)) +
                           blift * (std::fabs(cdx * ady) + std::fabs(adx * cdy)) +
                           clift * (std::fabs(adx * bdy) + std::fabs(bdx * ady));
  return filter::certified_sign(value, magnitude, 10);
}

}  // namespace

int in_circumsphere(const PointSet& points, const std::uint32_t* s, const double* q) {
  // L = det[(p_i - q, |p_i - q|^2)], i = 0..d: for a positively oriented simplex, q
  // lies strictly inside its circumsphere exactly when (-1)^d L > 0.
  const int d = points.dimension();
  const int w = d + 1;
  int sign = d == 2   ? incircle_filtered(points, s, q)
             : d == 3 ? lifted_sign_filtered<4>(points, s, q)
                      : BoundedDouble::kUnknownSign;
  if (sign == BoundedDouble::kUnknownSign) {
    std::vector<mpq_class> e(static_cast<std::size_t>(w * w));
    for (int r = 0; r < w; ++r) {
      const double* p = points.point(s[r]);
      mpq_class lift = 0;
      for (int k = 0; k < d; ++k) {
        const mpq_class diff = mpq_class(p[k]) - mpq_class(q[k]);
        e[static_cast<std::size_t>(r * w + k)] = diff;
        lift += diff * diff;
      }
      e[static_cast<std::size_t>(r * w + d)] = lift;
    }
    sign = sgn(exact_determinant(std::move(e), w));
  }
  return d % 2 == 0 ? sign : -sign;
}

namespace {

// The circumcentre of the triangle (0, a, b) (coordinates relative to the query), in
// double; false when flat.
bool centre_with_origin(double ax, double ay, double bx, double by, double& cx, double& cy) {
  const double det = 2 * (ax * by - ay * bx);
  if (!(std::fabs(det) > 0)) return false;
  const double a2 = ax * ax + ay * ay, b2 = bx * bx + by * by;
  cx = (by * a2 - ay * b2) / det;
  cy = (ax * b2 - bx * a2) / det;
  return std::isfinite(cx) && std::isfinite(cy);
}

// 2-d Sibson coordinates from the cavity by Watson's construction, in O(cavity): the
// boundary runs counter-clockwise around q through the natural neighbours; neighbour
// p's stolen part is the polygon of the two new Voronoi vertices on its sides (the
// centres of (q, previous, p) and (q, p, next)) and, between them, the old ones of
// the cavity triangles around p (their circumcentres), in order around p. Coordinates
// relative to q. False where a centre is flat (the caller clips instead).
bool watson_2d(const DelaunayArrays& tri, const std::vector<std::int32_t>& cavity, const double* q,
               NaturalCoordinates& out) {
  const PointSet& points = *tri.points;
  auto in_cavity = [&](std::int32_t t) { return t >= 0 && std::find(cavity.begin(), cavity.end(), t) != cavity.end(); };
  auto vertex = [&](std::int32_t t, int k) {
    return tri.simplices[static_cast<std::size_t>(t) * 3 + static_cast<std::size_t>(k % 3)];
  };
  auto rel = [&](std::uint32_t id, double& x, double& y) {
    x = points.point(id)[0] - q[0];
    y = points.point(id)[1] - q[1];
  };
  // Boundary edges a -> b (counter-clockwise), each with its cavity triangle.
  struct Edge {
    std::uint32_t a, b;
    std::int32_t t;
  };
  thread_local std::vector<Edge> edges;
  edges.clear();
  for (const std::int32_t t : cavity) {
    for (int k = 0; k < 3; ++k) {
      if (!in_cavity(tri.adjacency[static_cast<std::size_t>(t) * 3 + static_cast<std::size_t>(k)])) {
        edges.push_back({vertex(t, k + 1), vertex(t, k + 2), t});
      }
    }
  }
  auto edge_from = [&](std::uint32_t a) -> const Edge* {
    for (const Edge& e : edges) {
      if (e.a == a) return &e;
    }
    return nullptr;
  };
  out.neighbors.clear();
  out.weights.clear();
  for (const Edge& in : edges) {
    const std::uint32_t p = in.b;  // the neighbour between edge `in` and the one after it
    const Edge* next = edge_from(p);
    if (next == nullptr) return false;
    double px, py, ax, ay, bx, by;
    rel(p, px, py);
    rel(in.a, ax, ay);
    rel(next->b, bx, by);
    double x0, y0, x1, y1;
    if (!centre_with_origin(ax, ay, px, py, x0, y0) || !centre_with_origin(px, py, bx, by, x1, y1)) return false;
    // Shoelace over c(q, a, p), the old centres around p from in.t to next->t, c(q, p, b).
    double twice = 0, lx = x0, ly = y0;
    auto add = [&](double x, double y) {
      twice += lx * y - ly * x;
      lx = x;
      ly = y;
    };
    std::int32_t t = in.t;
    std::int32_t came = -1;
    for (std::size_t steps = 0; steps <= cavity.size(); ++steps) {
      double ux, uy, vx, vy, wx, wy;
      rel(vertex(t, 0), ux, uy);
      rel(vertex(t, 1), vx, vy);
      rel(vertex(t, 2), wx, wy);
      // The old centre, relative to q: u + the centre of (0, v - u, w - u).
      double cx, cy;
      if (!centre_with_origin(vx - ux, vy - uy, wx - ux, wy - uy, cx, cy)) return false;
      add(ux + cx, uy + cy);
      if (t == next->t) break;
      // Across the other edge at p (the edges at p are opposite its two other vertices).
      int j = 0;
      while (vertex(t, j) != p) ++j;
      std::int32_t forward = -1;
      for (int k : {j + 1, j + 2}) {
        const std::int32_t u = tri.adjacency[static_cast<std::size_t>(t) * 3 + static_cast<std::size_t>(k % 3)];
        if (u != came && in_cavity(u)) forward = u;
      }
      if (forward < 0) return false;
      came = t;
      t = forward;
    }
    add(x1, y1);
    add(x0, y0);
    const double area = std::fabs(twice) / 2;
    out.neighbors.push_back(p);
    out.weights.push_back(area);
  }
  // Ascending ids, as the clipping path gives them (an insertion sort: a handful), and
  // the total summed in that order: the same bits whichever simplex the walk began in.
  for (std::size_t i = 1; i < out.neighbors.size(); ++i) {
    for (std::size_t j = i; j > 0 && out.neighbors[j - 1] > out.neighbors[j]; --j) {
      std::swap(out.neighbors[j - 1], out.neighbors[j]);
      std::swap(out.weights[j - 1], out.weights[j]);
    }
  }
  double total = 0;
  for (const double x : out.weights) total += x;
  if (!(total > 0)) return false;
  for (double& x : out.weights) x /= total;
  out.where = NaturalCoordinates::Where::kInside;
  return true;
}

// A 3-d cavity's Voronoi vertices around q, relative to q: the old centres of its
// simplices and the new centres of q with each boundary facet, each with its point ids
// sorted (a new centre's 3, then kNoPoint) and the cavity simplex it belongs to (a new
// centre's: the one its facet bounds), in the order of their ids (kNoPoint last: a
// simplex's centre before its facets'), so that whatever reads them in order gets the
// same bits whichever simplex the cavity's search began in. A centre flat in double is
// left out; returns how many were.
constexpr std::uint32_t kNoPoint = 0xFFFFFFFFu;
struct CavityCentre {
  std::array<std::uint32_t, 4> ids;
  std::int32_t simplex;
  Vec x;
  bool fresh() const { return ids[3] == kNoPoint; }
};
std::size_t cavity_centres_3d(const DelaunayArrays& tri, const std::vector<std::int32_t>& cavity,
                              const std::vector<std::pair<std::int32_t, int>>& boundary, const double* q,
                              std::vector<CavityCentre>& out) {
  const PointSet& points = *tri.points;
  constexpr std::size_t w = 4;
  std::size_t flat = 0;
  out.clear();
  for (const std::int32_t s : cavity) {
    CavityCentre n{{}, s, {}};
    for (std::size_t j = 0; j < w; ++j) n.ids[j] = tri.simplices[static_cast<std::size_t>(s) * w + j];
    Vec c;
    if (!circumcentre_with(points, n.ids.data() + 1, points.point(n.ids[0]), c)) {
      ++flat;
      continue;
    }
    for (std::size_t k = 0; k < 3; ++k) n.x[k] = c[k] - q[k];
    std::sort(n.ids.begin(), n.ids.end());
    out.push_back(n);
  }
  for (const auto& [s, k] : boundary) {
    CavityCentre n{{kNoPoint, kNoPoint, kNoPoint, kNoPoint}, s, {}};
    for (std::size_t j = 0, at = 0; j < w; ++j) {
      if (static_cast<int>(j) != k) n.ids[at++] = tri.simplices[static_cast<std::size_t>(s) * w + j];
    }
    Vec c;
    if (!circumcentre_with(points, n.ids.data(), q, c)) {
      ++flat;
      continue;
    }
    for (std::size_t k2 = 0; k2 < 3; ++k2) n.x[k2] = c[k2] - q[k2];
    std::sort(n.ids.begin(), n.ids.begin() + 3);
    out.push_back(n);
  }
  std::sort(out.begin(), out.end(), [](const CavityCentre& a, const CavityCentre& b) { return a.ids < b.ids; });
  return flat;
}

// 3-d Sibson coordinates from the cavity's combinatorics, in O(neighbours x cavity):
// neighbour p's stolen part is a convex polytope whose faces are known without
// clipping. One face lies on the bisector of q and p: its vertices are the centres of
// q's new simplices at p (q and a boundary facet holding p), consecutive when their
// facets share an edge at p. One face lies on the bisector of p and each neighbour r
// it shares a cavity simplex or a boundary facet with: its vertices are the old centres
// of the cavity's simplices holding edge pr and the new centres of the (0 or 2)
// boundary facets holding it, consecutive across a facet holding pr. Each face's area
// is a fan around its vertices' mean (faces are convex), its plane is the bisector
// (known exactly), and the volume is the divergence theorem's sum of area times signed
// height over 3, taken from q: V = sum_F A_F n_F . (m_F - q) / 3. Relative to q.
// Everything is visited in the order of point ids, so the bits do not depend on the
// simplex the cavity's search began in. False where a new centre is flat in double
// (the caller falls back).
bool stolen_faces_3d(const DelaunayArrays& tri, const std::vector<std::int32_t>& cavity,
                     const std::vector<std::pair<std::int32_t, int>>& boundary, const double* q,
                     NaturalCoordinates& out) {
  const PointSet& points = *tri.points;
  constexpr std::uint32_t kNone = kNoPoint;
  using Node = CavityCentre;
  thread_local std::vector<Node> nodes_tl;
  auto& nodes = nodes_tl;
  if (cavity_centres_3d(tri, cavity, boundary, q, nodes) != 0) return false;
  // Each neighbour's nodes (the centres its stolen part has for vertices): runs of
  // (p, node), sorted. Then, within p's run, (r, node) for every other point r of a node
  // (kNone for a new centre's own face on the bisector of q and p), sorted: each run of
  // one r is a face of p's part, its vertices the run's nodes.
  thread_local std::vector<std::pair<std::uint32_t, std::uint32_t>> by_point_tl, by_other_tl;
  auto& by_point = by_point_tl;
  auto& by_other = by_other_tl;
  by_point.clear();
  for (std::uint32_t k = 0; k < nodes.size(); ++k) {
    for (const std::uint32_t v : nodes[k].ids) {
      if (v != kNone) by_point.emplace_back(v, k);
    }
  }
  std::sort(by_point.begin(), by_point.end());
  auto rel = [&](std::uint32_t id) {
    const double* p = points.point(id);
    return Vec{p[0] - q[0], p[1] - q[1], p[2] - q[2]};
  };
  // Whether the face's vertices a and b (nodes) are consecutive around it: on the
  // bisector of q and p, new centres whose facets share an edge at p (a second point);
  // on the bisector of p and r, old centres across a facet holding pr (three points
  // shared), an old centre and the new one of its own facet, or the two new ones.
  auto consecutive = [&](const Node& a, const Node& b, bool q_face) {
    int common = 0;
    for (const std::uint32_t v : a.ids) {
      if (v != kNone && std::find(b.ids.begin(), b.ids.end(), v) != b.ids.end()) ++common;
    }
    if (q_face) return common == 2;
    if (!a.fresh() && !b.fresh()) return common == 3;
    if (a.fresh() != b.fresh()) return a.simplex == b.simplex;
    return true;
  };
  out.weights.assign(out.neighbors.size(), 0.0);
  double total = 0;
  std::size_t i = 0;  // out.neighbors[i] is the run's point (both ascending)
  for (std::size_t at = 0; at < by_point.size();) {
    const std::uint32_t p = by_point[at].first;
    std::size_t end = at;
    while (end < by_point.size() && by_point[end].first == p) ++end;
    while (i < out.neighbors.size() && out.neighbors[i] < p) ++i;
    if (i == out.neighbors.size() || out.neighbors[i] != p) return false;
    by_other.clear();
    for (std::size_t e = at; e < end; ++e) {
      const Node& n = nodes[by_point[e].second];
      for (const std::uint32_t v : n.ids) {
        if (v != p) by_other.emplace_back(v, by_point[e].second);  // kNone: the face on q's bisector
      }
    }
    std::sort(by_other.begin(), by_other.end());
    const Vec pp = rel(p);
    const double p2 = pp[0] * pp[0] + pp[1] * pp[1] + pp[2] * pp[2];
    double volume = 0;
    for (std::size_t f = 0; f < by_other.size();) {
      const std::uint32_t r = by_other[f].first;
      std::size_t g = f;
      while (g < by_other.size() && by_other[g].first == r) ++g;
      if (g - f >= 3) {
        // The face's area: a fan from its vertices' mean (it is convex).
        Vec c{0, 0, 0};
        for (std::size_t e = f; e < g; ++e) {
          for (std::size_t k = 0; k < 3; ++k) c[k] += nodes[by_other[e].second].x[k];
        }
        for (double& x : c) x /= static_cast<double>(g - f);
        double area = 0;
        for (std::size_t e = f; e < g; ++e) {
          const Node& na = nodes[by_other[e].second];
          for (std::size_t h = e + 1; h < g; ++h) {
            const Node& nb = nodes[by_other[h].second];
            if (!consecutive(na, nb, r == kNone)) continue;
            const double ux = na.x[0] - c[0], uy = na.x[1] - c[1], uz = na.x[2] - c[2];
            const double vx = nb.x[0] - c[0], vy = nb.x[1] - c[1], vz = nb.x[2] - c[2];
            const double cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
            area += 0.5 * std::sqrt(cx * cx + cy * cy + cz * cz);
          }
        }
        // Its plane's signed height from q (outward from p's part): the bisector of q
        // and p at |p - q| / 2; of p and r at (|r - q|^2 - |p - q|^2) / (2 |r - p|).
        double height;
        if (r == kNone) {
          height = std::sqrt(p2) / 2;
        } else {
          const Vec rr = rel(r);
          const double r2 = rr[0] * rr[0] + rr[1] * rr[1] + rr[2] * rr[2];
          const double dx = rr[0] - pp[0], dy = rr[1] - pp[1], dz = rr[2] - pp[2];
          height = (r2 - p2) / (2 * std::sqrt(dx * dx + dy * dy + dz * dz));
        }
        volume += area * height / 3;
      }
      f = g;
    }
    out.weights[i] = volume;
    at = end;
  }
  for (const double v : out.weights) {
    if (!(v >= 0)) return false;
    total += v;
  }
  if (!(total > 0)) return false;
  for (double& x : out.weights) x /= total;
  return true;
}

// Whether Sibson's coordinates reproduce q (sum w_i (p_i - q) = 0) to 1e-9 of the
// neighbours' reach: the clipping in double keeps it to about 1e-15 on points in general
// position; on cospherical ones (a grid's), bisectors through one old Voronoi vertex
// meet in copies of it that differ in their last bits, and a clipped part can be wrong.
bool reproduces_query(const PointSet& points, const NaturalCoordinates& nn, const double* q) {
  const int d = points.dimension();
  double reach = 0;
  std::array<double, 3> sum{};
  for (std::size_t i = 0; i < nn.neighbors.size(); ++i) {
    const double* p = points.point(nn.neighbors[i]);
    for (int k = 0; k < d; ++k) {
      sum[static_cast<std::size_t>(k)] += nn.weights[i] * (p[k] - q[k]);
      reach = std::max(reach, std::fabs(p[k] - q[k]));
    }
  }
  for (int k = 0; k < d; ++k) {
    if (!(std::fabs(sum[static_cast<std::size_t>(k)]) <= 1e-9 * reach)) return false;
  }
  return true;
}

// 3-d Sibson coordinates where the faces' sum cannot be used (a flat centre) or fails
// to reproduce q (not seen on uniform, grid or clustered sets): neighbour p's stolen part is
// the convex hull of its vertices, the centres of q's new simplices at p (q and a
// boundary facet holding p) and the old centres of the cavity's simplices at p; its
// volume from an exact hull of those points (ConvexHull), so copies of one vertex that
// differ in their last bits change it by as little. Relative to q.
Status stolen_hulls_3d(const DelaunayArrays& tri, const std::vector<std::int32_t>& cavity,
                       const std::vector<std::pair<std::int32_t, int>>& boundary, const double* q,
                       NaturalCoordinates& out) {
  std::vector<CavityCentre> centres;
  cavity_centres_3d(tri, cavity, boundary, q, centres);  // a flat centre: left out of its hulls
  // (Sized here: the faces' sum may have given up before sizing them.)
  out.weights.assign(out.neighbors.size(), 0.0);
  double total = 0;
  std::vector<double> coords;
  for (std::size_t i = 0; i < out.neighbors.size(); ++i) {
    coords.clear();
    for (const CavityCentre& c : centres) {
      if (std::find(c.ids.begin(), c.ids.end(), out.neighbors[i]) == c.ids.end()) continue;
      coords.insert(coords.end(), c.x.begin(), c.x.end());
    }
    double volume = 0;
    auto hull = coords.size() >= 12 ? ConvexHull::build(coords, 3) : Result<ConvexHull>(invalid_argument("flat"));
    if (hull.is_ok()) {
      const std::vector<std::uint32_t> facets = hull->facet_vertices();
      const std::vector<std::uint32_t> vertices = hull->vertices();
      Vec mid{0, 0, 0};
      for (const std::uint32_t v : vertices) {
        for (std::size_t k = 0; k < 3; ++k) mid[k] += coords[v * 3 + k] / static_cast<double>(vertices.size());
      }
      for (std::size_t f = 0; f + 3 <= facets.size(); f += 3) {
        Vec a, b, e;
        for (std::size_t k = 0; k < 3; ++k) {
          a[k] = coords[facets[f] * 3 + k] - mid[k];
          b[k] = coords[facets[f + 1] * 3 + k] - mid[k];
          e[k] = coords[facets[f + 2] * 3 + k] - mid[k];
        }
        volume += std::fabs(a[0] * (b[1] * e[2] - b[2] * e[1]) - a[1] * (b[0] * e[2] - b[2] * e[0]) +
                            a[2] * (b[0] * e[1] - b[1] * e[0])) /
                  6;
      }
    }  // else flat: no volume stolen
    out.weights[i] = volume;
    total += volume;
  }
  if (!(total > 0)) return internal_error("natural neighbours: the query's cell has no volume");
  for (double& x : out.weights) x /= total;
  return Status::ok();
}

}  // namespace

Status natural_neighbors(const DelaunayArrays& tri, std::int32_t simplex, const double* q, NaturalCoordinates& out) {
  const PointSet& points = *tri.points;
  const int d = points.dimension();
  if (d != 2 && d != 3) {
    return invalid_argument("natural neighbours: dimension " + std::to_string(d) +
                            " is not supported (Sibson's coordinates are computed in 2-d and 3-d)");
  }
  out.where = NaturalCoordinates::Where::kOutside;
  out.neighbors.clear();
  out.weights.clear();
  if (simplex < 0) return Status::ok();  // outside the hull
  const int w = d + 1;
  const std::uint32_t* start = &tri.simplices[static_cast<std::size_t>(simplex) * w];
  // q on a point of the set: that point alone.
  for (int k = 0; k < w; ++k) {
    const double* p = points.point(start[k]);
    if (std::equal(p, p + d, q)) {
      out.where = NaturalCoordinates::Where::kInside;
      out.neighbors = {start[k]};
      out.weights = {1.0};
      return Status::ok();
    }
  }
  // q on the hull's boundary: on a hull facet of its simplex (exactly).
  for (int k = 0; k < w; ++k) {
    if (tri.adjacency[static_cast<std::size_t>(simplex) * w + k] >= 0) continue;
    std::array<std::uint32_t, kMaxDimension> facet{};
    for (int j = 0, at = 0; j < w; ++j) {
      if (j != k) facet[static_cast<std::size_t>(at++)] = start[j];
    }
    std::array<const double*, kMaxDimension + 1> corners{};
    for (int j = 0; j < d; ++j) corners[static_cast<std::size_t>(j)] = points.point(facet[static_cast<std::size_t>(j)]);
    corners[static_cast<std::size_t>(d)] = q;
    if (orientation_of(corners, d) == 0) {
      // In the canonical simplex (on a hull edge in 3-d, q lies in several), its
      // vertices ascending: the same bits whichever simplex the walk found.
      out.where = NaturalCoordinates::Where::kOnHull;
      const std::int32_t canonical = canonical_simplex(tri, simplex, q);
      std::array<std::uint32_t, kMaxDimension + 1> v{};
      std::copy_n(&tri.simplices[static_cast<std::size_t>(canonical) * w], w, v.begin());
      sort_vertices(v.data(), w);
      std::array<double, kMaxDimension + 1> bary;
      barycentric_coordinates(points, v.data(), q, bary.data());
      for (int j = 0; j < w; ++j) {
        if (bary[static_cast<std::size_t>(j)] != 0) {
          out.neighbors.push_back(v[static_cast<std::size_t>(j)]);
          out.weights.push_back(bary[static_cast<std::size_t>(j)]);
        }
      }
      return Status::ok();
    }
  }
  // The cavity: the simplices whose circumspheres hold q strictly, from q's simplex
  // across facets; its boundary facets (to a simplex not in it, or the hull) make q's
  // new simplices.
  // Scratch kept per thread: a query allocates nothing once the buffers have grown.
  thread_local std::vector<std::int32_t> cavity, tested;
  thread_local std::vector<std::pair<std::int32_t, int>> boundary;
  cavity.assign(1, simplex);
  tested.assign(1, simplex);
  boundary.clear();
  for (std::size_t i = 0; i < cavity.size(); ++i) {
    const std::int32_t s = cavity[i];
    for (int k = 0; k < w; ++k) {
      const std::int32_t t = tri.adjacency[static_cast<std::size_t>(s) * w + k];
      if (t >= 0 && std::find(cavity.begin(), cavity.end(), t) != cavity.end()) continue;
      bool inside = false;
      if (t >= 0) {
        if (std::find(tested.begin(), tested.end(), t) == tested.end()) {
          tested.push_back(t);
          if (in_circumsphere(points, &tri.simplices[static_cast<std::size_t>(t) * w], q) > 0) {
            cavity.push_back(t);
            inside = true;
          }
        } else {
          inside = std::find(cavity.begin(), cavity.end(), t) != cavity.end();
        }
      }
      if (!inside) boundary.emplace_back(s, k);
    }
  }
  // Boundary facets whose other side joined the cavity later are not boundary.
  boundary.erase(std::remove_if(boundary.begin(), boundary.end(),
                                [&](const auto& b) {
                                  const std::int32_t t =
                                      tri.adjacency[static_cast<std::size_t>(b.first) * w + b.second];
                                  return t >= 0 && std::find(cavity.begin(), cavity.end(), t) != cavity.end();
                                }),
                 boundary.end());
  if (d == 2 && watson_2d(tri, cavity, q, out)) return Status::ok();
  for (const std::int32_t s : cavity) {
    for (int k = 0; k < w; ++k) out.neighbors.push_back(tri.simplices[static_cast<std::size_t>(s) * w + k]);
  }
  std::sort(out.neighbors.begin(), out.neighbors.end());
  out.neighbors.erase(std::unique(out.neighbors.begin(), out.neighbors.end()), out.neighbors.end());
  if (d == 3) {
    // The faces' volumes; where a centre is flat in double or the answer does not
    // reproduce q (not seen on uniform, grid or clustered sets), exact hulls.
    out.where = NaturalCoordinates::Where::kInside;
    if (stolen_faces_3d(tri, cavity, boundary, q, out) && reproduces_query(points, out, q)) return Status::ok();
    return stolen_hulls_3d(tri, cavity, boundary, q, out);
  }
  // 2-d where Watson's construction met a flat centre: the query's cell clipped.
  // q's cell lies in the box of its vertices, the circumcentres of its new simplices.
  Vec lo{0, 0, 0}, hi{0, 0, 0};
  bool first = true;
  for (const auto& [s, k] : boundary) {
    std::array<std::uint32_t, kMaxDimension> facet{};
    for (int j = 0, at = 0; j < w; ++j) {
      if (j != k) facet[static_cast<std::size_t>(at++)] = tri.simplices[static_cast<std::size_t>(s) * w + j];
    }
    Vec c;
    if (!circumcentre_with(points, facet.data(), q, c)) continue;
    for (int j = 0; j < d; ++j) {
      lo[static_cast<std::size_t>(j)] = first
                                            ? c[static_cast<std::size_t>(j)]
                                            : std::min(lo[static_cast<std::size_t>(j)], c[static_cast<std::size_t>(j)]);
      hi[static_cast<std::size_t>(j)] = first
                                            ? c[static_cast<std::size_t>(j)]
                                            : std::max(hi[static_cast<std::size_t>(j)], c[static_cast<std::size_t>(j)]);
    }
    first = false;
  }
  double span = 0;
  for (int j = 0; j < d; ++j) span = std::max(span, hi[static_cast<std::size_t>(j)] - lo[static_cast<std::size_t>(j)]);
  for (int j = 0; j < d; ++j) {
    lo[static_cast<std::size_t>(j)] -= 1e-3 * span + 1e-300;
    hi[static_cast<std::size_t>(j)] += 1e-3 * span + 1e-300;
  }
  // Each neighbour's stolen part: the box, closer to q than to it, and closer to it
  // than to the other natural neighbours.
  // Everything relative to q (the origin below): the stolen parts are small near q,
  // and their coordinates keep their low bits.
  const Vec qv{0, 0, 0};
  auto at = [&](std::uint32_t id) {
    const double* p = points.point(id);
    return Vec{p[0] - q[0], p[1] - q[1], d == 3 ? p[2] - q[2] : 0.0};
  };
  for (int j = 0; j < d; ++j) {
    lo[static_cast<std::size_t>(j)] -= q[j];
    hi[static_cast<std::size_t>(j)] -= q[j];
  }
  auto bisector = [](const Vec& from, const Vec& to) {  // closer to `from` than to `to`
    Halfspace h;
    for (std::size_t k = 0; k < 3; ++k) {
      h.a[k] = to[k] - from[k];
      h.m[k] = 0.5 * (from[k] + to[k]);
    }
    return h;
  };
  double total = 0;
  out.weights.assign(out.neighbors.size(), 0.0);
  for (std::size_t i = 0; i < out.neighbors.size(); ++i) {
    const Vec pi = at(out.neighbors[i]);
    std::vector<Vec> poly{{lo[0], lo[1], 0}, {hi[0], lo[1], 0}, {hi[0], hi[1], 0}, {lo[0], hi[1], 0}};
    poly = clip_loop(poly, bisector(qv, pi), 2, nullptr);
    for (std::size_t j = 0; j < out.neighbors.size() && poly.size() >= 3; ++j) {
      if (j != i) poly = clip_loop(poly, bisector(pi, at(out.neighbors[j])), 2, nullptr);
    }
    const double measure = poly.size() >= 3 ? polygon_area(poly) : 0.0;
    out.weights[i] = measure;
    total += measure;
  }
  if (!(total > 0)) return internal_error("natural neighbours: the query's cell has no volume");
  for (double& x : out.weights) x /= total;
  out.where = NaturalCoordinates::Where::kInside;
  return Status::ok();
}

Result<NaturalCoordinates> natural_neighbors(const DelaunayArrays& tri, std::int32_t simplex, const double* q) {
  NaturalCoordinates out;
  if (Status s = natural_neighbors(tri, simplex, q, out); !s.is_ok()) return s;
  return out;
}

}  // namespace spokemesh
