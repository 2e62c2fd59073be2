// Delaunay triangulations of the flat torus: a point set in a PeriodicBox
// whose opposite sides are identified, meshed as the Delaunay triangulation of all its
// images p + k (HI - LO), each simplex once up to a lattice translation.
//
// How: the walker meshes a cover, the points followed by their images that lie within
// a margin outside the box (PeriodicCover), stored as points of their own with ids from
// n on. Every predicate decides an image id as the exact image (Predicates' ImageMap),
// and the walker computes its coordinates relative to a seed rounded once
// (image_difference), so the cover's rounded coordinates only steer the k-d tree, whose
// boxes around images are widened by their rounding. Only the points 0..n-1 are seeds.
//
//  * Complete, for any margin: the representative of a periodic simplex whose
//    smallest-indexed point is that point itself (offset 0) has an empty sphere among
//    all images, so among the cover's, so it is in the cover's Delaunay star of that
//    point, which emits it.
//  * Sound, checked: a simplex is written only when its circumsphere lies inside the
//    cover's region (the box grown by the margin), which holds every image near it, so
//    emptiness in the cover is emptiness on the torus. A star with a sphere outside the
//    region (or an unbounded cell) makes the run record the margin it needed; the run is
//    then repeated with that margin, the caller told to start its output again. The
//    first margin, 3.5 mean spacings, suffices for well-spread points.
//  * Weighted points (power weights, CGAL's convention) give the regular triangulation
//    of the torus and its power cells the same way: the images carry their points'
//    weights, and a power sphere (centre c, squared radius R^2) can be entered only by
//    points within sqrt(R^2 + max w) of c, which is what the margin must hold.
//  * Degeneracies (periodic grids) fall to the same symbolic perturbation, ordered by
//    the images' exact coordinates (CGAL's Perturbation_order), which is invariant
//    under lattice translations, so the stars of different points agree.
//
// A simplex is written as its d + 1 point indices with the owner (its smallest point
// index) first at offset 0, positively oriented, and the other vertices' offsets: vertex
// v of simplex s stands at points[s_v] + offset_v (HI - LO). Sets whose torus
// triangulation is not a simplicial complex (too few points: some simplex holds two
// images of one point) are meshed all the same; every simplex is still written once.
//
// The cover is periodic_cover.hpp (the walker reads it); periodic stars and cells are
// periodic_cells.hpp.
//
// Thread safety: mesh_periodic() may run concurrently with other calls.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/mesh.hpp"
#include "spokemesh/periodic_box.hpp"
#include "spokemesh/periodic_cover.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

struct PeriodicMeshStats {
  MeshStats mesh;              // of the last run (its simplices: the torus's)
  std::uint64_t images = 0;    // images in the last run's cover
  std::vector<double> margin;  // its margin per axis
  int runs = 0;                // 1, or more when a margin proved too thin
};

// Receives a block of simplices of the torus: (d + 1) point indices each, and (d + 1) d
// offsets each (vertex by vertex), with the number of seeds finished so far.
using PeriodicSink = std::function<Status(std::span<const std::uint32_t> simplices,
                                          std::span<const std::int32_t> offsets, std::uint64_t seeds_done)>;

// The Delaunay triangulation of the torus `box` over `points` (validated, inside the
// box: PeriodicBox::check_contains), each simplex once, in the cover's sweep order (a
// function of the points and the box). options: threads, random seed, cancel, facet
// cache, and a seed range [seed_begin, seed_end) of the points (the simplices those
// seeds own: consecutive ranges together are the whole torus, each simplex once);
// sweep ranges, split and accept are the run's own. When a run proves
// its margin too thin, `restart` is called before the run is repeated: everything
// given to `sink` so far is void. With options.star.weights (one per point), the regular
// triangulation of the torus (its power spheres are what the margin must hold).
// Errors: INVALID_ARGUMENT as PeriodicCover::build, or when even a margin of three box
// lengths is too thin (fewer points than the torus needs); CANCELLED; the sink's.
Result<PeriodicMeshStats> mesh_periodic(const PointSet& points, const PeriodicBox& box, const MeshOptions& options,
                                        const PeriodicSink& sink, const std::function<Status()>& restart,
                                        const std::string& source);

// Rows of a periodic triangulation (d + 1 point indices and (d + 1) d offsets each,
// positively oriented) in a form that depends on the torus alone, not on the cover
// they were found in: the vertices of each row ascending by (point, offset
// lexicographically), except that the last two are swapped where that order would be
// negative (the row's orientation is kept: a permutation's parity is tracked, no
// predicate is evaluated); with sort_rows, the rows then in lexicographic order.
void canonicalize_periodic_rows(int d, std::vector<std::uint32_t>& simplices, std::vector<std::int32_t>& offsets,
                                bool sort_rows);

}  // namespace spokemesh
