// StarWalker: the Delaunay star of one seed by Recursive Spoke Darts.
//
// Ebeida & Rushdi, "Recursive Spoke Darts", IMR 2016. The paper's operations read
// exactly as gift wrapping on the lifted points p -> (p, |p|^2), which is how they
// are decided here (see docs/algorithm.md):
//   * a spoke from the seed x in direction u, trimmed by the nearest bisector, is the
//     rotation of the hyperplane tangent to the paraboloid at x about a (d-1)-flat
//     until it meets a lifted point (Sec. 3.1, "spoke trimming");
//   * a spoke inside the Voronoi face found so far (Sec. 3.2, recursion) is the same
//     rotation about a flat that also contains the lifted points found so far;
//   * after d levels the hyperplane supports d + 1 lifted points: a Delaunay simplex,
//     i.e. a Voronoi vertex of cell(x);
//   * a ray along a Voronoi edge leaving that vertex away from s_k (Sec. 3.3, the
//     walk) is the rotation about the lifted facet opposite s_k; no hit means the
//     edge is unbounded, certified by KdTree::any_beyond.
// Each rotation ("wrap") picks the first lifted point hit with the exact predicates
// of predicates.hpp, so the star is exact and, through symbolic perturbation, a
// function of the point set; the random spoke directions only choose where the walk
// starts.
//
// Candidates come from the k-d tree sorted by distance and cached per seed. A sphere
// of radius r through x holds no point farther than 2r from x, so a wrap whose sphere
// lies within the certified candidate radius is decided by the candidates alone (the
// security radius of geogram's clip_by_cell_SR; the paper's alpha). A larger sphere,
// which only seeds near the hull meet, is certified by a k-d tree query for points
// below the lifted plane instead of by growing the neighbourhood, so a near-hull
// seed never drags in the whole point set.
//
// Ownership: borrows the KdTree (and its PointSet), which must outlive the walker.
// Thread safety: NOT thread-safe; use one StarWalker per thread. Different walkers
// on the same tree are independent and give identical answers.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/walk_memo.hpp"

namespace spokemesh {

class PeriodicCover;

struct StarOptions {
  // Mixed with the seed index into every random spoke direction.
  std::uint64_t random_seed = 0x5eed;
  // Candidates loaded first; 0 picks a default for the dimension.
  std::size_t initial_candidates = 0;
  // Checked between wraps; a set flag makes compute() return CANCELLED.
  const std::atomic<bool>* cancel = nullptr;
  // Checked between wraps too (when set): once it has passed, compute() returns
  // DEADLINE_EXCEEDED. For callers with another way to the same star that would rather
  // take it than wait (the sweep's walks of few seeds in a region: on a sphere's
  // surface one walk can take seconds where the region's triangulation takes ms).
  std::chrono::steady_clock::time_point deadline = std::chrono::steady_clock::time_point::max();
  // What other stars of the same run found (not owned; see FacetMemo, used for
  // d >= 3, and EdgeCache, for d = 2). Only saves work: every star is the same with or
  // without them.
  FacetMemo* facets = nullptr;
  EdgeCache* edges = nullptr;
  // Power weights, one per point of the tree (not owned; finite, |w| <= kMaxWeight,
  // as read_weights checks): the stars of the regular (weighted Delaunay)
  // triangulation, CGAL's Regular_triangulation convention (a weight is a squared
  // radius). Empty: the Delaunay stars. Equal weights give the Delaunay stars.
  std::span<const double> weights{};
  // A periodic set's cover (periodic.hpp; not owned), whose tree this walker's is: the
  // cover's image ids are decided as the exact images. Seeds must be points (ids below
  // cover->point_count()). With weights, `weights` holds one per cover point (the
  // cover's weights()).
  const PeriodicCover* cover = nullptr;
};

// Counters summed over a walker's lifetime (for benchmarks and tuning).
struct StarStats {
  std::uint64_t seeds = 0;
  std::uint64_t wraps = 0;
  std::uint64_t candidate_tests = 0;
  std::uint64_t exact_fallbacks = 0;
  std::uint64_t hull_queries = 0;      // k-d tree halfspace queries (unbounded Voronoi edges)
  std::uint64_t sphere_queries = 0;    // k-d tree queries certifying spheres beyond the candidates
  std::uint64_t cached_wraps = 0;      // wraps answered by the FacetCache
  std::uint64_t cached_starts = 0;     // stars begun at a FacetCache facet instead of by spokes
  std::uint64_t candidate_loads = 0;   // k-d tree neighbourhoods loaded (a star wholly cached needs none)
  std::uint64_t hidden = 0;            // with weights: seeds whose power cell is empty
  std::uint64_t start_programmes = 0;  // with weights: seeds outside their own power cells (power_start's programme)

