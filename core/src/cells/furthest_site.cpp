// The furthest-site Delaunay triangulation by gift-wrapping over the hull's vertices
// (voronoi_diagram.hpp).
//
// Why the wrap is right. For a facet F (d points) of a furthest-site simplex, the
// spheres through F form a pencil: centre c0 + t n (n normal to F). A point q lies
// outside the sphere of parameter t iff its power (|q - c0|^2 - R0^2) - 2 t n.(q - c0)
// is positive, linear in t with the sign of its side of F's hyperplane. So on the side
// wanted, the sphere that holds every point is that of the candidate whose own sphere
// is outermost: scanning the candidates and keeping the one the kept sphere leaves
// outside finds it. Points on the other side are held by that sphere because the
// simplex on that side already holds them. Ties (cospherical points) are decided by the
// perturbed in-sphere test, a total order consistent with the Delaunay mesh's.
#include <algorithm>
#include <array>
#include <deque>
#include <map>
#include <numeric>
#include <optional>
#include <string>
#include <vector>

#include <gmpxx.h>

#include "spokemesh/predicates.hpp"
#include "spokemesh/voronoi_diagram.hpp"

namespace spokemesh {

namespace {

using Key = std::array<std::uint32_t, kMaxDimension + 1>;

Key sorted_key(const std::uint32_t* ids, int count) {
  Key k{};
  std::copy_n(ids, count, k.begin());
  std::sort(k.begin(), k.begin() + count);
  return k;
}

// Reduces `rows` (each of `cols` rationals) to echelon form in place; returns the rank.
int rank_of(std::vector<std::vector<mpq_class>>& rows, int cols) {
  int rank = 0;
  for (int c = 0; c < cols && rank < static_cast<int>(rows.size()); ++c) {
    auto pivot = std::find_if(rows.begin() + rank, rows.end(), [&](const auto& r) { return sgn(r[c]) != 0; });
    if (pivot == rows.end()) continue;
    std::swap(rows[static_cast<std::size_t>(rank)], *pivot);
    const std::vector<mpq_class>& top = rows[static_cast<std::size_t>(rank)];
    for (std::size_t r = static_cast<std::size_t>(rank) + 1; r < rows.size(); ++r) {
      if (sgn(rows[r][c]) == 0) continue;
      const mpq_class f = rows[r][c] / top[c];
      for (int j = c; j < cols; ++j) rows[r][j] -= f * top[j];
    }
    ++rank;
  }
  return rank;
}

// The normal of the hyperplane through d points (exact): a non-zero solution n of
// (p_i - p_0) . n = 0 for i = 1..d-1, from the echelon form of those rows.
std::vector<mpq_class> normal_of(const PointSet& points, const std::uint32_t* ids) {
  const int d = points.dimension();
  std::vector<std::vector<mpq_class>> rows;
  for (int i = 1; i < d; ++i) {
    std::vector<mpq_class> r(static_cast<std::size_t>(d));
    for (int c = 0; c < d; ++c) r[c] = mpq_class(points.point(ids[i])[c]) - mpq_class(points.point(ids[0])[c]);
    rows.push_back(std::move(r));
  }
  rank_of(rows, d);  // d - 1 for a facet's points (affinely independent)
  // Back substitution with the free column (the first without a pivot) set to 1.
  std::vector<int> pivot_col;
  for (const auto& r : rows) {
    int c = 0;
    while (c < d && sgn(r[c]) == 0) ++c;
    pivot_col.push_back(c);
  }
  int free_col = 0;
  while (std::find(pivot_col.begin(), pivot_col.end(), free_col) != pivot_col.end()) ++free_col;
  std::vector<mpq_class> n(static_cast<std::size_t>(d), 0);
  n[free_col] = 1;
  for (int i = static_cast<int>(rows.size()) - 1; i >= 0; --i) {
    const int c = pivot_col[static_cast<std::size_t>(i)];
    if (c >= d) continue;
    mpq_class sum = 0;
    for (int j = c + 1; j < d; ++j) sum += rows[i][j] * n[j];
    n[c] = -sum / rows[i][c];
  }
  return n;
}

}  // namespace

Result<std::vector<std::uint32_t>> furthest_site_simplices(const PointSet& points,
                                                           std::span<const std::uint32_t> delaunay,
                                                           std::span<const std::int32_t> adjacency) {
  const int d = points.dimension();
  const int w = d + 1;
  const std::size_t m = delaunay.size() / static_cast<std::size_t>(w);
  const Predicates predicates(points);

  // The hull's facets (each with the vertex of its simplex inside) and vertices.
  struct HullFacet {
    std::array<std::uint32_t, kMaxDimension> ids;
    std::uint32_t inside;
  };
  std::vector<HullFacet> hull;
  std::vector<std::uint32_t> vertices;
  for (std::size_t s = 0; s < m; ++s) {
    for (int k = 0; k < w; ++k) {
      if (adjacency[s * w + k] >= 0) continue;
      HullFacet f{};
      int at = 0;
      for (int j = 0; j < w; ++j) {
        if (j != k) f.ids[at++] = delaunay[s * w + j];
      }
      f.inside = delaunay[s * w + k];
      hull.push_back(f);
      vertices.insert(vertices.end(), f.ids.begin(), f.ids.begin() + d);
    }
  }
  std::sort(vertices.begin(), vertices.end());
  vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());

