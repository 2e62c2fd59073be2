// The exact Delaunay-neighbour oracle for any dimension, as linear programs (GLPK;
// tests and benchmarks only). (i, j) is a Delaunay edge iff some w is equidistant to
// x_i and x_j and strictly closer to them than to every other point. With w relative
// to x_i, each other point k gives 2 w.(x_k - x_i) <= |x_k - x_i|^2 - delta, and j
// gives equality with delta = 0; maximise delta (capped at 1): an edge iff delta > 0.
// GLPK solves in floating point, so the decision uses a small tolerance: fine for an
// oracle on random inputs, which have no near-ties at that scale.
#pragma once

#include <glpk.h>

#include <cstdint>
#include <vector>

namespace spokemesh::testing {

// Delaunay neighbours of point i among n points (row-major, dimension d), ascending.
// candidates: the j to test (empty: all).
inline std::vector<std::uint32_t> lp_delaunay_neighbors(const std::vector<double>& pts, int d, std::uint32_t i,
                                                        std::vector<std::uint32_t> candidates = {}) {
  const std::size_t n = pts.size() / static_cast<std::size_t>(d);
  if (candidates.empty()) {
    for (std::uint32_t j = 0; j < n; ++j) candidates.push_back(j);
  }
  const double* xi = &pts[static_cast<std::size_t>(i) * d];
  // Rows: one per point k != i (k == j becomes the equality row); columns: w (d), delta.
  std::vector<int> ia(1), ja(1);
  std::vector<double> ar(1), rhs(n);
  for (std::size_t k = 0; k < n; ++k) {
    if (k == i) continue;
    const double* xk = &pts[k * d];
    double r = 0;
    for (int c = 0; c < d; ++c) r += (xk[c] - xi[c]) * (xk[c] - xi[c]);
    rhs[k] = r;
  }
  std::vector<std::uint32_t> out;
  for (std::uint32_t j : candidates) {
    if (j == i) continue;
    glp_prob* lp = glp_create_prob();
    glp_set_obj_dir(lp, GLP_MAX);
    glp_add_cols(lp, d + 1);
    for (int c = 1; c <= d; ++c) glp_set_col_bnds(lp, c, GLP_FR, 0, 0);
    glp_set_col_bnds(lp, d + 1, GLP_UP, 0, 1);  // delta <= 1
    glp_set_obj_coef(lp, d + 1, 1);
    glp_add_rows(lp, static_cast<int>(n - 1));
    ia.assign(1, 0);
    ja.assign(1, 0);
    ar.assign(1, 0);
    int row = 0;
    for (std::size_t k = 0; k < n; ++k) {
      if (k == i) continue;
      ++row;
      const double* xk = &pts[k * d];
      for (int c = 0; c < d; ++c) {
        ia.push_back(row);
        ja.push_back(c + 1);
        ar.push_back(2 * (xk[c] - xi[c]));
      }
      if (k == j) {
        glp_set_row_bnds(lp, row, GLP_FX, rhs[k], rhs[k]);
      } else {
        ia.push_back(row);
        ja.push_back(d + 1);
        ar.push_back(1);
        glp_set_row_bnds(lp, row, GLP_UP, 0, rhs[k]);
      }
    }
    glp_load_matrix(lp, static_cast<int>(ia.size() - 1), ia.data(), ja.data(), ar.data());
    glp_smcp parm;
    glp_init_smcp(&parm);
    parm.msg_lev = GLP_MSG_OFF;
    parm.presolve = GLP_ON;
    const int rc = glp_simplex(lp, &parm);
    if (rc == 0 && glp_get_status(lp) == GLP_OPT && glp_get_obj_val(lp) > 1e-9 * rhs[j]) out.push_back(j);
    glp_delete_prob(lp);
  }
  return out;
}

}  // namespace spokemesh::testing