  StarStats& operator+=(const StarStats& o) {
    seeds += o.seeds;
    wraps += o.wraps;
    candidate_tests += o.candidate_tests;
    exact_fallbacks += o.exact_fallbacks;
    hull_queries += o.hull_queries;
    sphere_queries += o.sphere_queries;
    cached_wraps += o.cached_wraps;
    cached_starts += o.cached_starts;
    candidate_loads += o.candidate_loads;
    hidden += o.hidden;
    start_programmes += o.start_programmes;
    return *this;
  }
};

// The Delaunay simplices incident to one seed.
struct Star {
  std::uint32_t seed = 0;
  int dimension = 0;
  // d + 1 vertex indices per simplex, positively oriented (det[s_1 - s_0, ...,
  // s_d - s_0] > 0, decided exactly): ascending within a simplex, except that the last
  // two are swapped where ascending order would be negative. Simplices in
  // lexicographic order of their sorted vertex lists; s_0 is always the smallest.
  std::vector<std::uint32_t> simplices;
  // Facets of the star that lie on the convex hull (unbounded Voronoi edges).
  std::size_t hull_facets = 0;
  // With weights: the seed's power cell is empty (its lifted point lies above the
  // lower hull of the others'), so it is a vertex of no simplex and the star is empty.
  bool hidden = false;

  std::size_t size() const { return simplices.size() / static_cast<std::size_t>(dimension + 1); }
  const std::uint32_t* simplex(std::size_t i) const {
    return simplices.data() + i * static_cast<std::size_t>(dimension + 1);
  }
  bool bounded_cell() const { return hull_facets == 0; }
};

// Which simplices of a star compute() returns: all, or only those the seed owns (its
// other vertices all have larger indices), which is all a whole mesh needs; or all
// of them with only the owned ones in canonical form (ordered, positively oriented, a
// suffix) and the others as sorted vertex lists in any order: what a whole mesh
// needs when each whole star is also certified (spokemesh-mpi), without the cost of
// ordering and orienting what is not written.
enum class StarPart { kAll, kOwned, kWhole };

// Where a caller's stars come from when it does not walk them: each seed's whole star
// (kAll), the Star StarWalker::compute gives. WholeStarReader (mesh.hpp) reads them out
// of the triangulation of every point; a distributed run hands on the stars it has just
// certified.
// Thread safety: as each implementation says (typically one per thread).
class StarSource {
 public:
  virtual ~StarSource() = default;
  virtual Status star(std::uint32_t seed, Star& out) = 0;
};

class StarWalker {
 public:
  explicit StarWalker(const KdTree& tree, StarOptions options = {});
  ~StarWalker();
  StarWalker(const StarWalker&) = delete;
  StarWalker& operator=(const StarWalker&) = delete;

  // Computes the star of `seed` into `out` (its buffers are reused); with kOwned,
  // out.simplices keeps only the owned simplices (hull_facets still counts the star's).
  // Errors: OUT_OF_RANGE for a seed >= n; CANCELLED when options.cancel is set;
  // DEADLINE_EXCEEDED past options.deadline.
  Status compute(std::uint32_t seed, Star& out, StarPart part = StarPart::kAll);
  // The deadline of the next computes (StarOptions::deadline).
  void set_deadline(std::chrono::steady_clock::time_point deadline) { options_.deadline = deadline; }
  // With weights: whether `seed` is hidden (its power cell is empty), decided as
  // compute() decides it (power_start) without walking the star. Without weights: false.
  Result<bool> hidden(std::uint32_t seed);

