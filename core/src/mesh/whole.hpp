// The triangulation of every point of a 2-d or 3-d set (Whole<D>, behind the public
// WholeTriangulation), and what reads stars and rows out of a triangulation: shared by
// the whole mesh's sweep (delaunay_sweep.cpp: regions' triangulations, and one of every
// point when balls reach across the set) and by the callers that keep one
// (whole.cpp: cells, the service's per-seed answers, insertion).
//
// A star read here is the star StarWalker::compute gives for the same part, simplex for
// simplex: the cells around the seed are its simplices (a triangulation of the inserted
// points is unique under the symbolic perturbation, and the seed's star is certified
// or the set is whole), each written canonically (vertices ascending, the last two
// swapped where that order is negatively oriented: the cell is positive, so the sort's
// parity says so), in lexicographic order of their sorted vertex lists.
//
// Thread safety: a Whole is immutable once built; star_of and friends only read it.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <utility>
#include <vector>

#include "mesh/triangulation.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::detail {

// A finite cell's owner, its smallest point id (the seed whose rows hold it); kNoOwner
// for an infinite cell.
constexpr std::uint32_t kNoOwner = 0xFFFFFFFFu;
template <int D>
std::uint32_t owner_of(const Triangulation<D>& t, std::uint32_t c) {
  std::uint32_t owner = kNoOwner;
  for (const std::uint32_t v : t.cell(c).v) {
    if (v == Triangulation<D>::kInfinite) return kNoOwner;
    owner = std::min(owner, t.global(v));
  }
  return owner;
}

// The triangulation of every point with what reads it: each point's local id, and
// the finite cells by owner (their smallest point id): owner p's are
// owned[owned_start[p] .. owned_start[p + 1]) (empty when not indexed: the cells around
// each seed are read instead). It owns (shares) the Predicates its triangulation
// borrows, so a caller may keep it past the run that built it.
template <int D>
struct Whole final : WholeTriangulation {
  std::shared_ptr<const Predicates> pred;
  const PointSet* points = nullptr;
  std::unique_ptr<Triangulation<D>> tri;
  std::vector<std::uint32_t> local, owned_start, owned;
  std::size_t bytes() const override {
    return tri->bytes() + (local.capacity() + owned_start.capacity() + owned.capacity()) * sizeof(std::uint32_t);
  }
  int dimension() const override { return D; }
  const PointSet& point_set() const override { return *points; }
};

// w's owner index: a counting sort of the finite cells by owner. A seed's rows then
// cost its own cells, not a search around it (on a torus's surface a point has 76
// cells around it and owns 19).
template <int D>
void index_owners(Whole<D>& w) {
  const Triangulation<D>& t = *w.tri;
  const std::size_t n = w.points->size();
  w.owned_start.assign(n + 1, 0);
  for (std::uint32_t c = 0; c < t.cell_slots(); ++c) {
    if (!t.is_live(c)) continue;
    if (const std::uint32_t o = owner_of(t, c); o != kNoOwner) ++w.owned_start[o + 1];
  }
  for (std::size_t p = 0; p < n; ++p) w.owned_start[p + 1] += w.owned_start[p];
  w.owned.resize(w.owned_start[n]);
  std::vector<std::uint32_t> next(w.owned_start.begin(), w.owned_start.end() - 1);
  for (std::uint32_t c = 0; c < t.cell_slots(); ++c) {
    if (!t.is_live(c)) continue;
    if (const std::uint32_t o = owner_of(t, c); o != kNoOwner) w.owned[next[o]++] = c;
  }
}

// Inserts points `order` (ids, in insertion order) into w's triangulation, recording
// their local ids, and asks granted() now and then (every `every` insertions, and at
// the end) whether the memory may grow: false when it refuses. stop() is asked as often:
// CANCELLED when it says so. With `near` (one point id per point of `order`, inserted
// before it, or kNoOwner), each point's location is walked from its near point's cells.
template <int D, class Granted, class Stop>
Result<bool> insert_into(Whole<D>& w, std::span<const std::uint32_t> order, std::uint32_t every, Granted&& granted,
                         Stop&& stop, std::span<const std::uint32_t> near = {}) {
  Triangulation<D>& t = *w.tri;
  for (std::size_t k = 0; k < order.size(); ++k) {
    if ((k + 1) % every == 0) {
      if (stop()) return cancelled("triangulation cancelled");
      if (!granted()) return false;
    }
    if (!near.empty() && near[k] != kNoOwner) t.walk_from(w.local[near[k]]);
    w.local[order[k]] = t.insert_next(order, k);
  }
  return granted();
}

