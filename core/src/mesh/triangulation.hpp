// Triangulation<D>: an exact Delaunay triangulation of some points of a PointSet,
// built by incremental insertion (Bowyer-Watson), for D = 2 and 3.
//
// The whole-mesh sweep (delaunay_sweep.cpp) triangulates a region of the set with a
// margin around it and reads the stars of the region's seeds from it, certifying each
// with the balls of its simplices (docs/algorithm.md, "Whole meshes in 2-d and 3-d").
// Every decision is the sign of an exact predicate: orientation, and the in-sphere
// test under the same symbolic perturbation as the star walk (Predicates::lifted_sign:
// CGAL's perturbed_side_of_positive_sphere), so the triangulation of the inserted
// points is unique (a function of the points alone, whatever the insertion order)
// and equals CGAL's and the star walk's.
//
// Representation (CGAL's): cells of D + 1 local vertex ids and D + 1 neighbours,
// neighbour i across the facet opposite vertex i. Local vertex 0 is the vertex at
// infinity; a cell holding it stands for a convex-hull facet (the other D vertices).
// Finite cells are positively oriented (det[v1 - v0, ..., vD - v0] > 0); an infinite
// cell is oriented so that putting a point beyond its hull facet in the place of the
// infinite vertex gives a positive orientation (the finite cell across that facet
// then gives a negative one).
//
// Conflicts (which cells a new point p destroys): a finite cell when p is inside its
// perturbed circumsphere; an infinite cell when p is strictly beyond its hull facet,
// or on the facet's plane and in conflict with the finite cell across the facet
// (on that plane the sphere of the finite cell meets it in the facet's circle, and the
// perturbed sign there depends only on points of the plane: the 2-d perturbed test
// inside the hull's face).
//
// Filters: each predicate is first evaluated in double with its monomials'
// magnitudes and rounding depth (the bound of predicates.hpp), then the same in x87
// extended precision (nearly cospherical points: a sphere's surface), then, when that
// cannot certify the sign either, by Predicates' exact stage and perturbation.
//
// Ownership: borrows the PointSet and the Predicates (which must outlive it); owns
// copies of the inserted points' coordinates, in insertion order.
// Thread safety: NOT thread-safe for insertion; concurrent const reads are safe.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh::detail {

template <int D>
class Triangulation {
 public:
  static_assert(D == 2 || D == 3);
  static constexpr std::uint32_t kInfinite = 0;  // the local id of the vertex at infinity
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;

  struct Cell {
    std::array<std::uint32_t, D + 1> v;  // local vertex ids
    std::array<std::uint32_t, D + 1> n;  // n[i]: the cell across the facet opposite v[i]
    std::uint32_t mark;                  // insertion scratch (in the cell: its line is read anyway)
    std::uint32_t tag;                   // the caller's, 0 when the cell is made (tag(c) below)
  };

  Triangulation(const PointSet& points, const Predicates& predicates);
  // A copy of `from` over `points`, whose first points are those of from's set (the
  // same ids, the same coordinates): insertion goes on with the others (a set with
  // points appended, extend_whole). The cells and local ids are from's.
  Triangulation(const Triangulation& from, const PointSet& points, const Predicates& predicates);

  // Forgets every point and cell (keeps the memory).
  void clear();
  // Room for about `points` points without reallocating (a Delaunay triangulation of
  // well-spread points has about 2 cells a point in 2-d and 6.8 in 3-d, infinite ones
  // included: the arrays then grow by a tenth instead of doubling).
  void reserve(std::size_t points);
  // Gives a local id to point `id` of the set and inserts it (its id is returned).
  // Points are only buffered until D + 1 affinely independent ones have come; then
  // the first simplex is built and they are inserted. Precondition: `id` was not
  // inserted before (the set has no duplicate points).
  std::uint32_t insert(std::uint32_t id);
  // Asks the cache for point `id`'s coordinates ahead of its insert(): insertion orders
  // jump about the set, and the miss was 14% of a 2-d insertion's time. Callers ask
  // kPrefetchAhead insertions ahead (2-d uniform 1M: 0.54 -> 0.44 us an insertion).
  static constexpr std::size_t kPrefetchAhead = 8;
  void prefetch(std::uint32_t id) const { __builtin_prefetch(ps_.point(id)); }
  // insert(ids[k]), asking first for the coordinates of ids[k + kPrefetchAhead]: a loop
  // over an insertion order.
  std::uint32_t insert_next(std::span<const std::uint32_t> ids, std::size_t k) {
    if (k + kPrefetchAhead < ids.size()) prefetch(ids[k + kPrefetchAhead]);
    return insert(ids[k]);
  }

  // Starts the next insertion's point location at a cell incident to local vertex v
  // (a point inserted before, near the next one) instead of where the last one ended:
  // points added to a built triangulation (extend_whole), each far from the last.
  void walk_from(std::uint32_t v) {
    if (full_ && v < vcell_.size() && vcell_[v] != kNone) hint_ = vcell_[v];
  }