  // A hint for a caller that knows which seeds come next (no effect on any answer):
  // starts loading the seed's point, its EdgeCache posts and its memo start.
  void prefetch(std::uint32_t seed) const;

  const StarStats& stats() const { return stats_; }

 private:
  // A fixed-length tuple set (open addressing) that keeps its memory between seeds.
  class TupleSet {
   public:
    void reset(int length);
    bool insert(const std::uint32_t* sorted_key);                      // true if it was new
    bool insert(const std::uint32_t* sorted_key, std::uint64_t hash);  // hash: hash(sorted_key)
    // The key's position (0, 1, ... in order of first insertion), inserting it if new.
    std::uint32_t position(const std::uint32_t* sorted_key, std::uint64_t hash, bool& inserted);
    std::uint64_t hash(const std::uint32_t* key) const;
    void prefetch(std::uint64_t hash) const;  // the key's first slot (a hint only)

   private:
    void grow();
    int length_ = 0;
    std::size_t count_ = 0;
    std::vector<std::uint32_t> keys_;
    // A slot is in use when its top 16 bits equal generation_ (reset() only bumps
    // it: no clearing per seed); then bits 32-47 are a tag from the key's hash and
    // the low 32 bits its position + 1.
    std::vector<std::uint64_t> slots_;
    std::uint64_t generation_ = 1;
    static constexpr std::uint64_t kGenerationShift = 48;
    static constexpr std::uint64_t kTagMask = 0x0000FFFF00000000ull;
    static constexpr std::uint64_t kPositionMask = 0x00000000FFFFFFFFull;
  };

  void load_candidates(std::size_t k);
  // Loads the seed's first candidates unless done (a star answered wholly by the
  // FacetCache never needs them).
  void ensure_candidates();
  // The lifted plane through x and the d points `ids` (its orientation is arbitrary:
  // a wrap's reference only needs every point on one side of it).
  void simplex_plane(const std::uint32_t* ids, BoundedDouble* out);
  template <int D>
  void simplex_plane_kernel(const std::uint32_t* ids, BoundedDouble* out);
  // A point's row relative to x, in double: q = p - x rounded (p given by its index
  // and coordinates), |q|^2 from it, the lifted height (|q|^2, or with weights
  // |q|^2 - (w_p - w_x)), a bound on the height's monomials and its rounding depth
  // (or kUnsafe).
  struct Lift {
    double norm2, height, magnitude;
    int depth;
  };
  Lift relative_row(std::uint32_t id, const double* p, double* q) const;
  // q = p - x rounded once, p given by its index and stored coordinates: for an image
  // of a periodic cover, from its exact position (image_difference), not the stored one.
  void relative(std::uint32_t id, const double* p, double* q) const;
  // Coordinate c of point id exactly (an image's from its point and offset).
  mpq_class exact_coordinate(std::uint32_t id, int c) const;
  // The same as a BoundedDouble row (q, height), for cached candidates.
  void lifted_row(const double* q, const Lift& lift, BoundedDouble* out) const;
  // Which side of the pivot's spatial hyperplane a wrap turns to: away from a point
  // (the walk), or towards (or, reversed, away from) a spoke direction.
  struct Side {
    std::int64_t away_from = -1;
    const double* toward = nullptr;
    bool reverse = false;
  };
  // A wrap's answer: the point hit, or none on that side (the Voronoi edge or the
  // spoke is unbounded), or the run was cancelled.
  struct WrapResult {
    enum class Kind : std::uint8_t { kHit, kUnbounded, kCancelled };
    Kind kind = Kind::kUnbounded;
    std::uint32_t point = 0;  // when kHit

