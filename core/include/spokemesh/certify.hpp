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
