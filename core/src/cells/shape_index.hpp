// Internals of ShapeDomain (shape_domain.hpp): its faces binned on a uniform grid, the
// winding number of every grid cell no face touches, and the exact predicates the
// domain and its clipper share.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "spokemesh/shape_domain.hpp"

namespace spokemesh {

// Exact signs (a double filter with Shewchuk's static bound, then GMP rationals).
// orient2d: sign of det[b - a, c - a] (+1: a, b, c counter-clockwise).
int orient2d_exact(const double* a, const double* b, const double* c);
// orient3d: sign of det[b - a, c - a, q - a] (+1: q on the side (b - a) x (c - a) points to).
int orient3d_exact(const double* a, const double* b, const double* c, const double* q);
// Sign of |x - p|^2 - |x - q|^2 (d coordinates): -1 when x is closer to p.
int distance_compare_exact(const double* x, const double* p, const double* q, int d);

struct ShapeDomain::Index {
  int d = 0;
  std::string source;
  std::vector<double> vertices;      // d per vertex
  std::vector<std::uint32_t> faces;  // d per face, oriented outward
  std::vector<double> normals;       // d per face: unit, outward
  std::vector<double> measures;      // per face: area (3-d) or length (2-d)
  std::vector<std::uint32_t> component_of_face;
  std::size_t components = 0;
  double volume = 0, boundary = 0;
  std::vector<double> lo, hi;  // bounding box of the vertices

  // The grid: cells per axis, cell size, origin (lo). Face lists per cell (CSR);
  // winding number of each cell no face touches (-1 where a face does).
  int cells[3] = {1, 1, 1};
  double size[3] = {1, 1, 1};
  std::vector<std::uint32_t> cell_start;  // cells + 1
  std::vector<std::uint32_t> cell_faces;
  std::vector<std::int8_t> cell_winding;

  std::size_t face_count() const { return measures.size(); }
  const double* vertex(std::uint32_t v) const { return vertices.data() + static_cast<std::size_t>(v) * d; }
  const std::uint32_t* face(std::size_t f) const { return faces.data() + f * static_cast<std::size_t>(d); }
  // The grid cell range [from, to] (inclusive, per axis) of a box, clamped to the grid.
  void cell_range(const double* box_lo, const double* box_hi, int* from, int* to) const;
  std::size_t cell_id(const int* at) const {
    return static_cast<std::size_t>(at[0]) +
           static_cast<std::size_t>(cells[0]) *
               (static_cast<std::size_t>(at[1]) + static_cast<std::size_t>(cells[1]) * static_cast<std::size_t>(at[2]));
  }
  // Builds the grid, the normals and measures (faces already oriented).
  void build();
  // The winding number at x by a ray along +x perturbed symbolically, or 2 when x lies
  // on the boundary. `stamp`/`epoch`: per-face marks so a face binned in several cells
  // is tested once (the caller's scratch; sized face_count()).
  int winding(const double* x, std::vector<std::uint32_t>& stamp, std::uint32_t& epoch) const;
};

}  // namespace spokemesh