    static WrapResult hit(std::uint32_t p) { return {Kind::kHit, p}; }
    static WrapResult unbounded() { return {Kind::kUnbounded, 0}; }
    static WrapResult cancelled() { return {Kind::kCancelled, 0}; }
    bool is_hit() const { return kind == Kind::kHit; }
  };
  // Rotates the lifted hyperplane about pivot (d - 1 rows) towards `side` of the
  // pivot's spatial hyperplane, starting from `reference` (d + 1 coefficients of a
  // plane through the lifted pivot and x with every point on or above it); returns
  // the point hit and writes its plane, oriented the same way, to `hit_plane`.
  WrapResult wrap(const Row* pivot, Side side, const BoundedDouble* reference, BoundedDouble* hit_plane);
  template <int D>
  WrapResult wrap_kernel(const Row* pivot, Side side, const BoundedDouble* reference, BoundedDouble* hit_plane);
  // One wrap's state and named steps (star.cpp).
  template <int D>
  class WrapState;
  // The first simplex by recursive spokes (d ids, without x) and its plane; with
  // weights, sets `hidden` (and finds nothing) when x's power cell is empty.
  Status first_simplex(std::uint32_t* out, BoundedDouble* plane, bool& hidden);
  // Why a wrap stopped: DEADLINE_EXCEEDED past options_.deadline, else CANCELLED.
  Status stopped() const;
  // Whether options_.deadline is set and has passed (read between wraps).
  bool past_deadline() const {
    return options_.deadline != std::chrono::steady_clock::time_point::max() &&
           std::chrono::steady_clock::now() > options_.deadline;
  }
  // With weights (power_start.cpp): the plane h = slope . q that the spokes start
  // from, through lifted x with every other lifted point strictly above it (slope 0,
  // the tangent plane, when x lies in its own power cell), or `hidden`.
  // `started`: x's cell has no volume and exists only by the symbolic perturbation, so
  // no plane below the others passes through lifted x; one simplex of its star (d ids,
  // without x) is written to `start` instead.
  Status power_start(bool& hidden, std::uint32_t* start, bool& started);
  // The per-seed state compute() and hidden() start from.
  void begin_seed(std::uint32_t seed);
  // A simplex of x's (perturbed) star among d-subsets of `pool`, if any: written to
  // `start` (d ids, without x).
  bool star_simplex_among(const std::vector<std::uint32_t>& pool, std::uint32_t* start) const;
  // Whether no point lies inside the perturbed power sphere of `simplex` (d + 1 ids,
  // non-degenerate), exactly (a k-d tree query about its power centre).
  bool power_sphere_empty(std::span<const std::uint32_t> simplex) const;
  // Sign of height(p) - slope . (p - x), exactly.
  int sign_above_slope(std::uint32_t p, const double* slope) const;
  // Up to `most` points p != x with height(p) - slope . (p - x) <= 0 (on or below the
  // plane) into `out`; returns their number.
  std::size_t points_not_above(const double* slope, std::uint32_t* out, std::size_t most) const;
  // For the start: where x lies in the convex hull of `face` (points), the sign of the
  // lifted face's height above lifted x there (-1: x is hidden), exactly; 2 when x is
  // not in the face or the face is not a simplex.
  int face_side(std::span<const std::uint32_t> face) const;
  // The affine rank of the points, exactly.
  int affine_rank(std::span<const std::uint32_t> points) const;
  // Loads the candidates before a wrap, or a larger neighbourhood once sphere queries
  // keep finding points they lack.
  void prepare_wrap();
  // The star walk for d = 2: x's star as a ring of neighbours (ring_walk.cpp), with
  // its own state; it wraps through this walker.
  class RingWalk;
  // The walk for d >= 3: one star's steps over the per-seed arrays below (star.cpp).
  class StarWalk;
  std::unique_ptr<RingWalk> ring_walk_;  // set when d == 2
  // Writes the simplices in work_ (d ids each, without x) to `out` in canonical form.
  void emit_canonical(std::size_t hull, StarPart part, Star& out);
  // Orients simplices [first, size()).
  void orient_positively(Star& out, std::size_t first = 0) const;

  // The kernels compiled for this walker's dimension (chosen once, in the constructor).
  struct Kernels {
    WrapResult (StarWalker::*wrap)(const Row*, Side, const BoundedDouble*, BoundedDouble*) = nullptr;
    void (StarWalker::*simplex_plane)(const std::uint32_t*, BoundedDouble*) = nullptr;
  };
  Kernels kernels_;

