// The whole mesh in 2-d and 3-d by local Delaunay triangulations whose stars are
// certified (docs/algorithm.md, "Whole meshes in 2-d and 3-d").
//
// The sweep's positions are cut into regions of consecutive blocks (a few tens of
// thousands of points each). A worker triangulates a region's points and the points of
// a box E around them (Triangulation<D>, incremental, exact), and reads each seed's
// star there. A simplex of that triangulation is one of the whole set's when no point
// of the set lies inside its circumsphere: every point it holds is inserted, which
// holds when the part of its ball inside the set's bounding box lies in E (all of E's
// points are inserted), or when a k-d tree query finds no other point inside it. A
// hull facet likewise, with its outer half-space. A seed is emitted when every simplex
// and hull facet around it is certified; otherwise E grows (by the boxes of the balls
// that failed), or the failing balls are asked of the tree one by one, or, when the
// balls reach across most of the set (points on a closed surface, whose Delaunay
// balls span its inside), one triangulation of every point serves the rest of the run.
// No global emptiness query per simplex: certification costs a few bound computations
// per simplex, and the triangulation's own tests are local.
//
// The rows are those of the star walk's sweep, byte for byte: sweep order, each seed's
// owned simplices lexicographic, positively oriented (the triangulation's cells are,
// and sorting a cell's vertices flips the orientation with the permutation's parity).
//
// Thread safety: run() is safe to call concurrently on the same tree.
#pragma once

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh::detail {

// Whether mesh_seeds may take this route: d = 2 or 3, unweighted, not periodic.
bool triangulation_sweep_applies(const PointSet& points, const MeshOptions& options);
// Whether exact ties dominate the set (a grid), measured on the first few thousand
// points of the sweep: MeshEngine::kAuto then takes the star walk, which decides ties
// faster (the rows are the same).
bool ties_dominate(const PointSet& points, const SpaceSplit& split);

// The run of mesh_seeds over `split`'s positions [sweep_begin, sweep_end) and seeds
// [seed_begin, seed_end) (clamped as mesh_seeds clamps them), with the caller's k-d
// tree for its box queries, or (no tree) with the split's own index (SplitIndex; a
// k-d tree is then built only if some seeds fall back to star walks).
Result<MeshStats> triangulation_sweep(const KdTree& tree, const SpaceSplit& split, const MeshOptions& options,
                                      const SimplexSink& sink);
Result<MeshStats> triangulation_sweep(const PointSet& points, const SpaceSplit& split, const MeshOptions& options,
                                      const SimplexSink& sink);

}  // namespace spokemesh::detail
