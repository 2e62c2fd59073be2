// Shared helpers for the test suite: point generators with fixed seeds, whole-mesh
// helpers, and the brute-force Delaunay oracle.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh::testing {

using Simplices = std::vector<std::uint32_t>;

inline std::vector<double> uniform_points(int d, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> c(n * d);
  for (double& v : c) v = u(rng);
  return c;
}

// side^d integer grid points (maximally cospherical).
inline std::vector<double> grid_points(int d, int side) {
  std::size_t n = 1;
  for (int k = 0; k < d; ++k) n *= side;
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t t = i;
    for (int k = 0; k < d; ++k) {
      c.push_back(static_cast<double>(t % side));
      t /= side;
    }
  }
  return c;
}

// The same grid with every coordinate v written as scale(v): i / (side - 1) as numpy's
// linspace computes it, i * 0.1, i / 32. Ties stay exact ties (a box's corners are
// cospherical whatever its side lengths), but the coordinates are no longer integers.
inline std::vector<double> scaled_grid_points(int d, int side, double (*scale)(double, int)) {
  std::vector<double> c = grid_points(d, side);
  for (double& v : c) v = scale(v, side);
  return c;
}
inline double linspace_value(double i, int side) { return i + 1 == side ? 1.0 : i * (1.0 / (side - 1)); }
inline double decimal_value(double i, int) { return i * 0.1; }
inline double dyadic_value(double i, int) { return i / 32.0; }

// Integer points on the sphere |p|^2 = r2 (exactly cospherical), plus the centre.
inline std::vector<double> sphere_points(int d, int r2, bool with_centre) {
  std::vector<double> c;
  int r = 0;
  while ((r + 1) * (r + 1) <= r2) ++r;
  std::vector<int> p(d, -r);
  for (;;) {
    int s = 0;
    for (int v : p) s += v * v;
    if (s == r2) c.insert(c.end(), p.begin(), p.end());
    int k = 0;
    while (k < d && p[k] == r) p[k++] = -r;
    if (k == d) break;
    ++p[k];
  }
  if (with_centre) c.insert(c.end(), d, 0.0);
  return c;
}

inline PointSet make_points(int d, std::vector<double> coords) {
  PointSet ps(d, std::move(coords));
  const Status s = ps.validate("test");
  EXPECT_TRUE(s.is_ok()) << s.message();
  return ps;
}

// The rows of a mesh_seeds run (in sweep order, as written), and its statistics when asked.
template <class TreeOrPoints>
Simplices mesh_rows(const TreeOrPoints& tree_or_points, const MeshOptions& options, MeshStats* stats = nullptr) {
  Simplices out;
  auto r = mesh_seeds(tree_or_points, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
    out.insert(out.end(), block.begin(), block.end());
    return Status::ok();
  });
  EXPECT_TRUE(r.is_ok()) << r.status().message();
  if (stats != nullptr && r.is_ok()) *stats = r.value();
  return out;
}

inline Simplices mesh_all(const KdTree& tree, unsigned threads = 1, std::uint32_t begin = 0,
                          std::uint32_t end = 0xFFFFFFFFu, std::uint64_t random_seed = 0x5eed,
                          std::size_t facet_cache_bytes = MeshOptions{}.facet_cache_bytes, std::uint32_t block_size = 0,
                          MeshEngine engine = MeshEngine::kAuto, std::uint32_t region_points = 0) {
  MeshOptions options;
  options.engine = engine;
  options.region_points = region_points;
  options.block_size = block_size;
  options.facet_cache_bytes = facet_cache_bytes;
  options.threads = threads;
  options.seed_begin = begin;
  options.seed_end = end;
  options.star.random_seed = random_seed;
  return mesh_rows(tree, options);
}

// The rows of a mesh (width indices each, as written) in lexicographic order of the
// rows themselves: equal for two meshes with the same oriented rows in any order.
inline Simplices sorted_rows(const Simplices& flat, int width) {
  std::vector<std::vector<std::uint32_t>> rows;
  for (std::size_t i = 0; i + width <= flat.size(); i += width)
    rows.emplace_back(flat.begin() + i, flat.begin() + i + width);
  std::sort(rows.begin(), rows.end());
  Simplices out;
  for (const auto& r : rows) out.insert(out.end(), r.begin(), r.end());
  return out;
}

// Sorted simplices as a set of tuples.
inline std::set<std::vector<std::uint32_t>> as_set(const Simplices& flat, int width) {
  std::set<std::vector<std::uint32_t>> s;
  for (std::size_t i = 0; i + width <= flat.size(); i += width) {
    std::vector<std::uint32_t> t(flat.begin() + i, flat.begin() + i + width);
    std::sort(t.begin(), t.end());
    s.insert(t);
  }
  return s;
}

// All Delaunay simplices incident to `seed` by exhaustive search over d-subsets
// (tiny inputs only): non-degenerate, and no point inside the perturbed circumsphere.
// With weights: the regular triangulation's star (power spheres), empty when the
// seed is hidden.
inline std::set<std::vector<std::uint32_t>> brute_force_star(const PointSet& ps, std::uint32_t seed,
                                                             std::span<const double> weights = {}) {
  const Predicates pred(ps, weights);
  const int d = ps.dimension();
  const std::uint32_t n = static_cast<std::uint32_t>(ps.size());
  std::vector<std::uint32_t> others;
  for (std::uint32_t i = 0; i < n; ++i) {
    if (i != seed) others.push_back(i);
  }
  std::set<std::vector<std::uint32_t>> truth;
  std::vector<bool> pick(others.size(), false);
  std::fill(pick.begin(), pick.begin() + d, true);
  do {
    std::vector<std::uint32_t> s{seed};
    for (std::size_t i = 0; i < pick.size(); ++i) {
      if (pick[i]) s.push_back(others[i]);
    }
    std::sort(s.begin(), s.end());
    if (pred.orientation(s) == 0) continue;
    bool empty = true;
    for (std::uint32_t q = 0; q < n && empty; ++q) {
      if (!std::binary_search(s.begin(), s.end(), q) && pred.side_of_sphere(s, q) < 0) empty = false;
    }
    if (empty) truth.insert(s);
  } while (std::prev_permutation(pick.begin(), pick.end()));
  return truth;
}

}  // namespace spokemesh::testing
