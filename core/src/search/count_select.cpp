#include "spokemesh/count_select.hpp"

#include <algorithm>
#include <numeric>

#include "spokemesh/space_split.hpp"

namespace spokemesh {

CountSelect::CountSelect(int d, int axis, std::span<const double> coords, std::span<const std::uint64_t> ids,
                         std::vector<std::uint32_t> members)
    : d_(d), axis_(axis), coords_(coords), ids_(ids), sorted_(std::move(members)) {
  // The candidates are kept unsorted: each round selects and partitions in time linear
  // in them (they shrink by a quarter a round), where a sort of every point per level
  // was most of the distributed split's time.
  hi_ = sorted_.size();
}

CountSelect::CountSelect(int d, int axis, std::span<const double> coords, std::span<const std::uint64_t> ids)
    : CountSelect(d, axis, coords, ids, [&] {
        std::vector<std::uint32_t> all(ids.size());
        std::iota(all.begin(), all.end(), 0u);
        return all;
      }()) {}

bool CountSelect::less(std::uint32_t a, std::uint32_t b) const {
  const auto d_size = static_cast<std::size_t>(d_);
  return before_along(axis_, d_, &coords_[a * d_size], ids_[a], &coords_[b * d_size], ids_[b]);
}

bool CountSelect::less_than(std::uint32_t a, const Key& pivot) const {
  return before_along(axis_, d_, &coords_[a * static_cast<std::size_t>(d_)], ids_[a], pivot.coords.data(), pivot.id);
}

bool CountSelect::before(const Key& a, const Key& b, int axis) {
  return before_along(axis, static_cast<int>(a.coords.size()), a.coords.data(), a.id, b.coords.data(), b.id);
}

CountSelect::Key CountSelect::key_at(std::size_t i) const {
  const std::uint32_t p = sorted_[i];
  const double* c = &coords_[std::size_t{p} * static_cast<std::size_t>(d_)];
  return {std::vector<double>(c, c + d_), ids_[p]};
}

CountSelect::Proposal CountSelect::propose() {
  if (lo_ == hi_) return {};
  // The middle candidate in the total order (the one a sorted run would give).
  const auto first = sorted_.begin() + static_cast<std::ptrdiff_t>(lo_);
  const auto middle = first + static_cast<std::ptrdiff_t>((hi_ - lo_) / 2);
  std::nth_element(first, middle, sorted_.begin() + static_cast<std::ptrdiff_t>(hi_),
                   [&](std::uint32_t a, std::uint32_t b) { return less(a, b); });
  return {key_at(static_cast<std::size_t>(middle - sorted_.begin())), hi_ - lo_};
}

CountSelect::Key CountSelect::pivot_of(std::span<const Proposal> proposals, int axis) {
  // The weighted median of the parts' medians: the first, in the total order, at
  // which the counts of the proposals up to it reach half of all. At least half the
  // candidates of the parts proposing at or before it lie at or below their medians,
  // so a quarter of all lie at or below the pivot, and likewise above.
  std::vector<const Proposal*> given;
  std::uint64_t total = 0;
  for (const Proposal& p : proposals) {
    if (p.count == 0) continue;
    given.push_back(&p);
    total += p.count;
  }
  std::sort(given.begin(), given.end(),
            [&](const Proposal* a, const Proposal* b) { return before(a->key, b->key, axis); });
  std::uint64_t seen = 0;
  for (const Proposal* p : given) {
    seen += p->count;
    if (2 * seen >= total) return p->key;
  }
  return given.empty() ? Key{} : given.back()->key;
}

CountSelect::Counts CountSelect::count(const Key& pivot) const {
  Counts out;
  for (std::size_t i = lo_; i < hi_; ++i) {
    const std::uint32_t p = sorted_[i];
    if (less_than(p, pivot)) {
      ++out.below;
    } else if (ids_[p] == pivot.id && std::equal(pivot.coords.begin(), pivot.coords.end(),
                                                 coords_.begin() + static_cast<std::ptrdiff_t>(p) * d_)) {
      out.at = 1;
    }
  }
  return out;
}

CountSelect::Side CountSelect::decide(std::uint64_t& k, const Counts& total) {
  if (k < total.below) return Side::kBelow;
  if (k < total.below + total.at) return Side::kFound;
  k -= total.below + total.at;
  return Side::kAbove;
}

void CountSelect::narrow(const Key& pivot, Side side) {
  // The candidates before the pivot to the front, then the pivot itself (if here).
  const auto first = sorted_.begin() + static_cast<std::ptrdiff_t>(lo_);
  const auto last = sorted_.begin() + static_cast<std::ptrdiff_t>(hi_);
  const auto mid = std::partition(first, last, [&](std::uint32_t p) { return less_than(p, pivot); });
  const auto at =
      std::partition(mid, last, [&](std::uint32_t p) { return !less_than(p, pivot) && ids_[p] == pivot.id; });
  const auto below = static_cast<std::size_t>(mid - sorted_.begin());
  const auto after = static_cast<std::size_t>(at - sorted_.begin());
  if (side == Side::kBelow) {
    hi_ = below;
  } else if (side == Side::kAbove) {
    lo_ = after;
  } else {
    lo_ = hi_ = below;  // found: nothing left to choose
  }
}

}  // namespace spokemesh
