#include "spokemesh/front_cache.hpp"

#include <algorithm>
#include <cmath>

#include "base/mixing.hpp"

namespace spokemesh {

FrontMail::FrontMail(int d, const SpaceSplit& blocks, std::size_t max_bytes)
    : entry_words_(static_cast<std::size_t>(d) + 2), max_bytes_(max_bytes), boxes_(blocks.block_count()) {}

FrontMail::Estimate FrontMail::estimate(int d, std::uint64_t n, unsigned threads, std::uint32_t block_points) {
  const double facets = expected_facets_per_point(d);
  const double words = d + 2;
  // Measured (tests/test_sweep.cpp, docs/algorithm.md): the mail peaks at about 2 to 3
  // entries per facet-per-point per n^((d-1)/d) in 3-d; 8 leaves room for clustered
  // sets and for higher d, where the surface is most of the set.
  const double surface = std::min(static_cast<double>(n), 8 * std::pow(static_cast<double>(n), (d - 1.0) / d));
  // A table at most half full, grown by doubling: up to 4 slots of d + 3 words per entry.
  const double table = std::min<double>(static_cast<double>(block_points), static_cast<double>(n)) * facets * 4 *
                       (d + 3) * sizeof(std::uint32_t);
  return {static_cast<std::size_t>(surface * facets * words * sizeof(std::uint32_t)),
          static_cast<std::size_t>(table) * std::max(threads, 1u)};
}

void FrontMail::post_all(std::span<const std::uint32_t> records) {
  const std::size_t stride = 1 + entry_words_;
  std::lock_guard lock(mu_);
  std::size_t held = held_.load(std::memory_order_relaxed);
  for (std::size_t at = 0; at + stride <= records.size(); at += stride) {
    Mailbox& box = boxes_[records[at]];
    if (box.begun) continue;  // its stars are being computed: too late to help
    if (held + entry_words_ * sizeof(std::uint32_t) > max_bytes_) continue;
    const std::size_t before = box.words.capacity();
    box.words.insert(box.words.end(), records.begin() + static_cast<std::ptrdiff_t>(at + 1),
                     records.begin() + static_cast<std::ptrdiff_t>(at + stride));
    held += (box.words.capacity() - before) * sizeof(std::uint32_t);
  }
  held_.store(held, std::memory_order_relaxed);
  if (held > peak_.load(std::memory_order_relaxed)) peak_.store(held, std::memory_order_relaxed);
}

void FrontMail::take(std::uint32_t b, std::vector<std::uint32_t>& out) {
  std::vector<std::uint32_t> spare;  // out's old buffer, freed outside the lock
  std::lock_guard lock(mu_);
  Mailbox& box = boxes_[b];
  box.begun = true;
  out.clear();
  out.swap(box.words);
  spare.swap(box.words);
  held_.fetch_sub(out.capacity() * sizeof(std::uint32_t), std::memory_order_relaxed);
}

FrontCache::FrontCache(int d, const SpaceSplit& blocks, FrontMail& mail, const RunOrder& seeds)
    : FacetMemo(d),
      blocks_(blocks),
      mail_(mail),
      seeds_(seeds),
      stride_(static_cast<std::size_t>(d) + 3),
      table_((std::size_t{1} << 12) * stride_, 0),
      capacity_(std::size_t{1} << 12) {}

void FrontCache::begin_block(std::uint32_t b) {
  ++generation_;  // every slot of the last block reads empty now
  count_ = 0;
  lo_ = blocks_.begin(b);
  hi_ = blocks_.end(b);
  starts_.assign(hi_ - lo_, 0);
  mail_.take(b, incoming_);
  const std::size_t entry = static_cast<std::size_t>(d_) + 2;
  for (std::size_t at = 0; at + entry <= incoming_.size(); at += entry) {
    const std::uint32_t* facet = &incoming_[at];
    // Passed on to the next block that wants it (posted when this block ends).
    if (add(facet, hash(facet), facet[d_], facet[d_ + 1])) post_next(facet, hi_, facet[d_], facet[d_ + 1]);
  }
  incoming_.clear();
}

void FrontCache::end_block() {
  mail_.post_all(outgoing_);
  outgoing_.clear();
}

std::size_t FrontCache::held_bytes() const {
  return (table_.capacity() + starts_.capacity() + outgoing_.capacity() + incoming_.capacity()) * sizeof(std::uint32_t);
}

std::int64_t FrontCache::find(const std::uint32_t* facet, std::uint64_t hash, std::size_t& empty) const {
  const std::size_t mask = capacity_ - 1;
  for (std::size_t s = hash & mask;; s = (s + 1) & mask) {
    const std::uint32_t* w = slot(s);
    if (w[0] != generation_) {  // the load stays below 1/2: an empty slot ends every probe
      empty = s;
      return -1;
    }
    if (detail::same_indices(facet, w + 1, static_cast<std::size_t>(d_))) return static_cast<std::int64_t>(s);
  }
}

bool FrontCache::add(const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a, std::uint32_t b) {
  std::size_t s = 0;
  if (find(facet, hash, s) >= 0) return false;
  std::uint32_t* w = slot(s);
  w[0] = generation_;
  std::copy(facet, facet + d_, w + 1);
  w[1 + d_] = a;
  w[2 + d_] = b;
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (r >= lo_ && r < hi_ && starts_[r - lo_] == 0) starts_[r - lo_] = static_cast<std::uint32_t>(s + 1);
  }
  if (++count_ * 2 > capacity_) grow();
  return true;
}

