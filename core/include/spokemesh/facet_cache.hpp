// FacetCache: the Delaunay facets found during one run of many seeds' stars, shared by
// its workers, so that each facet's wrap is computed once instead of once per vertex.
// The cells command uses it (where a cell falls back to its star); whole meshes use
// the sweep's FrontCache instead (front_cache.hpp), which holds only the front.
//
// In the star walk a seed x rotates about every facet F of its star (d vertices, x
// among them) to find the simplex on the far side; each of F's d vertices does so in
// its own star, so a whole mesh computes every wrap d times. The answer, the apex b
// across F from apex a, is an exact function of the point set (the predicates decide
// it, with symbolic perturbation), so any star may take it from another's work: the
// walk only runs fewer wraps, and every star, and so the mesh, is unchanged.
//
// The cache also remembers, per point, one facet that contains it ("a start"): a
// seed with a start begins its walk at a known simplex instead of d levels of spokes.
// Whole meshes use it for d >= 3; 2-d runs use the EdgeCache (walk_memo.hpp) instead.
//
// Memory: a fixed open-addressing table of d + 3 words per slot, sized from the
// expected facet count and capped at `max_bytes`, plus 4 bytes per point. When the
// table reaches its load limit it stops taking entries and the walk simply computes
// what it cannot find: memory stays bounded whatever the point count. The memory is
// mapped from the OS (huge pages where available) and committed on first touch, so an
// unused part of the table costs nothing.
//
// Entries are never removed, so a slot, once published, is immutable.
// Thread safety: all methods are safe to call concurrently and lock-free (a slot is
// claimed with a compare-and-swap, filled, then published with a release store; a
// reader that sees it acquires its contents). A reader that races a writer may miss
// the entry and compute the wrap itself; it never sees a partial one.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "spokemesh/kd_tree.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/walk_memo.hpp"

namespace spokemesh {

class FacetCache final : public FacetMemo {
 public:
  // d: dimension (2..8); n: point count; the run meshes seeds [begin, end) in blocks
  // of `block` seeds, in block order, each block's seeds in any order; max_bytes caps
  // the table and the per-point starts. A cap too small for a useful table gives a
  // disabled cache (every call a no-op).
  FacetCache(int d, std::uint32_t n, std::uint32_t begin, std::uint32_t end, std::size_t max_bytes,
             std::uint32_t block = 1);
  ~FacetCache() override;

  bool enabled() const { return capacity_ != 0; }
  // Bytes reserved (address space; pages are committed as they are touched).
  std::size_t reserved_bytes() const;
  // What a cache for n points in dimension d would reserve within max_bytes (0: it
  // would be disabled), without building it: for charging a memory budget first.
  static std::size_t bytes_for(int d, std::uint32_t n, std::size_t max_bytes);

  void prefetch(std::uint64_t hash) const override;
  void prefetch_start(std::uint32_t v) const override {
    if (enabled() && v < n_) __builtin_prefetch(starts_.get() + v);
  }
  bool lookup(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
              std::uint32_t& across) const override;
  std::size_t reserve(std::size_t count) override;
  bool wanted(std::uint32_t x, const std::uint32_t* facet) const override;
  void insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
              std::uint32_t b) override;
  bool start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const override;

 private:
  static std::size_t slots_for(int d, std::uint32_t n, std::size_t max_bytes);
  std::uint32_t* slot(std::size_t s) const { return table_.get() + s * stride_; }
  // A hash's first slot: its low 32 bits scaled to [0, capacity) (the tag uses the
  // high 32); probing goes on linearly, wrapping at the end.
  std::size_t home(std::uint64_t hash) const {
    return static_cast<std::size_t>(((hash & 0xFFFFFFFFull) * capacity_) >> 32);
  }
  std::size_t next(std::size_t s) const { return s + 1 == capacity_ ? 0 : s + 1; }
  bool find(const std::uint32_t* facet, std::uint64_t hash, std::size_t& s) const;

  std::uint32_t n_;
  RunOrder order_;
  std::size_t stride_ = 0;    // words per slot: state, d ids, 2 apexes
  std::size_t capacity_ = 0;  // slots (at most 2^31), 0 when disabled
  std::size_t max_entries_ = 0;
  MappedWords table_;
  MappedWords starts_;  // per point: slot + 1, or 0
  mutable std::atomic<std::size_t> entries_{0};
};

// The cache one whole-mesh run shares among its walkers: an EdgeCache in 2-d (posts
// per point: the ring walk), a FacetCache otherwise. Both only save work.
// Ownership: owns the cache it holds. Thread safety: as the cache it holds.
class RunCache {
 public:
  // As FacetCache's constructor; an EdgeCache where uses_edges(d).
  RunCache(int d, std::uint32_t n, std::uint32_t begin, std::uint32_t end, std::size_t max_bytes,
           std::uint32_t block = 1) {
    if (uses_edges(d)) {
      edges_ = std::make_unique<EdgeCache>(n, begin, end, max_bytes, block);
    } else {
      facets_ = std::make_unique<FacetCache>(d, n, begin, end, max_bytes, block);
    }
  }
  bool enabled() const { return (facets_ && facets_->enabled()) || (edges_ && edges_->enabled()); }
  std::size_t reserved_bytes() const {
    return facets_ ? facets_->reserved_bytes() : edges_ ? edges_->reserved_bytes() : 0;
  }
  // What the cache of a run over n points would reserve within max_bytes.
  static std::size_t bytes_for(int d, std::uint32_t n, std::size_t max_bytes) {
    return uses_edges(d) ? EdgeCache::bytes_for(n, max_bytes) : FacetCache::bytes_for(d, n, max_bytes);
  }
  // Whether stars in dimension d share edges per point (the ring walk's: 2-d) rather
  // than facets; the core's dimension policy decides.
  static bool uses_edges(int d);
  // The cache of this run's kind when enabled, else nullptr.
  FacetCache* facets() const { return facets_ && facets_->enabled() ? facets_.get() : nullptr; }
  EdgeCache* edges() const { return edges_ && edges_->enabled() ? edges_.get() : nullptr; }

 private:
  std::unique_ptr<FacetCache> facets_;
  std::unique_ptr<EdgeCache> edges_;
};

}  // namespace spokemesh
