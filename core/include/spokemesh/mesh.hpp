// Whole-mesh assembly with no communication between seeds.
//
// Every Delaunay simplex is emitted by exactly one seed, its owner: its smallest
// vertex index. Meshing a set of seeds emits exactly the simplices owned there; the
// union over any partition of the points is the whole mesh, each simplex once. A run
// takes the seeds in an index range [seed_begin, seed_end) (the CLI's --seeds) and in
// a range of sweep positions [sweep_begin, sweep_end) (the service's shards).
//
// mesh_seeds() sweeps the blocks of the point set's SpaceSplit (space_split.hpp):
// worker threads take blocks in order, each computes its block's seeds in order, and
// the finished blocks go to `sink` in that order, on the calling thread. The rows are
// therefore in sweep order: seeds by their SpaceSplit position, each seed's owned
// simplices lexicographic. That order is a function of the point set alone (not of
// the thread count or the block size), so the bytes of every output are too, and P
// processes can compute it together without holding the whole set (the MPI job,
// docs/distributed.md); sort the rows for lexicographic order.
//
// Memory is the point set, the tree, a bounded window of blocks in flight and the
// front (front_cache.hpp: the wraps recorded for blocks still to come; in 2-d the
// EdgeCache, 64 bytes per point), never the mesh. The stars share their wraps through
// it; each star, and so the output, is the same without it.
//
// Thread safety: mesh_seeds() is safe to call concurrently on the same tree.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <new>
#include <span>
#include <type_traits>
#include <utility>
#include <vector>

#include "spokemesh/certify.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// How a whole mesh is computed (the rows are the same either way).
enum class MeshEngine {
  kAuto,            // local triangulations where they apply (2-d and 3-d, unweighted, not periodic) and
                    // ties do not dominate (engine_for), else stars
  kStars,           // every seed's star by the star walk, sharing wraps through the front
  kTriangulations,  // local triangulations with certified stars (an error where they do not apply)
};

// The triangulation of every point of a 2-d or 3-d set, which a run by local
// triangulations builds when the set's Delaunay balls reach across it (closed
// surfaces: a sphere, a torus), as a caller may keep it for later runs on the same
// set (MeshOptions::whole and keep_whole): those runs read their stars from it and
// build nothing. Opaque.
// Ownership: borrows the PointSet it was built on, which must outlive it.
// Thread safety: immutable once handed out; concurrent runs may share it.
class WholeTriangulation {
 public:
  virtual ~WholeTriangulation() = default;
  virtual std::size_t bytes() const = 0;  // what it holds (its cells, points and indexes)
  virtual int dimension() const = 0;
  virtual const PointSet& point_set() const = 0;  // the points it was built on (borrowed)
};

// How triangulate_whole builds one on its own.
struct WholeOptions {
  // Asked before it grows past what it was granted so far (16 MiB or more at a time),
  // as MeshOptions::reserve_bytes; false refuses (RESOURCE_EXHAUSTED). Unset: no limit.
  std::function<bool(std::size_t bytes)> reserve_bytes;
  const std::atomic<bool>* cancel = nullptr;
  // Index the finite cells by owner (a seed's rows without a search around it; 4 bytes
  // a cell more).
  bool owner_index = true;
  // The points' sweep (its order makes the insertion order's rounds spatially
  // coherent; borrowed, over the same points); null: one is built for the call.
  const SpaceSplit* split = nullptr;
};

// The triangulation of every point of a 2-d or 3-d set (unweighted, not periodic), as
// a run by local triangulations builds it when balls reach across the set, for callers
// that read many stars of one set from it (cells, the service's per-seed answers,
// insertion). One thread, the points in biased randomized order over the sweep's
// positions: about 1 to 3 us a point in 3-d uniform and 25 on a torus's surface, 40
// bytes a cell (6.8 cells a point uniform in 3-d, 2 in 2-d), 4 more with the owner index.
// Every cell is one of the set's Delaunay triangulation (the triangulation of all the
// points is unique under the symbolic perturbation): nothing is certified. Errors:
// INVALID_ARGUMENT outside 2-d and 3-d; CANCELLED; RESOURCE_EXHAUSTED when
// reserve_bytes refuses.
Result<std::shared_ptr<const WholeTriangulation>> triangulate_whole(const PointSet& points,
                                                                    const WholeOptions& options = {});

