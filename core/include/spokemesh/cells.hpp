// All Voronoi cells of a point set (or of a range of seeds), clipped to a domain,
// computed by worker threads and handed over in seed order (docs/cells.md).
//
// compute_cells() works in rounds of threads x block consecutive seeds: each worker
// computes one contiguous slice of the round (for cells built directly, of the round's
// seeds sorted into the k-d tree's leaf order: space order), then the calling thread
// hands the round's cells to `sink` in seed order. Memory is the tree plus one round's cells, never all cells.
// Each cell is the same whatever the threads or block size (a function of the point
// set and the domain), and so are the bytes of every output.
//
// Thread safety: safe to call concurrently on the same tree.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>

#include "spokemesh/domain.hpp"
#include "spokemesh/facet_cache.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/shape_domain.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

// Clipped Voronoi cells of one point set, one seed at a time, by either of two exact
// routes that give the same polytope:
//   * directly, for a box domain: the box clipped by the bisectors of the seed's
//     nearest points in order of distance until the next bisector lies beyond the
//     cell's farthest vertex (Voro++'s construction and the security radius of
//     geogram's clip_by_cell_SR), each keep/drop decided exactly (cell_polytope.hpp);
//   * from the seed's Delaunay star (StarWalker), clipped by the domain's walls.
// In general position both give the one clipped cell. At a tie (a vertex exactly on
// a bisector: grids, cospherical points) the 3-d direct route decides by the star's
// own symbolic perturbation, so it still builds the star's cell; the generic polytope
// (other dimensions) sends that seed to the star instead. Which route a
// seed takes depends only on the point set, the domain and the seed, so every cell
// is a function of them, whatever the threads, order or caller.
//
// The direct route is taken in 3-d (CellRoute::kAuto), where it is the faster; tests
// force either route in any dimension to check that they agree.
//
// Ownership: borrows the tree and the domain, which must outlive the builder.
// Thread safety: NOT thread-safe; one builder per thread (they share nothing).
enum class CellRoute { kAuto, kDirect, kStar };

class ClippedCellBuilder {
 public:
  // Errors from cell(): INVALID_ARGUMENT when the domain's dimension is not the
  // points' or the seed lies outside it (naming both); OUT_OF_RANGE; CANCELLED (from
  // star_options.cancel).
  ClippedCellBuilder(const KdTree& tree, const Domain& domain, StarOptions star_options = {},
                     CellRoute route = CellRoute::kAuto);
  ~ClippedCellBuilder();
  ClippedCellBuilder(const ClippedCellBuilder&) = delete;
  ClippedCellBuilder& operator=(const ClippedCellBuilder&) = delete;

  Result<VoronoiCell> cell(std::uint32_t seed);
  // The same into `out`, reusing its buffers (a loop over many seeds allocates little).
  Status cell(std::uint32_t seed, VoronoiCell& out);

  // Leave out vertex coordinates and facet vertex loops (measures and neighbours
  // only): cheaper where the caller drops them anyway. Off by default.
  void set_measures_only(bool measures_only) { measures_only_ = measures_only; }
  // Stars from a StarSource (the triangulation of every point, mesh.hpp's
  // WholeStarReader, or stars a distributed run certified; over the tree's points;
  // borrowed) instead of walked: the same stars, so the same cells.
  // With skip_doomed, where the direct route is taken, each seed's star is read first
  // and a seed the route would certainly give up on goes straight to it: one with at
  // least as many points as the route's last round lists within twice the distance of
  // its cell's farthest Voronoi vertex inside the box (the route can stop only at a
  // point beyond twice its cell's reach, which never falls below that vertex's
  // distance). Worth it where the route gives up on most seeds (surfaces): elsewhere it
  // costs every seed a star and a query. Unweighted, non-periodic points only; null:
  // star walks.
  void set_stars(StarSource* stars, bool skip_doomed = false) {
    stars_ = stars;
    skip_doomed_ = skip_doomed;
  }
  // Whether a builder for these points and this domain builds cells directly (then
  // seeds visited in space order run faster).
  static bool takes_direct_route(int dimension, const Domain& domain, CellRoute route);
  // Whether the direct route alone builds this seed's cell (no star is computed): for
  // a caller deciding how its seeds' stars should come.
  bool builds_directly(std::uint32_t seed);
  // Seeds that went the star's way (for benchmarks and tests).
  std::uint64_t star_fallbacks() const { return star_fallbacks_; }
  // 3-d seeds the specialised cell gave up on (a decision within its error bounds),
  // built by the generic polytope instead (for tests).
  std::uint64_t generic_fallbacks() const { return generic_fallbacks_; }

  // What the last cell() depended on, for a caller whose tree holds only part of a
  // point set (spokemesh-mpi, docs/distributed.md): the star the cell was built from
  // (nullptr when it was built directly), and the squared distance (nanoflann's, see
  // kDistanceMargin) from the seed within which the points decided the direct route,
  // its result or its giving up (0 when it was not tried; infinity when the answer
  // rested on there being no other points at all). A builder over a superset of the
  // points holding the same points within that distance, and the same star, builds
  // the same cell, bit for bit: candidates at equal distances are taken in index order,
  // and a round never splits a group of them.
  const Star* last_star() const { return last_from_star_ ? &star_ : nullptr; }
  double last_reach2() const { return last_reach2_; }

