// Circumcentres (and power centres) of faces of a point set: constructions, not
// predicates, with a stated error bound; rounded from exact rationals where double
// could miss it. For the walkers' margins, the cells' vertices and the certificates.
//
// Thread safety: pure functions.
#pragma once

#include <cstdint>
#include <vector>

#include "spokemesh/point_set.hpp"

namespace spokemesh {

// Circumcentre of the points `ids` (2..d+1 of them): the centre of the smallest
// sphere through them, which lies in their affine hull. Solved on the coordinate
// differences: a triangle in 2-d or a tetrahedron in 3-d by Cramer's rule where its
// forward error bound meets the target, otherwise by column-pivoting QR, and in exact
// rationals where the QR's condition estimate says double could miss the bound: within 1e-12 of the circumradius plus
// one ulp of each coordinate. No heap allocation but the result (d <= 8). With
// `weights` (one per point, or null): the orthocentre (power centre), the point of the
// affine hull with equal power |c - p|^2 - w_p to every point, within 1e-12 of the
// larger of its distance from the first point and the face's size (plus one ulp).
std::vector<double> circumcentre(const PointSet& points, const std::uint32_t* ids, int count,
                                 const double* weights = nullptr);
// The same written to out[0..d): no heap allocation at all for triangles in 2-d and
// tetrahedra in 3-d that Cramer's rule decides (nearly all of them: a star's centres).
void circumcentre(const PointSet& points, const std::uint32_t* ids, int count, const double* weights, double* out);
// The face's size in circumcentre()'s bound for power centres: the largest squared
// distance from the first of `ids` to the others.
double face_size2(const PointSet& points, const std::uint32_t* ids, int count);

}  // namespace spokemesh
