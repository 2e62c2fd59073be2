// Small linear systems (2 x 2, 3 x 3) by Cramer's rule with a forward error bound: the
// circumcentres of triangles and tetrahedra (voronoi.cpp) and the vertices of the
// specialised 3-d cell (box_cell_3d.cpp). Internal to the core.
#pragma once

#include "spokemesh/predicates.hpp"

#include <cmath>
#include <limits>

namespace spokemesh::detail {

// Solves A y = c (rows a[i]) as y = adj(A) c / det(A). Returns false when det(A) is
// within 64 units of its own rounding (nearly singular: the caller decides another
// way). Otherwise `error` bounds |y - y*|_inf, y* the exact solution of the system
// whose entries are the exact values that a and c approximate with a few units of
// relative rounding each (differences of coordinates, squared norms / 2, a wall's
// distance).
//
// The bound, first order with a factor 2 to spare: the numerators and det(A) are off
// by at most gamma = 16u times their absolute-value sums, so y by (|dN| + |y| |dD|) /
// (|D| - |dD|); the inputs' own rounding (4u relative) moves the exact solution by at
// most |A^-1| 4u (|A| |y| + 2 |c|), with |A^-1| <= |adj A| / |D| (infinity norms).
//
// T is double, or long double (x87 extended precision: u = 2^-64) for systems too
// ill-conditioned for double; the bound is the same with T's unit roundoff u, the
// inputs then computed in T too.
//
// Thread safety: a pure function.
template <int N, class T>
bool cramer_solve(const T (&a)[N][N], const T (&c)[N], T (&y)[N], T& error) {
  static_assert(N == 2 || N == 3);
  constexpr T kUnit = filter::kUnitRoundoffOf<T>;
  // adj[i][k]: the cofactor of a[i][k], so y_k = sum_i c_i adj[i][k] / D; adj_abs its
  // products' absolute-value sums (its rounding).
  T adj[N][N], adj_abs[N][N];
  if constexpr (N == 3) {
    for (int i = 0; i < 3; ++i) {
      const T* p = a[(i + 1) % 3];
      const T* q = a[(i + 2) % 3];
      for (int k = 0; k < 3; ++k) {
        const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
        adj[i][k] = p[k1] * q[k2] - p[k2] * q[k1];
        adj_abs[i][k] = std::abs(p[k1] * q[k2]) + std::abs(p[k2] * q[k1]);
      }
    }
  } else {
    adj[0][0] = a[1][1], adj[0][1] = -a[1][0];
    adj[1][0] = -a[0][1], adj[1][1] = a[0][0];
    for (int i = 0; i < 2; ++i) {
      for (int k = 0; k < 2; ++k) adj_abs[i][k] = std::abs(adj[i][k]);
    }
  }
  T D = 0, DA = 0;
  for (int k = 0; k < N; ++k) {
    D += a[0][k] * adj[0][k];
    DA += std::abs(a[0][k]) * adj_abs[0][k];
  }
  if (!(std::abs(D) > 64 * kUnit * DA)) return false;
  const T gamma = 16 * kUnit;
  const T inv_d = 1 / (std::abs(D) - gamma * DA);
  T y_norm = 0, n_abs = 0;
  for (int k = 0; k < N; ++k) {
    T num = 0, num_abs = 0;
    for (int i = 0; i < N; ++i) {
      num += c[i] * adj[i][k];
      num_abs += std::abs(c[i]) * adj_abs[i][k];
    }
    y[k] = num / D;
    y_norm = std::max(y_norm, std::abs(y[k]));
    n_abs = std::max(n_abs, num_abs);
  }
  T adj_norm = 0, a_norm = 0, c_norm = 0;
  for (int r = 0; r < N; ++r) {
    T adj_row = 0, a_row = 0;
    for (int i = 0; i < N; ++i) {
      adj_row += std::abs(adj[i][r]);  // row r of adj(A) as a matrix acting on c
      a_row += std::abs(a[r][i]);
    }
    adj_norm = std::max(adj_norm, adj_row);
    a_norm = std::max(a_norm, a_row);
    c_norm = std::max(c_norm, std::abs(c[r]));
  }
  const T err_round = (gamma * n_abs + y_norm * gamma * DA) * inv_d;
  const T err_input = adj_norm * inv_d * 4 * kUnit * (a_norm * y_norm + 2 * c_norm);
  error = 2 * (err_round + err_input);
  return std::isfinite(error);
}

}  // namespace spokemesh::detail
