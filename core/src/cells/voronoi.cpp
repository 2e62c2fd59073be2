#include "spokemesh/voronoi.hpp"

#include <gmpxx.h>
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>

#include "base/invariant.hpp"
#include "cells/cell_polytope.hpp"
#include "predicates/cramer.hpp"

namespace spokemesh {

namespace {

// The order of a cell's vertices (as indices into the star's simplices): in 2-d
// counter-clockwise around the seed, by topology alone. Each triangle is positively
// oriented, so read from the seed x it is (x, a, b) counter-clockwise, and the next
// vertex counter-clockwise is the triangle (x, b, c) across the edge x-b. An
// unbounded cell's vertices form a path, which starts at the triangle whose edge x-a
// lies on the hull (no triangle ends at a). Other dimensions: the star's order.
std::vector<std::uint32_t> vertex_order(const Star& star) {
  const std::size_t m = star.size();
  std::vector<std::uint32_t> order(m);
  std::iota(order.begin(), order.end(), 0u);
  if (star.dimension != 2 || m == 0) return order;
  std::vector<std::array<std::uint32_t, 2>> arc(m);  // (a, b) of each triangle
  for (std::size_t i = 0; i < m; ++i) {
    const std::uint32_t* s = star.simplex(i);
    const int p = static_cast<int>(std::find(s, s + 3, star.seed) - s);
    arc[i] = {s[(p + 1) % 3], s[(p + 2) % 3]};
  }
  std::size_t at = 0;
  for (std::size_t i = 0; i < m; ++i) {
    const bool starts = std::none_of(arc.begin(), arc.end(), [&](const auto& t) { return t[1] == arc[i][0]; });
    if (starts) at = i;
  }
  std::vector<bool> taken(m, false);
  std::size_t filled = 0;
  while (filled < m) {
    order[filled++] = static_cast<std::uint32_t>(at);
    taken[at] = true;
    const auto next = std::find_if(arc.begin(), arc.end(), [&](const auto& t) { return t[0] == arc[at][1]; });
    if (next == arc.end() || taken[static_cast<std::size_t>(next - arc.begin())]) break;
    at = static_cast<std::size_t>(next - arc.begin());
  }
  SPOKEMESH_INVARIANT(filled == m, "a 2-d star's triangles form one fan around the seed");
  for (std::size_t i = 0; i < m && filled < m; ++i) {  // never reached for a valid star
    if (!taken[i]) order[filled++] = static_cast<std::uint32_t>(i);
  }
  return order;
}

}  // namespace

namespace {

// Facets, measures and (3-d) facet loops from the polytope; `index` maps polytope
// vertices to the cell's vertex numbers (-1: not a cell vertex, i.e. ideal).
void add_facets(const detail::CellPolytope& polytope, const std::vector<std::int64_t>& index, VoronoiCell& cell) {
  const detail::PolytopeMeasures measures = polytope.measures();
  cell.volume = measures.volume;
  cell.centroid = measures.centroid;
  for (const detail::FacetMeasure& m : measures.facets) {
    VoronoiFacet facet;
    facet.neighbor = detail::is_wall_label(m.label) ? -1 - static_cast<std::int64_t>(m.label - detail::kWallLabel0)
                                                    : static_cast<std::int64_t>(m.label);
    for (const std::uint32_t v : m.vertices) {
      if (index[v] >= 0) facet.vertices.push_back(static_cast<std::uint32_t>(index[v]));
    }
    if (cell.dimension != 3) std::sort(facet.vertices.begin(), facet.vertices.end());
    facet.area = m.area;
    facet.normal = polytope.facet_normal(m.label);
    cell.facets.push_back(std::move(facet));
  }
  detail::sort_facets(cell.facets);
}

}  // namespace

Status check_seed_in_domain(const PointSet& points, std::uint32_t seed, const Domain& domain) {
  return check_seed_in_domain(points.point(seed), seed, domain);
}

Status check_seed_in_domain(const double* point, std::uint64_t seed, const Domain& domain) {
  if (const auto wall = domain.violated_wall(point)) {
    return invalid_argument("seed " + std::to_string(seed) + " lies outside the domain (" + domain.describe() +
                            "): beyond wall " + std::to_string(*wall));
  }
  return Status::ok();
}

namespace {
// A hidden seed's cell: empty, said so.
VoronoiCell hidden_cell(const Star& star, int d, bool clipped) {
  VoronoiCell cell;
  cell.seed = star.seed;
  cell.dimension = d;
  cell.bounded = true;
  cell.clipped = clipped;
  cell.hidden = true;
  cell.volume = 0;
  return cell;
}
}  // namespace

VoronoiCell voronoi_cell(const PointSet& points, const Star& star, std::span<const double> weights) {
  const int d = points.dimension();
  if (star.hidden) return hidden_cell(star, d, false);
  VoronoiCell cell;
  cell.seed = star.seed;
  cell.dimension = d;
  cell.bounded = star.bounded_cell();
  const detail::CellPolytope polytope(points, star, nullptr, weights.empty() ? nullptr : weights.data());
  const std::vector<std::uint32_t> order = vertex_order(star);
  std::vector<std::int64_t> index(polytope.size(), -1);
  cell.vertex_simplices.reserve(star.simplices.size());
  cell.vertices.reserve(order.size() * d);
  for (std::size_t k = 0; k < order.size(); ++k) {
    const std::uint32_t i = order[k];
    index[i] = static_cast<std::int64_t>(k);
    const std::uint32_t* s = star.simplex(i);
    cell.vertex_simplices.insert(cell.vertex_simplices.end(), s, s + d + 1);
    cell.vertices.insert(cell.vertices.end(), polytope.coordinates(i), polytope.coordinates(i) + d);
  }
  add_facets(polytope, index, cell);
  return cell;
}

Result<VoronoiCell> voronoi_cell(const PointSet& points, const Star& star, const Domain& domain,
                                 std::span<const double> weights) {
  const int d = points.dimension();
  if (domain.dimension() != d) {
    return invalid_argument("domain: dimension " + std::to_string(domain.dimension()) + " does not match the points' " +
                            std::to_string(d));
  }
  if (Status st = check_seed_in_domain(points, star.seed, domain); !st.is_ok()) return st;
  if (star.hidden) return hidden_cell(star, d, true);
  detail::CellPolytope polytope(points, star, &domain, weights.empty() ? nullptr : weights.data());
  polytope.clip_all();
  return detail::assemble_clipped(polytope, star.seed, d);
}

namespace detail {

void sort_facets(std::vector<VoronoiFacet>& facets) {
  std::sort(facets.begin(), facets.end(), [](const VoronoiFacet& a, const VoronoiFacet& b) {
    if (a.is_wall() != b.is_wall()) return !a.is_wall();
    return a.is_wall() ? a.wall() < b.wall() : a.neighbor < b.neighbor;
  });
}

VoronoiCell assemble_clipped(const CellPolytope& polytope, std::uint32_t seed, int d) {
  VoronoiCell cell;
  cell.seed = seed;
  cell.dimension = d;
  cell.clipped = true;
  cell.bounded = polytope.bounded();
  // A power cell need not hold its seed, so the domain can cut it away whole (a
  // small particle at the domain's edge beside a large one outside): volume 0.
  if (polytope.size() == 0) {
    cell.bounded = true;
    cell.volume = 0;
    return cell;
  }
  std::vector<std::uint32_t> order;
  if (d == 2) {
    order = polytope.polygon_order();
  } else {
    for (std::size_t v = 0; v < polytope.size(); ++v) {
      if (!polytope.is_ideal(v)) order.push_back(static_cast<std::uint32_t>(v));
    }
  }
  std::vector<std::int64_t> index(polytope.size(), -1);
  cell.vertices.reserve(order.size() * d);
  for (std::size_t k = 0; k < order.size(); ++k) {
    index[order[k]] = static_cast<std::int64_t>(k);
    cell.vertices.insert(cell.vertices.end(), polytope.coordinates(order[k]), polytope.coordinates(order[k]) + d);
  }
  add_facets(polytope, index, cell);
  return cell;
}

}  // namespace detail

void keep_measures_only(VoronoiCell& cell) {
  cell.vertices.clear();
  cell.vertex_simplices.clear();
  for (VoronoiFacet& f : cell.facets) f.vertices.clear();
}

}  // namespace spokemesh
