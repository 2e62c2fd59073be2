// Approximate Delaunay neighbours in any dimension: Recursive Spoke Darts with a miss
// budget (Ebeida & Rushdi, IMR 2016, Sec. 4.4), and plain Spoke Darts for comparison.
//
// RSD mode: recursive spokes find a first Voronoi vertex of cell(x) (a spoke from x
// trimmed by the nearest bisector, then a spoke inside that Voronoi facet, ... d
// levels); then the walk goes from vertex to vertex along Voronoi edges, each leg
// heading for one nearby point not yet found by the simplex method, or, when that
// point's facet is far, replaced by one spoke aimed at the facet (docs/algorithm.md,
// section 7). A vertex whose equidistant points add no new neighbour is a miss, and so
// is a target refuted without a leg; the walk stops after `max_misses` consecutive
// misses (or `max_vertices`, or cancellation).
// Spokes mode: random rays from x only, each finding one Voronoi facet (one
// neighbour); a ray that finds no new neighbour is a miss.
//
// The walk itself is floating point: it only proposes neighbours. Every neighbour
// reported is certified: a witness point W on the bisector of x and s (a point inside
// the Voronoi facet, constructed exactly in rationals) with every other point strictly
// farther from W than x and s are, decided by a filtered exact predicate (the BoundedDouble
// bound of predicates.hpp, then GMP). Strict inequalities survive any infinitesimal
// perturbation, so each reported edge is a Delaunay edge of the point set, whatever
// the degeneracies: precision is 1 by construction, only recall is approximate.
//
// Ownership: borrows the KdTree (and its PointSet). Thread safety: NOT thread-safe;
// use one walker per thread; walkers on one tree are independent and deterministic
// (every random direction is drawn from the seed index and the options).
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <string_view>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// The walk's budget unless a request names one: every route (CLI, service, Python)
// takes its defaults from these.
inline constexpr std::uint32_t kDefaultMaxMisses = 100;
inline constexpr std::uint32_t kDefaultMaxVertices = 20000;

struct ApproxOptions {
  enum class Mode { kRsd, kSpokes };
  Mode mode = Mode::kRsd;
  std::uint32_t max_misses = kDefaultMaxMisses;      // consecutive misses before stopping (the paper's M)
  std::uint32_t max_vertices = kDefaultMaxVertices;  // Voronoi vertices (RSD) or rays (spokes), at most
  std::uint64_t random_seed = 0x5eed;                // mixed with the seed index into every direction
  const std::atomic<bool>* cancel = nullptr;         // checked between rays
};

// How a seed's neighbours are found, one vocabulary for every route (the CLI's --mode
// with --approx, Python's mode=, REST's mode=, gRPC's NeighborMode): the exact star;
// the paper's certified approximate walk (Recursive Spoke Darts); or plain spokes.
enum class NeighborMode { kExact, kApproximate, kSpokes };

// Parses a neighbour mode: "exact", "approximate" (or "rsd", its walk's name),
// "spokes". INVALID_ARGUMENT naming `field` and the accepted names otherwise.
Result<NeighborMode> parse_neighbor_mode(std::string_view text, std::string_view field);
// The mode's name as the service answers it: "exact", "approximate" or "spokes".
const char* neighbor_mode_name(NeighborMode mode);
// The walk an approximate mode runs (kApproximate: RSD). Precondition: not kExact.
ApproxOptions::Mode approx_walk(NeighborMode mode);

struct ApproxNeighbors {
  std::uint32_t seed = 0;
  std::vector<std::uint32_t> neighbors;  // certified Delaunay neighbours, ascending
  std::uint64_t vertices = 0;            // Voronoi vertices visited (RSD) or rays shot (spokes)
  std::uint64_t rays = 0;                // rays shot in all (walk, spokes and witnesses)
  std::uint64_t misses = 0;              // consecutive misses when the walk stopped
  std::uint64_t uncertified = 0;         // proposed neighbours whose witness failed (retried later)
  // RSD: the walk had nothing left to try and gave nothing up: every point was
  // certified or refuted, so `neighbors` is the complete (exact) set. False whenever
  // the miss or vertex budget stopped the walk, or a target was abandoned.
  bool exhausted = false;
};

class ApproxWalker {
 public:
  ApproxWalker(const KdTree& tree, ApproxOptions options);

  // Errors: OUT_OF_RANGE for a seed >= n; CANCELLED when options.cancel is set.
  Status compute(std::uint32_t seed, ApproxNeighbors& out);

 private:
  struct Ray;
  // Lists the k points nearest to x (k + 1 with x itself; all of them if fewer).
  void load_candidates(std::size_t k);
  // First point (not x, not excluded) that becomes equidistant with x along
  // y + t e, t > 0 (relative coordinates: y, e relative to x), if any.
  // head_only: among the nearest few candidates only (a guess, no tree query).
  std::optional<std::uint32_t> shoot(const double* y, const double* e, const std::uint32_t* exclude, int excluded,
                                     double& t, bool head_only = false);
  // Is w' (relative to x) a witness for the edge (x, s)? Projects it exactly onto the
  // bisector and checks every point with the filtered exact predicate.
  bool certify(std::uint32_t s, const double* w);
  // The RSD walk of one seed: its state and named steps (approx.cpp).
  class RsdWalk;
  Status compute_rsd(ApproxNeighbors& out);
  Status compute_spokes(ApproxNeighbors& out);
  bool stop_requested() const { return options_.cancel != nullptr && options_.cancel->load(std::memory_order_relaxed); }

  const KdTree& tree_;
  const PointSet& ps_;
  ApproxOptions options_;
  int d_;
  std::uint32_t x_ = 0;
  std::uint64_t rng_ = 0;
  std::uint64_t rays_ = 0;
  // Candidates nearest first: ids, coordinates relative to x, |p - x|^2.
  std::vector<std::uint32_t> cand_id_;
  std::vector<double> cand_q_;
  std::vector<double> cand_norm2_;
  double cand_radius2_ = 0;  // every unlisted point has |p - x|^2 at least this (up to rounding)
  std::vector<double> scratch_;
  std::vector<std::pair<std::uint32_t, double>> near_;  // a ray's ball query
};

}  // namespace spokemesh
