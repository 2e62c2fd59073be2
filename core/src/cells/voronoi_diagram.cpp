#include "spokemesh/voronoi_diagram.hpp"

#include <algorithm>
#include <array>
#include <numeric>
#include <thread>

#include "spokemesh/predicates.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

namespace {

using Key = std::array<std::uint32_t, kMaxDimension + 1>;

// How many chunks in_chunks makes: one per thread, but no chunk under about 1024 items.
std::size_t chunk_count(std::size_t count, unsigned threads) {
  return std::max<std::size_t>(1, std::min<std::size_t>(threads, count / 1024 + 1));
}

// Runs fn(c, begin, end) over [0, count) in chunk_count() contiguous chunks (chunk c
// gets the c-th range, so a caller that keeps per-chunk results can join them in order).
template <class Fn>
void in_chunks(std::size_t count, unsigned threads, Fn&& fn) {
  const std::size_t chunks = chunk_count(count, threads);
  std::vector<std::thread> pool;
  for (std::size_t c = 1; c < chunks; ++c) {
    pool.emplace_back([&, c] { fn(c, count * c / chunks, count * (c + 1) / chunks); });
  }
  fn(0, 0, count / chunks);
  for (std::thread& t : pool) t.join();
}

// Union-find whose root is the smallest member, so groups do not depend on the order
// of the unions.
struct Groups {
  std::vector<std::uint32_t> parent;
  explicit Groups(std::size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  std::uint32_t root(std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void join(std::uint32_t a, std::uint32_t b) {
    a = root(a), b = root(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

// Appends ids with runs of equal values (and, for a closed cycle, a last value equal
// to the first) collapsed.
void append_collapsed(std::vector<std::int32_t>& out, std::size_t from, bool cycle) {
  std::size_t w = from;
  for (std::size_t r = from; r < out.size(); ++r) {
    if (w > from && out[w - 1] == out[r]) continue;
    out[w++] = out[r];
  }
  if (cycle && w - from > 1 && out[w - 1] == out[from]) --w;
  out.resize(w);
}

// The simplices around each point, ascending (CSR).
class Incidence {
 public:
  Incidence(std::span<const std::uint32_t> simplices, int w, std::size_t n)
      : first_(n + 1, 0), around_(simplices.size()) {
    for (const std::uint32_t v : simplices) ++first_[v + 1];
    std::partial_sum(first_.begin(), first_.end(), first_.begin());
    std::vector<std::int64_t> at(first_.begin(), first_.end() - 1);
    const std::size_t m = simplices.size() / static_cast<std::size_t>(w);
    for (std::size_t s = 0; s < m; ++s) {
      for (int k = 0; k < w; ++k)
        around_[static_cast<std::size_t>(at[simplices[s * w + k]]++)] = static_cast<std::uint32_t>(s);
    }
  }
  std::span<const std::uint32_t> of(std::size_t p) const {
    return {around_.data() + first_[p], static_cast<std::size_t>(first_[p + 1] - first_[p])};
  }

 private:
  std::vector<std::int64_t> first_;
  std::vector<std::uint32_t> around_;
};

// Whether the apex lies off the circumsphere of the simplex `v` (d + 1 points), for
// d = 2 and 3, in double precision: true only when certain. The incircle and insphere
// determinants with coordinates relative to the apex, and Shewchuk's first-stage
// error bounds ("Adaptive Precision Floating-Point Arithmetic and Fast Robust
// Geometric Predicates", 1997: (10 + 96 eps) eps and (16 + 224 eps) eps times the
// permanent), which cover the subtractions too. Magnitudes where products could
// underflow are left to the exact test.
bool surely_off_sphere(const PointSet& points, const std::uint32_t* v, std::uint32_t apex, int d) {
  constexpr double eps = filter::kUnitRoundoff;
  const double* e = points.point(apex);
  if (d == 2) {
    const double* a = points.point(v[0]);
    const double* b = points.point(v[1]);
    const double* c = points.point(v[2]);
    const double adx = a[0] - e[0], ady = a[1] - e[1], bdx = b[0] - e[0], bdy = b[1] - e[1];
    const double cdx = c[0] - e[0], cdy = c[1] - e[1];
    const double bc = bdx * cdy - cdx * bdy, ca = cdx * ady - adx * cdy, ab = adx * bdy - bdx * ady;
    const double al = adx * adx + ady * ady, bl = bdx * bdx + bdy * bdy, cl = cdx * cdx + cdy * cdy;
    const double det = al * bc + bl * ca + cl * ab;
    const double permanent = (std::abs(bdx * cdy) + std::abs(cdx * bdy)) * al +
                             (std::abs(cdx * ady) + std::abs(adx * cdy)) * bl +
                             (std::abs(adx * bdy) + std::abs(bdx * ady)) * cl;
    if (!(permanent > 1e-200 && permanent < 1e200)) return false;
    return std::abs(det) > (10 + 96 * eps) * eps * permanent;
  }
  if (d != 3) return false;
  const double* a = points.point(v[0]);
  const double* b = points.point(v[1]);
  const double* c = points.point(v[2]);
  const double* f = points.point(v[3]);
  const double aex = a[0] - e[0], aey = a[1] - e[1], aez = a[2] - e[2];
  const double bex = b[0] - e[0], bey = b[1] - e[1], bez = b[2] - e[2];
  const double cex = c[0] - e[0], cey = c[1] - e[1], cez = c[2] - e[2];
  const double dex = f[0] - e[0], dey = f[1] - e[1], dez = f[2] - e[2];
  const double ab = aex * bey - bex * aey, bc = bex * cey - cex * bey, cd = cex * dey - dex * cey;
  const double da = dex * aey - aex * dey, ac = aex * cey - cex * aey, bd = bex * dey - dex * bey;
  const double abc = aez * bc - bez * ac + cez * ab;
  const double bcd = bez * cd - cez * bd + dez * bc;
  const double cda = cez * da + dez * ac + aez * cd;
  const double dab = dez * ab + aez * bd + bez * da;
  const double al = aex * aex + aey * aey + aez * aez, bl = bex * bex + bey * bey + bez * bez;
  const double cl = cex * cex + cey * cey + cez * cez, dl = dex * dex + dey * dey + dez * dez;
  const double det = (dl * abc - cl * dab) + (bl * cda - al * bcd);
  auto p2 = [](double x1, double y1, double x2, double y2) { return std::abs(x1 * y2) + std::abs(x2 * y1); };
  const double pab = p2(aex, aey, bex, bey), pbc = p2(bex, bey, cex, cey), pcd = p2(cex, cey, dex, dey);
  const double pda = p2(dex, dey, aex, aey), pac = p2(aex, aey, cex, cey), pbd = p2(bex, bey, dex, dey);
  const double pabc = std::abs(aez) * pbc + std::abs(bez) * pac + std::abs(cez) * pab;
  const double pbcd = std::abs(bez) * pcd + std::abs(cez) * pbd + std::abs(dez) * pbc;
  const double pcda = std::abs(cez) * pda + std::abs(dez) * pac + std::abs(aez) * pcd;
  const double pdab = std::abs(dez) * pab + std::abs(aez) * pbd + std::abs(bez) * pda;
  const double permanent = (dl * pabc + cl * pdab) + (bl * pcda + al * pbcd);
  if (!(permanent > 1e-200 && permanent < 1e200)) return false;
  return std::abs(det) > (16 + 224 * eps) * eps * permanent;
}

}  // namespace

std::vector<std::int32_t> simplex_adjacency(std::span<const std::uint32_t> simplices, int d, unsigned threads) {
  const int w = d + 1;
  const std::size_t m = simplices.size() / static_cast<std::size_t>(w);
  std::size_t n = 0;
  for (const std::uint32_t v : simplices) n = std::max<std::size_t>(n, std::size_t{v} + 1);
  const Incidence around(simplices, w, n);
  // A facet's two simplices both hold its smallest vertex: each point matches the
  // facets it is the smallest vertex of, among its own simplices (a few dozen), by
  // sorting their other vertices. Each facet is matched at one point, so the points'
  // writes never meet.
  std::vector<std::int32_t> adjacency(m * static_cast<std::size_t>(w), -1);
  struct Facet {
    std::array<std::uint32_t, kMaxDimension> key{};
    std::uint32_t simplex;
    std::uint8_t opposite;
    bool operator<(const Facet& o) const { return key < o.key; }
  };
  in_chunks(n, threads, [&](std::size_t, std::size_t begin, std::size_t end) {
    std::vector<Facet> facets;
    for (std::size_t a = begin; a < end; ++a) {
      facets.clear();
      for (const std::uint32_t s : around.of(a)) {
        const std::uint32_t* v = &simplices[static_cast<std::size_t>(s) * w];
        for (int k = 0; k < w; ++k) {
          if (v[k] == a) continue;
          bool smallest = true;
          for (int j = 0; j < w; ++j) smallest = smallest && (j == k || v[j] >= a);
          if (!smallest) continue;
          Facet& f = facets.emplace_back();
          int at = 0;
          for (int j = 0; j < w; ++j) {
            if (j != k && v[j] != a) f.key[static_cast<std::size_t>(at++)] = v[j];
          }
          std::sort(f.key.begin(), f.key.begin() + at);
          f.simplex = s;
          f.opposite = static_cast<std::uint8_t>(k);
        }
      }
      std::sort(facets.begin(), facets.end());
      for (std::size_t i = 0; i + 1 < facets.size(); ++i) {
        if (facets[i].key != facets[i + 1].key) continue;
        adjacency[std::size_t{facets[i].simplex} * w + facets[i].opposite] =
            static_cast<std::int32_t>(facets[i + 1].simplex);
        adjacency[std::size_t{facets[i + 1].simplex} * w + facets[i + 1].opposite] =
            static_cast<std::int32_t>(facets[i].simplex);
        ++i;
      }
    }
  });
  return adjacency;
}

VoronoiDiagram voronoi_diagram(const PointSet& points, std::span<const std::uint32_t> simplices,
                               std::span<const std::int32_t> adjacency, unsigned threads) {
  const int d = points.dimension();
  const int w = d + 1;
  const std::size_t n = points.size();
  const std::size_t m = simplices.size() / static_cast<std::size_t>(w);
  const Predicates predicates(points);
  threads = std::max(1u, threads);
  VoronoiDiagram out;

  // 1. Simplices that share a circumsphere: across each interior facet, the far
  // simplex's apex on the near one's sphere (the exact sign, unperturbed, is 0). The
  // signs are computed in parallel, the groups joined after.
  std::vector<std::uint8_t> cospherical(m * static_cast<std::size_t>(w), 0);
  in_chunks(m, threads, [&](std::size_t, std::size_t begin, std::size_t end) {
    std::array<Row, kMaxDimension + 1> rows;
    for (std::size_t s = begin; s < end; ++s) {
      const std::uint32_t* v = &simplices[s * w];
      for (int k = 0; k < w; ++k) {
        const std::int32_t t = adjacency[s * w + k];
        if (t < 0 || static_cast<std::size_t>(t) < s) continue;
        const std::uint32_t* u = &simplices[static_cast<std::size_t>(t) * w];
        std::uint32_t apex = u[0];
        for (int j = 0; j < w; ++j) {
          if (adjacency[static_cast<std::size_t>(t) * w + j] == static_cast<std::int32_t>(s)) apex = u[j];
        }
        if (surely_off_sphere(points, v, apex, d)) continue;
        for (int r = 0; r < d; ++r) rows[r] = Row::of_point(v[r + 1]);
        rows[d] = Row::of_point(apex);
        cospherical[s * w + k] = predicates.lifted_sign_unperturbed(v[0], std::span<const Row>(rows.data(), w)) == 0;
      }
    }
  });
  Groups groups(m);
  for (std::size_t s = 0; s < m; ++s) {
    for (int k = 0; k < w; ++k) {
      if (cospherical[s * w + k])
        groups.join(static_cast<std::uint32_t>(s), static_cast<std::uint32_t>(adjacency[s * w + k]));
    }
  }
  cospherical = {};

  // 2. Vertices: each group's smallest simplex as a sorted tuple, the groups in the
  // order of those tuples.
  std::vector<Key> keys(m);
  for (std::size_t s = 0; s < m; ++s) {
    Key& key = keys[s];
    key.fill(0);
    std::copy_n(&simplices[s * w], w, key.begin());
    std::sort(key.begin(), key.begin() + w);
  }
  std::vector<std::uint32_t> smallest(m, UINT32_MAX);  // per root: its smallest simplex
  for (std::size_t s = 0; s < m; ++s) {
    const std::uint32_t r = groups.root(static_cast<std::uint32_t>(s));
    if (smallest[r] == UINT32_MAX || keys[s] < keys[smallest[r]]) smallest[r] = static_cast<std::uint32_t>(s);
  }
  std::vector<std::uint32_t> representatives;
  for (std::size_t s = 0; s < m; ++s) {
    if (groups.root(static_cast<std::uint32_t>(s)) == s) representatives.push_back(smallest[s]);
  }
  std::sort(representatives.begin(), representatives.end(),
            [&](std::uint32_t a, std::uint32_t b) { return keys[a] < keys[b]; });
  std::vector<std::int64_t> vertex_of_root(m, -1);
  for (std::size_t k = 0; k < representatives.size(); ++k) {
    vertex_of_root[groups.root(representatives[k])] = static_cast<std::int64_t>(k);
  }
  out.vertex_of_simplex.resize(m);
  for (std::size_t s = 0; s < m; ++s)
    out.vertex_of_simplex[s] = vertex_of_root[groups.root(static_cast<std::uint32_t>(s))];
  vertex_of_root = {};
  out.vertices.resize(representatives.size() * static_cast<std::size_t>(d));
  in_chunks(representatives.size(), threads, [&](std::size_t, std::size_t begin, std::size_t end) {
    for (std::size_t k = begin; k < end; ++k) {
      const std::vector<double> c = circumcentre(points, keys[representatives[k]].data(), w);
      std::copy(c.begin(), c.end(), out.vertices.begin() + static_cast<std::ptrdiff_t>(k * d));
    }
  });
  keys = {};

  // 3. The simplices around each point (ascending).
  const Incidence incidence(simplices, w, n);
  // 4. Per point, its region and the ridges to its larger neighbours, in chunks of
  // points joined in order.
  const std::size_t chunks = chunk_count(n, threads);
  struct Part {
    std::vector<std::int64_t> region_sizes, ridge_sizes;
    std::vector<std::int32_t> regions, ridge_vertices;
    std::vector<std::uint32_t> ridge_points;
  };
  std::vector<Part> parts(chunks);
  auto position_in = [&](std::uint32_t s, std::uint32_t p) {
    for (int k = 0; k < w; ++k) {
      if (simplices[static_cast<std::size_t>(s) * w + k] == p) return k;
    }
    return -1;
  };
  auto vertex = [&](std::uint32_t s) { return static_cast<std::int32_t>(out.vertex_of_simplex[s]); };
  in_chunks(n, threads, [&](std::size_t c, std::size_t begin, std::size_t end) {
    Part& part = parts[c];
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;       // (q, simplex), by q
    std::vector<std::pair<std::uint32_t, std::uint32_t>> neighbours;  // (q, count, then start)
    std::vector<std::uint32_t> fill;
    for (std::size_t p = begin; p < end; ++p) {
      const auto p32 = static_cast<std::uint32_t>(p);
      const std::span<const std::uint32_t> around = incidence.of(p);
      const std::uint32_t* star = around.data();
      const std::size_t size = around.size();
      // The region.
      const std::size_t region_at = part.regions.size();
      bool unbounded = false;
      std::uint32_t start = size ? star[0] : 0;
      for (std::size_t i = 0; i < size; ++i) {
        const std::uint32_t s = star[i];
        for (int k = 0; k < w; ++k) {
          if (simplices[static_cast<std::size_t>(s) * w + k] != p32 &&
              adjacency[static_cast<std::size_t>(s) * w + k] < 0) {
            // In 2-d the walk starts where the hull edge is the clockwise side.
            const int i_p = position_in(s, p32);
            if (!unbounded && (d != 2 || k == (i_p + 2) % 3)) start = s;
            unbounded = unbounded || d != 2 || k == (i_p + 2) % 3;
          }
        }
      }
      if (size != 0) {
        if (unbounded) part.regions.push_back(-1);
        const std::size_t path_at = part.regions.size();
        if (d == 2) {
          // Counter-clockwise: from triangle (p, a, b), positively oriented, the next
          // one shares edge (p, b), across from a.
          std::uint32_t s = start;
          for (std::size_t steps = 0; steps < size; ++steps) {
            part.regions.push_back(vertex(s));
            const int i_p = position_in(s, p32);
            const std::int32_t next =
                adjacency[static_cast<std::size_t>(s) * 3 + static_cast<std::size_t>((i_p + 1) % 3)];
            if (next < 0 || static_cast<std::uint32_t>(next) == start) break;
            s = static_cast<std::uint32_t>(next);
          }
          append_collapsed(part.regions, path_at, !unbounded);
          if (!unbounded) {
            std::rotate(
                part.regions.begin() + static_cast<std::ptrdiff_t>(path_at),
                std::min_element(part.regions.begin() + static_cast<std::ptrdiff_t>(path_at), part.regions.end()),
                part.regions.end());
          }
        } else {
          for (std::size_t i = 0; i < size; ++i) part.regions.push_back(vertex(star[i]));
          std::sort(part.regions.begin() + static_cast<std::ptrdiff_t>(path_at), part.regions.end());
          part.regions.erase(
              std::unique(part.regions.begin() + static_cast<std::ptrdiff_t>(path_at), part.regions.end()),
              part.regions.end());
        }
      }
      part.region_sizes.push_back(static_cast<std::int64_t>(part.regions.size() - region_at));

      // The ridges to larger neighbours q: the simplices holding edge (p, q), grouped
      // by q (a point has a few dozen neighbours: found by a linear search, grouped by
      // a counting pass, taken in ascending q).
      neighbours.clear();
      for (std::size_t i = 0; i < size; ++i) {
        for (int k = 0; k < w; ++k) {
          const std::uint32_t q = simplices[static_cast<std::size_t>(star[i]) * w + k];
          if (q <= p32) continue;
          auto at = std::find_if(neighbours.begin(), neighbours.end(), [&](const auto& x) { return x.first == q; });
          if (at == neighbours.end()) {
            neighbours.emplace_back(q, 1);
          } else {
            ++at->second;
          }
        }
      }
      std::sort(neighbours.begin(), neighbours.end());
      edges.resize(0);
      for (auto& [q, count] : neighbours) {
        const std::uint32_t simplices_of_q = count;
        count = static_cast<std::uint32_t>(edges.size());  // now: where q's simplices start
        edges.resize(edges.size() + simplices_of_q, {q, 0});
      }
      fill.assign(neighbours.size(), 0);
      for (std::size_t i = 0; i < size; ++i) {
        for (int k = 0; k < w; ++k) {
          const std::uint32_t q = simplices[static_cast<std::size_t>(star[i]) * w + k];
          if (q <= p32) continue;
          const auto at = static_cast<std::size_t>(
              std::lower_bound(neighbours.begin(), neighbours.end(), std::pair<std::uint32_t, std::uint32_t>(q, 0)) -
              neighbours.begin());
          edges[neighbours[at].second + fill[at]++].second = star[i];
        }
      }
      for (std::size_t a = 0; a < edges.size();) {
        std::size_t b = a;
        while (b < edges.size() && edges[b].first == edges[a].first) ++b;
        const std::uint32_t q = edges[a].first;
        // The facets holding p and q: opposite the other vertices. On the hull when
        // one of them has no simplex beyond.
        auto holds_both = [&](std::uint32_t s, int k) {
          const std::uint32_t v = simplices[static_cast<std::size_t>(s) * w + k];
          return v != p32 && v != q;
        };
        bool hull = false;
        std::uint32_t from = edges[a].second;
        for (std::size_t e = a; e < b && !hull; ++e) {
          for (int k = 0; k < w; ++k) {
            if (holds_both(edges[e].second, k) && adjacency[static_cast<std::size_t>(edges[e].second) * w + k] < 0) {
              hull = true;
              from = edges[e].second;
            }
          }
        }
        const std::size_t ridge_at = part.ridge_vertices.size();
        if (hull) part.ridge_vertices.push_back(-1);
        const std::size_t path_at = part.ridge_vertices.size();
        if (d == 3) {
          // Around the edge: from a hull simplex (or the first) to the next across the
          // facets that hold the edge.
          std::uint32_t s = from;
          std::int32_t previous = -1;
          for (std::size_t steps = 0; steps < b - a; ++steps) {
            part.ridge_vertices.push_back(vertex(s));
            std::int32_t next = -1;
            for (int k = 0; k < w; ++k) {
              const std::int32_t t = adjacency[static_cast<std::size_t>(s) * w + k];
              if (holds_both(s, k) && t >= 0 && t != previous) {
                next = t;
                break;
              }
            }
            if (next < 0 || static_cast<std::uint32_t>(next) == from) break;
            previous = static_cast<std::int32_t>(s);
            s = static_cast<std::uint32_t>(next);
          }
          append_collapsed(part.ridge_vertices, path_at, !hull);
        } else {
          for (std::size_t e = a; e < b; ++e) part.ridge_vertices.push_back(vertex(edges[e].second));
          std::sort(part.ridge_vertices.begin() + static_cast<std::ptrdiff_t>(path_at), part.ridge_vertices.end());
          part.ridge_vertices.erase(std::unique(part.ridge_vertices.begin() + static_cast<std::ptrdiff_t>(path_at),
                                                part.ridge_vertices.end()),
                                    part.ridge_vertices.end());
        }
        // A ridge with fewer than d vertices, counting the one at infinity, is left out,
        // as Qhull leaves it out: bounded, it has no area (its edge lies inside a group
        // of cospherical simplices, as a grid square's diagonal); unbounded, the
        // vertices cannot say where it goes (in 3-d a wedge from one vertex).
        if (part.ridge_vertices.size() - ridge_at < static_cast<std::size_t>(d)) {
          part.ridge_vertices.resize(ridge_at);
        } else {
          part.ridge_points.push_back(p32);
          part.ridge_points.push_back(q);
          part.ridge_sizes.push_back(static_cast<std::int64_t>(part.ridge_vertices.size() - ridge_at));
        }
        a = b;
      }
    }
  });

  out.region_ptr.assign(1, 0);
  out.ridge_ptr.assign(1, 0);
  for (Part& part : parts) {
    for (const std::int64_t s : part.region_sizes) out.region_ptr.push_back(out.region_ptr.back() + s);
    for (const std::int64_t s : part.ridge_sizes) out.ridge_ptr.push_back(out.ridge_ptr.back() + s);
    out.regions.insert(out.regions.end(), part.regions.begin(), part.regions.end());
    out.ridge_vertices.insert(out.ridge_vertices.end(), part.ridge_vertices.begin(), part.ridge_vertices.end());
    out.ridge_points.insert(out.ridge_points.end(), part.ridge_points.begin(), part.ridge_points.end());
    part = Part();
  }
  return out;
}

}  // namespace spokemesh