  const KdTree& tree_;
  const PointSet& ps_;
  Predicates predicates_;
  StarOptions options_;
  StarStats stats_;
  int d_;
  // Weights (null when unweighted) and this seed's direction slope, as the exact
  // rows see them.
  PointExtras extras_;
  std::array<double, kMaxDimension> slope_{};
  double max_weight_ = 0;  // the largest weight
  // A periodic cover's images (ids from image_first_): their stored coordinates lie
  // within image_pad_ of their exact positions, per axis.
  std::uint32_t image_first_ = 0xFFFFFFFFu;
  double image_pad_ = 0;
  // An upper bound on max_p w_p - w_x for this seed (0 when unweighted): a point's
  // height is at least |q|^2 minus this, which is what the certificates' bounds use.
  double weight_excess_ = 0;
  // The exit estimate of a plane whose slope has squared length slope2: where points
  // are certainly above it, (|slope| + sqrt(weight_excess_))^2 (an estimate only).
  double exit_estimate(double slope2) const;

  // Per-seed state, kept across seeds to avoid allocation.
  std::uint32_t x_ = 0;
  std::vector<std::uint32_t> cand_id_;
  std::vector<double> cand_q_;           // p - x, rounded, row-major
  std::vector<double> cand_height_;      // lifted height (|p - x|^2, or with weights) as computed from cand_q_
  std::vector<double> cand_height_mag_;  // bound on its monomials (= cand_height_ when unweighted)
  std::vector<double> cand_block_;       // the pencil scan's column-major copy (see load_candidates)
  std::size_t cand_stride_ = 0;          // candidate count rounded up to whole pencil-scan chunks
  std::vector<double> cand_norm_;        // |p - x|, for error bounds
  std::vector<int> cand_depth_;          // rounding depth of cand_height_, or BoundedDouble::kUnsafe
  std::vector<double> cand_lower_;       // exact |p - x|^2 of this and later candidates >= this
  double r2_certified_ = 0;              // every unlisted point has exact |p - x|^2 >= this
  std::size_t cand_k_ = 0;               // candidates requested from the tree for this seed
  double knn_guess2_ = std::numeric_limits<double>::infinity();  // the last full load's k-th |p - x|^2
  bool loaded_ = false;                                          // the candidates are loaded for this seed
  std::size_t cache_credit_ = 0;                                 // FacetCache entries reserved and not yet used
  int missed_candidates_ = 0;                                    // sphere queries that found a point beyond them
  bool grown_ = false;                                           // the neighbourhood was enlarged for this seed
  std::vector<std::uint32_t> knn_ids_;
  std::vector<double> knn_d2_;
  std::vector<const double*> knn_coords_;
  std::vector<double> directions_;
  std::vector<BoundedDouble> minors_;
  TupleSet simplex_seen_, facet_seen_;
  struct Contender {
    std::uint32_t index;  // into the candidate arrays
    double lower;         // certified lower bound of its pencil parameter
  };
  std::vector<Contender> contenders_;       // a wrap's pencil-scan contenders
  std::vector<std::uint32_t> work_;         // star simplices found, d ids each (without x), ascending
  std::vector<std::uint32_t> work_facets_;  // per work_ simplex: facet_seen_ position of facet k (without id k)
  std::vector<std::uint8_t> facet_open_;    // per facet_seen_ position: one side known, not yet walked
  std::vector<std::uint32_t> facet_apex_;   // per facet_seen_ position: the apex of its first simplex
  std::vector<std::uint32_t> deferred_;     // facets (simplex * d + k) the cache could not answer, to wrap
  std::vector<BoundedDouble> work_planes_;  // their lifted planes, d + 1 coefficients each
  std::vector<std::uint8_t> plane_known_;   // per work_ simplex: work_planes_ is filled in
  std::vector<std::uint64_t> work_hashes_;  // per work_ simplex, with a facet cache: its d facets' hashes
  std::vector<std::uint32_t> sort_flat_, sort_order_;  // canonical ordering scratch
};

// Default first candidate count for dimension d.
std::size_t default_candidates(int d);

// Delaunay neighbours of the seed, ascending.
std::vector<std::uint32_t> star_neighbors(const Star& star);

}  // namespace spokemesh
