// The order in which Triangulation<D> receives points: biased randomized insertion
// order (BRIO: Amenta, Choi and Rote 2003, as CGAL's spatial_sort) over the split's
// order (SpaceSplit: median cuts by counts, spatially coherent).
//
// Why: an insertion's point location walks from the previous insertion's cells, so
// consecutive points should be close (the split's order within a round), while early
// rounds spread thinly over the whole region keep later cavities small. The share of
// the last round matters most. Measured on 1M points, one thread, triangulation alone
// (bench/triangulate.cpp), rounds halving (the last holds half the points) against
// CGAL's shares (seven eighths in 3-d, three quarters in 2-d): a torus's surface 21.3
// -> 15.5 s (78 -> 48 walk steps an insertion), 3-d uniform 3.73 -> 3.35 s. Each round
// along a Hilbert curve instead of the split's order saved 0.1 s of insertions (3-d
// uniform) for 0.18 s of sorting, so the split's order stays.
//
// The order is a function of the points alone: a point's round comes from a hash of
// its id, and the split's order is the points'. The triangulation does not depend on
// the order at all; only its cost does.
//
// Thread safety: pure functions of their arguments.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "base/mixing.hpp"

namespace spokemesh::detail {

// BRIO (Amenta, Choi and Rote 2003; CGAL's spatial_sort): rounds of growing random
// samples. A point's round comes from the trailing zero bits of a hash of its id,
// kRoundBits[D] bits a round: in 3-d an eighth of the points are in the rounds before
// the last, an eighth of those before the one before, and so on (a quarter in 2-d).
// Points on a surface inserted along a curve alone met cavities of 150 cells on
// average; in rounds, 22 to 55.
inline constexpr int kBrioRounds = 24;
inline constexpr int kRoundBits[4] = {1, 1, 2, 3};
template <int D>
int brio_round(std::uint32_t id) {
  std::uint64_t state = id;
  const std::uint64_t h = splitmix64(state) | (std::uint64_t{1} << 63);
  return std::min(__builtin_ctzll(h) / kRoundBits[D], kBrioRounds - 1);
}

// Reorders items into BRIO rounds, coarsest first, keeping their order within a round
// (a counting sort; item i stands for point id_of(i)). `scratch` is the caller's.
template <int D, class IdOf>
void insertion_order(std::vector<std::uint32_t>& items, std::vector<std::uint32_t>& scratch, const IdOf& id_of) {
  std::array<std::size_t, kBrioRounds + 1> start{};
  auto slot = [&](std::uint32_t i) { return static_cast<std::size_t>(kBrioRounds - 1 - brio_round<D>(id_of(i))); };
  for (const std::uint32_t i : items) ++start[slot(i) + 1];
  for (std::size_t k = 0; k < kBrioRounds; ++k) start[k + 1] += start[k];
  scratch.resize(items.size());
  for (const std::uint32_t i : items) scratch[start[slot(i)]++] = i;
  items.swap(scratch);
}
// The same for point ids.
template <int D>
void insertion_order(std::vector<std::uint32_t>& ids, std::vector<std::uint32_t>& scratch) {
  insertion_order<D>(ids, scratch, [](std::uint32_t id) { return id; });
}

}  // namespace spokemesh::detail