 private:
  StarWalker& walker();
  bool direct(std::uint32_t seed, VoronoiCell& out);
  // With stars_: reads the seed's star into star_ and says whether the direct route
  // would certainly give up on it (see set_stars).
  bool direct_gives_up(std::uint32_t seed);
  // kDone, or why not: a decision at a tie (or within the error bounds), or more
  // candidates than the direct route takes.
  enum class Clipped { kDone, kUndecided, kTooMany };
  template <class Polytope>
  Clipped clip_by_neighbours(std::uint32_t seed, Polytope& polytope);

  const KdTree& tree_;
  const Domain& domain_;
  StarOptions star_options_;
  bool direct_ok_ = false;
  std::unique_ptr<StarWalker> walker_;  // made on first need
  Star star_;
  struct Scratch;
  std::unique_ptr<Scratch> scratch_;
  std::uint64_t star_fallbacks_ = 0;
  std::uint64_t generic_fallbacks_ = 0;
  bool measures_only_ = false;
  StarSource* stars_ = nullptr;
  bool skip_doomed_ = false;
  bool last_from_star_ = false;
  double last_reach2_ = 0;
};

struct CellsOptions {
  unsigned threads = 1;                  // worker threads (>= 1)
  std::uint32_t seed_begin = 0;          // cells of seeds [seed_begin, seed_end)
  std::uint32_t seed_end = 0xFFFFFFFFu;  // clamped to n
  // Seeds per worker and round; 0 = automatic: 8192 where cells are built directly
  // (3-d boxes), whose rounds are visited in space order and gain locality with size
  // (1M points, 2 threads: 1/61 of the set per round), else 2048, in seed order (the
  // stars' shared cache is tuned to it; space order made 2-d 15% slower).
  std::uint32_t block_size = 0;
  // Drop each cell's vertex coordinates and facet vertex lists before the sink sees
  // them (measures only: what `spokemesh cells ... -o x.npz` writes).
  bool measures_only = false;
  // Cap (bytes) on the cache through which the run's stars share their wraps, as in
  // MeshOptions; 0 for none. The cells are the same either way.
  std::size_t facet_cache_bytes = std::size_t{1} << 28;
  StarOptions star;  // star.cancel also stops the run
  // Stars (where a cell needs its seed's) from the triangulation of every point, read
  // concurrently by the workers, instead of a star walk per seed: the same stars, so
  // the same cells (2-d and 3-d, unweighted, not periodic). kAuto takes it where many
  // seeds need stars (every seed where cells come from stars; where they are built
  // directly, when the direct route gives up on an eighth of a sample of seeds:
  // surfaces, scans) unless exact ties dominate (grids: the walks decide them faster);
  // kStars always walks; kTriangulations takes it wherever it applies.
  MeshEngine stars = MeshEngine::kAuto;
  // A triangulation of every point kept from an earlier run on the same PointSet object
  // (null: none; ignored when over other points): read, nothing built.
  std::shared_ptr<const WholeTriangulation> whole;
  // Given the triangulation this run built (a caller may keep it for later runs).
  std::function<void(std::shared_ptr<const WholeTriangulation>)> keep_whole;
  // Asked before the triangulation grows past what it was granted, as
  // MeshOptions::reserve_bytes; refused: star walks (the same cells). Unset: no limit.
  std::function<bool(std::size_t bytes)> reserve_bytes;
  // A domain of any shape (shape_domain.hpp): each cell is first clipped to `domain`,
  // which must then be ShapeClipper::box(points, *shape), and intersected with the
  // shape (with ShapeClipper's geometry unless measures_only). Unweighted points only.
  // nullptr: none.
  const ShapeDomain* shape = nullptr;
};

// How a run's cells should get their stars (CellsOptions::stars), from a sample of its
// seeds: the triangulation of every point where the stars are needed by every seed
// (cells from stars) or by enough of them that walking those would take longer than
// triangulating every point (the direct route gives up on them; the sample's walks are
// timed), and then whether to read each seed's star before the direct route
// (ClippedCellBuilder::set_stars' skip_doomed: where the route gives up on most seeds).
// `seeds`: how many the run computes. Decides speed only: the cells are the same.
struct CellStarPlan {
  bool triangulate = false;
  bool skip_doomed = false;
};
CellStarPlan plan_cell_stars(const KdTree& tree, const Domain* domain, const CellsOptions& options,
                             std::span<const std::uint32_t> sample, std::uint64_t seeds);

// Receives the cells of consecutive seeds and the number of seeds done so far; a
// non-OK status stops the run and is returned.
using CellSink = std::function<Status(std::span<const VoronoiCell> cells, std::uint64_t seeds_done)>;

// One seed's cell in a domain of any shape, as compute_cells builds it: the convex cell
// clipped to `box` (ShapeClipper::box of the points and the shape; computed once by the
// caller, it scans every point), then intersected with the shape, with drawing geometry
// (ShapeClipper::set_geometry). Unweighted points. Errors: the builder's (CANCELLED
// from star.cancel, OUT_OF_RANGE).
// `stars`: where the convex cell's star comes from when it needs one (see
// ClippedCellBuilder::set_stars); null: walked.
Status shape_cell(const KdTree& tree, const ShapeDomain& shape, const Domain& box, std::uint32_t seed, VoronoiCell& out,
                  StarOptions star = {}, StarSource* stars = nullptr, bool skip_doomed = false);

// `domain`: nullptr for unclipped cells. Errors: the first seed outside the domain
// (INVALID_ARGUMENT, naming it), CANCELLED, or the sink's status.
Status compute_cells(const KdTree& tree, const Domain* domain, const CellsOptions& options, const CellSink& sink);

}  // namespace spokemesh
