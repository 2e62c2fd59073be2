#include "spokemesh/facet_cache.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdlib>

#include <sys/mman.h>
#include <unistd.h>

#include "base/dimension.hpp"
#include "base/mixing.hpp"
#include "spokemesh/point_set.hpp"
#include "walks/mapped_words.hpp"

namespace spokemesh {
namespace {

// Slot states (word 0): empty, being written, or a published entry's tag (>= 2).
constexpr std::uint32_t kEmpty = 0, kWriting = 1;
// Linear probing with at most this load, and at most this many probes per call, so
// every call is bounded even when the table is full of colliding entries.
constexpr double kMaxLoad = 0.7;
constexpr std::size_t kMaxProbes = 64;
// Below this many slots the cache is not worth its probes.
constexpr std::size_t kMinSlots = 1024;
// Starts store slot + 1 in 32 bits.
constexpr std::size_t kMaxSlots = std::size_t{1} << 31;

using Word = std::atomic_ref<std::uint32_t>;

std::uint32_t tag_of(std::uint64_t hash) {
  const auto t = static_cast<std::uint32_t>(hash >> 32);
  return t <= kWriting ? t + 2 : t;  // never empty or being written
}

}  // namespace

// The table's slot count for n points within max_bytes (with the per-point starts);
// 0 when the cache would be disabled.
std::size_t FacetCache::slots_for(int d, std::uint32_t n, std::size_t max_bytes) {
  const std::size_t starts_bytes = std::size_t{n} * sizeof(std::uint32_t);
  const std::size_t stride = static_cast<std::size_t>(d) + 3;
  if (d < 2 || d > kMaxDimension || max_bytes <= starts_bytes) return 0;
  const double wanted = expected_facets_per_point(d) * static_cast<double>(n) / kMaxLoad;
  const std::size_t affordable = (max_bytes - starts_bytes) / (stride * sizeof(std::uint32_t));
  // Any slot count (home slots come from a multiply, not a mask), 10% above the
  // estimate: a power of two would waste up to half the table, and every page of it
  // is zeroed by the kernel when first touched (bench/README.md, "Tuning history").
  const auto estimate = static_cast<std::size_t>(std::min(wanted * 1.1, static_cast<double>(kMaxSlots)));
  const std::size_t slots = std::min({std::max(estimate, kMinSlots), affordable, kMaxSlots});
  return slots < kMinSlots ? 0 : slots;  // too little memory for a useful table: none
}

std::size_t FacetCache::bytes_for(int d, std::uint32_t n, std::size_t max_bytes) {
  const std::size_t slots = slots_for(d, n, max_bytes);
  if (slots == 0) return 0;
  return (slots * (static_cast<std::size_t>(d) + 3) + std::max<std::size_t>(n, 1)) * sizeof(std::uint32_t);
}

FacetCache::FacetCache(int d, std::uint32_t n, std::uint32_t begin, std::uint32_t end, std::size_t max_bytes,
                       std::uint32_t block)
    : FacetMemo(d),
      n_(n),
      order_{begin, std::min(end, n), std::max(block, 1u)},
      stride_(static_cast<std::size_t>(d) + 3) {
  if (order_.begin >= order_.end) return;
  const std::size_t slots = slots_for(d, n, max_bytes);
  if (slots == 0) return;
  table_ = allocate_zeroed(slots * stride_);
  starts_ = allocate_zeroed(std::max<std::size_t>(n, 1));
  if (!table_ || !starts_) {
    table_.reset();
    starts_.reset();
    return;
  }
  capacity_ = slots;
  max_entries_ = static_cast<std::size_t>(static_cast<double>(slots) * kMaxLoad);
}

FacetCache::~FacetCache() = default;

std::size_t FacetCache::reserved_bytes() const {
  return enabled() ? (capacity_ * stride_ + n_) * sizeof(std::uint32_t) : 0;
}

bool FacetCache::find(const std::uint32_t* facet, std::uint64_t hash, std::size_t& s) const {
  const std::uint32_t tag = tag_of(hash);
  s = home(hash);
  for (std::size_t probe = 0; probe < kMaxProbes; ++probe, s = next(s)) {
    std::uint32_t* w = slot(s);
    const std::uint32_t state = Word(w[0]).load(std::memory_order_acquire);
    if (state == kEmpty) return false;
    if (state == tag && detail::same_indices(facet, w + 1, static_cast<std::size_t>(d_))) return true;
  }
  return false;
}

void FacetCache::prefetch(std::uint64_t hash) const {
  if (enabled()) __builtin_prefetch(slot(home(hash)));
}

bool FacetCache::lookup(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
                        std::uint32_t& across) const {
  if (!enabled()) return false;
  // Only a vertex meshed before x can have recorded the facet.
  bool earlier = false;
  for (int i = 0; i < d_; ++i) earlier |= order_.maybe_before(facet[i], x);
  if (!earlier) return false;
  std::size_t s;
  if (!find(facet, hash, s)) return false;
  const std::uint32_t* w = slot(s);
  return across_from(w[1 + d_], w[2 + d_], from, across);
}

std::size_t FacetCache::reserve(std::size_t count) {
  if (!enabled()) return 0;
  const std::size_t before = entries_.fetch_add(count, std::memory_order_relaxed);
  return before >= max_entries_ ? 0 : std::min(count, max_entries_ - before);
}

bool FacetCache::wanted(std::uint32_t x, const std::uint32_t* facet) const {
  if (!enabled()) return false;
  bool later = false;
  for (int i = 0; i < d_; ++i) later |= order_.maybe_after(facet[i], x);
  return later;
}

void FacetCache::insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
                        std::uint32_t b) {
  if (!enabled()) return;
  const std::uint32_t tag = tag_of(hash);
  std::size_t s = home(hash);
  for (std::size_t probe = 0; probe < kMaxProbes; ++probe, s = next(s)) {
    std::uint32_t* w = slot(s);
    std::uint32_t state = Word(w[0]).load(std::memory_order_acquire);
    if (state == kEmpty && Word(w[0]).compare_exchange_strong(state, kWriting, std::memory_order_acquire)) {
      std::copy(facet, facet + d_, w + 1);
      w[1 + d_] = a;
      w[2 + d_] = b;
      Word(w[0]).store(tag, std::memory_order_release);
      // Starts for the later vertices that have none yet (a lost race only replaces
      // one valid start with another).
      for (int i = 0; i < d_; ++i) {
        if (order_.maybe_after(facet[i], x)) {
          Word start(starts_[facet[i]]);
          if (start.load(std::memory_order_relaxed) == 0)
            start.store(static_cast<std::uint32_t>(s + 1), std::memory_order_release);
        }
      }
      return;
    }
    if (state == tag && detail::same_indices(facet, w + 1, static_cast<std::size_t>(d_)))
      return;  // another star got there first
  }
}

bool FacetCache::start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const {
  if (!enabled() || x >= n_) return false;
  const std::uint32_t s1 = Word(starts_[x]).load(std::memory_order_acquire);
  if (s1 == 0) return false;
  std::uint32_t* w = slot(s1 - 1);
  // Published before the start was stored; the acquire above makes it visible.
  if (Word(w[0]).load(std::memory_order_acquire) <= kWriting) return false;
  std::copy(w + 1, w + 1 + d_, facet);
  a = w[1 + d_];
  b = w[2 + d_];
  return true;
}

bool RunCache::uses_edges(int d) { return detail::policy(d).ring_walk; }

}  // namespace spokemesh
