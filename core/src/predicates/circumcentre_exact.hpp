// The exact circumcentres behind circumcentre() (circumcentre.cpp), for tests that hold
// the two exact ways to each other. Internal to the core.
#pragma once

#include <cstdint>
#include <vector>

#include "spokemesh/point_set.hpp"

namespace spokemesh::detail {

// The exact circumcentre (power centre with `weights`) of the points ids[0..k], rounded
// once (mpq -> double truncates: at most one ulp): Gaussian elimination on the normal
// equations in rationals. Any k <= d.
std::vector<double> circumcentre_rational(const PointSet& points, const std::uint32_t* ids, int k,
                                          const double* weights);

// The same value for a triangle in 2-d or a tetrahedron in 3-d without weights (k = d),
// by Cramer's rule on integers: the coordinates scaled by one power of two to integers,
// so differences, squared norms and the determinants are exact integer arithmetic with
// one rational per coordinate at the end (no normalisation in between): the same
// rational, so the same double, at a fraction of the cost. False (out untouched) when
// the simplex is flat or the case is not one of these.
bool circumcentre_integer(const PointSet& points, const std::uint32_t* ids, int k, double* out);

}  // namespace spokemesh::detail
