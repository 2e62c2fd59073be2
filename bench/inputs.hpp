// Generated benchmark inputs, shared by the benchmarks of this folder and the tests:
// uniform random points, grids written the way users write them, and the shapes users
// bring (the same families as bench/shapes.py, drawn with C++'s generators:
// alike in shape, not in every digit). Fixed seeds: every run meshes the same points.
// Coordinates are row-major, d per point.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace spokemesh::bench {

enum class Kind { kUniform, kGridInteger, kGridDyadic, kGridLinspace, kGridDecimal, kGridJittered };

inline std::vector<double> uniform(int d, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> c(n * d);
  for (double& v : c) v = u(rng);
  return c;
}

// A grid's axis values: i (integers), i / 32 (exact dyadic), i / (side - 1) as numpy's
// linspace(0, 1, side) computes it, i * 0.1 (decimal steps), or integers jittered by
// up to 1e-3 per coordinate (general position: the twin without ties).
inline std::vector<double> grid(int d, int side, Kind kind, std::uint64_t seed) {
  std::vector<double> axis(static_cast<std::size_t>(side));
  for (int i = 0; i < side; ++i) {
    switch (kind) {
      case Kind::kGridDyadic:
        axis[i] = i / 32.0;
        break;
      case Kind::kGridLinspace:  // numpy: arange(side) * step + 0, the last value set to stop
        axis[i] = i + 1 == side ? 1.0 : i * (1.0 / (side - 1));
        break;
      case Kind::kGridDecimal:
        axis[i] = i * 0.1;
        break;
      default:
        axis[i] = i;
        break;
    }
  }
  std::size_t n = 1;
  for (int c = 0; c < d; ++c) n *= static_cast<std::size_t>(side);
  std::vector<double> coords(n * d);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> jitter(-1e-3, 1e-3);
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t rest = i;
    for (int c = d - 1; c >= 0; --c) {
      coords[i * d + c] = axis[rest % side] + (kind == Kind::kGridJittered ? jitter(rng) : 0.0);
      rest /= side;
    }
  }
  return coords;
}

inline constexpr double kTwoPi = 6.283185307179586;

// 2-d contour lines: `curves` nested closed curves of radius 5 + 8k wobbled by 5%, a
// point every `step` along each, coordinates rounded to 1e-3 (60 curves at step 0.5:
// about 180k points).
inline std::vector<double> contours(int curves, double step, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> phase(0, kTwoPi);
  std::vector<double> c;
  for (int k = 0; k < curves; ++k) {
    const double r0 = 5 + 8.0 * k, p3 = phase(rng), p5 = phase(rng), p7 = phase(rng);
    const int count = static_cast<int>(kTwoPi * r0 / step);
    for (int i = 0; i < count; ++i) {
      const double t = kTwoPi * i / count;
      const double r = r0 * (1 + 0.05 * (std::sin(3 * t + p3) + std::sin(5 * t + p5) + std::sin(7 * t + p7)) / 3);
      c.push_back(std::round(r * std::cos(t) * 1000) / 1000);
      c.push_back(std::round(r * std::sin(t) * 1000) / 1000);
    }
  }
  return c;
}

// 2.5-d terrain: x, y uniform over [0, side]^2, z a smooth surface of amplitude 3 plus
// gaussian noise 0.05 (a LiDAR ground model; side 1000 for the benchmarks).
inline std::vector<double> terrain(std::size_t n, double side, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, side);
  std::normal_distribution<double> noise(0, 0.05);
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = u(rng), y = u(rng);
    const double z =
        1.5 * std::sin(x / 97) * std::cos(y / 131) + std::sin((x + y) / 53) + 0.5 * std::cos(x / 23 - y / 41);
    c.insert(c.end(), {x, y, z + noise(rng)});
  }
  return c;
}

