// CountSelect: the k-th point of a set spread over P parts (processes), in the total
// order along an axis that SpaceSplit uses, found by rounds of one gather and one sum:
// SpaceSplit's median step when no part holds the whole set (docs/distributed.md).
//
// Each part keeps its candidates unsorted: a round selects its middle candidate and
// partitions the rest about the pivot, in time linear in the candidates. A round: every part proposes the middle of its
// candidates with their count (propose); every part computes the same pivot from all proposals, the median of the
// medians weighted by their counts (pivot_of); every part counts its candidates below
// and at the pivot (count); the sums say whether the pivot is the k-th point or on
// which side it lies (decide), and every part keeps that side (narrow). The pivot has
// at least a quarter of all candidates on each side, so each round keeps at most three
// quarters: O(log n) rounds. With MPI a round is an MPI_Allgather of the proposals and
// an MPI_Allreduce of the counts; all parts decide alike, so the result is the same
// point for every P, the one SpaceSplit picks on one process.
//
// Ownership: borrows the part's coordinates and indices. Thread safety: none needed
// (one per part and round; pivot_of and decide are pure).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace spokemesh {

class CountSelect {
 public:
  // A point as every part sees it: its d coordinates and its index in the whole set.
  struct Key {
    std::vector<double> coords;
    std::uint64_t id = 0;
  };
  struct Proposal {
    Key key;                  // the middle of the part's candidates
    std::uint64_t count = 0;  // its candidates (0: nothing proposed)
  };
  struct Counts {
    std::uint64_t below = 0, at = 0;  // candidates before the pivot, and the pivot itself
  };
  enum class Side { kFound, kBelow, kAbove };

  // This part's points: d coordinates each (row-major) with their indices in the
  // whole set; the order along `axis` (0 <= axis < d). Borrowed: they must outlive it.
  CountSelect(int d, int axis, std::span<const double> coords, std::span<const std::uint64_t> ids);
  // Among them only `members` (indices into coords / ids): a node of a split, without
  // copying its points out.
  CountSelect(int d, int axis, std::span<const double> coords, std::span<const std::uint64_t> ids,
              std::vector<std::uint32_t> members);

  // The total order along the axis: that coordinate, then every coordinate in turn,
  // then the index (SpaceSplit's).
  static bool before(const Key& a, const Key& b, int axis);

  Proposal propose();  // (reorders the candidates)
  static Key pivot_of(std::span<const Proposal> proposals, int axis);
  Counts count(const Key& pivot) const;
  // With the counts summed over the parts: where the k-th candidate lies; k is made
  // relative to that side.
  static Side decide(std::uint64_t& k, const Counts& total);
  void narrow(const Key& pivot, Side side);
  std::uint64_t candidates() const { return hi_ - lo_; }

 private:
  Key key_at(std::size_t i) const;
  bool less(std::uint32_t a, std::uint32_t b) const;  // two of this part's points, in the total order
  bool less_than(std::uint32_t a, const Key& pivot) const;
  int d_, axis_;
  std::span<const double> coords_;
  std::span<const std::uint64_t> ids_;
  std::vector<std::uint32_t> sorted_;  // this part's points; the candidates are sorted_[lo_, hi_)
  std::size_t lo_ = 0, hi_ = 0;
};

}  // namespace spokemesh
