// What a rank of spokemesh-mpi holds beyond its own points (docs/distributed.md,
// "Stars, halos and certification"): the boxes it has fetched around its nodes, the
// others' points it received, and the requests it answers; and the held points as one
// PointSet in global index order.
//
// Thread safety: Halo is used from the main thread only (its exchanges are
// collective); gather_local is reentrant.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "comm.hpp"
#include "split.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/point_set.hpp"

namespace spokemesh::mpi {

// The rank's points (owned, then the others' fetched so far) and what it has asked for.
class Halo {
 public:
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;

  // The halo of this rank's pieces of `split` (borrowed) within the whole set's box
  // (d lows, d highs): at first each piece's box grown by `first_halo_factor` mean
  // spacings of its points (a star's balls reach about twice the spacing; 0 starts
  // from none, for tests of the rounds).
  Halo(Comm& comm, const TopSplit& split, std::vector<double> global_box, double first_halo_factor);

  std::span<const double> held_box(std::size_t piece) const { return held_[piece]; }
  // Boxes covering every point of the set that piece's seeds do not see: the other
  // ranks' nodes less the piece's held box.
  std::vector<double> unheld(std::size_t piece) const;
  // The held boxes of the given pieces, as requests for fetch().
  std::vector<double> requests_of(const std::vector<std::size_t>& pieces) const;

  // Exchanges this round's requests (collective): boxes (2 d doubles each), every point
  // inside wanted; hull facets (d points, the inner apex, then a box: (d + 3) d doubles
  // each), every point inside the box beyond or on the facet's plane wanted; and balls
  // (centre, radius: d + 1 doubles), every point within wanted. Every rank answers each
  // other rank's requests with the points of its own that it has not sent that rank
  // before, found in `held_tree` (the round's tree of the held points; own_of_held maps
  // its indices to the rank's own points, kNone for the others') or, without one, in a
  // tree of its own points built for this exchange.
  void fetch(const std::vector<double>& boxes, const std::vector<double>& facets, const std::vector<double>& balls,
             const KdTree* held_tree = nullptr, const std::vector<std::uint32_t>* own_of_held = nullptr);

  const Points& ghosts() const { return ghosts_; }

 private:
  std::vector<double> grown(std::size_t p) const;
  bool contains(const double* q, const double* x) const;

  Comm& comm_;
  const TopSplit& split_;
  int d_;
  std::vector<double> global_;
  std::vector<std::vector<double>> held_;
  std::vector<double> depth_;
  Points ghosts_;
  std::vector<std::vector<char>> sent_;  // per rank: which owned points it has had
};

// The held points as one PointSet in global index order (so that every comparison of
// indices, and so every row, is as on one process).
struct LocalSet {
  PointSet points;
  std::vector<std::uint64_t> global;        // local index -> global index
  std::vector<std::uint32_t> local_of_own;  // owned k -> local index
  std::vector<std::int32_t> piece_of;       // local index -> owned piece, -1 for ghosts
};

// The rank's own points and the ghosts fetched so far, as one LocalSet.
LocalSet gather_local(const TopSplit& split, const Points& ghosts);

}  // namespace spokemesh::mpi
