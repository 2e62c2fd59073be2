// The one dispatch from a runtime dimension to code compiled for it.
//
// As geogram's RVD (runtime dimension -> kernels compiled for the common d, a generic
// path for the rest): loops over coordinates unroll, fixed-size scratch lives on the
// stack, and index arithmetic by d becomes shifts and constant offsets. Every
// dimension-specialised kernel of the core is reached through dispatch_dimension, so
// adding or dropping a compiled dimension is a change here only.
#pragma once

#include <type_traits>

#include "spokemesh/point_set.hpp"

namespace spokemesh::detail {

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
    case 2: return fn(Dimension<2>{});
    case 3: return fn(Dimension<3>{});
    case 4: return fn(Dimension<4>{});
    case 5: return fn(Dimension<5>{});
    case 6: return fn(Dimension<6>{});
    case 7: return fn(Dimension<7>{});
    case 8: return fn(Dimension<8>{});
    default: return fn(Dimension<0>{});
  }
}

}  // namespace spokemesh::detail
