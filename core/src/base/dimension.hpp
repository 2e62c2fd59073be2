// The one dispatch from a runtime dimension to code compiled for it.
//
// As geogram's RVD (runtime dimension -> kernels compiled for the common d, a generic
// path for the rest): loops over coordinates unroll, fixed-size scratch lives on the
// stack, and index arithmetic by d becomes shifts and constant offsets. Every
// dimension-specialised kernel of the core is reached through dispatch_dimension, so
// adding or dropping a compiled dimension is a change here only.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>

#include "spokemesh/point_set.hpp"

namespace spokemesh::detail {

// The core's dimension policy, in one table: which specialised method each stage
// takes in a dimension, and its measured tuning (each value: bench/README.md, "Tuning
// history"). Dimensions beyond kMaxDimension take the last row. Kernels compiled per
// dimension are reached by dispatch_dimension below; everything else that depends on
// d asks policy(d), so a dimension's choices are read and changed here.
struct DimensionPolicy {
  std::size_t candidates;            // a star's first k-NN candidates (StarWalker)
  double simplices_per_point;        // Delaunay simplices per uniform point, for sizing tables
  std::uint32_t sweep_block_points;  // a whole mesh's largest sweep block (BlockDecomposition)
  // Stars by the ring walk around the seed (RingWalk: 2-d, where a star is a polygon),
  // and what a run's stars share: edges per point (EdgeCache) instead of facets.
  bool ring_walk;
  // Clipped cells to a box by the direct route (clipping the box by bisectors, as
  // Voro++) unless the caller chooses; the star's route otherwise. Measured: 3-d the
  // direct route is faster; 2-d the ring walk is; 4-d they tie; from 6-d the box's 2^d
  // corners make clipping slow.
  bool direct_cells;
  std::size_t cell_candidates;  // the direct route's first k-NN round
  // A whole mesh by local triangulations (2-d, 3-d; delaunay_sweep.cpp): the points of
  // a region triangulated at once (0: the route does not apply).
  std::uint32_t triangulation_region_points;
};
inline const DimensionPolicy& policy(int d) {
  // Simplices per point as meshed here (2-d to 5-d: 5,000 to 1,000,000 points; 6-d to
  // 8-d: rough, they rise with n as the hull's share falls).
  static constexpr std::array<DimensionPolicy, kMaxDimension + 1> kTable = {{
      {0, 0, 0, false, false, 16, 0},
      {8, 0, 0, false, false, 16, 0},
      {16, 2.0, 16384, true, false, 16, 131072},
      {48, 6.8, 4096, false, true, 40, 65536},
      {100, 31, 1024, false, false, 64, 0},
      {200, 160, 1024, false, false, 128, 0},
      {400, 900, 1024, false, false, 256, 0},
      {1280, 6000, 1024, false, false, 512, 0},
      {2560, 40000, 1024, false, false, 1024, 0},
  }};
  return kTable[static_cast<std::size_t>(std::clamp(d, 0, kMaxDimension))];
}

// A compile-time dimension; 0 stands for "the runtime d" (the generic path).
template <int D>
using Dimension = std::integral_constant<int, D>;

// Calls fn(Dimension<d>{}) for 2 <= d <= kMaxDimension and fn(Dimension<0>{})
// otherwise (the k-d tree also serves the approximate walk, up to d = 1024); returns
// what fn returns. Callers that only support the compiled range guard the generic
// path with `if constexpr`.
template <class Fn>
decltype(auto) dispatch_dimension(int d, Fn&& fn) {
  static_assert(kMaxDimension == 8, "add or remove the cases below with kMaxDimension");
  switch (d) {
    case 2:
      return fn(Dimension<2>{});
    case 3:
      return fn(Dimension<3>{});
    case 4:
      return fn(Dimension<4>{});
    case 5:
      return fn(Dimension<5>{});
    case 6:
      return fn(Dimension<6>{});
    case 7:
      return fn(Dimension<7>{});
    case 8:
      return fn(Dimension<8>{});
    default:
      return fn(Dimension<0>{});
  }
}

// dispatch_dimension for kernels compiled in 2-d and 3-d only (the local
// triangulations and the halo certificates): fn(Dimension<d>{}) there, `otherwise`
// in every other dimension.
template <class R, class Fn>
R dispatch_2d_3d(int d, R otherwise, Fn&& fn) {
  return dispatch_dimension(d, [&](auto dim) -> R {
    constexpr int D = decltype(dim)::value;
    if constexpr (D == 2 || D == 3) {
      return fn(dim);
    } else {
      return std::move(otherwise);
    }
  });
}

}  // namespace spokemesh::detail
