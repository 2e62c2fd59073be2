// Delaunay triangulations of the flat torus (issue 28): a point set in a PeriodicBox
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
// Thread safety: a PeriodicCover is immutable after build(); mesh_periodic() may run
// concurrently with other calls.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/cells.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/periodic_box.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

class PeriodicCover {
 public:
  // The cover of `points` (validated, inside `box`, same dimension; both borrowed and
  // must outlive the cover) with the images whose coordinates lie within margin[c] of
  // the box on every axis c (absolute lengths, d of them). INVALID_ARGUMENT, naming
  // `source`, when the images cannot be told apart in double precision (points closer
  // than the rounding of the box's coordinates).
  // weights: the points' power weights (n of them) or empty; the images carry their
  // points' weights (weights()).
  static Result<std::unique_ptr<PeriodicCover>> build(const PointSet& points, const PeriodicBox& box,
                                                      std::span<const double> margin, const std::string& source,
                                                      std::span<const double> weights = {});

  const PointSet& points() const { return cover_; }  // the points, then the images
  const KdTree& tree() const { return *tree_; }
  const PeriodicBox& box() const { return box_; }
  std::uint32_t point_count() const { return n_; }  // ids below are points, the rest images
  std::size_t image_count() const { return image_point_.size(); }
  ImageMap images() const { return {n_, image_point_.data(), image_offset_.data()}; }
  // The point an id stands for, and its offset (d integers; zeros for a point).
  std::uint32_t point_of(std::uint32_t id) const { return id < n_ ? id : image_point_[id - n_]; }
  const std::int32_t* offset_of(std::uint32_t id) const;
  const std::vector<double>& margin() const { return margin_; }
  // How far an image's stored coordinates may lie from its exact position (per axis).
  double pad() const { return pad_; }
  // One power weight per cover point (the points', then each image's point's), or empty.
  std::span<const double> weights() const { return weights_; }
  // The largest weight (0 when unweighted).
  double max_weight() const { return max_weight_; }

 private:
  PeriodicCover(const PointSet& points, const PeriodicBox& box) : base_(points), box_(box) {}
  const PointSet& base_;
  const PeriodicBox& box_;
  std::uint32_t n_ = 0;
  std::vector<double> margin_;
  double pad_ = 0;
  PointSet cover_;
  std::vector<std::uint32_t> image_point_;
  std::vector<std::int32_t> image_offset_;  // d per image
  std::vector<std::int32_t> zeros_;
  std::vector<double> weights_;
  double max_weight_ = 0;
  std::unique_ptr<KdTree> tree_;
};

struct PeriodicMeshStats {
  MeshStats mesh;                 // of the last run (its simplices: the torus's)
  std::uint64_t images = 0;       // images in the last run's cover
  std::vector<double> margin;     // its margin per axis
  int runs = 0;                   // 1, or more when a margin proved too thin
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

// One seed's star on the torus: its Delaunay simplices among all images, the seed
// itself at offset 0 in each (d + 1 point indices and (d + 1) d offsets per simplex),
// in canonical form (canonicalize_periodic_rows); and its cell when asked (facets'
// neighbours as points, VoronoiCell::facet_offsets their images). The margin grows
// until every sphere of the star lies inside it, as for meshes. Errors: OUT_OF_RANGE
// for a seed >= n; the rest as mesh_periodic's.
struct PeriodicStar {
  std::uint32_t seed = 0;
  std::vector<std::uint32_t> simplices;
  std::vector<std::int32_t> offsets;
  std::vector<double> centres;  // d per simplex, the (power) circumcentres of the images: when asked
  bool hidden = false;          // with weights: the seed's power cell is empty (no simplices)
  std::size_t size(int d) const { return simplices.size() / static_cast<std::size_t>(d + 1); }
};
Result<PeriodicStar> periodic_star(const PointSet& points, const PeriodicBox& box, std::uint32_t seed,
                                   const StarOptions& options, const std::string& source,
                                   VoronoiCell* cell = nullptr);

// The seed's Delaunay neighbours on the torus: the images in its star other than the
// seed itself, each once, ascending by point then offset (lexicographically); d
// offsets per neighbour. A point can be a neighbour through several images.
void periodic_neighbors(const PeriodicStar& star, int d, std::vector<std::uint32_t>& points,
                        std::vector<std::int32_t>& offsets);

// Rows of a periodic triangulation (d + 1 point indices and (d + 1) d offsets each,
// positively oriented) in a form that depends on the torus alone, not on the cover
// they were found in: the vertices of each row ascending by (point, offset
// lexicographically), except that the last two are swapped where that order would be
// negative (the row's orientation is kept: a permutation's parity is tracked, no
// predicate is evaluated); with sort_rows, the rows then in lexicographic order.
void canonicalize_periodic_rows(int d, std::vector<std::uint32_t>& simplices, std::vector<std::int32_t>& offsets,
                                bool sort_rows);

// The stars and cells of one periodic set, seed by seed, on a cover kept between calls:
// what a server answering single seeds of a stored set needs (periodic_star builds a
// cover per call). A seed whose spheres reach beyond the kept cover's margin (near a
// void of a clustered set) gets wider covers for that call only, grown as
// periodic_star grows them, so an answer is periodic_star's, whatever was asked before.
//
// Ownership: borrows points, box and weights, which must outlive it.
// Thread safety: immutable after build(); star() may be called concurrently.
class PeriodicStars {
 public:
  // Errors as PeriodicCover::build's.
  static Result<std::unique_ptr<PeriodicStars>> build(const PointSet& points, const PeriodicBox& box,
                                                      std::span<const double> weights, std::string source);
  // options.weights and options.cover are the set's own (ignored if given). With
  // centres, PeriodicStar::centres is filled.
  Result<PeriodicStar> star(std::uint32_t seed, const StarOptions& options, VoronoiCell* cell = nullptr,
                            bool centres = false) const;
  const PeriodicCover& cover() const { return *cover_; }
  // Bytes of a kept cover of n points in d dimensions, about.
  static std::uint64_t estimated_bytes(std::uint64_t n, int d);

 private:
  PeriodicStars(const PointSet& points, const PeriodicBox& box, std::span<const double> weights, std::string source)
      : points_(points), box_(box), weights_(weights), source_(std::move(source)) {}
  const PointSet& points_;
  const PeriodicBox& box_;
  std::span<const double> weights_;
  std::string source_;
  std::shared_ptr<const PeriodicCover> cover_;
};

struct PeriodicCellsStats {
  std::uint64_t images = 0;    // images in the last run's cover
  std::vector<double> margin;  // its margin per axis
  int runs = 0;
};

// The Voronoi cells of the torus `box` over `points` (validated, inside the box), in
// seed order: each cell is the seed's cell among all images, a bounded polytope around
// the seed (its vertices may lie outside the box); a facet's neighbor is the
// neighbour's point and VoronoiCell::facet_offsets its image's offset. Their volumes
// sum to the box's. options: threads, block size, measures_only, the facet cache, star
// options (random seed, cancel); seed ranges are not taken (every point's cell). A cell
// is handed over only if every vertex's sphere lies inside the cover's margin; when one
// does not, the run measures the margin it needed and is repeated, `restart` called
// first. Errors as mesh_periodic's.
Result<PeriodicCellsStats> compute_periodic_cells(const PointSet& points, const PeriodicBox& box,
                                                  const CellsOptions& options, const CellSink& sink,
                                                  const std::function<Status()>& restart, const std::string& source);

}  // namespace spokemesh
