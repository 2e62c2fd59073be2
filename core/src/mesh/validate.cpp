#include "spokemesh/validate.hpp"

#include <gmpxx.h>

#include <algorithm>
#include <array>
#include <numeric>

#include "base/mixing.hpp"

namespace spokemesh {
namespace {

constexpr int kMaxCols = kMaxDimension + 1;

std::string tuple_text(const std::uint32_t* ids, int count) {
  std::string s = "(";
  for (int i = 0; i < count; ++i) {
    if (i != 0) s += ' ';
    s += std::to_string(ids[i]);
  }
  s += ')';
  return s;
}

// Exact determinant of rows (p_i - origin) for d points.
mpq_class exact_volume_det(const PointSet& ps, std::uint32_t origin, const std::uint32_t* ids) {
  const int d = ps.dimension();
  std::vector<mpq_class> m(static_cast<std::size_t>(d * d));
  for (int r = 0; r < d; ++r) {
    for (int c = 0; c < d; ++c) m[r * d + c] = mpq_class(ps.point(ids[r])[c]) - mpq_class(ps.point(origin)[c]);
  }
  return exact_determinant(std::move(m), d);
}

}  // namespace

MeshCheck check_mesh(const KdTree& tree, std::span<const std::uint32_t> simplices, std::size_t max_violations) {
  const PointSet& ps = tree.points();
  const Predicates pred(ps);
  const int d = ps.dimension(), w = d + 1;
  const std::size_t n = ps.size(), m = simplices.size() / w;
  MeshCheck report;
  report.simplices = m;
  auto fail = [&](std::string message) {
    if (report.violations.size() < max_violations) report.violations.push_back(std::move(message));
  };

  // 1. Simplices.
  std::vector<bool> used(n, false);
  for (std::size_t i = 0; i < m; ++i) {
    std::array<std::uint32_t, kMaxCols> s{};
    std::copy_n(&simplices[i * w], w, s.begin());
    bool ok = true;
    for (int k = 0; k < w; ++k) {
      if (s[k] >= n) {
        fail("simplex " + std::to_string(i) + " " + tuple_text(s.data(), w) + ": index " + std::to_string(s[k]) +
             " is out of range (" + std::to_string(n) + " points)");
        ok = false;
      }
    }
    detail::sort_small(s.data(), w);
    if (ok && std::adjacent_find(s.begin(), s.begin() + w) != s.begin() + w) {
      fail("simplex " + std::to_string(i) + " " + tuple_text(s.data(), w) + " repeats a vertex");
      ok = false;
    }
    if (ok && pred.orientation(std::span<const std::uint32_t>(s.data(), w)) == 0) {
      fail("simplex " + std::to_string(i) + " " + tuple_text(s.data(), w) + " is degenerate (zero volume)");
      ok = false;
    }
    if (ok) {
      for (int k = 0; k < w; ++k) used[s[k]] = true;
    }
  }
  if (!report.violations.empty()) return report;

  // 2-3. Facets, sorted so that the (at most two) simplices sharing one are adjacent.
  struct FacetRef {
    std::uint32_t simplex;
    std::uint8_t opposite;  // position of the vertex not on the facet
  };
  auto facet_key = [&](const FacetRef& f, std::array<std::uint32_t, kMaxCols>& key) {
    const std::uint32_t* s = &simplices[f.simplex * w];
    int r = 0;
    for (int k = 0; k < w; ++k) {
      if (k != f.opposite) key[r++] = s[k];
    }
    detail::sort_small(key.data(), d);
  };
  std::vector<FacetRef> facets(m * w);
  for (std::size_t i = 0; i < m; ++i) {
    for (int k = 0; k < w; ++k) facets[i * w + k] = {static_cast<std::uint32_t>(i), static_cast<std::uint8_t>(k)};
  }
  std::sort(facets.begin(), facets.end(), [&](const FacetRef& a, const FacetRef& b) {
    std::array<std::uint32_t, kMaxCols> ka{}, kb{};
    facet_key(a, ka);
    facet_key(b, kb);
    return std::lexicographical_compare(ka.begin(), ka.begin() + d, kb.begin(), kb.begin() + d);
  });

  std::vector<FacetRef> hull;
  std::array<Row, kMaxCols> rows;
  // Side of point q relative to the facet (sorted ids) hyperplane.
  auto side = [&](const std::array<std::uint32_t, kMaxCols>& key, std::uint32_t q) {
    for (int r = 0; r + 1 < d; ++r) rows[r] = Row::of_point(key[r + 1]);
    rows[d - 1] = Row::of_point(q);
    return pred.spatial_sign(key[0], std::span<const Row>(rows.data(), d));
  };
  for (std::size_t i = 0; i < facets.size();) {
    std::array<std::uint32_t, kMaxCols> key{}, next{};
    facet_key(facets[i], key);
    std::size_t j = i + 1;
    while (j < facets.size()) {
      facet_key(facets[j], next);
      if (!std::equal(key.begin(), key.begin() + d, next.begin())) break;
      ++j;
    }
    const std::size_t count = j - i;
    if (count == 1) {
      hull.push_back(facets[i]);
    } else if (count == 2) {
      ++report.interior_facets;
      const FacetRef a = facets[i], b = facets[i + 1];
      const std::uint32_t apex_a = simplices[a.simplex * w + a.opposite];
      const std::uint32_t apex_b = simplices[b.simplex * w + b.opposite];
      if (side(key, apex_a) == side(key, apex_b)) {
        fail("facet " + tuple_text(key.data(), d) + ": simplices " + std::to_string(a.simplex) + " and " +
             std::to_string(b.simplex) + " overlap (both on the same side)");
      } else if (pred.side_of_sphere(std::span<const std::uint32_t>(&simplices[a.simplex * w], w), apex_b) < 0) {
        fail("facet " + tuple_text(key.data(), d) + " is not locally Delaunay: point " + std::to_string(apex_b) +
             " lies inside the circumsphere of simplex " + std::to_string(a.simplex) + " " +
             tuple_text(&simplices[a.simplex * w], w));
      }
    } else {
      fail("facet " + tuple_text(key.data(), d) + " is shared by " + std::to_string(count) + " simplices");
    }
    i = j;
  }
  report.hull_facets = hull.size();

  // 4. Coverage.
  for (std::size_t p = 0; p < n; ++p) {
    if (!used[p]) {
      fail("point " + std::to_string(p) + " is not a vertex of any simplex");
      break;
    }
  }
  mpq_class hull_volume = 0;
  const std::uint32_t reference = 0;
  std::array<BoundedDouble, kMaxDimension> normal;
  for (const FacetRef& f : hull) {
    std::array<std::uint32_t, kMaxCols> key{};
    facet_key(f, key);
    const std::uint32_t apex = simplices[f.simplex * w + f.opposite];
    const int inner = side(key, apex);
    for (int r = 0; r + 1 < d; ++r) rows[r] = Row::of_point(key[r + 1]);
    pred.spatial_normal(key[0], std::span<const Row>(rows.data(), d - 1), normal.data());
    const std::optional<std::uint32_t> beyond =
        tree.any_beyond(ps.point(key[0]), normal.data(), -inner, [&](std::uint32_t q) { return side(key, q); });
    if (beyond) {
      fail("boundary facet " + tuple_text(key.data(), d) + " is not on the convex hull: point " +
           std::to_string(*beyond) + " lies beyond it");
      continue;
    }
    // Signed volume of the cone from the reference point, positive when the reference
    // is on the inner side.
    std::array<std::uint32_t, kMaxCols> cone{};
    std::copy(key.begin() + 1, key.begin() + d, cone.begin());
    cone[d - 1] = reference;
    const mpq_class det = exact_volume_det(ps, key[0], cone.data());
    hull_volume += inner > 0 ? det : mpq_class(-det);
  }
  if (report.violations.empty()) {
    mpq_class mesh_volume = 0;
    for (std::size_t i = 0; i < m; ++i)
      mesh_volume += abs(exact_volume_det(ps, simplices[i * w], &simplices[i * w + 1]));
    if (mesh_volume != hull_volume) {
      fail("the simplices' volume (" + std::to_string(mesh_volume.get_d()) +
           " x d!) differs from the volume enclosed by "
           "the boundary facets (" +
           std::to_string(hull_volume.get_d()) + " x d!): the simplices overlap or leave gaps");
    }
  }
  report.valid = report.violations.empty();
  return report;
}

}  // namespace spokemesh