// A scanner 2 m above a ground plane: `rings` elevation rings (-25 to -1 degrees) of
// `azimuths` points each, every ray ending on the ground or on the first of
// `buildings` axis-aligned boxes around the scanner, within 120 m; noise 2 mm per
// coordinate, rounded to 0.1 mm (32 x 3000: 96,000 points).
inline std::vector<double> scanner_rings(int rings, int azimuths, int buildings, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> noise(0, 0.002);
  std::vector<std::array<double, 6>> boxes;
  for (int k = 0; k < buildings; ++k) {
    const double angle = k * kTwoPi / std::max(buildings, 1) + (u(rng) - 0.5) * 0.4, dist = 15 + 25 * u(rng);
    const double cx = dist * std::cos(angle), cy = dist * std::sin(angle);
    const double w = 4 + 6 * u(rng), l = 4 + 6 * u(rng), h = 3 + 9 * u(rng);
    boxes.push_back({cx - w / 2, cy - l / 2, 0, cx + w / 2, cy + l / 2, h});
  }
  const double origin[3] = {0, 0, 2};
  std::vector<double> c;
  for (int e = 0; e < rings; ++e) {
    const double elev = (-25 + 24.0 * e / std::max(rings - 1, 1)) * kTwoPi / 360;
    const double offset = u(rng) * kTwoPi / azimuths;  // a spinning head's timing
    for (int a = 0; a < azimuths; ++a) {
      const double az = kTwoPi * a / azimuths + offset;
      const double dir[3] = {std::cos(elev) * std::cos(az), std::cos(elev) * std::sin(az), std::sin(elev)};
      double t = -origin[2] / dir[2];
      for (const auto& b : boxes) {  // slab test
        double lo = 0, hi = t;
        for (int k = 0; k < 3 && lo <= hi; ++k) {
          if (std::fabs(dir[k]) < 1e-300) {
            if (origin[k] < b[k] || origin[k] > b[3 + k]) hi = -1;
            continue;
          }
          double t1 = (b[k] - origin[k]) / dir[k], t2 = (b[3 + k] - origin[k]) / dir[k];
          if (t1 > t2) std::swap(t1, t2);
          lo = std::max(lo, t1);
          hi = std::min(hi, t2);
        }
        if (lo <= hi && lo > 0) t = lo;
      }
      if (t >= 120) continue;
      for (int k = 0; k < 3; ++k) c.push_back(std::round((origin[k] + dir[k] * t + noise(rng)) * 1e4) / 1e4);
    }
  }
  return c;
}

// n points on the unit sphere (normalised gaussians, float64).
inline std::vector<double> sphere_surface(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g;
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = g(rng), y = g(rng), z = g(rng), r = std::sqrt(x * x + y * y + z * z);
    c.insert(c.end(), {x / r, y / r, z / r});
  }
  return c;
}

// n points on a torus (major radius 3, minor 1), uniform by area.
inline std::vector<double> torus_surface(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> angle(0, kTwoPi), u(0, 1);
  std::vector<double> c;
  while (c.size() < 3 * n) {
    const double a = angle(rng), b = angle(rng);
    if (u(rng) >= (3 + std::cos(b)) / 4) continue;
    c.insert(c.end(), {(3 + std::cos(b)) * std::cos(a), (3 + std::cos(b)) * std::sin(a), std::sin(b)});
  }
  return c;
}

