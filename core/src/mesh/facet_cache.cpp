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

// Bytes the caches hold mapped right now, process-wide (see mapped_cache_bytes()).
std::atomic<std::size_t> g_mapped_bytes{0};

// Zeroed memory straight from the OS: pages are committed on first touch, and huge
// pages are requested because lookups land at random all over the table (with 4 KiB
// pages nearly every lookup also missed the TLB). Empty on failure.
//
// The deleter is built here, after the size is known, and handed out with the
// pointer: an earlier version built `UnmapWords{bytes}` in the same call expression
// as the allocation, so it captured the size before it was set and every munmap got
// length 0 (EINVAL): each whole mesh leaked its cache.
MappedWords allocate_zeroed(std::size_t words, bool huge = true) {
  const std::size_t bytes = words * sizeof(std::uint32_t);
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) return MappedWords(nullptr, UnmapWords{0});
  if (huge) ::madvise(p, bytes, MADV_HUGEPAGE);  // advice only: ignored where unsupported
  g_mapped_bytes.fetch_add(bytes, std::memory_order_relaxed);
  return MappedWords(static_cast<std::uint32_t*>(p), UnmapWords{bytes});
}


}  // namespace

double expected_facets_per_point(int d) {
  // Simplices per point times (d + 1) / 2 facets per simplex. An underestimate only
  // fills a table sooner; then the walk computes the rest.
  const int c = std::clamp(d, 2, kMaxDimension);
  return detail::policy(c).simplices_per_point * (c + 1) / 2.0;
}

void UnmapWords::operator()(std::uint32_t* p) const {
  if (p == nullptr) return;
  if (::munmap(p, bytes) == 0) g_mapped_bytes.fetch_sub(bytes, std::memory_order_relaxed);
}

std::size_t mapped_cache_bytes() { return g_mapped_bytes.load(std::memory_order_relaxed); }

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
    : FacetMemo(d), n_(n), order_{begin, std::min(end, n), std::max(block, 1u)}, stride_(static_cast<std::size_t>(d) + 3) {
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

std::uint64_t FacetMemo::hash(const std::uint32_t* facet) const {
  std::uint64_t sum = 0;
  for (int i = 0; i < d_; ++i) sum += detail::set_hash_term(facet[i]);
  return detail::set_hash_finish(sum);
}

void FacetMemo::facet_hashes(std::uint32_t x, const std::uint32_t* others, std::uint64_t* out) const {
  std::array<std::uint64_t, kMaxDimension> terms;
  std::uint64_t sum = detail::set_hash_term(x);
  for (int k = 0; k < d_; ++k) {
    terms[static_cast<std::size_t>(k)] = detail::set_hash_term(others[k]);
    sum += terms[static_cast<std::size_t>(k)];
  }
  for (int k = 0; k < d_; ++k) out[k] = detail::set_hash_finish(sum - terms[static_cast<std::size_t>(k)]);
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
          if (start.load(std::memory_order_relaxed) == 0) start.store(static_cast<std::uint32_t>(s + 1), std::memory_order_release);
        }
      }
      return;
    }
    if (state == tag && detail::same_indices(facet, w + 1, static_cast<std::size_t>(d_))) return;  // another star got there first
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

// ---------------------------------------------------------------------------------
// EdgeCache

std::size_t EdgeCache::bytes_for(std::uint32_t n, std::size_t max_bytes) {
  const std::size_t bytes = std::size_t{n} * kBoxWords * sizeof(std::uint32_t);
  return bytes > max_bytes ? 0 : bytes;
}

EdgeCache::EdgeCache(std::uint32_t n, RunOrder order, std::size_t max_bytes) : n_(n), order_(order) {
  order_.end = std::min(order_.end, n);
  if (order_.begin >= order_.end || bytes_for(n, max_bytes) == 0) return;
  // A sweep touches its boxes in sweep order and releases them behind it: small pages,
  // so that what is held is the boxes near the sweep and the front's posts ahead of it
  // (a huge page would hold 2 MiB for each post far ahead).
  boxes_ = allocate_zeroed(std::size_t{n} * kBoxWords, /*huge=*/order_.sweep == nullptr);
}

void EdgeCache::release_before(std::uint32_t rank) {
  if (!enabled() || order_.sweep == nullptr) return;
  const std::size_t page = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  const std::size_t bytes = std::size_t{n_} * kBoxWords * sizeof(std::uint32_t);
  auto* base = reinterpret_cast<unsigned char*>(boxes_.get());
  // What is resident now, before this release (sampled at each finished block: the
  // peak between two samples is at most the blocks finished since).
  residency_.resize((bytes + page - 1) / page);
  if (::mincore(base, bytes, residency_.data()) == 0) {
    std::size_t resident = 0;
    for (const unsigned char r : residency_) resident += r & 1u;
    resident_peak_ = std::max(resident_peak_, resident * page);
  }
  const std::size_t upto = std::min(std::size_t{rank} * kBoxWords * sizeof(std::uint32_t), bytes) / page * page;
  if (upto > released_) {
    // Anonymous private pages: freed now, and zero if ever read again (none is: every
    // seed before `rank` is done, and posts go only to later ones).
    ::madvise(base + released_, upto - released_, MADV_DONTNEED);
    released_ = upto;
  }
}

void EdgeCache::post(std::uint32_t t, const Post& p) {
  if (!enabled() || t >= n_) return;
  std::uint32_t* w = box(t);
  const std::uint32_t i = Word(w[0]).fetch_add(1, std::memory_order_relaxed);
  if (i >= static_cast<std::uint32_t>(kPostsPerPoint)) return;  // full (the count only grows)
  std::uint32_t* slot = w + 1 + 3 * i;
  slot[1] = p.a;
  slot[2] = p.b;
  Word(slot[0]).store(p.from + 1, std::memory_order_release);
}

int EdgeCache::read(std::uint32_t t, Post* out) const {
  if (!enabled() || t >= n_) return 0;
  std::uint32_t* w = box(t);
  const std::uint32_t claimed = Word(w[0]).load(std::memory_order_relaxed);
  const int count = static_cast<int>(std::min<std::uint32_t>(claimed, kPostsPerPoint));
  int got = 0;
  for (int i = 0; i < count; ++i) {
    std::uint32_t* slot = w + 1 + 3 * i;
    const std::uint32_t from = Word(slot[0]).load(std::memory_order_acquire);
    if (from == 0) continue;  // claimed, still being written
    out[got++] = Post{from - 1, slot[1], slot[2]};
  }
  return got;
}

bool RunCache::uses_edges(int d) { return detail::policy(d).ring_walk; }

}  // namespace spokemesh