// The triangulation of `points` from `base`'s, whose set is `points`' first points
// (the same coordinates, the same ids: a set with points appended): base's cells
// copied and the others inserted, in the sweep's order (options.split over `points`,
// or one built for the call). The same triangulation triangulate_whole(points) builds
// (it is unique), at the cost of a copy (a few tenths of a second for a 3-d million)
// and of the new points. base is only read, and may be shared meanwhile. Errors:
// INVALID_ARGUMENT when `points` does not begin with base's set (compared byte for
// byte); those of triangulate_whole.
Result<std::shared_ptr<const WholeTriangulation>> extend_whole(const WholeTriangulation& base, const PointSet& points,
                                                               const WholeOptions& options = {});

// Reads stars out of a WholeTriangulation: for kAll and kOwned the Star that
// StarWalker::compute gives, simplex for simplex (kWhole: the owned suffix the same,
// the others in another order).
// Ownership: borrows the triangulation, which must outlive it.
// Thread safety: NOT thread-safe (scratch); readers of one triangulation may run
// concurrently, one per thread.
class WholeStarReader final : public StarSource {
 public:
  explicit WholeStarReader(const WholeTriangulation& whole);
  ~WholeStarReader() override;
  WholeStarReader(const WholeStarReader&) = delete;
  WholeStarReader& operator=(const WholeStarReader&) = delete;
  // Errors: OUT_OF_RANGE for a seed >= n.
  Status star(std::uint32_t seed, Star& out, StarPart part);
  Status star(std::uint32_t seed, Star& out) override { return star(seed, out, StarPart::kAll); }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

struct MeshOptions {
  unsigned threads = 1;                  // worker threads (>= 1)
  std::uint32_t seed_begin = 0;          // seeds [seed_begin, seed_end) are meshed
  std::uint32_t seed_end = 0xFFFFFFFFu;  // clamped to n
  // ...and of those, only the seeds at sweep positions [sweep_begin, sweep_end)
  // (clamped to n): a contiguous part of the sweep, so the parts of consecutive ranges
  // concatenate to the whole run's output, byte for byte.
  std::uint32_t sweep_begin = 0;
  std::uint32_t sweep_end = 0xFFFFFFFFu;
  std::uint32_t block_size = 0;  // points per block at most; 0 = automatic (output is the same)
  // The sweep's order and blocks, over the tree's points (borrowed; it must outlive the
  // run); null: built by the run from the tree's points and block_size, 8 bytes per
  // point while the run lasts (and 32 to 72 more while it is built).
  const SpaceSplit* split = nullptr;
  // Cap on what the stars of this run share (the front's mailboxes; in 2-d the
  // EdgeCache): bytes, 0 to mesh without it. The output is the same either way.
  std::size_t facet_cache_bytes = std::size_t{1} << 30;
  StarOptions star;                       // star.cancel also stops the whole run
  MeshEngine engine = MeshEngine::kAuto;  // engine_for() below
  // Local triangulations: the points of a region triangulated at once (the split's
  // nodes of at most this many; 0 = the dimension's default). The output is the same
  // for any size; small regions exercise every certificate on small sets (tests).
  std::uint32_t region_points = 0;
  // Local triangulations: asked before the run's triangulations grow past what it was
  // granted so far, with the bytes wanted (16 MiB or more at a time; called from the
  // workers, one call at a time). False refuses them: the seeds of that region (or of
  // every region needing the triangulation of the whole set) are walked as stars
  // instead (the same rows, slower, in bounded memory). Unset: no limit.
  std::function<bool(std::size_t bytes)> reserve_bytes;
  // When set, every seed's whole star (all its simplices) is given to `accept`, on the
  // worker thread that computed it; a seed whose star it refuses emits nothing. A
  // process meshing its part of a larger set refuses the stars it cannot certify from
  // the points it holds, and computes them again with more (spokemesh-mpi). Called
  // concurrently from the workers.
  std::function<bool(const Star&)> accept;
  // The form of the stars `accept` sees: kWhole (the owned simplices canonical, a
  // suffix; the others as sorted vertex lists) or kAll (every simplex canonical, as
  // StarWalker::compute gives a star on its own).
  StarPart accept_part = StarPart::kWhole;
  // A run over the points this process holds of a larger set (spokemesh-mpi's ranks;
  // borrowed, frozen, its known_hull over this run's point indices; null, or one that
  // holds_all(): the points are the whole set). Every star must then also hold against
  // the points the process lacks: the local triangulations certify each cell's ball
  // and hull facet against it too (a ball a query finds empty of held points must
  // also be held), star walks each star (HeldRegion::certify). A seed whose star
  // cannot be certified so emits nothing (and is not offered to `accept`): `defer` is
  // given it with what would certify it, the balls and hull facets to fetch, or, when
  // the balls reach across most of the whole set (a closed surface: one process would
  // take the whole set), a reach of the whole box. Called concurrently from the workers.
  const HeldRegion* held = nullptr;
  std::function<void(std::uint32_t seed, StarCertificate certificate)> defer;
  // Only these seeds (ascending, no repeats; not owned, must outlive the run), among
  // those the ranges above admit; empty: every seed. A batch of seeds computes its
  // stars as a whole mesh restricted to them would (through `accept`).
  std::span<const std::uint32_t> seeds;
  // A triangulation of every point kept from an earlier run on the same PointSet object
  // (null: none). Ignored unless it was built on this run's points (same object).
  std::shared_ptr<const WholeTriangulation> whole;
  // When set, a run that builds the triangulation of every point hands it here once it
  // is complete (the caller may keep it, charged to its memory, for later runs).
  std::function<void(std::shared_ptr<const WholeTriangulation>)> keep_whole;
};

// What the local triangulations did (MeshEngine::kTriangulations).
struct TriangulationStats {
  std::uint64_t regions = 0;        // regions of the sweep triangulated
  std::uint64_t inserted = 0;       // points inserted, margins included
  std::uint64_t margin_rounds = 0;  // times a region's box E was grown
  std::uint64_t ball_queries = 0;   // balls and hull facets certified by a k-d tree query
  std::uint64_t walked_seeds = 0;   // seeds whose stars were walked instead (few wanted in a region)
  bool whole_set = false;           // one triangulation of every point served (part of) the run
  std::uint64_t exact_calls = 0;    // predicates the filters could not decide
  std::size_t peak_bytes = 0;       // the largest triangulation held, summed over workers
};

struct MeshStats {
  std::uint64_t seeds = 0;
  std::uint64_t deferred = 0;  // seeds handed to MeshOptions::defer (a run over held points)
  std::uint64_t simplices = 0;
  TriangulationStats triangulation;
  // The most the front's mailboxes held at once (d >= 3): grows with the surface
  // between the blocks done and those to come, O(n^((d-1)/d)), not with n.
  std::size_t front_peak_bytes = 0;
  // All the stars shared: the front's peak plus each worker's block table at its
  // largest (d >= 3); in 2-d the EdgeCache's resident peak (its boxes are kept in sweep
  // order and given back behind the sweep: the blocks in flight and the posts ahead).
  std::size_t facet_cache_bytes = 0;
  StarStats star;
};

// Receives a block of owned simplices ((d + 1) indices each, positively oriented as in
// Star, the owner first; in sweep order, see above) and the number of seeds finished
// so far. A non-OK status stops the run.
using SimplexSink = std::function<Status(std::span<const std::uint32_t> simplices, std::uint64_t seeds_done)>;

Result<MeshStats> mesh_seeds(const KdTree& tree, const MeshOptions& options, const SimplexSink& sink);

// The same without a k-d tree: a run by local triangulations queries the split's own
// hierarchy instead (about 60 bytes a point less than a KdTree; a tree is built only
// for seeds that fall back to star walks); a run by star walks builds the tree.
// options.split, when given, must be over `points`.
Result<MeshStats> mesh_seeds(const PointSet& points, const MeshOptions& options, const SimplexSink& sink);

// The engine mesh_seeds takes for these options over this split: kTriangulations or
// kStars (kAuto resolved: local triangulations for unweighted, non-periodic 2-d and 3-d
// sets, unless exact ties dominate them, as on grids, whose ties the star walk decides
// faster: measured by triangulating the sweep's first 4,096 points, a few ms). A
// caller that budgets memory sets the engine it got: local triangulations take what
// reserve_bytes grants, the star walk the facet cache.
MeshEngine engine_for(const PointSet& points, const SpaceSplit& split, const MeshOptions& options);

// The simplices owned by `seed` within its star (a suffix of star.simplices).
std::span<const std::uint32_t> owned_simplices(const Star& star);

// A vector of rows whose resize leaves the new elements uninitialised: for buffers
// sized and then written in full, in parallel (a 100 MB zero fill is one thread's
// page faults before the writers touch the same pages again).
template <class T>
struct UninitializedAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <class U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;  // default-, not value-initialised
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
using Rows = std::vector<std::uint32_t, UninitializedAllocator<std::uint32_t>>;

// Incremental insertion: the mesh of the tree's points [0, n) from the mesh of its
// first n_old points, computing only the new points' stars. Every new simplex has a
// new vertex, so those stars hold all of them, and their old vertices are the old
// points whose stars change: an old point none of whose Delaunay neighbours is new
// keeps its star (its simplices, all of old points, are Delaunay in the new set as in
// the old, and cover a neighbourhood of the point as its old star does), and so its
// owned rows. A changed old point's rows are its old ones less those a new point's
// circumsphere test removes (an old simplex is Delaunay in the new set unless a new
// point lies in its circumsphere, decided exactly), with the new ones it owns. The rows
// come out in the sweep order of `split` (the SpaceSplit of all n points), so `out` is
// byte for byte what mesh_seeds writes for the whole set. When more than a fifth of
// the points (3-d; an eighth otherwise) are new, the whole set is swept instead
// (mesh_seeds: its stars share their wraps), which is then faster; so it is in 2-d and
// 3-d when a probe of a few new stars, walked against a deadline, says walking them all
// would cost more than a quarter of that (surfaces, scans, contour lines).
//
// old_rows: mesh_seeds' output for the first n_old points (any sweep order: rows are
// regrouped by owner, and an owner's rows are consecutive and lexicographic in every
// sweep). options: threads, star options and the engine (kStars: the new stars walked
// and the rows filtered, always; kTriangulations: in 2-d and 3-d the whole set swept;
// kAuto: the probe decides; seed and sweep ranges, split, accept and the facet cache are
// not used). Errors: INVALID_ARGUMENT when n_old is not below n or
// the rows name a point >= n_old; CANCELLED.
struct InsertStats {
  std::uint64_t stars = 0;        // stars computed (the new points'; all n when swept whole)
  std::uint64_t rows_redone = 0;  // old points whose owned rows were brought up to date
  std::uint64_t rows_kept = 0;    // rows taken from old_rows
  bool whole = false;             // the whole set was swept (many new points, or walks dear)
};
Result<InsertStats> insert_points(const KdTree& tree, const SpaceSplit& split, std::uint32_t n_old,
                                  std::span<const std::uint32_t> old_rows, const MeshOptions& options, Rows& out);
// The same, with the split given when first needed (a caller may still be building it
// while the new points' stars are computed, which need only the tree).
Result<InsertStats> insert_points(const KdTree& tree, const std::function<const SpaceSplit&()>& split_when_needed,
                                  std::uint32_t n_old, std::span<const std::uint32_t> old_rows,
                                  const MeshOptions& options, Rows& out);

// About how many simplices the Delaunay triangulation of n well-spread points in
// dimension d has (the core's sizing estimate; hull effects and clustering move it):
// for progress reports, never for correctness.
std::uint64_t expected_simplices(int d, std::uint64_t n);

}  // namespace spokemesh
