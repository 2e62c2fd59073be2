// StarCertifier: whether a star computed from part of a point set is the star in the
// whole set (a process of spokemesh-mpi holds its own points and, around them, the
// others' points inside a box; docs/distributed.md, "Stars, halos and certification").
//
// Every point the process does not hold lies in one of a list of `unheld` boxes. A
// star computed from the held points is the whole set's star when each of its
// simplices' circumballs and each of its hull facets' outer half-spaces miss every
// unheld box: then no point of the whole set lies inside any of them, so every simplex
// of the star is Delaunay in the whole set (empty circumsphere, the same symbolic
// perturbation: it depends only on the lexicographic order of the points involved)
// and every hull facet is a hull facet of the whole set; a star is a complete
// neighbourhood of its seed, so a star made of such simplices is the whole star.
//
// Decided in floating point with rigorous error bounds, as a static filter (and for a
// nearly flat simplex, whose bounds cannot separate D from 0, with the centre solved in
// rationals): the circumcentre's offset from the seed is N / D (Cramer), each of N and D computed with
// its magnitude (the same sums of products over absolute values), whose error is at
// most gamma = 1e-14 (about 90 units in the last place; the longest chain of roundings,
// the inputs' subtraction included, is 11 for d = 3) times that magnitude; intervals
// for the centre, the radius and the distances follow, rounded outwards. The hull
// facets' sides are orientation determinants filtered the same way. A star the bounds
// cannot decide is refused, never accepted: the caller fetches more points (in the
// end all of them, when every star is certified trivially), so the answer is exact.
//
// Dimensions 2 and 3 (the MPI job's); other dimensions are never certified unless no
// box is unheld.
//
// Ownership: borrows the PointSet. Thread safety: certified() is const and safe to call
// concurrently.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh {

// What certification found: certified, or what it would take.
struct StarCertificate {
  bool certified = false;
  // A box (d lows, d highs) to hold before the star can be decided at all: certify()
  // leaves it empty (its balls say what to fetch); the distributed run sets it for a
  // seed whose held points do not yet span the space.
  std::vector<double> reach;
  // The failing circumballs, each as d centre coordinates and a radius (rounded
  // outwards): with every point inside them held, they are certified. A nearly flat
  // simplex, whose centre the filtered bounds cannot place, has its ball placed exactly.
  std::vector<double> balls;
  // Hull facets whose outer side could not be shown empty: d indices each (the seed's
  // included, ascending), then the facet's inner apex.
  std::vector<std::uint32_t> hull_facets;
};

// HeldRegion: what one process holds of a larger point set (a rank of spokemesh-mpi),
// for runs whose every answer must hold against the points it lacks
// (MeshOptions::held). Every point of the whole set lies in whole_box(); every point
// the process lacks lies in one of the unheld boxes (the other ranks' nodes), less
// what it fetched: the held boxes and balls, inside each of which it holds every
// point of the whole set. The unheld boxes are cut by the held boxes once, when the
// region is frozen, into residual boxes (closed: a point on a held box's face counts
// as possibly lacking), so that every test below is a pass over the residuals:
//   box_held    the box misses every residual;
//   ball_held   the ball misses every residual, or lies in a held ball;
//   beyond_held a hull facet's outer side (and its plane) misses every residual, or
//               the facet is known to be one of the whole set's hull (known_hull).
// Each is conservative (false when undecided). Dimensions 2 and 3; in any other
// nothing is held unless no box is unheld.
//
// Ownership: a value. Thread safety: build it on one thread, freeze() it, then its
// const calls are safe concurrently.
class HeldRegion {
 public:
  // whole_box: d lows, then d highs; whole_points: the whole set's size.
  HeldRegion(int d, std::vector<double> whole_box, std::uint64_t whole_points);

  // Every point of the whole set inside the closed box (2 d doubles) is held.
  void add_held_box(std::span<const double> box);
  // Every point within the closed ball (d centre coordinates, then the radius) is held.
  void add_held_ball(std::span<const double> ball);
  // Points not held may lie in this box (2 d doubles), at most `points` of them (a
  // count for estimates of work only).
  void add_unheld_box(std::span<const double> box, std::uint64_t points);
  // Hull facets (d ascending indices of the run's PointSet) known to be the whole set's.
  void set_known_hull(std::function<bool(std::span<const std::uint32_t>)> known) { known_hull_ = std::move(known); }
  // Cuts the unheld boxes by the held ones (call after the last add_*: the tests
  // below read the residuals).
  void freeze();