  std::array<std::uint32_t, kMaxDimension + 1> simplex{};
  auto orientation_with = [&](const std::uint32_t* facet, std::uint32_t q) {
    std::copy_n(facet, d, simplex.begin());
    simplex[d] = q;
    return predicates.orientation(std::span<const std::uint32_t>(simplex.data(), w));
  };
  // The wrap starts from a hull facet of the furthest-site triangulation. A Delaunay
  // hull facet is one when its hyperplane holds no other hull vertex. On a hull whose
  // every facet plane holds more (a grid's sides) the Delaunay hull facets are pieces
  // of those planes' own triangulations, not furthest-site facets: in 2-d the ends of a
  // side are (the points between them lie below the chord on the paraboloid); above 2-d
  // the start would need a furthest-site triangulation within the plane, and is refused.
  auto on_plane_of = [&](const HullFacet& f, std::uint32_t v) {
    return std::find(f.ids.begin(), f.ids.begin() + d, v) == f.ids.begin() + d &&
           orientation_with(f.ids.data(), v) == 0;
  };
  std::optional<HullFacet> start;
  for (const HullFacet& f : hull) {
    if (std::none_of(vertices.begin(), vertices.end(), [&](std::uint32_t v) { return on_plane_of(f, v); })) {
      start = f;
      break;
    }
  }
  if (!start && d == 2 && !hull.empty()) {
    // The two ends of the first side, among the hull vertices on its line.
    HullFacet f = hull.front();
    std::vector<std::uint32_t> line(f.ids.begin(), f.ids.begin() + 2);
    for (const std::uint32_t v : vertices) {
      if (on_plane_of(f, v)) line.push_back(v);
    }
    const auto lex = [&](std::uint32_t a, std::uint32_t b) { return lex_less(points.point(a), points.point(b), d); };
    f.ids[0] = *std::min_element(line.begin(), line.end(), lex);
    f.ids[1] = *std::max_element(line.begin(), line.end(), lex);
    start = f;
  }
  // Above 2-d on such a hull: the start is found among the hull's corners (the hull
  // vertices that lie inside no face of it: the hyperplanes of their hull facets meet
  // in them alone), as a simplex of corners whose sphere holds every other corner
  // (the perturbed test deciding ties), containing the first corner. Only corners can be
  // furthest-site vertices: a point inside a face of the hull lies strictly inside the
  // sphere of any simplex of corners around it (the paraboloid is strictly convex).
  // The search is C(corners - 1, d) simplices, each tested against the corners: cube-like
  // hulls have few corners; beyond a budget the set is refused as before.
  std::optional<std::array<std::uint32_t, kMaxDimension + 1>> start_simplex;
  if (!start && d > 2 && !hull.empty()) {
    std::map<std::uint32_t, std::vector<std::size_t>> facets_of;
    for (std::size_t f = 0; f < hull.size(); ++f) {
      for (int j = 0; j < d; ++j) facets_of[hull[f].ids[static_cast<std::size_t>(j)]].push_back(f);
    }
    std::vector<std::uint32_t> corners;
    for (const auto& [v, fs] : facets_of) {
      std::vector<std::vector<mpq_class>> normals;
      for (const std::size_t f : fs) normals.push_back(normal_of(points, hull[f].ids.data()));
      if (rank_of(normals, d) == d) corners.push_back(v);
    }
    double subsets = 1;  // C(corners - 1, d)
    for (int j = 0; j < d; ++j)
      subsets = subsets * static_cast<double>(static_cast<int>(corners.size()) - 1 - j) / (j + 1);
    constexpr double kCornerTestBudget = 2e6;
    if (static_cast<int>(corners.size()) > d && subsets * static_cast<double>(corners.size()) <= kCornerTestBudget) {
      std::vector<int> pick(static_cast<std::size_t>(d));
      std::iota(pick.begin(), pick.end(), 1);
      const int k = static_cast<int>(corners.size());
      while (!start_simplex) {
        std::array<std::uint32_t, kMaxDimension + 1> t{};
        t[0] = corners[0];
        for (int j = 0; j < d; ++j) t[static_cast<std::size_t>(j) + 1] = corners[static_cast<std::size_t>(pick[j])];
        const std::span<const std::uint32_t> ts(t.data(), static_cast<std::size_t>(w));
        int orient = predicates.orientation(ts);
        if (orient < 0) {
          std::swap(t[0], t[1]);
          orient = 1;
        }
        bool holds = orient > 0;
        for (std::size_t c = 0; c < corners.size() && holds; ++c) {
          if (std::find(t.begin(), t.begin() + w, corners[c]) != t.begin() + w) continue;
          holds = predicates.side_of_sphere(ts, corners[c]) < 0;
        }
        if (holds) {
          start_simplex = t;
          break;
        }
        // The next d-subset of 1..k-1 in lexicographic order.
        int j = d - 1;
        while (j >= 0 && pick[static_cast<std::size_t>(j)] == k - d + j) --j;
        if (j < 0) break;
        ++pick[static_cast<std::size_t>(j)];
        for (int i = j + 1; i < d; ++i) pick[static_cast<std::size_t>(i)] = pick[static_cast<std::size_t>(i) - 1] + 1;
      }
    }
  }
  if (!start && !start_simplex) {
    if (hull.empty()) return internal_error("furthest_site: the triangulation has no hull facet");
    const HullFacet& f = hull.front();
    std::string ids;
    for (int j = 0; j < d; ++j) ids += std::to_string(f.ids[static_cast<std::size_t>(j)]) + ", ";
    const auto extra =
        std::find_if(vertices.begin(), vertices.end(), [&](std::uint32_t v) { return on_plane_of(f, v); });
    return invalid_argument("furthest_site: points " + ids + "and " + std::to_string(*extra) +
                            " lie on one facet of the convex hull, as on every facet, and the hull has too many " +
                            "corners to search for a first furthest-site simplex among them");
  }

