// Domains of any shape for tests and benchmarks (shape_domain.hpp): generated meshes
// and polygons whose measures are known, and seeds inside them.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/shape_domain.hpp"

namespace spokemesh::testing {

struct Mesh {
  std::vector<double> vertices;
  std::vector<std::uint32_t> triangles;
  std::uint32_t add(double x, double y, double z) {
    vertices.insert(vertices.end(), {x, y, z});
    return static_cast<std::uint32_t>(vertices.size() / 3 - 1);
  }
  void tri(std::uint32_t a, std::uint32_t b, std::uint32_t c) { triangles.insert(triangles.end(), {a, b, c}); }
  void quad(std::uint32_t a, std::uint32_t b, std::uint32_t c, std::uint32_t d) {
    tri(a, b, c);
    tri(a, c, d);
  }
  // An axis-aligned box [lo, hi], outward, each side cut into n x n squares.
  void box(const double lo[3], const double hi[3], int n = 1) {
    for (int axis = 0; axis < 3; ++axis) {
      for (int side = 0; side < 2; ++side) {
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        std::vector<std::uint32_t> id((n + 1) * (n + 1));
        for (int i = 0; i <= n; ++i) {
          for (int j = 0; j <= n; ++j) {
            double p[3];
            p[axis] = side ? hi[axis] : lo[axis];
            p[u] = lo[u] + (hi[u] - lo[u]) * i / n;
            p[v] = lo[v] + (hi[v] - lo[v]) * j / n;
            id[i * (n + 1) + j] = add(p[0], p[1], p[2]);
          }
        }
        for (int i = 0; i < n; ++i) {
          for (int j = 0; j < n; ++j) {
            const std::uint32_t a = id[i * (n + 1) + j], b = id[(i + 1) * (n + 1) + j],
                                c = id[(i + 1) * (n + 1) + j + 1], d = id[i * (n + 1) + j + 1];
            if (side)
              quad(a, b, c, d);  // u x v = axis direction: outward on the high side
            else
              quad(a, d, c, b);
          }
        }
      }
    }
  }
  // A UV sphere (outward), `rings` x `segments`.
  void sphere(const double centre[3], double r, int rings, int segments) {
    const std::uint32_t south = add(centre[0], centre[1], centre[2] - r);
    std::vector<std::uint32_t> id;
    for (int i = 1; i < rings; ++i) {
      const double phi = M_PI * i / rings - M_PI / 2;
      for (int j = 0; j < segments; ++j) {
        const double th = 2 * M_PI * j / segments;
        id.push_back(add(centre[0] + r * std::cos(phi) * std::cos(th), centre[1] + r * std::cos(phi) * std::sin(th),
                         centre[2] + r * std::sin(phi)));
      }
    }
    const std::uint32_t north = add(centre[0], centre[1], centre[2] + r);
    auto at = [&](int i, int j) { return id[(i - 1) * segments + (j % segments)]; };
    for (int j = 0; j < segments; ++j) tri(south, at(1, j + 1), at(1, j));
    for (int i = 1; i + 1 < rings; ++i) {
      for (int j = 0; j < segments; ++j) quad(at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j));
    }
    for (int j = 0; j < segments; ++j) tri(north, at(rings - 1, j), at(rings - 1, j + 1));
  }
  // A torus about the z axis (outward).
  void torus(double major, double minor, int nu, int nv) {
    std::vector<std::uint32_t> id;
    for (int i = 0; i < nu; ++i) {
      const double u = 2 * M_PI * i / nu;
      for (int j = 0; j < nv; ++j) {
        const double v = 2 * M_PI * j / nv;
        id.push_back(add((major + minor * std::cos(v)) * std::cos(u), (major + minor * std::cos(v)) * std::sin(u),
                         minor * std::sin(v)));
      }
    }
    auto at = [&](int i, int j) { return id[(i % nu) * nv + (j % nv)]; };
    for (int i = 0; i < nu; ++i)
      for (int j = 0; j < nv; ++j) quad(at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
  }
  // An L-shaped prism: the L in x, y ([0,2]^2 minus [1,2]^2), z in [0, h], its sides
  // and caps cut at the unit grid.
  void l_part(double h) {
    // Caps: three unit squares each; sides: the L's six edges cut at unit length.
    const double L[8][2] = {{0, 0}, {1, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2}, {0, 2}, {0, 1}};
    std::vector<std::uint32_t> bottom, top;
    for (const auto& p : L) bottom.push_back(add(p[0], p[1], 0));
    for (const auto& p : L) top.push_back(add(p[0], p[1], h));
    // The caps as triangles over the L's vertices and (0.5, 0.5)-free fans: squares
    // [0,1]^2 = 0,1,4,7; [1,2]x[0,1] = 1,2,3,4; [0,1]x[1,2] = 7,4,5,6.
    const int squares[3][4] = {{0, 1, 4, 7}, {1, 2, 3, 4}, {7, 4, 5, 6}};
    for (const auto& s : squares) {
      quad(top[s[0]], top[s[1]], top[s[2]], top[s[3]]);
      quad(bottom[s[0]], bottom[s[3]], bottom[s[2]], bottom[s[1]]);
    }
    for (int i = 0; i < 8; ++i) {
      const int j = (i + 1) % 8;
      quad(bottom[i], bottom[j], top[j], top[i]);
    }
  }
  // A cube [lo, hi] (n x n squares a side) with a spherical cavity, the cavity given
  // outward too: nesting turns it inward.
  static Mesh cube_with_cavity(const double lo[3], const double hi[3], int n, const double centre[3], double r,
                               int rings, int segments) {
    Mesh m;
    m.box(lo, hi, n);
    Mesh cavity;
    cavity.sphere(centre, r, rings, segments);
    const std::uint32_t base = static_cast<std::uint32_t>(m.vertices.size() / 3);
    m.vertices.insert(m.vertices.end(), cavity.vertices.begin(), cavity.vertices.end());
    for (std::uint32_t v : cavity.triangles) m.triangles.push_back(base + v);
    return m;
  }
  ShapeDomain solid(const std::string& name = "mesh") const {
    auto s = ShapeDomain::solid(vertices, triangles, name);
    if (!s.is_ok()) throw std::runtime_error(s.status().message());
    return std::move(s).value();
  }
};

inline std::vector<double> circle_ring(double cx, double cy, double r, int n, bool clockwise = false) {
  std::vector<double> ring;
  for (int i = 0; i < n; ++i) {
    const double t = 2 * M_PI * (clockwise ? -i : i) / n;
    ring.insert(ring.end(), {cx + r * std::cos(t), cy + r * std::sin(t)});
  }
  return ring;
}

// A 10 x 10 square with three holes: a square, a triangle and a 24-gon (given in
// mixed orientations: the domain orients them by nesting).
inline ShapeDomain three_holes() {
  std::vector<std::vector<double>> rings = {
      {0, 0, 10, 0, 10, 10, 0, 10},
      {1, 1, 1, 3, 3, 3, 3, 1},
      {6, 1, 9, 1, 7.5, 4},
      circle_ring(5, 7, 1.5, 24, true),
  };
  auto s = ShapeDomain::polygon(rings, "three_holes");
  if (!s.is_ok()) throw std::runtime_error(s.status().message());
  return std::move(s).value();
}

// n uniform points in the box [lo, hi] that `shape` holds strictly (plus, when
// `outside` > 0, that many more anywhere in the box).
inline PointSet seeds_inside(const ShapeDomain& shape, std::size_t n, std::uint64_t seed, std::size_t outside = 0) {
  const int d = shape.dimension();
  std::mt19937_64 rng(seed);
  std::vector<double> coords;
  std::size_t in = 0, out = 0;
  while (in < n || out < outside) {
    double x[3];
    for (int c = 0; c < d; ++c) {
      std::uniform_real_distribution<double> u(shape.lower()[c], shape.upper()[c]);
      x[c] = u(rng);
    }
    const int where = shape.locate(x);
    if (where > 0 && in < n) {
      ++in;
    } else if (where < 0 && out < outside) {
      ++out;
    } else {
      continue;
    }
    coords.insert(coords.end(), x, x + d);
  }
  PointSet ps(d, std::move(coords));
  if (Status st = ps.validate("seeds"); !st.is_ok()) throw std::runtime_error(st.message());
  return ps;
}

}  // namespace spokemesh::testing
