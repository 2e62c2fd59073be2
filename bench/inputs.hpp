// Generated benchmark inputs, shared by the benchmarks of this folder: uniform random
// points and grids written the way users write them. Fixed seeds: every run meshes
// the same points.
#pragma once

#include <cstdint>
#include <random>
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
      case Kind::kGridDyadic: axis[i] = i / 32.0; break;
      case Kind::kGridLinspace:  // numpy: arange(side) * step + 0, the last value set to stop
        axis[i] = i + 1 == side ? 1.0 : i * (1.0 / (side - 1));
        break;
      case Kind::kGridDecimal: axis[i] = i * 0.1; break;
      default: axis[i] = i; break;
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

}  // namespace spokemesh::bench