  // Wrap from a hull facet: its furthest simplex lies on the side of its inner vertex.
  struct Task {
    std::array<std::uint32_t, kMaxDimension> facet;
    std::uint32_t away;  // a point on the side not wanted (or, for the first, wanted)
    bool same_side;
  };
  std::deque<Task> tasks;
  std::map<Key, int> facet_uses;  // simplices found on each facet (sorted, padded)
  std::vector<Key> found;
  std::map<Key, bool> seen;
  // A simplex found: recorded, and a wrap queued across each of its facets.
  auto take = [&](const std::array<std::uint32_t, kMaxDimension + 1>& t) {
    const Key tkey = sorted_key(t.data(), w);
    if (seen.count(tkey) != 0) return;
    seen[tkey] = true;
    found.push_back(tkey);
    for (int v = 0; v < w; ++v) {
      Task next{};
      int at = 0;
      for (int j = 0; j < w; ++j) {
        if (j != v) next.facet[at++] = t[j];
      }
      next.away = t[v];
      next.same_side = false;
      if (++facet_uses[sorted_key(next.facet.data(), d)] == 1) tasks.push_back(next);
    }
  };
  if (start) {
    tasks.push_back({start->ids, start->inside, true});
  } else {
    take(*start_simplex);
  }
  while (!tasks.empty()) {
    const Task task = tasks.front();
    tasks.pop_front();
    const Key fkey = sorted_key(task.facet.data(), d);
    if (facet_uses[fkey] >= 2) continue;
    const int away = orientation_with(task.facet.data(), task.away);
    const int want = task.same_side ? away : -away;
    std::int64_t best = -1;
    for (const std::uint32_t c : vertices) {
      if (std::find(task.facet.begin(), task.facet.begin() + d, c) != task.facet.begin() + d) continue;
      if (orientation_with(task.facet.data(), c) != want) continue;
      if (best < 0) {
        best = c;
        continue;
      }
      std::copy_n(task.facet.begin(), d, simplex.begin());
      simplex[d] = static_cast<std::uint32_t>(best);
      // side_of_sphere wants a positively oriented simplex: swap two vertices if not.
      if (predicates.orientation(std::span<const std::uint32_t>(simplex.data(), w)) < 0)
        std::swap(simplex[0], simplex[1]);
      if (predicates.side_of_sphere(std::span<const std::uint32_t>(simplex.data(), w), c) > 0) best = c;
    }
    if (best < 0) continue;  // a hull facet: nothing beyond
    std::array<std::uint32_t, kMaxDimension + 1> t{};
    std::copy_n(task.facet.begin(), d, t.begin());
    t[d] = static_cast<std::uint32_t>(best);
    take(t);
  }
  std::sort(found.begin(), found.end());
  std::vector<std::uint32_t> out;
  out.reserve(found.size() * static_cast<std::size_t>(w));
  for (Key k : found) {
    // Positively oriented: ascending but for the last two where that is negative.
    if (predicates.orientation(std::span<const std::uint32_t>(k.data(), w)) < 0) std::swap(k[d - 1], k[d]);
    out.insert(out.end(), k.begin(), k.begin() + w);
  }
  return out;
}

}  // namespace spokemesh
