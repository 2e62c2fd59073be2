// ShapeDomain: a non-convex domain for Voronoi cells (docs/cells.md, "Domains of any
// shape"): a 2-d polygon with holes (rings) or a 3-d closed triangle mesh (possibly with
// cavities and several components). ShapeClipper intersects a seed's convex cell with
// it.
//
// Faces: the domain's boundary pieces, numbered as the input gives them. In 3-d a face
// is a triangle (file order; an n-gon of an .off/.obj file is a fan of n - 2 triangles,
// numbered in place). In 2-d a face is a ring's edge: ring r's edges follow ring r-1's,
// edge k of a ring runs from its vertex k to vertex k + 1 (the last back to vertex 0).
// A wall facet of a cell names its face as VoronoiFacet::neighbor = -1 - face.
//
// Orientation is fixed by nesting, whatever the file's: a component (3-d) or ring (2-d)
// inside an even number of others bounds solid on its inside (an outer boundary),
// inside an odd number it bounds a cavity or hole. Faces' normals then point out of
// the domain.
//
// Exactness: validation (degenerate faces, open or non-manifold edges, inconsistent
// orientation, intersecting faces or rings) and whether a point lies inside, outside or
// on the boundary are decided by exact predicates (a floating-point filter, then GMP
// rationals), with a ray perturbed symbolically (Simulation of Simplicity) so that rays
// through edges and vertices count right.
//
// Units: the coordinates'. Ownership: a value type (holds its vertices and an index).
// Thread safety: immutable after construction; share freely between threads.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "spokemesh/domain.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

// Most faces a shape domain may have (triangles or ring edges).
inline constexpr std::size_t kMaxShapeFaces = std::size_t{1} << 24;

class ShapeDomain {
 public:
  ShapeDomain();
  ~ShapeDomain();
  ShapeDomain(ShapeDomain&&) noexcept;
  ShapeDomain& operator=(ShapeDomain&&) noexcept;

  // A polygon with holes from its rings: each ring's vertices (x, y pairs) in order,
  // the closing vertex not repeated (a repeated one is dropped). `source` names the
  // input in messages ("part.txt"). Errors (INVALID_ARGUMENT, naming ring and vertex):
  // a ring of fewer than 3 vertices, a coordinate not finite, a zero-length edge, a
  // ring of zero area, rings or edges that cross or touch, no ring at all.
  static Result<ShapeDomain> polygon(std::vector<std::vector<double>> rings, const std::string& source);
  // A solid from a triangle mesh: vertices (x, y, z each), triangles (three vertex
  // indices each), `face_polygon` (optional, one per triangle) the input polygon each
  // triangle came from, for messages. Errors (INVALID_ARGUMENT, naming face, edge or
  // vertex): an index out of range, a degenerate triangle (two equal vertices or zero
  // area), an open boundary (an edge of one triangle only), a non-manifold edge (of
  // more than two), inconsistent orientation (an edge run the same way by both its
  // triangles), intersecting triangles, a coordinate not finite, no triangle.
  static Result<ShapeDomain> solid(std::vector<double> vertices, std::vector<std::uint32_t> triangles,
                                   const std::string& source);

  int dimension() const;
  std::size_t face_count() const;
  std::size_t vertex_count() const;
  // Vertex coordinates (d each) and faces (d vertex indices each, oriented outward).
  const std::vector<double>& vertices() const;
  const std::vector<std::uint32_t>& faces() const;
  // A face's (d-1)-measure and unit outward normal (d values).
  double face_measure(std::size_t face) const;
  const double* face_normal(std::size_t face) const;
  // Rings (2-d) or connected components (3-d), and how many.
  std::size_t component_count() const;
  // The domain's d-measure (area in 2-d) and its boundary's (d-1)-measure.
  double volume() const;
  double boundary_measure() const;
  // Bounding box of the vertices (d each).
  const std::vector<double>& lower() const;
  const std::vector<double>& upper() const;
  // "polygon of 4 rings (40 edges) from part.txt" / "solid of 960 triangles (2 components) from part.off".
  std::string describe() const;
  const std::string& source() const;
  // Bytes held (vertices, faces, normals, the grid), for callers that budget memory.
  std::size_t memory_bytes() const;

  // Where x lies: +1 strictly inside, 0 on the boundary, -1 strictly outside (exact).
  int locate(const double* x) const;