  int dimension() const { return d_; }
  const std::vector<double>& whole_box() const { return whole_; }
  std::uint64_t whole_points() const { return whole_points_; }
  // Whether the process holds every point (no residual).
  bool holds_all() const { return residual_.empty(); }
  bool box_held(const double* box) const { return residual_meeting(box) == nullptr; }
  // A residual box (2 d doubles) that the closed box meets, or null when it is held.
  const double* residual_meeting(const double* box) const;
  // The closed ball whose centre lies in [centre_lo, centre_hi] (per axis) with squared
  // radius at most radius2_up.
  bool ball_held(const double* centre_lo, const double* centre_hi, double radius2_up) const;
  // f: the facet's d points; inner: a point on its inner side; ids: the facet's indices.
  bool beyond_held(const double* const* f, const double* inner, std::span<const std::uint32_t> ids) const;
  // A star of the run's PointSet (`points`, whose indices known_hull reads): certified
  // when every simplex's ball and every hull facet's outer side is held; otherwise the
  // balls and hull facets to fetch (as StarCertifier::certify gives them).
  StarCertificate certify(const PointSet& points, const Star& star) const;
  // About how many points the process lacks inside the box: each residual's share of
  // its unheld box's count, by volume (for decisions of work only, never of answers).
  double lacking_in(const double* box) const;

 private:
  int d_;
  std::vector<double> whole_;
  std::uint64_t whole_points_;
  std::vector<double> held_boxes_, held_balls_;
  struct Unheld {
    std::vector<double> box;
    std::uint64_t points;
  };
  std::vector<Unheld> unheld_;
  struct Residual {
    std::vector<double> box;
    double points;  // the unheld box's count times this part's share of its volume
  };
  std::vector<Residual> residual_;
  std::vector<double> residual_boxes_;  // the residuals' boxes, one after another
  std::function<bool(std::span<const std::uint32_t>)> known_hull_;
};

class StarCertifier {
 public:
  // held: the points held; whole_box: the whole set's bounding box (d lows, d highs),
  // outside which there are no points.
  StarCertifier(const PointSet& held, std::span<const double> whole_box)
      : points_(held), global_(whole_box.begin(), whole_box.end()) {}

  // held_boxes: boxes (d lows, then d highs each) inside each of which every point of
  // the whole set is held (a ball whose part inside the whole set's box lies in one
  // misses every unheld box). unheld: boxes
  // (2 d doubles each) covering every point not held. known_hull(facet) says whether a
  // hull facet (d ascending indices) is known to be one of the whole set (every point
  // beyond or on its plane was fetched, and it is still a hull facet). Certified when
  // the bounds prove the star is the whole set's.
  // held_balls: balls (d centre coordinates, then the radius) inside each of which
  // every point is held, likewise.
  StarCertificate certify(const Star& star, std::span<const double> held_boxes, std::span<const double> held_balls,
                          std::span<const double> unheld,
                          const std::function<bool(std::span<const std::uint32_t>)>& known_hull) const;
  bool certified(const Star& star, std::span<const double> held_boxes, std::span<const double> unheld) const {
    return certify(star, held_boxes, {}, unheld, [](std::span<const std::uint32_t>) { return false; }).certified;
  }

  // Whether every point of the whole set within the closed ball around point `seed`
  // (held) of squared radius radius2 is held, by the same boxes and balls as
  // certify(): the ball's part inside the whole set's box lies in a held box or a held
  // ball, or the ball misses every unheld box. Conservative (false when undecided).
  bool ball_is_held(std::uint32_t seed, double radius2, std::span<const double> held_boxes,
                    std::span<const double> held_balls, std::span<const double> unheld) const;

  // Whether box (2 D doubles) may hold a point beyond or on the plane of the facet
  // through points f (d of them) on the side away from `inner` (a conservative filter:
  // true when undecided). For answering hull queries. d = 2, 3.
  static bool may_be_beyond(int d, const double* const* f, const double* inner, const double* box);
  // Whether point q may lie beyond or on that plane (true when undecided).
  static bool may_be_beyond_point(int d, const double* const* f, const double* inner, const double* q);

 private:
  const PointSet& points_;
  std::vector<double> global_;
};

}  // namespace spokemesh
