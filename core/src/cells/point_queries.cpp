#include "spokemesh/point_queries.hpp"

#include <algorithm>
#include <limits>
#include <utility>

#include "spokemesh/voronoi_diagram.hpp"

namespace spokemesh {

namespace {

// Whether simplex s's ascending vertex list is less than t's.
bool sorted_less(const std::uint32_t* s, const std::uint32_t* t, int w) {
  std::array<std::uint32_t, kMaxDimension + 1> a{}, b{};
  std::copy(s, s + w, a.begin());
  std::copy(t, t + w, b.begin());
  sort_vertices(a.data(), w);
  sort_vertices(b.data(), w);
  return std::lexicographical_compare(a.begin(), a.begin() + w, b.begin(), b.begin() + w);
}

// The simplices holding q: `located` and those reached across facets q lies on
// (orientation 0 with q in place of the opposite vertex), a face's star, a handful;
// with `hull`, the hull facets q lies on (simplex, opposite vertex).
void simplices_holding(const DelaunayArrays& tri, std::int32_t located, const double* q,
                       std::vector<std::int32_t>& holding, std::vector<std::pair<std::int32_t, int>>* hull) {
  const PointSet& points = *tri.points;
  const int d = points.dimension();
  const auto w = static_cast<std::size_t>(d + 1);
  holding.assign(1, located);
  for (std::size_t i = 0; i < holding.size(); ++i) {
    const std::int32_t s = holding[i];
    const std::uint32_t* v = &tri.simplices[static_cast<std::size_t>(s) * w];
    for (std::size_t k = 0; k < w; ++k) {
      const std::int32_t t = tri.adjacency[static_cast<std::size_t>(s) * w + k];
      if (t >= 0 && std::find(holding.begin(), holding.end(), t) != holding.end()) continue;
      if (t < 0 && hull == nullptr) continue;
      std::array<const double*, kMaxDimension + 1> corners{};
      for (std::size_t j = 0; j < w; ++j) corners[j] = j == k ? q : points.point(v[j]);
      if (orientation_of(corners, d) != 0) continue;
      if (t < 0) {
        hull->emplace_back(s, static_cast<int>(k));
      } else {
        holding.push_back(t);
      }
    }
  }
}

}  // namespace

void sort_vertices(std::uint32_t* v, int w) {
  for (int i = 1; i < w; ++i) {
    for (int j = i; j > 0 && v[j - 1] > v[j]; --j) std::swap(v[j - 1], v[j]);
  }
}

std::int32_t canonical_simplex(const DelaunayArrays& tri, std::int32_t located, const double* q) {
  if (located < 0) return located;
  const auto w = static_cast<std::size_t>(tri.points->dimension() + 1);
  thread_local std::vector<std::int32_t> holding;
  simplices_holding(tri, located, q, holding, nullptr);
  std::int32_t best = located;
  for (const std::int32_t s : holding) {
    if (sorted_less(&tri.simplices[static_cast<std::size_t>(s) * w], &tri.simplices[static_cast<std::size_t>(best) * w],
                    static_cast<int>(w))) {
      best = s;
    }
  }
  return best;
}

Result<std::unique_ptr<DelaunayIndex>> DelaunayIndex::build(const KdTree& tree, MeshOptions options,
                                                            const std::function<bool(std::size_t)>& reserve_bytes) {
  const PointSet& points = tree.points();
  const int d = points.dimension();
  const std::size_t n = points.size();
  // The rows and the adjacency as expected_simplices says, and the locator's 4 bytes a point.
  const std::size_t expected = expected_simplices(d, n) * static_cast<std::size_t>(d + 1) * 8 + 4 * n;
  if (reserve_bytes && !reserve_bytes(expected)) {
    return Status{Code::kResourceExhausted, "the triangulation's arrays (" + std::to_string(expected >> 20) +
                                                " MiB) do not fit the memory budget"};
  }
  std::unique_ptr<DelaunayIndex> index(new DelaunayIndex(tree));
  index->simplices_.reserve(expected_simplices(d, n) * static_cast<std::size_t>(d + 1));
  auto run = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
    index->simplices_.insert(index->simplices_.end(), block.begin(), block.end());
    return Status::ok();
  });
  if (!run.is_ok()) return run.status();
  const std::size_t bytes = index->simplices_.size() * 8 + 4 * n;
  if (reserve_bytes && bytes > expected && !reserve_bytes(bytes - expected)) {
    return Status{Code::kResourceExhausted,
                  "the triangulation's arrays (" + std::to_string(bytes >> 20) + " MiB) do not fit the memory budget"};
  }
  index->simplices_.shrink_to_fit();
  index->adjacency_ = simplex_adjacency(index->simplices_, d, std::max(1u, options.threads));
  index->locator_ = std::make_unique<SimplexLocator>(points, index->simplices_, index->adjacency_, tree);
  return index;
}

std::size_t DelaunayIndex::bytes() const {
  return simplices_.capacity() * sizeof(std::uint32_t) + adjacency_.capacity() * sizeof(std::int32_t) +
         tree_.points().size() * sizeof(std::int32_t);
}

