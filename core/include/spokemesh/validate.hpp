// Independent validation of a Delaunay mesh of a point set.
//
// check_mesh() does not trust how the mesh was made. A mesh is accepted only if:
//   1. every simplex has d + 1 distinct in-range indices and non-zero volume;
//   2. every facet is shared by at most two simplices, which lie on opposite sides;
//   3. every interior facet is locally Delaunay under the exact predicates and the
//      symbolic perturbation (the apex of each neighbour lies outside the perturbed
//      circumsphere), which with 2 and 4 makes the mesh the Delaunay triangulation;
//   4. every boundary facet supports the point set (no point strictly beyond it),
//      every point is a vertex, and the simplex volumes sum exactly (rationals) to
//      the volume enclosed by the boundary facets, i.e. the convex hull's.
//
// Thread safety: reentrant.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/kd_tree.hpp"

namespace spokemesh {

struct MeshCheck {
  bool valid = false;
  std::size_t simplices = 0;
  std::size_t interior_facets = 0;
  std::size_t hull_facets = 0;
  std::vector<std::string> violations;  // the first few, human-readable
};

MeshCheck check_mesh(const KdTree& tree, std::span<const std::uint32_t> simplices, std::size_t max_violations = 10);

}  // namespace spokemesh