void FrontCache::grow() {
  std::vector<std::uint32_t> old(capacity_ * 2 * stride_, 0);
  old.swap(table_);
  const std::size_t old_capacity = capacity_;
  capacity_ *= 2;
  const auto moved = [&](std::size_t s) {  // old slot s's place in the new table
    const std::uint32_t* w = &old[s * stride_];
    std::size_t to = 0;
    find(w + 1, hash(w + 1), to);
    return to;
  };
  for (std::size_t s = 0; s < old_capacity; ++s) {
    const std::uint32_t* w = &old[s * stride_];
    if (w[0] != generation_) continue;
    std::copy(w, w + stride_, slot(moved(s)));
  }
  for (std::uint32_t& start : starts_) {
    if (start == 0) continue;
    std::size_t at = 0;
    const std::uint32_t* w = &old[std::size_t{start - 1} * stride_];
    start = static_cast<std::uint32_t>(find(w + 1, hash(w + 1), at) + 1);
  }
}

void FrontCache::prefetch(std::uint64_t hash) const { __builtin_prefetch(slot(hash & (capacity_ - 1))); }

bool FrontCache::lookup(std::uint32_t, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
                        std::uint32_t& across) const {
  std::size_t empty = 0;
  const std::int64_t s = find(facet, hash, empty);
  if (s < 0) return false;
  const std::uint32_t* w = slot(static_cast<std::size_t>(s));
  return across_from(w[1 + d_], w[2 + d_], from, across);
}

bool FrontCache::wanted(std::uint32_t x, const std::uint32_t* facet) const {
  const std::uint32_t rx = blocks_.position_of(x);
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (facet[i] != x && r != kNotSeed && r > rx) return true;
  }
  return false;
}

void FrontCache::post_next(const std::uint32_t* facet, std::uint32_t after, std::uint32_t a, std::uint32_t b) {
  std::uint32_t next = kNotSeed;  // the smallest position at or past `after` among its seeds
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (r != kNotSeed && r >= after) next = std::min(next, r);
  }
  if (next == kNotSeed) return;
  outgoing_.push_back(blocks_.block_of(next));
  outgoing_.insert(outgoing_.end(), facet, facet + d_);
  outgoing_.push_back(a);
  outgoing_.push_back(b);
}

void FrontCache::insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
                        std::uint32_t b) {
  // Who still wants it: later seeds of this block (the table) and later blocks. Only
  // the first of those blocks is sent it; that block passes it on (begin_block), so a
  // facet waits in one mailbox at a time, however many blocks its vertices span.
  const std::uint32_t rx = blocks_.position_of(x);
  bool here = false;
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    here |= facet[i] != x && r != kNotSeed && r > rx && r < hi_;
  }
  // Already in the table: recorded, and posted, by an earlier star.
  if (here && !add(facet, hash, a, b)) return;
  post_next(facet, hi_, a, b);
}

bool FrontCache::start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const {
  const std::uint32_t r = blocks_.position_of(x);
  if (r < lo_ || r >= hi_) return false;
  const std::uint32_t s1 = starts_[r - lo_];
  if (s1 == 0) return false;
  const std::uint32_t* w = slot(s1 - 1);
  std::copy(w + 1, w + 1 + d_, facet);
  a = w[1 + d_];
  b = w[2 + d_];
  return true;
}

}  // namespace spokemesh