// Sorts a cell's point ids ascending; true when that took an odd permutation (the
// sorted cell is then negatively oriented, its cells being positive).
template <std::size_t W>
bool sort_with_parity(std::array<std::uint32_t, W>& g) {
  bool odd = false;
  for (std::size_t i = 1; i < g.size(); ++i) {
    for (std::size_t j = i; j > 0 && g[j - 1] > g[j]; --j) {
      std::swap(g[j - 1], g[j]);
      odd = !odd;
    }
  }
  return odd;
}

// A finite cell's row: its point ids ascending but for the last two, swapped when
// ascending order is negatively oriented (the cell is positive).
template <int D>
std::array<std::uint32_t, D + 1> row_of(const Triangulation<D>& t, std::uint32_t c) {
  const auto& v = t.cell(c).v;
  std::array<std::uint32_t, D + 1> g{};
  for (std::size_t k = 0; k <= D; ++k) g[k] = t.global(v[k]);
  if (sort_with_parity(g)) std::swap(g[D - 1], g[D]);
  return g;
}

// One owner's rows in order: lexicographic by their sorted vertex lists (compare the
// last two sorted).
template <int D>
void sort_rows(std::array<std::uint32_t, D + 1>* begin, std::array<std::uint32_t, D + 1>* end) {
  auto key = [](const std::array<std::uint32_t, D + 1>& a) {
    std::array<std::uint32_t, D + 1> s = a;
    if (s[D - 1] > s[D]) std::swap(s[D - 1], s[D]);
    return s;
  };
  std::sort(begin, end, [&](const auto& a, const auto& b) { return key(a) < key(b); });
}

// Scratch for star_of (one per thread).
template <int D>
struct StarScratch {
  std::vector<std::pair<std::array<std::uint32_t, D + 1>, bool>> sorted;  // rows and their parities
  std::vector<std::uint32_t> others;
};

// The star of point `seed` (a point id of t's set) from the cells around it in t
// (`cells`: finite and infinite, as incident_cells lists them), as StarWalker::compute
// gives it for `part`: kAll every simplex canonical in lexicographic order; kOwned the
// owned ones only (the seed their smallest vertex); kWhole the others first, as they
// come (their vertices ascending, not oriented), then the owned ones canonical.
template <int D>
void star_of(const Triangulation<D>& t, std::span<const std::uint32_t> cells, std::uint32_t seed, StarPart part,
             Star& out, StarScratch<D>& scratch) {
  constexpr std::size_t w = D + 1;
  scratch.sorted.clear();
  scratch.others.clear();
  std::size_t hull = 0;
  for (const std::uint32_t c : cells) {
    const auto& v = t.cell(c).v;
    std::array<std::uint32_t, w> g{};
    bool infinite = false;
    for (std::size_t k = 0; k < w; ++k) {
      infinite = infinite || v[k] == Triangulation<D>::kInfinite;
      g[k] = t.global(v[k]);
    }
    if (infinite) {
      ++hull;
      continue;
    }
    const bool odd = sort_with_parity(g);
    if (g[0] == seed || part == StarPart::kAll) {
      scratch.sorted.emplace_back(g, odd);
    } else if (part == StarPart::kWhole) {
      scratch.others.insert(scratch.others.end(), g.begin(), g.end());  // as they come
    }
  }
  // Lexicographic by sorted vertex lists, then positive: the last two swapped where the
  // sort was odd. The seed's own simplices (smallest vertex the seed) come last.
  std::sort(scratch.sorted.begin(), scratch.sorted.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  out.seed = seed;
  out.dimension = D;
  out.hull_facets = hull;
  out.hidden = false;
  out.simplices = scratch.others;
  for (auto [g, odd] : scratch.sorted) {
    if (odd) std::swap(g[w - 2], g[w - 1]);
    out.simplices.insert(out.simplices.end(), g.begin(), g.end());
  }
}

// Point `id`'s star from the triangulation of every point (its owned rows from the
// owner index where the part is kOwned and it was built).
template <int D>
void whole_star(const Whole<D>& whole, std::uint32_t id, StarPart part, Star& out, StarScratch<D>& scratch,
                std::vector<std::uint32_t>& cells, std::vector<std::uint32_t>& seen) {
  cells.clear();
  whole.tri->incident_cells(whole.local[id], cells, seen);
  star_of<D>(*whole.tri, cells, id, part, out, scratch);
}

}  // namespace spokemesh::detail