  struct Index;  // the faces binned on a grid (internal)
  const Index& index() const;

 private:
  std::unique_ptr<Index> index_;
};

// Intersects seeds' convex cells with a shape domain, one seed at a time.
//
// The convex cell comes from ClippedCellBuilder over `box()`: the domain's and the
// points' bounding box grown by 2^-10 of its extent on every side, so that no
// wall of the box touches the domain. Then, with o the seed, w(o) its winding number
// (1 inside, 0 outside) and, for each face t that meets the cell C, shadow(o, t) the
// part of the cone from o over t that lies beyond t:
//   (C ∩ D) = w(o) C  -  sum_t ±(C ∩ shadow(o, t))      (as signed indicator functions)
// because a segment from o to a point x of C stays in C, so only faces meeting C can
// cross it, and each crossing changes the winding number by one. Volumes, centroids
// and the neighbour facets' areas follow from the same sum (convex clips in double);
// wall facets are the faces clipped to C. A cell that meets no face costs one lookup.
// Seeds outside the domain get their Voronoi cell ∩ the domain as well: usually empty
// (volume 0, no facets), but not always (a seed just outside a wall).
//
// Measures: each term is a convex polytope clipped in double relative to the seed, so
// a measure is within a few ulps per term of the exact one, relative to the cell's
// size; with k faces meeting the cell, about (k + 1) * 1e-15 relatively.
//
// Output: VoronoiCell with clipped = true, bounded = true, volume and centroid (empty
// centroid when the volume is 0), facets: neighbours ascending (area of the bisector
// facet inside the domain, positive; or any facet of a cell that meets no face, zero
// areas kept as today), then walls ascending (neighbor = -1 - face, the area of the face
// inside the cell, its outward unit normal). No vertices (measures only) unless
// set_geometry(true).
//
// Ownership: borrows the tree and the domain. Thread safety: one clipper per thread.
class ShapeClipper {
 public:
  ShapeClipper(const PointSet& points, const ShapeDomain& shape);
  ~ShapeClipper();
  ShapeClipper(const ShapeClipper&) = delete;
  ShapeClipper& operator=(const ShapeClipper&) = delete;

  // The convex box every cell is first clipped to (see above).
  static Result<Domain> box(const PointSet& points, const ShapeDomain& shape);
  // The same from the points' bounding box (d values each), for a caller holding part
  // of the points (spokemesh-mpi: the whole set's box).
  static Result<Domain> box(std::vector<double> points_lo, std::vector<double> points_hi, const ShapeDomain& shape);
  // `convex`: the seed's cell clipped to box() (with vertices and facet loops); replaced
  // by its intersection with the shape.
  void clip(std::uint32_t seed, VoronoiCell& convex);

  // Cells that met at least one face (for benchmarks and tests).
  std::uint64_t cut_cells() const { return cut_cells_; }
  // With geometry (for drawing; off by default), a cell the domain cuts comes with
  // vertices: each wall facet's piece of its face (3-d: a loop, counter-clockwise from
  // outside; 2-d: its two ends) and each neighbour facet's outline inside the domain
  // as segments (vertex pairs), in double precision; a cell inside keeps its convex
  // geometry. Measures do not depend on it.
  void set_geometry(bool geometry) { geometry_ = geometry; }

 private:
  // clip()'s steps (shape_clip.cpp).
  struct FaceScan {
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};  // the cell's box
    bool any_face = false;  // a face's grid cell meets the cell's box
    int winding_hint = -2;  // the winding number every empty grid cell met agrees on (-3: they differ)
  };
  FaceScan scan_faces(const VoronoiCell& cell);
  int place_origin(std::uint32_t seed, const VoronoiCell& cell);
  void load_cell(std::uint32_t seed, const VoronoiCell& cell, int w);
  bool cut_by_face(std::uint32_t seed, const VoronoiCell& cell, std::uint32_t face);  // false: it misses the cell
  void assemble(VoronoiCell& cell, int w);
  std::vector<std::pair<std::array<double, 3>, std::array<double, 3>>> neighbour_outline(std::size_t facet, int w);
  struct Scratch;
  const PointSet& points_;
  const ShapeDomain& shape_;
  std::unique_ptr<Scratch> scratch_;
  std::uint64_t cut_cells_ = 0;
  bool geometry_ = false;
};

}  // namespace spokemesh
