#include "spokemesh/walk_memo.hpp"

#include <algorithm>
#include <array>
#include <atomic>

#include <sys/mman.h>
#include <unistd.h>

#include "base/dimension.hpp"
#include "base/mixing.hpp"
#include "walks/mapped_words.hpp"

namespace spokemesh {
namespace {

using Word = std::atomic_ref<std::uint32_t>;

// Bytes the caches hold mapped right now, process-wide (see mapped_cache_bytes()).
std::atomic<std::size_t> g_mapped_bytes{0};

}  // namespace

// Zeroed memory straight from the OS: pages are committed on first touch, and huge
// pages are requested because lookups land at random all over the table (with 4 KiB
// pages nearly every lookup also missed the TLB). Empty on failure.
//
// The deleter is built here, after the size is known, and handed out with the
// pointer: an earlier version built `UnmapWords{bytes}` in the same call expression
// as the allocation, so it captured the size before it was set and every munmap got
// length 0 (EINVAL): each whole mesh leaked its cache.
MappedWords allocate_zeroed(std::size_t words, bool huge) {
  const std::size_t bytes = words * sizeof(std::uint32_t);
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) return MappedWords(nullptr, UnmapWords{0});
  if (huge) ::madvise(p, bytes, MADV_HUGEPAGE);  // advice only: ignored where unsupported
  g_mapped_bytes.fetch_add(bytes, std::memory_order_relaxed);
  return MappedWords(static_cast<std::uint32_t*>(p), UnmapWords{bytes});
}

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

}  // namespace spokemesh
