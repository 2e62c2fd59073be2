#include "spokemesh/count_select.hpp"

#include <algorithm>
#include <numeric>

#include "spokemesh/space_split.hpp"

namespace spokemesh {

CountSelect::CountSelect(int d, int axis, std::span<const double> coords, std::span<const std::uint64_t> ids)
    : d_(d), axis_(axis), coords_(coords.begin(), coords.end()), ids_(ids.begin(), ids.end()) {
  sorted_.resize(ids_.size());
  std::iota(sorted_.begin(), sorted_.end(), 0u);
  const auto d_size = static_cast<std::size_t>(d_);
  std::sort(sorted_.begin(), sorted_.end(), [&](std::uint32_t a, std::uint32_t b) {
    return before_along(axis_, d_, &coords_[a * d_size], ids_[a], &coords_[b * d_size], ids_[b]);
  });
  hi_ = sorted_.size();
}

bool CountSelect::before(const Key& a, const Key& b, int axis) {
  return before_along(axis, static_cast<int>(a.coords.size()), a.coords.data(), a.id, b.coords.data(), b.id);
}

CountSelect::Key CountSelect::key_at(std::size_t i) const {
  const std::uint32_t p = sorted_[i];
  const double* c = &coords_[std::size_t{p} * static_cast<std::size_t>(d_)];
  return {std::vector<double>(c, c + d_), ids_[p]};
}

CountSelect::Proposal CountSelect::propose() const {
  if (lo_ == hi_) return {};
  return {key_at(lo_ + (hi_ - lo_) / 2), hi_ - lo_};
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
  // Candidates are a run of the sorted order: the pivot's place by binary search.
  auto below = [&](std::size_t i) { return before(key_at(i), pivot, axis_); };
  std::size_t a = lo_, b = hi_;
  while (a < b) {
    const std::size_t mid = a + (b - a) / 2;
    if (below(mid)) {
      a = mid + 1;
    } else {
      b = mid;
    }
  }
  Counts out;
  out.below = a - lo_;
  if (a < hi_) {
    const Key k = key_at(a);
    out.at = (!before(pivot, k, axis_) && !before(k, pivot, axis_)) ? 1 : 0;
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
  const Counts c = count(pivot);
  if (side == Side::kBelow) {
    hi_ = lo_ + c.below;
  } else if (side == Side::kAbove) {
    lo_ = lo_ + c.below + c.at;
  } else {
    lo_ = hi_ = lo_ + c.below;  // found: nothing left to choose
  }
}

}  // namespace spokemesh