  // Whether a full-dimensional simplex exists (else no cell does, and every point
  // given so far lies in a common hyperplane).
  bool full() const { return full_; }
  std::uint32_t vertex_count() const { return static_cast<std::uint32_t>(global_.size()); }  // with infinity
  std::uint32_t global(std::uint32_t local) const { return global_[local]; }
  const double* coords(std::uint32_t local) const { return &coords_[static_cast<std::size_t>(local) * D]; }
  const Cell& cell(std::uint32_t c) const { return cells_[c]; }
  bool is_infinite(std::uint32_t c) const;
  // The index of the infinite vertex in cell c (an infinite cell).
  int infinite_index(std::uint32_t c) const;
  // Cells currently alive; cell slots (alive or freed: cells are ids below this).
  std::size_t cell_count() const { return cells_.size() - free_.size(); }
  std::uint32_t cell_slots() const { return static_cast<std::uint32_t>(cells_.size()); }
  // Whether slot c holds a cell (a freed slot's first vertex is kNone).
  bool is_live(std::uint32_t c) const { return cells_[c].v[0] != kNone; }
  std::size_t bytes() const;
  // A word per cell for the caller (the sweep's certificates), 0 whenever the cell is
  // made: cells are reused after insertions destroy them, and a reused cell starts
  // at 0 again.
  std::uint32_t tag(std::uint32_t c) const { return cells_[c].tag; }
  void set_tag(std::uint32_t c, std::uint32_t tag) { cells_[c].tag = tag; }

  // The cells incident to local vertex v (finite and infinite), appended to `out`.
  // Precondition: full(). Safe to call concurrently (`seen` is the caller's scratch).
  void incident_cells(std::uint32_t v, std::vector<std::uint32_t>& out, std::vector<std::uint32_t>& seen) const;

  // Whether (not yet inserted) point `id` would destroy cell c: inside its perturbed
  // circumsphere, or beyond (or, as above, on) its hull facet.
  bool in_conflict(std::uint32_t c, std::uint32_t id) const;

  // Checks the structure and the Delaunay property: neighbours mutual, finite cells
  // positive, infinite cells oriented as above, every facet locally Delaunay (the
  // apex across is outside the perturbed sphere). For tests; O(cells).
  bool valid(std::string* why = nullptr) const;

  // Work counters since construction (for benchmarks and tests).
  struct Stats {
    std::uint64_t insertions = 0;
    std::uint64_t walk_steps = 0;    // cells a point location stepped through
    std::uint64_t cavity_cells = 0;  // cells destroyed by insertions
    std::uint64_t exact_calls = 0;   // predicates the filters could not decide
  };
  const Stats& stats() const { return stats_; }

 private:
  std::uint32_t new_cell();
  void insert_local(std::uint32_t p);
  void start();  // tests the newest buffered point; builds the first simplex when it can
  std::uint32_t locate(std::uint32_t p) const;
  // Cell vertices v without v[i], sorted: the facet opposite v[i] as a set, to match
  // facets between cells.
  static std::array<std::uint32_t, D> sorted_facet(const std::array<std::uint32_t, D + 1>& v, int i);
  // The predicates on points given by coordinates, with their point ids for the
  // exact stage (ids() gives them, only when the filter fails): orientation
  // det[x1 - x0, ..., xD - x0], and the perturbed side of q against the sphere of the
  // positively oriented simplex x (+1 outside, -1 inside).
  using Points = std::array<const double*, D + 1>;
  using Ids = std::array<std::uint32_t, D + 1>;
  Points points_of(const std::array<std::uint32_t, D + 1>& v) const;  // local ids -> coordinates
  Ids ids_of(const std::array<std::uint32_t, D + 1>& v) const;        // local ids -> point ids
  template <class IdsFn>
  int orient_at(const Points& x, IdsFn&& ids) const;
  template <class IdsFn>
  int sphere_at(const Points& x, IdsFn&& ids, const double* q, std::uint32_t q_id) const;
  // The same on cells: cell c's vertices with v[i] replaced by p; the side of p
  // against finite cell c's sphere; whether p conflicts with cell c.
  int orient_points(const std::array<std::uint32_t, D + 1>& v) const;  // all finite
  int orient_with(std::uint32_t c, int i, const double* p, std::uint32_t p_id) const;
  int side_of_sphere(std::uint32_t c, const double* p, std::uint32_t p_id) const;
  bool conflict_at(std::uint32_t c, const double* p, std::uint32_t p_id) const;

  const PointSet& ps_;
  const Predicates& pred_;
  bool full_ = false;
  std::vector<std::uint32_t> global_;   // local id -> point id (0: infinity, unused)
  std::vector<double> coords_;          // local id -> D coordinates
  std::vector<std::uint32_t> pending_;  // local ids waiting for the first simplex
  // The greedy affine basis among pending_ so far (its first basis_size_ entries):
  // kept across start() calls so each buffered point is tested once.
  std::array<std::uint32_t, D + 1> basis_{};
  int basis_size_ = 0;
  std::vector<Cell> cells_;           // Cell::mark: 2 gen in conflict, 2 gen + 1 tested and not
  std::vector<std::uint32_t> free_;   // deleted cells, reused first
  std::vector<std::uint32_t> vcell_;  // local id -> an incident cell
  std::uint32_t gen_ = 0;
  std::uint32_t hint_ = kNone;  // where the next walk starts
  mutable std::uint32_t walk_turn_ = 0;
  // Insertion scratch.
  std::vector<std::uint32_t> stack_, cavity_;
  struct Boundary {
    std::uint32_t cell;
    int facet;
  };
  std::vector<Boundary> boundary_;
  struct Ridge {
    std::uint64_t key;
    std::uint32_t cell;
    std::uint32_t gen;
    int facet;
  };
  std::vector<Ridge> ridges_;
  mutable Stats stats_;
};

extern template class Triangulation<2>;
extern template class Triangulation<3>;

}  // namespace spokemesh::detail
