// Triangulation<D> (core/src/mesh/triangulation.hpp), the whole mesh's kernel in 2-d
// and 3-d: valid after every insertion on small inputs, equal to CGAL's Delaunay
// triangulation simplex for simplex (random, grids, cospherical, the surface shapes of
// issue 41), and the same for any insertion order.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "cgal_oracle.hpp"
#include "mesh/triangulation.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace spokemesh::testing;

template <int D>
Tuples finite_cells(const detail::Triangulation<D>& t) {
  Tuples out;
  std::vector<bool> live(1, true);
  // Live cells: those reachable from the vertices' incident cells.
  std::vector<std::uint32_t> cells, seen;
  for (std::uint32_t v = 1; v < t.vertex_count(); ++v) t.incident_cells(v, cells, seen);
  for (const std::uint32_t c : cells) {
    if (t.is_infinite(c)) continue;
    std::vector<std::uint32_t> tuple;
    for (const std::uint32_t v : t.cell(c).v) tuple.push_back(t.global(v));
    std::sort(tuple.begin(), tuple.end());
    out.insert(tuple);
  }
  return out;
}

template <int D>
Tuples triangulate(const PointSet& ps, const std::vector<std::uint32_t>& order, bool check_each = false) {
  const Predicates pred(ps);
  detail::Triangulation<D> t(ps, pred);
  for (const std::uint32_t id : order) {
    t.insert(id);
    if (check_each) {
      std::string why;
      EXPECT_TRUE(t.valid(&why)) << why << " after point " << id;
    }
  }
  std::string why;
  EXPECT_TRUE(t.valid(&why)) << why;
  return finite_cells(t);
}

struct Case {
  std::string name;
  int d;
  std::vector<double> coords;
};

std::vector<double> on_sphere(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g;
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    double v[3] = {g(rng), g(rng), g(rng)};
    const double r = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    c.insert(c.end(), {v[0] / r, v[1] / r, v[2] / r});
  }
  return c;
}

std::vector<double> contour_lines(int curves, double step, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> phase(0, 6.283185307179586);
  std::vector<double> c;
  for (int k = 0; k < curves; ++k) {
    const double r0 = 5 + 8 * k, ph = phase(rng);
    const int count = static_cast<int>(6.283185307179586 * r0 / step);
    for (int i = 0; i < count; ++i) {
      const double t = 6.283185307179586 * i / count;
      const double r = r0 * (1 + 0.05 * std::sin(3 * t + ph));
      c.push_back(std::round(r * std::cos(t) * 1000) / 1000);
      c.push_back(std::round(r * std::sin(t) * 1000) / 1000);
    }
  }
  return c;
}

std::vector<Case> cases() {
  std::vector<Case> out = {
      {"uniform-2d", 2, uniform_points(2, 3000, 21)},
      {"uniform-3d", 3, uniform_points(3, 2000, 22)},
      {"grid-2d", 2, grid_points(2, 30)},
      {"grid-3d", 3, grid_points(3, 9)},
      {"linspace-grid-2d", 2, scaled_grid_points(2, 25, linspace_value)},
      {"linspace-grid-3d", 3, scaled_grid_points(3, 8, linspace_value)},
      {"decimal-grid-3d", 3, scaled_grid_points(3, 7, decimal_value)},
      {"circle-2d", 2, sphere_points(2, 325, true)},
      {"sphere-3d", 3, sphere_points(3, 50, true)},
      {"float-sphere-3d", 3, on_sphere(1500, 5)},
      {"contours-2d", 2, contour_lines(6, 0.5, 7)},
  };
  std::vector<double> bcc = grid_points(3, 4);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) bcc.insert(bcc.end(), {i + 0.5, j + 0.5, k + 0.5});
  out.push_back({"bcc-3d", 3, bcc});
  // A flat square of grid points with a few points off the plane: coplanar hull faces.
  std::vector<double> slab = grid_points(2, 12);
  std::vector<double> slab3;
  for (std::size_t i = 0; i < slab.size(); i += 2) slab3.insert(slab3.end(), {slab[i], slab[i + 1], 0.0});
  slab3.insert(slab3.end(), {5.5, 5.5, 3.0, 2.0, 7.0, -1.5, 12.5, 3.0, 0.0, -2.0, -2.0, 0.0});
  out.push_back({"flat-grid+apexes-3d", 3, slab3});
  return out;
}

TEST(Triangulation, EqualsCgalInAnyOrder) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    std::vector<std::uint32_t> order(ps.size());
    std::iota(order.begin(), order.end(), 0u);
    const Tuples cgal = c.d == 2 ? cgal_2(ps) : cgal_3(ps);
    const Tuples ours = c.d == 2 ? triangulate<2>(ps, order) : triangulate<3>(ps, order);
    EXPECT_EQ(ours.size(), cgal.size());
    EXPECT_TRUE(ours == cgal) << "index order";
    for (std::uint64_t seed : {1u, 2u}) {
      std::mt19937_64 rng(seed);
      std::shuffle(order.begin(), order.end(), rng);
      const Tuples shuffled = c.d == 2 ? triangulate<2>(ps, order) : triangulate<3>(ps, order);
      EXPECT_TRUE(shuffled == cgal) << "shuffled order, seed " << seed;
    }
  }
}

TEST(Triangulation, ValidAfterEveryInsertion) {
  // Small sets, checked whole after each point (degenerate starts included: the first
  // points of a grid in index order are collinear, then coplanar).
  for (const Case& c : {Case{"grid-3d", 3, grid_points(3, 4)}, Case{"grid-2d", 2, grid_points(2, 6)},
                        Case{"uniform-3d", 3, uniform_points(3, 60, 3)}, Case{"sphere-3d", 3, sphere_points(3, 9, true)}}) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    std::vector<std::uint32_t> order(ps.size());
    std::iota(order.begin(), order.end(), 0u);
    const Tuples ours = c.d == 2 ? triangulate<2>(ps, order, true) : triangulate<3>(ps, order, true);
    EXPECT_TRUE(ours == (c.d == 2 ? cgal_2(ps) : cgal_3(ps)));
  }
}

}  // namespace
}  // namespace spokemesh
