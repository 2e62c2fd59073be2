// Stars and Voronoi cells on the flat torus: one seed's star (with its cell when asked),
// a server's kept cover answering seed after seed, and every point's cell. The cover
// and its margins are periodic.hpp's; the answers are the same whatever margin a run
// began with.
//
// Thread safety: periodic_star() and compute_periodic_cells() may run concurrently
// with other calls; PeriodicStars as stated on it.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/cells.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

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
                                   const StarOptions& options, const std::string& source, VoronoiCell* cell = nullptr);

// The seed's Delaunay neighbours on the torus: the images in its star other than the
// seed itself, each once, ascending by point then offset (lexicographically); d
// offsets per neighbour. A point can be a neighbour through several images.
void periodic_neighbors(const PeriodicStar& star, int d, std::vector<std::uint32_t>& points,
                        std::vector<std::int32_t>& offsets);

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
