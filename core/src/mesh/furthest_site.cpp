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
#include <optional>
#include <string>

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

}  // namespace

Result<std::vector<std::uint32_t>> furthest_site_simplices(const PointSet& points, std::span<const std::uint32_t> delaunay,
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
    return std::find(f.ids.begin(), f.ids.begin() + d, v) == f.ids.begin() + d && orientation_with(f.ids.data(), v) == 0;
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
  if (!start) {
    if (hull.empty()) return internal_error("furthest_site: the triangulation has no hull facet");
    const HullFacet& f = hull.front();
    std::string ids;
    for (int j = 0; j < d; ++j) ids += std::to_string(f.ids[static_cast<std::size_t>(j)]) + ", ";
    const auto extra = std::find_if(vertices.begin(), vertices.end(), [&](std::uint32_t v) { return on_plane_of(f, v); });
    return invalid_argument("furthest_site: points " + ids + "and " + std::to_string(*extra) +
                            " lie on one facet of the convex hull, as on every facet; furthest-site triangulations " +
                            "of such hulls are supported in 2-d only for now");
  }

  // Wrap from a hull facet: its furthest simplex lies on the side of its inner vertex.
  struct Task {
    std::array<std::uint32_t, kMaxDimension> facet;
    std::uint32_t away;  // a point on the side not wanted (or, for the first, wanted)
    bool same_side;
  };
  std::deque<Task> tasks;
  tasks.push_back({start->ids, start->inside, true});
  std::map<Key, int> facet_uses;  // simplices found on each facet (sorted, padded)
  std::vector<Key> found;
  std::map<Key, bool> seen;
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
      if (predicates.orientation(std::span<const std::uint32_t>(simplex.data(), w)) < 0) std::swap(simplex[0], simplex[1]);
      if (predicates.side_of_sphere(std::span<const std::uint32_t>(simplex.data(), w), c) > 0) best = c;
    }
    if (best < 0) continue;  // a hull facet: nothing beyond
    std::array<std::uint32_t, kMaxDimension + 1> t{};
    std::copy_n(task.facet.begin(), d, t.begin());
    t[d] = static_cast<std::uint32_t>(best);
    const Key tkey = sorted_key(t.data(), w);
    if (seen.count(tkey) != 0) continue;
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