Status answer_point(const DelaunayArrays& tri, std::int32_t located, const double* q, bool natural, PointAnswer& out) {
  const int d = tri.points->dimension();
  const std::int32_t s = canonical_simplex(tri, located, q);
  out.vertex_count = 0;
  if (s >= 0) {
    out.vertex_count = d + 1;
    const std::uint32_t* v = &tri.simplices[static_cast<std::size_t>(s) * static_cast<std::size_t>(d + 1)];
    std::copy(v, v + d + 1, out.simplex.begin());
    sort_vertices(out.simplex.data(), d + 1);
    barycentric_coordinates(*tri.points, out.simplex.data(), q, out.barycentric.data());
    for (int j = 0; j <= d; ++j) out.barycentric[static_cast<std::size_t>(j)] += 0.0;  // no -0
  }
  if (!natural) return Status::ok();
  return natural_neighbors(tri, s, q, out.natural);
}

void answer_support(const DelaunayArrays& tri, std::int32_t located, const double* q, bool natural,
                    AnswerSupport& out) {
  out.outside = located < 0;
  out.simplices.clear();
  out.hull_facets.clear();
  if (located < 0) return;
  const PointSet& points = *tri.points;
  const int d = points.dimension();
  const auto w = static_cast<std::size_t>(d + 1);
  auto listed = [](const std::vector<std::int32_t>& list, std::int32_t t) {
    return std::find(list.begin(), list.end(), t) != list.end();
  };
  // The simplices holding q, and the hull facets q lies on.
  simplices_holding(tri, located, q, out.simplices, &out.hull_facets);
  if (!natural) return;
  const std::vector<std::int32_t> holding = out.simplices;
  // The cavity (circumspheres holding q strictly) from the holders, and what lies
  // across its boundary.
  std::vector<std::int32_t> cavity;
  std::vector<std::int32_t> across;
  for (const std::int32_t s : holding) {
    if (in_circumsphere(points, &tri.simplices[static_cast<std::size_t>(s) * w], q) > 0) cavity.push_back(s);
  }
  for (std::size_t i = 0; i < cavity.size(); ++i) {
    const std::int32_t s = cavity[i];
    for (std::size_t k = 0; k < w; ++k) {
      const std::int32_t t = tri.adjacency[static_cast<std::size_t>(s) * w + k];
      if (t < 0) {
        out.hull_facets.emplace_back(s, static_cast<int>(k));
        continue;
      }
      if (listed(cavity, t) || listed(across, t)) continue;
      if (in_circumsphere(points, &tri.simplices[static_cast<std::size_t>(t) * w], q) > 0) {
        cavity.push_back(t);
      } else {
        across.push_back(t);
      }
    }
  }
  for (const std::int32_t s : cavity) {
    if (!listed(holding, s)) out.simplices.push_back(s);
  }
  for (const std::int32_t t : across) {
    if (!listed(out.simplices, t)) out.simplices.push_back(t);
  }
}

bool interpolate_linear(const PointAnswer& answer, std::span<const double> values, std::size_t width, double* out) {
  if (answer.vertex_count == 0) return false;
  std::fill(out, out + width, 0.0);
  for (int j = 0; j < answer.vertex_count; ++j) {
    const double* v = values.data() + static_cast<std::size_t>(answer.simplex[static_cast<std::size_t>(j)]) * width;
    const double b = answer.barycentric[static_cast<std::size_t>(j)];
    for (std::size_t c = 0; c < width; ++c) out[c] += b * v[c];
  }
  return true;
}

bool interpolate_natural(const PointAnswer& answer, std::span<const double> values, std::size_t width, double* out) {
  const NaturalCoordinates& nn = answer.natural;
  if (nn.where == NaturalCoordinates::Where::kOutside) return false;
  std::fill(out, out + width, 0.0);
  for (std::size_t j = 0; j < nn.neighbors.size(); ++j) {
    const double* v = values.data() + static_cast<std::size_t>(nn.neighbors[j]) * width;
    for (std::size_t c = 0; c < width; ++c) out[c] += nn.weights[j] * v[c];
  }
  return true;
}

std::uint32_t nearest_point(const KdTree& tree, const double* q) {
  std::uint32_t id = 0;
  double d0 = 0;
  if (tree.knn(q, 1, &id, &d0) != 1) return 0;
  // Every point as near (nanoflann's distance <= d0), the least by this one's, then index.
  thread_local std::vector<std::pair<std::uint32_t, double>> near;
  near.clear();
  tree.within(q, std::nextafter(d0, std::numeric_limits<double>::infinity()), near);
  const PointSet& points = tree.points();
  const int d = points.dimension();
  double best = std::numeric_limits<double>::infinity();
  for (const auto& [candidate, unused] : near) {
    const double* p = points.point(candidate);
    double d2 = 0;
    for (int c = 0; c < d; ++c) d2 += (p[c] - q[c]) * (p[c] - q[c]);
    if (d2 < best || (d2 == best && candidate < id)) {
      best = d2;
      id = candidate;
    }
  }
  return id;
}

}  // namespace spokemesh