// The vertices marching cubes puts on the level set f = 1 of a sum of six gaussian
// blobs, sampled on a side^3 grid over [-1.5, 1.5]^3: a point on every grid edge whose
// ends straddle the level, interpolated linearly (about 0.41 side^2 of them).
inline std::vector<double> isosurface(int side, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::array<std::array<double, 4>, 6> blobs{};
  for (auto& b : blobs) b = {u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5, 0.25 + 0.15 * u(rng)};
  const double step = 3.0 / (side - 1);
  auto at = [&](int i) { return -1.5 + step * i; };
  auto f = [&](double x, double y, double z) {
    double s = 0;
    for (const auto& b : blobs)
      s += std::exp(-((x - b[0]) * (x - b[0]) + (y - b[1]) * (y - b[1]) + (z - b[2]) * (z - b[2])) / (b[3] * b[3]));
    return s - 1;
  };
  std::vector<double> values(static_cast<std::size_t>(side) * side * side);
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j)
      for (int k = 0; k < side; ++k)
        values[(static_cast<std::size_t>(i) * side + j) * side + k] = f(at(i), at(j), at(k));
  std::vector<double> c;
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j)
      for (int k = 0; k < side; ++k) {
        const double v = values[(static_cast<std::size_t>(i) * side + j) * side + k];
        const int next[3][3] = {{i + 1, j, k}, {i, j + 1, k}, {i, j, k + 1}};
        for (int axis = 0; axis < 3; ++axis) {
          const auto& nx = next[axis];
          if (nx[0] >= side || nx[1] >= side || nx[2] >= side) continue;
          const double w = values[(static_cast<std::size_t>(nx[0]) * side + nx[1]) * side + nx[2]];
          if ((v < 0) == (w < 0)) continue;
          std::array<double, 3> p = {at(i), at(j), at(k)};
          p[static_cast<std::size_t>(axis)] += step * v / (v - w);
          c.insert(c.end(), p.begin(), p.end());
        }
      }
  return c;
}

// Nearest-neighbour spacing over six orders of magnitude: half the points in 50
// gaussian clumps of width 1e-5, half uniform, in [0, 100]^3.
inline std::vector<double> density_contrast(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 100);
  std::normal_distribution<double> g(0, 1e-5);
  std::vector<std::array<double, 3>> centres(50);
  for (auto& c : centres) c = {u(rng), u(rng), u(rng)};
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    if (i % 2 == 0) {
      const auto& m = centres[i / 2 % 50];
      c.insert(c.end(), {m[0] + g(rng), m[1] + g(rng), m[2] + g(rng)});
    } else {
      c.insert(c.end(), {u(rng), u(rng), u(rng)});
    }
  }
  return c;
}

// Gaussian clumps: `clumps` centres uniform in [0, 1]^d, standard deviation 0.01.
inline std::vector<double> clustered(int d, std::size_t n, int clumps, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> g(0, 0.01);
  std::vector<double> centres(static_cast<std::size_t>(clumps) * d);
  for (double& v : centres) v = u(rng);
  std::vector<double> c;
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t k = i % static_cast<std::size_t>(clumps);
    for (int j = 0; j < d; ++j) c.push_back(centres[k * d + j] + g(rng));
  }
  return c;
}

// The shape families by name, at about n points (a family with a natural size scales
// its own parameter: curves, rings, grid side): what tests and benchmarks loop over.
struct Shape {
  std::string name;
  int d;
  std::vector<double> coords;
};
inline std::vector<Shape> shape_families(std::size_t n, std::uint64_t seed) {
  const double scale = std::sqrt(static_cast<double>(n) / 181680.0);
  return {
      {"contours", 2, contours(std::max(2, static_cast<int>(60 * scale)), 0.5, seed)},
      {"terrain", 3, terrain(n, 1000 * std::sqrt(static_cast<double>(n) / 200000.0), seed + 1)},
      {"rings", 3, scanner_rings(32, std::max(16, static_cast<int>(n / 32)), 0, seed + 2)},
      {"rings-buildings", 3, scanner_rings(32, std::max(16, static_cast<int>(n / 32)), 8, seed + 3)},
      {"sphere", 3, sphere_surface(n, seed + 4)},
      {"torus", 3, torus_surface(n, seed + 5)},
      {"isosurface", 3, isosurface(std::max(8, static_cast<int>(std::sqrt(static_cast<double>(n) / 0.41))), seed + 6)},
      {"contrast", 3, density_contrast(n, seed + 7)},
      {"clustered", 3, clustered(3, n, std::max(2, static_cast<int>(n / 1000)), seed + 8)},
  };
}

}  // namespace spokemesh::bench
